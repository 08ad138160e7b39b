/// @file window_input.h
/// @brief The window's mouse and keyboard (docs/runtime.md "Window mode"): what the GLFW
/// callbacks write (WindowInput), the mouse haptic device moved by the mouse and the keys, the
/// section view's keys. The window's loop (window_run.cpp) reads the requests once a frame.
#pragma once

#include "runtime/gl/renderer.h"
#include "runtime/haptics/haptics.h"

#include <array>
#include <chrono>
#include <cstdio>

struct GLFWwindow;

namespace heartsim {

/// The keys that move instrument 0 (→ ← ↑ ↓, PgUp, PgDn), kept by the key callback between
/// frames: every press counts and so does the time each key is held, however slow the frames
/// (on llvmpipe a frame can take a second). The loop takes what they owe (take_key_motion).
struct MovementKeys {
    using Clock = std::chrono::steady_clock;
    static constexpr int count = 6;
    /// A press moves at least as much as this hold, s (a tap between two frames counts).
    static constexpr double tap_s = 0.1;
    /// The longest stretch counted at once, s: a stall of the program (a key held while it hung,
    /// released after) does not throw the instrument away. Longer than a slow frame.
    static constexpr double longest_stretch_s = 2.0;
    std::array<bool, count> down{};
    std::array<bool, count> slow{};  ///< Shift was held at the press: 5x slower
    std::array<Clock::time_point, count> pressed_at{}, counted_to{};
    std::array<double, count> owed_s{};  ///< held seconds not yet moved (Shift's at a fifth)
    bool report = false;                 ///< say each release (a keyboard instrument or the mouse device moves)
};

/// The index of a movement key in MovementKeys (GLFW_KEY_RIGHT, …), or -1.
int movement_key_index(int glfw_key);
/// A press or release of movement key `index` at `now` (a release says how long it was held when
/// keys.report).
void movement_key_event(MovementKeys& keys, int index, bool press, bool slow, MovementKeys::Clock::time_point now);
/// Counts the held keys' time up to `now` (also while the loop waits between frames).
void count_held_keys(MovementKeys& keys, MovementKeys::Clock::time_point now);
/// What the keys owe up to `now`, in seconds of motion along the view frame's axes (x right,
/// y up, z out of the screen), and owes nothing after.
Eigen::Vector3d take_key_motion(MovementKeys& keys, MovementKeys::Clock::time_point now);

/// The window's mouse and keyboard state (GLFW callbacks write it).
struct WindowInput {
    Renderer* renderer = nullptr;
    double last_x = 0, last_y = 0;
    bool orbiting = false, panning = false, paused = false;
    // The mouse haptic device (--device mouse): Ctrl + left drag moves it in the view plane,
    // Ctrl + wheel in depth, G toggles its button 1 (grab), E the emergency stop.
    haptics::WindowDevice* device = nullptr;
    haptics::HapticSession* session = nullptr;
    haptics::DevicePose device_pose;
    bool dragging_device = false, estop = false;
    // Ctrl + Shift + left click: the mouse device onto the tissue's surface under the cursor;
    // held and dragged, it slides along the surface (`surface_offset_mm` from it).
    bool sliding_device = false;
    /// Where the mouse device goes from the surface point, towards the eye, mm: a quarter of its
    /// instrument's smallest semi-axis below it (pressing); a scalpel's or needle's tip on it; a
    /// patch 2 mm in front of it (laid, it drapes onto the surface along the view).
    double surface_offset_mm = -0.5;
    int surface_moves = 0;              ///< slides since the click (for the line said at release)
    /// The simulation has stepped the mouse device where the window put it (position and buttons)
    /// since the last input that moved it or pressed its button.
    bool device_in_place = false;
    bool reset_tissue = false;  ///< T: the tissue back to its rest state before the next step
    bool show_hud = true, show_help = false;  ///< F2 / Tab, H / F1
    bool show_figures = false;  ///< I: the HUD's figures (real time, fps, steps/s, particles, backend, mass scale)
    int single_steps = 0;       ///< N while paused: steps asked for, not yet handed on
    bool screenshot = false;    ///< P: write the window as seen after the next frame
    bool toggle_recording = false;  ///< F5: start or stop a recording (haptic sessions)
    bool toggle_scalpel = false;    ///< K: instrument 0 to the scalpel and back (haptic sessions)
    bool toggle_patch = false;      ///< Shift + P: instrument 0 to a patch and back (haptic sessions)
    bool toggle_needle = false;     ///< Shift + N: instrument 0 to a needle and back (haptic sessions)
    bool redraw = false;            ///< C, [, ], V: the section changed; draw the next frame now
    MovementKeys movement;          ///< arrows, PgUp / PgDn: presses and held time since the last frame
};

/// An event line on stdout at once (tests and logs read it while the window runs).
template <class... Args>
void say(const char* format, Args... args) {
    std::printf(format, args...);
    std::fflush(stdout);
}

/// Sets the window's mouse, motion, wheel and key callbacks, which write `input` (it must outlive
/// the window's loop), and takes the cursor's position now.
void install_input_callbacks(GLFWwindow* window, WindowInput& input);

/// G or Ctrl + right click: the mouse device's button 1 (a grabber closes or opens, a scalpel's
/// blade goes down or up, …); "in place" follows once the simulation has stepped with it.
void toggle_device_button(WindowInput& in);

/// An input moved the mouse device. Where the simulation had it where the window put it, that
/// ends ("moving" is said); "in place" is said once the simulation has stepped it at the new
/// place. A log (a test) that reads both knows when the simulation has taken an input in.
void device_moved(WindowInput& in);


}  // namespace heartsim
