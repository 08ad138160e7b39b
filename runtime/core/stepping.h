/// @file stepping.h
/// @brief The stepping core that every mode of `heartsim run` drives (docs/runtime.md "The
/// stepping core"): the headless scripted run, the headless haptic session, the window's GL loop,
/// the window's simulation thread (window_simulation.h) and the replay. One Stepper per run owns
/// what each step or frame does besides the solver's own work:
///
///   - the pacing: the real time owed (OwedClock, pauses excluded), the steps it has room for,
///     a haptic session's steps to its clock (step_to_real_time);
///   - `--real-time auto`: the one MassScaleGovernor of the run (runtime/core/real_time.h), observed
///     after steps, measuring afresh after a pause;
///   - a scripted step: the hands posed as run_scripted poses them, the step, the force pass;
///   - the detailed mesh opened where a scalpel's blade lifted (the program's open/preview hooks,
///     run_modes.h open_incisions);
///   - the live link to 3D Slicer: the state offered when a frame is due, the final state;
///   - a haptic session's recording: a change of the mass scale is an event of its recording.
///
///     Stepper stepper(backend, {.real_time_auto = true, .link = link, .open_incisions = open});
///     options.on_step = stepper.scripted_on_step(trajectory, wall_start, screenshots);  // headless
///     stepper.step_to_real_time(100);                                                   // haptics
///     stepper.finish_link(steps, hands);
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/backend/instrument_shape.h"
#include "runtime/link/slicer_link.h"
#include "runtime/core/trajectory.h"

#include <array>
#include <chrono>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

namespace heartsim {

class MassScaleGovernor;
namespace haptics {
class HapticRun;
}

/// The real time owed to the simulation: the wall clock since the start less the time paused.
class OwedClock {
public:
    using Clock = std::chrono::steady_clock;
    /// At `now`, with the run `paused` or not: the owed time, ms (frozen while paused).
    double owed_ms(bool paused, Clock::time_point now);

private:
    Clock::time_point start_ = Clock::now(), paused_at_{};
    double paused_total_ms_ = 0;
    bool paused_ = false;
};

class Stepper {
public:
    /// The drawn detailed mesh opened (or previewed) along the scalpel's strokes, at `positions`
    /// with `strokes` (both null: the backend's own). Returns whether the drawn mesh changed.
    using IncisionHook = std::function<bool(const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes)>;

    struct Settings {
        /// --real-time auto: the governor steers the backend's mass scale.
        bool real_time_auto = false;
        /// --igtl: the live link (null: none).
        SlicerLink* link = nullptr;
        /// The repair as the link sends it (made only when a mesh is sent); empty: none.
        SlicerLink::PatchSource link_patch;
        /// Opens the drawn mesh along the strokes whose blade lifted (run_modes.h open_incisions).
        IncisionHook open_incisions;
        /// While a blade is down: the drawn mesh opened as far as it has gone (a window's frames).
        IncisionHook preview_incisions;
        /// A started haptic session whose devices move the instruments (null: scripted hands).
        haptics::HapticRun* haptic = nullptr;
    };

    Stepper(Backend& backend, Settings settings);
    ~Stepper();
    Stepper(const Stepper&) = delete;
    Stepper& operator=(const Stepper&) = delete;

    Backend& backend() { return backend_; }
    haptics::HapticRun* haptic() const { return settings_.haptic; }
    SlicerLink* link() const { return settings_.link; }

    // ---- Pacing and --real-time auto ------------------------------------------------------

    /// The whole steps of the backend's step (it changes with the mass scale) that fit in
    /// `owed_ms` beyond `simulated_ms`, 0 to 10^6.
    int steps_owed(double owed_ms, double simulated_ms) const;
    /// After steps: the real time owed (pauses excluded) and the simulated time, both from the
    /// run's start. When the governor changes the mass scale it prints the line that says so
    /// (and a recording keeps the event); returns whether it did. Nothing without --real-time auto.
    bool observe(double owed_ms, double simulated_ms);
    /// A pause (or a reset, a stall): the governor measures afresh from the next observe().
    void restart_measuring();

    // ---- Steps ----------------------------------------------------------------------------

    /// One step of scripted hands (the window's loops): step `step` of `clock`, each hand the
    /// trajectory uses posed as run_scripted poses it, except hand 0 with `keyboard_hand0`, which
    /// takes `hand0` where given; then the step and, where a hand is used, the force pass
    /// (`forces`: its result when it has arrived).
    StepReport step_scripted(ScriptedHands& hands, const Trajectory& trajectory, StepClock& clock, long long step, bool keyboard_hand0,
                             const std::optional<InstrumentPose>& hand0, std::optional<InstrumentForces>& forces);
    /// The headless scripted run's ScriptedRunOptions::on_step: after each step, the mesh opened
    /// where a blade lifted, then `extra` (the numbered screenshots), then the governor (the wall
    /// clock since `wall_start`), then the link's frame when due.
    std::function<void(int, const StepReport&)> scripted_on_step(const Trajectory& trajectory, std::chrono::steady_clock::time_point wall_start,
                                                                  std::function<void(int, const StepReport&)> extra);
    /// A haptic session: steps until the simulated time reaches the session clock, at most
    /// `max_steps` and for about `max_wall_ms` (one step may overrun it), the ticks drained and
    /// the governor observed after each; returns how many ran (0 at once when ahead).
    int step_to_real_time(int max_steps, double max_wall_ms = 10.0);
    /// A haptic session in a window: paused, its real-time reference stops (and the governor
    /// measures afresh on resuming).
    void set_paused(bool paused);

    // ---- The detailed mesh along the scalpel's strokes ------------------------------------

    /// After steps: the mesh opened along the strokes whose blade lifted. Returns whether it changed.
    bool open_incisions(const std::vector<std::array<float, 3>>* positions = nullptr, const StrokeLog* strokes = nullptr);
    /// Before a window's frame: opened where a blade lifted, else previewed as far as it has gone.
    void open_or_preview_incisions(const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes);

    // ---- The live link to 3D Slicer -------------------------------------------------------

    /// Whether the link would send now (false without one).
    bool link_due() const;
    /// The backend's state after `steps` steps, when a frame is due; `patch` replaces the
    /// settings' patch source where given.
    void offer(long long steps, const SlicerLinkHands& hands, SlicerLink::State state, const SlicerLink::PatchSource& patch = {});
    /// The same from a state taken elsewhere (the window's latest positions at `time_ms`).
    void offer(double time_ms, const std::vector<std::array<float, 3>>& positions, long long steps, const SlicerLinkHands& hands,
               SlicerLink::State state, const SlicerLink::PatchSource& patch = {});
    /// The run is over: the final state to the link, if any.
    void finish_link(long long steps, const SlicerLinkHands& hands);

private:
    Backend& backend_;
    Settings settings_;
    std::unique_ptr<MassScaleGovernor> governor_;
    bool paused_ = false;
};

}  // namespace heartsim
