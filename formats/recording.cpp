// The haptic session recording (recording.h): HDF5 C API, atomic write, validating read.
#include "recording.h"

#include "hdf5_util.h"
#include "libmodel/errors.h"

#include <cmath>
#include <cstring>

namespace heartsim {

using namespace h5;

namespace {

static_assert(sizeof(std::array<double, 3>) == 3 * sizeof(double), "arrays of doubles are packed");
static_assert(sizeof(std::array<std::array<double, 3>, 2>) == 6 * sizeof(double), "arrays of doubles are packed");

constexpr std::size_t what_length = 24;  // fixed-length event names

void write_f64(hid_t where, const char* name, const void* data, std::initializer_list<hsize_t> dims, const std::string& file) {
    write_dataset(where, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, data, dims, file);
}

template <std::size_t N>
std::vector<std::array<double, N>> rows_of(const std::vector<double>& flat) {
    std::vector<std::array<double, N>> rows(flat.size() / N);
    if (!rows.empty()) std::memcpy(rows.data(), flat.data(), rows.size() * sizeof(rows[0]));
    return rows;
}

template <std::size_t N>
void write_vector_attribute(hid_t where, const char* name, const std::array<double, N>& values, const std::string& file) {
    const hsize_t n = N;
    Handle space(H5Screate_simple(1, &n, nullptr), H5Sclose);
    Handle attribute(H5Acreate2(where, name, H5T_IEEE_F64LE, space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid() || H5Awrite(attribute.get(), H5T_NATIVE_DOUBLE, values.data()) < 0)
        throw OutputError(file + ": cannot write attribute " + name);
}

template <std::size_t N>
std::array<double, N> read_vector_attribute(hid_t where, const char* name, const std::string& file) {
    Handle attribute(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
    std::array<double, N> values{};
    if (!attribute.valid() || attribute_elements(attribute.get()) != (long long)N ||
        H5Aread(attribute.get(), H5T_NATIVE_DOUBLE, values.data()) < 0)
        throw InputError(file + ": attribute " + name + " is missing or not " + std::to_string(N) + " numbers");
    for (double v : values)
        if (!std::isfinite(v)) throw InputError(file + ": attribute " + name + " is not finite");
    return values;
}

void require_finite(const std::vector<double>& values, const std::string& file, const std::string& name) {
    for (double v : values)
        if (!std::isfinite(v)) throw InputError(file + ": dataset " + name + " holds a non-finite value");
}

}  // namespace

void write_recording(const std::filesystem::path& path, const Recording& r) {
    const std::string file = path.string();
    const RecordedSteps& s = r.steps;
    const std::size_t n = s.size();
    if (s.wall_ms.size() != n || s.tool_time_ms.size() != n || s.tool_position_mm.size() != n || s.tool_orientation.size() != n ||
        s.grab.size() != n || s.applied.size() != n || s.force_n.size() != n || s.force_step.size() != n || s.diverged.size() != n)
        throw OutputError(file + ": the step columns have different lengths (a bug in heartsim)");
    write_atomically(path, [&](hid_t root) {
        write_file_header(root, "heartsim.recording", 1, "mm g ms N", file);
        write_string_attribute(root, "scenario", r.scenario, file);
        write_scalar_attribute<std::int64_t>(root, "particles", H5T_STD_I64LE, H5T_NATIVE_INT64, r.particles, file);
        write_scalar_attribute<double>(root, "dt_ms", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, r.dt_ms, file);
        write_scalar_attribute<std::int32_t>(root, "substeps", H5T_STD_I32LE, H5T_NATIVE_INT32, r.substeps, file);
        write_string_attribute(root, "backend", r.backend, file);
        write_string_attribute(root, "contact", r.contact, file);
        write_string_attribute(root, "interpolation", r.interpolation, file);
        write_scalar_attribute<double>(root, "rate_hz", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, r.rate_hz, file);
        write_scalar_attribute<std::int32_t>(root, "coupling", H5T_STD_I32LE, H5T_NATIVE_INT32, r.coupling ? 1 : 0, file);
        const std::pair<const char*, double> figures[] = {
            {"period_p50_ms", r.period_p50_ms},   {"period_p99_ms", r.period_p99_ms},   {"period_max_ms", r.period_max_ms},
            {"period_mean_ms", r.period_mean_ms}, {"latency_p50_ms", r.latency_p50_ms}, {"latency_p99_ms", r.latency_p99_ms},
            {"latency_max_ms", r.latency_max_ms}};
        for (const auto& [name, value] : figures) write_scalar_attribute<double>(root, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, value, file);
        write_scalar_attribute<std::int64_t>(root, "periods", H5T_STD_I64LE, H5T_NATIVE_INT64, r.periods, file);
        write_scalar_attribute<std::int64_t>(root, "overruns", H5T_STD_I64LE, H5T_NATIVE_INT64, r.overruns, file);

        for (int h = 0; h < 2; ++h) {
            const RecordedHand& hand = r.hands[h];
            if (!hand.used) continue;
            const std::size_t t = hand.tick_time_ms.size();
            if (hand.position_mm.size() != t || hand.orientation.size() != t || hand.buttons.size() != t || hand.input_n.size() != t ||
                hand.force_n.size() != t || hand.gain.size() != t)
                throw OutputError(file + ": the tick columns of hand " + std::to_string(h) + " have different lengths (a bug in heartsim)");
            const std::string group_name = "hand" + std::to_string(h);
            Handle group(H5Gcreate2(root, group_name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
            if (!group.valid()) throw OutputError(file + ": cannot create group /" + group_name);
            const hid_t g = group.get();
            write_string_attribute(g, "device", hand.device, file);
            write_string_attribute(g, "device_name", hand.device_name, file);
            write_string_attribute(g, "instrument", hand.instrument, file);
            write_vector_attribute(g, "semi_axes_mm", hand.semi_axes_mm, file);
            write_scalar_attribute<double>(g, "max_force_n", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, hand.max_force_n, file);
            write_vector_attribute(g, "mapping_offset_mm", hand.mapping_offset_mm, file);
            write_vector_attribute(g, "mapping_rotation", hand.mapping_rotation, file);
            write_scalar_attribute<double>(g, "mapping_scale", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, hand.mapping_scale, file);
            write_scalar_attribute<double>(g, "force_scale", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, hand.force_scale, file);
            write_f64(g, "tick_time_ms", hand.tick_time_ms.data(), {t}, file);
            write_f64(g, "position_mm", hand.position_mm.data(), {t, 3}, file);
            write_f64(g, "orientation", hand.orientation.data(), {t, 4}, file);
            write_dataset(g, "buttons", H5T_STD_U32LE, H5T_NATIVE_UINT32, hand.buttons.data(), {t}, file);
            write_f64(g, "input_n", hand.input_n.data(), {t, 3}, file);
            write_f64(g, "force_n", hand.force_n.data(), {t, 3}, file);
            write_dataset(g, "gain", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, hand.gain.data(), {t}, file);
        }

        Handle steps(H5Gcreate2(root, "steps", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
        if (!steps.valid()) throw OutputError(file + ": cannot create group /steps");
        const hid_t g = steps.get();
        write_f64(g, "time_ms", s.time_ms.data(), {n}, file);
        write_f64(g, "wall_ms", s.wall_ms.data(), {n}, file);
        write_f64(g, "tool_time_ms", s.tool_time_ms.data(), {n}, file);
        write_f64(g, "tool_position_mm", s.tool_position_mm.data(), {n, 2, 3}, file);
        write_f64(g, "tool_orientation", s.tool_orientation.data(), {n, 2, 4}, file);
        write_dataset(g, "grab", H5T_STD_I8LE, H5T_NATIVE_INT8, s.grab.data(), {n, 2}, file);
        write_dataset(g, "applied", H5T_STD_I8LE, H5T_NATIVE_INT8, s.applied.data(), {n, 2}, file);
        write_f64(g, "force_n", s.force_n.data(), {n, 2, 3}, file);
        write_dataset(g, "force_step", H5T_STD_I64LE, H5T_NATIVE_INT64, s.force_step.data(), {n}, file);
        write_dataset(g, "diverged", H5T_STD_I8LE, H5T_NATIVE_INT8, s.diverged.data(), {n}, file);

        Handle events(H5Gcreate2(root, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
        if (!events.valid()) throw OutputError(file + ": cannot create group /events");
        const std::size_t e = r.events.size();
        std::vector<double> times(e);
        std::vector<std::int32_t> hands(e);
        std::vector<char> what(e * what_length, '\0');
        for (std::size_t i = 0; i < e; ++i) {
            times[i] = r.events[i].time_ms;
            hands[i] = r.events[i].hand;
            std::strncpy(&what[i * what_length], r.events[i].what.c_str(), what_length - 1);
        }
        write_f64(events.get(), "time_ms", times.data(), {e}, file);
        write_dataset(events.get(), "hand", H5T_STD_I32LE, H5T_NATIVE_INT32, hands.data(), {e}, file);
        Handle string_type(H5Tcopy(H5T_C_S1), H5Tclose);
        H5Tset_size(string_type.get(), what_length);
        H5Tset_strpad(string_type.get(), H5T_STR_NULLTERM);
        write_dataset(events.get(), "what", string_type.get(), string_type.get(), what.data(), {e}, file);
    });
}

Recording read_recording(const std::filesystem::path& path) {
    const std::string file = path.string();
    Handle h5 = open_read_only(path);
    const hid_t root = h5.get();
    check_file_header(root, "heartsim.recording", 1, file, "is this a heartsim run --record file?");
    Recording r;
    r.scenario = read_string_attribute(root, "scenario", file);
    r.particles = read_scalar_attribute<std::int64_t>(root, "particles", H5T_NATIVE_INT64, file);
    r.dt_ms = read_scalar_attribute<double>(root, "dt_ms", H5T_NATIVE_DOUBLE, file);
    r.substeps = read_scalar_attribute<std::int32_t>(root, "substeps", H5T_NATIVE_INT32, file);
    r.backend = read_string_attribute(root, "backend", file);
    r.contact = read_string_attribute(root, "contact", file);
    r.interpolation = read_string_attribute(root, "interpolation", file);
    r.rate_hz = read_scalar_attribute<double>(root, "rate_hz", H5T_NATIVE_DOUBLE, file);
    r.coupling = read_scalar_attribute<std::int32_t>(root, "coupling", H5T_NATIVE_INT32, file) != 0;
    r.period_p50_ms = read_scalar_attribute<double>(root, "period_p50_ms", H5T_NATIVE_DOUBLE, file);
    r.period_p99_ms = read_scalar_attribute<double>(root, "period_p99_ms", H5T_NATIVE_DOUBLE, file);
    r.period_max_ms = read_scalar_attribute<double>(root, "period_max_ms", H5T_NATIVE_DOUBLE, file);
    r.period_mean_ms = read_scalar_attribute<double>(root, "period_mean_ms", H5T_NATIVE_DOUBLE, file);
    r.latency_p50_ms = read_scalar_attribute<double>(root, "latency_p50_ms", H5T_NATIVE_DOUBLE, file);
    r.latency_p99_ms = read_scalar_attribute<double>(root, "latency_p99_ms", H5T_NATIVE_DOUBLE, file);
    r.latency_max_ms = read_scalar_attribute<double>(root, "latency_max_ms", H5T_NATIVE_DOUBLE, file);
    r.periods = read_scalar_attribute<std::int64_t>(root, "periods", H5T_NATIVE_INT64, file);
    r.overruns = read_scalar_attribute<std::int64_t>(root, "overruns", H5T_NATIVE_INT64, file);
    if (!(r.dt_ms > 0.0) || !std::isfinite(r.dt_ms)) throw InputError(file + ": attribute dt_ms must be positive");

    for (int h = 0; h < 2; ++h) {
        const std::string group_name = "hand" + std::to_string(h);
        if (H5Lexists(root, group_name.c_str(), H5P_DEFAULT) <= 0) continue;
        Handle group(H5Gopen2(root, group_name.c_str(), H5P_DEFAULT), H5Gclose);
        if (!group.valid()) throw InputError(file + ": /" + group_name + " is not a group");
        const hid_t g = group.get();
        const std::string where = file + ":/" + group_name;
        RecordedHand& hand = r.hands[h];
        hand.used = true;
        hand.device = read_string_attribute(g, "device", where);
        hand.device_name = read_string_attribute(g, "device_name", where);
        hand.instrument = read_string_attribute(g, "instrument", where);
        if (hand.instrument != "probe" && hand.instrument != "grabber")
            throw InputError(where + ": attribute instrument is '" + hand.instrument + "', expected probe or grabber");
        hand.semi_axes_mm = read_vector_attribute<3>(g, "semi_axes_mm", where);
        for (double a : hand.semi_axes_mm)
            if (!(a > 0.0)) throw InputError(where + ": attribute semi_axes_mm must be positive");
        hand.max_force_n = read_scalar_attribute<double>(g, "max_force_n", H5T_NATIVE_DOUBLE, where);
        hand.mapping_offset_mm = read_vector_attribute<3>(g, "mapping_offset_mm", where);
        hand.mapping_rotation = read_vector_attribute<4>(g, "mapping_rotation", where);
        hand.mapping_scale = read_scalar_attribute<double>(g, "mapping_scale", H5T_NATIVE_DOUBLE, where);
        hand.force_scale = read_scalar_attribute<double>(g, "force_scale", H5T_NATIVE_DOUBLE, where);
        {
            const auto& q = hand.mapping_rotation;
            if (!(std::abs(std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) < 1e-6))
                throw InputError(where + ": attribute mapping_rotation is not a unit quaternion");
            if (!(hand.mapping_scale > 0.0) || !std::isfinite(hand.mapping_scale) || !std::isfinite(hand.force_scale))
                throw InputError(where + ": attributes mapping_scale and force_scale must be finite, mapping_scale positive");
        }
        hand.tick_time_ms = read_dataset<double>(g, "tick_time_ms", H5T_NATIVE_DOUBLE, {0}, where);
        const hsize_t t = hand.tick_time_ms.size();
        const auto position = read_dataset<double>(g, "position_mm", H5T_NATIVE_DOUBLE, {t, 3}, where);
        const auto orientation = read_dataset<double>(g, "orientation", H5T_NATIVE_DOUBLE, {t, 4}, where);
        require_finite(hand.tick_time_ms, where, "tick_time_ms");
        require_finite(position, where, "position_mm");
        require_finite(orientation, where, "orientation");
        hand.position_mm = rows_of<3>(position);
        hand.orientation = rows_of<4>(orientation);
        hand.buttons = read_dataset<std::uint32_t>(g, "buttons", H5T_NATIVE_UINT32, {t}, where);
        hand.input_n = rows_of<3>(read_dataset<double>(g, "input_n", H5T_NATIVE_DOUBLE, {t, 3}, where));
        const auto force = read_dataset<double>(g, "force_n", H5T_NATIVE_DOUBLE, {t, 3}, where);
        require_finite(force, where, "force_n");
        hand.force_n = rows_of<3>(force);
        hand.gain = read_dataset<float>(g, "gain", H5T_NATIVE_FLOAT, {t}, where);
        for (std::size_t i = 1; i < hand.tick_time_ms.size(); ++i)
            if (hand.tick_time_ms[i] < hand.tick_time_ms[i - 1]) throw InputError(where + ": dataset tick_time_ms goes backwards at row " + std::to_string(i));
    }

    Handle steps(H5Gopen2(root, "steps", H5P_DEFAULT), H5Gclose);
    if (!steps.valid()) throw InputError(file + ": group /steps is missing");
    const hid_t g = steps.get();
    const std::string where = file + ":/steps";
    RecordedSteps& s = r.steps;
    s.time_ms = read_dataset<double>(g, "time_ms", H5T_NATIVE_DOUBLE, {0}, where);
    const hsize_t n = s.time_ms.size();
    s.wall_ms = read_dataset<double>(g, "wall_ms", H5T_NATIVE_DOUBLE, {n}, where);
    s.tool_time_ms = read_dataset<double>(g, "tool_time_ms", H5T_NATIVE_DOUBLE, {n}, where);
    const auto position = read_dataset<double>(g, "tool_position_mm", H5T_NATIVE_DOUBLE, {n, 2, 3}, where);
    const auto orientation = read_dataset<double>(g, "tool_orientation", H5T_NATIVE_DOUBLE, {n, 2, 4}, where);
    require_finite(position, where, "tool_position_mm");
    require_finite(orientation, where, "tool_orientation");
    s.tool_position_mm.resize(n);
    s.tool_orientation.resize(n);
    if (n) {
        std::memcpy(s.tool_position_mm.data(), position.data(), position.size() * sizeof(double));
        std::memcpy(s.tool_orientation.data(), orientation.data(), orientation.size() * sizeof(double));
    }
    const auto grab = read_dataset<std::int8_t>(g, "grab", H5T_NATIVE_INT8, {n, 2}, where);
    s.grab.resize(n);
    for (std::size_t i = 0; i < n; ++i) s.grab[i] = {grab[2 * i], grab[2 * i + 1]};
    const auto applied = read_dataset<std::int8_t>(g, "applied", H5T_NATIVE_INT8, {n, 2}, where);
    s.applied.resize(n);
    for (std::size_t i = 0; i < n; ++i) s.applied[i] = {applied[2 * i], applied[2 * i + 1]};
    const auto force = read_dataset<double>(g, "force_n", H5T_NATIVE_DOUBLE, {n, 2, 3}, where);
    require_finite(force, where, "force_n");
    s.force_n.resize(n);
    if (n) std::memcpy(s.force_n.data(), force.data(), force.size() * sizeof(double));
    s.force_step = read_dataset<std::int64_t>(g, "force_step", H5T_NATIVE_INT64, {n}, where);
    s.diverged = read_dataset<std::int8_t>(g, "diverged", H5T_NATIVE_INT8, {n}, where);
    for (std::size_t i = 0; i < n; ++i)
        for (int h = 0; h < 2; ++h) {
            const std::string row = " row " + std::to_string(i) + ", hand " + std::to_string(h);
            if (s.grab[i][h] != 0 && s.grab[i][h] != 1) throw InputError(where + ": dataset grab" + row + " is not 0 or 1");
            if (s.applied[i][h] != 0 && s.applied[i][h] != 1) throw InputError(where + ": dataset applied" + row + " is not 0 or 1");
            if (s.applied[i][h] && !r.hands[h].used) throw InputError(where + ": dataset applied" + row + " applies a hand without a device");
            if (s.grab[i][h] && (!r.hands[h].used || r.hands[h].instrument != "grabber"))
                throw InputError(where + ": dataset grab" + row + " grabs with a hand that holds no grabber");
            if (!r.hands[h].used) continue;
            const auto& q = s.tool_orientation[i][h];
            if (!(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] > 1e-12))
                throw InputError(where + ": dataset tool_orientation" + row + " is a zero quaternion");
        }
    for (std::size_t i = 0; i < n; ++i)
        if (s.force_step[i] < -1 || s.force_step[i] > std::int64_t(i))
            throw InputError(where + ": dataset force_step row " + std::to_string(i) + " names step " + std::to_string(s.force_step[i]) +
                             ", expected −1 … " + std::to_string(i));

    Handle events(H5Gopen2(root, "events", H5P_DEFAULT), H5Gclose);
    if (!events.valid()) throw InputError(file + ": group /events is missing");
    const std::string event_where = file + ":/events";
    const auto times = read_dataset<double>(events.get(), "time_ms", H5T_NATIVE_DOUBLE, {0}, event_where);
    const auto hands = read_dataset<std::int32_t>(events.get(), "hand", H5T_NATIVE_INT32, {times.size()}, event_where);
    Handle string_type(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(string_type.get(), what_length);
    const auto what = read_dataset<std::array<char, what_length>>(events.get(), "what", string_type.get(), {times.size()}, event_where);
    for (std::size_t i = 0; i < times.size(); ++i) {
        std::array<char, what_length> w = what[i];
        w[what_length - 1] = '\0';
        r.events.push_back({times[i], hands[i], std::string(w.data())});
    }
    return r;
}

}  // namespace heartsim
