// The simulation state file (state.h): HDF5 C API, atomic write, validating read.
#include "state.h"

#include "libmodel/errors.h"

#include <hdf5.h>

#include <cmath>
#include <random>
#include <utility>

namespace heartsim {

namespace {

class Handle {
public:
    Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
    Handle(const Handle&) = delete;
    Handle& operator=(const Handle&) = delete;
    ~Handle() { if (id_ >= 0) close_(id_); }
    hid_t get() const { return id_; }
    bool valid() const { return id_ >= 0; }
    void reset() { if (id_ >= 0) close_(id_); id_ = -1; }
private:
    hid_t id_;
    herr_t (*close_)(hid_t);
};

void quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

void write_string_attribute(hid_t where, const char* name, const std::string& value, const std::string& file) {
    Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(type.get(), value.empty() ? 1 : value.size());
    H5Tset_strpad(type.get(), H5T_STR_NULLTERM);
    Handle space(H5Screate(H5S_SCALAR), H5Sclose);
    Handle attribute(H5Acreate2(where, name, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid() || H5Awrite(attribute.get(), type.get(), value.c_str()) < 0)
        throw OutputError(file + ": cannot write attribute " + name);
}

template <class T>
void write_scalar_attribute(hid_t where, const char* name, hid_t file_type, hid_t memory_type, T value, const std::string& file) {
    Handle space(H5Screate(H5S_SCALAR), H5Sclose);
    Handle attribute(H5Acreate2(where, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid() || H5Awrite(attribute.get(), memory_type, &value) < 0) throw OutputError(file + ": cannot write attribute " + name);
}

void write_dataset(hid_t where, const char* name, hid_t file_type, hid_t memory_type, const void* data, std::initializer_list<hsize_t> dims,
                   const std::string& file) {
    std::vector<hsize_t> d(dims);
    Handle space(H5Screate_simple(int(d.size()), d.data(), nullptr), H5Sclose);
    Handle set(H5Dcreate2(where, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose);
    if (!set.valid()) throw OutputError(file + ": cannot create dataset " + name);
    if (H5Dwrite(set.get(), memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
        throw OutputError(file + ": cannot write dataset " + name + " (disk full?)");
}

std::string read_string_attribute(hid_t where, const char* name, const std::string& file) {
    Handle attribute(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid()) throw InputError(file + ": attribute " + std::string(name) + " is missing");
    Handle type(H5Aget_type(attribute.get()), H5Tclose);
    if (H5Tget_class(type.get()) != H5T_STRING || H5Tis_variable_str(type.get()) > 0)
        throw InputError(file + ": attribute " + std::string(name) + " is not a fixed-length string");
    std::string value(H5Tget_size(type.get()), '\0');
    Handle memory(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(memory.get(), value.size());
    if (H5Aread(attribute.get(), memory.get(), value.data()) < 0) throw InputError(file + ": cannot read attribute " + std::string(name));
    value.resize(value.find('\0') == std::string::npos ? value.size() : value.find('\0'));
    return value;
}

template <class T>
T read_scalar_attribute(hid_t where, const char* name, hid_t memory_type, const std::string& file) {
    Handle attribute(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
    T value{};
    if (!attribute.valid() || H5Aread(attribute.get(), memory_type, &value) < 0)
        throw InputError(file + ": attribute " + std::string(name) + " is missing or unreadable");
    return value;
}

template <class T>
std::vector<T> read_dataset(hid_t where, const char* name, hid_t memory_type, std::vector<hsize_t> expected, const std::string& file) {
    Handle set(H5Dopen2(where, name, H5P_DEFAULT), H5Dclose);
    if (!set.valid()) throw InputError(file + ": dataset " + std::string(name) + " is missing");
    Handle space(H5Dget_space(set.get()), H5Sclose);
    const int rank = H5Sget_simple_extent_ndims(space.get());
    std::vector<hsize_t> dims(std::size_t(std::max(rank, 0)));
    H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
    bool ok = dims.size() == expected.size();
    for (std::size_t i = 0; ok && i < dims.size(); ++i) ok = expected[i] == 0 || dims[i] == expected[i];
    if (!ok) throw InputError(file + ": dataset " + std::string(name) + " has an unexpected shape");
    hsize_t count = 1;
    for (hsize_t d : dims) count *= d;
    std::vector<T> values(count);
    if (count && H5Dread(set.get(), memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()) < 0)
        throw InputError(file + ": cannot read dataset " + std::string(name));
    return values;
}

}  // namespace

void write_state(const std::filesystem::path& path, const SimulationState& state) {
    quiet();
    const std::string file = path.string();
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    if (!std::filesystem::is_directory(folder)) throw OutputError(file + ": folder " + folder.string() + " does not exist");
    std::random_device device;
    const auto temporary = folder / ("." + path.filename().string() + ".tmp-" + std::to_string(device()));
    try {
        {
            Handle h5(H5Fcreate(temporary.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose);
            if (!h5.valid()) throw OutputError(file + ": cannot create the file");
            const hid_t root = h5.get();
            write_string_attribute(root, "format", "heartsim.state", file);
            write_scalar_attribute<std::int32_t>(root, "format_version", H5T_STD_I32LE, H5T_NATIVE_INT32, 1, file);
            write_string_attribute(root, "units", "mm g ms", file);
            write_string_attribute(root, "frame", "LPS", file);
            write_string_attribute(root, "backend", state.backend, file);
            write_string_attribute(root, "scenario", state.scenario, file);
            write_scalar_attribute<double>(root, "time_ms", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, state.time_ms, file);
            write_scalar_attribute<std::int64_t>(root, "steps", H5T_STD_I64LE, H5T_NATIVE_INT64, state.steps, file);
            write_dataset(root, "positions", H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, state.positions.data(), {state.positions.size(), 3}, file);
            write_dataset(root, "instrument_forces", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, state.force_n.data(), {2, 3}, file);
            write_dataset(root, "instrument_particles", H5T_STD_I32LE, H5T_NATIVE_INT32, state.particles.data(), {2}, file);
            write_dataset(root, "instrument_kind", H5T_STD_I32LE, H5T_NATIVE_INT32, state.kind.data(), {2}, file);
            if (H5Fflush(root, H5F_SCOPE_GLOBAL) < 0) throw OutputError(file + ": cannot flush");
        }
        std::error_code error;
        std::filesystem::rename(temporary, path, error);
        if (error) throw OutputError(file + ": cannot rename the finished file into place: " + error.message());
    } catch (...) {
        std::error_code ignored;
        std::filesystem::remove(temporary, ignored);
        throw;
    }
}

SimulationState read_state(const std::filesystem::path& path) {
    quiet();
    const std::string file = path.string();
    if (!std::filesystem::exists(path)) throw InputError(file + ": no such file");
    Handle h5(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
    if (!h5.valid()) throw InputError(file + ": not an HDF5 file");
    const hid_t root = h5.get();
    if (read_string_attribute(root, "format", file) != "heartsim.state") throw InputError(file + ": attribute format is not heartsim.state");
    if (read_scalar_attribute<std::int32_t>(root, "format_version", H5T_NATIVE_INT32, file) != 1)
        throw InputError(file + ": format_version is not 1");
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
    return state;
}

}  // namespace heartsim
