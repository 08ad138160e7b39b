// The simulation state file (state.h): HDF5 C API, atomic write, validating read.
#include "state.h"

#include "libmodel/errors.h"

#include "hdf5_util.h"

#include <cmath>
#include <utility>

namespace heartsim {

using namespace h5;

void write_state(const std::filesystem::path& path, const SimulationState& state) {
    const std::string file = path.string();
    write_atomically(path, [&](hid_t root) {
        write_file_header(root, "heartsim.state", 1, "mm g ms", file);
        write_string_attribute(root, "backend", state.backend, file);
        write_string_attribute(root, "scenario", state.scenario, file);
        write_scalar_attribute<double>(root, "time_ms", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, state.time_ms, file);
        write_scalar_attribute<std::int64_t>(root, "steps", H5T_STD_I64LE, H5T_NATIVE_INT64, state.steps, file);
        write_dataset(root, "positions", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, state.positions.data(), {state.positions.size(), 3}, file);
        write_dataset(root, "instrument_forces", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, state.force_n.data(), {2, 3}, file);
        write_dataset(root, "instrument_particles", H5T_STD_I32LE, H5T_NATIVE_INT32, state.particles.data(), {2}, file);
        write_dataset(root, "instrument_kind", H5T_STD_I32LE, H5T_NATIVE_INT32, state.kind.data(), {2}, file);
        if (!state.visual_positions.empty()) {
            Handle visual(H5Gcreate2(root, "visual", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
            if (!visual.valid()) throw OutputError(file + ": cannot create group /visual");
            write_dataset(visual.get(), "positions", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, state.visual_positions.data(),
                          {state.visual_positions.size(), 3}, file);
        }
    });
}

SimulationState read_state(const std::filesystem::path& path) {
    const std::string file = path.string();
    Handle h5 = open_read_only(path);
    const hid_t root = h5.get();
    check_file_header(root, "heartsim.state", 1, file);
    SimulationState state;
    state.backend = read_string_attribute(root, "backend", file);
    state.scenario = read_string_attribute(root, "scenario", file);
    state.time_ms = read_scalar_attribute<double>(root, "time_ms", H5T_NATIVE_DOUBLE, file);
    state.steps = read_scalar_attribute<std::int64_t>(root, "steps", H5T_NATIVE_INT64, file);
    const auto positions = read_dataset<float>(root, "positions", H5T_NATIVE_FLOAT, {0, 3}, file);
    state.positions.resize(positions.size() / 3);
    for (std::size_t i = 0; i < state.positions.size(); ++i) state.positions[i] = {positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]};
    const auto forces = read_dataset<double>(root, "instrument_forces", H5T_NATIVE_DOUBLE, {2, 3}, file);
    for (int h = 0; h < 2; ++h)
        for (int c = 0; c < 3; ++c) state.force_n[h][c] = forces[std::size_t(3 * h + c)];
    const auto particles = read_dataset<std::int32_t>(root, "instrument_particles", H5T_NATIVE_INT32, {2}, file);
    const auto kind = read_dataset<std::int32_t>(root, "instrument_kind", H5T_NATIVE_INT32, {2}, file);
    for (int h = 0; h < 2; ++h) state.particles[h] = particles[h], state.kind[h] = kind[h];
    for (const auto& p : state.positions)
        for (float c : p)
            if (!std::isfinite(c)) throw InputError(file + ": dataset positions holds a non-finite value");
    if (H5Lexists(root, "visual", H5P_DEFAULT) > 0) {
        const auto visual = read_dataset<float>(root, "visual/positions", H5T_NATIVE_FLOAT, {0, 3}, file);
        state.visual_positions.resize(visual.size() / 3);
        for (std::size_t i = 0; i < state.visual_positions.size(); ++i) {
            state.visual_positions[i] = {visual[3 * i], visual[3 * i + 1], visual[3 * i + 2]};
            for (float c : state.visual_positions[i])
                if (!std::isfinite(c)) throw InputError(file + ": dataset visual/positions holds a non-finite value");
        }
    }
    return state;
}

}  // namespace heartsim
