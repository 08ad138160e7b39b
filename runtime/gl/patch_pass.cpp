#include "runtime/gl/patch_pass.h"

#include "runtime/gl/gl_context.h"
#include "runtime/gl/gl_object.h"
#include "runtime/gl/gl_program.h"
#include "runtime/gl/shaders/bindings.h"
#include "runtime/gl/shaders/patch_shaders.h"
#include "runtime/gl/shaders/solver_shaders.h"

#include "libmodel/errors.h"

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace heartsim {

namespace {

namespace sh = gl_shaders;
constexpr int ring_slots = 4;               // hand-force readbacks in flight
constexpr GLsizeiptr ring_stride = 64;      // 6 doubles a slot

/// Appends `values` to `into` and returns where they start.
template <class T> GLuint append(std::vector<T>& into, const std::vector<T>& values) {
    const GLuint at = GLuint(into.size());
    into.insert(into.end(), values.begin(), values.end());
    return at;
}
std::vector<double> flat(const std::vector<Eigen::Vector3d>& values) {
    std::vector<double> out;
    out.reserve(3 * values.size());
    for (const auto& v : values) out.insert(out.end(), {v.x(), v.y(), v.z()});
    return out;
}
template <class T, std::size_t N> std::vector<T> flat(const std::vector<std::array<T, N>>& values) {
    std::vector<T> out;
    out.reserve(N * values.size());
    for (const auto& v : values) out.insert(out.end(), v.begin(), v.end());
    return out;
}

class GlPatchPass final : public PatchStepper {
public:
    GlPatchPass(std::function<unsigned()> positions, unsigned loads, std::function<void(bool)> loaded, std::size_t n_particles)
        : positions_(std::move(positions)), loads_(loads), loaded_(std::move(loaded)), n_particles_(n_particles) {
        const std::string what = "gl backend: the patch's compute shader";
        program_ = link_program({compile_shader(GL_COMPUTE_SHADER, {sh::common, sh::geometry, sh::patch_step}, what)}, what);
        const GLbitfield flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
        gl::storage(ring_, std::size_t(ring_slots) * ring_stride, flags);
        ring_map_ = glMapNamedBufferRange(ring_.id(), 0, ring_slots * ring_stride, flags);
        if (!ring_map_) throw GlUnavailable("gl backend: cannot map the patch's force readback buffer persistently");
        check("setting up the patch's pass");
    }
    ~GlPatchPass() override {
        if (ring_.id()) glUnmapNamedBuffer(ring_.id());
        if (snapshot_.id()) glUnmapNamedBuffer(snapshot_.id());
    }

    bool takes(const PatchModel& patch) const override {
        return patch.laid() && patch.positions().size() <= std::size_t(sh::patch_pass_max_vertices);
    }

    void load(const PatchPassInput& in) override {
        const std::size_t n = in.x.size();
        if (n == 0 || n > std::size_t(sh::patch_pass_max_vertices))
            throw InputError("gl backend: the patch's pass takes 1 to " + std::to_string(sh::patch_pass_max_vertices) + " vertices, not " +
                             std::to_string(n));
        for (std::int32_t p : in.particles)
            if (p < 0 || std::size_t(p) >= n_particles_) throw InputError("gl backend: a patch's particle is out of range");
        unload_loads();
        input_ = in;
        n_ = n;
        slots_ = in.particles.size();
        surface_ = in.surface_base.size();
        stitches_ = in.stitch_vertex.size();
        distances_ = in.distance_vertices.size();
        colours_ = in.colour_first.empty() ? 0 : in.colour_first.size() - 1;
        // The constants: doubles, read only.
        std::vector<double> k;
        at_["k_inverse_mass"] = append(k, in.inverse_mass);
        at_["k_dist"] = append(k, flat(in.distance_rest_compliance));
        at_["k_surface_base"] = append(k, flat(in.surface_base));
        at_["k_surface_weight"] = append(k, in.surface_weight);
        at_["k_surface_w"] = append(k, in.surface_inverse_mass);
        at_["k_stitch_tied"] = append(k, in.stitch_tied_ms);
        at_["k_stitch_start"] = append(k, in.stitch_start_length);
        at_["k_stitch_w"] = append(k, in.stitch_inverse_mass);
        at_["k_stitch_base"] = append(k, flat(in.stitch_base));
        at_["k_stitch_weight"] = append(k, in.stitch_weight);
        at_["k_slot_vertex_weight"] = append(k, in.slot_vertex_weight);
        at_["k_slot_stitch_weight"] = append(k, in.slot_stitch_weight);
        gl::storage(constants_, k);
        // The state and scratch: doubles, read and written.
        std::size_t size = 0;
        auto reserve = [&](const char* name, std::size_t count) {
            at_[name] = GLuint(size);
            size += count;
        };
        reserve("s_x", 3 * n);
        reserve("s_v", 3 * n);
        reserve("s_stepped", 3 * slots_ + 1);  // and whether the pass has stepped
        reserve("s_slot_x", 3 * slots_);
        reserve("s_sx", 3 * surface_);
        reserve("s_previous", 3 * n);
        reserve("s_bary", 3 * n);
        reserve("s_normal", 3 * n);
        reserve("s_point", 3 * n);
        reserve("s_under_w", n);
        reserve("s_offset", n);
        reserve("s_pushed", 3 * n);
        reserve("s_carried", 3 * n);
        reserve("s_lambda", distances_);
        reserve("s_anchor", 3 * stitches_);
        reserve("s_target", stitches_);
        reserve("s_stitch_lambda", stitches_);
        reserve("s_stitch_dir", 3 * stitches_);
        reserve("s_anchor_offset", 3 * stitches_);
        reserve("s_obstacle_push", 6 * n);
        reserve("s_force", 3 * n);
        reserve("s_surface_force", 3 * surface_);
        reserve("s_out", std::size_t(sh::patch_out_fixed) + 3 * stitches_);
        reserve("s_under", n);
        reserve("s_searched_at", 3 * n);
        reserve("s_searched_shift", 3 * n);
        reserve("s_searched_travel", n);
        reserve("s_searched_valid", n);
        reserve("s_global", 7);  // the tissue's shift (3) and deformation, whether slot_x, grid and asleep hold positions
        reserve("s_grid", 3 * slots_);
        reserve("s_asleep", 3 * slots_);
        std::vector<double> state(size, 0.0);
        const std::vector<double> x = flat(in.x), v = flat(in.v);
        std::copy(x.begin(), x.end(), state.begin() + at_["s_x"]);
        std::copy(v.begin(), v.end(), state.begin() + at_["s_v"]);
        if (in.stepped_slot_x.size() == slots_ && slots_ > 0) {
            const std::vector<double> stepped = flat(in.stepped_slot_x);
            std::copy(stepped.begin(), stepped.end(), state.begin() + at_["s_stepped"]);
            state[at_["s_stepped"] + 3 * slots_] = 1.0;
        }
        auto place = [&](const char* name, const std::vector<Eigen::Vector3d>& values) {
            const std::vector<double> d = flat(values);
            std::copy(d.begin(), d.end(), state.begin() + at_[name]);
        };
        if (in.kept.under.size() != n || in.kept.searched_at.size() != n || in.kept.searched_shift.size() != n || in.kept.searched_travel.size() != n)
            throw InputError("gl backend: the patch's kept state does not match its vertices");
        for (std::size_t i = 0; i < n; ++i) {
            state[at_["s_under"] + i] = double(in.kept.under[i]);
            const bool looked = std::isfinite(in.kept.searched_travel[i]);
            state[at_["s_searched_travel"] + i] = looked ? in.kept.searched_travel[i] : 0.0;
            state[at_["s_searched_valid"] + i] = looked ? 1.0 : 0.0;
        }
        place("s_searched_at", in.kept.searched_at);
        place("s_searched_shift", in.kept.searched_shift);
        const GLuint global = at_["s_global"];
        for (int c = 0; c < 3; ++c) state[global + GLuint(c)] = in.kept.tissue_shift[c];
        state[global + 3] = in.kept.tissue_travel;
        auto slots_of = [&](const char* name, const std::vector<Eigen::Vector3d>& values, GLuint flag) {
            if (values.size() != slots_ || slots_ == 0) return;
            place(name, values);
            state[global + flag] = 1.0;
        };
        slots_of("s_slot_x", in.kept.slot_x, 4);
        slots_of("s_grid", in.kept.grid_slot_x, 5);
        slots_of("s_asleep", in.kept.asleep_slot_x, 6);
        gl::storage(state_, state, GL_DYNAMIC_STORAGE_BIT);
        state_size_ = size;
        upload_ints(in);
        // The uniforms that stay.
        const GLuint p = program_.id();
        for (const auto& [name, offset] : at_) glProgramUniform1ui(p, glGetUniformLocation(p, name.c_str()), offset);
        glProgramUniform1ui(p, glGetUniformLocation(p, "vertex_count"), GLuint(n));
        glProgramUniform1ui(p, glGetUniformLocation(p, "colour_count"), GLuint(colours_));
        glProgramUniform1ui(p, glGetUniformLocation(p, "slot_count"), GLuint(slots_));
        glProgramUniform1ui(p, glGetUniformLocation(p, "surface_count"), GLuint(surface_));
        glProgramUniform1ui(p, glGetUniformLocation(p, "stitch_count"), GLuint(stitches_));
        glProgramUniform1ui(p, glGetUniformLocation(p, "stitch_colour_count"),
                            GLuint(in.stitch_colour_first.empty() ? 0 : in.stitch_colour_first.size() - 1));
        glProgramUniform1i(p, glGetUniformLocation(p, "iterations"), in.iterations);
        glProgramUniform1d(p, glGetUniformLocation(p, "thickness"), in.thickness_mm);
        glProgramUniform1d(p, glGetUniformLocation(p, "friction"), in.friction);
        glProgramUniform1d(p, glGetUniformLocation(p, "tie_ms"), in.tie_ms);
        glProgramUniform1d(p, glGetUniformLocation(p, "stitch_stiffness"), in.stitch_stiffness);
        glProgramUniform3dv(p, glGetUniformLocation(p, "acceleration"), 1, in.acceleration.data());
        glProgramUniform3dv(p, glGetUniformLocation(p, "facing"), 1, in.facing.data());
        glProgramUniform1d(p, glGetUniformLocation(p, "search_again"), in.search_again_mm);
        glProgramUniform1d(p, glGetUniformLocation(p, "grid_margin"), in.grid_margin_mm);
        glProgramUniform1d(p, glGetUniformLocation(p, "largest_weight_sum"), in.largest_weight_sum);
        for (auto& f : fences_) f.reset();
        snapshot_fence_.reset();
        sequence_ = 0;
        latest_.reset();
        loaded_here_ = true;
        check("loading the patch");
    }

    void load_candidates(const PatchPassInput& in) override {
        if (!loaded_here_) throw InputError("gl backend: no patch is loaded to take candidates");
        if (in.candidate_first.size() != n_ + 1 || in.over_first.size() != surface_ + 1)
            throw InputError("gl backend: the patch's candidates do not match the loaded patch");
        input_.candidate_first = in.candidate_first;
        input_.candidate = in.candidate;
        input_.over_first = in.over_first;
        input_.over = in.over;
        upload_ints(input_);
        check("loading the patch's candidates");
    }

    void step(const PatchPassStep& step) override {
        if (!loaded_here_) throw InputError("gl backend: no patch is loaded to step");
        if (!(step.dt_ms > 0) || !std::isfinite(step.dt_ms) || !(step.mass_scale > 0) || step.obstacles.size() > 2)
            throw InputError("gl backend: a patch step needs a positive step, a positive mass scale and at most two obstacles");
        const GLuint p = program_.id();
        glProgramUniform1d(p, glGetUniformLocation(p, "dt"), step.dt_ms);
        glProgramUniform1d(p, glGetUniformLocation(p, "time_ms"), step.time_ms);
        glProgramUniform1d(p, glGetUniformLocation(p, "mass_scale"), step.mass_scale);
        glProgramUniform1d(p, glGetUniformLocation(p, "keep"), std::max(0.0, 1.0 - input_.damping_per_ms * step.dt_ms));
        glProgramUniform1i(p, glGetUniformLocation(p, "obstacle_count"), int(step.obstacles.size()));
        for (std::size_t o = 0; o < step.obstacles.size(); ++o) {
            const PatchObstacle& obstacle = step.obstacles[o];
            static constexpr const char* centre[2] = {"obstacle_centre[0]", "obstacle_centre[1]"};
            static constexpr const char* rotation_name[2] = {"obstacle_rotation[0]", "obstacle_rotation[1]"};
            static constexpr const char* axes_name[2] = {"obstacle_axes[0]", "obstacle_axes[1]"};
            const Eigen::Matrix3d rotation = obstacle.pose.orientation.normalized().toRotationMatrix();
            const Eigen::Vector3d axes = obstacle.semi_axes + Eigen::Vector3d::Constant(0.5 * input_.thickness_mm);
            glProgramUniform3dv(p, glGetUniformLocation(p, centre[o]), 1, obstacle.pose.position.data());
            glProgramUniformMatrix3dv(p, glGetUniformLocation(p, rotation_name[o]), 1, GL_FALSE, rotation.data());
            glProgramUniform3dv(p, glGetUniformLocation(p, axes_name[o]), 1, axes.data());
            static constexpr const char* reach_name[2] = {"obstacle_reach[0]", "obstacle_reach[1]"};
            glProgramUniform1d(p, glGetUniformLocation(p, reach_name[o]), obstacle.semi_axes.maxCoeff() + 0.5 * input_.thickness_mm + input_.edge_mm);
        }
        glProgramUniform1iv(p, glGetUniformLocation(p, "hand_output"), 2, step.hand_output.data());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, positions_());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load, loads_);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::patch_ints, ints_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::patch_constants, constants_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::patch_state, state_.id());
        harvest(false);
        std::array<gl::Query, 2> timing;
        gl::generate(timing);
        glQueryCounter(timing[0], GL_TIMESTAMP);
        glUseProgram(p);
        glDispatchCompute(1, 1, 1);
        glQueryCounter(timing[1], GL_TIMESTAMP);
        timings_.push_back(std::move(timing));
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        // The hands' forces into the ring, fenced (read by hand_forces without waiting).
        const int slot = int(sequence_ % ring_slots);
        if (fences_[slot]) {  // the oldest readback still in flight: rare, four outstanding
            glClientWaitSync(fences_[slot], GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(10'000'000'000ull));
            fences_[slot].reset();
        }
        glCopyNamedBufferSubData(state_.id(), ring_.id(), GLintptr(at_["s_out"] * 8), GLintptr(slot) * ring_stride, 48);
        glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
        fences_[slot].reset(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0));
        sequence_of_[slot] = sequence_++;
        if (!loads_on_) loaded_(loads_on_ = true);
        check("stepping the patch");
    }

    PatchPassState state(std::vector<Eigen::Vector3d>* obstacle_forces) override {
        if (!loaded_here_) throw InputError("gl backend: no patch is loaded");
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        std::vector<double> raw(state_size_);
        glGetNamedBufferSubData(state_.id(), 0, GLsizeiptr(raw.size() * 8), raw.data());
        check("reading the patch back");
        auto vectors = [&](GLuint at, std::size_t count) {
            std::vector<Eigen::Vector3d> out(count);
            for (std::size_t i = 0; i < count; ++i) out[i] = Eigen::Vector3d(raw[at + 3 * i], raw[at + 3 * i + 1], raw[at + 3 * i + 2]);
            return out;
        };
        PatchPassState s;
        s.x = vectors(at_["s_x"], n_);
        s.v = vectors(at_["s_v"], n_);
        const GLuint out = at_["s_out"];
        s.stitch_force = vectors(out + GLuint(sh::patch_out_fixed), stitches_);
        if (raw[at_["s_stepped"] + 3 * slots_] != 0.0) s.stepped_slot_x = vectors(at_["s_stepped"], slots_);
        s.contact_force = Eigen::Vector3d(raw[out + 6], raw[out + 7], raw[out + 8]);
        s.kept.under.resize(n_);
        s.kept.searched_travel.resize(n_);
        for (std::size_t i = 0; i < n_; ++i) {
            s.kept.under[i] = std::int32_t(raw[at_["s_under"] + i]);
            s.kept.searched_travel[i] = raw[at_["s_searched_valid"] + i] != 0.0 ? raw[at_["s_searched_travel"] + i] : std::numeric_limits<double>::quiet_NaN();
        }
        s.kept.searched_at = vectors(at_["s_searched_at"], n_);
        s.kept.searched_shift = vectors(at_["s_searched_shift"], n_);
        const GLuint global = at_["s_global"];
        s.kept.tissue_shift = Eigen::Vector3d(raw[global], raw[global + 1], raw[global + 2]);
        s.kept.tissue_travel = raw[global + 3];
        if (raw[global + 4] != 0.0) s.kept.slot_x = vectors(at_["s_slot_x"], slots_);
        if (raw[global + 5] != 0.0) s.kept.grid_slot_x = vectors(at_["s_grid"], slots_);
        if (raw[global + 6] != 0.0) s.kept.asleep_slot_x = vectors(at_["s_asleep"], slots_);
        if (obstacle_forces) {
            const std::vector<Eigen::Vector3d> pushes = vectors(out + 9, 2);
            obstacle_forces->assign(pushes.begin(), pushes.begin() + std::ptrdiff_t(std::min<std::size_t>(obstacle_forces->size(), 2)));
        }
        return s;
    }

    std::optional<std::array<Eigen::Vector3d, 2>> hand_forces(bool wait) override {
        if (!loaded_here_ || sequence_ == 0) return latest_;
        for (int back = 1; back <= ring_slots; ++back) {
            if (sequence_ < std::uint64_t(back)) break;
            const std::uint64_t sequence = sequence_ - std::uint64_t(back);
            const int slot = int(sequence % ring_slots);
            if (!fences_[slot] || sequence_of_[slot] != sequence) continue;
            const bool newest = back == 1;
            const GLenum state = glClientWaitSync(fences_[slot], wait && newest ? GL_SYNC_FLUSH_COMMANDS_BIT : 0,
                                                  wait && newest ? GLuint64(60'000'000'000ull) : 0);
            if (state != GL_ALREADY_SIGNALED && state != GL_CONDITION_SATISFIED) continue;
            fences_[slot].reset();
            const double* d = reinterpret_cast<const double*>(static_cast<const char*>(ring_map_) + slot * ring_stride);
            latest_ = std::array<Eigen::Vector3d, 2>{Eigen::Vector3d(d[0], d[1], d[2]), Eigen::Vector3d(d[3], d[4], d[5])};
            break;
        }
        return latest_;
    }

    void request_snapshot() override {
        if (!loaded_here_) throw InputError("gl backend: no patch is loaded");
        const std::size_t doubles = 3 * n_ + 3 * slots_ + 1;
        if (doubles * 8 > snapshot_bytes_) {
            if (snapshot_.id()) glUnmapNamedBuffer(snapshot_.id());
            snapshot_bytes_ = doubles * 8;
            const GLbitfield flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
            gl::storage(snapshot_, snapshot_bytes_, flags);
            snapshot_map_ = glMapNamedBufferRange(snapshot_.id(), 0, GLsizeiptr(snapshot_bytes_), flags);
            if (!snapshot_map_) throw GlUnavailable("gl backend: cannot map the patch's snapshot buffer persistently");
        }
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        glCopyNamedBufferSubData(state_.id(), snapshot_.id(), GLintptr(at_["s_x"] * 8), 0, GLsizeiptr(3 * n_ * 8));
        if (slots_ > 0) glCopyNamedBufferSubData(state_.id(), snapshot_.id(), GLintptr(at_["s_slot_x"] * 8), GLintptr(3 * n_ * 8), GLsizeiptr(3 * slots_ * 8));
        glCopyNamedBufferSubData(state_.id(), snapshot_.id(), GLintptr((at_["s_global"] + 4) * 8), GLintptr((3 * n_ + 3 * slots_) * 8), 8);
        glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
        snapshot_fence_.reset(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0));
        glFlush();
        check("copying the patch for a snapshot");
    }

    std::pair<std::vector<Eigen::Vector3d>, std::vector<Eigen::Vector3d>> snapshot() override {
        if (!snapshot_fence_) request_snapshot();
        glClientWaitSync(snapshot_fence_, GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(60'000'000'000ull));
        snapshot_fence_.reset();
        const double* d = static_cast<const double*>(snapshot_map_);
        std::vector<Eigen::Vector3d> x(n_), slot_x;
        for (std::size_t i = 0; i < n_; ++i) x[i] = Eigen::Vector3d(d[3 * i], d[3 * i + 1], d[3 * i + 2]);
        if (d[3 * n_ + 3 * slots_] != 0.0) {
            slot_x.resize(slots_);
            for (std::size_t k = 0; k < slots_; ++k) slot_x[k] = Eigen::Vector3d(d[3 * n_ + 3 * k], d[3 * n_ + 3 * k + 1], d[3 * n_ + 3 * k + 2]);
        }
        return {std::move(x), std::move(slot_x)};
    }

    std::pair<double, long long> device_time(bool wait) override {
        harvest(wait);
        return {timed_ms_, timed_};
    }

    void unload() override {
        unload_loads();
        loaded_here_ = false;
        latest_.reset();
        for (auto& f : fences_) f.reset();
        snapshot_fence_.reset();
    }

private:
    static void check(const char* what) { check_gl_error("gl backend", what); }

    /// The timer queries of finished passes into timed_ms_ (all of them, waiting, with `wait`).
    void harvest(bool wait) {
        while (!timings_.empty()) {
            std::array<gl::Query, 2>& q = timings_.front();
            GLint ready = 0;
            if (!wait) {
                glGetQueryObjectiv(q[1], GL_QUERY_RESULT_AVAILABLE, &ready);
                if (!ready) break;
            }
            GLuint64 begin = 0, end = 0;
            glGetQueryObjectui64v(q[0], GL_QUERY_RESULT, &begin);
            glGetQueryObjectui64v(q[1], GL_QUERY_RESULT, &end);
            timed_ms_ += double(end - begin) * 1e-6;
            ++timed_;
            timings_.pop_front();
        }
    }

    /// The ints: the constant lists, the triangle under each vertex (scratch), the candidates last.
    void upload_ints(const PatchPassInput& in) {
        std::vector<std::int32_t> ints;
        auto put = [&](const char* name, const std::vector<std::int32_t>& values) { at_[name] = append(ints, values); };
        put("i_dist", flat(in.distance_vertices));
        put("i_colour", in.colour_first);
        put("i_particle", in.particles);
        put("i_surface_first", in.surface_first);
        put("i_surface_slot", in.surface_slot);
        put("i_triangle", flat(in.triangles));
        put("i_stitch_vertex", in.stitch_vertex);
        put("i_stitch_first", in.stitch_first);
        put("i_stitch_slot", in.stitch_slot);
        put("i_stitch_colour", in.stitch_colour_first);
        put("i_stitch_order", in.stitch_order);
        put("i_slot_vertex_first", in.slot_vertex_first);
        put("i_slot_vertex", in.slot_vertex);
        put("i_slot_stitch_first", in.slot_stitch_first);
        put("i_slot_stitch", in.slot_stitch);
        put("i_candidate_first", in.candidate_first);
        put("i_candidate", in.candidate);
        put("i_over_first", in.over_first);
        put("i_over", in.over);
        const std::size_t bytes = std::max<std::size_t>(ints.size() * 4, 16);
        if (bytes > ints_bytes_) {
            ints_bytes_ = std::max(bytes, 2 * ints_bytes_);
            gl::storage(ints_, ints_bytes_, GL_DYNAMIC_STORAGE_BIT);
        }
        glNamedBufferSubData(ints_.id(), 0, GLsizeiptr(ints.size() * 4), ints.data());
        const GLuint p = program_.id();
        for (const char* name : {"i_candidate_first", "i_candidate", "i_over_first", "i_over"})
            glProgramUniform1ui(p, glGetUniformLocation(p, name), at_[name]);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    }

    /// Zero loads on the particles of the patch loaded (queued), and the step pass told.
    void unload_loads() {
        if (!loaded_here_) return;
        const float zero[4] = {0, 0, 0, 0};
        for (std::int32_t particle : input_.particles)
            glClearNamedBufferSubData(loads_, GL_RGBA32F, GLintptr(std::size_t(particle) * 16), 16, GL_RGBA, GL_FLOAT, zero);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        if (loads_on_) loaded_(loads_on_ = false);
    }

    std::function<unsigned()> positions_;
    unsigned loads_;
    std::function<void(bool)> loaded_;
    std::size_t n_particles_;
    gl::Program program_;
    gl::Buffer ints_, constants_, state_, ring_, snapshot_;
    std::size_t snapshot_bytes_ = 0;
    void* snapshot_map_ = nullptr;
    gl::Fence snapshot_fence_;
    std::size_t ints_bytes_ = 0, state_size_ = 0;
    void* ring_map_ = nullptr;
    std::array<gl::Fence, ring_slots> fences_;
    std::array<std::uint64_t, ring_slots> sequence_of_{};
    std::uint64_t sequence_ = 0;
    std::deque<std::array<gl::Query, 2>> timings_;  ///< each pass's GL_TIMESTAMP pair, oldest first
    double timed_ms_ = 0.0;
    long long timed_ = 0;
    std::optional<std::array<Eigen::Vector3d, 2>> latest_;
    PatchPassInput input_;
    std::map<std::string, GLuint> at_;
    std::size_t n_ = 0, slots_ = 0, surface_ = 0, stitches_ = 0, distances_ = 0, colours_ = 0;
    bool loaded_here_ = false, loads_on_ = false;
};

}  // namespace

std::unique_ptr<PatchStepper> make_gl_patch_pass(std::function<unsigned()> positions, unsigned loads, std::function<void(bool)> loaded,
                                                 std::size_t n_particles) {
    return std::make_unique<GlPatchPass>(std::move(positions), loads, std::move(loaded), n_particles);
}

}  // namespace heartsim
