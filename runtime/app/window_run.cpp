// The window mode's loop: docs/runtime.md "Window mode".
#include "runtime/app/window_run.h"
#include "runtime/core/real_time.h"

#include "runtime/gl/hud.h"
#include "runtime/view/png.h"
#include "runtime/surgery/repair.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/view/section_plane.h"
#include "runtime/link/slicer_link.h"
#include "runtime/app/window_input.h"
#include "runtime/view/window_keys.h"
#include "runtime/app/window_simulation.h"

#include "libmodel/surgery/closure.h"
#include "libmodel/errors.h"
#include "libmodel/mapping.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <limits>
#include <numbers>
#include <optional>
#include <vector>

namespace heartsim {

namespace {

/// The local time now, for the names of screenshots and recordings.
std::tm local_time_now() {
    const std::time_t wall = std::time(nullptr);
    std::tm local{};
    localtime_r(&wall, &local);
    return local;
}

/// The arrows' and PgUp / PgDn's speed, mm per second held: a quarter of the model's radius
/// (Shift: a fifth of that).
double keyboard_speed_mm_per_s(const Camera& camera) { return 0.25 * double(camera.radius); }

/// Shift + P's patch and Shift + N's needle: the patch plan-repair lays on a defect of the
/// scenario's diameter (D + 2·(rim + 2 mm) across; a 10 mm defect's without one), as thick as its
/// patch; the plan's needle.
Instrument repair_instrument(InstrumentKind kind, const Scenario* scenario) {
    const RepairPlanOptions plan;
    if (kind == InstrumentKind::needle) return {.kind = kind, .semi_axes = plan.needle_semi_axes};
    const double defect_mm = scenario && scenario->source.defect_diameter_mm > 0 ? scenario->source.defect_diameter_mm : 10.0;
    const double radius = 0.5 * defect_mm + plan.rim_mm + 2.0;
    return {.kind = kind, .semi_axes = Eigen::Vector3d(radius, radius, 0.5 * plan.thickness_mm)};
}

/// The mouse device's orientation (world frame) for hand 0's instrument: a patch faces into the
/// screen (tool +z away from the eye, onto the tissue in front of it), a needle's shaft points to
/// the eye (tool +z out of the tissue, as plan-repair holds it); anything else the device's own.
Eigen::Quaterniond mouse_orientation(InstrumentKind kind, const Camera& camera) {
    const Eigen::Quaterniond view = camera.orientation.cast<double>();
    if (kind == InstrumentKind::patch) return view * Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()));
    if (kind == InstrumentKind::needle) return view;
    return Eigen::Quaterniond::Identity();
}

/// The closure check of the repair a frame shows (libmodel/surgery/closure.h): the detailed mesh mapped
/// onto `positions` and the patch as it lies, the rim where its stitches are. No leak test: the
/// check at the end of the run (run_modes.cpp) holds the patch to the pressure. nullopt: the scenario has no defect or no
/// mapped detailed mesh. Throws InputError when the check cannot run (ClosureResult::cannot_tell
/// where it ran and cannot tell).
std::optional<ClosureResult> closure_now(const Scenario& scenario, const std::vector<std::array<float, 3>>& positions, const DrawnPatch& patch) {
    if (!scenario.visual || !scenario.mapping || !scenario.simulation_surface) return std::nullopt;
    std::optional<DefectFrame> frame = defect_frame_now(scenario, positions, nullptr);
    if (!frame) return std::nullopt;
    // The axis toward the side the patch lies on (defect_frame_now's rule with a patch).
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto& x : patch.positions) centroid += Eigen::Vector3d(x[0], x[1], x[2]);
    if (!patch.positions.empty() && (centroid / double(patch.positions.size()) - frame->centre).dot(frame->axis) < 0) frame->axis = -frame->axis;
    const auto mapped = apply_mapping(*scenario.mapping, positions, *scenario.simulation_surface);
    std::vector<std::array<float, 3>> tissue;
    tissue.reserve(mapped.size());
    for (const auto& v : mapped) tissue.push_back({v.x(), v.y(), v.z()});
    // The patch's reach: its farthest vertex from the axis, as it lies.
    double reach = 0;
    for (const auto& x : patch.positions) reach = std::max(reach, distance_from_axis(*frame, Eigen::Vector3d(x[0], x[1], x[2])));
    std::vector<Eigen::Vector3d> stitches;
    for (const auto& anchor : patch.stitch_to) stitches.emplace_back(anchor[0], anchor[1], anchor[2]);
    const ClosureOptions options = repair_closure_options(*frame, reach, stitches);
    return check_closure(tissue, scenario.visual->triangles, patch.positions, patch.triangles, patch.thickness_mm, *frame, options);
}


/// The window mode's loop (run_window): the simulation follows the wall clock through the
/// stepping core (the cpu backend on its own thread, the gl backend between frames, haptics
/// through its session) with the script, the keyboard or the devices moving the instruments;
/// frames are drawn from the latest state. Its state lives across frames; each part of a frame
/// is a method of its own.
class WindowLoop {
public:
    WindowLoop(GlContext& context, Stepper& stepper, Renderer& renderer, Trajectory& trajectory, bool keyboard_hand0, int steps,
               const WindowRunOptions& options);
    /// Not Esc, not closed, not interrupted, `steps` not done, --seconds not past, the watchdog
    /// not given up.
    bool running() const {
        return !glfwWindowShouldClose(window) && !(a.interrupted && a.interrupted->load()) && (steps < 0 || attempted < steps) &&
               !past_end() && !result.gave_up;
    }
    void frame();
    /// The simulation thread joined, the window's line said; what run_scripted would return.
    ScriptedRunResult finish();

private:
    /// --seconds when the step has changed with the mass scale: the simulated time decides (gl and
    /// a haptic session here; the cpu thread decides for itself).
    bool past_end() const {
        return !simulation && a.end_ms > 0 && backend.options().mass_scale != start_mass_scale &&
               backend.simulated_time_ms() - start_simulated_ms >= a.end_ms * (1 - 1e-12);
    }
    /// T, F5, K, Shift + P, Shift + N: handed to the thread that steps (or done here).
    void handle_requests();
    /// The steps the frame owes (gl), the keyboard's hand 0 and the mouse device moved, a haptic
    /// session stepped to real time (gl), the simulation thread's state taken (cpu).
    void step_frame(std::chrono::steady_clock::time_point now);
    /// The arrows and PgUp / PgDn: instrument 0 (the keyboard's or the mouse device) moved by what
    /// the keys owe up to `now`, 0.25 model radius a second held, whatever the frame rate.
    void move_by_keys(std::chrono::steady_clock::time_point now);
    /// The keyboard's instrument: "in place at" once the simulation has stepped it where the keys
    /// put it (after they moved it and are all up).
    void say_keyboard_in_place();
    /// Paused, resumed, one step done: said once the simulation has taken them in.
    void say_events();
    /// The instruments to draw, with their contact colour; the mouse device's "in place".
    std::vector<InstrumentShape> frame_shapes();
    /// The drawn mesh opened along the strokes; the repair as the frame's positions have it, and at
    /// most once a second whether it closes the defect.
    DrawnPatch repair_now();
    /// --igtl: what this frame shows, to 3D Slicer (the sender thread does the rest).
    void offer_link(const std::vector<InstrumentShape>& shapes, const DrawnPatch& drawn);
    /// The HUD over the scene (hud.h): figures, hands and forces, axes, scale, help.
    void draw_hud(const std::vector<InstrumentShape>& shapes, const DrawnPatch& drawn, int width, int height);
    /// P's screenshot, the swap, the draw share's wait, the numbered screenshots, the title.
    void end_frame(int width, int height, std::chrono::steady_clock::time_point draw_start);

    Stepper& stepper;
    Backend& backend;
    haptics::HapticRun* const haptic;
    Renderer& renderer;
    Trajectory& trajectory;
    const bool keyboard_hand0;
    const int steps;
    const WindowRunOptions& a;
    GLFWwindow* const window;
    WindowInput input;
    std::optional<Hud> hud;
    RepairBackend* repair = nullptr;
    HudRepair repair_shown;  // the closure check as last run (at most once a second)
    std::optional<std::array<float, 3>> leak_shown;  // where the last check found a leak pass the rim
    std::chrono::steady_clock::time_point next_closure = std::chrono::steady_clock::now();
    bool has_defect = false;
    std::string defect_line;  // the HUD's: the scenario's septal defect, named, and its diameter
    const bool hud_fixed = std::getenv("HEARTSIM_HUD_FIXED") != nullptr;  // fixed figures (tests)
    bool said_paused = false;
    long long resets_said = 0;  // T on the cpu thread: resets done and said
    double paused_simulated_ms = 0;       // the simulated time while paused, as last seen
    long long steps_before_single = -1;  // attempted steps when the pending N was handed on
    double largest_mouse_force_n = 0;     // the mouse device's force, largest seen at a frame
    std::array<bool, 2> touching{};       // each hand's instrument felt the tissue at the last frame (its contact colour)
    bool mouse_touching = false;          // the mouse device's force was above 0.01 N at a frame (and not zero since)
    std::optional<InstrumentForces> gl_forces;  // the gl loop's newest force pass
    std::atomic<bool> recording_now{false};     // F5's recording is on (set by the thread that steps)
    std::atomic<int> toggles_pending{0};        // F5 presses the thread that steps has not handled yet

    // Scripted hands: the same per-step rule as run_scripted (trajectory.h).
    ScriptedHands hands;
    StepClock step_clock;
    const double start_simulated_ms;
    InstrumentKeyframe keyboard;
    bool keyboard_in_place = true;  // the simulation has stepped hand 0 where the keys put it (said)
    std::optional<Eigen::Vector3d> gl_keyboard_stepped;  // gl: hand 0's position at the last step
    bool said_help = false;         // the help's layout said since it was turned on
    // The simulation follows the wall clock, never ahead of it: with the cpu backend on its own
    // thread (a haptic session's steps too, so drawing never stalls the forces); with the gl
    // backend (one GL context) between frames within a time budget. Drawing takes at most
    // --draw-share of the wall clock (docs/runtime.md "Window mode").
    std::optional<WindowSimulation> simulation;
    double paused_ms = 0.0;  // gl pacing: wall time spent paused, not owed
    double next_title_s = 0.0;
    bool said_slow = false;
    std::vector<std::array<float, 3>> latest_positions;

    ScriptedRunResult result;
    int attempted = 0;  // step() calls: a step the watchdog restores counts here, not in result.steps
    double last_draw_ms = 0.0;  // render + present of the last frame (not the swap's vsync wait)
    long long frames = 0, next_shot = -1;
    std::chrono::steady_clock::time_point start, last;
    // The window closes when the watchdog gives up too: the tissue cannot move on (heartsim says
    // why and exits 6).
    const double start_mass_scale;
};

WindowLoop::WindowLoop(GlContext& context, Stepper& stepper, Renderer& renderer, Trajectory& trajectory, bool keyboard_hand0, int steps,
                       const WindowRunOptions& options)
    : stepper(stepper), backend(stepper.backend()), haptic(stepper.haptic()), renderer(renderer), trajectory(trajectory),
      keyboard_hand0(keyboard_hand0), steps(steps), a(options), window(static_cast<GLFWwindow*>(context.window())), hands(trajectory),
      step_clock(backend.time_step_ms()), start_simulated_ms(backend.simulated_time_ms()), start_mass_scale(backend.options().mass_scale) {
    input.renderer = &renderer;
    renderer.set_show_hidden_instruments(true);  // an instrument pushed into the wall stays in sight
    if (haptic) {
        input.session = &haptic->session();
        input.device = haptic->window_device();
        if (input.device) input.device_pose = input.device->last_set();
    }
    install_input_callbacks(window, input);
    input.movement.report = (keyboard_hand0 && !haptic) || input.device;
    glfwSwapInterval(1);
    hud.emplace(window);
    repair = repair_of(backend);
    has_defect = a.scenario && !a.scenario->source.defect.empty();
    if (has_defect) {
        const ScenarioSource& source = a.scenario->source;
        defect_line = source.defect == "vsd"   ? "ventricular septal defect (VSD)"
                      : source.defect == "asd" ? "atrial septal defect (ASD)"
                                               : "defect: " + source.defect;
        if (source.defect_diameter_mm > 0) {
            char across[48];
            std::snprintf(across, sizeof across, ", %.3g mm across", source.defect_diameter_mm);
            defect_line += across;
        }
    }
    if (keyboard_hand0) {
        keyboard = trajectory.at(0, 0.0);
        backend.set_instrument(0, {.kind = keyboard.kind, .semi_axes = keyboard.semi_axes});
        backend.set_pose(0, keyboard.pose);
    }
    // The HUD's leading lines, on the terminal too (a log of the session).
    say("window: %s%s%s%s%s\n", std::filesystem::path(a.scenario_name).stem().string().c_str(), defect_line.empty() ? "" : ", ",
        defect_line.c_str(), a.procedure.empty() ? "" : "; ", a.procedure.c_str());
    const double speed = keyboard_speed_mm_per_s(renderer.camera());
    if (keyboard_hand0 && !haptic) {
        const Eigen::Vector3d& p = keyboard.pose.position;
        say("keyboard: instrument 0 (%s) at (%.2f, %.2f, %.2f) mm; the arrows move it in the view plane, PgUp / PgDn in depth, "
            "%.3g mm/s (Shift: %.3g mm/s); H lists the keys\n",
            to_string(keyboard.kind), p.x(), p.y(), p.z(), speed, 0.2 * speed);
    } else if (input.device) {
        say("keyboard: the arrows move the mouse device in the view plane, PgUp / PgDn in depth, %.3g mm/s (Shift: %.3g mm/s); H lists "
            "the keys\n",
            speed, 0.2 * speed);
    }
    const WindowSimulationOptions simulation_options{.keyboard_hand0 = keyboard_hand0, .steps = steps, .end_ms = a.end_ms};
    if (backend.kind() == BackendKind::cpu) {
        if (haptic) simulation.emplace(stepper, simulation_options);
        else simulation.emplace(stepper, trajectory, simulation_options);
    }
    next_shot = a.screenshot_every > 0 ? a.screenshot_every : -1;
    start = last = std::chrono::steady_clock::now();
}

void WindowLoop::frame() {
    glfwPollEvents();
    const auto now = std::chrono::steady_clock::now();
    if (input.paused) paused_ms += 1e3 * std::chrono::duration<double>(now - last).count();
    last = now;
    handle_requests();
    step_frame(now);
    say_events();
    say_keyboard_in_place();
    int width = 0, height = 0;
    glfwGetFramebufferSize(window, &width, &height);
    if (width > 0 && height > 0) renderer.resize(width, height);
    const std::vector<InstrumentShape> shapes = frame_shapes();
    DrawnPatch drawn = repair_now();
    drawn.leak = leak_shown;
    renderer.set_patch(drawn);
    const auto draw_start = std::chrono::steady_clock::now();
    if (simulation) renderer.render(latest_positions, shapes);
    else renderer.render(backend, shapes);
    renderer.present(width, height);
    if (stepper.link_due()) offer_link(shapes, drawn);
    draw_hud(shapes, drawn, width, height);
    end_frame(width, height, draw_start);
}

void WindowLoop::handle_requests() {
    if (input.reset_tissue && (recording_now || toggles_pending > 0)) {
        // The reset is no step input a replay could repeat: the recording would not replay.
        say("T: not while recording (a reset inside a recording could not be replayed); F5 stops the recording, F5 again starts a new one from rest\n");
        input.reset_tissue = false;
    }
    if (input.reset_tissue && haptic && haptic->records_session()) {
        // The same for --record's whole-session recording.
        say("T: not while --record records the session (a reset inside a recording could not be replayed)\n");
        input.reset_tissue = false;
    }
    if (input.toggle_recording) {
        // F5: a recording from the tissue's rest state (T, grabs released) to the next F5,
        // written beside the scenario (docs/haptics.md "Recording from the window"). Started
        // and stopped on the thread that steps, between two steps.
        input.toggle_recording = false;
        if (!haptic) {
            say("recording: needs a haptic session (--device mouse, scripted:FILE, …): nothing to record\n");
        } else if (haptic->records_session()) {
            say("recording: --record %s records the whole session already; F5 is off\n", haptic->recording_path().c_str());
        } else {
            // F5 toggles what the stepping thread has: on → stop and write; off → start.
            const std::string scenario_path = a.scenario_path;
            ++toggles_pending;
            auto toggle = [haptic = haptic, &backend = backend, &recording_now = recording_now, &toggles_pending = toggles_pending, scenario_path] {
                // Handled once recording_now says what it did (T is refused until then).
                struct Handled {
                    std::atomic<int>& pending;
                    ~Handled() { --pending; }
                } handled{toggles_pending};
                if (!haptic->window_recording()) {
                    // Named on this thread, once the previous recording is written: never the same name.
                    const std::string path = timestamped_path(scenario_path, local_time_now(), ".rec.h5");
                    try {
                        haptic->start_recording(path);
                        recording_now = true;
                        say("recording: started at %.10g ms simulated, to %s (the tissue reset to its rest state; F5 stops and writes it)\n",
                            backend.simulated_time_ms(), path.c_str());
                    } catch (const std::exception& e) {
                        say("recording: could not start %s: %s\n", path.c_str(), e.what());
                    }
                    return;
                }
                const std::string path = haptic->recording_path();
                recording_now = false;
                try {
                    const std::size_t steps = haptic->stop_recording();
                    say("recording: wrote %s (%zu steps)\n", path.c_str(), steps);
                } catch (const std::exception& e) {
                    say("recording: could not write %s: %s\n", path.c_str(), e.what());
                }
            };
            if (simulation) simulation->run_between_steps(toggle);
            else toggle();
        }
    }
    if (input.toggle_scalpel || input.toggle_patch || input.toggle_needle) {
        // K, Shift + P, Shift + N: hand 0 holds a scalpel, a patch or a needle, or its own
        // instrument again, switched on the thread that steps between two steps (a recording
        // keeps the switch: /steps/instrument).
        const InstrumentKind asked = input.toggle_scalpel ? InstrumentKind::scalpel
                                     : input.toggle_patch ? InstrumentKind::patch
                                                          : InstrumentKind::needle;
        const char* key = input.toggle_scalpel ? "K" : input.toggle_patch ? "Shift + P" : "Shift + N";
        input.toggle_scalpel = input.toggle_patch = input.toggle_needle = false;
        if (!haptic || !haptic->uses_hand(0)) {
            say(asked == InstrumentKind::scalpel ? "%s: the scalpel is a device's instrument: run with --device (mouse, openhaptics, …)\n"
                                                 : "%s: the patch and the needle are a device's instruments: run with --device (mouse, openhaptics, …)\n",
                key);
        } else if (asked != InstrumentKind::scalpel && !repair) {
            say("%s: the scenario has no detailed mesh with its mapping for a patch to lie on\n", key);
        } else {
            const Instrument instrument = asked == InstrumentKind::scalpel
                                              ? Instrument{.kind = InstrumentKind::scalpel, .semi_axes = default_blade_semi_axes_mm}
                                              : repair_instrument(asked, a.scenario);
            auto swap = [haptic = haptic, instrument, key] {
                try {
                    const InstrumentKind now = haptic->toggle_instrument(0, instrument);
                    const char* how = now == InstrumentKind::scalpel ? " (G or button 1 lowers the blade: it cuts what it sweeps)"
                                      : now == InstrumentKind::patch
                                          ? " (G or button 1 lays it on the tissue in front of it; held there until its first stitch)"
                                      : now == InstrumentKind::needle
                                          ? " (G or button 1 ties a stitch from the tissue at its tip to the patch's point nearest it)"
                                          : "";
                    say("instrument 0: %s%s\n", to_string(now), how);
                } catch (const std::exception& e) {
                    say("%s: %s\n", key, e.what());
                }
            };
            if (simulation) simulation->run_between_steps(swap);
            else swap();
        }
    }
    if (input.reset_tissue) {
        if (simulation) {
            simulation->request_reset_tissue();
        } else {
            backend.reset_tissue();
            say("tissue reset to its rest state\n");
        }
        input.reset_tissue = false;
    }
    if (simulation && simulation->status().resets > resets_said) {  // said once the thread has done it
        resets_said = simulation->status().resets;
        say("tissue reset to its rest state\n");
    }
}

void WindowLoop::move_by_keys(std::chrono::steady_clock::time_point now) {
    const Eigen::Vector3d held = take_key_motion(input.movement, now);
    if (!keyboard_hand0 && !input.device) return;
    const Camera& camera = renderer.camera();
    const Eigen::Matrix3d basis = camera.orientation.toRotationMatrix().cast<double>();
    const Eigen::Vector3d move = keyboard_speed_mm_per_s(camera) * (basis * held);
    keyboard.pose.position += move;
    if (keyboard_hand0 && !move.isZero()) keyboard_in_place = false;
    if (simulation && keyboard_hand0) simulation->set_keyboard_pose(keyboard.pose);
    if (input.device) {
        input.device_pose.position_mm += move;
        if (!move.isZero()) device_moved(input);
        if (haptic->device_spec(0) == "mouse") input.device_pose.orientation = mouse_orientation(haptic->instrument(0), camera);
        input.device->set_pose(input.device_pose);
    }
}

void WindowLoop::say_keyboard_in_place() {
    if (!keyboard_hand0 || haptic || keyboard_in_place) return;
    for (const bool down : input.movement.down)
        if (down) return;
    const std::optional<Eigen::Vector3d> stepped = simulation ? simulation->status().keyboard_position_mm : gl_keyboard_stepped;
    if (!stepped || (*stepped - keyboard.pose.position).norm() > 1e-9) return;
    keyboard_in_place = true;
    say("keyboard: instrument 0 in place at (%.2f, %.2f, %.2f) mm\n", stepped->x(), stepped->y(), stepped->z());
}

void WindowLoop::step_frame(std::chrono::steady_clock::time_point now) {
    // gl: the steps the wall clock owes, within a budget of twice the last frame's drawing
    // (12 ms at least), so a slow renderer leaves the simulation most of the wall clock.
    int n = 0;
    if (!simulation && !haptic && !input.paused) {
        const double owed_ms = 1e3 * std::chrono::duration<double>(now - start).count() - paused_ms;
        // The steps that fit in the time owed and not yet simulated (the step changes with the mass scale).
        n = stepper.steps_owed(owed_ms, backend.simulated_time_ms() - start_simulated_ms);
        stepper.observe(owed_ms, backend.simulated_time_ms());
    }
    if (!simulation && !haptic && input.paused) stepper.restart_measuring();
    // N while paused: one step (the gl loop here, the cpu thread by request); not with a
    // haptic session, whose steps follow the session clock.
    if (!input.paused) input.single_steps = 0;
    if (input.single_steps > 0 && haptic) {
        say("N: single steps need a run without --device (a haptic session follows its own clock)\n");
        input.single_steps = 0;
    }
    if (input.single_steps > 0 && steps_before_single < 0) {
        steps_before_single = attempted;
        --input.single_steps;
        if (simulation) simulation->request_single_step();
        else n = 1;
    }
    if (steps >= 0) n = std::min(n, steps - attempted);
    const double step_budget_ms = std::max(12.0, 2.0 * last_draw_ms);

    // Keyboard: arrows move hand 0 (or the mouse device) in the view plane, PgUp/PgDn into /
    // out of the screen.
    const InstrumentPose from = keyboard.pose;
    move_by_keys(now);
    const InstrumentPose to = keyboard.pose;
    if (haptic && !simulation) {
        // Haptics with the gl backend: the simulation follows real time between frames; the
        // device thread moves the instruments.
        stepper.set_paused(input.paused);  // the real-time reference stops while paused
        // Stepping gets at least twice the last frame's drawing time (12 ms minimum): on a slow
        // renderer (llvmpipe) the simulation keeps 2/3 of the wall clock, fewer frames are drawn.
        if (!input.paused)
            stepper.step_to_real_time(steps >= 0 ? std::max(0, std::min(100000, steps - attempted)) : 100000,
                                      std::max(12.0, 2.0 * last_draw_ms));
        else haptic->drain();
        attempted = int(haptic->rows());
        result.steps = haptic->result().steps;
        result.substeps = haptic->result().substeps;
        n = 0;
    }
    if (simulation) {
        simulation->set_paused(input.paused);
        simulation->latest(latest_positions);
        const WindowSimulation::Status status = simulation->status();
        attempted = int(std::min<long long>(status.attempted, std::numeric_limits<int>::max()));
        result = status.run;
        if (status.finished) {
            simulation->latest(latest_positions);  // the final state
            attempted = std::max(attempted, steps);
        }
    }
    const auto step_start = std::chrono::steady_clock::now();
    for (int k = 0; k < n && !past_end(); ++k) {
        if (k > 0 && std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - step_start).count() > step_budget_ms) break;
        const int step = attempted++;
        const double f = double(k + 1) / double(n);  // the keyboard's hand 0 moves over the frame's steps
        const InstrumentPose hand0{from.position + f * (to.position - from.position), to.orientation};
        std::optional<InstrumentForces> forces;
        result.add(stepper.step_scripted(hands, trajectory, step_clock, step, keyboard_hand0, hand0, forces));
        if (keyboard_hand0) gl_keyboard_stepped = hand0.position;
        if (forces) {
            ++result.forces_received;
            gl_forces = forces;
        }
    }
}

void WindowLoop::say_events() {
    // Event lines once the simulation has taken them in: paused (no step runs from here on),
    // resumed, one step done.
    const double simulated_now_ms = simulation ? simulation->status().simulated_ms : backend.simulated_time_ms();
    const bool paused_seen = simulation ? simulation->status().paused : input.paused;
    if (input.paused && paused_seen && !said_paused && steps_before_single < 0) {
        said_paused = true;
        say("paused at %.10g ms simulated (Space resumes, N steps once)\n", simulated_now_ms);
    }
    if (input.paused && paused_seen) paused_simulated_ms = simulated_now_ms;
    if (!input.paused && said_paused) {
        said_paused = false;
        say("resumed at %.10g ms simulated\n", paused_simulated_ms);  // the time it stood at while paused
    }
    if (steps_before_single >= 0) {
        const long long now_attempted = simulation ? simulation->status().attempted : attempted;
        if (now_attempted > steps_before_single || !input.paused) {
            if (now_attempted > steps_before_single) say("one step: %.10g ms simulated\n", simulated_now_ms);
            steps_before_single = -1;
        }
    }
}

std::vector<InstrumentShape> WindowLoop::frame_shapes() {
    std::vector<InstrumentShape> shapes = !haptic ? std::vector<InstrumentShape>{}
                                          : simulation ? simulation->status().shapes : haptic->shapes();
    for (InstrumentShape& shape : shapes) {
        if (shape.hand < 0 || shape.hand > 1) continue;
        shape.touching = touching[std::size_t(shape.hand)];
        // The mouse device's instrument: where it goes when put on the surface.
        if (input.device && haptic->device_spec(shape.hand) == "mouse") {
            const bool tip = shape.kind == InstrumentKind::scalpel || shape.kind == InstrumentKind::needle;
            input.surface_offset_mm = tip ? 0.0 : shape.kind == InstrumentKind::patch ? 2.0 : -0.25 * shape.semi_axes.minCoeff();
            // The simulation has stepped it where the window put it, its button too: said once
            // after each input that moved it (device_moved), so that a log or a test waits for
            // the simulation to take an input in rather than for a time.
            const bool there = (shape.pose.position - input.device_pose.position_mm).norm() <= 1e-6 && shape.buttons == input.device_pose.buttons;
            if (there && !input.device_in_place)
                say("mouse device: in place at (%.2f, %.2f, %.2f) mm\n", shape.pose.position.x(), shape.pose.position.y(), shape.pose.position.z());
            input.device_in_place = input.device_in_place || there;
        }
    }
    for (int hand = 0; hand < 2 && !haptic; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        const double time_ms = simulation ? simulation->status().simulated_ms : backend.simulated_time_ms();
        const InstrumentKeyframe k = hand == 0 && keyboard_hand0 ? keyboard : trajectory.at(hand, time_ms);
        if (k.kind != InstrumentKind::none) shapes.push_back({k.kind, k.pose, k.semi_axes, hand, touching[std::size_t(hand)]});
    }
    return shapes;
}

DrawnPatch WindowLoop::repair_now() {
    if (simulation) {
        const StrokeLog strokes = simulation->strokes();
        stepper.open_or_preview_incisions(&latest_positions, &strokes);
    } else {
        stepper.open_or_preview_incisions(nullptr, nullptr);
    }
    // The repair as the frame's positions have it, and at most once a second whether it closes the defect.
    DrawnPatch drawn;
    if (simulation) drawn = simulation->patch();
    else if (const PatchModel* patch = repair ? repair->patch() : nullptr) drawn = drawn_patch(*patch, repair->stitch_anchors());
    if (drawn.triangles.empty()) {
        repair_shown = {};
        leak_shown.reset();
    } else if (has_defect && std::chrono::steady_clock::now() >= next_closure) {
        try {
            const std::optional<ClosureResult> closure =
                closure_now(*a.scenario, simulation ? latest_positions : backend.positions(), drawn);
            repair_shown.known = closure.has_value() && !closure->cannot_tell;
            leak_shown.reset();
            if (closure) {
                repair_shown.closed = closure->closed;
                repair_shown.rim_gap_mm = closure->largest_rim_gap_mm;
                repair_shown.leak = leak_place(*closure);
                if (closure->leak_mm) leak_shown = {float(closure->leak_mm->x()), float(closure->leak_mm->y()), float(closure->leak_mm->z())};
            }
        } catch (const InputError&) {
            repair_shown.known = false;
            leak_shown.reset();
        }
        repair_shown.checked = true;
        next_closure = std::chrono::steady_clock::now() + std::chrono::seconds(1);
    }
    return drawn;
}

void WindowLoop::offer_link(const std::vector<InstrumentShape>& shapes, const DrawnPatch& drawn) {
    // --igtl: what this frame shows, to 3D Slicer (the sender thread does the rest).
    // The forces of what the frame shows: the simulation thread's, the gl backend's last
    // force pass (with the particles it summed), or the haptic session's published ones.
    const WindowSimulation::Status st = simulation ? simulation->status() : WindowSimulation::Status{};
    InstrumentForces forces{};
    for (int hand = 0; hand < 2; ++hand) {
        if (simulation && st.has_forces) forces.hand[std::size_t(hand)].force_n = st.forces[std::size_t(hand)];
        else if (gl_forces) forces.hand[std::size_t(hand)] = gl_forces->hand[std::size_t(hand)];
        else if (haptic) forces.hand[std::size_t(hand)].force_n = haptic->latest_published_forces().hand[std::size_t(hand)].force_n;
    }
    const SlicerLinkHands streamed = link_hands(shapes, forces);
    const SlicerLink::State state = input.estop ? SlicerLink::State::emergency_stop
                                    : input.paused ? SlicerLink::State::paused
                                                   : SlicerLink::State::running;
    const auto patch = [&drawn] { return drawn; };  // the repair this frame draws
    if (simulation) stepper.offer(st.simulated_ms, latest_positions, (long long)result.steps, streamed, state, patch);
    else stepper.offer((long long)result.steps, streamed, state, patch);
}

void WindowLoop::draw_hud(const std::vector<InstrumentShape>& shapes, const DrawnPatch& drawn, int width, int height) {
    // The HUD over the scene (hud.h): figures, hands and forces, axes, scale, help.
    const double s = std::max(1e-9, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    HudState state;
    state.show_hud = input.show_hud, state.show_help = input.show_help, state.show_figures = input.show_figures;
    state.case_name = std::filesystem::path(a.scenario_name).stem().string();
    state.defect = defect_line;
    state.procedure = a.procedure;
    const WindowSimulation::Status status = simulation ? simulation->status() : WindowSimulation::Status{};
    const double owed_ms = simulation ? status.owed_ms : 1e3 * s - paused_ms;
    state.simulated_ms = simulation ? status.simulated_ms : backend.simulated_time_ms();
    state.real_time_factor = haptic && !simulation ? 1.0 : owed_ms > 0 ? state.simulated_ms / owed_ms : 1.0;
    state.frames_per_s = frames / s;
    state.steps_per_s = result.steps / s;
    state.particles = backend.size();
    state.backend = to_string(backend.kind());
    if (!a.backend_note.empty()) state.backend += " (" + a.backend_note + ")";
    state.mass_scale = simulation ? status.mass_scale : backend.options().mass_scale;
    state.paused = input.paused;
    state.emergency_stop = input.estop;
    state.recording = recording_now;
    if (const auto& section = renderer.section()) {
        state.section = true;
        state.section_depth_mm = section->depth_from(renderer.model_centre());
        state.section_normal = section->normal.cast<double>();
    }
    state.haptic_period_p99_ms = simulation ? status.haptic_period_p99_ms : haptic ? haptic->session().live_period_p99_ms() : -1;
    const bool has_forces = simulation ? status.has_forces : gl_forces.has_value();
    for (int hand = 0; hand < 2; ++hand) {
        HudHand& h = state.hands[hand];
        for (const InstrumentShape& shape : shapes)
            if (shape.hand == hand) h.position_mm = shape.pose.position;
        if (haptic) {
            h.used = haptic->uses_hand(hand);
            if (!h.used) continue;
            h.device = haptic->device_spec(hand);
            if (const auto colon = h.device.find(':'); colon != std::string::npos && h.device.find('/') != std::string::npos)
                h.device = h.device.substr(0, colon + 1) + std::filesystem::path(h.device.substr(colon + 1)).filename().string();
            h.instrument = to_string(haptic->instrument(hand));
            h.max_force_n = haptic->max_force_n(hand);
            // The simulation's force on the instrument (what the session sends on, before
            // safety); for the mouse device what it was sent.
            h.has_force = simulation ? status.has_forces : true;
            h.force_n = simulation ? status.forces[hand] : haptic->latest_published_forces().hand[hand].force_n;
            h.force_source = "on the instrument";
            if (input.device && h.device == "mouse") {
                h.force_source = "sent to the device";
                // The force sent to the mouse device (world frame: its mapping is the identity).
                h.has_force = true;
                h.force_n = input.device->latest_force();
                h.grabbing = (input.device_pose.buttons & 1u) != 0;
                // Contact as the hand feels it, on the terminal too (a log, the tests): the
                // largest force the device thread sent since the last frame.
                const double peak = std::max(input.device->peak_force_since_last(), h.force_n.norm());
                largest_mouse_force_n = std::max(largest_mouse_force_n, peak);
                if (!mouse_touching && peak > 0.01) say("mouse device: touching the tissue, %.4g N\n", peak);
                if (mouse_touching && peak == 0.0) say("mouse device: free\n");
                mouse_touching = peak > 0.01 || (mouse_touching && peak > 0.0);
            }
            touching[std::size_t(hand)] = h.has_force && h.force_n.norm() > 0.01;
            continue;
        }
        h.used = trajectory.uses_hand(hand);
        if (!h.used) continue;
        h.device = hand == 0 && keyboard_hand0 ? "keyboard" : "script";
        const InstrumentKeyframe k = hand == 0 && keyboard_hand0 ? keyboard : trajectory.at(hand, state.simulated_ms);
        h.instrument = to_string(k.kind);
        h.grabbing = k.grab;
        h.has_force = has_forces;
        h.force_n = simulation ? status.forces[hand] : gl_forces ? gl_forces->hand[hand].force_n : Eigen::Vector3d::Zero();
        touching[std::size_t(hand)] = h.has_force && h.force_n.norm() > 0.01;
    }
    state.repair = repair_shown;
    state.repair.laid = !drawn.triangles.empty();
    state.repair.material = drawn.material;
    state.repair.stitches = drawn.stitch_from.size();
    state.repair.defect = has_defect;
    if (hud_fixed) {
        // HEARTSIM_HUD_FIXED (golden-image tests): the figures that depend on the
        // machine's speed and on timing shown as fixed values, so the picture is the same
        // on every run (docs/runtime.md "Screenshots and the golden image").
        state.real_time_factor = 1.0, state.frames_per_s = 60.0, state.steps_per_s = 1000.0, state.simulated_ms = 0.0;
        if (state.haptic_period_p99_ms >= 0) state.haptic_period_p99_ms = 1.0;
    }
    state.keys = {.keyboard_instrument = keyboard_hand0 && !haptic, .device = haptic != nullptr, .mouse_device = input.device != nullptr};
    hud->draw(state, renderer.camera(), width, height);
    // The help's layout, said once it shows (a log, a test: whether its last row is in the window).
    const HudHelpLayout& help = hud->help_layout();
    if (help.shown && !said_help)
        say("help: %zu keys for this session%s, from y %.0f to %.0f (last row ends at %.0f) of %d pixels\n", help.rows,
            help.details ? "" : " (actions only: the details would not fit)", help.top, help.bottom, help.last_row_bottom, height);
    said_help = help.shown;
}

void WindowLoop::end_frame(int width, int height, std::chrono::steady_clock::time_point draw_start) {
    if (input.screenshot) {
        // P: the window as seen, HUD included, beside the scenario (written atomically).
        input.screenshot = false;
        const std::string path = timestamped_screenshot(a.scenario_path, local_time_now());
        try {
            write_png(path, read_window_pixels(width, height));
            say("screenshot: wrote %s (%dx%d)\n", path.c_str(), width, height);
        } catch (const std::exception& e) {
            say("screenshot: could not write %s: %s\n", path.c_str(), e.what());
        }
    }
    glfwSwapBuffers(window);
    input.redraw = false;
    last_draw_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - draw_start).count();
    ++frames;
    // Drawing takes at most --draw-share of the wall clock: on a software renderer the window
    // draws fewer frames and the simulation keeps the cores.
    if (simulation && a.draw_share < 1.0) {
        const double rest_ms = last_draw_ms / a.draw_share - last_draw_ms;
        const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double, std::milli>(std::min(rest_ms, 1000.0));
        while (std::chrono::steady_clock::now() < until && !glfwWindowShouldClose(window) && !simulation->status().finished) {
            glfwWaitEventsTimeout(0.01);
            move_by_keys(std::chrono::steady_clock::now());  // the keyboard's instrument moves while the window waits too
            if (input.reset_tissue || input.paused || input.screenshot || input.toggle_recording || input.single_steps > 0 || input.redraw)
                break;
        }
    }
    if (next_shot > 0 && result.steps >= next_shot) {
        const std::string path = numbered_screenshot(a.screenshot, result.steps);
        write_png(path, renderer.read_pixels());
        while (next_shot <= result.steps) next_shot += a.screenshot_every;
    }
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (s >= next_title_s) {  // the title twice a second
        next_title_s = s + 0.5;
        char title[256];
        std::string forces;
        if (input.device) {
            const Eigen::Vector3d f = input.device->latest_force();
            char text[96];
            std::snprintf(text, sizeof text, ", mouse device force %.3f N%s", f.norm(), input.device_pose.buttons & 1u ? ", grab" : "");
            forces = text;
        }
        if (input.estop) forces += ", EMERGENCY STOP (E releases)";
        const double simulated_ms = simulation ? simulation->status().simulated_ms : backend.simulated_time_ms();
        const double owed_ms = simulation ? simulation->status().owed_ms : 1e3 * s - paused_ms;
        const double factor = owed_ms > 0 ? simulated_ms / owed_ms : 1.0;
        std::snprintf(title, sizeof title, "heartsim — %s — %.1f fps, %.0f steps/s, %.2f× real time%s%s",
                      a.scenario_name.c_str(), frames / s, result.steps / s, haptic && !simulation ? 1.0 : factor,
                      input.paused ? " (paused)" : "", forces.c_str());
        glfwSetWindowTitle(window, title);
        if ((!haptic || simulation) && !said_slow && !input.paused && owed_ms > 2000 && factor < 0.95) {
            said_slow = true;
            say("window: the simulation runs at %.2f× real time here (%zu particles, %s backend, mass scale %g): instruments move "
                "slower than the hand; it %s\n",
                factor, backend.size(), to_string(backend.kind()), backend.options().mass_scale,
                speed_verdict(backend, factor, backend.options().mass_scale).c_str());
        }
    }
}

ScriptedRunResult WindowLoop::finish() {
    const double wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    const char* pacing = simulation ? (haptic ? "haptic simulation on its own thread, paced to the session clock"
                                              : "simulation on its own thread, paced to the wall clock")
                         : haptic   ? "steps to real time between frames (haptics)"
                                    : "steps owed to the wall clock between frames";
    double simulated_ms = backend.time_step_ms() * double(result.steps);
    if (simulation) {
        const WindowSimulation::Status status = simulation->status();
        simulated_ms = status.simulated_ms;
        result = status.run;
        simulation.reset();  // joins the thread before the caller reads the backend
    }
    result.wall_ms = wall_ms;
    if (input.device) std::printf("mouse device: largest force sent %.4g N\n", largest_mouse_force_n);
    std::printf("window: %lld frames in %.3g s (%.1f fps), %s; %.4g ms simulated, %.3g× real time\n", frames, result.wall_ms * 1e-3,
                frames / std::max(result.wall_ms * 1e-3, 1e-9), pacing, simulated_ms, simulated_ms / std::max(result.wall_ms, 1e-9));
    return result;
}

}  // namespace

ScriptedRunResult run_window(GlContext& context, Stepper& stepper, Renderer& renderer, Trajectory& trajectory, bool keyboard_hand0,
                             int steps, const WindowRunOptions& a) {
    WindowLoop loop(context, stepper, renderer, trajectory, keyboard_hand0, steps, a);
    while (loop.running()) loop.frame();
    return loop.finish();
}

}  // namespace heartsim
