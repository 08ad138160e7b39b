/// @file window_simulation.h
/// @brief The window's simulation on its own thread (cpu backend): paced to the wall clock, never
/// ahead of real time and never one step per frame; the window draws at its own rate from the
/// latest positions it asks for. Scripted or keyboard instruments, or a haptic session (its steps
/// to real time, so drawing never stalls the forces). With a repair (runtime/surgery/repair.h), the patch
/// and its stitches are copied with the positions. Each step goes through the stepping core
/// (runtime/core/stepping.h: the hands, the pacing, --real-time auto). docs/runtime.md "Window mode".
///
///     WindowSimulation simulation(stepper, trajectory, {.keyboard_hand0 = true, .steps = -1});
///     simulation.set_keyboard_pose(pose);              // hand 0 from the arrow keys
///     if (simulation.latest(positions)) renderer.render(positions, shapes);
///     WindowSimulation::Status s = simulation.status(); // simulated time, steps, RTF
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/haptics/haptic_run.h"
#include "runtime/gl/renderer.h"
#include "runtime/surgery/repair.h"
#include "runtime/core/stepping.h"
#include "runtime/core/trajectory.h"

#include <array>
#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace heartsim {

struct WindowSimulationOptions {
    bool keyboard_hand0 = false;  ///< hand 0 follows set_keyboard_pose instead of the trajectory
    long long steps = -1;         ///< stop after this many steps (< 0: until destroyed)
    /// > 0 (--seconds): once the mass scale has changed (and with it the step), the run ends where
    /// the simulated time reaches this, ms, rather than after `steps`.
    double end_ms = 0.0;
};

class WindowSimulation {
public:
    struct Status {
        double simulated_ms = 0;      ///< simulated time
        double owed_ms = 0;           ///< real time since the start, pauses excluded
        long long attempted = 0;      ///< step() calls, restored ones too
        ScriptedRunResult run;        ///< what the steps did, as run_scripted reports it (wall_ms unset)
        bool finished = false;        ///< the step limit was reached, or the watchdog gave up
        std::vector<InstrumentShape> shapes;  ///< a haptic session's instruments as last applied
        long long resets = 0;         ///< tissue resets done (request_reset_tissue)
        bool paused = false;          ///< the thread has seen the pause: no step runs until resumed (or step_once)
        bool has_forces = false;      ///< forces holds a force pass's result (the haptic session's last published, with one)
        std::array<Eigen::Vector3d, 2> forces{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};  ///< per hand, N, world
        double haptic_period_p99_ms = -1;  ///< a haptic session's device period p99 so far, ms (< 0: none yet)
        double mass_scale = 1.0;      ///< the backend's mass scale after the last step
        /// The keyboard's hand 0 (set_keyboard_pose): its position at the last step, mm; none before.
        std::optional<Eigen::Vector3d> keyboard_position_mm;
        /// Simulated per real time over the run so far (1 when it keeps up).
        double real_time_factor() const { return owed_ms > 0 ? simulated_ms / owed_ms : 1.0; }
    };

    /// Starts the thread. `stepper` (its backend) and `trajectory` must outlive this object and
    /// are stepped by the thread only (the caller must not step or pose the backend meanwhile).
    WindowSimulation(Stepper& stepper, const Trajectory& trajectory, const WindowSimulationOptions& options);
    /// The stepper's haptic session (started) steps to real time on the thread; the caller must
    /// not touch the session until this object is destroyed (then HapticRun::finish()).
    WindowSimulation(Stepper& stepper, const WindowSimulationOptions& options);
    ~WindowSimulation();  ///< stops and joins
    WindowSimulation(const WindowSimulation&) = delete;
    WindowSimulation& operator=(const WindowSimulation&) = delete;

    void set_keyboard_pose(const InstrumentPose& pose);
    /// While paused the simulation stops and the paused time is not owed afterwards.
    void set_paused(bool paused);
    void request_reset_tissue();
    /// A haptic session: runs `action` on the simulation's thread between two steps (in the
    /// order asked; the window's recording toggle, which must happen on a step boundary).
    void run_between_steps(std::function<void()> action);
    /// While paused: one step (the hands posed for it as usual). Not with a haptic session (ignored).
    void request_single_step();
    /// The newest positions (N×3, mm): asks the thread for a copy after its next step and waits
    /// for it (at most one step). False once the thread has stopped and nothing new exists.
    bool latest(std::vector<std::array<float, 3>>& positions);
    /// The scalpel strokes as of the positions latest() returned last (Backend::strokes, copied
    /// on the thread when they changed).
    StrokeLog strokes() const;
    /// The repair's patch and stitches as of the positions latest() returned last (drawn_patch
    /// of RepairBackend::patch and stitch_anchors, copied on the thread); no triangles while no
    /// patch is laid or the backend holds no repair.
    DrawnPatch patch() const;
    Status status() const;

private:
    void run();
    void run_haptic();
    void copy_strokes();       ///< with the mutex held: the backend's stroke log, if it changed, and the patch
    void publish_start();      ///< the positions before the first step
    void publish_if_wanted();  ///< with the mutex held
    bool finish_at_limit();    ///< with the mutex held: true (and the final state published) at the step limit

    Stepper& stepper_;
    Backend& backend_;
    RepairBackend* repair_ = nullptr;  ///< backend_ as a RepairBackend, where it is one
    std::optional<ScriptedHands> hands_;
    const Trajectory* trajectory_ = nullptr;
    haptics::HapticRun* haptic_ = nullptr;
    WindowSimulationOptions options_;
    double start_mass_scale_ = 1.0;
    std::thread thread_;

    mutable std::mutex mutex_;
    std::condition_variable published_;
    bool stop_ = false, paused_ = false, reset_ = false, want_positions_ = false, fresh_ = false;
    int single_steps_ = 0;
    std::vector<std::function<void()>> actions_;  ///< run_between_steps, not yet run
    InstrumentPose keyboard_pose_;
    bool keyboard_set_ = false;
    std::vector<std::array<float, 3>> positions_;
    StrokeLog strokes_, published_strokes_;  ///< the thread's copy, and the one of the positions handed out
    DrawnPatch patch_, published_patch_;     ///< the same for the repair
    Status status_;
};

}  // namespace heartsim
