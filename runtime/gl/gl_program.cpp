#include "runtime/gl/gl_program.h"

#include "runtime/gl/gl_context.h"
#include "runtime/gl/shaders/bindings.h"

#include <new>
#include <sstream>
#include <stdexcept>

namespace heartsim {

namespace {
std::string with_advice(const std::string& message, const std::string& advice) {
    return advice.empty() ? message : message + "; " + advice;
}

/// The `#version` line must come first in a shader, so the binding names follow it here.
const char* preamble() {
    static const std::string text = [] {
        std::string lines = "#version 430 core\n";
        for (const auto& [name, value] : gl_shaders::shader_constants)
            lines += "#define " + std::string(name) + " " + std::to_string(value) + "\n";
        return lines;
    }();
    return text.c_str();
}
}  // namespace

GLuint compile_shader(GLenum stage, const std::vector<const char*>& sources, const std::string& what, const std::string& advice) {
    std::vector<const char*> strings{preamble()};
    strings.insert(strings.end(), sources.begin(), sources.end());
    const GLuint shader = glCreateShader(stage);
    glShaderSource(shader, GLsizei(strings.size()), strings.data(), nullptr);
    glCompileShader(shader);
    GLint ok = 0;
    glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[4096] = {};
        glGetShaderInfoLog(shader, sizeof log, nullptr, log);
        glDeleteShader(shader);
        throw GlUnavailable(with_advice(what + " does not compile on this driver: " + log, advice));
    }
    return shader;
}

GLuint link_program(const std::vector<GLuint>& shaders, const std::string& what, const std::string& advice,
                    const char* feedback_varying) {
    const GLuint program = glCreateProgram();
    for (GLuint s : shaders) glAttachShader(program, s);
    if (feedback_varying) glTransformFeedbackVaryings(program, 1, &feedback_varying, GL_INTERLEAVED_ATTRIBS);
    glLinkProgram(program);
    for (GLuint s : shaders) glDeleteShader(s);
    GLint ok = 0;
    glGetProgramiv(program, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[4096] = {};
        glGetProgramInfoLog(program, sizeof log, nullptr, log);
        glDeleteProgram(program);
        throw GlUnavailable(with_advice(what + " does not link: " + log, advice));
    }
    return program;
}

void check_gl_error(const char* who, const char* what) {
    const GLenum error = glGetError();
    if (error == GL_OUT_OF_MEMORY) throw std::bad_alloc();  // the driver's memory: heartsim says "out of memory"
    if (error != GL_NO_ERROR) {
        std::ostringstream s;
        s << who << ": OpenGL error 0x" << std::hex << error << " while " << what;
        throw std::runtime_error(s.str());
    }
}

}  // namespace heartsim
