/// @file window_run.h
/// @brief The window mode's loop (docs/runtime.md "Window mode"): mouse and keyboard, the
/// simulation paced to the wall clock (on its own thread with the cpu backend, window_simulation.h),
/// frames drawn from the latest state, the title with the real-time factor.
#pragma once

#include "runtime/backend.h"
#include "runtime/gl/gl_context.h"
#include "runtime/haptics/haptic_run.h"
#include "runtime/gl/renderer.h"
#include "runtime/stepping.h"
#include "runtime/trajectory.h"

#include "formats/scenario.h"

#include <atomic>
#include <ctime>
#include <functional>
#include <string>

namespace heartsim {

struct WindowRunOptions {
    std::string scenario_name;      ///< for the title
    std::string scenario_path;      ///< the P key's screenshots go beside it
    std::string screenshot;         ///< OUT.png; with screenshot_every, numbered frames too
    int screenshot_every = 0;       ///< also OUT-000123.png after every N steps
    double draw_share = 0.1;        ///< drawing takes at most this fraction of the wall clock (cpu backend)
    const std::atomic<bool>* interrupted = nullptr;  ///< ends the loop when set (Ctrl-C)
    /// > 0 (--seconds): once the mass scale has changed (and with it the step), the run ends where
    /// the simulated time reaches this, ms, rather than after `steps`.
    double end_ms = 0.0;
    /// Said after the backend's name in the HUD: why it is the one simulating (e.g. "OpenGL is
    /// software"); empty: nothing.
    std::string backend_note;
    /// The scenario run: with a septal defect, the HUD says at most once a second whether the
    /// patch closes it (libmodel/closure.h), and Shift + P's patch is sized to it. Null: neither.
    const Scenario* scenario = nullptr;
    /// What the session does, for the HUD's procedure line (e.g. "scripted: repair.csv").
    std::string procedure;
};

/// Runs the window until Esc, the window is closed, `interrupted`, or `steps` steps (< 0: no
/// limit). `keyboard_hand0`: the arrow keys move hand 0 (no trajectory). The stepping core
/// (runtime/stepping.h) steps its backend, with its haptic session where it has one (the
/// devices move the instruments), paces it, opens the drawn mesh along the strokes before each
/// frame and offers the frame to the live link. Returns what run_scripted would.
ScriptedRunResult run_window(GlContext& context, Stepper& stepper, Renderer& renderer, Trajectory& trajectory, bool keyboard_hand0,
                             int steps, const WindowRunOptions& options);

/// SCENARIO-YYYYmmdd-HHMMSS`ending` beside `scenario` (the .h5) at `local_time`, with -2, -3, …
/// appended while that name, or its recording journal (NAME.journal), exists already.
std::string timestamped_path(const std::string& scenario, const std::tm& local_time, const std::string& ending);

/// The P key's screenshot: SCENARIO-YYYYmmdd-HHMMSS.png beside `scenario` (the .h5) at
/// `local_time`, with -2, -3, … appended when that name exists already.
std::string timestamped_screenshot(const std::string& scenario, const std::tm& local_time);

/// OUT.png → OUT-000123.png for step 123.
std::string numbered_screenshot(const std::string& path, long long step);

}  // namespace heartsim
