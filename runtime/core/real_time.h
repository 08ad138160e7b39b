/// @file real_time.h
/// @brief `--real-time auto`: heartsim measures its own speed and takes the smallest explicit mass
/// scaling S (SolverOptions::mass_scale) from a fixed ladder that keeps the simulation at or
/// above real time with a margin; it re-checks while the run goes on and raises S when the
/// machine slows. docs/runtime.md "Real time", docs/solver.md "Mass scaling".
///
/// Every mode's governor is the stepping core's (runtime/core/stepping.h Stepper::observe): after every
/// step (or a few), observe(wall_ms, simulated_ms); when it returns a line, the mass scale changed.
#pragma once

#include "runtime/backend/backend.h"

#include <array>
#include <optional>
#include <string>

namespace heartsim {

/// `--real-time`: auto (the governor chooses S) or off (S stays what --mass-scale gives, 1 unless).
enum class RealTimeMode { automatic, off };
/// "auto" or "off"; throws OptionError naming {RealTimeMode} otherwise.
RealTimeMode parse_real_time_mode(const std::string& text);

/// The closed-form cost of S for messages and the HUD: "transients 2× slower, forces at rest
/// unchanged" (the critical step and a transient's time scale grow by √S).
std::string mass_scale_cost(double mass_scale);

/// The step and its substeps `backend` would take at mass scale `scale` (what set_mass_scale
/// would take); a scale that needs too many substeps gets an unreachable plan.
ScaledStep planned_step(const Backend& backend, double scale);
/// The real-time factor predicted at mass scale `scale` from `factor` measured at `measured_at`:
/// the wall time of a substep is kept; the simulated time per substep (the step over its
/// substeps, stability.h scaled_step_ms and substeps_for_step) is what S changes.
double predicted_factor(const Backend& backend, double factor, double measured_at, double scale);
/// The smallest S of MassScaleGovernor::ladder, not below `now`, predicted to reach its margin from
/// `factor` measured at `now`; the fastest when none does.
double chosen_mass_scale(const Backend& backend, double factor, double now);
/// The one speed verdict every part gives (`heartsim info`, the window, the governor): from
/// `factor` measured at mass scale `measured_at`, the mass scale --real-time auto takes and the
/// factor predicted there, or, where even the ladder's top falls short, what would keep up
/// (keep_up_advice at the factor predicted there). One clause, no newline.
std::string speed_verdict(const Backend& backend, double factor, double measured_at);

class MassScaleGovernor {
public:
    /// The scalings the governor chooses from, smallest first.
    static constexpr std::array<double, 5> ladder{1.0, 2.0, 4.0, 8.0, 16.0};
    /// The real-time factor a choice must be predicted to reach: 25 % above real time, for the
    /// jitter of a shared machine and the window's drawing.
    static constexpr double margin = 1.25;
    /// The first measurement: this much wall clock from the first observation.
    static constexpr double first_window_ms = 500.0;
    /// Afterwards: the speed over each window of this much wall clock; below real time raises S.
    static constexpr double recheck_window_ms = 2000.0;

    /// Steers `backend`'s mass scale from the next observe() on; S starts at the backend's.
    /// `assumed_factor` > 0 replaces what the governor measures at S = 1 by that real-time
    /// factor (the environment variable HEARTSIM_ASSUME_REAL_TIME_FACTOR: a test double for the
    /// machine's speed, so that tests choose without timing anything).
    explicit MassScaleGovernor(Backend& backend, double assumed_factor = assumed_factor_from_environment());

    /// After steps: the wall clock now (ms, any origin, non-decreasing; the real time owed, pauses
    /// excluded) and the simulated time. A run that kept up with the wall clock over a window is
    /// measured by the time its backend spent stepping (PassTimes), one that fell behind by the
    /// wall clock.
    /// When a measuring window closes it may change the backend's S; then it returns the line
    /// that says so (what was measured, the S taken, its cost). Steps while paused must not be
    /// observed (call restart() on resuming).
    std::optional<std::string> observe(double wall_ms, double simulated_ms);
    /// Starts a new measuring window at the next observe() (after a pause, a reset, a long stall).
    void restart() { window_open_ = false; }

    double mass_scale() const;
    /// The last measured real-time factor (0 before the first window closed).
    double measured_factor() const { return measured_; }
    /// The real-time factor predicted at S from `factor` measured at `measured_at`: the wall time
    /// of a substep is kept; the simulated time per substep (the step over its substeps,
    /// stability.h scaled_step_ms and substeps_for_step) is what S changes.
    double predict(double factor, double measured_at, double scale) const;
    /// The smallest S of the ladder predicted to reach `margin` from `factor` measured at the
    /// current S, never below the current S; the largest when none does.
    double choose(double factor) const;

    static double assumed_factor_from_environment();

private:
    /// The step and its substeps at `scale` (what the backend's set_mass_scale would take).
    ScaledStep plan(double scale) const;
    /// The backend's time spent stepping and gathering forces so far, ms (PassTimes).
    double busy_ms() const;

    Backend& backend_;
    double assumed_factor_ = 0.0;
    bool window_open_ = false, first_done_ = false, told_slow_at_top_ = false;
    double window_wall_ms_ = 0.0, window_simulated_ms_ = 0.0, window_busy_ms_ = 0.0;
    double measured_ = 0.0;
};

}  // namespace heartsim
