/// @file run_modes.h
/// @brief The modes of `heartsim run` (docs/runtime.md, docs/haptics.md): a scripted headless
/// run, a headless haptic session, the window (with or without haptic devices) and the replay
/// of a recording. main.cpp fills RunArguments from the command line, prepares the run and
/// calls one mode; each prints what the command prints and returns its exit status.
///
///     PreparedRun run(arguments);          // checks, scenario, backend, renderer, instruments
///     return headless_scripted_mode(arguments, run);
#pragma once

#include "libmodel/surgery/incision_state.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/gl_context.h"
#include "runtime/gl/renderer.h"
#include "runtime/core/real_time.h"
#include "runtime/link/slicer_link.h"
#include "runtime/core/trajectory.h"

#include "formats/recording.h"
#include "formats/scenario.h"
#include "runtime/surgery/repair.h"

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// The options of `heartsim run`, as main.cpp's CLI11 definitions fill them. An option whose
/// absence means something of its own is optional: nullopt when not given.
struct RunArguments {
    std::string scenario;
    bool headless = false;
    std::optional<std::string> backend;  ///< gl or cpu; nullopt: gl, or cpu for --replay and on a software rasteriser with --device
    std::optional<int> steps;            ///< nullopt: 1 headless, no limit in a window; 0 is the rest state
    double seconds = 0.0;
    std::string probe, grab, trajectory, save_state;
    std::vector<double> gravity;  ///< --gravity X Y Z, mm/ms²; empty = the scenario's
    std::optional<double> mass_scale;    ///< --mass-scale S (fixed explicit mass scaling); nullopt: 1, or --real-time auto's choice
    std::optional<std::string> real_time;  ///< --real-time auto|off; nullopt: real_time_default()
    bool stats = false;
    std::string stats_csv;           // --stats-csv FILE: the --stats table as CSV, one row per pass
    std::optional<std::string> contact;  ///< probe contacts: direct | picking | search (runtime/backend/contact.h); nullopt: direct, or a replay's own
    std::optional<int> picking_refresh;  ///< the picking buffer is rendered every K force requests; nullopt: 1
    // Rendering (docs/runtime.md "Rendering"): screenshots, window, view.
    std::string screenshot;          // OUT.png: the last frame
    int screenshot_every = 0;        // also OUT-000123.png after every N steps (numbered by step)
    double draw_share = 0.1;         // the window draws at most this fraction of the wall clock (cpu backend)
    std::string size;                // WxH pixels of the window or the offscreen frame
    std::optional<std::string> view;  ///< --view; nullopt: the --trajectory's planned view (trajectory.h) when no --eye or --look-at is given, else anterior
    std::string surface_detail = "on";  // --surface-detail on|off: the coronary arteries and the fibres (docs/runtime.md)
    std::string clip;                // --clip PX,PY,PZ,NX,NY,NZ or centre: the section view (section_plane.h); empty: none
    std::string look_at;             // --look-at X,Y,Z[,DISTANCE]: the camera centred on a point (camera.h); empty: the fitted view
    std::string eye;                 // --eye X,Y,Z: with --look-at, where the camera stands (camera.h LookAt::eye)
    // Haptics (docs/haptics.md): devices for hand 0 and hand 1, their instruments, the session.
    std::vector<std::string> devices, instruments;
    double haptic_rate = 1000.0;
    std::optional<double> max_force;     ///< N; nullopt: each device's own maximum
    std::string interpolation = "hold";
    bool coupling = false;
    std::string haptic_priority = "realtime";
    std::optional<std::string> record;
    std::string replay;
    double replay_tolerance = -1.0;  // < 0: exact for a cpu recording replayed on cpu, else 10 % of the largest force
    std::vector<std::string> device_options_given;  // --max-force, --haptic-rate, --interpolation, --coupling, --haptic-priority as typed
    // The live link to 3D Slicer (runtime/link/slicer_link.h, docs/runtime.md "Live link to 3D Slicer").
    std::string igtl;                 // --igtl PORT | HOST:PORT; empty: none
    std::optional<double> igtl_wait;  // --igtl-wait S: wait up to S s for Slicer before the first step
    std::optional<double> igtl_mesh_rate;  // --igtl-mesh-rate HZ: cap on the mesh messages (default 20)
    std::optional<std::string> igtl_bind;   // --igtl-bind ADDRESS: where --igtl PORT listens (default 127.0.0.1)
    std::optional<std::string> igtl_frame;  // --igtl-frame ras|lps: the coordinates sent (default ras)
    // The repair of a septal defect (runtime/surgery/repair.h, docs/runtime.md "Closing a defect").
    std::string patch_material = "pericardium";  // --patch-material
    double leak_test_mmhg = 75.0;                // --leak-test: the pressure the closure check holds the patch to (a child's systolic difference)

    static constexpr const char* default_contact = "direct";
    static constexpr int default_picking_refresh = 1;
    /// --real-time when not given: auto for the window and haptic sessions (they follow the wall
    /// clock), off for scripted headless runs, replays and a fixed --mass-scale.
    RealTimeMode real_time_mode() const {
        if (real_time) return parse_real_time_mode(*real_time);
        return replay.empty() && !mass_scale && (!headless || !devices.empty()) ? RealTimeMode::automatic : RealTimeMode::off;
    }
    /// The contact mode and picking refresh the run uses (the defaults where not given).
    std::string contact_mode() const { return contact.value_or(default_contact); }
    int picking_refresh_every() const { return picking_refresh.value_or(default_picking_refresh); }
};

/// What every mode starts from. The constructor checks the arguments (InputError), reads the
/// scenario, opens the GL context where one is needed (a window unless --headless), makes the
/// backend and the renderer (where frames are seen: a window or a screenshot), sets the probe
/// contacts, and scripts the instruments (--trajectory, --probe, --grab, or the window's
/// keyboard probe); it prints the run's first lines.
struct PreparedRun {
    explicit PreparedRun(const RunArguments& arguments);
    PreparedRun(const PreparedRun&) = delete;
    PreparedRun& operator=(const PreparedRun&) = delete;

    // The renderer and the backend are declared after the context, so their GL objects are
    // deleted while it still exists.
    Scenario scenario;
    std::optional<Recording> replayed;  ///< --replay's recording, read before the backend is made
    int frame_width = 0, frame_height = 0;  ///< pixels of the window or the offscreen frame
    ViewDirection view = ViewDirection::anterior;
    bool surface_detail = true;  ///< the coronary arteries and the fibres drawn where the scenario gives them
    /// The gl backend was asked for by default but the OpenGL device is a software rasteriser: a
    /// window or haptic session simulates on the cpu backend instead (make_context_and_backend).
    bool software_gl = false;
    std::optional<GlContext> context;
    BackendKind kind = BackendKind::gl;
    std::unique_ptr<Backend> backend;
    std::optional<Renderer> renderer;
    int steps = 0;               ///< steps to run; 0 the rest state, < 0 no limit (a window)
    Trajectory trajectory;
    bool keyboard_hand0 = false;  ///< the window's arrow keys move hand 0
    /// --igtl: the live link to 3D Slicer, bound before the scenario is read and started last.
    std::unique_ptr<SlicerLink> link;
    /// The detailed mesh as the scalpel opened it; made at the first stroke (open_incisions).
    std::unique_ptr<IncisionState> incisions;
    /// The backend as a RepairBackend (runtime/surgery/repair.h) where the scenario can hold a patch; else null.
    RepairBackend* repair = nullptr;
    /// The closure check at the end of the run (report_closure), for --save-state.
    struct ClosureReport {
        ClosureResult result;
        DefectFrame frame;
        std::vector<std::array<float, 3>> tested_patch;  ///< the patch after the leak test
        double rim_offset_mm = 0.0, margin_mm = 0.0;
    };
    std::optional<ClosureReport> closure;
    std::uint64_t previewed_strokes = 0;              ///< the stroke log's version the last preview showed
    std::chrono::steady_clock::time_point previewed;  ///< when (preview_incisions)
};

/// Opens the detailed mesh along the scalpel strokes the backend logged that are finished (the
/// blade lifted), or all of them with `finish` (the end of a run), and has the renderer draw it;
/// prints a line each time. `positions` and `strokes`: the backend's, read from it when null (a
/// window whose simulation runs on its own thread passes the copies it drew). Returns whether the drawn mesh changed. Nothing to do without a mapped visual mesh.
bool open_incisions(PreparedRun& run, bool finish, const std::vector<std::array<float, 3>>* positions = nullptr,
                    const StrokeLog* strokes = nullptr);

/// A window, while a blade is down: at most four times a second, the drawn mesh opened as far as
/// the blade has gone (IncisionState::preview; the stroke opens for good when it lifts, through
/// open_incisions). Arguments as open_incisions'. Returns whether the drawn mesh changed.
bool preview_incisions(PreparedRun& run, const std::vector<std::array<float, 3>>* positions = nullptr, const StrokeLog* strokes = nullptr);

/// --replay: the recording's tool poses and grabs, step by step, on the backend; compares the
/// forces with the recorded ones. 0 when they agree within the tolerance, 5 when not.
int replay_mode(const RunArguments& arguments, PreparedRun& run);
/// --headless with --device: the haptic session for --seconds of wall clock or --steps steps,
/// the simulation following real time; Ctrl-C ends it cleanly. 0, or 4 when a device faulted.
int headless_haptic_mode(const RunArguments& arguments, PreparedRun& run);
/// The window, with the haptic devices of --device if any, until it is closed or `run.steps`.
/// 0, or 4 when a device faulted.
int window_mode(const RunArguments& arguments, PreparedRun& run);
/// --headless: `run.steps` steps along the scripted instruments, with numbered screenshots
/// after every --screenshot-every steps. 0.
int headless_scripted_mode(const RunArguments& arguments, PreparedRun& run);

/// `heartsim recover JOURNAL [-o OUT.h5]`: the journal a killed `--record` session left
/// (OUT.h5.journal) written as its recording, to `output` or, when empty, the journal's name
/// without `.journal`; then the journal is deleted. 0; InputError when the journal is in use,
/// is not one, or holds no step.
int recover_recording(const std::string& journal, const std::string& output);

}  // namespace heartsim
