// The modes of `heartsim run` (run_modes.h): what each prints, in the order it prints it, is the
// command's output that tests/test_runtime_cli.cpp and tests/test_haptics_cli.cpp check.
#include "runtime/run_modes.h"

#include "runtime/gl/backend_gl.h"
#include "runtime/gl/picking.h"

#include "runtime/haptics/haptic_run.h"
#include "runtime/png.h"
#include "runtime/section_plane.h"
#include "runtime/window_run.h"

#include "formats/atomic_file.h"
#include "formats/recording.h"
#include "formats/recording_journal.h"
#include "formats/state.h"
#include "formats/xdmf.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "cli/exit_codes.h"
#include "libmodel/mapping.h"
#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <sstream>
#include <thread>
#include <tuple>
#include <utility>

namespace heartsim {

namespace {

using Clock = std::chrono::steady_clock;

/// Ctrl-C during a haptic run: end it cleanly (forces fade out, the recording is written).
std::atomic<bool> interrupted{false};

/// Ctrl-C or a termination request ends a haptic session cleanly (fade, recording written); the
/// handlers stay until the session is finished, so a second Ctrl-C cannot cut the fade.
void catch_interrupts() {
    std::signal(SIGINT, [](int) { interrupted.store(true); });
    std::signal(SIGTERM, [](int) { interrupted.store(true); });
}

/// Ctrl-C is the terminal's again; what the run said is flushed first, so a Ctrl-C after this
/// cannot take the lines that say what was written.
void restore_interrupts() {
    std::fflush(stdout);
    std::signal(SIGINT, SIG_DFL), std::signal(SIGTERM, SIG_DFL);
}

/// "WxH" → (W, H); empty gives `fallback`.
std::pair<int, int> parse_size(const std::string& text, std::pair<int, int> fallback) {
    if (text.empty()) return fallback;
    int w = 0, h = 0;
    char x = 0, extra = 0;
    if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 16 || h < 16 || w > 16384 ||
        h > 16384)
        throw UsageError("--size '" + text + "': expected WxH pixels, each from 16 to 16384, e.g. 1024x768");
    return {w, h};
}

/// The particles' rest bounding box (where the devices' frames are placed when nothing is drawn).
Eigen::AlignedBox3f model_box(const Scenario& scenario) {
    Eigen::AlignedBox3f box;
    for (const auto& p : scenario.lattice.particles.rest_position) box.extend(Eigen::Vector3f(p[0], p[1], p[2]));
    if (box.isEmpty()) box.extend(Eigen::Vector3f::Zero());
    return box;
}

/// The instruments of the script at `time_ms`, to draw.
std::vector<InstrumentShape> shapes_at(const Trajectory& trajectory, double time_ms) {
    std::vector<InstrumentShape> shapes;
    for (int hand = 0; hand < 2; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        const InstrumentKeyframe k = trajectory.at(hand, time_ms);
        if (k.kind != InstrumentKind::none) shapes.push_back({k.kind, k.pose, k.semi_axes});
    }
    return shapes;
}

/// The combinations of options no mode accepts (UsageError, exit 2) and output places that cannot
/// hold a file (OutputError, exit 7), refused before anything is read.
void check_arguments(const RunArguments& a) {
    if (a.steps.value_or(0) > 0 && a.seconds > 0) throw UsageError("give --steps or --seconds, not both");
    if (!std::isfinite(a.seconds) || a.seconds > 1e6) throw UsageError("--seconds: expected a finite number of seconds up to 10^6");
    if (a.max_force && !std::isfinite(*a.max_force)) throw UsageError("--max-force: expected a finite force in N");
    if (a.max_force) {  // 0 is no limit of its own, not "send nothing": refused with the range
        try {
            plausible::require(*a.max_force, plausible::device_force_n, "the force", "--max-force");
        } catch (const InputError& e) {
            throw UsageError(e.what());
        }
    }
    if (a.record && a.record->empty()) throw UsageError("--record: give the file to write, e.g. --record session.h5");
    if (a.replay_tolerance >= 0 && a.replay.empty()) throw UsageError("--replay-tolerance needs --replay");
    if (!a.replay.empty() && (a.steps || a.seconds > 0))
        throw UsageError("--replay runs the recording's own steps: no --steps or --seconds with it");
    if (a.screenshot_every > 0 && a.screenshot.empty()) throw UsageError("--screenshot-every needs --screenshot OUT.png");
    if (!a.clip.empty() && a.headless && a.screenshot.empty())
        throw UsageError("--clip cuts the heart open in the picture: headless it needs --screenshot OUT.png");
    if (a.mass_scale && !valid_mass_scale(*a.mass_scale))
        throw UsageError("--mass-scale: expected a number from 1 (no scaling) to 1024, not " + std::to_string(*a.mass_scale));
    if (a.mass_scale && a.real_time == "auto")
        throw UsageError("--mass-scale fixes S and --real-time auto chooses it: give one of them");
    if (!a.replay.empty() && (a.mass_scale || a.real_time == "auto"))
        throw UsageError("--replay steps with the recording's own mass scale: no --mass-scale or --real-time auto with it");
    const bool haptic_run = !a.devices.empty();
    if (a.devices.size() > 2) throw UsageError("--device: at most two (hand 0, hand 1)");
    if (haptic_run && (!a.trajectory.empty() || !a.probe.empty() || !a.grab.empty()))
        throw UsageError("--device moves the instruments: give --device or --trajectory/--probe/--grab, not both");
    if (!haptic_run && (!a.instruments.empty() || a.record))
        throw UsageError(std::string(!a.record ? "--instrument" : "--record") + " needs --device");
    // The device options change nothing without a device: said, rather than ignored.
    if (!haptic_run)
        for (const std::string& option : a.device_options_given) throw UsageError(option + " sets how forces reach a haptic device: it needs --device");
    if (!a.replay.empty() && (haptic_run || !a.trajectory.empty() || !a.probe.empty() || !a.grab.empty()))
        throw UsageError("--replay drives the instruments from the recording: no --device, --trajectory, --probe or --grab with it");
    if (a.igtl.empty() && (a.igtl_wait || a.igtl_mesh_rate || a.igtl_bind || a.igtl_frame))
        throw UsageError(std::string(a.igtl_wait ? "--igtl-wait" : a.igtl_mesh_rate ? "--igtl-mesh-rate" : a.igtl_bind ? "--igtl-bind" : "--igtl-frame") +
                         " sets how heartsim streams to 3D Slicer: it needs --igtl PORT");
    if (a.igtl_bind && a.igtl.find(':') != std::string::npos)
        throw UsageError("--igtl-bind sets where heartsim listens: not with --igtl " + a.igtl + ", where heartsim connects to a Slicer server");
    if (!a.igtl.empty() && !a.replay.empty()) throw UsageError("--igtl streams a running session: not with --replay");
    if (haptic_run && a.headless && a.seconds <= 0 && a.steps && *a.steps == 0)
        throw UsageError("--steps 0 runs no step: a headless haptic run needs --steps N of at least 1, or --seconds S "
                         "(wall clock: the simulation follows real time)");
    if (haptic_run && a.headless && a.seconds <= 0 && !(a.steps.value_or(0) > 0))
        throw UsageError("a headless haptic run needs --seconds S (wall clock: the simulation follows real time) or --steps N");
    // Files written after the run: a place they cannot go is refused now, not after the simulation.
    // An output must not replace an input: the scenario, the trajectory, the recording replayed,
    // a device's script (simulated:FILE[@…], scripted:FILE).
    std::vector<InputFile> inputs = {
        {a.scenario, "the scenario being run"}, {a.trajectory, "the --trajectory file"}, {a.replay, "the recording replayed"}};
    for (const std::string& device : a.devices) {
        const auto colon = device.find(':');
        if (colon == std::string::npos) continue;
        std::string file = device.substr(colon + 1);
        if (const auto at = file.rfind('@'); at != std::string::npos && !std::filesystem::exists(file)) file = file.substr(0, at);
        inputs.push_back({file, "the file of --device " + device});
    }
    const std::vector<std::pair<const char*, std::string>> outputs = {
        {"--save-state", a.save_state}, {"--screenshot", a.screenshot}, {"--stats-csv", a.stats_csv}, {"--record", a.record.value_or("")}};
    for (const auto& [option, path] : outputs) {
        if (path.empty()) continue;
        refuse_an_input_as_output(std::string(option) + " " + path, path, inputs);
        for (const auto& [other_option, other] : outputs)
            if (other_option != option && !other.empty() && same_file(other, path))
                throw UsageError(std::string(option) + " and " + other_option + " name the same file, " + path + "; give each its own");
    }
    // --save-state and --record also write a ParaView description beside their file (xdmf.h): it
    // must not be another output, an input, or the scenario's own description, and its place must
    // take a file, all before the run (a folder there failed after the run, leaving the .h5).
    namespace fs = std::filesystem;
    const fs::path scenario_description = xdmf_beside(a.scenario);
    const std::pair<const char*, std::string> described[] = {{"--save-state", a.save_state}, {"--record", a.record.value_or("")}};
    for (const auto& [option, path] : described) {
        if (path.empty()) continue;
        const fs::path description = xdmf_beside(path);
        const std::string what = std::string(option) + " " + path + ": its ParaView description " + description.string();
        if (same_file(description, scenario_description))
            throw UsageError(what + " would replace the scenario's own; give another name");
        for (const auto& [input, input_what] : inputs)
            if (!input.empty() && same_file(description, input)) throw UsageError(what + " would replace " + input_what + "; give another name");
        for (const auto& [other_option, other] : outputs)
            if (!other.empty() && same_file(description, other))
                throw UsageError(what + " is the file " + other_option + " names; give each its own");
        for (const auto& [other_option, other] : described)
            if (other_option != option && !other.empty() && same_file(description, xdmf_beside(other)))
                throw UsageError(what + " is also " + other_option + "'s; give them different names");
    }
    for (const auto& [option, path] : {std::pair{"--save-state", a.save_state}, {"--screenshot", a.screenshot}, {"--stats-csv", a.stats_csv}}) {
        if (path.empty()) continue;
        try {
            check_destination(path);
        } catch (const OutputError& e) {
            throw OutputError(std::string(option) + " " + e.what());
        }
    }
    // The places of the descriptions (--record's own place is check_record_path's).
    for (const auto& [option, path] : described) {
        if (path.empty()) continue;
        try {
            check_xdmf_destination(path);
        } catch (const OutputError& e) {
            throw OutputError(std::string(option) + " " + e.what());
        }
    }
}

/// The scenario's solver options, with --gravity instead of its gravity.
SolverOptions solver_options(const RunArguments& a, const Scenario& scenario) {
    SolverOptions options = options_from(scenario.solver);
    if (!a.gravity.empty()) {
        const Eigen::Vector3d g(a.gravity[0], a.gravity[1], a.gravity[2]);
        if (!g.allFinite()) throw UsageError("--gravity must be three finite numbers, mm/ms²");
        if (g != options.gravity) {
            std::printf("gravity: (%.4g, %.4g, %.4g) mm/ms² instead of the scenario's (%.4g, %.4g, %.4g)%s\n", g.x(), g.y(), g.z(),
                        options.gravity.x(), options.gravity.y(), options.gravity.z(),
                        options.balanced_gravity != g ? "; the rest state is not balanced for it: the tissue moves to a new equilibrium"
                                                      : "");
            options.gravity = g;
        }
    }
    return options;
}

/// A replay steps with the solver's rules of the build that recorded (docs/haptics.md "Recording
/// and replay"), and says which differ from this build's.
void replay_rules(const Recording& recording, SolverOptions& options) {
    const SolverRules recorded = recording.rules.value_or(rules_before_recorded());
    if (!recording.rules)
        std::printf("replay: recorded before recordings kept the solver's rules: replaying with those heartsim had before the "
                    "probe's pierce and the one-piece grab\n");
    std::ostringstream differ;
    for_each_rule(
        [&](const char* name, const auto& value, const auto& this_build) {
            if (double(value) != double(this_build))
                differ << (differ.tellp() > 0 ? ", " : "") << name << " " << double(value) << " (this build: " << double(this_build) << ")";
        },
        recorded, options);
    if (differ.tellp() > 0) std::printf("replay: the recorded solver rules: %s\n", differ.str().c_str());
    static_cast<SolverRules&>(options) = recorded;
}

/// The GL context (a window unless --headless; a headless one where the backend or the
/// screenshots need it) and the backend.
void make_context_and_backend(const RunArguments& a, bool render, PreparedRun& p) {
    SolverOptions options = solver_options(a, p.scenario);
    if (p.replayed) replay_rules(*p.replayed, options);
    // A replay starts with the mass scale its first step ran with (and follows the recording's changes).
    options.mass_scale = p.replayed ? (p.replayed->steps.size() ? p.replayed->steps.mass_scale_at(0) : 1.0) : a.mass_scale.value_or(1.0);
    if (!a.headless)
        p.context.emplace(GlContext::create_window(p.frame_width, p.frame_height,
                                                   "heartsim — " + std::filesystem::path(a.scenario).filename().string()));
    // Without --backend, on a software rasteriser (Mesa llvmpipe, softpipe) the compute shaders
    // run on the CPU cores, about ten times slower than the cpu backend: a window, a haptic session
    // and a headless run simulate with it (a window and screenshots still draw with OpenGL), and
    // say so; a headless run that asks for what only the gl backend has (--contact picking or
    // search) keeps it.
    const bool needs_gl = parse_contact_mode(a.contact_mode()) != ContactMode::direct && a.headless && a.devices.empty();
    if (p.kind == BackendKind::gl && !a.backend && !needs_gl) {
        if (!p.context) p.context.emplace(GlContext::create_headless());
        const GlInfo info = p.context->info();
        if (is_software_rasteriser(info)) {
            p.kind = BackendKind::cpu;
            p.software_gl = true;
            std::printf("%s: the OpenGL device is %s, a software rasteriser: simulating with the cpu backend, which is faster "
                        "here%s (--backend gl to override)\n",
                        !a.devices.empty() ? "haptics" : a.headless ? "headless" : "window", info.renderer.c_str(),
                        a.headless ? "" : ", drawing with OpenGL");
            std::fflush(stdout);  // the first line a window's user (and its tests) read
        }
    }
    if (p.kind == BackendKind::gl) {
        if (!p.context) p.context.emplace(GlContext::create_headless());
        const GlInfo info = p.context->info();
        const std::size_t need = estimate_gl_memory_bytes(p.scenario);
        std::printf("gl: %s, OpenGL %d.%d; device memory needed %.1f MiB\n", info.renderer.c_str(), info.major, info.minor,
                    double(need) / (1024.0 * 1024.0));
        if (info.max_ssbo_bytes > 0 && (long long)(p.scenario.lattice.particles.size() * 18 * 4 + 4096) > info.max_ssbo_bytes)
            throw InputError("the neighbour table needs more than the largest shader storage block this device offers (" +
                             std::to_string(info.max_ssbo_bytes) + " bytes); run with --backend cpu");
        p.backend = make_gl_backend(*p.context, p.scenario, options);
    } else {
        SolverOptions cpu = options;
        if (p.replayed && p.replayed->backend == "cpu") {
            // Reproduce a cpu recording's forces to the bit: its slot arithmetic, whatever this CPU's
            // fastest kernel would do (docs/haptics.md "Recording and replay").
            cpu.arithmetic = p.replayed->arithmetic == "fused" ? SlotArithmetic::fused : SlotArithmetic::separate;
            if (cpu.arithmetic == SlotArithmetic::separate)
                std::printf("replay: recorded with the spring slot's multiply-adds rounded apart (the sse2 kernel, or a heartsim "
                            "whose kernels did not fuse them): replaying with the sse2 kernel\n");
        }
        p.backend = make_cpu_backend(p.scenario, cpu);
        if (render && !p.context) p.context.emplace(GlContext::create_headless());  // screenshots of the cpu backend
    }
    // A patch and its stitches ride on the backend: every mode's hands reach them (runtime/repair.h).
    RepairSettings repair;
    // A replay lays the patch the session laid (its recorded --patch-material).
    repair.material = patch_material_named(p.replayed ? p.replayed->patch_material : a.patch_material);
    p.backend = with_repair(std::move(p.backend), p.scenario, repair);
    p.repair = repair_of(*p.backend);
}

void make_renderer(PreparedRun& p, const std::optional<SectionRequest>& section) {
    p.context->make_current();
    p.renderer.emplace(p.scenario, RenderOptions{.width = p.frame_width, .height = p.frame_height, .view = p.view});
    Renderer& renderer = *p.renderer;
    if (renderer.draws_visual_mesh())
        std::printf("render: visual mesh, %zu vertices, %zu triangles, mapped onto %zu simulation-surface triangles; %dx%d\n",
                    renderer.vertex_count(), renderer.triangle_count(), p.scenario.simulation_surface->size(), renderer.width(),
                    renderer.height());
    else
        std::printf("render: no /visual mesh with /mapping: the simulation surface, %zu triangles (flat shaded); %dx%d\n",
                    renderer.triangle_count(), renderer.width(), renderer.height());
    if (section) {
        // --clip: the plane given, or through the model's centre facing the fitted camera.
        SectionPlane plane = section->plane;
        if (section->facing_view) plane = section_facing(renderer.camera(), renderer.model_centre());
        if (section->through_defect) {
            const ScenarioSource& source = p.scenario.source;
            if (source.defect.empty())
                throw UsageError("--clip defect: the scenario has no septal defect (heartprep build --defect vsd|asd makes one)");
            plane = section_through_defect(renderer.camera(), source.defect_centre.cast<float>(), source.defect_axis.cast<float>());
        }
        if (section->through_defect || section->aim_camera) aim_at_section(renderer.camera(), plane);
        renderer.set_section(plane);
        std::printf("section view: %s; the side the normal points to is not drawn\n", describe(plane, renderer.model_centre()).c_str());
    }
}

void set_contact(const RunArguments& a, PreparedRun& p) {
    ContactSettings contact;
    contact.mode = parse_contact_mode(a.contact_mode());
    contact.picking_refresh = a.picking_refresh_every();
    // Options that contradict each other (exit 2); the backend refuses it too, for its other callers.
    if (contact.mode != ContactMode::direct && p.kind != BackendKind::gl) throw UsageError("--contact picking|search needs --backend gl");
    // The refresh only paces the picking buffer: with any other contact it changed nothing, unsaid.
    if (a.picking_refresh && contact.mode != ContactMode::picking)
        throw UsageError("--picking-refresh paces the picking buffer: it needs --contact picking");
    if (contact.mode != ContactMode::direct && p.kind == BackendKind::gl)
        std::printf("contact: %s%s, %.2f MiB more device memory\n", to_string(contact.mode),
                    contact.mode == ContactMode::picking ? (" (buffer rendered every " + std::to_string(contact.picking_refresh) +
                                                            " force requests)").c_str() : "",
                    double(estimate_picking_memory_bytes(p.scenario, contact)) / (1024.0 * 1024.0));
    p.backend->set_contact(contact);
}

/// The instruments of --trajectory, or of --probe and --grab; in a window without a script,
/// the keyboard's probe on hand 0.
void script_instruments(const RunArguments& a, PreparedRun& p) {
    if (!a.trajectory.empty()) {
        if (!a.probe.empty() || !a.grab.empty()) throw UsageError("give --trajectory or --probe/--grab, not both");
        p.trajectory = read_trajectory(a.trajectory);
        // A patch lies on the detailed mesh (runtime/repair.h): without one, refuse before the
        // first step rather than stop the run when the hand lays it.
        if (!can_hold_patch(p.scenario))
            for (const InstrumentKeyframe& k : p.trajectory.keyframes)
                if (k.kind == InstrumentKind::patch || k.kind == InstrumentKind::needle) {
                    char when[200];
                    std::snprintf(when, sizeof when, "the --trajectory's %s of hand %d at %.6g ms", to_string(k.kind), k.hand, k.time_ms);
                    throw no_patch_surface(when);
                }
    } else {
        if (!a.probe.empty()) p.trajectory.keyframes.push_back(parse_fixed_instrument(a.probe, InstrumentKind::probe, 0));
        if (!a.grab.empty()) {
            // "X,Y,Z,AX,AY,AZ[,DX,DY,DZ]": grabs at the start, pulls by D over the run.
            InstrumentKeyframe start = parse_fixed_instrument(a.grab, InstrumentKind::grabber, 1);
            InstrumentKeyframe end = start;
            std::vector<double> values;
            {
                std::stringstream in(a.grab);
                std::string field;
                while (std::getline(in, field, ',')) values.push_back(std::stod(field));
            }
            if (values.size() == 9) end.pose.position += Eigen::Vector3d(values[6], values[7], values[8]);
            end.time_ms = (p.steps >= 0 ? p.steps : 1000) * p.backend->time_step_ms();  // a window without limit: over 1000 steps
            p.trajectory.keyframes.push_back(start);
            p.trajectory.keyframes.push_back(end);
        }
    }

    // Window without a script: the keyboard moves hand 0, the --probe or a default probe
    // (semi-axes 1.5 lattice spacings) in front of the model, between it and the camera.
    p.keyboard_hand0 = !a.headless && a.trajectory.empty();
    if (p.keyboard_hand0 && a.probe.empty()) {
        InstrumentKeyframe k;
        k.hand = 0;
        k.kind = InstrumentKind::probe;
        k.semi_axes = Eigen::Vector3d::Constant(1.5 * p.scenario.lattice.spacing);
        const Camera& camera = p.renderer->camera();
        const Eigen::Vector3d back = (camera.orientation * Eigen::Vector3f::UnitZ()).cast<double>();
        k.pose.position = camera.target.cast<double>() + back * (0.8 * camera.radius);
        p.trajectory.keyframes.insert(p.trajectory.keyframes.begin(), k);
    }
}

/// The devices of --device, described, and their session started.
std::unique_ptr<haptics::HapticRun> start_haptics(const RunArguments& a, PreparedRun& p) {
    haptics::HapticRunSettings settings;
    settings.devices = a.devices;
    settings.instruments = a.instruments;
    settings.session.rate_hz = a.haptic_rate;
    settings.session.safety.max_force_n = a.max_force.value_or(0.0);  // 0: each device's own maximum
    settings.session.interpolation = a.interpolation == "extrapolate" ? haptics::ForceInterpolation::extrapolate
                                                                      : haptics::ForceInterpolation::hold;
    settings.session.coupling.enabled = a.coupling;  // K, B chosen per device within the passivity bound
    settings.session.realtime = a.haptic_priority == "realtime";
    settings.record = a.record.value_or("");
    settings.contact = a.contact_mode();
    settings.patch_material = a.patch_material;
    settings.real_time_auto = a.real_time_mode() == RealTimeMode::automatic;
    haptics::HapticRunContext context_settings{.headless = a.headless};
    context_settings.camera = p.renderer ? p.renderer->camera()
                                         : fit_camera(model_box(p.scenario), p.view, float(p.frame_width) / float(p.frame_height));
    auto haptic = std::make_unique<haptics::HapticRun>(*p.backend, p.scenario, a.scenario, settings, context_settings);
    for (int hand = 0; hand < 2; ++hand)
        if (haptic->uses_hand(hand)) std::printf("%s\n", haptic->describe(hand).c_str());
    if (a.headless) std::printf("haptics: %s at %.0f Hz; the simulation follows real time; Ctrl-C ends the run cleanly\n",
                                a.seconds > 0 ? (std::to_string(a.seconds) + " s").c_str() : (std::to_string(p.steps) + " steps").c_str(),
                                a.haptic_rate);
    else std::printf("haptics: E = emergency stop (again: release), G = grab button of the mouse device, Ctrl + drag / wheel moves it\n");
    std::fflush(stdout);
    haptic->start();
    return haptic;
}

/// --stats: Sørensen & Mosegaard's Table 1, per pass.
void print_stats(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, double wall_ms) {
    const PassTimes t = p.backend->pass_times();
    std::printf("\nTable 1 (%s, %s timing)\n", to_string(p.kind), t.gpu_timed ? "GPU timer queries" : "wall clock");
    std::printf("%-22s %12s %12s\n", "pass", "per call ms", "calls");
    const double per_substep = t.substeps ? t.step_ms / double(t.substeps) : 0.0;
    std::printf("%-22s %12.4f %12lld   (%zu particles, 18 neighbours)\n", "simulation step", per_substep, t.substeps,
                p.backend->load_report().particles);
    if (p.renderer) {
        Renderer& renderer = *p.renderer;
        const RenderTimes r = renderer.times(true);
        if (r.normals_calls)
            std::printf("%-22s %12.4f %12lld   (compute, one invocation per surface particle)\n", "particle normals",
                        r.normals_ms / double(r.normals_calls), r.normals_calls);
        std::printf("%-22s %12.4f %12lld   (%s: %zu vertices, %zu faces; %dx%d)\n", "visualisation step",
                    r.frames ? r.draw_ms / double(r.frames) : 0.0, r.frames, renderer.draws_visual_mesh() ? "mapped visual mesh" : "simulation surface",
                    renderer.vertex_count(), renderer.triangle_count(), renderer.width(), renderer.height());
        if (r.uploads)
            std::printf("%-22s %12.4f %12lld   (cpu backend: positions to the GPU, wall clock)\n", "position upload", r.upload_ms / double(r.uploads),
                        r.uploads);
    } else {
        std::printf("%-22s %12s %12s\n", "visualisation step", "-", "skipped (headless, no --screenshot)");
    }
    if (t.picking_calls)
        std::printf("%-22s %12.4f %12lld   (%s; %lld buffer renders)\n", "picking buffer", t.picking_ms / double(t.picking_calls),
                    t.picking_calls, a.contact_mode().c_str(), t.picking_renders);
    else
        std::printf("%-22s %12s %12s\n", "picking buffer", "-", "none (--contact direct: the step's own probe test)");
    std::printf("%-22s %12.4f %12lld\n", "force buffer", t.force_calls ? t.force_ms / double(t.force_calls) : 0.0, t.force_calls);
    std::printf("steps/s (substeps/s)  %.0f from the step pass, %.0f overall\n", per_substep > 0 ? 1000.0 / per_substep : 0.0,
                run.substeps / (wall_ms * 1e-3));
}

/// --stats-csv: the --stats figures, one row per pass, with the run's columns repeated on every
/// row (tests/bench/run_runtime_bench.sh reads it). A pass that did not run: calls 0.
void write_stats_csv(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, double wall_ms) {
    const PassTimes t = p.backend->pass_times();
    const RenderTimes r = p.renderer ? p.renderer->times(true) : RenderTimes{};
    const std::string device = p.context ? p.context->info().renderer : std::string("none (cpu backend, headless, no GL context)");
    auto quote = [](const std::string& text) {
        std::string q = "\"";
        for (char c : text) q += c == '"' ? std::string("\"\"") : std::string(1, c);
        return q + "\"";
    };
    const double seconds = std::max(wall_ms * 1e-3, 1e-9);
    const double per_substep = t.substeps ? t.step_ms / double(t.substeps) : 0.0;
    char run_columns[512];
    std::snprintf(run_columns, sizeof run_columns, "%s,%s,%d,%s,%zu,%d,%lld,%.6f,%.6g,%.6g,%.6g,%lld,%.6g", to_string(p.kind),
                  a.contact_mode().c_str(), a.picking_refresh_every(), quote(device).c_str(), p.backend->load_report().particles, run.steps,
                  run.substeps, wall_ms, run.steps / seconds, run.substeps / seconds, per_substep > 0 ? 1000.0 / per_substep : 0.0, r.frames,
                  p.backend->options().mass_scale);
    std::ostringstream out;
    out << "pass,calls,total_ms,mean_ms,per,timing,backend,contact,picking_refresh,renderer,particles,steps,substeps,wall_ms,"
           "steps_per_s,substeps_per_s,step_pass_substeps_per_s,frames,mass_scale\n";
    const char* timing = t.gpu_timed ? "gpu" : "wall";
    auto row = [&](const char* pass, long long calls, double total_ms, const char* per, const char* how) {
        char line[256];
        std::snprintf(line, sizeof line, "%s,%lld,%.6f,%.6f,%s,%s,", pass, calls, total_ms, calls ? total_ms / double(calls) : 0.0, per, how);
        out << line << run_columns << '\n';
    };
    row("simulation step", t.substeps, t.step_ms, "substep", timing);
    row("particle normals", r.normals_calls, r.normals_ms, "frame", "gpu");
    row("visualisation step", r.frames, r.draw_ms, "frame", "gpu");
    row("position upload", r.uploads, r.upload_ms, "frame", "wall");
    row("picking buffer", t.picking_calls, t.picking_ms, "force request", timing);
    row("force buffer", t.force_calls, t.force_ms, "force request", timing);
    const std::string text = out.str();
    write_bytes_atomically(a.stats_csv, text.data(), text.size(), "the --stats-csv table");
    std::printf("wrote %s\n", a.stats_csv.c_str());
}

/// The run's incision state, made at the first stroke; null without a mapped visual mesh or
/// before any stroke.
IncisionState* incision_state(PreparedRun& p, const StrokeLog& log) {
    const Scenario& scenario = p.scenario;
    if (!scenario.visual || !scenario.mapping || !scenario.simulation_surface || scenario.visual->positions.empty()) return nullptr;
    if (!p.incisions && !log.strokes().empty())
        p.incisions = std::make_unique<IncisionState>(scenario.lattice, scenario.visual->positions, scenario.visual->normals,
                                                      scenario.visual->triangles, *scenario.mapping, *scenario.simulation_surface);
    return p.incisions.get();
}

/// `positions`, or the backend's read into `read`.
const std::vector<std::array<float, 3>>& positions_or_read(PreparedRun& p, const std::vector<std::array<float, 3>>* positions,
                                                            std::vector<std::array<float, 3>>& read) {
    if (positions) return *positions;
    read = p.backend->positions();
    return read;
}

/// The renderer draws the incision state's mesh from the next frame on.
void draw_incisions(PreparedRun& p) {
    const IncisionState& cut = *p.incisions;
    if (p.link) p.link->set_drawn_mesh(cut.drawn_triangles(), cut.mapping());  // and Slicer from its next mesh on
    if (!p.renderer || !p.renderer->draws_visual_mesh()) return;
    p.renderer->set_visual(cut.rest_positions(), cut.rest_normals(), cut.drawn_triangles(), cut.mapping(), cut.cap_first());
}

/// The renderer draws the repair's patch and stitches as they are now from the next frame on
/// (none before a patch is laid).
void draw_repair(PreparedRun& p) {
    if (!p.renderer) return;
    if (const PatchModel* patch = p.repair ? p.repair->patch() : nullptr) p.renderer->set_patch(drawn_patch(*patch, p.repair->stitch_anchors()));
    else p.renderer->clear_patch();
}

/// The repair as the link sends it, made only when a mesh is sent (none before a patch is laid).
SlicerLink::PatchSource link_patch(PreparedRun& p) {
    return [&p] {
        const PatchModel* patch = p.repair ? p.repair->patch() : nullptr;
        return patch ? drawn_patch(*patch, p.repair->stitch_anchors()) : DrawnPatch{};
    };
}

}  // namespace

bool open_incisions(PreparedRun& p, bool finish, const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    const StrokeLog& log = strokes ? *strokes : p.backend->strokes();
    IncisionState* incisions = incision_state(p, log);
    if (!incisions || !incisions->pending(log, finish)) return false;
    std::vector<std::array<float, 3>> read;
    const IncisionUpdate update = incisions->update(log, positions_or_read(p, positions, read), finish);
    for (const std::string& failure : update.failures)
        std::printf("incision: the detailed mesh does not open along one stroke: %s (the tissue is cut; the mesh stays closed)\n", failure.c_str());
    if (!update.opened) return false;
    const IncisionState& cut = *incisions;
    if (cut.cut())
        std::printf("incision: the detailed mesh opened along %zu stroke(s): %zu vertices, %zu triangles of which %zu cut faces; %zu vertices "
                    "embedded on their own side (%.0f ms)\n",
                    update.strokes, cut.mesh().rest.size(), cut.drawn_triangles().size(), cut.drawn_triangles().size() - cut.cap_first(),
                    update.reembedded, 1e3 * update.seconds);
    std::fflush(stdout);  // a window's user (and its tests) read it as it happens
    draw_incisions(p);
    return true;
}

bool preview_incisions(PreparedRun& p, const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    if (!p.renderer || !p.renderer->draws_visual_mesh()) return false;
    const StrokeLog& log = strokes ? *strokes : p.backend->strokes();
    if (log.strokes().empty() || log.version() == p.previewed_strokes) return false;
    if (std::chrono::steady_clock::now() - p.previewed < std::chrono::milliseconds(250)) return false;
    IncisionState* incisions = incision_state(p, log);
    if (!incisions) return false;
    std::vector<std::array<float, 3>> read;
    p.previewed_strokes = log.version();
    const IncisionUpdate update = incisions->preview(log, positions_or_read(p, positions, read));
    p.previewed = std::chrono::steady_clock::now();  // the next one a quarter second after this one ends
    if (!update.opened) return false;
    draw_incisions(p);
    return true;
}

namespace {

/// --save-state: the final positions, the forces, what each hand held and the springs cut.
/// The detailed mesh as drawn at `positions`: the mapping evaluated there (libmodel apply_mapping,
/// the vertex shader's formula and float order); once cut, the incision's mesh and mapping. Needs
/// the scenario's visual mesh, mapping and simulation surface.
std::vector<std::array<float, 3>> drawn_detailed_mesh(const PreparedRun& p, const std::vector<std::array<float, 3>>& positions) {
    const bool opened = p.incisions && p.incisions->cut();
    const auto visual = apply_mapping(opened ? p.incisions->mapping() : *p.scenario.mapping, positions, *p.scenario.simulation_surface);
    std::vector<std::array<float, 3>> out;
    out.reserve(visual.size());
    for (const auto& v : visual) out.push_back({v.x(), v.y(), v.z()});
    return out;
}

void save_state(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const InstrumentForces& forces,
                const std::vector<std::array<float, 3>>& positions, const haptics::HapticRun* haptic) {
    const Recording* replayed = p.replayed ? &*p.replayed : nullptr;
    SimulationState state;
    state.backend = to_string(p.kind);
    state.scenario = std::filesystem::path(a.scenario).filename().string();
    state.time_ms = p.backend->simulated_time_ms();
    state.steps = run.steps;
    state.mass_scale = p.backend->options().mass_scale;
    state.positions = positions;
    for (int hand = 0; hand < 2; ++hand) {
        for (int c = 0; c < 3; ++c) state.force_n[hand][c] = forces.hand[hand].force_n[c];
        state.particles[hand] = std::int32_t(forces.hand[hand].particles);
        if (haptic) {
            state.kind[hand] = !haptic->uses_hand(hand) ? 0 : std::int32_t(instrument_code(haptic->instrument(hand)));
        } else if (replayed) {  // a replay: the instruments the recording's hands held at its last step
            state.kind[hand] = std::int32_t(instrument_code(replayed->instrument_at(replayed->steps.size() ? replayed->steps.size() - 1 : 0, hand).kind));
        } else {
            state.kind[hand] = p.trajectory.uses_hand(hand) ? std::int32_t(instrument_code(p.trajectory.at(hand, p.backend->simulated_time_ms()).kind)) : 0;
        }
    }
    state.cut_springs = p.backend->cut_springs();
    if (const PatchModel* patch = p.repair ? p.repair->patch() : nullptr) {
        PatchState out;
        out.material = patch->spec().material.name;
        out.thickness_mm = patch->spec().thickness_mm;
        out.youngs_modulus_mpa = patch->spec().material.youngs_modulus_mpa;
        for (const auto& x : patch->positions()) out.positions.push_back({float(x.x()), float(x.y()), float(x.z())});
        out.triangles = patch->triangles();
        const auto anchors = p.repair->stitch_anchors();
        for (std::size_t k = 0; k < patch->stitches().size(); ++k) {
            const Stitch& stitch = patch->stitches()[k];
            out.stitch_vertex.push_back(stitch.vertex);
            out.stitch_anchor.push_back({float(anchors[k].x()), float(anchors[k].y()), float(anchors[k].z())});
            out.stitch_force.push_back({stitch.force_n.x(), stitch.force_n.y(), stitch.force_n.z()});
            out.stitch_tied_ms.push_back(stitch.tied_ms);
        }
        if (p.closure) {
            out.has_defect = true;
            for (int c = 0; c < 3; ++c) out.defect_centre[c] = p.closure->frame.centre[c], out.defect_axis[c] = p.closure->frame.axis[c];
            out.defect_diameter_mm = p.closure->frame.diameter_mm;
            out.closed = p.closure->result.closed;
            out.largest_rim_gap_mm = p.closure->result.largest_rim_gap_mm;
            if (const auto& leak = p.closure->result.leak_mm) out.leak_mm = std::array<double, 3>{leak->x(), leak->y(), leak->z()};
            out.leak_test_mmhg = a.leak_test_mmhg;
            out.leak_test_positions = p.closure->tested_patch;
            out.rim_offset_mm = p.closure->rim_offset_mm;
            out.margin_mm = p.closure->margin_mm;
        }
        state.patch = std::move(out);
    }
    if (p.scenario.visual && p.scenario.mapping && p.scenario.simulation_surface) {
        state.visual_positions = drawn_detailed_mesh(p, positions);
        if (p.incisions && p.incisions->cut()) {
            state.visual_triangles = p.incisions->drawn_triangles();
            state.visual_cap_first = p.incisions->cap_first();
        }
    }
    state.scenario_path = a.scenario;
    if (p.scenario.simulation_surface) state.scenario_simsurface_triangles = p.scenario.simulation_surface->size();
    if (p.scenario.visual) state.scenario_visual_triangles = p.scenario.visual->triangles.size();
    write_state(a.save_state, state);
    std::printf("wrote %s\n", a.save_state.c_str());
}

/// The closure check at the end of a run on a scenario with a defect (libmodel/closure.h): the
/// detailed mesh as drawn and the patch after the leak test, one line a trainer reads.
void report_closure(const RunArguments& a, PreparedRun& p, const std::vector<std::array<float, 3>>& positions) {
    const PatchModel* patch = p.repair ? p.repair->patch() : nullptr;
    const auto frame = defect_frame_now(p.scenario, positions, patch);
    p.closure.reset();
    if (!frame || !p.scenario.visual || !p.scenario.mapping || !p.scenario.simulation_surface) return;
    const auto tissue = drawn_detailed_mesh(p, positions);
    const bool opened = p.incisions && p.incisions->cut();
    const auto& triangles = opened ? p.incisions->drawn_triangles() : p.scenario.visual->triangles;
    std::vector<std::array<float, 3>> patch_positions;
    std::vector<std::array<std::int32_t, 3>> patch_triangles;
    double thickness = 0;
    if (patch) {
        const PatchModel tested = patch->under_pressure(p.repair->positions_of(patch->particles()), a.leak_test_mmhg * mmhg_in_n_per_mm2);
        for (const auto& x : tested.positions()) patch_positions.push_back({float(x.x()), float(x.y()), float(x.z())});
        patch_triangles = tested.triangles();
        thickness = tested.spec().thickness_mm;
    }
    try {
        // The patch's reach: its half-diameters, as laid.
        const ClosureOptions options =
            patch ? repair_closure_options(*frame, std::max(patch->spec().radius_x_mm, patch->spec().radius_y_mm), p.repair->stitch_anchors())
                  : ClosureOptions{};
        const ClosureResult r = check_closure(tissue, triangles, patch_positions, patch_triangles, thickness, *frame, options);
        p.closure = PreparedRun::ClosureReport{r, *frame, patch_positions, options.rim_offset_mm, options.margin_mm};
        if (r.cannot_tell) std::printf("defect closed: %s\n", r.why.c_str());  // "cannot tell: …"
        else if (r.closed) std::printf("defect closed: yes, largest rim gap %.2f mm\n", r.largest_rim_gap_mm);
        else std::printf("defect closed: no, largest rim gap %.2f mm (%s)\n", r.largest_rim_gap_mm, r.why.c_str());
        std::printf("  closure check: %s, %zu stitches, the patch held to %.3g mmHg across the septum; a flood fill of %zu voxels of "
                    "%.2f mm reached %zu from the far side; wall %.1f mm thick; %d rim points (%.2f s)\n",
                    patch ? "a patch" : "no patch", patch ? patch->stitches().size() : std::size_t(0), a.leak_test_mmhg, r.voxels,
                    ClosureOptions{}.voxel_mm, r.reached, r.wall_thickness_mm, r.rim_points, r.seconds);
        if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::rim)
            std::printf("  the leak: its way out of the opening passes the rim widest at (%.1f, %.1f, %.1f) mm, %s\n", r.leak_mm->x(),
                        r.leak_mm->y(), r.leak_mm->z(), leak_place(r).c_str());
        else if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::through_patch)
            std::printf("  the leak: its way out of the opening does not pass the rim but goes through the patch, out at (%.1f, %.1f, %.1f) mm\n",
                        r.leak_mm->x(), r.leak_mm->y(), r.leak_mm->z());
        else if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::uncovered)
            std::printf("  the leak: the fill found no way out, but the patch leaves the opening uncovered around (%.1f, %.1f, %.1f) mm\n",
                        r.leak_mm->x(), r.leak_mm->y(), r.leak_mm->z());
    } catch (const InputError& e) {
        std::printf("defect closed: cannot tell (%s)\n", e.what());
    }
}

/// After every mode but --replay: the last screenshot, the summary, --stats, --stats-csv,
/// --save-state. Returns the exit status: 4 when a haptic device faulted, else 0.
int finish_run(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const haptics::HapticRun* haptic,
               Clock::time_point wall_start) {
    Backend& backend = *p.backend;
    auto uses_hand = [&](int hand) { return haptic ? haptic->uses_hand(hand) : p.trajectory.uses_hand(hand); };
    open_incisions(p, true);  // a stroke still under way counts as finished
    if (p.renderer && !a.screenshot.empty()) {
        draw_repair(p);
        p.renderer->render(backend, haptic ? haptic->shapes() : shapes_at(p.trajectory, backend.simulated_time_ms()));
        write_png(a.screenshot, p.renderer->read_pixels());
        std::printf("wrote %s (%dx%d)\n", a.screenshot.c_str(), p.renderer->width(), p.renderer->height());
    }
    const InstrumentForces forces = backend.instrument_forces();       // waits: the run is finished
    const auto positions = backend.positions();
    const double wall_ms = std::chrono::duration<double, std::milli>(Clock::now() - wall_start).count();

    // Steps the watchdog rolled back are not counted: the simulated time says how far the run got.
    const long long advanced = run.watchdog_events ? std::llround(backend.simulated_time_ms() / backend.time_step_ms()) : run.steps;
    std::printf("ran %lld steps (%lld substeps), %.4g ms simulated in %.4g ms wall: %.0f substeps/s, real-time factor %.3g\n", advanced,
                run.substeps, backend.simulated_time_ms(), wall_ms, run.substeps / (wall_ms * 1e-3), backend.simulated_time_ms() / wall_ms);
    if (run.watchdog_events) std::printf("watchdog: %zu events; last: %s\n", run.watchdog_events, run.last_watchdog_message.c_str());
    if (p.repair && p.repair->patch_steps() > 0) {
        if (const auto [device_ms, timed] = p.repair->patch_device_time(); timed > 0)
            std::printf("repair: the GPU spent %.3g ms on each of the patch's %lld steps it ran (%.1f %% of the wall time)\n",
                        device_ms / double(timed), timed, 100.0 * device_ms / wall_ms);
        std::printf(p.repair->patch_on_device()
                        ? "repair: the patch's %lld steps (one every %d of the tissue's) ran on the GPU before the tissue's; the host "
                          "took %.3g ms each (queueing them, finding the surface near the patch again every 64, reading it back): "
                          "%.1f %% of the wall time\n"
                        : "repair: the patch's %lld steps (one every %d of the tissue's) took %.3g ms each (reading the tissue, stepping "
                          "the patch, loading the tissue): %.1f %% of the wall time\n",
                    p.repair->patch_steps(), p.repair->settings().patch_every, p.repair->patch_ms() / double(p.repair->patch_steps()),
                    100.0 * p.repair->patch_ms() / wall_ms);
    }
    {
        // How far the tissue is from where it was imaged: a heart that is held stays in place.
        const auto& rest = p.scenario.lattice.particles.rest_position;
        double largest = 0.0, sum = 0.0;
        std::size_t worst = 0;
        for (std::size_t i = 0; i < positions.size() && i < rest.size(); ++i) {
            const double d = std::sqrt(std::pow(double(positions[i][0]) - rest[i][0], 2) + std::pow(double(positions[i][1]) - rest[i][1], 2) +
                                       std::pow(double(positions[i][2]) - rest[i][2], 2));
            sum += d;
            if (d > largest) largest = d, worst = i;
        }
        std::printf("displacement from rest: max %.4g mm (particle %zu), mean %.4g mm\n", largest, worst,
                    positions.empty() ? 0.0 : sum / double(positions.size()));
    }
    for (int hand = 0; hand < 2; ++hand) {
        if (!uses_hand(hand)) continue;
        const auto& f = forces.hand[hand];
        std::printf("hand %d force (%.6g, %.6g, %.6g) N on %zu particles\n", hand, f.force_n.x(), f.force_n.y(), f.force_n.z(), f.particles);
    }
    if (p.repair || !p.scenario.source.defect.empty()) report_closure(a, p, positions);
    if (a.stats) print_stats(a, p, run, wall_ms);
    if (!a.stats_csv.empty()) write_stats_csv(a, p, run, wall_ms);
    if (!a.save_state.empty()) save_state(a, p, run, forces, positions, haptic);
    if (run.gave_up) {
        std::fprintf(stderr, "heartsim: error: the simulation could not recover and stopped: %s\n", one_line(run.last_watchdog_message).c_str());
        return exit_status(ExitCode::unrecoverable);
    }
    if (haptic && haptic->device_faulted()) {
        std::fprintf(stderr, "heartsim: error: a haptic device faulted during the session (above); the run's outputs were written\n");
        return exit_status(ExitCode::haptic_device);
    }
    return 0;
}

}  // namespace

PreparedRun::PreparedRun(const RunArguments& a) {
    // --replay checks a recording: the cpu backend (the reference, deterministic) unless --backend says otherwise.
    kind = parse_backend_kind(!a.replay.empty() && !a.backend ? "cpu" : a.backend.value_or("gl"));
    check_arguments(a);
    // --igtl: the port is taken now, so a port in use is said before the scenario is read.
    if (!a.igtl.empty())
        link = SlicerLink::open({.endpoint = a.igtl,
                                 .bind = a.igtl_bind.value_or("127.0.0.1"),
                                 .ras = a.igtl_frame.value_or("ras") == "ras",
                                 .mesh_rate_hz = a.igtl_mesh_rate.value_or(20.0),
                                 .wait_s = a.igtl_wait.value_or(0.0)});
    // Rendering only where it is seen: a window, or a screenshot (docs/runtime.md "Rendering").
    const bool render = !a.headless || !a.screenshot.empty();
    std::tie(frame_width, frame_height) = parse_size(a.size, a.headless ? std::pair{1024, 768} : std::pair{1280, 800});
    // --view section: the fitted anterior camera first, then turned to the plane (make_renderer).
    if (a.view == "section" && a.clip.empty())
        throw UsageError("--view section looks straight at the section plane: give --clip (a plane, centre or defect)");
    view = parse_view_direction(a.view == "section" ? "anterior" : a.view);
    std::optional<SectionRequest> section;
    if (!a.clip.empty()) section = parse_section_option(a.clip);
    if (section && a.view == "section") section->aim_camera = true;
    // --look-at: the camera centred on a point, after the view and the section have turned it.
    std::optional<LookAt> look;
    if (!a.look_at.empty()) look = parse_look_at(a.look_at);
    if (look && a.headless && a.screenshot.empty()) throw UsageError("--look-at aims the camera: headless it needs --screenshot");

    scenario = read_scenario(a.scenario);
    require_runnable(scenario, a.scenario);
    if (!a.replay.empty()) replayed = read_recording(a.replay);
    make_context_and_backend(a, render, *this);
    if (render) make_renderer(*this, section);
    if (render && look) aim_camera_at(renderer->camera(), *look);
    set_contact(a, *this);
    const SolverLoadReport& load = backend->load_report();
    steps = a.steps.value_or(0);
    if (a.seconds > 0) steps = int(std::ceil(a.seconds * 1000.0 / backend->time_step_ms() - 1e-9));
    // --steps 0: no step (the rest state, e.g. for a screenshot); no --steps: 1 step headless,
    // no limit in a window.
    if (steps <= 0) steps = a.steps == 0 ? 0 : a.headless ? 1 : -1;
    std::printf("%s backend: %zu particles, %zu springs, %zu anchored; step %.4g ms = %d substeps of %.4g ms (critical %.4g ms)\n",
                to_string(kind), load.particles, load.springs, load.anchored, backend->time_step_ms(), backend->substeps_per_step(),
                backend->substep_ms(), load.critical_dt_ms);
    if (load.mass_scale != 1.0)
        std::printf("mass scale %g: inertia × %g in the step (critical %.4g ms unscaled); %s\n", load.mass_scale, load.mass_scale,
                    load.unscaled_critical_dt_ms, mass_scale_cost(load.mass_scale).c_str());
    else if (a.real_time_mode() == RealTimeMode::automatic)
        std::printf("real time: auto: measuring this machine's speed over the first half second; mass scale 1 until then\n");
    script_instruments(a, *this);
    if (link) link->start(scenario);
}

int replay_mode(const RunArguments& a, PreparedRun& run) {
    Backend& backend = *run.backend;
    const Recording& recording = *run.replayed;
    // Each hand's instrument, and those the window switched it to (K, Shift + P, Shift + N) in turn.
    auto held = [&recording](int hand) {
        if (!recording.hands[std::size_t(hand)].used) return std::string();
        std::string words = "hand " + std::to_string(hand) + " " + recording.hands[std::size_t(hand)].instrument;
        const char* joint = ", then ";
        InstrumentKind last = recording.instrument_at(0, hand).kind;
        for (std::size_t k = 1; k < recording.steps.instrument.size(); ++k)
            if (const InstrumentKind now = recording.instrument_at(k, hand).kind; now != last) {
                words += joint + std::string(to_string(now));
                joint = ", ";
                last = now;
            }
        return words;
    };
    std::printf("replay: %s (%s backend, %zu steps of %.4g ms, %s%s%s) on the %s backend\n", a.replay.c_str(), recording.backend.c_str(),
                recording.steps.size(), recording.dt_ms, held(0).c_str(), recording.hands[0].used && recording.hands[1].used ? "; " : "",
                held(1).c_str(), to_string(backend.kind()));
    // The recording's contact mode, unless --contact says otherwise (the cpu backend has only
    // `direct`: a gl recording made with another mode is compared as is and may differ).
    if (!a.contact && recording.contact != "direct") {
        if (backend.kind() == BackendKind::gl) {
            ContactSettings contact;
            contact.mode = parse_contact_mode(recording.contact);
            backend.set_contact(contact);
            std::printf("replay: --contact %s, as recorded\n", recording.contact.c_str());
        } else {
            std::printf("replay: recorded with --contact %s on gl; the cpu backend's contacts are direct, so forces may differ\n",
                        recording.contact.c_str());
        }
    }
    const haptics::ReplayResult r = haptics::replay(backend, recording, a.replay, [&run] { open_incisions(run, false); });
    const bool exact = recording.backend == "cpu" && backend.kind() == BackendKind::cpu;
    const double tolerance = a.replay_tolerance >= 0 ? a.replay_tolerance : exact ? 0.0 : 0.10 * r.max_force_n;
    std::printf("replay: %zu steps in %.4g ms; %zu forces compared, %zu bit for bit identical; max |Δf| %.3g N, rms %.3g N "
                "(largest recorded force %.4g N%s)\n",
                r.steps, r.wall_ms, r.compared, r.identical, r.max_difference_n, r.rms_difference_n, r.max_force_n,
                r.worst_step >= 0 && r.max_difference_n > 0 ? (", worst at step " + std::to_string(r.worst_step)).c_str() : "");
    // The closure check every run on a defect ends with (finish_run's), on the state the replay reached.
    if (run.repair || !run.scenario.source.defect.empty()) {
        open_incisions(run, true);
        report_closure(a, run, backend.positions());
    }
    if (run.renderer && !a.screenshot.empty()) {
        draw_repair(run);
        run.renderer->render(backend, {});
        write_png(a.screenshot, run.renderer->read_pixels());
        std::printf("wrote %s\n", a.screenshot.c_str());
    }
    if (!a.save_state.empty()) {  // the state the replay ended in: positions, forces, the springs it cut
        ScriptedRunResult replayed;
        replayed.steps = int(r.steps);
        open_incisions(run, true);
        save_state(a, run, replayed, backend.instrument_forces(), backend.positions(), nullptr);
    }
    if (r.max_difference_n > tolerance) {
        std::fprintf(stderr, "heartsim: error: %s: the replay's forces differ from the recording by up to %.3g N (tolerance %.3g N%s)\n",
                     a.replay.c_str(), r.max_difference_n, tolerance, exact ? ": a cpu recording replayed on cpu must be identical" : "");
        return exit_status(ExitCode::replay_mismatch);
    }
    std::printf("replay: the forces %s\n", r.identical == r.compared ? "match the recording bit for bit"
                                                                    : ("match the recording within " + std::to_string(tolerance) + " N").c_str());
    return 0;
}

int headless_haptic_mode(const RunArguments& a, PreparedRun& run) {
    catch_interrupts();  // before start_haptics says that Ctrl-C ends the run cleanly
    const std::unique_ptr<haptics::HapticRun> haptic = start_haptics(a, run);
    const auto wall_start = Clock::now();
    ScriptedRunResult result;
    const double end_ms = a.seconds > 0 ? a.seconds * 1000.0 : 1e300;
    const double started = haptic->session().now_ms();
    while (!interrupted.load() && !haptic->result().gave_up && haptic->session().now_ms() - started < end_ms &&
           (a.seconds > 0 || haptic->rows() < std::size_t(run.steps))) {
        const int limit = a.seconds > 0 ? 1000 : run.steps - int(haptic->rows());
        const int stepped = haptic->step_to_real_time(limit);
        if (stepped > 0) open_incisions(run, false);  // the device thread goes on meanwhile
        if (stepped == 0)
            std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(std::clamp(haptic->ms_until_next_step(), 0.05, 1.0)));
        if (run.link && run.link->due())
            run.link->offer(*run.backend, (long long)haptic->rows(), link_hands(haptic->shapes(), haptic->latest_published_forces()),
                            SlicerLink::State::running, link_patch(run));
    }
    if (interrupted.load()) std::printf("interrupted: ending the session\n");
    haptic->finish(result);
    // Ctrl-C stays caught while the outputs are written: a state is never cut off half way.
    const int status = finish_run(a, run, result, haptic.get(), wall_start);
    if (run.link)
        run.link->finish(*run.backend, result.steps, link_hands(haptic->shapes(), run.backend->instrument_forces()), link_patch(run));
    restore_interrupts();
    return status;
}

int window_mode(const RunArguments& a, PreparedRun& run) {
    if (!a.devices.empty()) catch_interrupts();  // before start_haptics says how a session ends
    const std::unique_ptr<haptics::HapticRun> haptic = a.devices.empty() ? nullptr : start_haptics(a, run);
    const auto wall_start = Clock::now();
    const WindowRunOptions window{.scenario_name = std::filesystem::path(a.scenario).filename().string(),
                                  .scenario_path = a.scenario,
                                  .screenshot = a.screenshot,
                                  .screenshot_every = a.screenshot_every,
                                  .draw_share = a.draw_share,
                                  .interrupted = &interrupted,
                                  .real_time_auto = a.real_time_mode() == RealTimeMode::automatic,
                                  .end_ms = a.seconds > 0 ? a.seconds * 1000.0 : 0.0,
                                  .backend_note = run.software_gl ? "OpenGL is software" : "",
                                  .link = run.link.get(),
                                  .open_incisions = [&run](const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
                                      if (!open_incisions(run, false, positions, strokes)) preview_incisions(run, positions, strokes);
                                  },
                                  .scenario = &run.scenario};
    ScriptedRunResult result =
        run_window(*run.context, *run.backend, *run.renderer, run.trajectory, run.keyboard_hand0, run.steps, window, haptic.get());
    if (haptic) {
        if (interrupted.load()) std::printf("interrupted: ending the session\n");
        haptic->finish(result);  // Ctrl-C stays caught until the outputs are written (below)
    }
    const int status = finish_run(a, run, result, haptic.get(), wall_start);
    // After the run's outputs: the final mesh is the one they hold (a stroke under way opened).
    if (run.link)
        run.link->finish(*run.backend, result.steps,
                         haptic ? link_hands(haptic->shapes(), run.backend->instrument_forces())
                                : link_hands(run.trajectory, run.backend->simulated_time_ms(), run.backend->instrument_forces()),
                         link_patch(run));
    if (haptic) restore_interrupts();
    return status;
}

int headless_scripted_mode(const RunArguments& a, PreparedRun& run) {
    const auto wall_start = Clock::now();
    ScriptedRunOptions scripted{.steps = run.steps, .forces_every_step = !run.trajectory.keyframes.empty()};
    if (a.seconds > 0) scripted.end_ms = a.seconds * 1000.0;  // the steps lengthen when --real-time auto scales mass
    if (run.renderer && a.screenshot_every > 0)
        scripted.on_step = [&](int step, const StepReport&) {
            if ((step + 1) % a.screenshot_every != 0) return;
            draw_repair(run);
            run.renderer->render(*run.backend, shapes_at(run.trajectory, run.backend->simulated_time_ms()));
            write_png(numbered_screenshot(a.screenshot, step + 1), run.renderer->read_pixels());
        };
    // --real-time auto on a scripted run: the wall clock the run has taken against the simulated time.
    std::optional<MassScaleGovernor> governor;
    if (a.real_time_mode() == RealTimeMode::automatic) {
        governor.emplace(*run.backend);
        scripted.on_step = [&, screenshots = scripted.on_step](int step, const StepReport& report) {
            if (screenshots) screenshots(step, report);
            const double wall_ms = std::chrono::duration<double, std::milli>(Clock::now() - wall_start).count();
            if (auto change = governor->observe(wall_ms, run.backend->simulated_time_ms())) std::printf("%s\n", change->c_str());
        };
    }
    // --igtl: the state after each step to the link, when a frame is due (never waits on the network).
    if (run.link)
        scripted.on_step = [&, before = scripted.on_step](int step, const StepReport& report) {
            if (before) before(step, report);
            if (!run.link->due()) return;
            run.link->offer(*run.backend, step + 1, link_hands(run.trajectory, run.backend->simulated_time_ms(), run.backend->latest_forces()),
                            SlicerLink::State::running, link_patch(run));
        };
    // A stroke's blade lifted: the detailed mesh opens along it from the positions of that step
    // (before anything else sees the step: a screenshot shows it opened).
    scripted.on_step = [&, before = scripted.on_step](int step, const StepReport& report) {
        open_incisions(run, false);
        if (before) before(step, report);
    };
    const ScriptedRunResult result = run_scripted(*run.backend, run.trajectory, scripted);
    const int status = finish_run(a, run, result, nullptr, wall_start);
    if (run.link)
        run.link->finish(*run.backend, result.steps,
                         link_hands(run.trajectory, run.backend->simulated_time_ms(), run.backend->instrument_forces()), link_patch(run));
    return status;
}

int recover_recording(const std::string& journal, const std::string& output) {
    namespace fs = std::filesystem;
    const std::string suffix = ".journal";
    fs::path target = output;
    if (target.empty()) {
        if (journal.size() <= suffix.size() || journal.compare(journal.size() - suffix.size(), suffix.size(), suffix) != 0)
            throw UsageError(journal + ": not named OUT.h5.journal; give the recording to write with -o OUT.h5");
        target = journal.substr(0, journal.size() - suffix.size());
        const std::string name = text::lowercase(target.filename().string());
        if (!name.ends_with(".h5") && !name.ends_with(".hdf5"))
            throw UsageError(journal + ": not named OUT.h5.journal, so the recording's name cannot be " + target.string() +
                             "; give it with -o OUT.h5");
    }
    // A recording is a new file: whatever holds the name already (a scenario, an earlier
    // recording, anything) is left alone.
    if (std::error_code error; fs::exists(target, error))
        throw UsageError(target.string() + " exists; `heartsim recover` writes a new file: give another with -o OTHER.h5, or delete " +
                         target.string() + " first");
    if (journal_in_use(journal))
        throw InputError(journal + ": a running heartsim session is writing it; it writes its recording itself when it ends");
    check_destination(target);  // before the journal is read (seconds for a long session)
    check_xdmf_destination(target);
    const JournalContents contents = read_recording_journal(journal);
    const Recording& r = contents.recording;
    std::size_t ticks = 0;
    for (const RecordedHand& hand : r.hands) ticks = std::max(ticks, hand.tick_time_ms.size());
    std::printf("recover: %s: a --record %s session on %s (%s backend, %lld particles) by process %lld\n", journal.c_str(),
                contents.target.c_str(), r.scenario.c_str(), r.backend.c_str(), (long long)r.particles, (long long)contents.pid);
    std::printf("recover: %zu chunks: %zu steps (%.4g ms simulated), %zu device ticks, %zu events; %s\n", contents.chunks, r.steps.size(),
                r.steps.size() ? r.steps.time_ms.back() - r.steps.time_ms.front() + r.dt_ms : 0.0, ticks, r.events.size(),
                contents.ended ? "the session ended normally (its recording was not written)"
                               : contents.ignored_bytes ? ("the session was killed while writing its last chunk (" +
                                                           std::to_string(contents.ignored_bytes) + " bytes, not kept)").c_str()
                                                        : "the session was killed (an `interrupted` event marks where the journal ends)");
    if (r.steps.size() == 0)
        throw InputError(journal + ": holds no step (the session was killed within its first half second): nothing to recover; delete it");
    // Written beside the target and read back with every check a recording gets before it takes the
    // name, so what takes the name is a recording that reads; then its .xmf2 under that name.
    write_recording(target, r, [&](const fs::path& temporary) {
        try {
            read_recording(temporary);
        } catch (const InputError& e) {
            throw InputError(journal + ": the recovered session does not pass a recording's checks: " + e.what());
        }
    });
    std::printf("wrote %s (%zu steps, %zu device ticks, %zu events)\n", target.c_str(), r.steps.size(), ticks, r.events.size());
    std::error_code error;
    fs::remove(journal, error);
    if (error) std::fprintf(stderr, "heartsim: warning: %s: cannot delete it (%s); delete it before recording to %s again\n", journal.c_str(),
                            error.message().c_str(), contents.target.c_str());
    else std::printf("deleted %s\n", journal.c_str());
    return 0;
}

}  // namespace heartsim
