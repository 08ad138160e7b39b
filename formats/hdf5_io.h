/// @file hdf5_io.h
/// @brief The one HDF5 layer of formats/ (not a public header): a Writer that creates a file
/// atomically and a Reader that checks every name, shape and element type, both addressing
/// objects by path ("particles/mass", "/hand1") and reporting each failure as OutputError /
/// InputError naming the file and the object. The scenario, state and recording files keep only
/// their schemas.
#pragma once

#include "formats/atomic_file.h"
#include "libmodel/errors.h"

#include <hdf5.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <initializer_list>
#include <string>
#include <vector>

namespace heartsim::h5 {

/// An HDF5 identifier closed by the given function when it goes out of scope.
class Handle {
public:
    Handle() = default;
    Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
    Handle(const Handle&) = delete;
    Handle& operator=(const Handle&) = delete;
    Handle(Handle&& other) noexcept : id_(other.id_), close_(other.close_) { other.id_ = -1; }
    Handle& operator=(Handle&& other) noexcept {
        std::swap(id_, other.id_);
        std::swap(close_, other.close_);
        return *this;
    }
    ~Handle() {
        if (id_ >= 0 && close_) close_(id_);
    }
    hid_t get() const { return id_; }
    bool valid() const { return id_ >= 0; }
private:
    hid_t id_ = -1;
    herr_t (*close_)(hid_t) = nullptr;
};

/// How an element type is stored (little-endian, fixed width) and held in memory.
struct ElementType {
    hid_t file;
    hid_t memory;
    const char* name;  ///< in errors: "float32"
    bool floating;
    bool is_signed;
    std::size_t size;
};

template <class T> ElementType element_type();
template <> inline ElementType element_type<float>() { return {H5T_IEEE_F32LE, H5T_NATIVE_FLOAT, "float32", true, true, 4}; }
template <> inline ElementType element_type<double>() { return {H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, "float64", true, true, 8}; }
template <> inline ElementType element_type<std::int8_t>() { return {H5T_STD_I8LE, H5T_NATIVE_INT8, "int8", false, true, 1}; }
template <> inline ElementType element_type<std::uint8_t>() { return {H5T_STD_U8LE, H5T_NATIVE_UINT8, "uint8", false, false, 1}; }
template <> inline ElementType element_type<std::int32_t>() { return {H5T_STD_I32LE, H5T_NATIVE_INT32, "int32", false, true, 4}; }
template <> inline ElementType element_type<std::uint32_t>() { return {H5T_STD_U32LE, H5T_NATIVE_UINT32, "uint32", false, false, 4}; }
template <> inline ElementType element_type<std::int64_t>() { return {H5T_STD_I64LE, H5T_NATIVE_INT64, "int64", false, true, 8}; }

/// The number of elements of a dataset or attribute of shape `dims` (1 for a scalar).
inline std::size_t element_count(std::initializer_list<std::size_t> dims) {
    std::size_t count = 1;
    for (std::size_t d : dims) count *= d;
    return count;
}

/// The number type inside a (nested) std::array.
template <class E> struct Scalar { using type = E; };
template <class E, std::size_t K> struct Scalar<std::array<E, K>> { using type = typename Scalar<E>::type; };

/// Writes into one open file. Names are paths from the root; "/" is the root itself.
class Writer {
public:
    /// `file` is the open HDF5 file; `path` names it in errors (the final name, not the temporary).
    Writer(hid_t file, std::string path) : file_(file), path_(std::move(path)) {}

    void group(const std::string& name);

    /// Dataset of shape `dims` (the first is the row count). Datasets of 4096 elements or more
    /// are chunked and compressed (shuffle + deflate 1: fast, and every reader reads them whole).
    template <class T> void dataset(const std::string& name, const T* data, std::initializer_list<std::size_t> dims) {
        write_dataset(name, element_type<T>(), data, dims);
    }
    /// The same from a vector of numbers or of (nested) std::arrays of them, which must hold
    /// exactly the elements `dims` asks for.
    template <class E> void dataset(const std::string& name, const std::vector<E>& values, std::initializer_list<std::size_t> dims) {
        using T = typename Scalar<E>::type;
        static_assert(sizeof(E) % sizeof(T) == 0, "arrays are packed");
        if (element_count(dims) != values.size() * (sizeof(E) / sizeof(T))) fail("dataset " + name + " does not match its shape (a bug in heartsim)");
        write_dataset(name, element_type<T>(), values.data(), dims);
    }
    /// One-dimensional dataset of fixed-length UTF-8 strings, as wide as the longest (zero-padded).
    void strings(const std::string& name, const std::vector<std::string>& values);

    /// A fixed-length UTF-8 string attribute of `object` (its own length, at least 1; zero-padded).
    /// Fixed, not variable-length: variable-length strings live in HDF5's global heap, which no
    /// checksum covers (hdf5_io.cpp, utf8_string_type).
    void attribute(const std::string& object, const std::string& name, const std::string& value);
    void attribute(const std::string& object, const std::string& name, const char* value) { attribute(object, name, std::string(value)); }
    /// A scalar numeric attribute.
    template <class T> void attribute(const std::string& object, const std::string& name, T value) {
        write_attribute(object, name, element_type<T>(), &value, {});
    }
    /// A numeric attribute of shape `dims` ({n} for a list, {4, 4} for a matrix); a zero-length
    /// list is allowed.
    template <class T>
    void attribute(const std::string& object, const std::string& name, const T* values, std::initializer_list<std::size_t> dims) {
        write_attribute(object, name, element_type<T>(), values, dims);
    }

    /// The root attributes every heartsim HDF5 file starts with: format, format_version, units
    /// and frame (always LPS).
    void header(const std::string& format, int version, const std::string& units);

    [[noreturn]] void fail(const std::string& what) const;

private:
    void write_dataset(const std::string& name, const ElementType& type, const void* data, std::initializer_list<std::size_t> dims);
    void write_attribute(const std::string& object, const std::string& name, const ElementType& type, const void* values,
                         std::initializer_list<std::size_t> dims);
    hid_t file_;
    std::string path_;
};

/// Creates `path` through `fill` in a temporary file beside it, flushes, then renames it into
/// place: nothing half-written remains when fill throws or the disk fills. `check`, when given,
/// reads the complete temporary file before it takes the name; what it throws leaves no file.
/// `beside`: files that belong with it (the .xmf2), written and flushed before either is renamed.
void write_file(const std::filesystem::path& path, const std::function<void(Writer&)>& fill,
                const std::function<void(const std::filesystem::path&)>& check = {}, const std::vector<FileBeside>& beside = {});

/// HDF5's metadata checksum: Bob Jenkins' lookup3 (hashlittle) of `length` bytes, initval 0.
std::uint32_t lookup3(const unsigned char* data, std::size_t length);

/// Rewrites the checksum of a version 2 or 3 superblock at the start of a file image.
/// H5Fget_file_image in HDF5 1.10 clears the superblock's "open for writing" flags in the image it
/// returns but leaves the checksum computed with them set, so the image would not open.
void repair_superblock_checksum(std::vector<unsigned char>& image);

/// Reads one file, checking what it reads; every refusal is an InputError
/// "<file>: <object>: <what>". A call that fails because HDF5 could not allocate memory throws
/// std::bad_alloc instead (the file is not at fault; the tools say "out of memory while …"), and
/// so does the Writer.
class Reader {
public:
    /// Opens `path` read-only; refuses a missing file and one that is not HDF5.
    explicit Reader(const std::filesystem::path& path);

    const std::string& path() const { return path_; }
    /// Whether `name` (a group or dataset path) exists; false also when a group on its path does not.
    bool exists(const std::string& name) const;
    bool has_attribute(const std::string& object, const std::string& name) const;

    /// Checks the root's format (naming `hint` when it differs: which command writes such files),
    /// that format_version lies in [oldest, newest], units and frame; returns the version.
    int header(const std::string& format, int oldest, int newest, const std::string& units, const std::string& hint = "") const;

    /// Dataset `name` of exactly element type T and shape `shape`, where −1 accepts any extent;
    /// `rows` receives the first extent.
    template <class T>
    std::vector<T> dataset(const std::string& name, std::initializer_list<long> shape, std::size_t* rows = nullptr) const {
        std::vector<T> values;
        read_dataset(name, element_type<T>(), shape, rows, [&](std::size_t count) {
            values.resize(count);
            return static_cast<void*>(values.data());
        });
        return values;
    }
    /// One-dimensional string dataset (variable or fixed length) of `rows` entries (−1: any).
    std::vector<std::string> strings(const std::string& name, long rows) const;

    /// A single string attribute (variable or fixed length).
    std::string string_attribute(const std::string& object, const std::string& name) const;
    /// A finite numeric attribute of `count` values (−1: any count), converted to T.
    template <class T> std::vector<T> numbers(const std::string& object, const std::string& name, long count) const {
        std::vector<T> values;
        read_attribute(object, name, element_type<T>(), count, [&](std::size_t n) {
            values.resize(n);
            return static_cast<void*>(values.data());
        });
        for (T v : values)
            if (!std::isfinite(double(v))) fail(object, "attribute " + name + " is not finite");
        return values;
    }
    template <class T> T number(const std::string& object, const std::string& name) const { return numbers<T>(object, name, 1)[0]; }

    /// Refuses the first non-finite value of dataset `name`.
    template <class T> void require_finite(const std::string& name, const std::vector<T>& values) const {
        for (std::size_t n = 0; n < values.size(); ++n)
            if (!std::isfinite(values[n])) fail(name, "value " + std::to_string(n) + " is not finite");
    }

    [[noreturn]] void fail(const std::string& where, const std::string& what) const;

private:
    void read_dataset(const std::string& name, const ElementType& type, std::initializer_list<long> shape, std::size_t* rows,
                      const std::function<void*(std::size_t)>& allocate) const;
    void read_attribute(const std::string& object, const std::string& name, const ElementType& type, long count,
                        const std::function<void*(std::size_t)>& allocate) const;
    Handle open_attribute(const std::string& object, const std::string& name) const;
    Handle open_dataset(const std::string& name) const;
    /// Refuses a chunked dataset whose chunk index (a checksum-free B-tree) places a chunk outside
    /// the file or makes it larger than its values could take, before HDF5 allocates for it.
    void check_chunks(hid_t set, const std::string& name, std::size_t element_size) const;
    /// Before the first variable-length string is read (files written before heartsim stored strings
    /// fixed-length): check_global_heaps, once.
    void check_heaps_once() const;
    std::string path_;
    Handle file_;
    mutable bool heaps_checked_ = false;
};

/// The global heap collections of an HDF5 file (where variable-length strings live, under no
/// checksum), walked as HDF5 1.10 walks them: every object must advance and end inside its
/// collection, and the objects must tile it. HDF5 1.10 loops forever on a zero-sized free-space
/// object and copies out of bounds on an object larger than its collection (fuzz_scenario,
/// fuzz_recording). Collections are found by their signature "GCOL", version 1 and three zero
/// bytes; lengths are taken as 8 bytes (HDF5's default, and every heartsim file's). Returns an
/// empty string when every collection is sound, else what is wrong.
std::string global_heap_problem(const std::filesystem::path& path);

/// Rows of K values from a flat dataset read in row-major order.
template <std::size_t K, class T> std::vector<std::array<T, K>> rows_of(const std::vector<T>& flat) {
    static_assert(sizeof(std::array<T, K>) == K * sizeof(T), "arrays are packed");
    std::vector<std::array<T, K>> rows(flat.size() / K);
    if (!rows.empty()) std::memcpy(rows.data(), flat.data(), rows.size() * sizeof(rows[0]));
    return rows;
}

}  // namespace heartsim::h5
