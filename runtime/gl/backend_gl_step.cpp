// The gl backend's step (runtime/gl/backend_gl_impl.h): the substeps' passes with the probes
// and grabs, the scalpel's cut and blade passes and the strokes it logs, and the watchdog that
// reads each step's status late, without waiting, and puts the last verified state back.
#include "runtime/gl/backend_gl_impl.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace heartsim::gl_backend {

void GlBackend::reset_tissue() {
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

StepReport GlBackend::step(int steps) {
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
        const double radius = (hand_[probe_hands[q]].instrument.semi_axes.maxCoeff() + max_reach_beyond_) * (1 + 1e-3) + 1e-3;
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
        if (cell_count_ > 0) run_cell_pass();  // the volume term (Solver::cell_pass): the step adds each particle's slots
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

void GlBackend::cut(const BladeSweep& sweep, int hand) {
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

void GlBackend::blade(int hand, const BladeStep& r) {
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

void GlBackend::clear_blade(int hand) {
    const GLuint zero = 0;
    glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::cut0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::blade0 + sh::blade_words * unsigned(hand)) * 4),
                              GLsizeiptr(sh::blade_words * 4), GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
}

std::vector<std::array<std::int32_t, 2>> GlBackend::cut_springs() {
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

void GlBackend::queue_status() {
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

bool GlBackend::poll_status() {
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

void GlBackend::forget_status() {
    for (auto& fence : status_fences_) fence.reset();
    polled_sequence_ = status_sequence_;
    candidate_pending_ = false;
    substeps_since_snapshot_ = 0;
}

void GlBackend::place_tissue(const Buffer& positions, const Buffer* motion) {
    for (int hand = 0; hand < hands; ++hand) release_hand(hand, false);
    free_stayed();  // before the start motion is copied: rest_motion_ is the scenario's again
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

void GlBackend::restore(StepReport& report) {
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

void GlBackend::harvest_queries(bool wait) {
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

}  // namespace heartsim::gl_backend
