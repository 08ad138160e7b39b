// The haptic session recording (recording.h): its schema over the HDF5 layer (hdf5_io.h).
#include "recording.h"

#include "hdf5_io.h"
#include "xdmf.h"

#include "libmodel/errors.h"
#include "libmodel/surgery/patch.h"
#include "libmodel/plausible.h"
#include "libmodel/sim/solver.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace heartsim {

namespace {

static_assert(sizeof(std::array<std::array<double, 3>, 2>) == 6 * sizeof(double), "arrays of doubles are packed");
static_assert(sizeof(std::array<std::array<double, 4>, 2>) == 8 * sizeof(double), "arrays of doubles are packed");

template <std::size_t N> std::array<double, N> vector_attribute(const h5::Reader& r, const std::string& object, const char* name) {
    const auto values = r.numbers<double>(object, name, long(N));
    std::array<double, N> result{};
    std::copy(values.begin(), values.end(), result.begin());
    return result;
}

}  // namespace

StepInstrumentFault check_step_instrument(std::int8_t code, const std::array<double, 3>& semi_axes_mm, bool hand_used) {
    const auto kind = instrument_of_code(code);
    if (!kind)
        return {"instrument", " is " + std::to_string(int(code)) + ", expected 0 (none), 1 (probe), 2 (grabber), 3 (scalpel), 4 (patch), 5 (needle) or 6 (retractor)"};
    if (*kind != InstrumentKind::none && !hand_used) return {"instrument", " is an instrument of a hand without a device"};
    if (*kind == InstrumentKind::none && hand_used) return {"instrument", " holds no instrument in a hand with a device"};
    if (*kind != InstrumentKind::none)
        for (double a : semi_axes_mm)
            if (!plausible::semi_axis_mm.contains(a)) return {"semi_axes_mm", ": " + plausible::outside("semi-axis", a, plausible::semi_axis_mm)};
    return {};
}

Instrument Recording::instrument_at(std::size_t k, int hand) const {
    Instrument instrument;
    if (k < steps.instrument.size()) {
        instrument.kind = instrument_of_code(steps.instrument[k][hand]).value_or(InstrumentKind::none);  // read_recording checked it
        const auto& a = steps.semi_axes_mm[k][hand];
        instrument.semi_axes = Eigen::Vector3d(a[0], a[1], a[2]);
        return instrument;
    }
    if (!hands[hand].used) return instrument;
    instrument.kind = instrument_kind_named(hands[hand].instrument).value_or(InstrumentKind::none);
    const auto& a = hands[hand].semi_axes_mm;
    instrument.semi_axes = Eigen::Vector3d(a[0], a[1], a[2]);
    return instrument;
}

SolverRules rules_before_recorded() {
    SolverRules r;
    r.max_displacement_fraction = 2.0;
    r.probe_pierce_strain = 0.0;  // never pierces
    r.grab_reach = 0.0;           // everything inside
    r.contact_skin = 0.0;         // at the particles
    return r;
}

std::string check_rules(const SolverRules& r) {
    std::string wrong;
    for_each_rule(
        [&](const char* name, const auto& value) {
            if (wrong.empty() && !std::isfinite(double(value))) wrong = std::string(name) + " must be finite";
        },
        r);
    if (!wrong.empty()) return wrong;
    if (!(r.max_displacement_fraction > 0)) return "max_displacement_fraction must be positive, not " + std::to_string(r.max_displacement_fraction);
    if (!(r.energy_growth_limit > 1)) return "energy_growth_limit must be above 1, not " + std::to_string(r.energy_growth_limit);
    if (!(r.contact_skin >= 0 && r.contact_skin <= 1)) return "contact_skin must be in [0, 1], not " + std::to_string(r.contact_skin);
    if (r.watchdog_interval < 1) return "watchdog_interval must be at least 1, not " + std::to_string(r.watchdog_interval);
    if (r.max_consecutive_restores < 1) return "max_consecutive_restores must be at least 1, not " + std::to_string(r.max_consecutive_restores);
    return {};
}

void write_recording_data(const std::filesystem::path& path, const Recording& r, const std::function<void(const std::filesystem::path&)>& check,
                          const std::vector<FileBeside>& beside) {
    const std::string file = path.string();
    const RecordedSteps& s = r.steps;
    const std::size_t n = s.size();
    if (s.wall_ms.size() != n || s.tool_time_ms.size() != n || s.tool_position_mm.size() != n || s.tool_orientation.size() != n ||
        s.grab.size() != n || s.applied.size() != n || s.force_n.size() != n || s.force_step.size() != n || s.diverged.size() != n ||
        (!s.mass_scale.empty() && s.mass_scale.size() != n) || (!s.instrument.empty() && s.instrument.size() != n) ||
        s.semi_axes_mm.size() != s.instrument.size())
        throw OutputError(file + ": the step columns have different lengths (a bug in heartsim)");
    h5::write_file(path, [&](h5::Writer& w) {
        w.header("heartsim.recording", 1, "mm g ms N");
        w.attribute("/", "scenario", r.scenario);
        w.attribute("/", "particles", std::int64_t(r.particles));
        w.attribute("/", "dt_ms", r.dt_ms);
        w.attribute("/", "substeps", std::int32_t(r.substeps));
        w.attribute("/", "backend", r.backend);
        w.attribute("/", "contact", r.contact);
        w.attribute("/", "interpolation", r.interpolation);
        w.attribute("/", "arithmetic", r.arithmetic);
        w.attribute("/", "patch_material", r.patch_material);
        if (r.rules) {
            w.group("rules");
            for_each_rule([&](const char* name, const auto& value) { w.attribute("rules", name, value); }, *r.rules);
        }
        w.attribute("/", "rate_hz", r.rate_hz);
        w.attribute("/", "coupling", std::int32_t(r.coupling ? 1 : 0));
        const std::pair<const char*, double> figures[] = {
            {"period_p50_ms", r.period_p50_ms},   {"period_p99_ms", r.period_p99_ms},   {"period_max_ms", r.period_max_ms},
            {"period_mean_ms", r.period_mean_ms}, {"latency_p50_ms", r.latency_p50_ms}, {"latency_p99_ms", r.latency_p99_ms},
            {"latency_max_ms", r.latency_max_ms}};
        for (const auto& [name, value] : figures) w.attribute("/", name, value);
        w.attribute("/", "periods", std::int64_t(r.periods));
        w.attribute("/", "overruns", std::int64_t(r.overruns));

        for (int h = 0; h < 2; ++h) {
            const RecordedHand& hand = r.hands[h];
            if (!hand.used) continue;
            const std::size_t t = hand.tick_time_ms.size();
            if (hand.position_mm.size() != t || hand.orientation.size() != t || hand.buttons.size() != t || hand.input_n.size() != t ||
                hand.force_n.size() != t || hand.gain.size() != t)
                throw OutputError(file + ": the tick columns of hand " + std::to_string(h) + " have different lengths (a bug in heartsim)");
            const std::string g = "hand" + std::to_string(h);
            w.group(g);
            w.attribute(g, "device", hand.device);
            w.attribute(g, "device_name", hand.device_name);
            w.attribute(g, "instrument", hand.instrument);
            w.attribute(g, "semi_axes_mm", hand.semi_axes_mm.data(), {3});
            w.attribute(g, "max_force_n", hand.max_force_n);
            w.attribute(g, "mapping_offset_mm", hand.mapping_offset_mm.data(), {3});
            w.attribute(g, "mapping_rotation", hand.mapping_rotation.data(), {4});
            w.attribute(g, "mapping_scale", hand.mapping_scale);
            w.attribute(g, "force_scale", hand.force_scale);
            w.dataset(g + "/tick_time_ms", hand.tick_time_ms, {t});
            w.dataset(g + "/position_mm", hand.position_mm, {t, 3});
            w.dataset(g + "/orientation", hand.orientation, {t, 4});
            w.dataset(g + "/buttons", hand.buttons, {t});
            w.dataset(g + "/input_n", hand.input_n, {t, 3});
            w.dataset(g + "/force_n", hand.force_n, {t, 3});
            w.dataset(g + "/gain", hand.gain, {t});
        }

        w.group("steps");
        w.dataset("steps/time_ms", s.time_ms, {n});
        w.dataset("steps/wall_ms", s.wall_ms, {n});
        w.dataset("steps/tool_time_ms", s.tool_time_ms, {n});
        w.dataset("steps/tool_position_mm", s.tool_position_mm, {n, 2, 3});
        w.dataset("steps/tool_orientation", s.tool_orientation, {n, 2, 4});
        w.dataset("steps/grab", s.grab, {n, 2});
        w.dataset("steps/applied", s.applied, {n, 2});
        w.dataset("steps/force_n", s.force_n, {n, 2, 3});
        w.dataset("steps/force_step", s.force_step, {n});
        w.dataset("steps/diverged", s.diverged, {n});
        if (!s.mass_scale.empty()) w.dataset("steps/mass_scale", s.mass_scale, {n});
        if (!s.instrument.empty()) {
            w.dataset("steps/instrument", s.instrument, {n, 2});
            w.dataset("steps/semi_axes_mm", s.semi_axes_mm, {n, 2, 3});
        }

        w.group("events");
        std::vector<double> times;
        std::vector<std::int32_t> hands;
        std::vector<std::string> what;
        for (const RecordedEvent& e : r.events) times.push_back(e.time_ms), hands.push_back(e.hand), what.push_back(e.what);
        w.dataset("events/time_ms", times, {times.size()});
        w.dataset("events/hand", hands, {hands.size()});
        w.strings("events/what", what);
    }, check, beside);
}

void write_recording(const std::filesystem::path& path, const Recording& recording,
                     const std::function<void(const std::filesystem::path&)>& check) {
    const std::string xdmf = recording_xdmf(path.filename().string(), recording);
    check_xdmf_destination(path);
    write_recording_data(path, recording, check, {xdmf_file_beside(path, xdmf)});
}

namespace {

/// The run's attributes on the root group, and its solver's rules where it kept them.
void read_run_attributes(const h5::Reader& r, Recording& rec) {
    rec.scenario = r.string_attribute("/", "scenario");
    rec.particles = r.number<std::int64_t>("/", "particles");
    rec.dt_ms = r.number<double>("/", "dt_ms");
    rec.substeps = r.number<std::int32_t>("/", "substeps");
    rec.backend = r.string_attribute("/", "backend");
    rec.contact = r.string_attribute("/", "contact");
    rec.interpolation = r.string_attribute("/", "interpolation");
    // Absent in recordings made before the slot's multiply-adds were fused: rounded apart then.
    rec.arithmetic = r.has_attribute("/", "arithmetic") ? r.string_attribute("/", "arithmetic") : "separate";
    if (!known_arithmetic(rec.arithmetic))
        r.fail("/", "attribute arithmetic must be fused or separate, not '" + rec.arithmetic + "'");
    rec.patch_material = r.has_attribute("/", "patch_material") ? r.string_attribute("/", "patch_material") : "pericardium";
    try {
        patch_material_named(rec.patch_material);
    } catch (const InputError& e) {
        r.fail("/", std::string("attribute patch_material: ") + e.what());
    }
    // Absent in recordings made before they kept the solver's rules.
    if (r.exists("rules")) {
        SolverRules rules;
        for_each_rule(
            [&](const char* name, auto& value) {
                // contact_skin: absent in recordings made before instruments met the drawn surface.
                if (std::string(name) == "contact_skin" && !r.has_attribute("rules", name)) value = 0.0;
                else value = r.number<std::remove_reference_t<decltype(value)>>("rules", name);
            },
            rules);
        if (const std::string wrong = check_rules(rules); !wrong.empty()) r.fail("/rules", wrong);
        rec.rules = rules;
    }
    rec.rate_hz = r.number<double>("/", "rate_hz");
    rec.coupling = r.number<std::int32_t>("/", "coupling") != 0;
    rec.period_p50_ms = r.number<double>("/", "period_p50_ms");
    rec.period_p99_ms = r.number<double>("/", "period_p99_ms");
    rec.period_max_ms = r.number<double>("/", "period_max_ms");
    rec.period_mean_ms = r.number<double>("/", "period_mean_ms");
    rec.latency_p50_ms = r.number<double>("/", "latency_p50_ms");
    rec.latency_p99_ms = r.number<double>("/", "latency_p99_ms");
    rec.latency_max_ms = r.number<double>("/", "latency_max_ms");
    rec.periods = r.number<std::int64_t>("/", "periods");
    rec.overruns = r.number<std::int64_t>("/", "overruns");
    if (!(rec.dt_ms > 0.0)) r.fail("/", "attribute dt_ms must be positive");
}

/// Hand h's device, instrument and mapping attributes and its device ticks (group /handH), where
/// the recording has that hand.
void read_hand(const h5::Reader& r, int h, RecordedHand& hand) {
    const std::string g = "hand" + std::to_string(h);
    if (!r.exists(g)) return;
    const std::string where = "/" + g;
    hand.used = true;
    hand.device = r.string_attribute(g, "device");
    hand.device_name = r.string_attribute(g, "device_name");
    hand.instrument = r.string_attribute(g, "instrument");
    if (const auto kind = instrument_kind_named(hand.instrument); !kind || *kind == InstrumentKind::none)
        r.fail(where, "attribute instrument is '" + hand.instrument + "', expected probe, grabber, retractor, scalpel, patch or needle");
    hand.semi_axes_mm = vector_attribute<3>(r, g, "semi_axes_mm");
    for (double a : hand.semi_axes_mm)
        if (!plausible::semi_axis_mm.contains(a)) r.fail(where, "attribute " + plausible::outside("semi_axes_mm", a, plausible::semi_axis_mm));
    hand.max_force_n = r.number<double>(g, "max_force_n");
    if (!plausible::device_force_n.contains(hand.max_force_n))
        r.fail(where, "attribute " + plausible::outside("max_force_n", hand.max_force_n, plausible::device_force_n));
    hand.mapping_offset_mm = vector_attribute<3>(r, g, "mapping_offset_mm");
    hand.mapping_rotation = vector_attribute<4>(r, g, "mapping_rotation");
    hand.mapping_scale = r.number<double>(g, "mapping_scale");
    hand.force_scale = r.number<double>(g, "force_scale");
    {
        const auto& q = hand.mapping_rotation;
        if (!(std::abs(std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) < 1e-6))
            r.fail(where, "attribute mapping_rotation is not a unit quaternion");
        if (!(hand.mapping_scale > 0.0)) r.fail(where, "attribute mapping_scale must be positive");
    }
    std::size_t t = 0;
    hand.tick_time_ms = r.dataset<double>(g + "/tick_time_ms", {-1}, &t);
    const long ticks = long(t);
    const auto position = r.dataset<double>(g + "/position_mm", {ticks, 3});
    const auto orientation = r.dataset<double>(g + "/orientation", {ticks, 4});
    r.require_finite(g + "/tick_time_ms", hand.tick_time_ms);
    r.require_finite(g + "/position_mm", position);
    r.require_finite(g + "/orientation", orientation);
    hand.position_mm = h5::rows_of<3>(position);
    hand.orientation = h5::rows_of<4>(orientation);
    hand.buttons = r.dataset<std::uint32_t>(g + "/buttons", {ticks});
    hand.input_n = h5::rows_of<3>(r.dataset<double>(g + "/input_n", {ticks, 3}));
    const auto force = r.dataset<double>(g + "/force_n", {ticks, 3});
    r.require_finite(g + "/force_n", force);
    hand.force_n = h5::rows_of<3>(force);
    hand.gain = r.dataset<float>(g + "/gain", {ticks});
    r.require_finite(g + "/gain", hand.gain);
    for (std::size_t i = 1; i < hand.tick_time_ms.size(); ++i)
        if (hand.tick_time_ms[i] < hand.tick_time_ms[i - 1]) r.fail(g + "/tick_time_ms", "goes backwards at row " + std::to_string(i));
}

/// The steps' datasets (/steps), each row checked against the hands and instruments read before.
void read_steps(const h5::Reader& r, Recording& rec) {
    RecordedSteps& s = rec.steps;
    std::size_t n = 0;
    s.time_ms = r.dataset<double>("steps/time_ms", {-1}, &n);
    const long steps = long(n);
    s.wall_ms = r.dataset<double>("steps/wall_ms", {steps});
    s.tool_time_ms = r.dataset<double>("steps/tool_time_ms", {steps});
    r.require_finite("steps/time_ms", s.time_ms);
    r.require_finite("steps/wall_ms", s.wall_ms);
    r.require_finite("steps/tool_time_ms", s.tool_time_ms);
    const auto position = r.dataset<double>("steps/tool_position_mm", {steps, 2, 3});
    const auto orientation = r.dataset<double>("steps/tool_orientation", {steps, 2, 4});
    r.require_finite("steps/tool_position_mm", position);
    r.require_finite("steps/tool_orientation", orientation);
    s.tool_position_mm.resize(n);
    s.tool_orientation.resize(n);
    if (n) {
        std::memcpy(s.tool_position_mm.data(), position.data(), position.size() * sizeof(double));
        std::memcpy(s.tool_orientation.data(), orientation.data(), orientation.size() * sizeof(double));
    }
    s.grab = h5::rows_of<2>(r.dataset<std::int8_t>("steps/grab", {steps, 2}));
    s.applied = h5::rows_of<2>(r.dataset<std::int8_t>("steps/applied", {steps, 2}));
    const auto force = r.dataset<double>("steps/force_n", {steps, 2, 3});
    r.require_finite("steps/force_n", force);
    s.force_n.resize(n);
    if (n) std::memcpy(s.force_n.data(), force.data(), force.size() * sizeof(double));
    s.force_step = r.dataset<std::int64_t>("steps/force_step", {steps});
    s.diverged = r.dataset<std::int8_t>("steps/diverged", {steps});
    // Absent in recordings made before heartsim scaled mass: 1 throughout.
    if (r.exists("steps/mass_scale")) {
        s.mass_scale = r.dataset<double>("steps/mass_scale", {steps});
        for (std::size_t i = 0; i < n; ++i)
            if (!valid_mass_scale(s.mass_scale[i]))
                r.fail("steps/mass_scale", "row " + std::to_string(i) + " is " + std::to_string(s.mass_scale[i]) + ", expected " +
                                               std::to_string(min_mass_scale) + " … " + std::to_string(max_mass_scale));
    }
    // Absent in recordings made before an instrument could change inside one: the hands' attributes.
    if (r.exists("steps/instrument") != r.exists("steps/semi_axes_mm"))
        r.fail("/steps", "has one of the datasets instrument and semi_axes_mm without the other");
    if (r.exists("steps/instrument")) {
        s.instrument = h5::rows_of<2>(r.dataset<std::int8_t>("steps/instrument", {steps, 2}));
        const auto axes = r.dataset<double>("steps/semi_axes_mm", {steps, 2, 3});
        s.semi_axes_mm.resize(n);
        if (n) std::memcpy(s.semi_axes_mm.data(), axes.data(), axes.size() * sizeof(double));
        for (std::size_t i = 0; i < n; ++i)
            for (int h = 0; h < 2; ++h)
                if (const StepInstrumentFault fault = check_step_instrument(s.instrument[i][h], s.semi_axes_mm[i][h], rec.hands[h].used);
                    !fault.what.empty())
                    r.fail(std::string("steps/") + fault.dataset, "row " + std::to_string(i) + ", hand " + std::to_string(h) + fault.what);
    }
    for (std::size_t i = 0; i < n; ++i)
        for (int h = 0; h < 2; ++h) {
            const std::string row = "row " + std::to_string(i) + ", hand " + std::to_string(h);
            if (s.grab[i][h] != 0 && s.grab[i][h] != 1) r.fail("/steps", "dataset grab " + row + " is not 0 or 1");
            if (s.applied[i][h] != 0 && s.applied[i][h] != 1) r.fail("/steps", "dataset applied " + row + " is not 0 or 1");
            if (s.applied[i][h] && !rec.hands[h].used) r.fail("/steps", "dataset applied " + row + " applies a hand without a device");
            if (s.grab[i][h] && (!rec.hands[h].used || !takes_grab(rec.instrument_at(i, h).kind)))
                r.fail("/steps", "dataset grab " + row + " grabs with a hand that holds no grabber, retractor, scalpel, patch or needle");
            if (!rec.hands[h].used) continue;
            const auto& q = s.tool_orientation[i][h];
            if (!(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] > 1e-12))
                r.fail("/steps", "dataset tool_orientation " + row + " is a zero quaternion");
        }
    for (std::size_t i = 0; i < n; ++i)
        if (s.force_step[i] < -1 || s.force_step[i] > std::int64_t(i))
            r.fail("steps/force_step", "row " + std::to_string(i) + " names step " + std::to_string(s.force_step[i]) + ", expected −1 … " +
                                           std::to_string(i));
}

void read_events(const h5::Reader& r, Recording& rec) {
    std::size_t e = 0;
    const auto times = r.dataset<double>("events/time_ms", {-1}, &e);
    r.require_finite("events/time_ms", times);
    const auto hands = r.dataset<std::int32_t>("events/hand", {long(e)});
    const auto what = r.strings("events/what", long(e));
    for (std::size_t i = 0; i < e; ++i) rec.events.push_back({times[i], hands[i], what[i]});
}

}  // namespace

Recording read_recording(const std::filesystem::path& path) {
    const h5::Reader r(path);
    r.header("heartsim.recording", 1, 1, "mm g ms N", "is this a heartsim run --record file?");
    Recording rec;
    read_run_attributes(r, rec);
    for (int h = 0; h < 2; ++h) read_hand(r, h, rec.hands[h]);
    read_steps(r, rec);
    read_events(r, rec);
    return rec;
}

}  // namespace heartsim
