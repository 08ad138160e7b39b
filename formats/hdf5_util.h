/// @file hdf5_util.h
/// @brief Small HDF5 C API helpers shared by the state and recording files (formats/ only; not a
/// public header): an owning handle, scalar and string attributes, whole datasets, each failure
/// reported as InputError / OutputError naming the file and the object.
#pragma once

#include "atomic_file.h"

#include "libmodel/errors.h"

#include <hdf5.h>

#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <system_error>
#include <string>
#include <vector>

namespace heartsim::h5 {

class Handle {
public:
    Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
    Handle(const Handle&) = delete;
    Handle(Handle&& other) noexcept : id_(other.id_), close_(other.close_) { other.id_ = -1; }
    Handle& operator=(const Handle&) = delete;
    ~Handle() { if (id_ >= 0) close_(id_); }
    hid_t get() const { return id_; }
    bool valid() const { return id_ >= 0; }
    void reset() { if (id_ >= 0) close_(id_); id_ = -1; }
private:
    hid_t id_;
    herr_t (*close_)(hid_t);
};

/// Element count of an attribute's dataspace (scalar: 1), or −1 when it cannot be read.
inline long long attribute_elements(hid_t attribute) {
    Handle space(H5Aget_space(attribute), H5Sclose);
    return space.valid() ? (long long)H5Sget_simple_extent_npoints(space.get()) : -1;
}

inline void quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

inline void write_string_attribute(hid_t where, const char* name, const std::string& value, const std::string& file) {
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

inline void write_dataset(hid_t where, const char* name, hid_t file_type, hid_t memory_type, const void* data, std::initializer_list<hsize_t> dims,
                   const std::string& file) {
    std::vector<hsize_t> d(dims);
    Handle space(H5Screate_simple(int(d.size()), d.data(), nullptr), H5Sclose);
    Handle set(H5Dcreate2(where, name, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose);
    if (!set.valid()) throw OutputError(file + ": cannot create dataset " + name);
    if (H5Dwrite(set.get(), memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
        throw OutputError(file + ": cannot write dataset " + name + " (disk full?)");
}

inline std::string read_string_attribute(hid_t where, const char* name, const std::string& file) {
    Handle attribute(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid()) throw InputError(file + ": attribute " + std::string(name) + " is missing");
    Handle type(H5Aget_type(attribute.get()), H5Tclose);
    if (H5Tget_class(type.get()) != H5T_STRING) throw InputError(file + ": attribute " + std::string(name) + " is not a string");
    if (attribute_elements(attribute.get()) != 1) throw InputError(file + ": attribute " + std::string(name) + " must be a single string");
    Handle memory(H5Tcopy(H5T_C_S1), H5Tclose);
    if (H5Tis_variable_str(type.get()) > 0) {  // written by other tools (h5py, the scenario writer's peers)
        H5Tset_size(memory.get(), H5T_VARIABLE);
        char* text = nullptr;
        if (H5Aread(attribute.get(), memory.get(), &text) < 0 || !text) throw InputError(file + ": cannot read attribute " + std::string(name));
        std::string value(text);
        H5free_memory(text);
        return value;
    }
    std::string value(H5Tget_size(type.get()), '\0');
    H5Tset_size(memory.get(), value.size());
    if (H5Aread(attribute.get(), memory.get(), value.data()) < 0) throw InputError(file + ": cannot read attribute " + std::string(name));
    value.resize(value.find('\0') == std::string::npos ? value.size() : value.find('\0'));
    return value;
}

template <class T>
T read_scalar_attribute(hid_t where, const char* name, hid_t memory_type, const std::string& file) {
    Handle attribute(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid()) throw InputError(file + ": attribute " + std::string(name) + " is missing");
    // One element only: H5Aread writes every element of the attribute into `value`.
    if (attribute_elements(attribute.get()) != 1)
        throw InputError(file + ": attribute " + std::string(name) + " must be a single value");
    T value{};
    if (H5Aread(attribute.get(), memory_type, &value) < 0)
        throw InputError(file + ": attribute " + std::string(name) + " is unreadable (expected a number)");
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


/// Creates `path` through `fill(root)` in a temporary file beside it, flushes, then renames it
/// into place: nothing half-written remains when fill throws or the disk fills.
template <class Fill>
void write_atomically(const std::filesystem::path& path, Fill&& fill) {
    quiet();
    const std::string file = path.string();
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        Handle h5(H5Fcreate(temporary.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose);
        if (!h5.valid()) throw OutputError(file + ": cannot create the file");
        fill(h5.get());
        if (H5Fflush(h5.get(), H5F_SCOPE_GLOBAL) < 0) throw OutputError(file + ": cannot flush");
    });
}

/// The root attributes every heartsim HDF5 file except the scenario starts with: `format`,
/// `format_version`, `units`, `frame` (LPS).
inline void write_file_header(hid_t root, const std::string& format, std::int32_t version, const std::string& units,
                              const std::string& file) {
    write_string_attribute(root, "format", format, file);
    write_scalar_attribute<std::int32_t>(root, "format_version", H5T_STD_I32LE, H5T_NATIVE_INT32, version, file);
    write_string_attribute(root, "units", units, file);
    write_string_attribute(root, "frame", "LPS", file);
}

/// InputError naming `file` unless its `format` is `format` (then `hint`, e.g. which command
/// writes such files) and its `format_version` is `version`.
inline void check_file_header(hid_t root, const std::string& format, std::int32_t version, const std::string& file,
                              const std::string& hint = "") {
    if (read_string_attribute(root, "format", file) != format)
        throw InputError(file + ": attribute format is not " + format + (hint.empty() ? "" : " (" + hint + ")"));
    if (read_scalar_attribute<std::int32_t>(root, "format_version", H5T_NATIVE_INT32, file) != version)
        throw InputError(file + ": format_version is not " + std::to_string(version));
}

/// Opens an existing HDF5 file read-only; InputError when it is missing or not HDF5.
inline Handle open_read_only(const std::filesystem::path& path) {
    quiet();
    if (!std::filesystem::exists(path)) throw InputError(path.string() + ": no such file");
    Handle h5(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
    if (!h5.valid()) throw InputError(path.string() + ": not an HDF5 file");
    return h5;
}

}  // namespace heartsim::h5
