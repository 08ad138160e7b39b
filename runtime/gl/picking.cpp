// The picking buffer (Sørensen & Mosegaard's §1.2.2) and the direct surface search: docs/runtime.md,
// "Probe contacts: picking buffer and direct search". Shaders: shaders/picking_shaders.h.
#include "runtime/gl/picking.h"
#include "runtime/gl/gl_context.h"
#include "runtime/gl/gl_object.h"
#include "runtime/gl/gl_program.h"
#include "runtime/gl/shaders/bindings.h"
#include "runtime/gl/shaders/picking_shaders.h"

#include "libmodel/errors.h"

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <new>
#include <set>

namespace heartsim {



namespace {

namespace sh = gl_shaders;
constexpr int hands = 2;

GLuint compile(GLenum type, const std::vector<const char*>& sources, const char* name) {
    return compile_shader(type, sources, std::string("picking: the ") + name + " shader", "run with --contact direct");
}

GLuint link(const std::vector<GLuint>& shaders, const char* name) {
    return link_program(shaders, std::string("picking: the ") + name + " program", "run with --contact direct");
}

double default_tolerance(double spacing) { return 1e-3 * spacing; }

}  // namespace

struct PickingPass::Gl {
    gl::Program render_program, collect_program, search_program;
    gl::VertexArray vao;
    gl::Buffer triangles, surface, samples, mark, picked;
    struct Hand {
        gl::Framebuffer framebuffer;
        gl::Texture index, distance, depth;
        int resolution = 0;
        bool valid = false;
        int age = 0;                        // force requests since the buffer was rendered
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        Eigen::Matrix3d to_tool = Eigen::Matrix3d::Identity();
        double half_width = 1.0;
    };
    std::array<Hand, hands> hand;

};

std::size_t estimate_picking_memory_bytes(const Scenario& scenario, const ContactSettings& settings) {
    const std::size_t n = scenario.lattice.particles.size();
    const std::size_t t = scenario.simulation_surface ? scenario.simulation_surface->size() : 0;
    const std::size_t g = std::size_t(std::max(settings.sampling_grid, 2));
    const std::size_t r = std::size_t(std::max(settings.picking_resolution, 8));
    return t * 12 + n * 4 /* surface list, at most */ + (g * g + 4 * g) * 16 + n * 4 /* mark */ + hands * n * 4 /* lists */ +
           hands * r * r * 12 /* index, distance, depth */;
}

PickingPass::PickingPass(const std::optional<SimulationSurface>& simulation_surface, std::size_t particles, double spacing_mm,
                         const ContactSettings& settings)
    : gl_(std::make_unique<Gl>()) {
    if (!simulation_surface || simulation_surface->empty())
        throw InputError("--contact picking|search needs the scenario's /simsurface group (heartprep build writes it); "
                         "run with --contact direct");
    n_ = particles;
    spacing_ = spacing_mm > 0 ? spacing_mm : 1.0;
    const auto& triangles = simulation_surface->triangles;
    triangle_count_ = triangles.size();
    std::set<std::int32_t> vertices;
    std::vector<std::int32_t> flat;
    flat.reserve(3 * triangles.size());
    for (const auto& t : triangles)
        for (std::int32_t v : t) flat.push_back(v), vertices.insert(v);
    const std::vector<std::int32_t> surface(vertices.begin(), vertices.end());
    surface_count_ = surface.size();

    gl_->render_program = link({compile(GL_VERTEX_SHADER, {sh::picking_vertex_shader}, "picking vertex"),
                                compile(GL_FRAGMENT_SHADER, {sh::picking_fragment_shader}, "picking fragment")},
                               "picking render");
    gl_->collect_program = link({compile(GL_COMPUTE_SHADER, {sh::contact_common, sh::collect_body}, "picking collect")}, "picking collect");
    gl_->search_program = link({compile(GL_COMPUTE_SHADER, {sh::contact_common, sh::search_body}, "direct search")}, "direct search");
    for (GLuint p : {gl_->collect_program.id(), gl_->search_program.id()})
        glProgramUniform1ui(p, glGetUniformLocation(p, "particle_count"), GLuint(n_));
    glProgramUniform1ui(gl_->search_program, glGetUniformLocation(gl_->search_program, "surface_count"), GLuint(surface_count_));
    glCreateVertexArrays(1, gl_->vao.create());
    auto make = [](gl::Buffer& buffer, std::size_t bytes, const void* data, GLbitfield flags) {
        glCreateBuffers(1, buffer.create());
        glNamedBufferStorage(buffer, GLsizeiptr(std::max<std::size_t>(bytes, 16)), data, flags);
    };
    make(gl_->triangles, flat.size() * 4, flat.data(), 0);
    make(gl_->surface, surface.size() * 4, surface.data(), 0);
    const std::vector<std::uint32_t> zeros(n_, 0u);
    make(gl_->mark, n_ * 4, zeros.data(), 0);
    make(gl_->picked, std::size_t(hands) * n_ * 4, nullptr, 0);
    set_settings(settings);
    const GLenum error = glGetError();
    if (error == GL_OUT_OF_MEMORY) throw std::bad_alloc();  // the driver's memory: heartsim says "out of memory"
    if (error != GL_NO_ERROR) throw GlUnavailable("picking: OpenGL error " + std::to_string(error) + " while setting up");
}

PickingPass::~PickingPass() = default;

unsigned PickingPass::picked_buffer() const { return gl_->picked; }

void PickingPass::set_settings(const ContactSettings& settings) {
    if (settings.picking_refresh < 1) throw InputError("--picking-refresh must be at least 1");
    if (settings.picking_resolution < 8 || settings.picking_resolution > 4096)
        throw InputError("the picking resolution must be within [8, 4096] pixels");
    if (settings.sampling_grid < 2 || settings.sampling_grid > 1024) throw InputError("the sampling grid must be within [2, 1024]");
    if (!(settings.tolerance_mm >= 0) || !std::isfinite(settings.tolerance_mm)) throw InputError("the contact tolerance must be ≥ 0 mm");
    const bool regrid = !gl_->samples || settings.sampling_grid != settings_.sampling_grid;
    settings_ = settings;
    tolerance_ = settings.tolerance_mm > 0 ? settings.tolerance_mm : default_tolerance(spacing_);
    if (regrid) {
        // Sampling points on the unit sphere's front half (z ≥ 0, towards the tip), as a regular
        // grid in their projection along the axis (so they cover the picking buffer's view of
        // the probe evenly), plus a ring on the rim; scaled by the semi-axes in the shader.
        const int g = settings.sampling_grid;
        std::vector<std::array<float, 4>> unit;
        for (int a = 0; a < g; ++a)
            for (int b = 0; b < g; ++b) {
                const double u = -1.0 + (2.0 * a + 1.0) / g, v = -1.0 + (2.0 * b + 1.0) / g;
                const double r2 = u * u + v * v;
                if (r2 > 1.0) continue;
                unit.push_back({float(u), float(v), float(std::sqrt(1.0 - r2)), 0.0f});
            }
        for (int k = 0; k < 4 * g; ++k) {
            const double phi = 2.0 * M_PI * (k + 0.5) / (4.0 * g);
            unit.push_back({float(std::cos(phi)), float(std::sin(phi)), 0.0f, 0.0f});
        }
        sample_count_ = unit.size();
        glCreateBuffers(1, gl_->samples.create());
        glNamedBufferStorage(gl_->samples, GLsizeiptr(unit.size() * 16), unit.data(), 0);
        glProgramUniform1ui(gl_->collect_program, glGetUniformLocation(gl_->collect_program, "sample_count"), GLuint(sample_count_));
    }
    for (int h = 0; h < hands; ++h) invalidate(h);
    memory_bytes_ = triangle_count_ * 12 + surface_count_ * 4 + sample_count_ * 16 + n_ * 4 + hands * n_ * 4 +
                    std::size_t(hands) * std::size_t(settings_.picking_resolution) * std::size_t(settings_.picking_resolution) * 12;
}

void PickingPass::invalidate(int hand) { gl_->hand[std::size_t(hand)].valid = false; }

void PickingPass::render(int hand, const Instrument& instrument, const InstrumentPose& pose, unsigned positions_buffer) {
    Gl::Hand& h = gl_->hand[std::size_t(hand)];
    const int resolution = settings_.picking_resolution;
    if (h.resolution != resolution) {
        h = Gl::Hand{};  // the old targets delete themselves
        h.resolution = resolution;
        glCreateTextures(GL_TEXTURE_2D, 1, h.index.create());
        glTextureStorage2D(h.index, 1, GL_R32I, resolution, resolution);
        glCreateTextures(GL_TEXTURE_2D, 1, h.distance.create());
        glTextureStorage2D(h.distance, 1, GL_R32F, resolution, resolution);
        glCreateTextures(GL_TEXTURE_2D, 1, h.depth.create());
        glTextureStorage2D(h.depth, 1, GL_DEPTH_COMPONENT32F, resolution, resolution);
        for (GLuint t : {h.index.id(), h.distance.id()}) {
            glTextureParameteri(t, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
            glTextureParameteri(t, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        }
        glCreateFramebuffers(1, h.framebuffer.create());
        glNamedFramebufferTexture(h.framebuffer, GL_COLOR_ATTACHMENT0, h.index, 0);
        glNamedFramebufferTexture(h.framebuffer, GL_COLOR_ATTACHMENT1, h.distance, 0);
        glNamedFramebufferTexture(h.framebuffer, GL_DEPTH_ATTACHMENT, h.depth, 0);
        const GLenum draw[2] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
        glNamedFramebufferDrawBuffers(h.framebuffer, 2, draw);
        if (glCheckNamedFramebufferStatus(h.framebuffer, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
            throw GlUnavailable("picking: the R32I + R32F + depth picking buffer is not renderable on this driver; run with --contact direct");
    }
    // The camera: orthographic along the tool's +z, from the base (z = −c) to 3c + spacing.
    const Eigen::Vector3d& semi = instrument.semi_axes;
    h.centre = pose.position;
    h.to_tool = pose.orientation.toRotationMatrix().transpose();
    h.half_width = 1.02 * std::max(semi.x(), semi.y()) + tolerance_;
    const double near_z = -semi.z(), far_z = 3.0 * semi.z() + spacing_;

    // Keep the caller's render state (the visualisation shares the context).
    GLint previous_framebuffer = 0, viewport[4] = {0, 0, 0, 0}, previous_program = 0, previous_vao = 0;
    glGetIntegerv(GL_DRAW_FRAMEBUFFER_BINDING, &previous_framebuffer);
    glGetIntegerv(GL_VIEWPORT, viewport);
    glGetIntegerv(GL_CURRENT_PROGRAM, &previous_program);
    glGetIntegerv(GL_VERTEX_ARRAY_BINDING, &previous_vao);
    const GLboolean depth_test = glIsEnabled(GL_DEPTH_TEST), cull = glIsEnabled(GL_CULL_FACE), blend = glIsEnabled(GL_BLEND),
                    scissor = glIsEnabled(GL_SCISSOR_TEST);
    GLint depth_func = GL_LESS;
    glGetIntegerv(GL_DEPTH_FUNC, &depth_func);
    GLboolean depth_mask = GL_TRUE;
    glGetBooleanv(GL_DEPTH_WRITEMASK, &depth_mask);

    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, h.framebuffer);
    glViewport(0, 0, resolution, resolution);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
    glDisable(GL_CULL_FACE);
    glDisable(GL_BLEND);
    glDisable(GL_SCISSOR_TEST);
    const GLint no_particle = -1;
    const GLfloat far_distance = std::numeric_limits<float>::infinity(), far_depth = 1.0f;
    glClearNamedFramebufferiv(h.framebuffer, GL_COLOR, 0, &no_particle);
    glClearNamedFramebufferfv(h.framebuffer, GL_COLOR, 1, &far_distance);
    glClearNamedFramebufferfv(h.framebuffer, GL_DEPTH, 0, &far_depth);

    const GLuint p = gl_->render_program;
    const Eigen::Matrix3f to_tool = h.to_tool.cast<float>();
    glProgramUniform3f(p, glGetUniformLocation(p, "centre"), float(h.centre.x()), float(h.centre.y()), float(h.centre.z()));
    glProgramUniformMatrix3fv(p, glGetUniformLocation(p, "to_tool"), 1, GL_FALSE, to_tool.data());
    glProgramUniform4f(p, glGetUniformLocation(p, "window"), float(h.half_width), float(near_z), float(far_z), 0.0f);
    glProgramUniform3f(p, glGetUniformLocation(p, "semi_axes"), float(semi.x()), float(semi.y()), float(semi.z()));
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, positions_buffer);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picking_triangles, gl_->triangles);
    glUseProgram(p);
    glBindVertexArray(gl_->vao);
    glDrawArrays(GL_TRIANGLES, 0, GLsizei(3 * triangle_count_));

    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, GLuint(previous_framebuffer));
    glViewport(viewport[0], viewport[1], viewport[2], viewport[3]);
    glUseProgram(GLuint(previous_program));
    glBindVertexArray(GLuint(previous_vao));
    (depth_test ? glEnable : glDisable)(GL_DEPTH_TEST);
    (cull ? glEnable : glDisable)(GL_CULL_FACE);
    (blend ? glEnable : glDisable)(GL_BLEND);
    (scissor ? glEnable : glDisable)(GL_SCISSOR_TEST);
    glDepthFunc(GLenum(depth_func));
    glDepthMask(depth_mask);
    h.valid = true;
    h.age = 0;
    ++renders_;
}

void PickingPass::collect(int hand, const Instrument& instrument, const InstrumentPose& pose, unsigned positions_buffer,
                          unsigned counters_buffer, unsigned skin_buffer) {
    const GLuint zero = 0;
    glClearNamedBufferSubData(counters_buffer, GL_R32UI, GLintptr((sh::picked0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    ++epoch_;
    if (epoch_ == 0) {  // wrapped: clear the marks so that no old epoch matches
        glClearNamedBufferData(gl_->mark, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        epoch_ = 1;
    }
    const bool picking = settings_.mode == ContactMode::picking;
    Gl::Hand& h = gl_->hand[std::size_t(hand)];
    if (picking && (!h.valid || h.age >= settings_.picking_refresh)) render(hand, instrument, pose, positions_buffer);
    ++h.age;

    const GLuint p = picking ? gl_->collect_program : gl_->search_program;
    const Eigen::Matrix3d rotation = pose.orientation.toRotationMatrix();
    glProgramUniform1i(p, glGetUniformLocation(p, "hand"), hand);
    glProgramUniform1ui(p, glGetUniformLocation(p, "epoch"), epoch_);
    glProgramUniform3dv(p, glGetUniformLocation(p, "centre"), 1, pose.position.data());
    glProgramUniformMatrix3dv(p, glGetUniformLocation(p, "rotation"), 1, GL_FALSE, rotation.data());
    glProgramUniform3dv(p, glGetUniformLocation(p, "semi_axes"), 1, instrument.semi_axes.data());
    glProgramUniform1d(p, glGetUniformLocation(p, "tolerance"), tolerance_);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, positions_buffer);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::counters, counters_buffer);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picking_marks, gl_->mark);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picked, gl_->picked);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::skin, skin_buffer);
    std::size_t invocations = surface_count_;
    if (picking) {
        glProgramUniform1i(p, glGetUniformLocation(p, "resolution"), h.resolution);
        glProgramUniform3dv(p, glGetUniformLocation(p, "render_centre"), 1, h.centre.data());
        glProgramUniformMatrix3dv(p, glGetUniformLocation(p, "render_to_tool"), 1, GL_FALSE, h.to_tool.data());
        glProgramUniform1d(p, glGetUniformLocation(p, "render_half_width"), h.half_width);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picking_samples, gl_->samples);
        glBindTextureUnit(sh::picking_index_image, h.index);
        invocations = sample_count_;
    } else {
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picking_surface, gl_->surface);
    }
    GLint previous_program = 0;
    glGetIntegerv(GL_CURRENT_PROGRAM, &previous_program);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT | GL_FRAMEBUFFER_BARRIER_BIT);
    glUseProgram(p);
    glDispatchCompute(GLuint((invocations + 63) / 64), 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    glUseProgram(GLuint(previous_program));
    if (picking) glBindTextureUnit(sh::picking_index_image, 0);
}

}  // namespace heartsim
