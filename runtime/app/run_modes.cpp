// The modes of `heartsim run` (run_modes.h): what each prints, in the order it prints it, is the
// command's output that tests/test_runtime_cli.cpp and tests/test_haptics_cli.cpp check.
#include "runtime/app/run_modes.h"

#include "runtime/gl/backend_gl.h"
#include "runtime/gl/picking.h"

#include "runtime/haptics/haptic_run.h"
#include "runtime/view/png.h"
#include "runtime/app/run_outputs.h"
#include "runtime/app/run_progress.h"
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

using Clock = std::chrono::steady_clock;

/// A run's progress lines (run_progress.h) from `backend`'s simulated time since it was made and
/// the wall clock since `wall_start`.
class BackendProgress {
public:
    BackendProgress(const Backend& backend, Clock::time_point wall_start, int steps, double end_ms)
        : backend_(backend), wall_start_(wall_start), start_ms_(backend.simulated_time_ms()), progress_(steps, end_ms) {}
    void after_step(int steps_done) { progress_.after_step(steps_done, simulated_ms(), backend_.time_step_ms(), wall_s()); }
    void finish() { progress_.finish(simulated_ms(), wall_s()); }

private:
    double simulated_ms() const { return backend_.simulated_time_ms() - start_ms_; }
    double wall_s() const { return std::chrono::duration<double>(Clock::now() - wall_start_).count(); }
    const Backend& backend_;
    Clock::time_point wall_start_;
    double start_ms_;
    RunProgress progress_;
};

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

/// The HUD's procedure line: how the instruments are driven in the window.
std::string window_procedure(const RunArguments& a) {
    if (!a.devices.empty()) {
        std::string kinds;  // each --device's kind (the part before its ':')
        for (const std::string& device : a.devices) kinds += (kinds.empty() ? "" : ", ") + device.substr(0, device.find(':'));
        return "by hand (" + kinds + ")";
    }
    if (!a.trajectory.empty()) return "scripted: " + std::filesystem::path(a.trajectory).filename().string();
    return "exploring with the keyboard's probe";
}

/// The particles' rest bounding box (where the devices' frames are placed when nothing is drawn).
Eigen::AlignedBox3f model_box(const Scenario& scenario) {
    Eigen::AlignedBox3f box;
    for (const auto& p : scenario.lattice.particles.rest_position) box.extend(Eigen::Vector3f(p[0], p[1], p[2]));
    if (box.isEmpty()) box.extend(Eigen::Vector3f::Zero());
    return box;
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
    haptics::HapticRunContext context_settings{.headless = a.headless};
    // A patch lies on the detailed mesh (runtime/surgery/repair.h): a hand cannot hold one without it.
    context_settings.check_instrument = [&p](const Instrument& instrument, const std::string& what) {
        if ((instrument.kind == InstrumentKind::patch || instrument.kind == InstrumentKind::needle) && !can_hold_patch(p.scenario))
            throw no_patch_surface(what);
    };
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

/// The repair as the link sends it, made only when a mesh is sent (none before a patch is laid).
SlicerLink::PatchSource link_patch(PreparedRun& p) {
    return [&p] {
        const PatchModel* patch = p.repair ? p.repair->patch() : nullptr;
        return patch ? drawn_patch(*patch, p.repair->stitch_anchors()) : DrawnPatch{};
    };
}

/// What the stepping core of a mode does besides stepping: --real-time auto, the link, the
/// detailed mesh opened along the strokes, the haptic session (null: scripted hands).
Stepper::Settings stepping(const RunArguments& a, PreparedRun& p, haptics::HapticRun* haptic) {
    return {.real_time_auto = a.replay.empty() && a.real_time_mode() == RealTimeMode::automatic,
            .link = p.link.get(),
            .link_patch = link_patch(p),
            .open_incisions = [&p](const std::vector<std::array<float, 3>>* positions,
                                   const StrokeLog* strokes) { return open_incisions(p, false, positions, strokes); },
            .preview_incisions = [&p](const std::vector<std::array<float, 3>>* positions,
                                      const StrokeLog* strokes) { return preview_incisions(p, positions, strokes); },
            .haptic = haptic};
}

}  // namespace

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
    Stepper stepper(backend, stepping(a, run, nullptr));
    // A long replay says how far it has come on stderr, as a scripted run does (run_progress.h).
    BackendProgress progress(backend, Clock::now(), int(recording.steps.size()), 0.0);
    int replayed = 0;
    const haptics::ReplayResult r = haptics::replay(backend, recording, a.replay, [&] {
        stepper.open_incisions();
        progress.after_step(++replayed);
    });
    progress.finish();
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
    Stepper stepper(*run.backend, stepping(a, run, haptic.get()));
    const auto wall_start = Clock::now();
    ScriptedRunResult result;
    const double end_ms = a.seconds > 0 ? a.seconds * 1000.0 : 1e300;
    const double started = haptic->session().now_ms();
    // A long session says how far it has come on stderr, as a scripted run does (run_progress.h).
    BackendProgress progress(*run.backend, wall_start, a.seconds > 0 ? 0 : run.steps, a.seconds > 0 ? end_ms : 0.0);
    while (!interrupted.load() && !haptic->result().gave_up && haptic->session().now_ms() - started < end_ms &&
           (a.seconds > 0 || haptic->rows() < std::size_t(run.steps))) {
        const int limit = a.seconds > 0 ? 1000 : run.steps - int(haptic->rows());
        const int stepped = stepper.step_to_real_time(limit);
        if (stepped > 0) {
            stepper.open_incisions();  // the device thread goes on meanwhile
            progress.after_step(int(haptic->rows()));
        }
        if (stepped == 0)
            std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(std::clamp(haptic->ms_until_next_step(), 0.05, 1.0)));
        stepper.offer((long long)haptic->rows(), link_hands(haptic->shapes(), haptic->latest_published_forces()), SlicerLink::State::running);
    }
    if (interrupted.load()) std::printf("interrupted: ending the session\n");
    progress.finish();
    haptic->finish(result);
    // Ctrl-C stays caught while the outputs are written: a state is never cut off half way.
    const int status = finish_run(a, run, result, haptic.get(), wall_start);
    stepper.finish_link(result.steps, link_hands(haptic->shapes(), run.backend->instrument_forces()));
    restore_interrupts();
    return status;
}

int window_mode(const RunArguments& a, PreparedRun& run) {
    if (!a.devices.empty()) catch_interrupts();  // before start_haptics says how a session ends
    const std::unique_ptr<haptics::HapticRun> haptic = a.devices.empty() ? nullptr : start_haptics(a, run);
    Stepper stepper(*run.backend, stepping(a, run, haptic.get()));
    const auto wall_start = Clock::now();
    const WindowRunOptions window{.scenario_name = std::filesystem::path(a.scenario).filename().string(),
                                  .scenario_path = a.scenario,
                                  .screenshot = a.screenshot,
                                  .screenshot_every = a.screenshot_every,
                                  .draw_share = a.draw_share,
                                  .interrupted = &interrupted,
                                  .end_ms = a.seconds > 0 ? a.seconds * 1000.0 : 0.0,
                                  .backend_note = run.software_gl ? "OpenGL is software" : "",
                                  .scenario = &run.scenario,
                                  .procedure = window_procedure(a)};
    ScriptedRunResult result = run_window(*run.context, stepper, *run.renderer, run.trajectory, run.keyboard_hand0, run.steps, window);
    if (haptic) {
        if (interrupted.load()) std::printf("interrupted: ending the session\n");
        haptic->finish(result);  // Ctrl-C stays caught until the outputs are written (below)
    }
    const int status = finish_run(a, run, result, haptic.get(), wall_start);
    // After the run's outputs: the final mesh is the one they hold (a stroke under way opened).
    stepper.finish_link(result.steps, haptic ? link_hands(haptic->shapes(), run.backend->instrument_forces())
                                             : link_hands(run.trajectory, run.backend->simulated_time_ms(), run.backend->instrument_forces()));
    if (haptic) restore_interrupts();
    return status;
}

int headless_scripted_mode(const RunArguments& a, PreparedRun& run) {
    const auto wall_start = Clock::now();
    ScriptedRunOptions scripted{.steps = run.steps, .forces_every_step = !run.trajectory.keyframes.empty()};
    if (a.seconds > 0) scripted.end_ms = a.seconds * 1000.0;  // the steps lengthen when --real-time auto scales mass
    std::function<void(int, const StepReport&)> screenshots;
    if (run.renderer && a.screenshot_every > 0)
        screenshots = [&](int step, const StepReport&) {
            if ((step + 1) % a.screenshot_every != 0) return;
            draw_repair(run);
            run.renderer->render(*run.backend, shapes_at(run.trajectory, run.backend->simulated_time_ms()));
            write_png(numbered_screenshot(a.screenshot, step + 1), run.renderer->read_pixels());
        };
    Stepper stepper(*run.backend, stepping(a, run, nullptr));
    // A long run says how far it has come on stderr (run_progress.h).
    BackendProgress progress(*run.backend, wall_start, scripted.steps, scripted.end_ms);
    scripted.on_step = [&, each_step = stepper.scripted_on_step(run.trajectory, wall_start, std::move(screenshots))](int step,
                                                                                                                 const StepReport& report) {
        each_step(step, report);
        progress.after_step(step + 1);
    };
    const ScriptedRunResult result = run_scripted(*run.backend, run.trajectory, scripted);
    progress.finish();
    const int status = finish_run(a, run, result, nullptr, wall_start);
    stepper.finish_link(result.steps, link_hands(run.trajectory, run.backend->simulated_time_ms(), run.backend->instrument_forces()));
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
