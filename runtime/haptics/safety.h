/// @file safety.h
/// @brief ForceSafety: the chain every force passes on the device thread before a device gets it
/// (non-finite, clamp, rate limit, fades, emergency stop). Implementation: safety.cpp.
#pragma once

#include <Eigen/Core>

#include <cstdint>

namespace heartsim::haptics {

struct SafetySettings {
    double max_force_n = 0.0;          ///< 0 = the device's limit; never above it
    double max_rate_n_per_ms = 0.5;    ///< |Δf| per ms (3.3 N in 6.6 ms)
    double stall_ms = 30.0;            ///< no new simulation force for this long = stalled
    double fade_out_ms = 40.0;         ///< gain 1 → 0 (≤ 50 ms by requirement)
    double fade_in_ms = 100.0;         ///< gain 0 → 1 once healthy again
};

/// What the device thread knows about the simulation this tick.
struct SafetyInput {
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();  ///< candidate, device frame (may be NaN)
    double now_ms = 0.0;
    bool simulation_fresh = false;  ///< a new force arrived within stall_ms
    bool fault_event = false;       ///< the simulation diverged or was reset since the last tick
    bool clean_update = false;      ///< a new force arrived this tick, with no fault since the previous
    /// The fault event is a divergence (the watchdog restored the state), counted in
    /// Counters::faults; a reset (T, F5, the end of a session's fade-out) fades the same way but is
    /// no fault of the simulation and is not counted.
    bool divergence = false;
};

/// The chain every force passes on the device thread before any device gets it:
///  1. non-finite → zero (and the gain fades, as for a stall);
///  2. clamp |f| to the maximum force (direction kept);
///  3. rate limit: |Δf| ≤ max_rate·Δt;
///  4. gain g ∈ [0, 1]: falls at 1/fade_out_ms while the simulation is stale, faulted or the input
///     non-finite; a divergence or reset latches the fault until g reached 0 and a clean update
///     arrived; rises at 1/fade_in_ms when healthy;
///  5. emergency stop: zero at once (this tick), latched until released; then fades in;
///  6. a last check: finite and within the maximum, else zero.
class ForceSafety {
public:
    ForceSafety(const SafetySettings& settings, double device_max_force_n);
    Eigen::Vector3d filter(const SafetyInput& input);
    void emergency_stop() { estop_ = true; }
    void release_emergency_stop() { estop_ = false; }
    bool stopped() const { return estop_; }
    double gain() const { return gain_; }
    double max_force_n() const { return max_force_; }

    struct Counters {
        std::uint64_t ticks = 0, clamped = 0, rate_limited = 0, non_finite = 0, faults = 0, stopped = 0;
    };
    const Counters& counters() const { return counters_; }

private:
    SafetySettings settings_;
    double max_force_ = 0.0;
    Eigen::Vector3d limited_ = Eigen::Vector3d::Zero();  ///< after steps 1–3
    double gain_ = 0.0;
    double last_ms_ = 0.0;
    bool started_ = false, latched_fault_ = false, estop_ = false;
    Counters counters_;
};

}  // namespace heartsim::haptics
