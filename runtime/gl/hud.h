/// @file hud.h
/// @brief The window's heads-up display (docs/runtime.md "Window mode"), drawn over the scene with
/// Dear ImGui (kept inside hud.cpp): the case, its defect and the procedure, each hand's device,
/// instrument and force with a bar against the device's maximum, the session's figures on I, the repair's patch and whether it closes the
/// defect, a red banner while the emergency stop is
/// latched, the orientation axes (LPS), a scale bar in mm, force arrows at the instruments, and
/// the key help (window_keys.h). Display only: it takes no input.
///
///     Hud hud(glfw_window);                       // the window's context current
///     renderer.present(width, height);
///     hud.draw(state, renderer.camera(), width, height);
///     glfwSwapBuffers(glfw_window);
#pragma once

#include "runtime/gl/renderer.h"
#include "runtime/view/png.h"
#include "runtime/view/window_keys.h"

#include <Eigen/Core>

#include <array>
#include <string>

namespace heartsim {

/// One hand as the HUD shows it.
struct HudHand {
    bool used = false;
    std::string device;       ///< e.g. "mouse", "simulated:press.csv", "script", "keyboard"
    std::string instrument;   ///< "probe", "grabber"
    bool has_force = false;   ///< false: the force is not known here (shown as such)
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();  ///< world frame, N
    std::string force_source = "on the instrument";      ///< or "sent to the device" (after safety)
    double max_force_n = 0;   ///< the bar's full scale, N (the device's maximum or --max-force); 0: no bar
    bool grabbing = false;
    Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();  ///< the instrument's centre, world LPS (arrow origin)
};

/// A septal defect's repair as the HUD shows it (runtime/surgery/repair.h), once a patch is laid.
struct HudRepair {
    bool laid = false;          ///< a patch is laid: "patch: MATERIAL, N stitches"
    std::string material;       ///< PatchMaterial::name, e.g. "pericardium"
    std::size_t stitches = 0;
    bool defect = false;        ///< the scenario has a defect: its closure line too
    bool checked = false;       ///< the closure check has run (before: "checking")
    bool known = false;         ///< it ran to a yes or a no (else it could not tell: "cannot tell", never read as closed)
    bool closed = false;        ///< ClosureResult::closed (false where it cannot tell)
    double rim_gap_mm = 0;      ///< ClosureResult::largest_rim_gap_mm
    std::string leak;           ///< where it leaks (leak_place: "between stitches 3 and 4"); empty when closed
};

/// What the HUD shows in one frame.
struct HudState {
    bool show_hud = true, show_help = false;
    bool show_figures = false;     ///< I: the figures below too (real time, fps, steps/s, particles, backend, mass scale)
    std::string case_name;         ///< the scenario (its file name): the panel's first line
    std::string defect;            ///< its septal defect (e.g. "ventricular septal defect (VSD), 10 mm across"); empty: none
    std::string procedure;         ///< how the instruments are driven (WindowRunOptions::procedure); empty: no line
    double real_time_factor = 1, frames_per_s = 0, steps_per_s = 0, simulated_ms = 0;
    std::size_t particles = 0;
    std::string backend;
    double mass_scale = 1.0;       ///< shown with its cost when not 1 (--real-time auto, --mass-scale)
    bool paused = false;
    bool emergency_stop = false;   ///< latched: the banner
    bool recording = false;        ///< F5's recording is on: a red "REC" line
    bool section = false;          ///< the section view is on (C): a line with where its plane is
    double section_depth_mm = 0;   ///< the plane beyond the heart's centre, mm (SectionPlane::depth_from)
    Eigen::Vector3d section_normal = Eigen::Vector3d::Zero();  ///< unit, world LPS: the removed side
    double haptic_period_p99_ms = -1;  ///< < 0: not available
    std::array<HudHand, 2> hands;
    HudRepair repair;
    WindowKeySession keys;         ///< the help lists the keys that work in this session
};

/// The key help as the last frame laid it out (window pixels, y down from the top).
struct HudHelpLayout {
    bool shown = false;
    std::size_t rows = 0;      ///< keys listed (those that work in the session)
    bool details = true;       ///< each key's details too (false: its action only, when they would not fit)
    float top = 0, bottom = 0; ///< the help window's top and bottom edges
    float last_row_bottom = 0; ///< the bottom of the table's last row
};

class Hud {
public:
    /// Sets Dear ImGui up on `glfw_window` (a GLFWwindow*, its context current). It installs no
    /// GLFW callbacks (the window's own stay).
    explicit Hud(void* glfw_window);
    ~Hud();
    Hud(const Hud&) = delete;
    Hud& operator=(const Hud&) = delete;

    /// Draws `state` over the current default framebuffer, `width`×`height` pixels, projecting
    /// world points with `camera` (axes, scale bar, force arrows). Nothing when neither the HUD
    /// nor the help is on.
    void draw(const HudState& state, const Camera& camera, int width, int height);
    /// The help's layout in the last frame drawn (shown false while the help is off).
    const HudHelpLayout& help_layout() const { return help_layout_; }

private:
    void frame(const HudState& state, const Camera& camera, int width, int height, bool render);
    bool hud_shown_ = false, help_shown_ = false;
    double largest_force_n_ = 0;  ///< the force arrows' scale follows the largest force so far
    HudHelpLayout help_layout_;
};

/// A scale bar length, mm: the 1-2-5 series value whose length on screen is nearest to
/// `target_pixels` at `mm_per_pixel`.
double scale_bar_mm(double mm_per_pixel, double target_pixels);

}  // namespace heartsim
