/// @file gl_object.h
/// @brief One owner for OpenGL object names: `gl::Object<Delete>` holds a name and deletes it
/// when destroyed or handed another (move-only). The runtime's GL code (gl backend, renderer,
/// picking) keeps every buffer, program, vertex array, framebuffer, renderbuffer, texture and
/// timer query in one of the aliases below, and every fence in a `gl::Fence`, so no raw name
/// needs a hand-written destructor.
///
///     gl::Buffer buffer;
///     glCreateBuffers(1, buffer.create());        // or: buffer = name_from_elsewhere;
///     glNamedBufferStorage(buffer, bytes, data, 0);  // converts to GLuint
#pragma once

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <vector>
#include <cstddef>
#include <utility>

namespace heartsim::gl {

template <void (*Delete)(GLuint)>
class Object {
public:
    Object() = default;
    Object(const Object&) = delete;
    Object& operator=(const Object&) = delete;
    Object(Object&& other) noexcept : name_(std::exchange(other.name_, 0)) {}
    Object& operator=(Object&& other) noexcept {
        if (this != &other) reset(std::exchange(other.name_, 0));
        return *this;
    }
    /// Takes ownership of `name` (a name just created elsewhere), deleting the one held.
    Object& operator=(GLuint name) {
        reset(name);
        return *this;
    }
    ~Object() { reset(); }

    /// Deletes the name held (if any) and holds `name`.
    void reset(GLuint name = 0) {
        if (name_ && name_ != name) Delete(name_);
        name_ = name;
    }
    /// For glCreate*(1, …): deletes the name held and returns where to write the new one.
    GLuint* create() {
        reset();
        return &name_;
    }
    GLuint id() const { return name_; }
    operator GLuint() const { return name_; }  ///< hands the name to gl* calls
    explicit operator bool() const { return name_ != 0; }

private:
    GLuint name_ = 0;
};

inline void delete_buffer(GLuint name) { glDeleteBuffers(1, &name); }
inline void delete_program(GLuint name) { glDeleteProgram(name); }
inline void delete_vertex_array(GLuint name) { glDeleteVertexArrays(1, &name); }
inline void delete_framebuffer(GLuint name) { glDeleteFramebuffers(1, &name); }
inline void delete_renderbuffer(GLuint name) { glDeleteRenderbuffers(1, &name); }
inline void delete_texture(GLuint name) { glDeleteTextures(1, &name); }
inline void delete_query(GLuint name) { glDeleteQueries(1, &name); }

using Buffer = Object<delete_buffer>;
using Program = Object<delete_program>;
using VertexArray = Object<delete_vertex_array>;
using Framebuffer = Object<delete_framebuffer>;
using Renderbuffer = Object<delete_renderbuffer>;
using Texture = Object<delete_texture>;
using Query = Object<delete_query>;

/// A new immutable buffer holding `data` (at least 16 bytes: a zero-sized buffer cannot be bound).
template <class T>
void storage(Buffer& buffer, const std::vector<T>& data, GLbitfield flags = 0) {
    glCreateBuffers(1, buffer.create());
    glNamedBufferStorage(buffer, GLsizeiptr(std::max<std::size_t>(data.size() * sizeof(T), 16)), data.empty() ? nullptr : data.data(),
                         flags);
}

/// A new immutable buffer of `bytes` (at least 16), uninitialised.
inline void storage(Buffer& buffer, std::size_t bytes, GLbitfield flags) {
    glCreateBuffers(1, buffer.create());
    glNamedBufferStorage(buffer, GLsizeiptr(std::max<std::size_t>(bytes, 16)), nullptr, flags);
}

/// Fresh query names for all of `queries` (e.g. the GL_TIMESTAMP pair around a pass).
template <std::size_t N> void generate(std::array<Query, N>& queries) {
    for (Query& q : queries) glGenQueries(1, q.create());
}

/// One owner for a fence sync object (a GLsync pointer rather than a name): deleted when
/// destroyed or reset, move-only.
class Fence {
public:
    Fence() = default;
    Fence(const Fence&) = delete;
    Fence& operator=(const Fence&) = delete;
    Fence(Fence&& other) noexcept : sync_(std::exchange(other.sync_, nullptr)) {}
    Fence& operator=(Fence&& other) noexcept {
        if (this != &other) reset(std::exchange(other.sync_, nullptr));
        return *this;
    }
    ~Fence() { reset(); }
    /// Deletes the fence held (if any) and holds `sync`.
    void reset(GLsync sync = nullptr) {
        if (sync_ && sync_ != sync) glDeleteSync(sync_);
        sync_ = sync;
    }
    operator GLsync() const { return sync_; }  ///< hands the fence to glClientWaitSync; null when none
private:
    GLsync sync_ = nullptr;
};

}  // namespace heartsim::gl
