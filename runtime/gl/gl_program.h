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

}  // namespace heartsim
