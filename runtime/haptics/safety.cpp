// ForceSafety (safety.h): the last chain before any device. Design: docs/haptics.md.
#include "runtime/haptics/safety.h"

#include "libmodel/errors.h"

#include <cmath>

namespace heartsim::haptics {

namespace {

/// Scales v down to |v| ≤ limit (direction kept); true when it had to.
bool clamp_norm(Eigen::Vector3d& v, double limit) {
    const double n = v.norm();
    if (n > limit) {
        v *= limit / n;
        return true;
    }
    return false;
}

}  // namespace

ForceSafety::ForceSafety(const SafetySettings& settings, double device_max_force_n) : settings_(settings) {
    if (!(device_max_force_n > 0.0) || !std::isfinite(device_max_force_n))
        throw InputError("haptics: a device's maximum force must be positive and finite");
    max_force_ = settings.max_force_n > 0.0 ? std::min(settings.max_force_n, device_max_force_n) : device_max_force_n;
    if (!(settings.fade_out_ms > 0.0) || !(settings.fade_in_ms > 0.0) || !(settings.max_rate_n_per_ms > 0.0))
        throw InputError("haptics: fade times and the force rate limit must be positive");
}

Eigen::Vector3d ForceSafety::filter(const SafetyInput& in) {
    ++counters_.ticks;
    const double dt = started_ ? std::clamp(in.now_ms - last_ms_, 0.0, 1000.0) : 0.0;
    started_ = true;
    last_ms_ = in.now_ms;

    // 1. Non-finite → zero.
    Eigen::Vector3d f = in.force_n;
    const bool non_finite = !f.allFinite();
    if (non_finite) {
        ++counters_.non_finite;
        f.setZero();
    }
    // 2. Clamp to the maximum force.
    if (clamp_norm(f, max_force_)) ++counters_.clamped;
    // 3. Rate limit against the previous limited value.
    Eigen::Vector3d step = f - limited_;
    if (clamp_norm(step, settings_.max_rate_n_per_ms * dt)) ++counters_.rate_limited;
    limited_ += step;
    if (!limited_.allFinite()) limited_.setZero();

    // 4. Gain: faults latch until faded out and a clean update arrived.
    if (in.fault_event) {
        latched_fault_ = true;
        if (in.divergence) ++counters_.faults;
    } else if (latched_fault_ && gain_ <= 0.0 && in.clean_update) {
        latched_fault_ = false;
    }
    const bool healthy = in.simulation_fresh && !non_finite && !latched_fault_ && !estop_;
    if (healthy) gain_ = std::min(1.0, gain_ + dt / settings_.fade_in_ms);
    else gain_ = std::max(0.0, gain_ - dt / settings_.fade_out_ms);

    // 5. Emergency stop: zero now.
    if (estop_) {
        ++counters_.stopped;
        gain_ = 0.0;
        limited_.setZero();
        return Eigen::Vector3d::Zero();
    }
    // 6. Last check.
    Eigen::Vector3d out = gain_ * limited_;
    if (!out.allFinite() || out.norm() > max_force_ * (1.0 + 1e-12)) out.setZero();
    return out;
}

}  // namespace heartsim::haptics
