/// @file haptic_run.h
/// @brief `heartsim run … --device SPEC [--device SPEC]`: opens the devices, runs a HapticSession
/// beside the simulation at real time, records the session (`--record`), and replays a recording
/// (`--replay`). The device thread is haptics.h's; this is the simulation side and the command
/// line's vocabulary. The pacing of its steps (and the mass scale) is the stepping core's
/// (runtime/core/stepping.h Stepper::step_to_real_time). docs/haptics.md.
///
///     HapticRun run(backend, scenario, "pat1.h5", settings, {.headless = true});
///     run.start();
///     while (…) if (run.ms_until_next_step() <= 0) run.step(), run.drain();  // tools → backend → step → forces → devices
///     run.finish(result);                       // stops the thread, prints the table, writes --record
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/haptics/haptics.h"
#include "runtime/view/camera.h"
#include "runtime/backend/instrument_shape.h"
#include "runtime/core/trajectory.h"

#include "formats/recording.h"
#include "formats/recording_journal.h"

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim::haptics {

/// A --device argument: `scripted:FILE` (CSV pose script, or a recording .h5 with an optional
/// `@HAND`), `simulated:FILE` (docs/haptics.md "Simulated device file"), `mouse`, or
/// `openhaptics[:NAME]`. Throws InputError naming the argument.
struct DeviceSpec {
    enum class Kind { scripted, simulated, mouse, openhaptics } kind = Kind::scripted;
    std::string argument;  ///< the file or the device name (may be empty for mouse / openhaptics)
    std::string text;      ///< the whole spec as given
};
DeviceSpec parse_device_spec(const std::string& text);

/// The simulated device file: optional settings rows, then the hand force rows
///     start_mm, X, Y, Z          (world frame; default 0, 0, 0)
///     mass_g, M                  (default 50)
///     damping_n_ms_per_mm, B     (default 0.02)
///     max_force_n, F             (default 3.3)
///     workspace_mm, X0, Y0, Z0, X1, Y1, Z1   (default: the start ± 80, 60, 35 mm)
///     time_ms, fx, fy, fz        (header, optional)
///     0, 0, 0, -0.05             (hand force, N, piecewise linear, held after the last row)
SimulatedDeviceSettings parse_simulated_device(const std::string& text, const std::string& name);
SimulatedDeviceSettings read_simulated_device(const std::filesystem::path& path);

/// The device poses of one hand of a recording as a pose script (scripted:REC.h5@HAND), its
/// times counted from the recording's start (that of its first simulation step).
std::vector<PoseKeyframe> recorded_pose_script(const Recording& recording, int hand, const std::string& name);

/// A patch's semi-axes when none are given (mm): a disc 18 mm across and 0.5 mm thick, larger
/// than the stitch circle of a 10 mm defect (runtime/surgery/repair_plan.h: D + 2·rim).
inline const Eigen::Vector3d default_patch_semi_axes_mm{9.0, 9.0, 0.25};
/// A needle's semi-axes when none are given (mm): a shaft 12 mm long from the tip along the tool's
/// +z, 0.5 mm thick (as heartsim plan-repair's needle).
inline const Eigen::Vector3d default_needle_semi_axes_mm{0.25, 0.25, 6.0};

/// `--instrument KIND[:AX,AY,AZ]`: probe, grabber, retractor, scalpel, patch or needle, semi-axes mm (default
/// 1.5 lattice spacings; a scalpel's, a patch's and a needle's defaults are the constants above and
/// default_blade_semi_axes_mm). Button 1 grabs with a grabber, lowers a scalpel's blade, lays a
/// patch (runtime/surgery/repair.h) and ties a stitch with a needle. Throws OptionError naming the argument
/// and the option by its meaning ({HapticRunSettings::instruments}: heartsim spells it --instrument).
Instrument parse_instrument(const std::string& text, double default_semi_axis_mm);

struct HapticRunSettings {
    std::vector<std::string> devices;      ///< one or two --device specs: hand 0, hand 1
    std::vector<std::string> instruments;  ///< per hand; default probe for hand 0, grabber for hand 1
    HapticSettings session{};              ///< rate, interpolation, coupling, safety (max force)
    std::string record;                    ///< --record OUT.h5 ("" = none)
    std::string contact = "direct";        ///< recorded with the session
    std::string patch_material = "pericardium";  ///< --patch-material, recorded with the session
};

struct HapticRunContext {
    bool headless = true;
    /// Where devices with their own frame (mouse, openhaptics) are placed: the camera's view.
    Camera camera{};
    /// Checks an --instrument the run can hold (a patch or a needle needs a surface for a patch
    /// to lie on: the program's rule), given the instrument and the words that name it in an
    /// error; throws to refuse. Empty: every instrument is taken.
    std::function<void(const Instrument& instrument, const std::string& what)> check_instrument{};
};

/// The simulation side of a haptic session. Not thread-safe: one thread (the main one) calls
/// everything; the devices run on the session's thread.
class HapticRun {
public:
    HapticRun(Backend& backend, const Scenario& scenario, const std::string& scenario_name, const HapticRunSettings& settings,
              const HapticRunContext& context);
    ~HapticRun();
    HapticRun(const HapticRun&) = delete;
    HapticRun& operator=(const HapticRun&) = delete;

    /// Starts the device thread; the simulation clock starts with it.
    void start();
    /// One step: newest tool poses → backend (button 1 of a grabber, retractor, scalpel, patch or needle hand
    /// turning on → begin_grab, off → release) → step → forces → devices; recorded. Returns the
    /// step's report.
    StepReport step();
    /// Milliseconds until the next step is due (≤ 0: now).
    double ms_until_next_step() const;
    /// The real time owed since start(), pauses excluded, ms (the session clock).
    double owed_ms() const;
    /// The simulated time since start(), ms.
    double simulated_ms() const;
    /// An event of the session's recording at the session clock now (e.g. "mass_scale": the
    /// stepping core changed the mass scale); nothing while nothing records.
    void record_event(const char* what);
    /// step() calls so far (a step the watchdog restored counts: --steps limits these).
    std::size_t rows() const { return rows_; }
    /// Window pause: the real-time reference stops, so resuming does not race to catch up.
    void set_paused(bool paused);
    /// Empties the device thread's tick queue (recording) and reports device faults; step()
    /// does it after every step, a paused window every frame.
    void drain();
    /// True when a device reported a fault (its force is held at zero); heartsim exits 4.
    bool device_faulted() const;
    /// Stops the device thread (forces fade first), prints the haptic-rate table, writes --record
    /// and deletes its journal.
    void finish(ScriptedRunResult& result);

    /// The instruments to draw (tool poses and buttons as the simulation last used them).
    std::vector<InstrumentShape> shapes() const;
    /// The mouse device, if one was given (the window moves it).
    WindowDevice* window_device() const { return window_device_; }
    HapticSession& session() { return *session_; }
    const ScriptedRunResult& result() const { return result_; }
    bool uses_hand(int hand) const { return hands_[hand].device != nullptr; }
    /// The hand's instrument now; read from any thread (K switches it on the thread that steps).
    InstrumentKind instrument(int hand) const { return shown_kind_[hand].load(); }
    /// The window's K, Shift + P and Shift + N: `hand`'s instrument becomes `instrument`, or, when
    /// it holds one of that kind, its own again (--instrument's); the next step places it afresh,
    /// its predecessor's grab released, when it differs from the instrument the last step held;
    /// a button held through the switch acts at its next press. Called on the
    /// thread that steps, between steps; a recording keeps it (/steps/instrument), so a replay
    /// switches at the same step. Returns the kind now held.
    InstrumentKind toggle_instrument(int hand, const Instrument& instrument);
    /// The hand's device description for printing.
    std::string describe(int hand) const;
    /// The hand's --device spec as given ("mouse", "simulated:FILE", …); fixed once constructed.
    const std::string& device_spec(int hand) const { return hands_[hand].spec.text; }
    /// The forces last published to the devices (world frame, N, before safety and coupling): the
    /// tissue's force on each instrument. Read by the thread that steps.
    const InstrumentForces& latest_published_forces() const { return last_published_forces_; }
    /// The largest force the hand's device is sent, N (--max-force or the device's own maximum).
    double max_force_n(int hand) const { return recording_.hands[hand].max_force_n; }

    /// A recording started and stopped from the window (F5, docs/haptics.md "Recording from the
    /// window"); a window session only (not headless), and not with --record (records_session()).
    /// Called on the thread that steps, between steps. start_recording puts the tissue back to
    /// its rest state (grabs released: what T does), places the instruments afresh at the next
    /// step, and records from that step on into a new Recording, its journal `path`.journal:
    /// so the recording starts from the rest state at its step 0 and `--replay` reproduces it.
    /// Throws (the journal cannot be made) with nothing started.
    void start_recording(const std::string& path);
    /// Writes the recording start_recording began (atomically, its .xmf2 beside it) and deletes
    /// its journal; returns the steps written. Throws OutputError when the write fails (the
    /// journal stays for `heartsim recover`); the recording is off afterwards either way.
    std::size_t stop_recording();
    /// --record records the whole session (the window's toggle is off).
    bool records_session() const { return !settings_.record.empty(); }
    /// A recording from the window is on; where it goes.
    bool window_recording() const { return window_recording_; }
    const std::string& recording_path() const { return record_path_; }

private:
    struct Hand {
        std::unique_ptr<Device> device;
        DeviceSpec spec;
        Instrument instrument;
        Instrument own;  ///< --instrument's, which a second K, Shift + P or Shift + N gives back
        Instrument stepped;  ///< the instrument the last step held (a different one is placed afresh)
        InstrumentPose pose;  ///< last applied
        bool placed = false, grabbing = false;
        bool wait_release = false;  ///< button 1 was held when the instrument changed: ignored until let go
        std::uint32_t buttons = 0;
        std::uint64_t presses = 0;    ///< ToolSample::presses the last step saw
        std::uint64_t bad_poses = 0;  ///< device poses not applied (non-finite or out of range)
        std::string fault;            ///< a device fault, once reported
    };
    void poll_device_faults();
    /// Hands the rows recorded since the last chunk to the journal (serialised here, written by its thread).
    void journal_rows();
    /// The period and latency figures, the end event and the ticks into recording_, then
    /// writes it to record_path_ and deletes the journal; returns the steps written.
    std::size_t write_recording_now();

    Backend& backend_;
    HapticRunSettings settings_;
    std::array<Hand, 2> hands_;
    std::array<std::atomic<InstrumentKind>, 2> shown_kind_{InstrumentKind::none, InstrumentKind::none};
    WindowDevice* window_device_ = nullptr;
    InstrumentForces last_published_forces_{};
    std::unique_ptr<HapticSession> session_;
    Recording recording_;
    Recording recording_header_;  ///< recording_'s attributes and hands, no rows (a window recording starts from it)
    std::string record_path_;     ///< where recording_ goes: --record, or the window's recording
    bool window_recording_ = false;
    std::size_t record_first_row_ = 0;  ///< rows_ at the recording's step 0
    std::vector<TickRecord> ticks_;
    /// --record's journal (OUT.h5.journal): what a killed session keeps. A chunk every
    /// journal_period_ms of the session clock, so at most the last second is lost.
    std::unique_ptr<RecordingJournal> journal_;
    static constexpr double journal_period_ms = 500.0;
    std::size_t journaled_steps_ = 0, journaled_ticks_ = 0, journaled_events_ = 0;
    double journaled_at_ms_ = 0.0;
    bool journal_failure_reported_ = false;
    static constexpr std::size_t ring = 64;
    std::array<long long, ring> step_of_request_{};  ///< force request number mod ring → step index
    std::array<double, ring> step_tool_time_{};      ///< step index mod ring → tool sample time used
    std::uint64_t requests_ = 0, last_published_request_ = ~std::uint64_t(0);
    ScriptedRunResult result_;
    double start_sim_ms_ = 0.0, wall_start_ms_ = 0.0, last_step_wall_ms_ = 0.0;
    std::array<std::uint64_t, 65> latency_steps_{};  ///< published forces by pose → force steps (64 = more)
    bool recording_on_ = false, last_estop_ = false, last_fresh_ = false, finished_ = false, paused_ = false;
    std::size_t rows_ = 0;
    double paused_at_ms_ = 0.0;
};

/// Applies a hand's tool for one step exactly as the live session does (the replay uses the same
/// function, so a cpu replay reproduces the forces bit for bit): the first time places the
/// instrument; a grab flag that turns begins or releases the grab at the current pose; then the
/// pose the step should reach.
void apply_tool(Backend& backend, int hand, const Instrument& instrument, const InstrumentPose& pose, bool grab, bool& placed,
                bool& grabbing);

struct ReplayResult {
    std::size_t steps = 0;
    std::size_t compared = 0;        ///< step forces compared (steps with force_step ≥ 0 and a used hand)
    std::size_t identical = 0;       ///< of those, bit for bit equal
    double max_difference_n = 0.0;   ///< max |f_replay − f_recorded| over compared forces
    double rms_difference_n = 0.0;   ///< root mean square of |f_replay − f_recorded|
    double max_force_n = 0.0;        ///< max |f_recorded|
    long long worst_step = -1;
    double wall_ms = 0.0;
};

/// Replays `recording` on `backend` step by step (recorded tool poses and grabs), computing the
/// forces after every step, and compares them with the recorded ones. Throws InputError when the
/// recording was made on a different scenario (particle count, step). `after_step`, when given,
/// runs after each step (the detailed mesh opened where a stroke ended: run_modes.h open_incisions).
ReplayResult replay(Backend& backend, const Recording& recording, const std::string& recording_name,
                    const std::function<void()>& after_step = {});

}  // namespace heartsim::haptics
