// The scenario file through HDF5's C API. Every name, shape and type here is the contract of
// shared/SCENARIO.md; additions are documented in docs/scenario-format.md.
#include "scenario.h"

#include "atomic_file.h"

#include "libmodel/errors.h"

#include <hdf5.h>
#include <openssl/evp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <fstream>
#include <functional>
#include <sstream>

namespace heartsim {

namespace {

/// An HDF5 identifier closed by the given function when it goes out of scope.
class H5Object {
public:
    H5Object() = default;
    H5Object(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
    H5Object(H5Object&& other) noexcept : id_(other.id_), close_(other.close_) { other.id_ = -1; }
    H5Object& operator=(H5Object&& other) noexcept {
        std::swap(id_, other.id_);
        std::swap(close_, other.close_);
        return *this;
    }
    ~H5Object() {
        if (id_ >= 0 && close_) close_(id_);
    }
    hid_t get() const { return id_; }
    bool valid() const { return id_ >= 0; }
private:
    hid_t id_ = -1;
    herr_t (*close_)(hid_t) = nullptr;
};

/// HDF5 prints its own error stack by default; we report our own messages instead.
void silence_hdf5() {
    static const bool done = [] {
        H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
        return true;
    }();
    (void)done;
}

template <class T> struct H5Type;
template <> struct H5Type<float> {
    static hid_t native() { return H5T_NATIVE_FLOAT; }
    static hid_t file() { return H5T_IEEE_F32LE; }
    static constexpr const char* name = "float32";
};
template <> struct H5Type<double> {
    static hid_t native() { return H5T_NATIVE_DOUBLE; }
    static hid_t file() { return H5T_IEEE_F64LE; }
    static constexpr const char* name = "float64";
};
template <> struct H5Type<std::int32_t> {
    static hid_t native() { return H5T_NATIVE_INT32; }
    static hid_t file() { return H5T_STD_I32LE; }
    static constexpr const char* name = "int32";
};
template <> struct H5Type<std::uint8_t> {
    static hid_t native() { return H5T_NATIVE_UINT8; }
    static hid_t file() { return H5T_STD_U8LE; }
    static constexpr const char* name = "uint8";
};

// ---------------------------------------------------------------------------------------------
// Writing

class Writer {
public:
    Writer(const std::filesystem::path& final_path, const std::filesystem::path& path) : final_path_(final_path) {
        file_ = H5Object(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose);
        if (!file_.valid()) fail("cannot create the file");
    }
    hid_t file() const { return file_.get(); }
    void close() {
        if (H5Fflush(file_.get(), H5F_SCOPE_GLOBAL) < 0) fail("cannot flush");
        file_ = H5Object();
    }

    H5Object group(const char* name) {
        H5Object g(H5Gcreate2(file_.get(), name, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
        if (!g.valid()) fail(std::string("cannot create group ") + name);
        return g;
    }

    /// Dataset of `rows` × `columns` (columns 0 = one-dimensional). Large ones are chunked and
    /// compressed (shuffle + deflate 1: a fast setting; the runtime reads the whole file once).
    template <class T>
    void dataset(hid_t where, const char* name, const T* data, std::size_t rows, std::size_t columns = 0) {
        hsize_t dims[2] = {rows, columns};
        const int rank = columns ? 2 : 1;
        H5Object space(H5Screate_simple(rank, dims, nullptr), H5Sclose);
        H5Object properties(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
        const std::size_t elements = rows * (columns ? columns : 1);
        if (elements >= 4096) {
            hsize_t chunk[2] = {std::min<hsize_t>(rows, std::max<hsize_t>(1, 65536 / (columns ? columns : 1))), columns};
            H5Pset_chunk(properties.get(), rank, chunk);
            H5Pset_shuffle(properties.get());
            H5Pset_deflate(properties.get(), 1);
        }
        H5Object set(H5Dcreate2(where, name, H5Type<T>::file(), space.get(), H5P_DEFAULT, properties.get(), H5P_DEFAULT),
                     H5Dclose);
        if (!set.valid()) fail(std::string("cannot create dataset ") + name);
        if (elements && H5Dwrite(set.get(), H5Type<T>::native(), H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
            fail(std::string("cannot write dataset ") + name + " (disk full?)");
    }

    void strings(hid_t where, const char* name, const std::vector<std::string>& values) {
        hsize_t dims[1] = {values.size()};
        H5Object space(H5Screate_simple(1, dims, nullptr), H5Sclose);
        H5Object type = string_type();
        H5Object set(H5Dcreate2(where, name, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose);
        std::vector<const char*> pointers;
        for (const auto& v : values) pointers.push_back(v.c_str());
        if (!set.valid() || (!values.empty() && H5Dwrite(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0))
            fail(std::string("cannot write dataset ") + name);
    }

    void attribute(hid_t where, const char* name, const std::string& value) {
        H5Object type = string_type();
        H5Object space(H5Screate(H5S_SCALAR), H5Sclose);
        H5Object attr(H5Acreate2(where, name, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
        const char* pointer = value.c_str();
        if (!attr.valid() || H5Awrite(attr.get(), type.get(), &pointer) < 0) fail(std::string("cannot write attribute ") + name);
    }

    template <class T>
    void attribute(hid_t where, const char* name, const T* values, std::vector<hsize_t> dims) {
        H5Object space(dims.empty() ? H5Screate(H5S_SCALAR) : H5Screate_simple(int(dims.size()), dims.data(), nullptr), H5Sclose);
        H5Object attr(H5Acreate2(where, name, H5Type<T>::file(), space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
        if (!attr.valid() || H5Awrite(attr.get(), H5Type<T>::native(), values) < 0)
            fail(std::string("cannot write attribute ") + name);
    }
    template <class T> void attribute(hid_t where, const char* name, T value) { attribute(where, name, &value, {}); }

    void ints(hid_t where, const char* name, const std::vector<int>& values) {
        // An empty list is a zero-length attribute; H5Awrite still wants a non-null buffer.
        std::vector<std::int32_t> copy(values.begin(), values.end());
        const std::int32_t unused = 0;
        attribute(where, name, copy.empty() ? &unused : copy.data(), {hsize_t(copy.size())});
    }

    void matrix(hid_t where, const char* name, const Eigen::Matrix4d& m) {
        double rows[16];
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) rows[4 * r + c] = m(r, c);
        attribute(where, name, rows, {4, 4});
    }

    [[noreturn]] void fail(const std::string& what) const {
        throw OutputError(final_path_.string() + ": " + what);
    }

private:
    static H5Object string_type() {
        H5Object type(H5Tcopy(H5T_C_S1), H5Tclose);
        H5Tset_size(type.get(), H5T_VARIABLE);
        H5Tset_cset(type.get(), H5T_CSET_UTF8);
        return type;
    }
    std::filesystem::path final_path_;
    H5Object file_;
};

void write_contents(Writer& w, const Scenario& s) {
    const hid_t root = w.file();
    w.attribute(root, "format", std::string("heartsim.scenario"));
    w.attribute(root, "format_version", std::int32_t(scenario_format_version));
    w.attribute(root, "units", std::string("mm g ms"));
    w.attribute(root, "frame", std::string("LPS"));
    w.attribute(root, "generator", s.generator);
    w.attribute(root, "source_sha256", s.source.sha256);
    if (!s.batch_key.empty()) w.attribute(root, "batch_key", s.batch_key);

    {
        H5Object g = w.group("source");
        const auto& geometry = s.source.geometry;
        w.attribute(g.get(), "file_name", s.source.file_name);
        const std::int32_t dims[3] = {geometry.dims[0], geometry.dims[1], geometry.dims[2]};
        w.attribute(g.get(), "dims", dims, {3});
        w.attribute(g.get(), "spacing", geometry.spacing.data(), {3});
        w.matrix(g.get(), "voxel_to_world", geometry.voxel_to_world());
        w.ints(g.get(), "tissue_labels", s.source.tissue_labels);
        w.ints(g.get(), "cavity_labels", s.source.cavity_labels);
        w.ints(g.get(), "anchor_labels", s.source.anchor_labels);
        w.attribute(g.get(), "anchor_border", std::int32_t(s.source.anchor_border));
    }
    const auto& lattice = s.lattice;
    {
        H5Object g = w.group("lattice");
        w.attribute(g.get(), "spacing", lattice.spacing);
        const std::int32_t dims[3] = {lattice.dims[0], lattice.dims[1], lattice.dims[2]};
        w.attribute(g.get(), "dims", dims, {3});
        w.matrix(g.get(), "index_to_world", lattice.index_to_world);
    }
    {
        H5Object g = w.group("materials");
        std::vector<std::int32_t> label;
        std::vector<std::string> name;
        std::vector<float> density, stiffness, damping, youngs;
        for (const auto& m : lattice.materials) {
            label.push_back(m.label);
            name.push_back(m.name);
            density.push_back(float(m.density));
            stiffness.push_back(float(spring_stiffness(m.youngs_modulus_kpa, lattice.spacing)));
            damping.push_back(float(m.damping_ratio));
            youngs.push_back(float(m.youngs_modulus_kpa));
        }
        const std::size_t m = lattice.materials.size();
        w.dataset(g.get(), "label", label.data(), m);
        w.strings(g.get(), "name", name);
        w.dataset(g.get(), "density", density.data(), m);
        w.dataset(g.get(), "stiffness", stiffness.data(), m);
        w.dataset(g.get(), "damping", damping.data(), m);
        w.dataset(g.get(), "youngs_modulus_kpa", youngs.data(), m);
    }
    {
        H5Object g = w.group("particles");
        const auto& p = lattice.particles;
        const std::size_t n = p.size();
        w.dataset(g.get(), "rest_position", p.rest_position.data()->data(), n, 3);
        w.dataset(g.get(), "lattice_index", p.lattice_index.data()->data(), n, 3);
        w.dataset(g.get(), "mass", p.mass.data(), n);
        w.dataset(g.get(), "material", p.material.data(), n);
        w.dataset(g.get(), "anchored", p.anchored.data(), n);
        if (p.supported()) {
            if (p.support_stiffness.size() != n || p.support_point.size() != n)
                throw InputError("scenario: the support arrays differ in length from the particles");
            w.dataset(g.get(), "support_stiffness", p.support_stiffness.data(), n);
            w.dataset(g.get(), "support_point", p.support_point.data()->data(), n, 3);
            if (p.support_damping.size() != n) throw InputError("scenario: the support damping array differs in length from the particles");
            w.dataset(g.get(), "support_damping", p.support_damping.data(), n);
        }
    }
    {
        H5Object g = w.group("springs");
        const auto& sp = lattice.springs;
        w.dataset(g.get(), "pairs", sp.pairs.data()->data(), sp.size(), 2);
        w.dataset(g.get(), "rest_length", sp.rest_length.data(), sp.size());
        w.dataset(g.get(), "stiffness", sp.stiffness.data(), sp.size());
    }
    if (s.visual) {
        H5Object g = w.group("visual");
        const auto& v = *s.visual;
        w.dataset(g.get(), "positions", v.positions.data()->data(), v.positions.size(), 3);
        w.dataset(g.get(), "normals", v.normals.data()->data(), v.normals.size(), 3);
        w.dataset(g.get(), "triangles", v.triangles.data()->data(), v.triangles.size(), 3);
    }
    if (s.packing) {
        H5Object g = w.group("packing");
        const auto& p = *s.packing;
        w.dataset(g.get(), "neighbours", p.neighbours.data()->data(), p.neighbours.size(), 18);
        w.dataset(g.get(), "texture_coord", p.texture_coord.data()->data(), p.texture_coord.size(), 2);
        H5Object set(H5Dopen2(g.get(), "texture_coord", H5P_DEFAULT), H5Dclose);
        w.attribute(set.get(), "width", std::int32_t(p.width));
        w.attribute(set.get(), "height", std::int32_t(p.height));
        w.attribute(set.get(), "scheme", std::string(to_string(p.scheme)));
    }
    if (s.simulation_surface) {
        H5Object g = w.group("simsurface");
        const auto& surface = *s.simulation_surface;
        if (surface.normal_weight.size() != surface.triangles.size())
            throw InputError("scenario: the simulation surface has " + std::to_string(surface.normal_weight.size()) +
                             " normal weights for " + std::to_string(surface.triangles.size()) + " triangles");
        w.dataset(g.get(), "triangles", surface.triangles.data()->data(), surface.triangles.size(), 3);
        w.dataset(g.get(), "normal_weight", surface.normal_weight.data(), surface.normal_weight.size());
    }
    if (s.mapping) {
        H5Object g = w.group("mapping");
        const auto& m = *s.mapping;
        w.dataset(g.get(), "triangle", m.triangle.data(), m.triangle.size());
        w.dataset(g.get(), "barycentric", m.barycentric.data()->data(), m.barycentric.size(), 3);
        w.dataset(g.get(), "offset", m.offset.data(), m.offset.size());
        if (m.particles.size() != m.weights.size() || (!m.particles.empty() && m.particles.size() != m.triangle.size()))
            throw InputError("scenario: the mapping has " + std::to_string(m.particles.size()) + " carrier rows and " +
                             std::to_string(m.weights.size()) + " weight rows for " + std::to_string(m.triangle.size()) +
                             " visual vertices");
        if (!m.particles.empty()) {
            w.dataset(g.get(), "particles", m.particles.data()->data(), m.particles.size(), 8);
            w.dataset(g.get(), "weights", m.weights.data()->data(), m.weights.size(), 8);
        }
    }
    {
        H5Object g = w.group("solver");
        w.attribute(g.get(), "dt_ms", s.solver.dt_ms);
        w.attribute(g.get(), "substeps", std::int32_t(s.solver.substeps));
        w.attribute(g.get(), "damping", s.solver.damping);
        w.attribute(g.get(), "gravity", s.solver.gravity.data(), {3});
        w.attribute(g.get(), "balanced_gravity", s.solver.balanced_gravity.data(), {3});
        w.attribute(g.get(), "critical_dt_ms", s.solver.critical_dt_ms);
        w.attribute(g.get(), "critical_dt_bound_ms", s.solver.critical_dt_bound_ms);
        if (s.solver.damped_critical_dt_ms > 0) w.attribute(g.get(), "damped_critical_dt_ms", s.solver.damped_critical_dt_ms);
        w.attribute(g.get(), "safety_factor", s.solver.safety_factor);
    }
}

// ---------------------------------------------------------------------------------------------
// Reading

class Reader {
public:
    explicit Reader(const std::filesystem::path& path) : path_(path) {
        if (!std::filesystem::exists(path)) fail("", "file not found");
        if (H5Fis_hdf5(path.c_str()) <= 0) fail("", "not an HDF5 file");
        file_ = H5Object(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
        if (!file_.valid()) fail("", "cannot open (damaged HDF5 file?)");
    }
    hid_t file() const { return file_.get(); }

    bool exists(const char* name) const { return H5Lexists(file_.get(), name, H5P_DEFAULT) > 0; }

    H5Object object(const char* name) const {
        if (!exists(name)) fail(name, "missing");
        H5Object o(H5Oopen(file_.get(), name, H5P_DEFAULT), H5Oclose);
        if (!o.valid()) fail(name, "cannot open");
        return o;
    }

    /// Reads dataset `name` of element type T, shape [rows] (columns = 0) or [rows, columns];
    /// `rows` < 0 accepts any row count. Returns the row count.
    template <class T>
    std::vector<T> dataset(const char* name, long rows, std::size_t columns, std::size_t* rows_out = nullptr) const {
        if (!exists(name)) fail(name, "missing dataset");
        H5Object set(H5Dopen2(file_.get(), name, H5P_DEFAULT), H5Dclose);
        if (!set.valid()) fail(name, "is not a dataset");
        check_type<T>(name, H5Object(H5Dget_type(set.get()), H5Tclose).get());
        H5Object space(H5Dget_space(set.get()), H5Sclose);
        const int rank = H5Sget_simple_extent_ndims(space.get());
        hsize_t dims[2] = {0, 0};
        const int expected_rank = columns ? 2 : 1;
        std::ostringstream shape;
        shape << "[" << (rows < 0 ? std::string("N") : std::to_string(rows)) << (columns ? "," + std::to_string(columns) : "") << "]";
        if (rank != expected_rank) fail(name, "has rank " + std::to_string(rank) + ", expected shape " + shape.str());
        H5Sget_simple_extent_dims(space.get(), dims, nullptr);
        if ((rows >= 0 && dims[0] != hsize_t(rows)) || (columns && dims[1] != columns)) {
            std::ostringstream found;
            found << "[" << dims[0] << (columns ? "," + std::to_string(dims[1]) : "") << "]";
            fail(name, "has shape " + found.str() + ", expected " + shape.str());
        }
        std::vector<T> values(std::size_t(dims[0]) * (columns ? columns : 1));
        if (!values.empty() && H5Dread(set.get(), H5Type<T>::native(), H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()) < 0)
            fail(name, "cannot be read (damaged file?)");
        if (rows_out) *rows_out = std::size_t(dims[0]);
        return values;
    }

    std::vector<std::string> strings(const char* name, std::size_t rows) const {
        if (!exists(name)) fail(name, "missing dataset");
        H5Object set(H5Dopen2(file_.get(), name, H5P_DEFAULT), H5Dclose);
        H5Object type(H5Dget_type(set.get()), H5Tclose);
        if (H5Tget_class(type.get()) != H5T_STRING || !H5Tis_variable_str(type.get()))
            fail(name, "expected variable-length strings");
        H5Object space(H5Dget_space(set.get()), H5Sclose);
        hsize_t dims[1] = {0};
        if (H5Sget_simple_extent_ndims(space.get()) != 1) fail(name, "expected a one-dimensional dataset");
        H5Sget_simple_extent_dims(space.get(), dims, nullptr);
        if (dims[0] != rows) fail(name, "has " + std::to_string(dims[0]) + " entries, expected " + std::to_string(rows));
        std::vector<char*> pointers(rows, nullptr);
        if (rows && H5Dread(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0)
            fail(name, "cannot be read");
        std::vector<std::string> values;
        for (char* p : pointers) values.emplace_back(p ? p : "");
        if (rows) H5Dvlen_reclaim(type.get(), space.get(), H5P_DEFAULT, pointers.data());
        return values;
    }

    std::string string_attribute(hid_t where, const char* owner, const char* name) const {
        H5Object attr = open_attribute(where, owner, name);
        H5Object type(H5Aget_type(attr.get()), H5Tclose);
        if (H5Tget_class(type.get()) != H5T_STRING) fail(owner, std::string("attribute ") + name + " is not a string");
        {  // one string only: H5Aread writes every element into the buffer
            H5Object space(H5Aget_space(attr.get()), H5Sclose);
            if (H5Sget_simple_extent_npoints(space.get()) != 1) fail(owner, std::string("attribute ") + name + " must be a single string");
        }
        if (H5Tis_variable_str(type.get())) {
            char* value = nullptr;
            H5Object memory(H5Tcopy(H5T_C_S1), H5Tclose);
            H5Tset_size(memory.get(), H5T_VARIABLE);
            H5Tset_cset(memory.get(), H5Tget_cset(type.get()));
            if (H5Aread(attr.get(), memory.get(), &value) < 0) fail(owner, std::string("attribute ") + name + " cannot be read");
            std::string result = value ? value : "";
            H5free_memory(value);
            return result;
        }
        std::string value(H5Tget_size(type.get()), '\0');
        if (H5Aread(attr.get(), type.get(), value.data()) < 0) fail(owner, std::string("attribute ") + name + " cannot be read");
        return value.substr(0, value.find('\0'));
    }

    /// Numeric attribute with exactly `count` values (scalar when count is 1 and it is scalar).
    template <class T>
    std::vector<T> numeric_attribute(hid_t where, const char* owner, const char* name, std::size_t count, bool any_count = false) const {
        H5Object attr = open_attribute(where, owner, name);
        H5Object type(H5Aget_type(attr.get()), H5Tclose);
        const auto type_class = H5Tget_class(type.get());
        if (type_class != H5T_INTEGER && type_class != H5T_FLOAT)
            fail(owner, std::string("attribute ") + name + " is not numeric");
        H5Object space(H5Aget_space(attr.get()), H5Sclose);
        const hssize_t n = H5Sget_simple_extent_npoints(space.get());
        if (!any_count && std::size_t(n) != count)
            fail(owner, std::string("attribute ") + name + " has " + std::to_string(n) + " values, expected " + std::to_string(count));
        std::vector<T> values(std::size_t(std::max<hssize_t>(n, 0)));
        if (n > 0 && H5Aread(attr.get(), H5Type<T>::native(), values.data()) < 0)
            fail(owner, std::string("attribute ") + name + " cannot be read");
        for (T v : values)
            if (!std::isfinite(double(v))) fail(owner, std::string("attribute ") + name + " is not finite");
        return values;
    }
    template <class T> T scalar(hid_t where, const char* owner, const char* name) const {
        return numeric_attribute<T>(where, owner, name, 1)[0];
    }
    bool has_attribute(hid_t where, const char* name) const { return H5Aexists(where, name) > 0; }

    Eigen::Matrix4d matrix(hid_t where, const char* owner, const char* name) const {
        auto values = numeric_attribute<double>(where, owner, name, 16);
        Eigen::Matrix4d m;
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) m(r, c) = values[std::size_t(4 * r + c)];
        return m;
    }

    [[noreturn]] void fail(const std::string& where, const std::string& what) const {
        throw InputError(path_.string() + ": " + (where.empty() ? "" : where + ": ") + what);
    }

private:
    H5Object open_attribute(hid_t where, const char* owner, const char* name) const {
        if (H5Aexists(where, name) <= 0) fail(owner, std::string("attribute ") + name + " missing");
        H5Object attr(H5Aopen(where, name, H5P_DEFAULT), H5Aclose);
        if (!attr.valid()) fail(owner, std::string("attribute ") + name + " cannot be opened");
        return attr;
    }

    template <class T> void check_type(const char* name, hid_t type) const {
        const auto type_class = H5Tget_class(type);
        const std::size_t size = H5Tget_size(type);
        bool ok = size == sizeof(T);
        if constexpr (std::is_floating_point_v<T>) ok = ok && type_class == H5T_FLOAT;
        else ok = ok && type_class == H5T_INTEGER && (H5Tget_sign(type) == H5T_SGN_NONE) == std::is_unsigned_v<T>;
        if (!ok) {
            std::string found = type_class == H5T_FLOAT ? "float" : type_class == H5T_INTEGER ? "integer" : "non-numeric";
            fail(name, std::string("has element type ") + found + std::to_string(8 * size) + ", expected " + H5Type<T>::name);
        }
    }

    std::filesystem::path path_;
    H5Object file_;
};

template <class T, std::size_t K>
std::vector<std::array<T, K>> rows_of(const std::vector<T>& flat) {
    std::vector<std::array<T, K>> rows(flat.size() / K);
    std::memcpy(rows.data(), flat.data(), flat.size() * sizeof(T));
    return rows;
}

template <class T>
void require_finite(const Reader& r, const char* name, const std::vector<T>& values) {
    for (std::size_t n = 0; n < values.size(); ++n)
        if (!std::isfinite(values[n])) r.fail(name, "value " + std::to_string(n) + " is not finite");
}

void require_indices(const Reader& r, const char* name, const std::vector<std::int32_t>& values, std::size_t limit) {
    for (std::size_t n = 0; n < values.size(); ++n)
        if (values[n] < 0 || std::size_t(values[n]) >= limit)
            r.fail(name, "entry " + std::to_string(n) + " is " + std::to_string(values[n]) + ", outside [0, " +
                             std::to_string(limit) + ")");
}

/// /packing, /simsurface and /mapping, each optional, validated against the particles.
void read_packing_and_mapping(const Reader& r, Scenario& s) {
    const std::size_t n = s.lattice.particles.size();
    if (r.exists("packing")) {
        Packing p;
        auto flat = r.dataset<std::int32_t>("packing/neighbours", long(n), 18);
        p.neighbours = rows_of<std::int32_t, 18>(flat);
        for (std::size_t i = 0; i < n; ++i)
            for (int slot = 0; slot < 18; ++slot) {
                const std::int32_t j = p.neighbours[i][std::size_t(slot)];
                if (j == -1) continue;
                if (j < 0 || std::size_t(j) >= n)
                    r.fail("packing/neighbours", "row " + std::to_string(i) + " slot " + std::to_string(slot) + " is " +
                                                     std::to_string(j) + ", outside [-1, " + std::to_string(n) + ")");
                if (p.neighbours[std::size_t(j)][std::size_t(opposite_slot(slot))] != std::int32_t(i))
                    r.fail("packing/neighbours", "not symmetric: particle " + std::to_string(i) + " slot " + std::to_string(slot) +
                                                     " holds " + std::to_string(j) + " but " + std::to_string(j) +
                                                     "'s opposite slot does not hold " + std::to_string(i));
            }
        for (std::size_t k = 0; k < s.lattice.springs.size(); ++k) {
            const auto [a, b] = s.lattice.springs.pairs[k];
            const auto& row = p.neighbours[std::size_t(a)];
            if (std::find(row.begin(), row.end(), b) == row.end())
                r.fail("packing/neighbours", "spring " + std::to_string(k) + " (" + std::to_string(a) + ", " + std::to_string(b) +
                                                 ") has no neighbour slot");
        }
        p.texture_coord = rows_of<std::int32_t, 2>(r.dataset<std::int32_t>("packing/texture_coord", long(n), 2));
        H5Object set(H5Dopen2(r.file(), "packing/texture_coord", H5P_DEFAULT), H5Dclose);
        p.width = r.scalar<std::int32_t>(set.get(), "/packing/texture_coord", "width");
        p.height = r.scalar<std::int32_t>(set.get(), "/packing/texture_coord", "height");
        try {
            p.scheme = parse_packing_scheme(r.string_attribute(set.get(), "/packing/texture_coord", "scheme"));
        } catch (const InputError& e) {
            r.fail("/packing/texture_coord", std::string("attribute scheme: ") + e.what());
        }
        if (p.width <= 0 || p.height <= 0) r.fail("/packing/texture_coord", "width and height must be positive");
        std::vector<std::uint8_t> used(std::size_t(p.width) * std::size_t(p.height), 0);
        for (std::size_t i = 0; i < n; ++i) {
            const auto [x, y] = p.texture_coord[i];
            if (x < 0 || y < 0 || x >= p.width || y >= p.height)
                r.fail("packing/texture_coord", "row " + std::to_string(i) + " lies outside the " + std::to_string(p.width) + " x " +
                                                    std::to_string(p.height) + " texture");
            if (used[std::size_t(y) * std::size_t(p.width) + std::size_t(x)]++)
                r.fail("packing/texture_coord", "row " + std::to_string(i) + " shares its texel with another particle");
        }
        s.packing = std::move(p);
    }
    if (r.exists("simsurface")) {
        auto flat = r.dataset<std::int32_t>("simsurface/triangles", -1, 3);
        require_indices(r, "simsurface/triangles", flat, n);
        SimulationSurface surface;
        surface.triangles = rows_of<std::int32_t, 3>(flat);
        if (r.exists("simsurface/normal_weight")) {
            // ➕ One per triangle, 0 or 1. Files written before it existed count every triangle.
            surface.normal_weight = r.dataset<std::uint8_t>("simsurface/normal_weight", long(surface.triangles.size()), 0);
            for (std::size_t t = 0; t < surface.normal_weight.size(); ++t)
                if (surface.normal_weight[t] > 1)
                    r.fail("simsurface/normal_weight", "entry " + std::to_string(t) + " is " +
                                                           std::to_string(int(surface.normal_weight[t])) + ", not 0 or 1");
        } else {
            surface.normal_weight.assign(surface.triangles.size(), 1);
        }
        s.simulation_surface = std::move(surface);
    }
    if (r.exists("mapping")) {
        if (!s.visual) r.fail("mapping", "present without /visual");
        if (!s.simulation_surface) r.fail("mapping", "present without /simsurface");
        const long v = long(s.visual->positions.size());
        VisualMapping m;
        m.triangle = r.dataset<std::int32_t>("mapping/triangle", v, 0);
        require_indices(r, "mapping/triangle", m.triangle, s.simulation_surface->size());
        auto weights = r.dataset<float>("mapping/barycentric", v, 3);
        require_finite(r, "mapping/barycentric", weights);
        m.barycentric = rows_of<float, 3>(weights);
        for (std::size_t i = 0; i < m.barycentric.size(); ++i) {
            const auto& b = m.barycentric[i];
            if (std::abs(double(b[0]) + b[1] + b[2] - 1.0) > 1e-3)
                r.fail("mapping/barycentric", "row " + std::to_string(i) + " does not sum to 1");
        }
        m.offset = r.dataset<float>("mapping/offset", v, 0);
        require_finite(r, "mapping/offset", m.offset);
        // ➕ The carriers (format_version 3). A file without them reads as the triangle's three.
        const bool has_particles = r.exists("mapping/particles"), has_weights = r.exists("mapping/weights");
        if (has_particles != has_weights)
            r.fail(has_particles ? "mapping/weights" : "mapping/particles", "missing (mapping/particles and mapping/weights go together)");
        if (has_particles) {
            auto carriers = r.dataset<std::int32_t>("mapping/particles", v, 8);
            require_indices(r, "mapping/particles", carriers, s.lattice.particles.size());
            m.particles = rows_of<std::int32_t, 8>(carriers);
            auto carried = r.dataset<float>("mapping/weights", v, 8);
            require_finite(r, "mapping/weights", carried);
            m.weights = rows_of<float, 8>(carried);
            for (std::size_t i = 0; i < m.weights.size(); ++i) {
                double sum = 0.0;
                for (float w : m.weights[i]) sum += double(w);
                if (std::abs(sum - 1.0) > 1e-3) r.fail("mapping/weights", "row " + std::to_string(i) + " does not sum to 1");
            }
        }
        s.mapping = std::move(m);
    }
}

Scenario read_contents(const Reader& r) {
    Scenario s;
    const hid_t root = r.file();
    const std::string format = r.string_attribute(root, "/", "format");
    if (format != "heartsim.scenario") r.fail("/", "attribute format is '" + format + "', expected 'heartsim.scenario'");
    const int version = r.scalar<std::int32_t>(root, "/", "format_version");
    if (version < scenario_oldest_format_version || version > scenario_format_version)
        r.fail("/", "format_version " + std::to_string(version) + " is not supported (this build reads versions " +
                        std::to_string(scenario_oldest_format_version) + " to " + std::to_string(scenario_format_version) +
                        "); use a matching heartsim");
    if (r.string_attribute(root, "/", "units") != "mm g ms") r.fail("/", "attribute units must be 'mm g ms'");
    if (r.string_attribute(root, "/", "frame") != "LPS") r.fail("/", "attribute frame must be 'LPS'");
    s.generator = r.string_attribute(root, "/", "generator");
    s.source.sha256 = r.string_attribute(root, "/", "source_sha256");
    if (r.has_attribute(root, "batch_key")) s.batch_key = r.string_attribute(root, "/", "batch_key");

    {
        H5Object g = r.object("source");
        auto& geometry = s.source.geometry;
        s.source.file_name = r.string_attribute(g.get(), "/source", "file_name");
        auto dims = r.numeric_attribute<std::int32_t>(g.get(), "/source", "dims", 3);
        auto spacing = r.numeric_attribute<double>(g.get(), "/source", "spacing", 3);
        for (int a = 0; a < 3; ++a) {
            if (dims[std::size_t(a)] <= 0 || spacing[std::size_t(a)] <= 0) r.fail("/source", "dims and spacing must be positive");
            geometry.dims[std::size_t(a)] = dims[std::size_t(a)];
            geometry.spacing[a] = spacing[std::size_t(a)];
        }
        const Eigen::Matrix4d m = r.matrix(g.get(), "/source", "voxel_to_world");
        geometry.direction = m.topLeftCorner<3, 3>() * geometry.spacing.cwiseInverse().asDiagonal();
        geometry.origin = m.topRightCorner<3, 1>();
        auto labels = [&](const char* name) {
            auto values = r.numeric_attribute<std::int32_t>(g.get(), "/source", name, 0, true);
            return std::vector<int>(values.begin(), values.end());
        };
        s.source.tissue_labels = labels("tissue_labels");
        s.source.cavity_labels = labels("cavity_labels");
        s.source.anchor_labels = labels("anchor_labels");
        s.source.anchor_border = r.scalar<std::int32_t>(g.get(), "/source", "anchor_border") != 0;
    }
    auto& lattice = s.lattice;
    {
        H5Object g = r.object("lattice");
        lattice.spacing = r.scalar<double>(g.get(), "/lattice", "spacing");
        if (!(lattice.spacing > 0)) r.fail("/lattice", "spacing must be positive");
        auto dims = r.numeric_attribute<std::int32_t>(g.get(), "/lattice", "dims", 3);
        for (int a = 0; a < 3; ++a) {
            if (dims[std::size_t(a)] <= 0) r.fail("/lattice", "dims must be positive");
            lattice.dims[std::size_t(a)] = dims[std::size_t(a)];
        }
        lattice.index_to_world = r.matrix(g.get(), "/lattice", "index_to_world");
    }
    {
        std::size_t m = 0;
        auto label = r.dataset<std::int32_t>("materials/label", -1, 0, &m);
        auto name = r.strings("materials/name", m);
        auto density = r.dataset<float>("materials/density", long(m), 0);
        auto stiffness = r.dataset<float>("materials/stiffness", long(m), 0);
        auto damping = r.dataset<float>("materials/damping", long(m), 0);
        if (m == 0) r.fail("materials/label", "no material");
        std::vector<float> youngs;
        if (r.exists("materials/youngs_modulus_kpa")) youngs = r.dataset<float>("materials/youngs_modulus_kpa", long(m), 0);
        for (std::size_t i = 0; i < m; ++i) {
            if (!(density[i] > 0) || !std::isfinite(density[i])) r.fail("materials/density", "must be positive and finite");
            if (!(stiffness[i] > 0) || !std::isfinite(stiffness[i])) r.fail("materials/stiffness", "must be positive and finite");
            if (!(damping[i] >= 0) || !std::isfinite(damping[i])) r.fail("materials/damping", "must be non-negative and finite");
            Material material;
            material.label = label[i];
            material.name = name[i];
            material.density = density[i];
            material.damping_ratio = damping[i];
            // The face-spring stiffness is the contract; Young's modulus follows from k = 0.4·E·h.
            material.youngs_modulus_kpa = youngs.empty() ? stiffness[i] / (0.4e-3 * lattice.spacing) : youngs[i];
            lattice.materials.push_back(material);
        }
    }
    {
        auto& p = lattice.particles;
        std::size_t n = 0;
        auto rest = r.dataset<float>("particles/rest_position", -1, 3, &n);
        require_finite(r, "particles/rest_position", rest);
        p.rest_position = rows_of<float, 3>(rest);
        p.lattice_index = rows_of<std::int32_t, 3>(r.dataset<std::int32_t>("particles/lattice_index", long(n), 3));
        for (std::size_t i = 0; i < n; ++i)
            for (int a = 0; a < 3; ++a)
                if (p.lattice_index[i][std::size_t(a)] < 0 || p.lattice_index[i][std::size_t(a)] >= lattice.dims[std::size_t(a)])
                    r.fail("particles/lattice_index", "row " + std::to_string(i) + " lies outside /lattice dims");
        p.mass = r.dataset<float>("particles/mass", long(n), 0);
        for (std::size_t i = 0; i < n; ++i)
            if (!(p.mass[i] > 0) || !std::isfinite(p.mass[i]))
                r.fail("particles/mass", "entry " + std::to_string(i) + " is not a positive finite mass");
        p.material = r.dataset<std::int32_t>("particles/material", long(n), 0);
        require_indices(r, "particles/material", p.material, lattice.materials.size());
        p.anchored = r.dataset<std::uint8_t>("particles/anchored", long(n), 0);
        for (std::size_t i = 0; i < n; ++i)
            if (p.anchored[i] > 1) r.fail("particles/anchored", "entry " + std::to_string(i) + " is neither 0 nor 1");
        if (n == 0) r.fail("particles/mass", "no particles");
        // Supports (optional: a file without them has none).
        const bool has_stiffness = r.exists("particles/support_stiffness"), has_point = r.exists("particles/support_point");
        if (has_stiffness != has_point)
            r.fail(has_stiffness ? "particles/support_point" : "particles/support_stiffness",
                   "missing: support_stiffness and support_point come together");
        if (has_stiffness) {
            p.support_stiffness = r.dataset<float>("particles/support_stiffness", long(n), 0);
            for (std::size_t i = 0; i < n; ++i)
                if (!(p.support_stiffness[i] >= 0) || !std::isfinite(p.support_stiffness[i]))
                    r.fail("particles/support_stiffness", "entry " + std::to_string(i) + " is not a non-negative finite stiffness (N/mm)");
            auto point = r.dataset<float>("particles/support_point", long(n), 3);
            require_finite(r, "particles/support_point", point);
            p.support_point = rows_of<float, 3>(point);
            p.support_damping.assign(n, 0.0f);  // optional: undamped supports
            if (r.exists("particles/support_damping")) {
                p.support_damping = r.dataset<float>("particles/support_damping", long(n), 0);
                for (std::size_t i = 0; i < n; ++i)
                    if (!(p.support_damping[i] >= 0) || !std::isfinite(p.support_damping[i]))
                        r.fail("particles/support_damping", "entry " + std::to_string(i) + " is not a non-negative finite damping (N·ms/mm)");
            }
        }
    }
    {
        auto& sp = lattice.springs;
        const std::size_t n = lattice.particles.size();
        std::size_t count = 0;
        auto pairs = r.dataset<std::int32_t>("springs/pairs", -1, 2, &count);
        require_indices(r, "springs/pairs", pairs, n);
        sp.pairs = rows_of<std::int32_t, 2>(pairs);
        for (std::size_t i = 0; i < count; ++i)
            if (sp.pairs[i][0] >= sp.pairs[i][1])
                r.fail("springs/pairs", "row " + std::to_string(i) + " is not ordered first < second");
        sp.rest_length = r.dataset<float>("springs/rest_length", long(count), 0);
        sp.stiffness = r.dataset<float>("springs/stiffness", long(count), 0);
        for (std::size_t i = 0; i < count; ++i) {
            if (!(sp.rest_length[i] > 0) || !std::isfinite(sp.rest_length[i]))
                r.fail("springs/rest_length", "entry " + std::to_string(i) + " is not a positive finite length");
            if (!(sp.stiffness[i] >= 0) || !std::isfinite(sp.stiffness[i]))
                r.fail("springs/stiffness", "entry " + std::to_string(i) + " is not a non-negative finite stiffness");
        }
    }
    if (r.exists("visual")) {
        VisualMesh v;
        std::size_t count = 0;
        auto positions = r.dataset<float>("visual/positions", -1, 3, &count);
        require_finite(r, "visual/positions", positions);
        auto normals = r.dataset<float>("visual/normals", long(count), 3);
        require_finite(r, "visual/normals", normals);
        auto triangles = r.dataset<std::int32_t>("visual/triangles", -1, 3);
        require_indices(r, "visual/triangles", triangles, count);
        v.positions = rows_of<float, 3>(positions);
        v.normals = rows_of<float, 3>(normals);
        v.triangles = rows_of<std::int32_t, 3>(triangles);
        s.visual = std::move(v);
    }
    read_packing_and_mapping(r, s);
    {
        H5Object g = r.object("solver");
        auto& solver = s.solver;
        solver.dt_ms = r.scalar<double>(g.get(), "/solver", "dt_ms");
        solver.substeps = r.scalar<std::int32_t>(g.get(), "/solver", "substeps");
        solver.damping = r.scalar<double>(g.get(), "/solver", "damping");
        auto gravity = r.numeric_attribute<double>(g.get(), "/solver", "gravity", 3);
        solver.gravity = Eigen::Vector3d(gravity[0], gravity[1], gravity[2]);
        if (r.has_attribute(g.get(), "balanced_gravity")) {
            auto balanced = r.numeric_attribute<double>(g.get(), "/solver", "balanced_gravity", 3);
            solver.balanced_gravity = Eigen::Vector3d(balanced[0], balanced[1], balanced[2]);
            if (!solver.balanced_gravity.allFinite()) r.fail("/solver", "balanced_gravity must be finite");
        }
        solver.critical_dt_ms = r.scalar<double>(g.get(), "/solver", "critical_dt_ms");
        if (r.has_attribute(g.get(), "critical_dt_bound_ms"))
            solver.critical_dt_bound_ms = r.scalar<double>(g.get(), "/solver", "critical_dt_bound_ms");
        if (r.has_attribute(g.get(), "damped_critical_dt_ms"))
            solver.damped_critical_dt_ms = r.scalar<double>(g.get(), "/solver", "damped_critical_dt_ms");
        if (r.has_attribute(g.get(), "safety_factor")) solver.safety_factor = r.scalar<double>(g.get(), "/solver", "safety_factor");
        if (!(solver.dt_ms > 0)) r.fail("/solver", "dt_ms must be positive");
        if (solver.substeps < 1) r.fail("/solver", "substeps must be at least 1");
        if (!(solver.damping >= 0)) r.fail("/solver", "damping must be non-negative");
        if (!(solver.critical_dt_ms > 0)) r.fail("/solver", "critical_dt_ms must be positive");
    }
    return s;
}


}  // namespace

SolverOptions options_from(const SolverSettings& settings) { return settings; }

VisualMesh to_visual_mesh(const TriangleMesh& mesh) {
    VisualMesh v;
    v.positions.reserve(mesh.positions.size());
    for (const auto& x : mesh.positions) v.positions.push_back({float(x.x()), float(x.y()), float(x.z())});
    v.normals.reserve(mesh.positions.size());
    for (std::size_t i = 0; i < mesh.positions.size(); ++i) {
        const Eigen::Vector3d n = i < mesh.normals.size() ? mesh.normals[i] : Eigen::Vector3d::Zero();
        v.normals.push_back({float(n.x()), float(n.y()), float(n.z())});
    }
    v.triangles = mesh.triangles;
    return v;
}

void write_scenario(const std::filesystem::path& path, const Scenario& scenario) {
    silence_hdf5();
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        Writer writer(path, temporary);
        write_contents(writer, scenario);
        writer.close();
    });
}

Scenario read_scenario(const std::filesystem::path& path) {
    silence_hdf5();
    Reader reader(path);
    return read_contents(reader);
}

namespace {

/// Feeds bytes to SHA-256 through OpenSSL's EVP interface and returns lowercase hex.
class Sha256 {
public:
    Sha256() : context_(EVP_MD_CTX_new(), EVP_MD_CTX_free) { EVP_DigestInit_ex(context_.get(), EVP_sha256(), nullptr); }
    void add(const void* data, std::size_t size) { EVP_DigestUpdate(context_.get(), data, size); }
    std::string hex() {
        unsigned char digest[EVP_MAX_MD_SIZE];
        unsigned int length = 0;
        EVP_DigestFinal_ex(context_.get(), digest, &length);
        static const char* digits = "0123456789abcdef";
        std::string text;
        for (unsigned int i = 0; i < length; ++i) {
            text += digits[digest[i] >> 4];
            text += digits[digest[i] & 15];
        }
        return text;
    }
private:
    std::unique_ptr<EVP_MD_CTX, void (*)(EVP_MD_CTX*)> context_;
};

}  // namespace

std::string sha256_file(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot be read");
    Sha256 hash;
    std::vector<char> buffer(1 << 16);
    while (in) {
        in.read(buffer.data(), std::streamsize(buffer.size()));
        hash.add(buffer.data(), std::size_t(in.gcount()));
    }
    return hash.hex();
}

std::string sha256_text(const std::string& text) {
    Sha256 hash;
    hash.add(text.data(), text.size());
    return hash.hex();
}

}  // namespace heartsim
