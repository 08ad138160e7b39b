// The visualisation step: the mapped visual mesh (or the simulation surface), lit, with the
// instruments, into an offscreen framebuffer. renderer.h; docs/runtime.md "Rendering"; shaders:
// shaders/render_shaders.h.
#include "runtime/gl/renderer.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/gl/render_geometry.h"

#include "runtime/gl/gl_context.h"
#include "runtime/gl/gl_object.h"
#include "runtime/gl/gl_program.h"
#include "runtime/gl/shaders/bindings.h"
#include "runtime/gl/shaders/render_shaders.h"

#include "libmodel/coronary_field.h"
#include "libmodel/errors.h"
#include "libmodel/mapping.h"

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <deque>
#include <optional>
#include <vector>

namespace heartsim {

namespace {

namespace sh = gl_shaders;

void check(const char* what) { check_gl_error("renderer", what); }

GLuint compile(GLenum stage, const char* source, const char* name, const char* defines = "") {
    return compile_shader(stage, {defines, source}, std::string("renderer: the ") + name + " shader");
}

GLuint link(std::initializer_list<GLuint> shaders, const char* name, const char* feedback_varying = nullptr) {
    return link_program(shaders, std::string("renderer: the ") + name + " program", "", feedback_varying);
}

GLuint buffer_with(const void* data, std::size_t bytes, GLbitfield flags = 0) {
    GLuint id = 0;
    glCreateBuffers(1, &id);
    glNamedBufferStorage(id, GLsizeiptr(std::max<std::size_t>(bytes, 16)), bytes ? data : nullptr, flags);
    return id;
}

Eigen::Vector3f to_vector(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }



/// The patch's sheet: world positions and shading normals per vertex (a zero normal: flat, the
/// face's), lit by the shared fragment shader.
constexpr const char* patch_vertex_shader = R"(
layout(location = 0) in vec3 position;          // world mm
layout(location = 1) in vec3 normal;            // shading normal; 0: the face's
uniform mat4 view_projection;
out vec3 world_position;
out vec3 shading_normal;
void main() {
    world_position = position;
    shading_normal = normal;
    gl_Position = view_projection * vec4(position, 1.0);
}
)";


}  // namespace


// ---------------------------------------------------------------------------------------------
// Renderer

struct Renderer::State {
    bool visual = false;
    std::size_t particles = 0, vertices = 0, triangles = 0, surface_particles = 0;
    std::size_t memory = 0;
    int width = 0, height = 0;
    RenderOptions options;
    Eigen::AlignedBox3f box;
    Camera camera;
    std::optional<SectionPlane> section;
    bool show_hidden_instruments = false;  ///< the ghost pass (set_show_hidden_instruments)
    bool drawn = false;  ///< a frame has been drawn into the framebuffer since it was made (its depth is surface_point's)

    gl::Program normals_program, mesh_program, instrument_program;
    gl::Buffer records, elements, sheet;
    gl::VertexArray vao;
    gl::Buffer incidence_start, incidence, surface_list, normals;
    gl::Buffer own_positions;  // cpu backend: uploaded per frame
    gl::Buffer sphere_vertices, sphere_elements;
    gl::VertexArray sphere_vao;
    GLsizei sphere_index_count = 0;
    gl::Framebuffer fbo;
    gl::Renderbuffer colour_rb, depth_rb;
    gl::Buffer feedback;  // transform feedback capture buffer (lazily)
    // The coronary arteries drawn on the detailed mesh (RenderOptions::coronaries, the scenario's
    // landmarks): their field as a 3D texture in the rest state.
    gl::Texture coronary_texture;
    CoronaryField coronary;
    // The fibres' ridges (RenderOptions::fibres): turned about the heart's long axis.
    bool fibres = false;
    Eigen::Vector3f heart_axis = Eigen::Vector3f::UnitZ(), heart_base = Eigen::Vector3f::Zero();
    // The repair (set_patch): the patch's closed sheet, its sheet flags (all 0: a closed surface),
    // and the stitches to draw with the instrument program.
    gl::Program patch_program;
    gl::Buffer patch_vertices, patch_elements, patch_sheet_flags;
    gl::VertexArray patch_vao;
    GLsizei patch_index_count = 0;
    std::size_t patch_memory = 0;
    std::optional<DrawnPatch> patch;  ///< as last set; nullopt: none

    std::vector<std::array<float, 3>> rest_particles;  ///< the particles' rest positions (rest frame normals)
    std::vector<float> particle_grown;                  ///< 1 for a particle of a grown wall; empty: none grown
    const SimulationSurface* surface = nullptr;          ///< the scenario's (outlives the renderer's use)
    std::size_t mesh_memory = 0;                        ///< bytes of the records, elements and sheet buffers
    int cap_first = -1;                                 ///< the first cap triangle, or -1

    /// The mapped mesh's vertex records and triangles (the scenario's, or an incision's):
    /// positions and normals at rest (V), triangles in drawing order (caps from `caps_from`).
    void load_visual(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                     const std::vector<std::array<std::int32_t, 3>>& triangles, const VisualMapping& mapping, int caps_from) {
        // Rest interpolated normals (for turning the visual normals as the mesh deforms).
        const std::vector<Eigen::Vector3f> rest_normals = particle_normals(rest_particles, *surface);
        std::vector<VertexRecord> records(positions.size());
        for (std::size_t v = 0; v < records.size(); ++v) {
            const auto& t = surface->triangles[std::size_t(mapping.triangle[v])];
            const auto& l = mapping.barycentric[v];
            VertexRecord& r = records[v];
            Eigen::Vector3f m = Eigen::Vector3f::Zero();
            for (int k = 0; k < 3; ++k) {
                r.particle[k] = t[std::size_t(k)];
                r.lambda[k] = l[std::size_t(k)];
                r.rest_normal[k] = normals.size() == positions.size() ? normals[v][std::size_t(k)] : 0.0f;
                m += l[std::size_t(k)] * rest_normals[std::size_t(t[std::size_t(k)])];
            }
            r.offset = mapping.offset[v];
            std::array<std::int32_t, 8> carriers;
            std::array<float, 8> weights;
            mapping_carriers(mapping, *surface, v, carriers, weights);
            for (std::size_t k = 0; k < 8; ++k) {
                r.carrier[k] = carriers[k];
                r.weight[k] = weights[k];
            }
            const float length = m.norm();
            for (int k = 0; k < 3; ++k) r.rest_frame_normal[k] = length > 0 ? m[k] / length : 0.0f;
            for (int k = 0; k < 3; ++k) r.rest_position[k] = positions[v][std::size_t(k)];
            r.grown = 0.0f;
            if (!particle_grown.empty())
                for (std::size_t k = 0; k < 8; ++k) r.grown += weights[k] * particle_grown[std::size_t(carriers[k])];
        }
        std::vector<std::uint32_t> elements;
        elements.reserve(3 * triangles.size());
        for (const auto& t : triangles)
            for (int k = 0; k < 3; ++k) elements.push_back(std::uint32_t(t[std::size_t(k)]));
        load_records(records, elements, caps_from);
    }

    /// (Re)creates the records, elements and sheet buffers and points the vertex array at them.
    void load_records(const std::vector<VertexRecord>& records, const std::vector<std::uint32_t>& elements, int caps_from) {
        vertices = records.size();
        triangles = elements.size() / 3;
        cap_first = caps_from;
        memory -= mesh_memory;
        this->records = buffer_with(records.data(), records.size() * sizeof(VertexRecord));
        this->elements = buffer_with(elements.data(), elements.size() * 4);
        const std::vector<std::uint32_t> sheet_list = sheet_triangles(elements);
        sheet = buffer_with(sheet_list.data(), sheet_list.size() * 4);
        mesh_memory = records.size() * sizeof(VertexRecord) + elements.size() * 4 + sheet_list.size() * 4;
        memory += mesh_memory;
        if (!vao) {
            glCreateVertexArrays(1, vao.create());
            for (GLuint a = 0; a < 11; ++a) {
                glEnableVertexArrayAttrib(vao, a);
                glVertexArrayAttribBinding(vao, a, 0);
            }
            glVertexArrayAttribIFormat(vao, 0, 3, GL_INT, offsetof(VertexRecord, particle));
            glVertexArrayAttribFormat(vao, 1, 3, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, lambda));
            glVertexArrayAttribFormat(vao, 2, 1, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, offset));
            glVertexArrayAttribFormat(vao, 3, 3, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, rest_normal));
            glVertexArrayAttribFormat(vao, 4, 3, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, rest_frame_normal));
            glVertexArrayAttribIFormat(vao, 5, 4, GL_INT, offsetof(VertexRecord, carrier));
            glVertexArrayAttribIFormat(vao, 6, 4, GL_INT, offsetof(VertexRecord, carrier) + 16);
            glVertexArrayAttribFormat(vao, 7, 4, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, weight));
            glVertexArrayAttribFormat(vao, 8, 4, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, weight) + 16);
            glVertexArrayAttribFormat(vao, 9, 3, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, rest_position));
            glVertexArrayAttribFormat(vao, 10, 1, GL_FLOAT, GL_FALSE, offsetof(VertexRecord, grown));
        }
        glVertexArrayVertexBuffer(vao, 0, this->records, 0, sizeof(VertexRecord));
        glVertexArrayElementBuffer(vao, this->elements);
        feedback.reset();  // sized for the old vertex count
    }

    /// The arteries' field as an RGBA16F 3D texture (r: distance in radii, gba: the direction away),
    /// filtered linearly; beyond it, the field's reach (no artery).
    void load_coronaries(CoronaryField field) {
        coronary = std::move(field);
        if (coronary.empty()) return;
        std::vector<float> texels(4 * coronary.distance.size());
        for (std::size_t n = 0; n < coronary.distance.size(); ++n) {
            texels[4 * n] = coronary.distance[n];
            for (int k = 0; k < 3; ++k) texels[4 * n + 1 + std::size_t(k)] = coronary.away[n][k];
        }
        glCreateTextures(GL_TEXTURE_3D, 1, coronary_texture.create());
        glTextureStorage3D(coronary_texture, 1, GL_RGBA16F, coronary.nx, coronary.ny, coronary.nz);
        glTextureSubImage3D(coronary_texture, 0, 0, 0, 0, coronary.nx, coronary.ny, coronary.nz, GL_RGBA, GL_FLOAT, texels.data());
        glTextureParameteri(coronary_texture, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        glTextureParameteri(coronary_texture, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        for (GLenum wrap : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R})
            glTextureParameteri(coronary_texture, wrap, GL_CLAMP_TO_BORDER);
        const float border[4] = {float(coronary.reach), 0.0f, 0.0f, 0.0f};
        glTextureParameterfv(coronary_texture, GL_TEXTURE_BORDER_COLOR, border);
        memory += texels.size() * 2;  // four 16-bit components a node
        // The texture holds the field now: keep only its grid's placement for the uniforms.
        coronary.distance = {};
        coronary.away = {};
        check("loading the coronary arteries' field");
    }

    /// The mesh program's surface detail: the fibres' and the coronaries' uniforms and texture (unit 0).
    void bind_coronaries() {
        const GLuint p = mesh_program;
        glProgramUniform1i(p, glGetUniformLocation(p, "fibres_on"), fibres ? 1 : 0);
        glProgramUniform3fv(p, glGetUniformLocation(p, "heart_axis"), 1, heart_axis.data());
        glProgramUniform3fv(p, glGetUniformLocation(p, "heart_base"), 1, heart_base.data());
        const bool on = bool(coronary_texture);
        glProgramUniform1i(p, glGetUniformLocation(p, "coronaries_on"), on ? 1 : 0);
        if (!on) return;
        glBindTextureUnit(0, coronary_texture);
        glProgramUniform1i(p, glGetUniformLocation(p, "coronary_field"), 0);
        const Eigen::Vector3f origin = coronary.origin.cast<float>();
        glProgramUniform3fv(p, glGetUniformLocation(p, "field_origin"), 1, origin.data());
        glProgramUniform1f(p, glGetUniformLocation(p, "field_spacing"), float(coronary.spacing_mm));
        glProgramUniform3f(p, glGetUniformLocation(p, "field_nodes"), float(coronary.nx), float(coronary.ny), float(coronary.nz));
        glProgramUniform3f(p, glGetUniformLocation(p, "artery_color"), float(coronary_artery_rgb[0]) / 255.0f,
                           float(coronary_artery_rgb[1]) / 255.0f, float(coronary_artery_rgb[2]) / 255.0f);
        glProgramUniform3f(p, glGetUniformLocation(p, "fat_color"), float(epicardial_fat_rgb[0]) / 255.0f,
                           float(epicardial_fat_rgb[1]) / 255.0f, float(epicardial_fat_rgb[2]) / 255.0f);
    }

    struct Pending { std::array<gl::Query, 3> queries; bool normals = false; };
    std::deque<Pending> pending;
    RenderTimes times;

    void make_framebuffer(int w, int h) {
        width = std::max(w, 1), height = std::max(h, 1);
        drawn = false;
        glCreateRenderbuffers(1, colour_rb.create());
        glNamedRenderbufferStorage(colour_rb, GL_RGBA8, width, height);
        glCreateRenderbuffers(1, depth_rb.create());
        glNamedRenderbufferStorage(depth_rb, GL_DEPTH_COMPONENT24, width, height);
        glCreateFramebuffers(1, fbo.create());
        glNamedFramebufferRenderbuffer(fbo, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, colour_rb);
        glNamedFramebufferRenderbuffer(fbo, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_rb);
        if (glCheckNamedFramebufferStatus(fbo, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
            throw GlUnavailable("renderer: the offscreen framebuffer (RGBA8 + depth 24) is not supported by this driver");
        check("creating the offscreen framebuffer");
    }

    /// The position buffer to read: the gl backend's own, or ours after an upload (cpu).
    GLuint positions_of(Backend& backend) {
        const GLuint id = gl_position_buffer(backend);
        if (id) {
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
            return id;
        }
        return upload(backend.positions());
    }

    /// Uploads positions (N×3, mm) into our own position buffer.
    GLuint upload(const std::vector<std::array<float, 3>>& p) {
        const auto start = std::chrono::steady_clock::now();
        std::vector<float> packed(4 * particles, 0.0f);
        for (std::size_t i = 0; i < std::min(particles, p.size()); ++i)
            for (int c = 0; c < 3; ++c) packed[4 * i + std::size_t(c)] = p[i][std::size_t(c)];
        if (!own_positions) {
            own_positions = buffer_with(nullptr, packed.size() * sizeof(float), GL_DYNAMIC_STORAGE_BIT);
            memory += packed.size() * sizeof(float);
        }
        glNamedBufferSubData(own_positions, 0, GLsizeiptr(packed.size() * sizeof(float)), packed.data());
        times.upload_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        ++times.uploads;
        return own_positions;
    }

    void normals_pass(GLuint positions) {
        if (!visual) return;
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, positions);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::incidence_start, incidence_start);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::incidence, incidence);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::particle_normals, normals);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::surface_particles, surface_list);
        glUseProgram(normals_program);
        glDispatchCompute(GLuint((surface_particles + 63) / 64), 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    }

    void bind_mesh(GLuint positions) {
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, positions);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::particle_normals, normals);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::sheet_triangles, sheet);
        glUseProgram(mesh_program);
        glBindVertexArray(vao);
    }

    /// An ellipsoid (semi-axes `axes` along the columns of `rotation`) with the instrument
    /// program, its vertex array bound and its colour set.
    void ellipsoid(const Eigen::Vector3f& centre, const Eigen::Matrix3f& rotation, const Eigen::Vector3f& axes) {
        const GLuint q = instrument_program;
        Eigen::Matrix4f model = Eigen::Matrix4f::Identity();
        model.topLeftCorner<3, 3>() = rotation * axes.asDiagonal();
        model.topRightCorner<3, 1>() = centre;
        const Eigen::Matrix3f normal_matrix = rotation * axes.cwiseInverse().asDiagonal();
        glProgramUniformMatrix4fv(q, glGetUniformLocation(q, "model"), 1, GL_FALSE, model.data());
        glProgramUniformMatrix3fv(q, glGetUniformLocation(q, "normal_matrix"), 1, GL_FALSE, normal_matrix.data());
        glDrawElements(GL_TRIANGLES, sphere_index_count, GL_UNSIGNED_INT, nullptr);
    }

    /// The patch's sheet and the stitches (suture and knot as ellipsoids), cut by the section
    /// plane as the tissue is; the programs' camera and light uniforms set already.
    void draw_patch() {
        const DrawnPatch& drawn = *patch;
        const Eigen::Vector3f colour = Eigen::Vector3f(float(drawn.rgb[0]), float(drawn.rgb[1]), float(drawn.rgb[2])) / 255.0f;
        const Eigen::Vector3f suture = Eigen::Vector3f(float(suture_rgb[0]), float(suture_rgb[1]), float(suture_rgb[2])) / 255.0f;
        Eigen::Vector4f equation = Eigen::Vector4f::Zero();
        if (section) equation << section->normal, -section->normal.dot(section->point);
        for (GLuint p : {patch_program.id(), instrument_program.id()}) {
            glProgramUniform1i(p, glGetUniformLocation(p, "section_on"), section ? 1 : 0);
            glProgramUniform4fv(p, glGetUniformLocation(p, "section_plane"), 1, equation.data());
            glProgramUniform1f(p, glGetUniformLocation(p, "opacity"), 1.0f);
        }
        const GLuint p = patch_program;
        glProgramUniform3fv(p, glGetUniformLocation(p, "base_color"), 1, colour.data());
        const Eigen::Vector3f cut = 0.72f * colour;  // the sheet's inside where the plane cuts it: flat, darker
        glProgramUniform3fv(p, glGetUniformLocation(p, "cut_color"), 1, cut.data());
        glProgramUniform1f(p, glGetUniformLocation(p, "specular"), 0.25f);
        glProgramUniform1i(p, glGetUniformLocation(p, "cap_first"), -1);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::sheet_triangles, patch_sheet_flags);
        glUseProgram(p);
        glBindVertexArray(patch_vao);
        glDrawElements(GL_TRIANGLES, patch_index_count, GL_UNSIGNED_INT, nullptr);

        // Each stitch: the suture from its patch vertex to its tissue point, 0.44 mm thick (a
        // 4-0 suture is 0.15 to 0.2 mm: drawn thicker to be seen), and its knot on the patch.
        const GLuint q = instrument_program;
        glUseProgram(q);
        glBindVertexArray(sphere_vao);
        glProgramUniform3fv(q, glGetUniformLocation(q, "base_color"), 1, suture.data());
        glProgramUniform1f(q, glGetUniformLocation(q, "specular"), 0.35f);
        glEnable(GL_CULL_FACE);  // convex ellipsoids: their front faces are all that shows
        glCullFace(GL_BACK);
        constexpr float suture_radius = 0.22f, knot_radius = 0.6f;
        for (std::size_t k = 0; k < std::min(drawn.stitch_from.size(), drawn.stitch_to.size()); ++k) {
            const Eigen::Vector3f a = to_vector(drawn.stitch_from[k]), b = to_vector(drawn.stitch_to[k]);
            const float length = (b - a).norm();
            if (length > 1e-4f) {
                const Eigen::Matrix3f along = Eigen::Quaternionf::FromTwoVectors(Eigen::Vector3f::UnitZ(), (b - a) / length).toRotationMatrix();
                ellipsoid(0.5f * (a + b), along, {suture_radius, suture_radius, std::max(0.5f * length, suture_radius)});
            }
            ellipsoid(a, Eigen::Matrix3f::Identity(), Eigen::Vector3f::Constant(knot_radius));
        }
        glDisable(GL_CULL_FACE);
        glProgramUniform1i(q, glGetUniformLocation(q, "section_on"), 0);  // the instruments are drawn whole
    }

    void harvest(bool wait) {
        while (!pending.empty()) {
            Pending& p = pending.front();
            if (!wait) {
                GLint available = 0;
                glGetQueryObjectiv(p.queries[2], GL_QUERY_RESULT_AVAILABLE, &available);
                if (!available) break;
            }
            GLuint64 t[3] = {0, 0, 0};
            for (int k = 0; k < 3; ++k) glGetQueryObjectui64v(p.queries[k], GL_QUERY_RESULT, &t[k]);
            if (p.normals) times.normals_ms += double(t[1] - t[0]) * 1e-6, ++times.normals_calls;
            times.draw_ms += double(t[2] - t[1]) * 1e-6;
            ++times.frames;
            pending.pop_front();
        }
    }
};

Renderer::Renderer(const Scenario& scenario, const RenderOptions& options) : state_(std::make_unique<State>()) {
    State& s = *state_;
    s.options = options;
    const auto& rest = scenario.lattice.particles.rest_position;
    s.particles = rest.size();
    if (!scenario.simulation_surface || scenario.simulation_surface->empty())
        throw InputError("rendering needs the group /simsurface (the simulation surface, for the mapping or to be drawn itself); rebuild "
                         "the scenario with heartprep, or run --headless without --screenshot");
    const SimulationSurface& surface = *scenario.simulation_surface;
    s.visual = scenario.visual && scenario.mapping && !scenario.visual->positions.empty();

    GLint vertex_blocks = 0;
    glGetIntegerv(GL_MAX_VERTEX_SHADER_STORAGE_BLOCKS, &vertex_blocks);
    if (vertex_blocks < 2)
        throw GlUnavailable("renderer: the vertex stage of this OpenGL (" + std::to_string(vertex_blocks) +
                            " shader storage blocks) cannot read the particle buffers; run --headless without --screenshot");

    s.rest_particles = rest;
    s.surface = &surface;
    s.particle_grown = grown_particles(scenario);
    if (s.visual) {
        const VisualMesh& visual = *scenario.visual;
        s.load_visual(visual.positions, visual.normals, visual.triangles, *scenario.mapping, -1);
        for (const auto& p : visual.positions) s.box.extend(to_vector(p));

        const SurfaceIncidence lists = surface_incidence(surface, s.particles);
        const auto &start = lists.start, &surface_list = lists.surface_list;
        const auto& incidence = lists.incidence;
        s.surface_particles = surface_list.size();
        s.incidence_start = buffer_with(start.data(), start.size() * 4);
        s.incidence = buffer_with(incidence.data(), incidence.size() * 16);
        s.surface_list = buffer_with(surface_list.data(), surface_list.size() * 4);
        s.memory += start.size() * 4 + incidence.size() * 16 + surface_list.size() * 4;
        s.normals_program = link({compile(GL_COMPUTE_SHADER, sh::normals_shader, "normals")}, "normals");
        glProgramUniform1ui(s.normals_program, glGetUniformLocation(s.normals_program, "surface_count"), GLuint(s.surface_particles));
    } else {
        // The simulation surface itself: one record per particle, (i, i, i), λ = (1, 0, 0), d = 0
        // (the same shader gives p = x_i exactly); flat shaded, no normals pass.
        const std::vector<VertexRecord> records = particle_records(rest, s.particle_grown);
        std::vector<std::uint32_t> elements;
        for (const auto& t : surface.triangles)
            for (int k = 0; k < 3; ++k) {
                elements.push_back(std::uint32_t(t[std::size_t(k)]));
                s.box.extend(to_vector(rest[std::size_t(t[std::size_t(k)])]));
            }
        s.load_records(records, elements, -1);
    }
    // Normals: written by the pass for surface particles, zero elsewhere (and everywhere without
    // a visual mesh, where m = 0 leaves p unchanged).
    s.normals = buffer_with(std::vector<float>(4 * s.particles, 0.0f).data(), 16 * s.particles);
    s.memory += 16 * s.particles;

    std::vector<float> sphere;
    std::vector<std::uint32_t> sphere_indices;
    unit_sphere(sphere, sphere_indices);
    s.sphere_vertices = buffer_with(sphere.data(), sphere.size() * 4);
    s.sphere_elements = buffer_with(sphere_indices.data(), sphere_indices.size() * 4);
    s.sphere_index_count = GLsizei(sphere_indices.size());
    glCreateVertexArrays(1, s.sphere_vao.create());
    glVertexArrayVertexBuffer(s.sphere_vao, 0, s.sphere_vertices, 0, 12);
    glVertexArrayElementBuffer(s.sphere_vao, s.sphere_elements);
    glEnableVertexArrayAttrib(s.sphere_vao, 0);
    glVertexArrayAttribBinding(s.sphere_vao, 0, 0);
    glVertexArrayAttribFormat(s.sphere_vao, 0, 3, GL_FLOAT, GL_FALSE, 0);

    s.mesh_program = link({compile(GL_VERTEX_SHADER, sh::mesh_vertex_shader, "mapping vertex"),
                           compile(GL_FRAGMENT_SHADER, sh::fragment_shader, "fragment", "#define SURFACE_DETAIL 1\n")},
                          "mesh", "world_position");
    if (s.visual && options.coronaries && scenario.landmarks) s.load_coronaries(coronary_field(coronary_courses(*scenario.landmarks)));
    // The fibres need the left ventricle's long axis and base: the mitral ring.
    if (const Landmark* mitral = scenario.landmarks ? scenario.landmarks->find("mitral_ring") : nullptr;
        s.visual && options.fibres && mitral && mitral->normal.norm() > 0.5) {
        s.fibres = true;
        s.heart_axis = mitral->normal.normalized().cast<float>();
        s.heart_base = mitral->centre.cast<float>();
    }
    s.instrument_program = link({compile(GL_VERTEX_SHADER, sh::instrument_vertex_shader, "instrument vertex"),
                                 compile(GL_FRAGMENT_SHADER, sh::fragment_shader, "fragment")},
                                "instrument");
    s.patch_program = link({compile(GL_VERTEX_SHADER, patch_vertex_shader, "patch vertex"),
                            compile(GL_FRAGMENT_SHADER, sh::fragment_shader, "fragment")},
                           "patch");
    s.make_framebuffer(options.width, options.height);
    s.memory += std::size_t(s.width) * std::size_t(s.height) * 8;
    reset_camera();
    check("setting up the renderer");
}

Renderer::~Renderer() = default;

void Renderer::set_visual(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                          const std::vector<std::array<std::int32_t, 3>>& triangles, const VisualMapping& mapping, std::size_t cap_first) {
    State& s = *state_;
    if (!s.visual) throw InputError("renderer: set_visual needs a scenario with a mapped visual mesh");
    s.load_visual(positions, normals, triangles, mapping, cap_first < triangles.size() ? int(cap_first) : -1);
    check("loading the opened detailed mesh");
}

bool Renderer::draws_visual_mesh() const { return state_->visual; }
std::size_t Renderer::vertex_count() const { return state_->vertices; }
std::size_t Renderer::triangle_count() const { return state_->triangles; }
int Renderer::width() const { return state_->width; }
int Renderer::height() const { return state_->height; }
Camera& Renderer::camera() { return state_->camera; }
Eigen::Vector3f Renderer::model_centre() const { return state_->box.center(); }
void Renderer::set_show_hidden_instruments(bool show) { state_->show_hidden_instruments = show; }

void Renderer::set_patch(const DrawnPatch& patch) {
    State& s = *state_;
    if (patch.triangles.empty()) return clear_patch();
    if (s.patch && *s.patch == patch) return;
    for (const auto& t : patch.triangles)
        for (std::int32_t v : t)
            if (v < 0 || std::size_t(v) >= patch.positions.size())
                throw InputError("renderer: the patch's triangle index " + std::to_string(v) + " is out of range (" +
                                 std::to_string(patch.positions.size()) + " vertices)");
    std::vector<float> vertices;
    std::vector<std::uint32_t> elements;
    patch_sheet(patch, vertices, elements);
    const std::vector<std::uint32_t> flags(elements.size() / 3, 0u);  // a closed sheet: its back faces are its inside
    s.memory -= s.patch_memory;
    s.patch_vertices = buffer_with(vertices.data(), vertices.size() * 4);
    s.patch_elements = buffer_with(elements.data(), elements.size() * 4);
    s.patch_sheet_flags = buffer_with(flags.data(), flags.size() * 4);
    s.patch_memory = (vertices.size() + elements.size() + flags.size()) * 4;
    s.memory += s.patch_memory;
    if (!s.patch_vao) {
        glCreateVertexArrays(1, s.patch_vao.create());
        for (GLuint a = 0; a < 2; ++a) {
            glEnableVertexArrayAttrib(s.patch_vao, a);
            glVertexArrayAttribBinding(s.patch_vao, a, 0);
            glVertexArrayAttribFormat(s.patch_vao, a, 3, GL_FLOAT, GL_FALSE, a * 12);
        }
    }
    glVertexArrayVertexBuffer(s.patch_vao, 0, s.patch_vertices, 0, 24);
    glVertexArrayElementBuffer(s.patch_vao, s.patch_elements);
    s.patch_index_count = GLsizei(elements.size());
    s.patch = patch;
    check("loading the patch");
}

void Renderer::clear_patch() {
    State& s = *state_;
    s.patch.reset();
    s.memory -= s.patch_memory;
    s.patch_memory = 0;
    s.patch_vertices.reset(), s.patch_elements.reset(), s.patch_sheet_flags.reset();
    s.patch_index_count = 0;
}

bool Renderer::draws_patch() const { return state_->patch.has_value(); }

std::optional<Eigen::Vector3f> Renderer::surface_point(double x, double y, int window_width, int window_height) {
    State& s = *state_;
    if (window_width <= 0 || window_height <= 0) return std::nullopt;
    // No frame drawn yet (a click before the window's first frame): its depth is undefined, and
    // nothing is under the cursor.
    if (!s.drawn) return std::nullopt;
    // The window's pixel in the offscreen frame (the frame is stretched to the window).
    const int fx = int(std::floor(x * double(s.width) / double(window_width)));
    const int fy = int(std::floor(y * double(s.height) / double(window_height)));
    if (fx < 0 || fy < 0 || fx >= s.width || fy >= s.height) return std::nullopt;
    float depth = 1.0f;
    glBindFramebuffer(GL_READ_FRAMEBUFFER, s.fbo);
    glReadPixels(fx, s.height - 1 - fy, 1, 1, GL_DEPTH_COMPONENT, GL_FLOAT, &depth);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    if (!(depth < 1.0f)) return std::nullopt;  // the background
    const Eigen::Matrix4f view_projection = s.camera.projection(float(s.width) / float(s.height)) * s.camera.view();
    const Eigen::Vector4f ndc(2.0f * (float(fx) + 0.5f) / float(s.width) - 1.0f, 1.0f - 2.0f * (float(fy) + 0.5f) / float(s.height),
                              2.0f * depth - 1.0f, 1.0f);
    const Eigen::Vector4f world = view_projection.inverse() * ndc;
    if (!(std::abs(world.w()) > 0.0f)) return std::nullopt;
    const Eigen::Vector3f point = world.head<3>() / world.w();
    if (!point.allFinite()) return std::nullopt;
    return point;
}

void Renderer::set_section(const std::optional<SectionPlane>& plane) { state_->section = plane; }
const std::optional<SectionPlane>& Renderer::section() const { return state_->section; }
std::size_t Renderer::memory_bytes() const { return state_->memory; }

void Renderer::reset_camera() {
    state_->camera = fit_camera(state_->box, state_->options.view, float(state_->width) / float(state_->height));
}

void Renderer::resize(int width, int height) {
    if (width == state_->width && height == state_->height) return;
    state_->make_framebuffer(width, height);
}

void Renderer::render(Backend& backend, const std::vector<InstrumentShape>& instruments) {
    draw(state_->positions_of(backend), instruments);
}

void Renderer::render(const std::vector<std::array<float, 3>>& positions, const std::vector<InstrumentShape>& instruments) {
    draw(state_->upload(positions), instruments);
}

void Renderer::draw(unsigned positions, const std::vector<InstrumentShape>& instruments) {
    State& s = *state_;
    s.harvest(false);
    State::Pending timing;
    timing.normals = s.visual;
    gl::generate(timing.queries);

    glQueryCounter(timing.queries[0], GL_TIMESTAMP);
    s.normals_pass(positions);
    glQueryCounter(timing.queries[1], GL_TIMESTAMP);

    glBindFramebuffer(GL_FRAMEBUFFER, s.fbo);
    glViewport(0, 0, s.width, s.height);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);  // thin walls are double-sided sheets; lighting is two-sided
    glClearColor(0.10f, 0.11f, 0.14f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    s.drawn = true;

    const Camera& camera = s.camera;
    const Eigen::Matrix4f view_projection = camera.projection(float(s.width) / float(s.height)) * camera.view();
    const Eigen::Matrix3f basis = camera.orientation.toRotationMatrix();
    const Eigen::Vector3f eye = camera.eye();
    const Eigen::Vector3f key = basis * Eigen::Vector3f(-0.35f, 0.55f, 0.75f).normalized();
    const Eigen::Vector3f fill = basis * Eigen::Vector3f(0.6f, -0.25f, 0.5f).normalized();
    for (GLuint program : {s.mesh_program.id(), s.instrument_program.id(), s.patch_program.id()}) {
        glProgramUniformMatrix4fv(program, glGetUniformLocation(program, "view_projection"), 1, GL_FALSE, view_projection.data());
        glProgramUniform3fv(program, glGetUniformLocation(program, "eye"), 1, eye.data());
        glProgramUniform3fv(program, glGetUniformLocation(program, "key_light"), 1, key.data());
        glProgramUniform3fv(program, glGetUniformLocation(program, "fill_light"), 1, fill.data());
    }
    glProgramUniform3f(s.mesh_program, glGetUniformLocation(s.mesh_program, "base_color"), 0.80f, 0.33f, 0.30f);
    glProgramUniform1i(s.mesh_program, glGetUniformLocation(s.mesh_program, "cap_first"), s.cap_first);
    glProgramUniform1i(s.instrument_program, glGetUniformLocation(s.instrument_program, "cap_first"), -1);
    glProgramUniform3f(s.mesh_program, glGetUniformLocation(s.mesh_program, "cap_color"), float(incision_cap_rgb[0]) / 255.0f,
                       float(incision_cap_rgb[1]) / 255.0f, float(incision_cap_rgb[2]) / 255.0f);
    glProgramUniform1f(s.mesh_program, glGetUniformLocation(s.mesh_program, "specular"), 0.18f);
    // The section view cuts the tissue only; the instruments are drawn whole.
    glProgramUniform1i(s.mesh_program, glGetUniformLocation(s.mesh_program, "section_on"), s.section ? 1 : 0);
    glProgramUniform1i(s.instrument_program, glGetUniformLocation(s.instrument_program, "section_on"), 0);
    if (s.section) {
        const SectionPlane& plane = *s.section;
        const Eigen::Vector4f equation(plane.normal.x(), plane.normal.y(), plane.normal.z(), -plane.normal.dot(plane.point));
        glProgramUniform4fv(s.mesh_program, glGetUniformLocation(s.mesh_program, "section_plane"), 1, equation.data());
        glProgramUniform3f(s.mesh_program, glGetUniformLocation(s.mesh_program, "cut_color"), float(section_cut_rgb[0]) / 255.0f,
                           float(section_cut_rgb[1]) / 255.0f, float(section_cut_rgb[2]) / 255.0f);
        glProgramUniform3f(s.mesh_program, glGetUniformLocation(s.mesh_program, "grown_cut_color"), float(grown_wall_cut_rgb[0]) / 255.0f,
                           float(grown_wall_cut_rgb[1]) / 255.0f, float(grown_wall_cut_rgb[2]) / 255.0f);
    }
    s.bind_mesh(positions);
    s.bind_coronaries();
    glDrawElements(GL_TRIANGLES, GLsizei(3 * s.triangles), GL_UNSIGNED_INT, nullptr);
    if (s.patch) s.draw_patch();

    glProgramUniform1f(s.mesh_program, glGetUniformLocation(s.mesh_program, "opacity"), 1.0f);
    if (!instruments.empty()) {
        const GLuint p = s.instrument_program;
        glUseProgram(p);
        glBindVertexArray(s.sphere_vao);
        glProgramUniform1f(p, glGetUniformLocation(p, "specular"), 0.45f);
        // Instruments are tested against the tissue's depth but do not write it: the depth
        // buffer stays the tissue's alone (surface_point picks it under the cursor). Their back
        // faces are culled instead: an ellipsoid is convex, so its front faces never overlap.
        glDepthMask(GL_FALSE);
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        auto draw_shapes = [&](float opacity) {
            glProgramUniform1f(p, glGetUniformLocation(p, "opacity"), opacity);
            for (const InstrumentShape& shape : instruments) {
                if (shape.kind == InstrumentKind::none) continue;
                if (shape.kind == InstrumentKind::patch && s.patch) continue;  // the laid patch is drawn instead
                if (shape.touching) glProgramUniform3f(p, glGetUniformLocation(p, "base_color"), 0.98f, 0.62f, 0.18f);  // in contact: amber
                else if (shape.kind == InstrumentKind::probe) glProgramUniform3f(p, glGetUniformLocation(p, "base_color"), 0.55f, 0.66f, 0.82f);
                else if (shape.kind == InstrumentKind::scalpel) glProgramUniform3f(p, glGetUniformLocation(p, "base_color"), 0.86f, 0.88f, 0.92f);  // steel
                else glProgramUniform3f(p, glGetUniformLocation(p, "base_color"), 0.88f, 0.72f, 0.25f);  // grabber, retractor: gold
                s.ellipsoid(shape.drawn_centre().cast<float>(), shape.pose.orientation.normalized().toRotationMatrix().cast<float>(),
                            shape.semi_axes.cast<float>());
            }
        };
        draw_shapes(1.0f);
        if (s.show_hidden_instruments) {
            // What of an instrument lies inside or behind the tissue: a faint ghost over it, so a
            // probe pushed into the wall is still seen where it is.
            glDepthFunc(GL_GREATER);
            glEnable(GL_BLEND);
            glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
            draw_shapes(0.38f);
            glDisable(GL_BLEND);
            glDepthFunc(GL_LESS);
        }
        glDisable(GL_CULL_FACE);
        glDepthMask(GL_TRUE);
    }
    if (s.patch && s.patch->leak) {
        // Where the closure check found the leak pass the rim: a ball drawn last, whole (the
        // section does not cut it) and over everything, as it lies under the patch.
        constexpr float radius = 1.2f;
        const GLuint p = s.instrument_program;
        glUseProgram(p);
        glBindVertexArray(s.sphere_vao);
        glProgramUniform1i(p, glGetUniformLocation(p, "section_on"), 0);
        glProgramUniform1f(p, glGetUniformLocation(p, "opacity"), 1.0f);
        glProgramUniform1f(p, glGetUniformLocation(p, "specular"), 0.35f);
        glProgramUniform3f(p, glGetUniformLocation(p, "base_color"), float(leak_rgb[0]) / 255.0f, float(leak_rgb[1]) / 255.0f,
                           float(leak_rgb[2]) / 255.0f);
        glDisable(GL_DEPTH_TEST);
        glEnable(GL_CULL_FACE);  // its front faces only: with no depth test its back faces would show through
        glCullFace(GL_BACK);
        s.ellipsoid(to_vector(*s.patch->leak), Eigen::Matrix3f::Identity(), Eigen::Vector3f::Constant(radius));
        glDisable(GL_CULL_FACE);
        glEnable(GL_DEPTH_TEST);
    }
    glQueryCounter(timing.queries[2], GL_TIMESTAMP);
    glBindVertexArray(0);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    s.pending.push_back(std::move(timing));
    check("rendering a frame");
}

namespace {

/// The framebuffer bound for reading, RGB, rows top to bottom (GL's go bottom to top).
Image read_bound_framebuffer(int width, int height) {
    Image image;
    image.width = width;
    image.height = height;
    image.channels = 3;
    std::vector<std::uint8_t> raw(std::size_t(width) * std::size_t(height) * 3);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, raw.data());
    image.pixels.resize(raw.size());
    const std::size_t stride = std::size_t(width) * 3;
    for (int y = 0; y < height; ++y)
        std::copy_n(raw.begin() + std::ptrdiff_t(std::size_t(height - 1 - y) * stride), stride,
                    image.pixels.begin() + std::ptrdiff_t(std::size_t(y) * stride));
    return image;
}

}  // namespace

Image Renderer::read_pixels() {
    State& s = *state_;
    glBindFramebuffer(GL_READ_FRAMEBUFFER, s.fbo);
    glNamedFramebufferReadBuffer(s.fbo, GL_COLOR_ATTACHMENT0);
    Image image = read_bound_framebuffer(s.width, s.height);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    check("reading the frame back");
    return image;
}

Image read_window_pixels(int width, int height) {
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    glReadBuffer(GL_BACK);
    return read_bound_framebuffer(width, height);
}

void Renderer::present(int window_width, int window_height) {
    State& s = *state_;
    const bool same = window_width == s.width && window_height == s.height;
    glBlitNamedFramebuffer(s.fbo, 0, 0, 0, s.width, s.height, 0, 0, window_width, window_height, GL_COLOR_BUFFER_BIT,
                           same ? GL_NEAREST : GL_LINEAR);
    check("presenting the frame");
}

std::vector<std::array<float, 3>> Renderer::capture_vertices(Backend& backend) {
    State& s = *state_;
    const GLuint positions = s.positions_of(backend);
    s.normals_pass(positions);
    const std::size_t bytes = s.vertices * 12;
    if (!s.feedback) s.feedback = buffer_with(nullptr, bytes, 0);
    s.bind_mesh(positions);
    glBindFramebuffer(GL_FRAMEBUFFER, s.fbo);  // a complete framebuffer even with the rasteriser off (surfaceless EGL has none)
    glBindBufferBase(GL_TRANSFORM_FEEDBACK_BUFFER, sh::captured_vertices, s.feedback);
    glEnable(GL_RASTERIZER_DISCARD);
    glBeginTransformFeedback(GL_POINTS);
    glDrawArrays(GL_POINTS, 0, GLsizei(s.vertices));
    glEndTransformFeedback();
    glDisable(GL_RASTERIZER_DISCARD);
    glBindBufferBase(GL_TRANSFORM_FEEDBACK_BUFFER, sh::captured_vertices, 0);
    glBindVertexArray(0);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    std::vector<std::array<float, 3>> out(s.vertices);
    glGetNamedBufferSubData(s.feedback, 0, GLsizeiptr(bytes), out.data());
    check("capturing the mapped vertices (transform feedback)");
    return out;
}

std::vector<std::array<float, 3>> Renderer::read_particle_normals() {
    State& s = *state_;
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    std::vector<float> raw(4 * s.particles);
    glGetNamedBufferSubData(s.normals, 0, GLsizeiptr(raw.size() * 4), raw.data());
    check("reading the particle normals");
    std::vector<std::array<float, 3>> out(s.particles);
    for (std::size_t i = 0; i < s.particles; ++i) out[i] = {raw[4 * i], raw[4 * i + 1], raw[4 * i + 2]};
    return out;
}

RenderTimes Renderer::times(bool wait) {
    state_->harvest(wait);
    return state_->times;
}

}  // namespace heartsim
