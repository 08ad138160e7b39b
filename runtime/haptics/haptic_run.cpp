// The simulation side of a haptic session: devices from --device specs, the step, the
// haptic-rate table and the recording (haptic_run.h, docs/haptics.md); the steps' pacing is the
// stepping core's (runtime/core/stepping.h). The replay (replay.cpp) applies the tools with this
// file's apply_tool, exactly as the live run does, or a cpu replay would not reproduce the forces
// bit for bit.
#include "runtime/haptics/haptic_run.h"

#include "runtime/haptics/openhaptics.h"

#include "formats/atomic_file.h"
#include "formats/csv.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>
#include <thread>


namespace heartsim::haptics {

namespace {

std::string lower_extension(const std::string& file) { return text::lowercase(std::filesystem::path(file).extension().string()); }

std::array<double, 3> to_array(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

/// --record OUT.h5 must be a new or replaceable file: not a folder, no journal of another session
/// beside it, and its folder writable. Checked before the session, so nothing is lost at the end.
/// (That it is none of the run's inputs, the scenario or a device's script, check_arguments in
/// run_modes.cpp checks for every output.)
void check_record_path(const std::string& record) {
    namespace fs = std::filesystem;
    const fs::path path(record);
    if (record.back() == '/' || fs::is_directory(path)) throw OptionError("{HapticRunSettings::record} " + record + ": is a folder; give a file, e.g. " + (path / "session.h5").string());
    try {
        check_destination(path);  // the folder exists and takes a file
    } catch (const OutputError& e) {
        throw OutputError("{HapticRunSettings::record} " + std::string(e.what()));
    }
    // A journal there is a session that is recording now, or one that was killed before it could
    // write its recording: never replaced, so nothing of it is lost.
    const fs::path journal = journal_path(path);
    if (fs::exists(journal) || fs::is_symlink(journal)) {
        if (journal_in_use(journal))
            throw InputError("{HapticRunSettings::record} " + record + ": another heartsim session is recording to it now (its journal " + journal.string() +
                             " is open); give another file");
        throw InputError("{HapticRunSettings::record} " + record + ": " + journal.string() + " holds a session that was killed before it could write " + record +
                         ": `heartsim recover " + journal.string() + "` writes it (to " + record + ", or -o OTHER.h5), or delete " +
                         journal.string() + " to record over it");
    }
}
std::array<double, 4> to_array(const Eigen::Quaterniond& q) { return {q.w(), q.x(), q.y(), q.z()}; }

/// Appends the device ticks from `begin` on as hand `hand`'s rows of `r`.
void append_ticks(RecordedHand& r, const std::vector<TickRecord>& ticks, std::size_t begin, int hand) {
    for (std::size_t k = begin; k < ticks.size(); ++k) {
        const TickRecord& t = ticks[k];
        r.tick_time_ms.push_back(t.time_ms);
        r.position_mm.push_back(to_array(t.pose[hand].position_mm));
        r.orientation.push_back(to_array(t.pose[hand].orientation));
        r.buttons.push_back(t.pose[hand].buttons);
        r.input_n.push_back(to_array(t.input_n[hand]));
        r.force_n.push_back(to_array(t.force_n[hand]));
        r.gain.push_back(t.gain[hand]);
    }
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// Command-line vocabulary

DeviceSpec parse_device_spec(const std::string& text) {
    DeviceSpec spec;
    spec.text = text;
    const auto colon = text.find(':');
    const std::string kind = text.substr(0, colon);
    spec.argument = colon == std::string::npos ? "" : text.substr(colon + 1);
    const char* usage = "expected scripted:FILE, simulated:FILE, mouse or openhaptics[:NAME]";
    if (kind == "scripted" || kind == "simulated") {
        spec.kind = kind == "scripted" ? DeviceSpec::Kind::scripted : DeviceSpec::Kind::simulated;
        if (spec.argument.empty()) throw OptionError("{HapticRunSettings::devices} " + text + ": " + kind + " needs a file (" + usage + ")");
    } else if (kind == "mouse") {
        spec.kind = DeviceSpec::Kind::mouse;
        if (!spec.argument.empty()) throw OptionError("{HapticRunSettings::devices} " + text + ": mouse takes no argument");
    } else if (kind == "openhaptics") {
        spec.kind = DeviceSpec::Kind::openhaptics;
    } else {
        throw OptionError("{HapticRunSettings::devices} " + text + ": unknown device '" + kind + "'; " + usage);
    }
    return spec;
}

SimulatedDeviceSettings parse_simulated_device(const std::string& text, const std::string& name) {
    SimulatedDeviceSettings settings;
    bool workspace_given = false;
    // Settings rows are taken out (replaced by blank lines, so the force rows keep their numbers).
    std::istringstream in(text);
    std::string line, forces;
    int number = 0;
    while (std::getline(in, line)) {
        ++number;
        std::string content = line;
        if (const auto hash = content.find('#'); hash != std::string::npos) content.erase(hash);
        const std::string key = text::trim(content.substr(0, content.find(',')));
        const bool is_setting = key == "start_mm" || key == "mass_g" || key == "damping_n_ms_per_mm" || key == "max_force_n" || key == "workspace_mm";
        if (!is_setting) {
            forces += line + '\n';
            continue;
        }
        forces += '\n';
        std::vector<double> values;
        std::istringstream fields(content.substr(content.find(',') == std::string::npos ? content.size() : content.find(',') + 1));
        std::string field;
        while (std::getline(fields, field, ',')) {
            const std::string f = text::trim(field);
            char* end = nullptr;
            const double v = std::strtod(f.c_str(), &end);
            if (f.empty() || *end != '\0' || !std::isfinite(v))
                throw InputError(name + ":" + std::to_string(number) + ": " + key + ": '" + f + "' is not a finite number");
            values.push_back(v);
        }
        const std::size_t expected = key == "start_mm" ? 3 : key == "workspace_mm" ? 6 : 1;
        if (values.size() != expected)
            throw InputError(name + ":" + std::to_string(number) + ": " + key + " needs " + std::to_string(expected) + " number" +
                             (expected > 1 ? "s" : "") + ", found " + std::to_string(values.size()));
        if (key == "start_mm") settings.start_mm = Eigen::Vector3d(values[0], values[1], values[2]);
        if (key == "mass_g") {
            plausible::require(values[0], plausible::device_mass_g, "mass_g", name + ":" + std::to_string(number));
            settings.mass_g = values[0];
        }
        if (key == "damping_n_ms_per_mm") {
            if (!(values[0] >= 0.0)) throw InputError(name + ":" + std::to_string(number) + ": damping_n_ms_per_mm must not be negative");
            settings.damping_n_ms_per_mm = values[0];
        }
        if (key == "max_force_n") {
            plausible::require(values[0], plausible::device_force_n, "max_force_n", name + ":" + std::to_string(number));
            settings.limits.max_force_n = values[0];
        }
        if (key == "workspace_mm") {
            const Eigen::Vector3d lo(values[0], values[1], values[2]), hi(values[3], values[4], values[5]);
            if (!(lo.array() < hi.array()).all())
                throw InputError(name + ":" + std::to_string(number) + ": workspace_mm needs X0 < X1, Y0 < Y1, Z0 < Z1");
            settings.limits.workspace_mm = Eigen::AlignedBox3d(lo, hi);
            workspace_given = true;
        }
    }
    settings.hand_force = parse_hand_force(forces, name);
    if (!workspace_given) {
        const Eigen::Vector3d half(80, 60, 35);
        settings.limits.workspace_mm = Eigen::AlignedBox3d(settings.start_mm - half, settings.start_mm + half);
    }
    if (!settings.limits.workspace_mm.contains(settings.start_mm))
        throw InputError(name + ": start_mm lies outside workspace_mm");
    return settings;
}

SimulatedDeviceSettings read_simulated_device(const std::filesystem::path& path) {
    return parse_simulated_device(read_csv_file(path), path.string());
}

std::vector<PoseKeyframe> recorded_pose_script(const Recording& recording, int hand, const std::string& name) {
    if (hand < 0 || hand > 1 || !recording.hands[hand].used)
        throw InputError(name + ": the recording has no hand " + std::to_string(hand) + " (groups /hand0, /hand1)");
    const RecordedHand& h = recording.hands[hand];
    if (h.tick_time_ms.empty()) throw InputError(name + ":/hand" + std::to_string(hand) + ": no ticks recorded");
    std::vector<PoseKeyframe> keyframes(h.tick_time_ms.size());
    // The script's time 0 is where the recording began, the start of its first simulation step (a
    // step's time is its end): 0 for a --record session, 40,000 ms for one the window's F5 began
    // 40 s into a session, which then plays from its start rather than holding its first pose
    // for 40 s. Without two steps to tell, the session's own clock.
    const std::vector<double>& steps = recording.steps.time_ms;
    const double start_ms = steps.size() >= 2 ? std::clamp(2 * steps[0] - steps[1], 0.0, h.tick_time_ms.front()) : 0.0;
    for (std::size_t i = 0; i < keyframes.size(); ++i) {
        keyframes[i].time_ms = h.tick_time_ms[i] - start_ms;
        keyframes[i].pose.position_mm = Eigen::Vector3d(h.position_mm[i][0], h.position_mm[i][1], h.position_mm[i][2]);
        Eigen::Quaterniond q(h.orientation[i][0], h.orientation[i][1], h.orientation[i][2], h.orientation[i][3]);
        if (q.norm() < 1e-9) throw InputError(name + ":/hand" + std::to_string(hand) + "/orientation row " + std::to_string(i) + " is zero");
        keyframes[i].pose.orientation = q.normalized();
        keyframes[i].pose.buttons = h.buttons[i];
    }
    return keyframes;
}

Instrument parse_instrument(const std::string& text, double default_semi_axis_mm) {
    Instrument instrument;
    const auto colon = text.find(':');
    const std::string kind = text.substr(0, colon);
    const std::optional<InstrumentKind> named = instrument_kind_named(kind);
    if (named && *named != InstrumentKind::none) instrument.kind = *named;
    else throw OptionError("{HapticRunSettings::instruments} " + text + ": expected probe, grabber, retractor, scalpel, patch or needle, optionally :AX,AY,AZ (semi-axes, mm)");
    switch (instrument.kind) {
    case InstrumentKind::scalpel: instrument.semi_axes = default_blade_semi_axes_mm; break;
    case InstrumentKind::patch: instrument.semi_axes = default_patch_semi_axes_mm; break;
    case InstrumentKind::needle: instrument.semi_axes = default_needle_semi_axes_mm; break;
    default: instrument.semi_axes = Eigen::Vector3d::Constant(default_semi_axis_mm); break;
    }
    if (colon != std::string::npos) {
        double a[3];
        char extra = 0;
        if (std::sscanf(text.c_str() + colon + 1, "%lf,%lf,%lf%c", &a[0], &a[1], &a[2], &extra) != 3 || !(a[0] > 0) || !(a[1] > 0) ||
            !(a[2] > 0) || !std::isfinite(a[0] + a[1] + a[2]))
            throw OptionError("{HapticRunSettings::instruments} " + text + ": semi-axes must be three positive numbers AX,AY,AZ (mm)");
        try {
            for (double axis : a) plausible::require(axis, plausible::semi_axis_mm, "semi-axis", "{HapticRunSettings::instruments} " + text);
        } catch (const InputError& e) {
            throw OptionError(e.what());
        }
        instrument.semi_axes = Eigen::Vector3d(a[0], a[1], a[2]);
        if (instrument.kind == InstrumentKind::patch && (std::max(a[0], a[1]) > 50.0 || a[2] > 2.5))
            throw OptionError("{HapticRunSettings::instruments} " + text + ": a patch's half-diameters are at most 50 mm and its half thickness 2.5 mm");
    }
    return instrument;
}

void apply_tool(Backend& backend, int hand, const Instrument& instrument, const InstrumentPose& pose, bool grab, bool& placed,
                bool& grabbing) {
    if (!placed) {
        backend.set_instrument(hand, instrument);
        backend.set_pose(hand, pose);
        placed = true;
    }
    if (grab != grabbing) {
        if (grab) backend.begin_grab(hand);
        else backend.release(hand);
        grabbing = grab;
    }
    backend.set_pose(hand, pose);
}

// ------------------------------------------------------------------------------------------------
// HapticRun

HapticRun::HapticRun(Backend& backend, const Scenario& scenario, const std::string& scenario_name, const HapticRunSettings& settings,
                     const HapticRunContext& context)
    : backend_(backend), settings_(settings) {
    if (settings.devices.empty() || settings.devices.size() > 2) throw OptionError("{HapticRunSettings::devices}: give one or two devices (hand 0, hand 1)");
    if (settings.instruments.size() > settings.devices.size())
        throw OptionError("{HapticRunSettings::instruments}: one per {HapticRunSettings::devices} at most (" + std::to_string(settings.devices.size()) + " devices given)");
    if (!settings.record.empty()) check_record_path(settings.record);
    std::array<DeviceMapping, 2> mappings;
    const double semi_axis = 1.5 * scenario.lattice.spacing;
    for (int i = 0; i < int(settings.devices.size()); ++i) {
        Hand& h = hands_[i];
        h.spec = parse_device_spec(settings.devices[i]);
        h.instrument = i < int(settings.instruments.size()) ? parse_instrument(settings.instruments[i], semi_axis)
                                                            : parse_instrument(i == 0 ? "probe" : "grabber", semi_axis);
        h.own = h.stepped = h.instrument;
        if (context.check_instrument && i < int(settings.instruments.size()))
            context.check_instrument(h.instrument, "--instrument " + settings.instruments[std::size_t(i)] + " for hand " + std::to_string(i));
        DeviceMapping& mapping = mappings[i];  // scripted, simulated and mouse devices move in the world frame
        switch (h.spec.kind) {
        case DeviceSpec::Kind::scripted: {
            std::string file = h.spec.argument;
            int recorded_hand = i;
            if (const auto at = file.rfind('@'); at != std::string::npos && (lower_extension(file.substr(0, at)) == ".h5" ||
                                                                              lower_extension(file.substr(0, at)) == ".hdf5")) {
                const std::string which = file.substr(at + 1);
                if (which != "0" && which != "1") throw OptionError("{HapticRunSettings::devices} " + h.spec.text + ": @HAND must be @0 or @1");
                recorded_hand = which[0] - '0';
                file = file.substr(0, at);
            }
            if (!std::filesystem::exists(file)) throw InputError("{HapticRunSettings::devices} " + h.spec.text + ": " + file + ": no such file");
            std::vector<PoseKeyframe> keyframes;
            const std::string e = lower_extension(file);
            if (e == ".h5" || e == ".hdf5") {
                const Recording recorded = read_recording(file);
                keyframes = recorded_pose_script(recorded, recorded_hand, file);
                // The recorded device's poses are in its own frame: place them as it was placed.
                const RecordedHand& rh = recorded.hands[recorded_hand];
                mapping.offset_mm = Eigen::Vector3d(rh.mapping_offset_mm[0], rh.mapping_offset_mm[1], rh.mapping_offset_mm[2]);
                mapping.rotation = Eigen::Quaterniond(rh.mapping_rotation[0], rh.mapping_rotation[1], rh.mapping_rotation[2], rh.mapping_rotation[3]);
                mapping.scale = rh.mapping_scale;
                mapping.force_scale = rh.force_scale;
            } else {
                keyframes = read_pose_script(file);
            }
            DeviceLimits limits;
            limits.workspace_mm.setEmpty();
            h.device = std::make_unique<ScriptedDevice>(std::move(keyframes), limits);
            break;
        }
        case DeviceSpec::Kind::simulated:
            if (!std::filesystem::exists(h.spec.argument)) throw InputError("{HapticRunSettings::devices} " + h.spec.text + ": " + h.spec.argument + ": no such file");
            h.device = std::make_unique<SimulatedDevice>(read_simulated_device(h.spec.argument));
            break;
        case DeviceSpec::Kind::mouse: {
            if (context.headless)
                throw DeviceUnavailable("--device mouse needs the window; run without --headless, or use scripted:FILE / simulated:FILE");
            if (window_device_) throw OptionError("{HapticRunSettings::devices} mouse: only one hand can follow the mouse");
            auto device = std::make_unique<WindowDevice>();
            window_device_ = device.get();
            DevicePose start;
            const Eigen::Vector3d back = (context.camera.orientation * Eigen::Vector3f::UnitZ()).cast<double>();
            start.position_mm = context.camera.target.cast<double>() + back * (0.8 * context.camera.radius);
            window_device_->set_pose(start);
            h.device = std::move(device);
            break;
        }
        case DeviceSpec::Kind::openhaptics:
            h.device = open_openhaptics({.device_name = h.spec.argument, .library = ""});
            // The device's frame (x right, y up, z towards the user) is the camera's; its origin
            // the centre of the view.
            mapping.offset_mm = context.camera.target.cast<double>();
            mapping.rotation = context.camera.orientation.cast<double>();
            break;
        }
    }
    // The session (and its clock, the scripts' time zero) starts once every device is open.
    session_ = std::make_unique<HapticSession>(settings.session);
    for (int i = 0; i < 2; ++i)
        if (hands_[i].device) session_->attach(i, hands_[i].device.get(), mappings[i]);
    recording_on_ = !settings.record.empty();
    record_path_ = settings.record;
    // A window session keeps the ticks too (drained and dropped while nothing records), so F5 can
    // start a recording at any time.
    if (recording_on_ || !context.headless)
        session_->enable_tick_recording(std::size_t(4.0 * settings.session.rate_hz) + 1024);  // ≥ 4 s of ticks

    recording_.scenario = std::filesystem::path(scenario_name).filename().string();
    recording_.particles = std::int64_t(backend.size());
    recording_.dt_ms = backend.load_report().unscaled_dt_ms;  // the scenario's step (the mass scale lengthens it: /steps/mass_scale)
    recording_.substeps = backend.substeps_per_step();
    recording_.backend = to_string(backend.kind());
    recording_.arithmetic = backend.kind() == BackendKind::cpu && !fuses_multiply_adds(backend.load_report().kernel) ? "separate" : "fused";
    recording_.rules = static_cast<const SolverRules&>(backend.options());
    recording_.contact = settings.contact;
    recording_.patch_material = settings.patch_material;
    recording_.interpolation = to_string(settings.session.interpolation);
    recording_.rate_hz = settings.session.rate_hz;
    recording_.coupling = settings.session.coupling.enabled;
    for (int i = 0; i < 2; ++i) {
        if (!hands_[i].device) continue;
        RecordedHand& r = recording_.hands[i];
        r.used = true;
        r.device = hands_[i].spec.text;
        r.device_name = hands_[i].device->name();
        r.instrument = to_string(hands_[i].instrument.kind);
        shown_kind_[i] = hands_[i].instrument.kind;
        r.semi_axes_mm = to_array(hands_[i].instrument.semi_axes);
        r.max_force_n = std::min(hands_[i].device->limits().max_force_n,
                                 settings.session.safety.max_force_n > 0 ? settings.session.safety.max_force_n : 1e300);
        r.mapping_offset_mm = to_array(mappings[i].offset_mm);
        r.mapping_rotation = to_array(mappings[i].rotation.normalized());
        r.mapping_scale = mappings[i].scale;
        r.force_scale = mappings[i].force_scale;
    }
    recording_header_ = recording_;
    if (recording_on_) journal_ = std::make_unique<RecordingJournal>(journal_path(settings.record), recording_, settings.record);
}

InstrumentKind HapticRun::toggle_instrument(int hand, const Instrument& instrument) {
    if (hand < 0 || hand > 1 || !hands_[hand].device) throw std::logic_error("haptics: hand " + std::to_string(hand) + " has no device");
    Hand& h = hands_[hand];
    h.instrument = h.instrument.kind == instrument.kind ? h.own : instrument;
    // The next step places it afresh if it differs from the one the last step held (step(), as a
    // replay decides from /steps/instrument); a button held through the switch acts at its next
    // press, so the new instrument does not cut, lay or tie the moment it is taken up.
    h.wait_release = (h.buttons & 1u) != 0;
    shown_kind_[hand] = h.instrument.kind;
    return h.instrument.kind;
}

void HapticRun::start_recording(const std::string& path) {
    if (recording_on_) throw std::logic_error("haptics: a recording is on already (" + record_path_ + ")");
    Recording fresh = recording_header_;
    for (int i = 0; i < 2; ++i)  // the instruments in hand now (K may have switched one)
        if (fresh.hands[i].used) {
            fresh.hands[i].instrument = to_string(hands_[i].instrument.kind);
            for (int c = 0; c < 3; ++c) fresh.hands[i].semi_axes_mm[c] = hands_[i].instrument.semi_axes[c];
        }
    auto journal = std::make_unique<RecordingJournal>(journal_path(path), fresh, path);  // throws: nothing started
    // The tissue at rest, no grab, the instruments placed afresh by the next step: exactly the
    // state `--replay` starts from (the scenario's rest state, nothing placed), so the recording's
    // step 0 is the replay's step 0 and a cpu replay reproduces its forces bit for bit.
    backend_.reset_tissue();
    for (Hand& h : hands_) h.placed = false, h.grabbing = false;
    drain();  // the ticks so far are not this recording's
    ticks_.clear();
    recording_ = std::move(fresh);
    journal_ = std::move(journal);
    journaled_steps_ = journaled_ticks_ = journaled_events_ = 0;
    journaled_at_ms_ = session_->now_ms();
    journal_failure_reported_ = false;
    last_estop_ = last_fresh_ = false;
    record_first_row_ = rows_;
    record_path_ = path;
    recording_on_ = window_recording_ = true;
}

std::size_t HapticRun::stop_recording() {
    if (!window_recording_) throw std::logic_error("haptics: no recording from the window is on");
    drain();
    recording_on_ = window_recording_ = false;
    return write_recording_now();
}

HapticRun::~HapticRun() {
    if (session_) session_->stop();
    // A session that ended before its first step (a device that would not start) leaves nothing to
    // recover; one that ended by an error later keeps its journal for `heartsim recover`.
    if (journal_ && !finished_ && recording_.steps.size() == 0) journal_->remove();
}

std::string HapticRun::describe(int hand) const {
    const Hand& h = hands_[hand];
    char line[512];
    const CouplingSettings& c = session_->coupling(hand);
    std::snprintf(line, sizeof line, "hand %d: %s (%s) → %s %.3g×%.3g×%.3g mm, max force %.3g N%s", hand, h.spec.text.c_str(),
                  h.device->name().c_str(), to_string(h.instrument.kind), h.instrument.semi_axes.x(), h.instrument.semi_axes.y(),
                  h.instrument.semi_axes.z(), recording_.hands[hand].max_force_n,
                  c.enabled ? (", coupling K " + std::to_string(c.stiffness_n_per_mm) + " N/mm, B " + std::to_string(c.damping_n_ms_per_mm) +
                               " N·ms/mm").c_str()
                            : "");
    return line;
}

void HapticRun::start() {
    session_->start();
    start_sim_ms_ = backend_.simulated_time_ms();
    wall_start_ms_ = session_->now_ms();
    // The first tool poses (one tick), so the first step already has the instruments. The device
    // thread ticks at once, but a loaded machine may not run it for a while: only a device thread
    // that gives nothing for seconds ends the run.
    const double give_up_ms = session_->now_ms() + 5000.0;
    while (!session_->latest_tools() && session_->now_ms() < give_up_ms) std::this_thread::sleep_for(std::chrono::microseconds(50));
    if (!session_->latest_tools()) throw DeviceUnavailable("haptics: the device thread produced no tool pose within 5 s");
}

StepReport HapticRun::step() {
    // Rows count step() calls: a step the watchdog restores is a row (and a recorded step) too.
    const long long step_index = (long long)rows_++;
    double tool_time = -1.0;
    std::array<bool, 2> grab{false, false}, applied{false, false};
    // An instrument other than the one the last step held (K, Shift + P, Shift + N): placed afresh,
    // what the old one held let go (set_instrument releases it), exactly where a replay does so.
    for (int i = 0; i < 2; ++i) {
        Hand& h = hands_[i];
        if (!h.device || h.instrument == h.stepped) continue;
        if (h.grabbing && recording_on_) recording_.events.push_back({session_->now_ms(), i, "release"});
        h.placed = false, h.grabbing = false;
        h.stepped = h.instrument;
    }
    if (auto tools = session_->latest_tools()) {
        for (int i = 0; i < 2; ++i) {
            Hand& h = hands_[i];
            if (!h.device || !tools->hand[i].valid) continue;
            // A device pose that is not finite, or absurdly far (> 1 km), is not applied: the hand
            // keeps its last pose (counted, reported at the end).
            const InstrumentPose& p = tools->hand[i].pose;
            const bool usable = p.position.allFinite() && p.position.cwiseAbs().maxCoeff() < 1e6 && p.orientation.coeffs().allFinite() &&
                                p.orientation.norm() > 1e-6;
            if (!usable) {
                if (h.bad_poses++ == 0 && recording_on_) recording_.events.push_back({session_->now_ms(), i, "bad_pose"});
                if (!h.placed) continue;
                apply_tool(backend_, i, h.instrument, h.pose, h.grabbing, h.placed, h.grabbing);
                applied[i] = true;
                continue;
            }
            h.pose = p;
            h.buttons = tools->hand[i].buttons;
            // A press that began and ended since the last step acts for this one step (a patch is
            // laid, a stitch tied, a grabber closes and opens again at the next).
            const bool pressed_between = tools->hand[i].presses != h.presses && !(h.buttons & 1u) && !h.grabbing;
            h.presses = tools->hand[i].presses;
            if (!(h.buttons & 1u)) h.wait_release = false;
            const bool wants = takes_grab(h.instrument.kind) && ((h.buttons & 1u) || pressed_between) && !h.wait_release;
            const bool was = h.grabbing;
            apply_tool(backend_, i, h.instrument, h.pose, wants, h.placed, h.grabbing);
            applied[i] = true;
            if (h.grabbing != was && recording_on_)
                recording_.events.push_back({session_->now_ms(), i, h.grabbing ? "grab" : "release"});
            tool_time = std::max(tool_time, tools->hand[i].time_ms);
        }
    }
    for (int i = 0; i < 2; ++i) grab[i] = hands_[i].grabbing;

    const double step_mass_scale = backend_.options().mass_scale;
    const StepReport report = backend_.step(1);
    last_step_wall_ms_ = session_->now_ms();
    result_.add(report);
    if (report.diverged && recording_on_) recording_.events.push_back({session_->now_ms(), -1, "divergence"});
    // Which step each force request follows, and which tool sample each step used, for the
    // last `ring` steps: a gl readback is at most a few requests old.
    const std::size_t slot = std::size_t(step_index) % ring;
    step_tool_time_[slot] = tool_time;
    step_of_request_[requests_ % ring] = step_index;
    backend_.request_forces();
    ++requests_;

    long long force_step = -1;
    InstrumentForces forces{};
    if (auto latest = backend_.latest_forces()) {
        const std::uint64_t request = backend_.latest_forces_request();
        if (request < requests_ && requests_ - request <= ring) {
            force_step = step_of_request_[request % ring];
            forces = *latest;
            if (request != last_published_request_) {  // a gl readback that has not advanced is not a new sample
                last_published_request_ = request;
                last_published_forces_ = forces;
                ++result_.forces_received;
                // Steps from the one that first used the newest pose to the one whose forces these
                // are, inclusive: 1 when the forces come from the step that used the pose.
                ++latency_steps_[std::min<std::size_t>(std::size_t(step_index - force_step + 1), latency_steps_.size() - 1)];
                session_->publish_forces(forces, session_->now_ms(), report.diverged, false,
                                         step_tool_time_[std::size_t(force_step) % ring]);
            }
        }
    }
    if (!recording_on_) return report;

    RecordedSteps& s = recording_.steps;
    s.tool_time_ms.push_back(tool_time);
    s.time_ms.push_back(backend_.simulated_time_ms());
    s.wall_ms.push_back(session_->now_ms());
    std::array<std::array<double, 3>, 2> position{};
    std::array<std::array<double, 4>, 2> orientation{{{1, 0, 0, 0}, {1, 0, 0, 0}}};
    std::array<std::array<double, 3>, 2> force{};
    for (int i = 0; i < 2; ++i) {
        position[i] = to_array(hands_[i].pose.position);
        orientation[i] = to_array(hands_[i].pose.orientation);
        force[i] = to_array(forces.hand[i].force_n);
    }
    s.tool_position_mm.push_back(position);
    s.tool_orientation.push_back(orientation);
    s.grab.push_back({std::int8_t(grab[0]), std::int8_t(grab[1])});
    std::array<std::int8_t, 2> held{0, 0};
    std::array<std::array<double, 3>, 2> axes{};
    for (int i = 0; i < 2; ++i)
        if (hands_[i].device) held[i] = instrument_code(hands_[i].instrument.kind), axes[i] = to_array(hands_[i].instrument.semi_axes);
    s.instrument.push_back(held);
    s.semi_axes_mm.push_back(axes);
    s.applied.push_back({std::int8_t(applied[0]), std::int8_t(applied[1])});
    s.force_n.push_back(force);
    // Steps count from the recording's first (a window recording starts mid-session); a force
    // from a step before it is none of the recording's.
    s.force_step.push_back(force_step >= (long long)record_first_row_ ? force_step - (long long)record_first_row_ : -1);
    s.diverged.push_back(std::int8_t(report.diverged));
    s.mass_scale.push_back(step_mass_scale);
    return report;
}

double HapticRun::ms_until_next_step() const {
    const double simulated = backend_.simulated_time_ms() - start_sim_ms_;
    return simulated + backend_.time_step_ms() - session_->now_ms() + wall_start_ms_;
}

double HapticRun::owed_ms() const { return session_->now_ms() - wall_start_ms_; }

double HapticRun::simulated_ms() const { return backend_.simulated_time_ms() - start_sim_ms_; }

void HapticRun::record_event(const char* what) {
    if (recording_on_) recording_.events.push_back({session_->now_ms(), -1, what});
}

void HapticRun::set_paused(bool paused) {
    if (paused == paused_) return;
    const double now = session_->now_ms();
    if (paused) paused_at_ms_ = now;
    else wall_start_ms_ += now - paused_at_ms_;  // the paused interval does not count as simulation time owed
    paused_ = paused;
}

void HapticRun::drain() {
    poll_device_faults();
    const std::size_t before = ticks_.size();
    session_->drain_ticks(ticks_);
    if (!recording_on_) {
        ticks_.clear();
        return;
    }
    for (std::size_t k = before; k < ticks_.size(); ++k) {
        const TickRecord& t = ticks_[k];
        if (t.estop != last_estop_) recording_.events.push_back({t.time_ms, -1, t.estop ? "emergency_stop" : "emergency_stop_released"});
        if (t.simulation_fresh != last_fresh_) recording_.events.push_back({t.time_ms, -1, t.simulation_fresh ? "simulation_fresh" : "simulation_stalled"});
        last_estop_ = t.estop;
        last_fresh_ = t.simulation_fresh;
    }
    if (journal_ && session_->now_ms() - journaled_at_ms_ >= journal_period_ms) journal_rows();
}

void HapticRun::journal_rows() {
    journaled_at_ms_ = session_->now_ms();
    Recording rows;
    const RecordedSteps& s = recording_.steps;
    RecordedSteps& c = rows.steps;
    auto tail = [](auto& to, const auto& from, std::size_t begin) { to.assign(from.begin() + std::ptrdiff_t(begin), from.end()); };
    tail(c.time_ms, s.time_ms, journaled_steps_);
    tail(c.wall_ms, s.wall_ms, journaled_steps_);
    tail(c.tool_time_ms, s.tool_time_ms, journaled_steps_);
    tail(c.tool_position_mm, s.tool_position_mm, journaled_steps_);
    tail(c.tool_orientation, s.tool_orientation, journaled_steps_);
    tail(c.grab, s.grab, journaled_steps_);
    tail(c.applied, s.applied, journaled_steps_);
    tail(c.force_n, s.force_n, journaled_steps_);
    tail(c.force_step, s.force_step, journaled_steps_);
    tail(c.diverged, s.diverged, journaled_steps_);
    tail(c.mass_scale, s.mass_scale, journaled_steps_);
    tail(c.instrument, s.instrument, journaled_steps_);
    tail(c.semi_axes_mm, s.semi_axes_mm, journaled_steps_);
    for (int i = 0; i < 2; ++i) {
        if (!hands_[i].device) continue;
        append_ticks(rows.hands[i], ticks_, journaled_ticks_, i);
    }
    tail(rows.events, recording_.events, journaled_events_);
    journaled_steps_ = s.size();
    journaled_ticks_ = ticks_.size();
    journaled_events_ = recording_.events.size();
    journal_->append(rows);
    if (!journal_failure_reported_) {
        if (const std::string failure = journal_->failure(); !failure.empty()) {
            journal_failure_reported_ = true;
            std::fprintf(stderr, "heartsim: warning: %s; the session goes on and %s is still written at the end, but a crash now would "
                                 "lose it\n", failure.c_str(), record_path_.c_str());
        }
    }
}

void HapticRun::poll_device_faults() {
    for (int i = 0; i < 2; ++i) {
        Hand& h = hands_[i];
        if (!h.device || !h.fault.empty()) continue;
        if (const auto* touch = dynamic_cast<const OpenHapticsDevice*>(h.device.get())) {
            const std::string fault = touch->fault();
            if (fault.empty()) continue;
            h.fault = fault;
            std::fprintf(stderr, "heartsim: warning: hand %d (%s): device fault: %s; its force is held at zero\n", i, h.spec.text.c_str(), fault.c_str());
            if (recording_on_) recording_.events.push_back({session_->now_ms(), i, "device_fault"});
        }
    }
}

bool HapticRun::device_faulted() const {
    for (const Hand& h : hands_)
        if (!h.fault.empty()) return true;
    return false;
}

std::vector<InstrumentShape> HapticRun::shapes() const {
    std::vector<InstrumentShape> shapes;
    for (int hand = 0; hand < 2; ++hand) {
        const Hand& h = hands_[hand];
        if (h.device && h.placed) shapes.push_back({h.instrument.kind, h.pose, h.instrument.semi_axes, hand, false, h.buttons});
    }
    return shapes;
}

void HapticRun::finish(ScriptedRunResult& result) {
    if (finished_) return;
    finished_ = true;
    // End without a jolt: a reset fades the forces out (fade_out_ms), then the thread stops.
    if (session_->running()) {
        session_->publish_forces(InstrumentForces{}, session_->now_ms(), false, true);
        const double until = session_->now_ms() + settings_.session.safety.fade_out_ms + 2.0 * session_->period_ms();
        while (session_->now_ms() < until) std::this_thread::sleep_for(std::chrono::milliseconds(1));
        session_->stop();
    }
    drain();
    result_.wall_ms = session_->now_ms() - wall_start_ms_;
    result = result_;

    const PeriodStats period = session_->period_stats();
    const LatencyStats latency = session_->latency_stats();
    const double dt = backend_.time_step_ms();
    const double simulated = backend_.simulated_time_ms() - start_sim_ms_;
    std::printf("\nhaptics (%s, %s)\n", to_string(settings_.session.interpolation),
                settings_.session.coupling.enabled ? "virtual coupling" : "direct rendering");
    for (int i = 0; i < 2; ++i)
        if (hands_[i].device) std::printf("  %s\n", describe(i).c_str());
    std::printf("%-26s %10s %10s %10s %10s %10s\n", "", "samples", "p50 ms", "p99 ms", "max ms", "mean ms");
    std::printf("%-26s %10llu %10.3f %10.3f %10.3f %10.3f   (%.0f Hz target: %.3f ms; %llu overruns; device thread %s)\n", "haptic period",
                (unsigned long long)period.ticks, period.p50_ms, period.p99_ms, period.max_ms, period.mean_ms, settings_.session.rate_hz,
                session_->period_ms(), (unsigned long long)period.overruns, session_->scheduling().c_str());
    std::printf("%-26s %10llu %10.3f %10.3f %10.3f %10.3f   (pose read → first force from it at the device thread; step %.3g ms)\n",
                "pose → force latency", (unsigned long long)latency.samples, latency.p50_ms, latency.p99_ms, latency.max_ms,
                latency.mean_ms, dt);
    {
        std::uint64_t total = 0, seen = 0;
        for (auto c : latency_steps_) total += c;
        int p50 = 0, p99 = 0, worst = 0;
        for (std::size_t k = 0; k < latency_steps_.size(); ++k) {
            if (!latency_steps_[k]) continue;
            seen += latency_steps_[k];
            worst = int(k);
            if (!p50 && 2 * seen >= total) p50 = int(k);
            if (!p99 && 100 * seen >= 99 * total) p99 = int(k);
        }
        std::printf("%-26s %10llu %10d %10d %10d %10s   (simulation steps from the first step using a pose to the forces it gave)\n",
                    "pose → force, steps", (unsigned long long)total, p50, p99, worst, "");
    }
    std::printf("simulation: %d steps, %.4g ms simulated in %.4g ms wall (real-time factor %.3g)\n", result_.steps, simulated,
                result_.wall_ms, result_.wall_ms > 0 ? simulated / result_.wall_ms : 0.0);
    if (rows_ > 0)  // the session steps when due, never ahead: what it owed at its last step says whether it kept up
        std::printf("simulation: %.3g ms behind real time at the last step (mass scale %g)\n",
                    std::max(0.0, last_step_wall_ms_ - wall_start_ms_ - simulated), backend_.options().mass_scale);
    if (result_.wall_ms > 0 && simulated / result_.wall_ms < 0.95)
        std::fprintf(stderr, "heartsim: warning: the simulation ran slower than real time; forces lag the devices: %s\n",
                     keep_up_advice(simulated / result_.wall_ms, backend_.size(), backend_.kind()).c_str());
    std::printf("%-6s %12s %12s %10s %10s %10s %10s %8s   %s\n", "hand", "forces sent", "max sent N", "clamped", "rate-lim", "non-finite",
                "faults", "e-stop", "last sent N");
    for (int i = 0; i < 2; ++i) {
        if (!hands_[i].device) continue;
        const HandTelemetry t = session_->telemetry(i);
        char max_text[32];
        std::snprintf(max_text, sizeof max_text, "%.4f", t.max_force_n);
        std::printf("%-6d %12llu %12s %10llu %10llu %10llu %10llu %8llu   (%.4f, %.4f, %.4f)\n", i, (unsigned long long)t.forces_sent, max_text,
                    (unsigned long long)t.safety.clamped, (unsigned long long)t.safety.rate_limited, (unsigned long long)t.safety.non_finite,
                    (unsigned long long)t.safety.faults, (unsigned long long)t.safety.stopped, t.last_force_n.x(), t.last_force_n.y(),
                    t.last_force_n.z());
    }
    for (int i = 0; i < 2; ++i)
        if (hands_[i].bad_poses)
            std::fprintf(stderr, "heartsim: warning: hand %d: %llu tool poses from the device were not finite or out of range and were not applied\n",
                         i, (unsigned long long)hands_[i].bad_poses);
    if (session_->dropped_ticks())
        std::fprintf(stderr, "heartsim: warning: %llu device ticks were not recorded (the simulation thread fell behind draining them)\n",
                     (unsigned long long)session_->dropped_ticks());

    if (!recording_on_) return;
    recording_on_ = false;
    const bool window = window_recording_;
    window_recording_ = false;
    const std::size_t steps = write_recording_now();
    if (window) std::printf("recording: wrote %s (%zu steps)\n", record_path_.c_str(), steps);
}

std::size_t HapticRun::write_recording_now() {
    const PeriodStats period = session_->period_stats();
    const LatencyStats latency = session_->latency_stats();
    recording_.period_p50_ms = period.p50_ms;
    recording_.period_p99_ms = period.p99_ms;
    recording_.period_max_ms = period.max_ms;
    recording_.period_mean_ms = period.mean_ms;
    recording_.periods = std::int64_t(period.ticks);
    recording_.overruns = std::int64_t(period.overruns);
    recording_.latency_p50_ms = latency.p50_ms;
    recording_.latency_p99_ms = latency.p99_ms;
    recording_.latency_max_ms = latency.max_ms;
    if (session_->dropped_ticks()) recording_.events.push_back({session_->now_ms(), -1, "ticks_dropped"});
    recording_.events.push_back({session_->now_ms(), -1, "end"});
    // The journal first gets the rest and the figures, so it holds the whole session should the
    // recording below fail (a full disk): then `heartsim recover` still writes it.
    journal_rows();
    journal_->end(recording_);
    const std::string journal_failure = journal_->wait();
    std::stable_sort(recording_.events.begin(), recording_.events.end(),
                     [](const RecordedEvent& x, const RecordedEvent& y) { return x.time_ms < y.time_ms; });
    for (int i = 0; i < 2; ++i) {
        if (!hands_[i].device) continue;
        append_ticks(recording_.hands[i], ticks_, 0, i);
    }
    try {
        write_recording(record_path_, recording_);
    } catch (const std::exception& e) {
        if (!journal_failure.empty()) throw;
        const std::string what = dynamic_cast<const std::bad_alloc*>(&e) ? "out of memory while writing " + record_path_ : e.what();
        throw OutputError(what + "; the whole session is in " + journal_->path().string() + ": `heartsim recover " +
                          journal_->path().string() + " -o OTHER.h5` writes it elsewhere");
    }
    journal_->remove();
    journal_.reset();
    std::printf("wrote %s (%zu steps, %zu device ticks, %zu events)\n", record_path_.c_str(), recording_.steps.size(), ticks_.size(),
                recording_.events.size());
    std::fflush(stdout);
    const std::size_t steps = recording_.steps.size();
    ticks_.clear();
    return steps;
}

}  // namespace heartsim::haptics
