/// @file gl_program.h
/// @brief Compiling and linking GLSL programs with errors that say which shader failed, the
/// driver's log, and what the user can do instead. Shared by the backend, picking and renderer.
#pragma once

#include <epoxy/gl.h>

#include <string>
#include <vector>

namespace heartsim {

/// Compiles one shader stage from `sources` (concatenated) after a preamble: `#version 430 core`
/// and the names of shaders/bindings.h (BINDING_CURRENT, ...), which is why the sources carry no
/// `#version` line of their own. Throws GlUnavailable
/// "<what> does not compile on this driver: <log>[; <advice>]".
GLuint compile_shader(GLenum stage, const std::vector<const char*>& sources, const std::string& what,
                      const std::string& advice = "");

/// Links `shaders` (deleted afterwards) into a program; `feedback_varying`, when given, is
/// captured by transform feedback. Throws GlUnavailable "<what> does not link: <log>[; <advice>]".
GLuint link_program(const std::vector<GLuint>& shaders, const std::string& what, const std::string& advice = "",
                    const char* feedback_varying = nullptr);

/// Throws if OpenGL recorded an error: std::bad_alloc for GL_OUT_OF_MEMORY (heartsim says "out of
/// memory"), else std::runtime_error "<who>: OpenGL error 0x… while <what>". The gl backend, its
/// patch pass and the renderer check after their work with it.
void check_gl_error(const char* who, const char* what);

}  // namespace heartsim
