// What every mode of `heartsim run` starts from (run_modes.h PreparedRun): the arguments checked,
// the scenario read, the GL context, the backend, the renderer, the contacts and the instruments.
// What it prints, in the order it prints it, is the command's output the CLI tests check.
#include "runtime/app/run_modes.h"


#include "runtime/gl/backend_gl.h"
#include "runtime/gl/picking.h"

#include "runtime/haptics/haptic_run.h"
#include "runtime/view/png.h"
#include "runtime/view/section_plane.h"
#include "runtime/core/stepping.h"
#include "runtime/app/window_run.h"

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
    // A patch and its stitches ride on the backend: every mode's hands reach them (runtime/surgery/repair.h).
    RepairSettings repair;
    // A replay lays the patch the session laid (its recorded --patch-material).
    repair.material = patch_material_named(p.replayed ? p.replayed->patch_material : a.patch_material);
    p.backend = with_repair(std::move(p.backend), p.scenario, repair);
    p.repair = repair_of(*p.backend);
}

/// `framed`: --clip defect may bring the camera close to the defect (no --look-at was given).
void make_renderer(PreparedRun& p, const std::optional<SectionRequest>& section, bool framed) {
    p.context->make_current();
    p.renderer.emplace(p.scenario, RenderOptions{.width = p.frame_width, .height = p.frame_height, .view = p.view,
                                                 .coronaries = p.surface_detail, .fibres = p.surface_detail});
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
        // The defect close up: the whole section would leave a 10 mm opening a few percent of the
        // picture. --look-at, given, places the camera instead.
        const double diameter = p.scenario.source.defect_diameter_mm;
        if (section->through_defect && framed && diameter > 0.0) {
            Camera& camera = renderer.camera();
            const double span = diameter + defect_frame_margin_mm;
            camera.distance = float(defect_view_distance(camera, span));
            std::printf("section view: the camera %.1f mm from the defect's centre, so that its %.1f mm opening and %.0f mm round it "
                        "(%.1f mm, plan-repair's patch) span two thirds of the picture's height (--look-at places it otherwise)\n",
                        camera.distance, diameter, 0.5 * defect_frame_margin_mm, span);
        }
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
    if (!a.trajectory.empty()) {  // read by the constructor (its planned view)
        // A patch lies on the detailed mesh (runtime/surgery/repair.h): without one, refuse before the
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
    const std::string view_name = a.view.value_or("anterior");
    if (view_name == "section" && a.clip.empty())
        throw UsageError("--view section looks straight at the section plane: give --clip (a plane, centre or defect)");
    view = parse_view_direction(view_name == "section" ? "anterior" : view_name);
    surface_detail = a.surface_detail == "on";
    std::optional<SectionRequest> section;
    if (!a.clip.empty()) section = parse_section_option(a.clip);
    if (section && view_name == "section") section->aim_camera = true;
    // --look-at: the camera centred on a point, after the view and the section have turned it.
    std::optional<LookAt> look;
    if (!a.look_at.empty()) look = parse_look_at(a.look_at);
    if (!a.eye.empty() && !look) throw UsageError("--eye places the camera looking at a point: give that point with --look-at X,Y,Z");
    if (!a.eye.empty()) parse_eye(a.eye, *look);
    if (look && a.headless && a.screenshot.empty()) throw UsageError("--look-at aims the camera: headless it needs --screenshot");
    // The --trajectory's planned view (its `# view:` line), where none of --view, --eye and
    // --look-at was given and --clip defect does not aim the camera: the options it records, as if given.
    if (!a.trajectory.empty()) {
        if (!a.probe.empty() || !a.grab.empty()) throw UsageError("give --trajectory or --probe/--grab, not both");
        trajectory = read_trajectory(a.trajectory);
    }
    const bool view_given = a.view || !a.look_at.empty() || !a.eye.empty() || (section && section->through_defect);
    if (trajectory.view && !view_given) {
        view = trajectory.view->direction;
        look = trajectory.view->look;
        if (render)
            std::printf("view: as planned in %s, %s (--view, --eye or --look-at choose another)\n", a.trajectory.c_str(),
                        view_options(*trajectory.view).c_str());
    }

    scenario = read_scenario(a.scenario);
    require_runnable(scenario, a.scenario);
    if (!a.replay.empty()) replayed = read_recording(a.replay);
    make_context_and_backend(a, render, *this);
    if (render) make_renderer(*this, section, !look);
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

}  // namespace heartsim
