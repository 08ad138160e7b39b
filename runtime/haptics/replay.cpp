// The replay of a recording (haptic_run.h replay, docs/haptics.md "Recording and replay"): the
// recorded tool poses and grabs applied step by step exactly as the live session applied them
// (apply_tool, haptic_run.cpp), the forces compared with the recorded ones.
#include "runtime/haptics/haptic_run.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>

namespace heartsim::haptics {

ReplayResult replay(Backend& backend, const Recording& recording, const std::string& name, const std::function<void()>& after_step) {
    if (recording.particles != std::int64_t(backend.size()))
        throw InputError(name + ": recorded on " + recording.scenario + " with " + std::to_string(recording.particles) +
                         " particles; this scenario has " + std::to_string(backend.size()));
    const double step = backend.load_report().unscaled_dt_ms;  // at mass scale 1, as recorded
    if (std::abs(recording.dt_ms - step) > 1e-12 * recording.dt_ms) {
        char text[160];
        std::snprintf(text, sizeof text, "recorded with a step of %.17g ms; this scenario's step is %.17g ms", recording.dt_ms, step);
        throw InputError(name + ": " + text + " (another scenario, or other solver settings)");
    }
    if (!recording.hands[0].used && !recording.hands[1].used) throw InputError(name + ": the recording has no hand (/hand0, /hand1): nothing to replay");
    std::array<Instrument, 2> instruments;
    for (int i = 0; i < 2; ++i) instruments[i] = recording.instrument_at(0, i);
    const RecordedSteps& s = recording.steps;
    ReplayResult result;
    const auto start = std::chrono::steady_clock::now();
    std::vector<InstrumentForces> forces;
    forces.reserve(s.size());
    std::array<bool, 2> placed{false, false}, grabbing{false, false};
    for (std::size_t k = 0; k < s.size(); ++k) {
        // The mass scale the live step ran with (--real-time auto changes it between steps).
        if (s.mass_scale_at(k) != backend.options().mass_scale) backend.set_mass_scale(s.mass_scale_at(k));
        for (int i = 0; i < 2; ++i) {
            // An instrument changed in the window (K, Shift + P, Shift + N): placed afresh, its
            // predecessor's grab released, as the live step did.
            if (const Instrument now = recording.instrument_at(k, i); !(now == instruments[i]))
                instruments[i] = now, placed[i] = false, grabbing[i] = false;
            // Exactly where the live step applied the hand's tool (not before its first usable pose).
            if (!recording.hands[i].used || !s.applied[k][i]) continue;
            const auto& p = s.tool_position_mm[k][i];
            const auto& q = s.tool_orientation[k][i];
            InstrumentPose pose;
            pose.position = Eigen::Vector3d(p[0], p[1], p[2]);
            pose.orientation = Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
            apply_tool(backend, i, instruments[i], pose, s.grab[k][i] != 0, placed[i], grabbing[i]);
        }
        backend.step(1);
        forces.push_back(backend.instrument_forces());
        ++result.steps;
        if (after_step) after_step();
    }
    for (std::size_t k = 0; k < s.size(); ++k) {
        const long long from = s.force_step[k];
        if (from < 0) continue;
        for (int i = 0; i < 2; ++i) {
            if (!recording.hands[i].used) continue;
            const Eigen::Vector3d recorded(s.force_n[k][i][0], s.force_n[k][i][1], s.force_n[k][i][2]);
            const Eigen::Vector3d again = forces[std::size_t(from)].hand[i].force_n;
            // A non-finite difference counts as infinite (never as a match).
            const double d = std::isfinite((again - recorded).norm()) ? (again - recorded).norm() : std::numeric_limits<double>::infinity();
            ++result.compared;
            result.rms_difference_n += d * d;
            if (again == recorded) ++result.identical;
            result.max_force_n = std::max(result.max_force_n, recorded.norm());
            if (d > result.max_difference_n || result.worst_step < 0) result.max_difference_n = std::max(d, result.max_difference_n), result.worst_step = (long long)k;
        }
    }
    if (result.compared == 0)
        throw InputError(name + ": no recorded force to compare (no step has forces: /steps/force_step is −1 throughout)");
    if (result.compared) result.rms_difference_n = std::sqrt(result.rms_difference_n / double(result.compared));
    result.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return result;
}

}  // namespace heartsim::haptics
