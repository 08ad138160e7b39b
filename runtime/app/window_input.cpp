// The window's mouse and keyboard: window_input.h, docs/runtime.md "Window mode".
#include "runtime/app/window_input.h"

#include "runtime/view/section_plane.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>
#include <optional>

namespace heartsim {

/// An input moved the mouse device. Where the simulation had it where the window put it, that
/// ends ("moving" is said); "in place" is said once the simulation has stepped it at the new
/// place. A log (a test) that reads both knows when the simulation has taken an input in.
void device_moved(WindowInput& in) {
    if (!in.device_in_place) return;
    in.device_in_place = false;
    say("mouse device: moving\n");
}

/// G or Ctrl + right click: the mouse device's button 1 (a grabber closes or opens, a scalpel's
/// blade goes down or up, …); "in place" follows once the simulation has stepped with it.
void toggle_device_button(WindowInput& in) {
    in.device_pose.buttons ^= 1u;
    in.device_in_place = false;
    say("mouse device: button 1 %s\n", in.device_pose.buttons & 1u ? "pressed" : "released");
}

namespace {

/// Ctrl + Shift + click and drag: the mouse device onto the tissue's surface point under the
/// cursor, `surface_offset_mm` towards the eye from it (a probe's centre a quarter of its extent
/// below it: a click on the heart rests it on the tissue). False over the background (the device stays
/// where it was).
bool place_on_surface(WindowInput& in, GLFWwindow* window, double x, double y) {
    int width = 0, height = 0;
    glfwGetWindowSize(window, &width, &height);
    const std::optional<Eigen::Vector3f> hit = in.renderer->surface_point(x, y, width, height);
    if (!hit) return false;
    const Eigen::Vector3d point = hit->cast<double>();
    const Eigen::Vector3d to_eye = (in.renderer->camera().eye().cast<double>() - point).normalized();
    in.device_pose.position_mm = point + in.surface_offset_mm * to_eye;
    device_moved(in);
    return true;
}

/// The section view's keys (docs/runtime.md "Section view"). C: on, through the heart's centre
/// facing the view (the nearer half removed), or off.
void toggle_section(Renderer& renderer) {
    if (renderer.section()) {
        renderer.set_section(std::nullopt);
        say("section view: off\n");
        return;
    }
    const SectionPlane plane = section_facing(renderer.camera(), renderer.model_centre());
    renderer.set_section(plane);
    say("section view: on, %s; [ and ] move it, V aims it at the view, C turns it off\n", describe(plane, renderer.model_centre()).c_str());
}

/// [ and ]: the plane along its normal by `mm` (< 0: deeper, more removed).
void move_section(Renderer& renderer, float mm) {
    if (!renderer.section()) {
        say("section view: off; C turns it on\n");
        return;
    }
    renderer.set_section(renderer.section()->moved(mm));
    say("section view: %s\n", describe(*renderer.section(), renderer.model_centre()).c_str());
}

/// V: the plane turned to face the current view, at the same depth from the heart's centre (after
/// an orbit, the cut is seen square on again).
void aim_section(Renderer& renderer) {
    if (!renderer.section()) {
        say("section view: off; C turns it on\n");
        return;
    }
    const Eigen::Vector3f centre = renderer.model_centre();
    const SectionPlane plane = section_facing(renderer.camera(), centre).moved(-renderer.section()->depth_from(centre));
    renderer.set_section(plane);
    say("section view: aimed at the view, %s\n", describe(plane, centre).c_str());
}


}  // namespace

void install_input_callbacks(GLFWwindow* window, WindowInput& input) {
    glfwGetCursorPos(window, &input.last_x, &input.last_y);  // then every motion event keeps them
    glfwSetWindowUserPointer(window, &input);
    glfwSetMouseButtonCallback(window, [](GLFWwindow* w, int button, int action, int mods) {
        auto* in = static_cast<WindowInput*>(glfwGetWindowUserPointer(w));
        const bool down = action == GLFW_PRESS;
        if (button == GLFW_MOUSE_BUTTON_LEFT && in->device && (mods & GLFW_MOD_CONTROL) && (mods & GLFW_MOD_SHIFT)) {
            in->sliding_device = down;
            if (down) {
                in->surface_moves = 0;
                if (place_on_surface(*in, w, in->last_x, in->last_y))
                    say("mouse device: on the surface at (%.2f, %.2f, %.2f) mm\n", in->device_pose.position_mm.x(), in->device_pose.position_mm.y(),
                        in->device_pose.position_mm.z());
                else
                    say("mouse device: no tissue under the cursor\n");
            } else if (in->surface_moves > 0) {
                say("mouse device: slid along the surface to (%.2f, %.2f, %.2f) mm\n", in->device_pose.position_mm.x(),
                    in->device_pose.position_mm.y(), in->device_pose.position_mm.z());
            }
            if (!down) in->orbiting = in->panning = in->dragging_device = false;
            return;
        }
        if (button == GLFW_MOUSE_BUTTON_RIGHT && in->device && (mods & GLFW_MOD_CONTROL)) {
            // Ctrl + right click: the device's button 1, as G (a grabber closes or opens).
            if (down) toggle_device_button(*in);
            return;
        }
        if (button == GLFW_MOUSE_BUTTON_LEFT && in->device && (mods & GLFW_MOD_CONTROL)) in->dragging_device = down;
        else if (button == GLFW_MOUSE_BUTTON_LEFT && !(mods & GLFW_MOD_SHIFT)) in->orbiting = down;
        if (button == GLFW_MOUSE_BUTTON_RIGHT || button == GLFW_MOUSE_BUTTON_MIDDLE || (button == GLFW_MOUSE_BUTTON_LEFT && (mods & GLFW_MOD_SHIFT)))
            in->panning = down;
        if (!down) in->orbiting = in->panning = in->dragging_device = in->sliding_device = false;
        // No glfwGetCursorPos here: it asks the X server where the pointer is *now*, which, when
        // frames are slow and events queue up, is already the end of the drag, and the queued
        // motion events then cancel out (a lost orbit). last_x/last_y follow the motion events
        // in order instead.
    });
    glfwSetCursorPosCallback(window, [](GLFWwindow* w, double x, double y) {
        auto* in = static_cast<WindowInput*>(glfwGetWindowUserPointer(w));
        const float dx = float(x - in->last_x), dy = float(y - in->last_y);
        in->last_x = x, in->last_y = y;
        int width = 0, height = 0;
        glfwGetWindowSize(w, &width, &height);
        if (in->sliding_device) {
            if (place_on_surface(*in, w, x, y)) ++in->surface_moves;
            return;
        }
        if (in->dragging_device) {
            // One pixel = the model's view height / window height at the target's depth.
            const Camera& camera = in->renderer->camera();
            const Eigen::Matrix3d basis = camera.orientation.toRotationMatrix().cast<double>();
            in->device_pose.position_mm += camera.mm_per_pixel(height) * (double(dx) * basis.col(0) - double(dy) * basis.col(1));
            if (dx != 0 || dy != 0) device_moved(*in);
            return;
        }
        if (in->orbiting) in->renderer->camera().orbit(-0.008f * dx, -0.008f * dy);
        if (in->panning) in->renderer->camera().pan(dx, dy, height);
    });
    glfwSetScrollCallback(window, [](GLFWwindow* w, double, double y) {
        auto* in = static_cast<WindowInput*>(glfwGetWindowUserPointer(w));
        if (in->device && (glfwGetKey(w, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS || glfwGetKey(w, GLFW_KEY_RIGHT_CONTROL) == GLFW_PRESS)) {
            const Camera& camera = in->renderer->camera();
            const Eigen::Vector3d back = (camera.orientation * Eigen::Vector3f::UnitZ()).cast<double>();
            in->device_pose.position_mm -= back * (0.02 * camera.radius * y);  // wheel up: into the screen
            if (y != 0) device_moved(*in);
            return;
        }
        in->renderer->camera().zoom(std::pow(0.9f, float(y)));
    });
    glfwSetKeyCallback(window, [](GLFWwindow* w, int key, int, int action, int mods) {
        auto* in = static_cast<WindowInput*>(glfwGetWindowUserPointer(w));
        // The arrows and PgUp / PgDn: each press and the time held, counted as the events come
        // (the loop moves instrument 0 by them; a key repeat changes nothing).
        if (const int index = movement_key_index(key); index >= 0) {
            if (action != GLFW_REPEAT)
                movement_key_event(in->movement, index, action == GLFW_PRESS, (mods & GLFW_MOD_SHIFT) != 0, MovementKeys::Clock::now());
            return;
        }
        // [ and ] move the section plane, 1 mm a press (Shift: 5 mm), and go on while held.
        if ((key == GLFW_KEY_LEFT_BRACKET || key == GLFW_KEY_RIGHT_BRACKET) && action != GLFW_RELEASE) {
            const float step_mm = (mods & GLFW_MOD_SHIFT) ? 5.0f : 1.0f;
            move_section(*in->renderer, key == GLFW_KEY_RIGHT_BRACKET ? -step_mm : step_mm);
            in->redraw = true;
            return;
        }
        if (action != GLFW_PRESS) return;
        if (key == GLFW_KEY_ESCAPE) glfwSetWindowShouldClose(w, GLFW_TRUE);
        if (key == GLFW_KEY_R) in->renderer->reset_camera();
        if (key == GLFW_KEY_SPACE) in->paused = !in->paused;
        const bool shift = (mods & GLFW_MOD_SHIFT) != 0;
        if (key == GLFW_KEY_N && shift) in->toggle_needle = true;
        else if (key == GLFW_KEY_N && in->paused) ++in->single_steps;
        if (key == GLFW_KEY_T) in->reset_tissue = true;
        if (key == GLFW_KEY_P && shift) in->toggle_patch = true;
        else if (key == GLFW_KEY_P) in->screenshot = true;
        if (key == GLFW_KEY_F5) in->toggle_recording = true;
        if (key == GLFW_KEY_K) in->toggle_scalpel = true;
        if (key == GLFW_KEY_C || key == GLFW_KEY_V) {
            if (key == GLFW_KEY_C) toggle_section(*in->renderer);
            else aim_section(*in->renderer);
            in->redraw = true;
        }
        if (key == GLFW_KEY_F2 || key == GLFW_KEY_TAB) in->show_hud = !in->show_hud;
        if (key == GLFW_KEY_H || key == GLFW_KEY_F1) in->show_help = !in->show_help;
        if (key == GLFW_KEY_I) in->show_figures = !in->show_figures;
        if (key == GLFW_KEY_G && in->device) toggle_device_button(*in);
        if (key == GLFW_KEY_E && in->session) {
            in->estop = !in->estop;
            if (in->estop) in->session->emergency_stop();
            else in->session->release_emergency_stop();
            say(in->estop ? "emergency stop latched: every device's force is zero (E releases)\n" : "emergency stop released\n");
        }
    });
}

namespace {

/// The movement keys in MovementKeys' order, their names on the terminal, and where each moves
/// (the view frame: x right, y up, z out of the screen).
constexpr std::array<int, MovementKeys::count> movement_glfw_keys = {GLFW_KEY_RIGHT, GLFW_KEY_LEFT, GLFW_KEY_UP, GLFW_KEY_DOWN,
                                                                     GLFW_KEY_PAGE_UP, GLFW_KEY_PAGE_DOWN};
constexpr std::array<const char*, MovementKeys::count> movement_key_names = {"Right", "Left", "Up", "Down", "PgUp", "PgDn"};

Eigen::Vector3d movement_axis(int index) {
    const std::array<Eigen::Vector3d, MovementKeys::count> axes = {Eigen::Vector3d::UnitX(), -Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(),
                                                                   -Eigen::Vector3d::UnitY(), -Eigen::Vector3d::UnitZ(), Eigen::Vector3d::UnitZ()};
    return axes[std::size_t(index)];
}

double seconds(MovementKeys::Clock::duration d) { return std::chrono::duration<double>(d).count(); }

/// Key `k`'s held time from where it was counted to `now`, at most longest_stretch_s.
void count_key(MovementKeys& keys, std::size_t k, MovementKeys::Clock::time_point now) {
    if (!keys.down[k] || now <= keys.counted_to[k]) return;
    keys.owed_s[k] += std::min(seconds(now - keys.counted_to[k]), MovementKeys::longest_stretch_s) * (keys.slow[k] ? 0.2 : 1.0);
    keys.counted_to[k] = now;
}

}  // namespace

int movement_key_index(int glfw_key) {
    for (int k = 0; k < MovementKeys::count; ++k)
        if (movement_glfw_keys[std::size_t(k)] == glfw_key) return k;
    return -1;
}

void movement_key_event(MovementKeys& keys, int index, bool press, bool slow, MovementKeys::Clock::time_point now) {
    const auto k = std::size_t(index);
    if (press) {
        if (keys.down[k]) return;  // a second press without a release (a lost release): the hold goes on
        keys.down[k] = true, keys.slow[k] = slow;
        keys.pressed_at[k] = keys.counted_to[k] = now;
        return;
    }
    if (!keys.down[k]) return;
    count_key(keys, k, now);
    keys.down[k] = false;
    const double held_s = seconds(now - keys.pressed_at[k]);
    // A tap (pressed and released between two frames, or quicker than a frame) moves as tap_s held.
    if (held_s < MovementKeys::tap_s) keys.owed_s[k] += (MovementKeys::tap_s - held_s) * (keys.slow[k] ? 0.2 : 1.0);
    if (keys.report) say("keyboard: %s held %.3f s%s\n", movement_key_names[k], held_s, keys.slow[k] ? " (Shift: 5x slower)" : "");
}

void count_held_keys(MovementKeys& keys, MovementKeys::Clock::time_point now) {
    for (std::size_t k = 0; k < std::size_t(MovementKeys::count); ++k) count_key(keys, k, now);
}

Eigen::Vector3d take_key_motion(MovementKeys& keys, MovementKeys::Clock::time_point now) {
    count_held_keys(keys, now);
    Eigen::Vector3d motion = Eigen::Vector3d::Zero();
    for (int k = 0; k < MovementKeys::count; ++k) {
        motion += keys.owed_s[std::size_t(k)] * movement_axis(k);
        keys.owed_s[std::size_t(k)] = 0;
    }
    return motion;
}

}  // namespace heartsim
