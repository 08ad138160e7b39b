// The GL backend: the CPU solver's substep as OpenGL 4.3 compute shaders on shader storage
// buffers in the same packed layout. Shaders and the arithmetic contract: shaders/solver_shaders.h.
// Design and deviations: docs/runtime.md. One file because it is one class,
// GlBackend: every pass reads and writes the same buffers and hand state, kept private here.
#include "runtime/gl/backend_gl.h"
#include "runtime/gl/patch_pass.h"
#include "runtime/gl/picking.h"
#include "runtime/surgery.h"
#include "runtime/gl/gl_context.h"
#include "runtime/gl/gl_object.h"
#include "runtime/gl/gl_program.h"
#include "runtime/gl/shaders/bindings.h"
#include "runtime/gl/shaders/solver_shaders.h"

#include "libmodel/cutting.h"
#include "libmodel/cutting_force.h"
#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/stability.h"

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <limits>
#include <sstream>

namespace heartsim {

namespace {

namespace sh = gl_shaders;
constexpr int slot_count = 18, lane_count = 8, hands = 2;
constexpr int ring_slots = 4;              // force readbacks in flight
constexpr GLsizeiptr ring_stride = 256;    // ≥ GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT everywhere we know
constexpr int status_slots = 8;            // watchdog status readbacks in flight (one per step)
constexpr long long snapshot_substeps = 64;  // substeps between restore-point candidates, as the cpu watchdog_interval

using gl::Buffer;
/// A compute program and its uniform lookup.
struct Program {
    gl::Program id;
    GLint at(const char* name) const { return glGetUniformLocation(id, name); }
};

/// Compiles sh::common followed by `parts` into one compute program.
void build(Program& program, const char* name, std::initializer_list<const char*> parts) {
    const std::string what = std::string("gl backend: the ") + name + " compute shader";
    std::vector<const char*> sources{sh::common};
    sources.insert(sources.end(), parts.begin(), parts.end());
    program.id = link_program({compile_shader(GL_COMPUTE_SHADER, sources, what, "run with --backend cpu")}, what, "run with --backend cpu");
}

using gl::storage;

/// The entry of particle i's slot s in the gl per-entry tables ([group of 8][slot][lane]).
constexpr std::size_t table_entry(std::size_t i, int s) { return (i / lane_count * slot_count + std::size_t(s)) * lane_count + i % lane_count; }

struct ForceSlot {
    double force[2][4];     ///< each hand's force in x, y, z, N; w is 0 (the count has its own word)
    std::uint32_t status;
    std::uint32_t sequence;
    std::uint32_t cuts[2];  ///< springs each hand's blade cut in the step the forces are from
    std::uint32_t counts[2];  ///< particles each hand's force sums (held or touched)
    double blade[2][6];     ///< each hand's BladeState: energy, travel, velocity x, y, z, speed
};
static_assert(sizeof(ForceSlot) == 184 && sizeof(ForceSlot) <= std::size_t(ring_stride));  // std430 ForceBuffer

/// One entry of set_loads's scatter list (std430 `LoadEntry`, shaders/solver_shaders.h load_scatter).
struct LoadEntry {
    std::int32_t particle;
    float force[3];  ///< N; zero for a particle the new list drops
};
static_assert(sizeof(LoadEntry) == 16);

class GlBackend final : public Backend, public SurgerySupport {
public:
    bool software_device() const override { return software_; }
    void set_software(bool software) { software_ = software; }
    GlBackend(const Scenario& scenario, const SolverOptions& options) : options_(options) {
        // The CPU solver validates the scenario exactly as the cpu backend would and decides
        // the substeps (critical step, damping): both backends then share h and the constants.
        {
            const Solver reference(scenario.lattice, scenario.packing->neighbours, options);
            load_report_ = reference.load_report();
            dt_ms_ = reference.time_step_ms();
            h_ = reference.substep_ms();
            substeps_ = reference.substeps_per_step();
            lattice_frame_ = reference.lattice_frame();  // the scalpel's area per spring, as the cpu solver's
        }
        build_buffers(scenario);
        surface_ = scenario.simulation_surface;  // for the picking / search contact passes, built on demand
        lattice_spacing_ = scenario.lattice.spacing;
        build(step_program_, "step", {sh::springs, sh::geometry, sh::step});
        build(after_program_, "after-step", {sh::after_step});
        build(capture_program_, "grab", {sh::capture});
        build(release_program_, "release", {sh::release});
        build(force_program_, "force", {sh::springs, sh::force_pass});
        build(strain_program_, "strain", {sh::springs, sh::strain_pass});
        build(cut_program_, "cut", {sh::cut_pass});
        build(blade_program_, "blade", {sh::blade_pass});
        build(scatter_program_, "load scatter", {sh::load_scatter});
        build(gather_program_, "gather", {sh::gather});
        for (const Program* p : {&step_program_, &after_program_, &capture_program_, &release_program_, &force_program_, &strain_program_,
                                 &cut_program_, &scatter_program_, &gather_program_}) {
            glProgramUniform1ui(p->id, p->at("particle_count"), GLuint(n_));
            glProgramUniform1ui(p->id, p->at("padded_count"), GLuint(n_pad_));
        }
        glProgramUniform1f(step_program_.id, step_program_.at("keep"), keep());
        glProgramUniform3f(step_program_.id, step_program_.at("gravity"), float(options_.gravity.x()), float(options_.gravity.y()),
                           float(options_.gravity.z()));
        glProgramUniform1i(step_program_.id, step_program_.at("damped"), damped_);
        for (const Program* p : {&step_program_, &force_program_})
            glProgramUniform1i(p->id, p->at("supported"), supported_);
        glProgramUniform1i(force_program_.id, force_program_.at("damped"), damped_);
        glProgramUniform1f(after_program_.id, after_program_.at("slip_strain"), float(options_.grab_slip_strain));
        glProgramUniform1d(step_program_.id, step_program_.at("pierce_strain"), options_.probe_pierce_strain);
        check("setting up the gl backend");
    }

    ~GlBackend() override {
        if (ring_.id()) glUnmapNamedBuffer(ring_.id());
        if (status_ring_.id()) glUnmapNamedBuffer(status_ring_.id());
    }

    BackendKind kind() const override { return BackendKind::gl; }
    std::size_t size() const override { return n_; }
    const SolverLoadReport& load_report() const override { return load_report_; }
    const SolverOptions& options() const override { return options_; }
    double time_step_ms() const override { return dt_ms_; }
    double substep_ms() const override { return h_; }
    int substeps_per_step() const override { return substeps_; }
    double simulated_time_ms() const override { return time_ms_; }
    std::size_t memory_bytes() const override { return memory_bytes_; }
    unsigned position_buffer() const { return position_[current_].id(); }

    void set_instrument(int hand, const Instrument& instrument) override {
        check_hand(hand);
        for (int c = 0; c < 3; ++c)
            if (!(instrument.semi_axes[c] > 0) || !std::isfinite(instrument.semi_axes[c]))
                throw InputError("solver: instrument semi-axes must be positive and finite, mm");
        release(hand);
        hand_[hand].instrument = instrument;
        hand_[hand].placed = false;
        if (picking_) picking_->invalidate(hand);
        // A probe's touched list starts empty (the step pass refills it every substep).
        const GLuint zero = 0;
        glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::touched0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    }

    void set_pose(int hand, const InstrumentPose& pose) override {
        check_hand(hand);
        if (!pose.position.allFinite() || !pose.orientation.coeffs().allFinite() || pose.orientation.norm() < 1e-6)
            throw InputError("solver: an instrument pose must be finite with a non-zero quaternion");
        InstrumentPose p = pose;
        p.orientation.normalize();
        hand_[hand].target = p;
        if (!hand_[hand].placed) hand_[hand].pose = p;
        hand_[hand].placed = true;
    }

    std::size_t begin_grab(int hand) override {
        check_hand(hand);
        HandState& state = hand_[hand];
        if (state.instrument.kind == InstrumentKind::scalpel) {  // lowers the blade (Solver::begin_grab)
            if (!state.cutting) {
                const BladeState lowered = lowered_blade(options_.cutting_resistance, lattice_frame_);
                clear_blade(hand);
                glNamedBufferSubData(counters_.id(), GLintptr((sh::blade0 + sh::blade_words * unsigned(hand) + 2) * 4), 8, &lowered.travel);
                glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
            }
            state.cutting = true;
            return 0;
        }
        if (state.instrument.kind != InstrumentKind::grabber) throw InputError("solver: begin_grab on a hand that holds no grabber or scalpel");
        release(hand);
        state.grabbing = true;
        bind_common();
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
        const GLuint p = capture_program_.id;
        glProgramUniform1i(p, capture_program_.at("hand"), hand);
        glProgramUniform3dv(p, capture_program_.at("centre"), 1, state.pose.position.data());
        const Eigen::Matrix3d rotation = state.pose.orientation.toRotationMatrix();
        glProgramUniformMatrix3dv(p, capture_program_.at("rotation"), 1, GL_FALSE, rotation.data());
        glProgramUniform3dv(p, capture_program_.at("semi_axes"), 1, state.instrument.semi_axes.data());
        glUseProgram(p);
        glDispatchCompute(GLuint((n_ + 63) / 64), 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        GLuint count = 0;
        glGetNamedBufferSubData(counters_.id(), GLintptr((sh::held0 + hand) * 4), 4, &count);
        if (count > 0) count = keep_one_piece(hand, count);
        check("begin_grab");
        return count;
    }

    /// The captured list (in the atomics' order) in ascending particle order, as the cpu solver
    /// holds it, and only the piece of tissue the cpu solver keeps (SolverOptions::grab_reach,
    /// libmodel grab_piece, on host copies of the rest positions): the others are freed by the
    /// release pass run over just them. Returns the count kept.
    GLuint keep_one_piece(int hand, GLuint count) {
        const std::size_t base = std::size_t(hand) * n_;
        std::vector<std::int32_t> index(count);
        std::vector<double> local(3 * std::size_t(count));
        glGetNamedBufferSubData(held_.id(), GLintptr(base * 4), GLsizeiptr(count * 4), index.data());
        glGetNamedBufferSubData(held_local_.id(), GLintptr(base * 3 * 8), GLsizeiptr(std::size_t(count) * 3 * 8), local.data());
        std::vector<std::size_t> order(count);
        for (std::size_t q = 0; q < count; ++q) order[q] = q;
        std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return index[a] < index[b]; });
        std::vector<Eigen::Vector3d> sorted_local(count), rest(count);
        for (std::size_t q = 0; q < count; ++q) {
            const std::size_t from = order[q], i = std::size_t(index[from]);
            sorted_local[q] = Eigen::Vector3d(local[3 * from], local[3 * from + 1], local[3 * from + 2]);
            for (int c = 0; c < 3; ++c) rest[q][c] = double(rest_position_[3 * i + std::size_t(c)]);
        }
        // Where a cut runs among them, the side of the grabber's centre (the current table: one
        // readback, at the grab only).
        std::vector<std::int32_t> sorted_index(count);
        for (std::size_t q = 0; q < count; ++q) sorted_index[q] = index[order[q]];
        std::vector<std::int32_t> table;
        auto current = [&](std::size_t i, int s) {
            if (table.empty()) {
                table.resize(uncut_neighbour_.size());
                glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
                glGetNamedBufferSubData(neighbour_.id(), 0, GLsizeiptr(table.size() * 4), table.data());
            }
            return table[table_entry(i, s)];
        };
        const std::vector<std::array<std::int32_t, 2>> joined = blade_swept_ ? joined_captured(
            sorted_index, slot_count, current, [&](std::size_t i, int s) { return uncut_neighbour_[table_entry(i, s)]; }) :
            std::vector<std::array<std::int32_t, 2>>{};
        const std::vector<std::uint8_t> keep = grab_piece(sorted_local, rest, hand_[hand].instrument.semi_axes, options_.grab_reach, joined);
        std::vector<std::int32_t> kept, dropped;
        std::vector<double> kept_local;
        for (std::size_t q = 0; q < count; ++q) {
            const std::int32_t i = index[order[q]];
            if (!keep[q]) {
                dropped.push_back(i);
                continue;
            }
            kept.push_back(i);
            for (int c = 0; c < 3; ++c) kept_local.push_back(sorted_local[q][c]);
        }
        auto set_list = [&](const std::vector<std::int32_t>& list) {
            const GLuint size = GLuint(list.size());
            if (size > 0) glNamedBufferSubData(held_.id(), GLintptr(base * 4), GLsizeiptr(size * 4), list.data());
            glNamedBufferSubData(counters_.id(), GLintptr((sh::held0 + hand) * 4), 4, &size);
        };
        if (!dropped.empty()) {  // the release pass frees the hand's listed particles and zeroes its count
            set_list(dropped);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
            glProgramUniform1i(release_program_.id, release_program_.at("hand"), hand);
            glUseProgram(release_program_.id);
            glDispatchCompute(1, 1, 1);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        }
        set_list(kept);
        if (!kept.empty())
            glNamedBufferSubData(held_local_.id(), GLintptr(base * 3 * 8), GLsizeiptr(kept_local.size() * 8), kept_local.data());
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        return GLuint(kept.size());
    }

    void release(int hand) override {
        check_hand(hand);
        HandState& state = hand_[hand];
        if (state.cutting) strokes_.lift(hand);
        state.cutting = false;
        clear_blade(hand);  // a lifted blade exerts nothing (Solver::release)
        if (!state.grabbing) return;
        bind_common();
        glProgramUniform1i(release_program_.id, release_program_.at("hand"), hand);
        glUseProgram(release_program_.id);
        glDispatchCompute(1, 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        state.grabbing = false;
    }

    /// 1 − γh/S, as Solver's kernel constants (the drag force γ·m·v on the inertia S·m).
    float keep() const { return float(1.0 - options_.damping * h_ / options_.mass_scale); }

    void set_mass_scale(double mass_scale) override {
        const ScaledStep step = scaled_step(load_report_, options_, mass_scale);  // Solver::set_mass_scale's rule; throws first
        const double old_h = h_;
        options_.mass_scale = mass_scale;
        dt_ms_ = step.dt_ms;
        substeps_ = step.substeps;
        h_ = dt_ms_ / substeps_;
        load_report_.mass_scale = mass_scale;
        load_report_.critical_dt_ms = step.critical_dt_ms;
        load_report_.damped_critical_dt_ms = step.damped_critical_dt_ms;
        load_report_.substeps = substeps_;
        load_report_.substep_ms = h_;
        upload_step_constants();
        glProgramUniform1f(step_program_.id, step_program_.at("keep"), keep());
        if (old_h != h_) {  // velocities kept: u = v·h, scaled in float as the cpu solver does
            const float ratio = float(h_ / old_h);
            std::vector<float> motion(4 * n_pad_);
            glGetNamedBufferSubData(motion_[current_].id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
            for (std::size_t i = 0; i < n_pad_; ++i)
                for (int c = 0; c < 3; ++c) motion[4 * i + std::size_t(c)] = motion[4 * i + std::size_t(c)] * ratio;
            glNamedBufferSubData(motion_[current_].id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
        }
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        check("set_mass_scale");
    }

    /// The constants that depend on h and the mass scale (Solver::build_step_constants, and the
    /// start motion of reset()): h²/(S·m), the support and spring dashpots c/h, u₀ = −½·a·h².
    void upload_step_constants() {
        std::vector<ParticleConstants> constants = particle_host_;
        for (std::size_t i = 0; i < n_; ++i) {
            ParticleConstants& p = constants[i];
            p.inverse_mass_h2 = p.movable ? float(h_ * h_ / (double(p.mass) * options_.mass_scale)) : 0.0f;
            p.support_point[3] = p.support_stiffness > 0.0f ? float(support_damping_host_[i] / h_) : 0.0f;
        }
        std::vector<float> dashpot_over_h(dashpot_host_.size());
        for (std::size_t t = 0; t < dashpot_host_.size(); ++t) dashpot_over_h[t] = float(double(dashpot_host_[t]) / h_);
        // Solver::reset(): at rest the springs and supports balance `balanced_gravity`, so the
        // motion starts with acceleration (g − g_balanced)/S: u₀ = x₀ − x₋₁ = −½·a·h².
        const Eigen::Vector3d rest_acceleration = (options_.gravity - options_.balanced_gravity) / options_.mass_scale;
        std::vector<float> motion(4 * n_pad_, 0.0f);
        for (std::size_t i = 0; i < n_; ++i)
            if (constants[i].movable)
                for (int c = 0; c < 3; ++c) motion[4 * i + std::size_t(c)] = float(-0.5 * rest_acceleration[c] * h_ * h_);
        if (!particle_.id()) {
            storage(particle_, constants, GL_DYNAMIC_STORAGE_BIT);
            storage(dashpot_, dashpot_over_h, GL_DYNAMIC_STORAGE_BIT);
            storage(rest_motion_, motion, GL_DYNAMIC_STORAGE_BIT);
            storage(motion_[0], motion, GL_DYNAMIC_STORAGE_BIT);
            storage(motion_[1], motion, GL_DYNAMIC_STORAGE_BIT);
            return;
        }
        glNamedBufferSubData(particle_.id(), 0, GLsizeiptr(constants.size() * sizeof(ParticleConstants)), constants.data());
        glNamedBufferSubData(dashpot_.id(), 0, GLsizeiptr(dashpot_over_h.size() * sizeof(float)), dashpot_over_h.data());
        glNamedBufferSubData(rest_motion_.id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
    }

    void reset_tissue() override {
        glNamedBufferSubData(neighbour_.id(), 0, GLsizeiptr(uncut_neighbour_.size() * 4), uncut_neighbour_.data());  // heals cuts
        clear_loads();
        strokes_.clear();
        blade_swept_ = false;
        place_tissue(rest_current_, &rest_motion_);
        glCopyNamedBufferSubData(rest_current_.id(), good_position_.id(), 0, 0, GLsizeiptr(n_pad_ * 16));
        good_time_ms_ = time_ms_;
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        check("reset_tissue");
    }

    StepReport step(int steps) override {
        StepReport report;
        harvest_queries(false);
        if (steps <= 0) return report;
        // The watchdog, as the cpu one but asynchronous: the status of earlier steps arrives here
        // a step or two late, without waiting. A divergence restores the last verified state.
        if (poll_status()) {
            restore(report);
            return report;
        }
        Pending timing{};
        gl::generate(timing.queries);
        glQueryCounter(timing.queries[0], GL_TIMESTAMP);

        const long long total = (long long)steps * substeps_;
        std::array<InstrumentPose, hands> start;
        for (int hand = 0; hand < hands; ++hand) start[hand] = hand_[hand].pose;
        double max_displacement = options_.max_displacement_fraction * double(min_rest_length_);
        int probe_hands[2] = {0, 0}, probe_count = 0;
        for (int hand = 0; hand < hands; ++hand) {
            const HandState& state = hand_[hand];
            if (state.instrument.kind != InstrumentKind::none) max_displacement = std::max(max_displacement, state.instrument.semi_axes.maxCoeff());
            if (state.instrument.kind == InstrumentKind::probe) probe_hands[probe_count++] = hand;
        }
        const bool grabbing = hand_[0].grabbing || hand_[1].grabbing;
        const GLuint sp = step_program_.id, ap = after_program_.id;
        glProgramUniform1f(sp, step_program_.at("max_displacement2"),
                           options_.watchdog && std::isfinite(max_displacement) ? float(max_displacement * max_displacement)
                                                                               : std::numeric_limits<float>::infinity());
        glProgramUniform1i(sp, step_program_.at("probe_count"), probe_count);
        glProgramUniform1iv(sp, step_program_.at("probe_hand"), 2, probe_hands);
        for (int q = 0; q < probe_count; ++q) {
            const double radius = hand_[probe_hands[q]].instrument.semi_axes.maxCoeff() * (1 + 1e-3) + 1e-3;
            set_indexed_1f(sp, "probe_bound2", q, float(radius * radius));
            set_indexed_3dv(sp, "probe_semi_axes", q, hand_[probe_hands[q]].instrument.semi_axes.data());
        }
        int grab_flags[2] = {hand_[0].grabbing, hand_[1].grabbing};
        glProgramUniform1iv(ap, after_program_.at("grabbing"), 2, grab_flags);

        bind_common();
        for (int hand = 0; hand < hands; ++hand) {
            const HandState& state = hand_[hand];
            if (!state.cutting || !state.placed) continue;
            const double length = 2.0 * state.instrument.semi_axes.z();
            const BladeSweep sweep = blade_sweep(state.pose, state.target, length, cut_search_margin(max_rest_length_));
            if (sweep.cuts_anything) strokes_.sweep(hand, state.pose, state.target, length);
            const GLuint zero = 0;
            glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::cut0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
            cut(sweep, hand);
            blade(hand, blade_step(options_.cutting_resistance, lattice_frame_, state.pose, state.target, length, double(steps) * dt_ms_));
        }
        const GLuint zero = 0;
        for (long long q = 1; q <= total; ++q) {
            const double fraction = double(q) / double(total), previous_fraction = double(q - 1) / double(total);
            std::array<InstrumentPose, hands> poses, previous_poses;
            for (int hand = 0; hand < hands; ++hand) {
                poses[hand] = interpolate(start[hand], hand_[hand].target, fraction);
                previous_poses[hand] = interpolate(start[hand], hand_[hand].target, previous_fraction);
            }
            for (int k = 0; k < probe_count; ++k) {
                const int hand = probe_hands[k];
                const Eigen::Matrix3d rotation = poses[hand].orientation.toRotationMatrix();
                const Eigen::Matrix3d previous_rotation = previous_poses[hand].orientation.toRotationMatrix();
                set_indexed_3dv(sp, "probe_centre", k, poses[hand].position.data());
                set_indexed_3dv(sp, "probe_previous_centre", k, previous_poses[hand].position.data());
                set_indexed_matrix(sp, "probe_rotation", k, rotation.data());
                set_indexed_matrix(sp, "probe_previous_rotation", k, previous_rotation.data());
            }
            // Touched lists are per substep.
            glClearNamedBufferSubData(counters_.id(), GL_R32UI, 0, 8, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::motion, motion_[current_].id());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::next, position_[next_].id());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::next_motion, motion_[next_].id());
            glUseProgram(sp);
            glDispatchCompute(GLuint((n_pad_ + 63) / 64), 1, 1);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
            if (grabbing) {
                for (int hand = 0; hand < hands; ++hand) {
                    if (!hand_[hand].grabbing) continue;
                    const Eigen::Matrix3d rotation = poses[hand].orientation.toRotationMatrix();
                    set_indexed_3dv(ap, "grab_centre", hand, poses[hand].position.data());
                    set_indexed_matrix(ap, "grab_rotation", hand, rotation.data());
                }
                glUseProgram(ap);
                glDispatchCompute(1, 1, 1);
                glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
            }
            std::swap(current_, next_);
            time_ms_ += h_;
            ++report.substeps;
        }
        report.steps = steps;
        substeps_since_snapshot_ += report.substeps;
        queue_status();
        for (auto& state : hand_) state.pose = state.target;
        glQueryCounter(timing.queries[1], GL_TIMESTAMP);
        timing.is_force = false;
        timing.substeps = report.substeps;
        pending_.push_back(std::move(timing));
        glFlush();
        check("step");
        return report;
    }

    /// Neither hand holds anything the tissue feels (a repair's patch and needle hands): the forces
    /// are zero, and a request needs no pass.
    bool no_instruments() const {
        return hand_[0].instrument.kind == InstrumentKind::none && hand_[1].instrument.kind == InstrumentKind::none;
    }

    void request_forces() override {
        if (no_instruments()) {  // answered at once; requests still in flight are superseded
            for (auto& fence : fences_) fence.reset();
            latest_ = InstrumentForces{};
            latest_sequence_ = next_sequence_++;
            return;
        }
        const int slot = int(next_sequence_ % ring_slots);
        if (fences_[slot]) {  // ring full: the oldest readback is still in flight (rare: 4 outstanding)
            glClientWaitSync(fences_[slot], GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(10'000'000'000ull));
            fences_[slot].reset();
        }
        run_contact_search();
        Pending timing{};
        gl::generate(timing.queries);
        glQueryCounter(timing.queries[0], GL_TIMESTAMP);
        bind_common();
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::motion, motion_[current_].id());
        glBindBufferRange(GL_SHADER_STORAGE_BUFFER, sh::forces, ring_.id(), GLintptr(slot) * ring_stride, sizeof(ForceSlot));
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picked, picking_ ? picking_->picked_buffer() : touched_.id());
        int kinds[2];
        for (int hand = 0; hand < hands; ++hand)
            kinds[hand] = hand_[hand].instrument.kind == InstrumentKind::probe ? (listed_contacts() ? 3 : 1) : hand_[hand].grabbing ? 2 : 0;
        glProgramUniform1iv(force_program_.id, force_program_.at("hand_kind"), 2, kinds);
        glProgramUniform1ui(force_program_.id, force_program_.at("sequence_number"), GLuint(next_sequence_));
        glUseProgram(force_program_.id);
        glDispatchCompute(hands, 1, 1);
        glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
        fences_[slot].reset(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0));
        sequence_of_[slot] = next_sequence_++;
        glQueryCounter(timing.queries[1], GL_TIMESTAMP);
        timing.is_force = true;
        pending_.push_back(std::move(timing));
        glFlush();
        check("request_forces");
    }

    std::uint64_t latest_forces_request() const override { return latest_sequence_; }

    std::optional<InstrumentForces> latest_forces() override {
        // Newest finished slot, without waiting.
        for (int back = 1; back <= ring_slots; ++back) {
            if (next_sequence_ < std::uint64_t(back)) break;
            const std::uint64_t sequence = next_sequence_ - std::uint64_t(back);
            const int slot = int(sequence % ring_slots);
            if (!fences_[slot] || sequence_of_[slot] != sequence) continue;
            const GLenum state = glClientWaitSync(fences_[slot], 0, 0);
            if (state != GL_ALREADY_SIGNALED && state != GL_CONDITION_SATISFIED) continue;  // unfinished (or the wait failed)
            fences_[slot].reset();
            latest_ = read_slot(slot);
            latest_sequence_ = sequence;
            break;
        }
        return latest_;
    }

    InstrumentForces instrument_forces() override {
        request_forces();
        if (no_instruments()) return *latest_;
        const int slot = int((next_sequence_ - 1) % ring_slots);
        glClientWaitSync(fences_[slot], GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(60'000'000'000ull));
        fences_[slot].reset();
        latest_ = read_slot(slot);
        latest_sequence_ = next_sequence_ - 1;
        return *latest_;
    }

    /// Solver::cut on the gpu: the cut pass over the current positions, queued; the springs cut
    /// are counted into the hand's counter word (cleared by the caller).
    void cut(const BladeSweep& sweep, int hand) {
        if (!sweep.cuts_anything) return;
        blade_swept_ = true;
        const GLuint p = cut_program_.id;
        glProgramUniform1i(p, cut_program_.at("hand"), hand);
        glProgramUniform3fv(p, cut_program_.at("corner"), 4, sweep.corner[0].data());
        glProgramUniform3fv(p, cut_program_.at("low"), 1, sweep.low.data());
        glProgramUniform3fv(p, cut_program_.at("high"), 1, sweep.high.data());
        glProgramUniform3fv(p, cut_program_.at("near_low"), 1, sweep.near_low.data());  // the cpu solver's search box
        glProgramUniform3fv(p, cut_program_.at("near_high"), 1, sweep.near_high.data());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
        glUseProgram(p);
        glDispatchCompute(GLuint((n_pad_ + 63) / 64), 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    }

    /// The scalpel's state after its cut (Solver::step: next_blade_state with `r`), queued: one
    /// invocation reads the hand's cut counter and updates its state in the counter words.
    void blade(int hand, const BladeStep& r) {
        const GLuint p = blade_program_.id;
        glProgramUniform1i(p, blade_program_.at("hand"), hand);
        glProgramUniform1d(p, blade_program_.at("energy_per_spring"), r.energy_per_spring);
        glProgramUniform1d(p, blade_program_.at("travel"), r.travel);
        glProgramUniform1d(p, blade_program_.at("distance_keep"), r.distance_keep);
        glProgramUniform3dv(p, blade_program_.at("motion_rate"), 1, r.motion_rate.data());
        glProgramUniform1d(p, blade_program_.at("travel_rate"), r.travel_rate);
        glProgramUniform1d(p, blade_program_.at("keep"), r.keep);
        glProgramUniform1d(p, blade_program_.at("alpha"), r.alpha);
        glUseProgram(p);
        glDispatchCompute(1, 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    }

    /// The hand's cut counter and blade state to zero (a lifted blade, a new instrument, a reset).
    void clear_blade(int hand) {
        const GLuint zero = 0;
        glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::cut0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::blade0 + sh::blade_words * unsigned(hand)) * 4),
                                  GLsizeiptr(sh::blade_words * 4), GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    }

    const StrokeLog& strokes() const override { return strokes_; }

    std::vector<std::array<std::int32_t, 2>> cut_springs() override {
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        std::vector<std::int32_t> table(uncut_neighbour_.size());
        glGetNamedBufferSubData(neighbour_.id(), 0, GLsizeiptr(table.size() * 4), table.data());
        check("reading the cut springs");
        std::vector<std::array<std::int32_t, 2>> out;
        for (std::size_t i = 0; i < n_; ++i)
            for (int s = 0; s < slot_count; ++s) {
                const std::size_t t = table_entry(i, s);
                const std::int32_t j = uncut_neighbour_[t];
                if (std::size_t(j) > i && table[t] == std::int32_t(i)) out.push_back({std::int32_t(i), j});
            }
        std::sort(out.begin(), out.end());
        return out;
    }

    std::vector<std::array<float, 3>> positions() override {
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        std::vector<float> raw(4 * n_pad_);
        glGetNamedBufferSubData(position_[current_].id(), 0, GLsizeiptr(raw.size() * sizeof(float)), raw.data());
        check("reading positions");
        std::vector<std::array<float, 3>> out(n_);
        for (std::size_t i = 0; i < n_; ++i) out[i] = {raw[4 * i], raw[4 * i + 1], raw[4 * i + 2]};
        return out;
    }

    void set_loads(const std::vector<ParticleLoad>& loads) override {
        check_loads(loads, n_);  // Solver::set_loads's rule; throws before anything changes
        // One list for the scatter pass: the new loads, and the previous ones' particles that the
        // new list drops with a zero force; both sorted, so each particle appears once.
        std::vector<LoadEntry> entries;
        entries.reserve(loads.size() + load_particles_.size());
        std::size_t q = 0;
        for (const ParticleLoad& load : loads) {
            for (; q < load_particles_.size() && load_particles_[q] < load.particle; ++q) entries.push_back({load_particles_[q], {0, 0, 0}});
            if (q < load_particles_.size() && load_particles_[q] == load.particle) ++q;
            entries.push_back({load.particle, {float(load.force_n.x()), float(load.force_n.y()), float(load.force_n.z())}});
        }
        for (; q < load_particles_.size(); ++q) entries.push_back({load_particles_[q], {0, 0, 0}});
        if (!entries.empty()) {
            const std::size_t bytes = entries.size() * sizeof(LoadEntry);
            if (bytes > load_list_bytes_) {
                load_list_bytes_ = std::max<std::size_t>(bytes, 2 * load_list_bytes_);
                storage(load_list_, load_list_bytes_, GL_DYNAMIC_STORAGE_BIT);
            }
            glNamedBufferSubData(load_list_.id(), 0, GLsizeiptr(bytes), entries.data());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load_list, load_list_.id());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load, load_.id());
            glProgramUniform1ui(scatter_program_.id, scatter_program_.at("entry_count"), GLuint(entries.size()));
            glUseProgram(scatter_program_.id);
            glDispatchCompute(GLuint((entries.size() + 63) / 64), 1, 1);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        }
        load_particles_.resize(loads.size());
        for (std::size_t k = 0; k < loads.size(); ++k) load_particles_[k] = loads[k].particle;
        glProgramUniform1i(step_program_.id, step_program_.at("loaded"), !load_particles_.empty() || patch_loads_);
        check("set_loads");
    }

    std::vector<std::array<float, 3>> positions_of(const std::vector<std::int32_t>& particles) override {
        check_particle_indices(particles, n_);
        std::vector<std::array<float, 3>> out(particles.size());
        if (particles.empty()) return out;
        if (particles.size() > gather_capacity_) {
            gather_capacity_ = std::max<std::size_t>(particles.size(), 2 * gather_capacity_);
            storage(gather_index_, gather_capacity_ * 4, GL_DYNAMIC_STORAGE_BIT);
            storage(gathered_, gather_capacity_ * 16, 0);
        }
        glNamedBufferSubData(gather_index_.id(), 0, GLsizeiptr(particles.size() * 4), particles.data());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::gather_index, gather_index_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::gathered, gathered_.id());
        glProgramUniform1ui(gather_program_.id, gather_program_.at("gather_count"), GLuint(particles.size()));
        glUseProgram(gather_program_.id);
        glDispatchCompute(GLuint((particles.size() + 63) / 64), 1, 1);
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        std::vector<float> raw(4 * particles.size());
        glGetNamedBufferSubData(gathered_.id(), 0, GLsizeiptr(raw.size() * sizeof(float)), raw.data());
        check("reading positions of particles");
        for (std::size_t q = 0; q < particles.size(); ++q) out[q] = {raw[4 * q], raw[4 * q + 1], raw[4 * q + 2]};
        return out;
    }

    void set_contact(const ContactSettings& settings) override {
        if (settings.mode != ContactMode::direct && !picking_)
            picking_ = std::make_unique<PickingPass>(surface_, n_, lattice_spacing_, settings);
        if (picking_) picking_->set_settings(settings);
        contact_ = settings;
        check("set_contact");
    }

    std::vector<std::int32_t> contact_particles(int hand) override {
        check_hand(hand);
        const HandState& state = hand_[hand];
        if (state.instrument.kind == InstrumentKind::none) return {};
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        const bool listed = state.instrument.kind == InstrumentKind::probe && listed_contacts();
        const GLuint word = listed ? sh::picked0 + hand : state.grabbing ? sh::held0 + hand : sh::touched0 + hand;
        GLuint count = 0;
        glGetNamedBufferSubData(counters_.id(), GLintptr(word * 4), 4, &count);
        std::vector<std::int32_t> out(std::min<std::size_t>(count, n_));
        const GLuint list = listed ? picking_->picked_buffer() : state.grabbing ? held_.id() : touched_.id();
        if (!out.empty()) glGetNamedBufferSubData(list, GLintptr(std::size_t(hand) * n_ * 4), GLsizeiptr(out.size() * 4), out.data());
        check("reading contact particles");
        std::sort(out.begin(), out.end());
        return out;
    }

    PassTimes pass_times() override {
        harvest_queries(true);
        return times_;
    }

    SurgerySupport* surgery() override { return this; }
    /// The task, then the step: the patch pass it queues runs on the GPU before the tissue's.
    StepReport step_after(const std::function<void()>& task) override {
        task();
        return step(1);
    }

    PatchStepper* patch_stepper() override {
        if (!patch_pass_ && !patch_pass_refused_) {
            try {
                patch_pass_ = make_gl_patch_pass([this] { return unsigned(position_[current_].id()); }, load_.id(),
                                                 [this](bool on) {
                                                     patch_loads_ = on;
                                                     glProgramUniform1i(step_program_.id, step_program_.at("loaded"),
                                                                        !load_particles_.empty() || patch_loads_);
                                                 },
                                                 n_);
            } catch (const std::runtime_error& e) {  // a driver without what the pass needs (GlUnavailable, an OpenGL error): the host steps the patch
                patch_pass_refused_ = true;
                std::printf("repair: the patch steps on the host: %s\n", e.what());
            }
        }
        return patch_pass_.get();
    }

private:
    bool software_ = false;  ///< the context's device is a software rasteriser (keep_up_advice)
    struct HandState {
        Instrument instrument;
        InstrumentPose pose, target;
        bool grabbing = false, placed = false;
        bool cutting = false;  ///< a scalpel between begin_grab and release
    };
    struct Pending {
        std::array<gl::Query, 2> queries;
        bool is_force = false;
        bool is_picking = false;
        long long substeps = 0;
    };

    /// No loads: the load buffer back to zero, the step pass no longer reads it.
    void clear_loads() {
        const float zero4[4] = {0, 0, 0, 0};
        glClearNamedBufferData(load_.id(), GL_RGBA32F, GL_RGBA, GL_FLOAT, zero4);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        load_particles_.clear();
        glProgramUniform1i(step_program_.id, step_program_.at("loaded"), GL_FALSE);
    }

    /// The force pass reads the picking / search list (not the step's touched list) for probes.
    bool listed_contacts() const { return contact_.mode != ContactMode::direct && picking_; }

    /// picking or search: each probe's contact list for the force pass, timed as one call.
    void run_contact_search() {
        if (!listed_contacts()) return;
        bool any = false;
        const GLuint zero = 0;
        for (int hand = 0; hand < hands; ++hand) {
            const HandState& state = hand_[hand];
            if (state.instrument.kind != InstrumentKind::probe) continue;
            if (state.placed) any = true;
            else glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::picked0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        }
        if (!any) return;
        Pending timing{};
        timing.is_picking = true;
        gl::generate(timing.queries);
        glQueryCounter(timing.queries[0], GL_TIMESTAMP);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        for (int hand = 0; hand < hands; ++hand) {
            const HandState& state = hand_[hand];
            if (state.instrument.kind != InstrumentKind::probe || !state.placed) continue;
            picking_->collect(hand, state.instrument, state.pose, position_[current_].id(), counters_.id());
        }
        glQueryCounter(timing.queries[1], GL_TIMESTAMP);
        pending_.push_back(std::move(timing));
        check("the contact search");
    }

    static void check_hand(int hand) {
        if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    }

    static void check(const char* what) { check_gl_error("gl backend", what); }

    void set_indexed_1f(GLuint program, const std::string& name, int index, float value) {
        glProgramUniform1f(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), value);
    }
    void set_indexed_3dv(GLuint program, const std::string& name, int index, const double* value) {
        glProgramUniform3dv(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), 1, value);
    }
    void set_indexed_matrix(GLuint program, const std::string& name, int index, const double* column_major) {
        glProgramUniformMatrix3dv(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), 1, GL_FALSE,
                                  column_major);
    }

    InstrumentForces read_slot(int slot) {
        const auto* s = reinterpret_cast<const ForceSlot*>(static_cast<const char*>(ring_map_) + slot * ring_stride);
        InstrumentForces forces;
        for (int hand = 0; hand < hands; ++hand) {
            forces.hand[hand].force_n = Eigen::Vector3d(s->force[hand][0], s->force[hand][1], s->force[hand][2]);
            forces.hand[hand].particles = std::min<std::size_t>(s->counts[hand], n_);
            forces.hand[hand].springs_cut = s->cuts[hand];
            // A blade's state is zero but while its hand is a lowered scalpel, which touches and holds
            // nothing: its force is the blade's (Solver::instrument_forces), from the state the step had.
            const BladeState blade{s->blade[hand][0], s->blade[hand][1], Eigen::Vector3d(s->blade[hand][2], s->blade[hand][3], s->blade[hand][4]),
                                   s->blade[hand][5]};
            if (blade.energy != 0 || blade.travel != 0 || blade.travel_rate != 0 || blade.motion_rate != Eigen::Vector3d::Zero())
                forces.hand[hand].force_n = blade_force(blade, options_.cutting_resistance, 2.0 * hand_[hand].instrument.semi_axes.z());
            if (!forces.hand[hand].force_n.allFinite()) forces.hand[hand].force_n.setZero();  // never leak a non-finite force
        }
        return forces;
    }

    /// After a step: copies the sticky status word into the next status slot behind a fence, and
    /// every snapshot_substeps substeps takes the state as a restore-point candidate, with its
    /// largest spring stretch (strain_pass) beside the status. The candidate becomes the restore
    /// point once that slot comes back clean and its stretch within restore_strain_limit, as the
    /// cpu solver's rule: a torn state is stepped on from but never returned to. A full ring
    /// skips a step.
    void queue_status() {
        const int slot = int(status_sequence_ % status_slots);
        if (status_fences_[slot]) return;
        if (!candidate_pending_ && substeps_since_snapshot_ >= snapshot_substeps) {
            const GLuint zero = 0;
            glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr(sh::strain * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
            bind_common();
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::motion, motion_[current_].id());
            glUseProgram(strain_program_.id);
            glDispatchCompute(GLuint((n_ + 63) / 64), 1, 1);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
            glCopyNamedBufferSubData(counters_.id(), status_ring_.id(), GLintptr(sh::strain * 4), GLintptr(slot * 8 + 4), 4);
            glCopyNamedBufferSubData(position_[current_].id(), candidate_position_.id(), 0, 0, GLsizeiptr(n_pad_ * 16));
            candidate_time_ms_ = time_ms_;
            candidate_pending_ = true;
            candidate_slot_sequence_ = status_sequence_;
            substeps_since_snapshot_ = 0;
        }
        glCopyNamedBufferSubData(counters_.id(), status_ring_.id(), GLintptr(sh::status * 4), GLintptr(slot * 8), 4);
        glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
        status_fences_[slot].reset(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0));
        ++status_sequence_;
    }

    /// Reads the finished status slots in order without waiting; true at the first that shows a
    /// divergence. The candidate's slot drops it when its stretch is past the limit; a clean slot
    /// at or after the candidate's makes it the restore point.
    bool poll_status() {
        while (polled_sequence_ < status_sequence_) {
            const int slot = int(polled_sequence_ % status_slots);
            if (glClientWaitSync(status_fences_[slot], 0, 0) == GL_TIMEOUT_EXPIRED) return false;
            status_fences_[slot].reset();
            const std::uint32_t* words = static_cast<const std::uint32_t*>(status_map_) + 2 * slot;
            if (words[0] != 0) return true;
            if (candidate_pending_ && polled_sequence_ == candidate_slot_sequence_ && options_.restore_strain_limit > 0) {
                float stretch;
                std::memcpy(&stretch, &words[1], 4);
                if (!(double(stretch) <= options_.restore_strain_limit)) candidate_pending_ = false;
            }
            if (candidate_pending_ && polled_sequence_ >= candidate_slot_sequence_) {
                std::swap(good_position_, candidate_position_);
                good_time_ms_ = candidate_time_ms_;
                candidate_pending_ = false;
                consecutive_restores_ = 0;
            }
            ++polled_sequence_;
        }
        return false;
    }

    /// Drops every status slot and candidate in flight (they belong to a state that is gone).
    void forget_status() {
        for (auto& fence : status_fences_) fence.reset();
        polled_sequence_ = status_sequence_;
        candidate_pending_ = false;
        substeps_since_snapshot_ = 0;
    }

    /// The last verified state, at rest, grabs released, the status cleared; as Solver::restore.
    /// Grabs released, the tissue at `positions` (both buffers) with `motion` (null: at rest), the
    /// touched lists and the watchdog status cleared, nothing of the old state in flight. The
    /// one way reset_tissue() and restore() put the tissue somewhere.
    void place_tissue(const Buffer& positions, const Buffer* motion) {
        for (int hand = 0; hand < hands; ++hand) release(hand);
        const GLsizeiptr bytes = GLsizeiptr(n_pad_ * 16);
        glCopyNamedBufferSubData(positions.id(), position_[current_].id(), 0, 0, bytes);
        glCopyNamedBufferSubData(positions.id(), position_[next_].id(), 0, 0, bytes);
        if (motion) {
            glCopyNamedBufferSubData(motion->id(), motion_[current_].id(), 0, 0, bytes);
        } else {
            const float zero4[4] = {0, 0, 0, 0};
            for (Buffer& m : motion_) glClearNamedBufferData(m.id(), GL_RGBA32F, GL_RGBA, GL_FLOAT, zero4);
        }
        const GLuint zero = 0;
        for (GLuint word : {GLuint(sh::touched0), GLuint(sh::touched1), GLuint(sh::status)})
            glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr(word * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        forget_status();
    }

    void restore(StepReport& report) {
        const double failed_at = time_ms_;
        place_tissue(good_position_, nullptr);
        time_ms_ = good_time_ms_;
        report.diverged = true;
        report.reason = WatchdogReason::speed;
        report.gave_up = ++consecutive_restores_ >= options_.max_consecutive_restores;
        std::ostringstream message;
        message << "gl backend watchdog: a particle moved more than the displacement bound in one substep by t = " << failed_at
                << " ms; restored the state of t = " << time_ms_ << " ms at rest, grabs released";
        if (report.gave_up)
            message << "; " << consecutive_restores_ << " restores in a row without a new good state: the simulation cannot recover";
        report.message = message.str();
        check("restore");
    }

    void harvest_queries(bool wait) {
        while (!pending_.empty()) {
            Pending& p = pending_.front();
            GLint available = 0;
            if (!wait) {
                glGetQueryObjectiv(p.queries[1], GL_QUERY_RESULT_AVAILABLE, &available);
                if (!available) break;
            }
            GLuint64 begin = 0, end = 0;
            glGetQueryObjectui64v(p.queries[0], GL_QUERY_RESULT, &begin);
            glGetQueryObjectui64v(p.queries[1], GL_QUERY_RESULT, &end);
            const double ms = double(end - begin) * 1e-6;
            if (p.is_picking) times_.picking_ms += ms, ++times_.picking_calls;
            else if (p.is_force) times_.force_ms += ms, ++times_.force_calls;
            else times_.step_ms += ms, ++times_.step_calls, times_.substeps += p.substeps;
            pending_.pop_front();
        }
        times_.gpu_timed = true;
        times_.picking_renders = picking_ ? picking_->renders() : 0;
    }

    void bind_common() {
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::neighbour, neighbour_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::rest_length, rest_length_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::stiffness, stiffness_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::dashpot, dashpot_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::particle, particle_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held_by, held_by_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::counters, counters_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::touched, touched_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held, held_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held_local, held_local_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load, load_.id());
    }

    /// The tables of libmodel/solver.cpp's constructor, built the same way (same slot search,
    /// same rounding of the dashpot and h²/m from double).
    void build_buffers(const Scenario& scenario) {
        const Particles& particles = scenario.lattice.particles;
        const Springs& springs = scenario.lattice.springs;
        const auto& table = scenario.packing->neighbours;
        n_ = particles.size();
        n_pad_ = (n_ + lane_count - 1) / lane_count * lane_count;
        const std::vector<double> damping_ratio =
            options_.damping_ratio.empty() ? damping_ratios(scenario.lattice.materials) : options_.damping_ratio;
        const std::vector<std::int32_t> slot_spring = spring_of_slot(table, springs);  // throws for non-neighbours
        const std::size_t entries = n_pad_ * slot_count;
        std::vector<std::int32_t> neighbour(entries);
        std::vector<float> rest(entries, 0.0f), stiff(entries, 0.0f);
        dashpot_host_.assign(entries, 0.0f);
        min_rest_length_ = std::numeric_limits<float>::infinity();
        damped_ = false;
        for (std::size_t i = 0; i < n_pad_; ++i)
            for (int s = 0; s < slot_count; ++s) {
                const std::size_t t = table_entry(i, s);
                neighbour[t] = std::int32_t(i);
                if (i >= n_) continue;
                const std::int32_t q = slot_spring[i * slot_count + std::size_t(s)];
                if (q < 0) continue;
                const auto [a, b] = springs.pairs[std::size_t(q)];
                const std::size_t j = std::size_t(a) == i ? std::size_t(b) : std::size_t(a);
                neighbour[t] = std::int32_t(j);
                rest[t] = springs.rest_length[std::size_t(q)];
                stiff[t] = springs.stiffness[std::size_t(q)];
                const float c = float(spring_dashpot(particles, damping_ratio, double(springs.stiffness[std::size_t(q)]), i, j));
                damped_ = damped_ || c != 0.0f;
                dashpot_host_[t] = c;
                min_rest_length_ = std::min(min_rest_length_, rest[t]);
                max_rest_length_ = std::max(max_rest_length_, rest[t]);
            }
        std::vector<ParticleConstants>& constants = particle_host_;
        constants.assign(n_pad_, {1.0f, 0.0f, 0, 0.0f, {0.0f, 0.0f, 0.0f, 0.0f}});
        support_damping_host_.assign(n_, 0.0);
        std::vector<float> current(4 * n_pad_, 0.0f);
        supported_ = false;
        for (std::size_t i = 0; i < n_; ++i) {
            const bool movable = !particles.anchored[i];
            constants[i].mass = particles.mass[i];
            constants[i].movable = movable;
            const std::array<float, 3>& y = particles.supported() ? particles.support_point[i] : particles.rest_position[i];
            for (int c = 0; c < 3; ++c) constants[i].support_point[c] = y[std::size_t(c)];
            if (movable && particles.supported() && particles.support_stiffness[i] > 0.0f) {
                constants[i].support_stiffness = particles.support_stiffness[i];
                // Solver::build_step_constants(): c/h rounded from double (upload_step_constants).
                if (!particles.support_damping.empty()) support_damping_host_[i] = double(particles.support_damping[i]);
                supported_ = true;
            }
            for (int c = 0; c < 3; ++c) current[4 * i + std::size_t(c)] = particles.rest_position[i][std::size_t(c)];
        }
        storage(position_[0], current, 0);
        storage(position_[1], current, 0);
        storage(rest_current_, current, 0);    // the start state again, for reset_tissue()
        upload_step_constants();               // particle constants, dashpots c/h, the start motion (both buffers)
        storage(neighbour_, neighbour, GL_DYNAMIC_STORAGE_BIT);  // the cut pass and reset_tissue rewrite it
        uncut_neighbour_ = std::move(neighbour);
        storage(rest_length_, rest);
        storage(stiffness_, stiff);
        storage(held_by_, std::vector<std::int32_t>(n_pad_, -1));
        storage(counters_, std::vector<std::uint32_t>(sh::counter_words, 0u), GL_DYNAMIC_STORAGE_BIT);
        storage(touched_, std::size_t(hands) * n_ * 4, 0);
        storage(held_, std::size_t(hands) * n_ * 4, GL_DYNAMIC_STORAGE_BIT);              // begin_grab rewrites it
        storage(held_local_, std::size_t(hands) * n_ * 3 * 8, GL_DYNAMIC_STORAGE_BIT);
        storage(load_, std::vector<float>(4 * n_pad_, 0.0f), 0);  // set_loads's scatter pass writes it
        rest_position_.resize(3 * n_);  // begin_grab's piece of tissue (keep_one_piece)
        for (std::size_t i = 0; i < n_; ++i)
            for (int c = 0; c < 3; ++c) rest_position_[3 * i + std::size_t(c)] = particles.rest_position[i][std::size_t(c)];
        const GLbitfield ring_flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
        storage(ring_, std::size_t(ring_slots) * ring_stride, ring_flags);
        ring_map_ = glMapNamedBufferRange(ring_.id(), 0, ring_slots * ring_stride, ring_flags);
        if (!ring_map_) throw GlUnavailable("gl backend: cannot map the force readback buffer persistently; run with --backend cpu");
        storage(good_position_, current, 0);       // the watchdog's restore point, verified clean
        storage(candidate_position_, current, 0);  // the next restore point, while its status is in flight
        const GLbitfield status_flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
        storage(status_ring_, std::size_t(status_slots) * 8, status_flags);  // per slot: status, candidate stretch
        status_map_ = glMapNamedBufferRange(status_ring_.id(), 0, status_slots * 8, status_flags);
        if (!status_map_) throw GlUnavailable("gl backend: cannot map the status readback buffer persistently; run with --backend cpu");
        memory_bytes_ = estimate_gl_memory_bytes(scenario);
    }

    SolverOptions options_;
    SolverLoadReport load_report_;
    std::size_t n_ = 0, n_pad_ = 0, memory_bytes_ = 0;
    double dt_ms_ = 0, h_ = 0, time_ms_ = 0;
    int substeps_ = 1;
    float min_rest_length_ = 0;
    float max_rest_length_ = 0;
    bool damped_ = false;
    bool supported_ = false;
    std::array<HandState, hands> hand_{};

    /// Positions and the motion of the last substep (u = x_n − x_{n−1}), two buffers each: index
    /// current_ is read by a substep, next_ written; they swap after it.
    Buffer position_[2], motion_[2], rest_current_, rest_motion_;
    int current_ = 0, next_ = 1;
    Buffer neighbour_, rest_length_, stiffness_, dashpot_, particle_, held_by_, counters_, touched_, held_, held_local_, ring_;
    /// External loads: `load_` per padded particle (N, zero where none); set_loads's scatter list;
    /// positions_of's indices and positions. The two lists grow on demand.
    Buffer load_, load_list_, gather_index_, gathered_;
    std::size_t load_list_bytes_ = 0, gather_capacity_ = 0;
    std::vector<std::int32_t> load_particles_;  ///< the particles of the loads in force, ascending
    std::unique_ptr<PatchStepper> patch_pass_;  ///< a sewn patch's pass, made on first use (patch_pass.h)
    bool patch_pass_refused_ = false;           ///< the driver could not build it
    bool patch_loads_ = false;                  ///< the patch's pass has loads on the tissue
    std::vector<float> rest_position_;  ///< 3 per particle, host copy for begin_grab
    /// Host copies of what upload_step_constants() derives the h- and S-dependent constants from.
    struct ParticleConstants { float mass, inverse_mass_h2; std::int32_t movable; float support_stiffness; float support_point[4]; };
    static_assert(sizeof(ParticleConstants) == 32);  // std430 `Particle` in shaders/solver_shaders.h
    std::vector<ParticleConstants> particle_host_;
    std::vector<double> support_damping_host_;  ///< c_s per particle, N·ms/mm (0 where unsupported)
    std::vector<std::int32_t> uncut_neighbour_;  ///< the neighbour table as loaded (reset_tissue heals cuts)
    StrokeLog strokes_;  ///< what the scalpels swept (Backend::strokes)
    bool blade_swept_ = false;  ///< a cut pass ran since the tissue was last whole (a grab then reads the table)
    std::vector<float> dashpot_host_;           ///< c per table entry, N·ms/mm, rounded to float as the table's
    Program step_program_, after_program_, capture_program_, release_program_, force_program_, strain_program_, cut_program_,
        blade_program_, scatter_program_, gather_program_;
    LatticeFrame lattice_frame_;  ///< the reference solver's (Solver::lattice_frame)
    void* ring_map_ = nullptr;
    std::array<gl::Fence, ring_slots> fences_;
    std::array<std::uint64_t, ring_slots> sequence_of_{};
    std::uint64_t next_sequence_ = 0, latest_sequence_ = 0;
    std::optional<InstrumentForces> latest_;
    // Watchdog (queue_status, poll_status, restore).
    Buffer good_position_, candidate_position_, status_ring_;
    void* status_map_ = nullptr;
    std::array<gl::Fence, status_slots> status_fences_;
    std::uint64_t status_sequence_ = 0, polled_sequence_ = 0, candidate_slot_sequence_ = 0;
    double good_time_ms_ = 0.0, candidate_time_ms_ = 0.0;
    bool candidate_pending_ = false;
    long long substeps_since_snapshot_ = 0;
    int consecutive_restores_ = 0;
    std::deque<Pending> pending_;
    PassTimes times_;
    std::optional<SimulationSurface> surface_;
    double lattice_spacing_ = 1.0;
    ContactSettings contact_;
    std::unique_ptr<PickingPass> picking_;
};

}  // namespace

std::size_t estimate_gl_memory_bytes(const Scenario& scenario) {
    const std::size_t n = scenario.lattice.particles.size(), n_pad = (n + 7) / 8 * 8;
    return 8 * n_pad * 16            // positions and motions: two float4 buffers each, the start state of both, two restore points
           + n_pad * 18 * 4 * 4      // neighbour, rest length, stiffness, dashpot c/h
           + n_pad * 32 + n_pad * 4  // particle constants (with the support spring), held-by
           + n_pad * 16              // external loads
           + n * (2 * 4 + 2 * 4 + 2 * 24)  // touched lists, held lists and their local coordinates
           + ring_slots * ring_stride + status_slots * 8 + sh::counter_words * 4;
}

std::unique_ptr<Backend> make_gl_backend(GlContext& context, const Scenario& scenario, const SolverOptions& options) {
    require_runnable(scenario, "scenario");
    context.make_current();
    auto backend = std::make_unique<GlBackend>(scenario, options);
    backend->set_software(is_software_rasteriser(context.info()));
    return backend;
}

unsigned gl_position_buffer(const Backend& backend) {
    // The backend that simulates is a wrapper's inner one (Backend::simulating), never a wrapper:
    // of those, only the gl backend says it is one.
    const Backend& simulating = backend.simulating();
    return simulating.kind() == BackendKind::gl ? static_cast<const GlBackend&>(simulating).position_buffer() : 0;
}

}  // namespace heartsim
