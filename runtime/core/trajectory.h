/// @file trajectory.h
/// @brief Scripted instruments: a CSV of instrument keyframes per hand (the scripted-replay
/// device), and the loop that drives a Backend along it, step by step, identically for every
/// backend (so backends can be compared on the same gesture).
///
/// CSV columns (header line optional, `#` starts a comment; units mm, ms, world frame LPS):
///     time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab
/// kind is probe, grabber, retractor, scalpel, patch, needle or none ("grab" reads as grabber);
/// (x, y, z) the tool position, q its orientation (tool → world, normalised on use), (ax, ay, az)
/// the ellipsoid's semi-axes (a scalpel: the blade from the tip along the tool's +z, 2·az long, ax
/// and ay its half-width and half-thickness), grab 1 while the grabber or retractor holds, the
/// scalpel's blade is lowered and cuts, the patch is laid or the needle ties. A retractor holds as a
/// grabber; when its grab turns 0, or its hand takes another kind or semi-axes while it holds, the
/// tissue it held stays anchored where it is (Backend::release) until the tissue is reset.
/// Between two keyframes of a hand the pose moves linearly (position) and by slerp (orientation);
/// kind, semi-axes and grab switch at a keyframe's time and hold until the next. Toward a keyframe
/// whose kind or semi-axes differ the pose holds: an instrument does not travel to where the next
/// one is placed (a retractor holding until the hand takes a patch stays where it holds).
///
/// A whole-line comment `# view: OPTIONS` records the view the trajectory is planned to be seen
/// from (Trajectory::view), OPTIONS as heartsim run's view options take it (camera.h
/// view_options: `# view: --view surgeon --eye X,Y,Z --look-at X,Y,Z`); heartsim run starts there
/// when given none of --view, --eye and --look-at. At most one such line; any other comment is
/// ignored.
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/view/camera.h"

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace heartsim {

struct InstrumentKeyframe {
    double time_ms = 0.0;
    int hand = 0;
    InstrumentKind kind = InstrumentKind::none;
    InstrumentPose pose;
    Eigen::Vector3d semi_axes{2.0, 2.0, 2.0};  ///< mm
    bool grab = false;
};

struct Trajectory {
    std::vector<InstrumentKeyframe> keyframes;  ///< sorted by time within each hand
    /// The view it is planned to be seen from (the CSV's `# view:` line); nullopt: none recorded.
    std::optional<PlannedView> view;
    bool uses_hand(int hand) const;
    /// The keyframe state of `hand` at `time_ms` (pose interpolated toward the next keyframe, held
    /// when that one's kind or semi-axes differ; the rest from the keyframe at or before, or the
    /// first one before the script starts). Requires uses_hand(hand).
    InstrumentKeyframe at(int hand, double time_ms) const;
    /// Appends a keyframe (the planners' scripts build a trajectory with it, then sort_by_time).
    void add(double time_ms, int hand, InstrumentKind kind, const Eigen::Vector3d& position, const Eigen::Quaterniond& orientation,
             const Eigen::Vector3d& semi_axes, bool grab);
    /// Orders the keyframes by time, keeping the order of those at the same time.
    void sort_by_time();
};

/// Checks one keyframe by the rules a trajectory CSV's rows are read by (a finite time, a position
/// within plausible::coordinate_mm, a non-zero finite orientation, semi-axes within
/// plausible::semi_axis_mm, grab only on a kind that takes it). Throws InputError prefixed with
/// `where`.
void check_keyframe(const InstrumentKeyframe& keyframe, const std::string& where);
/// check_keyframe on every keyframe of a plan before it is written, so a planner never writes what
/// `heartsim run --trajectory` refuses. Throws OptionError naming the keyframe and the rule.
void check_planned_trajectory(const Trajectory& trajectory);

/// Reads a trajectory CSV. Throws InputError naming the file, line and column on a bad row, and
/// the file and line on a `# view:` line that parse_view_options refuses or that comes twice.
Trajectory read_trajectory(const std::filesystem::path& path);
/// Parses CSV text (the same format); `name` is used in error messages.
Trajectory parse_trajectory(const std::string& text, const std::string& name);
/// Writes `trajectory` as that CSV, after `comments` (whole `#` lines, each ending in a line break)
/// and its view's `# view:` line where it has one: what read_trajectory reads back, every number
/// to the last bit (%.17g; the view's floats in the fewest digits that read back the same). Written atomically
/// (formats/atomic_file.h): an old file at `path` is replaced whole or, when the write fails, left
/// as it was; OutputError naming the file and the cause ("No space left on device").
void write_trajectory_csv(const Trajectory& trajectory, const std::filesystem::path& path, const std::string& comments = "");

/// A fixed probe or grabber from the command line: "X,Y,Z,AX,AY,AZ" (mm), a grabber optionally
/// followed by ",DX,DY,DZ", the distance it pulls over the run. Throws OptionError naming
/// {fixed_probe} or {fixed_grabber} (heartsim's --probe, --grab) when it is not one.
InstrumentKeyframe parse_fixed_instrument(const std::string& text, InstrumentKind kind, int hand);

struct ScriptedRunOptions {
    int steps = 0;                    ///< backend steps of time_step_ms() each
    bool forces_every_step = true;    ///< queue the force pass after each step (asynchronous readback)
    std::function<void(int step, const StepReport&)> on_step{};  ///< optional, after each step
    /// > 0: once the step has changed on the way (--real-time auto with --seconds), stop where the
    /// simulated time reaches this (ms from the run's start) instead of after `steps`.
    double end_ms = 0.0;
};

struct ScriptedRunResult {
    int steps = 0;
    long long substeps = 0;
    double wall_ms = 0.0;
    std::size_t watchdog_events = 0;
    std::string last_watchdog_message;
    std::size_t forces_received = 0;  ///< asynchronous readbacks that had finished when polled
    /// The watchdog gave up (StepReport::gave_up): the run stopped stepping; heartsim exits 6.
    bool gave_up = false;

    /// Counts one step() call's report.
    void add(const StepReport& report) {
        steps += report.steps;
        substeps += report.substeps;
        if (report.diverged) ++watchdog_events, last_watchdog_message = report.message;
        gave_up = gave_up || report.gave_up;
    }
};

/// Drives `backend` along `trajectory` for `options.steps` steps. Before step k (time t = k·dt):
/// a hand whose kind or semi-axes change gets set_instrument and is placed at its pose at t; a
/// grab flag turning on calls begin_grab at t, turning off calls release; then set_pose with the
/// pose at t + dt, reached at the end of the step (the pose at t when the kind or semi-axes at
/// t + dt differ: the instrument of the step stays where it is until the next one is placed).
/// The simulated start and end of each step of a run whose step may change on the way (mass
/// scaling, runtime/core/real_time.h): step k starts where the steps before it ended. While the step
/// does not change these are k·dt and (k + 1)·dt, to the bit.
class StepClock {
public:
    explicit StepClock(double dt_ms) : dt_(dt_ms) {}
    /// Step `step` (counted from 0) of length `dt_ms`, the backend's step now.
    std::pair<double, double> at(long long step, double dt_ms) {
        if (dt_ms != dt_) {
            origin_ += double(step - origin_step_) * dt_;
            origin_step_ = step;
            dt_ = dt_ms;
        }
        return {origin_ + double(step - origin_step_) * dt_, origin_ + double(step + 1 - origin_step_) * dt_};
    }
    /// The step has changed during the run (then a run for a simulated time ends by time, not by
    /// the count of steps it began with).
    bool changed() const { return origin_step_ > 0; }

private:
    double dt_, origin_ = 0.0;
    long long origin_step_ = 0;
};

/// Applies a trajectory's keyframes to a backend step by step, remembering what each hand holds:
/// (re)places a hand whose kind or semi-axes change, begins or releases a grab when the flag
/// turns, then sets the pose the solver should reach by the end of the step. Shared by the
/// headless run (run_scripted) and the window loop.
class ScriptedHands {
public:
    explicit ScriptedHands(const Trajectory& trajectory) : trajectory_(trajectory) {}
    /// Before the step from t_ms to t_next_ms, for `hand` (skipped if the trajectory never uses it).
    void apply(Backend& backend, int hand, double t_ms, double t_next_ms);
private:
    struct Applied {
        bool active = false;
        InstrumentKind kind = InstrumentKind::none;
        Eigen::Vector3d semi_axes = Eigen::Vector3d::Zero();
        bool grab = false;
    };
    const Trajectory& trajectory_;
    Applied applied_[2];
};

ScriptedRunResult run_scripted(Backend& backend, const Trajectory& trajectory, const ScriptedRunOptions& options);

}  // namespace heartsim
