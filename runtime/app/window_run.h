/// @file window_run.h
/// @brief The window mode's loop (docs/runtime.md "Window mode"): mouse and keyboard, the
/// simulation paced to the wall clock (on its own thread with the cpu backend, window_simulation.h),
/// frames drawn from the latest state, the title with the real-time factor.
#pragma once

#include "runtime/app/output_names.h"

#include "runtime/backend/backend.h"
#include "runtime/gl/gl_context.h"
#include "runtime/haptics/haptic_run.h"
#include "runtime/gl/renderer.h"
#include "runtime/core/stepping.h"
#include "runtime/core/trajectory.h"

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
    /// patch closes it (libmodel/surgery/closure.h), and Shift + P's patch is sized to it. Null: neither.
    const Scenario* scenario = nullptr;
    /// What the session does, for the HUD's procedure line (e.g. "scripted: repair.csv").
    std::string procedure;
};

/// Runs the window until Esc, the window is closed, `interrupted`, or `steps` steps (< 0: no
/// limit). `keyboard_hand0`: the arrow keys move hand 0 (no trajectory). The stepping core
/// (runtime/core/stepping.h) steps its backend, with its haptic session where it has one (the
/// devices move the instruments), paces it, opens the drawn mesh along the strokes before each
/// frame and offers the frame to the live link. Returns what run_scripted would.
ScriptedRunResult run_window(GlContext& context, Stepper& stepper, Renderer& renderer, Trajectory& trajectory, bool keyboard_hand0,
                             int steps, const WindowRunOptions& options);


}  // namespace heartsim
