// The scenario file through HDF5's C API. Every name, shape and type here is the contract of
// shared/SCENARIO.md; additions are documented in docs/scenario-format.md.
#include "scenario.h"
#include "volume_io.h"

#include "hdf5_io.h"
#include "scenario_checks.h"
#include "scenario_landmarks.h"
#include "scenario_surfaces.h"
#include "xdmf.h"
#include "volume_header_checks.h"

#include "libmodel/plausible.h"
#include "libmodel/stability.h"
#include "libmodel/text.h"

#include "libmodel/errors.h"

#include <openssl/evp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <fstream>
#include <functional>
#include <sstream>
#include <unordered_map>

namespace heartsim {

namespace {

void write_matrix(h5::Writer& w, const std::string& object, const char* name, const Eigen::Matrix4d& m) {
    double rows[16];
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) rows[4 * r + c] = m(r, c);
    w.attribute(object, name, rows, {4, 4});
}

void write_labels(h5::Writer& w, const std::string& object, const char* name, const std::vector<int>& labels) {
    const std::vector<std::int32_t> values(labels.begin(), labels.end());
    w.attribute(object, name, values.data(), {values.size()});
}

/// /materials/origin, wall_thickness_mm, grown_from, tissue_volume_mm3: one row per material.
void write_tissue_origin(h5::Writer& w, const Scenario& s) {
    const std::size_t m = s.lattice.materials.size();
    if (s.tissue_origin.size() != m)
        throw InputError("scenario: " + std::to_string(s.tissue_origin.size()) + " tissue origins for " + std::to_string(m) + " materials");
    std::vector<std::string> origin;
    std::vector<float> thickness, volume;
    std::vector<std::int32_t> from;
    for (const TissueOrigin& o : s.tissue_origin) {
        origin.push_back(o.grown ? "grown" : "labelled");
        thickness.push_back(o.grown ? float(o.thickness_mm) : 0.0f);
        from.push_back(o.grown_from);
        volume.push_back(float(o.volume_mm3));
    }
    w.strings("materials/origin", origin);
    w.dataset("materials/wall_thickness_mm", thickness, {m});
    w.dataset("materials/grown_from", from, {m});
    w.dataset("materials/tissue_volume_mm3", volume, {m});
}

void write_contents(h5::Writer& w, const Scenario& s) {
    w.header("heartsim.scenario", scenario_format_version, "mm g ms");
    w.attribute("/", "generator", s.generator);
    w.attribute("/", "source_sha256", s.source.sha256);
    if (!s.batch_key.empty()) w.attribute("/", "batch_key", s.batch_key);
    if (s.build_warnings) w.strings("build_warnings", *s.build_warnings);

    {
        const std::string g = "source";
        w.group(g);
        const auto& geometry = s.source.geometry;
        w.attribute(g, "file_name", s.source.file_name);
        const std::int32_t dims[3] = {geometry.dims[0], geometry.dims[1], geometry.dims[2]};
        w.attribute(g, "dims", dims, {3});
        w.attribute(g, "spacing", geometry.spacing.data(), {3});
        write_matrix(w, g, "voxel_to_world", geometry.voxel_to_world());
        write_labels(w, g, "tissue_labels", s.source.tissue_labels);
        write_labels(w, g, "cavity_labels", s.source.cavity_labels);
        write_labels(w, g, "anchor_labels", s.source.anchor_labels);
        w.attribute(g, "anchor_border", std::int32_t(s.source.anchor_border));
        if (s.source.tissue_volume_mm3 > 0) w.attribute(g, "tissue_volume_mm3", s.source.tissue_volume_mm3);
        if (!s.source.defect.empty()) {
            w.attribute(g, "defect", s.source.defect);
            w.attribute(g, "defect_centre", s.source.defect_centre.data(), {3});
            w.attribute(g, "defect_axis", s.source.defect_axis.data(), {3});
            w.attribute(g, "defect_diameter_mm", s.source.defect_diameter_mm);
        }
    }
    const auto& lattice = s.lattice;
    {
        const std::string g = "lattice";
        w.group(g);
        w.attribute(g, "spacing", lattice.spacing);
        const std::int32_t dims[3] = {lattice.dims[0], lattice.dims[1], lattice.dims[2]};
        w.attribute(g, "dims", dims, {3});
        write_matrix(w, g, "index_to_world", lattice.index_to_world);
    }
    {
        const std::string g = "materials";
        w.group(g);
        std::vector<std::int32_t> label;
        std::vector<std::string> name;
        std::vector<float> density, stiffness, damping, youngs, poisson;
        bool volume_term = false;
        for (const auto& m : lattice.materials) {
            label.push_back(m.label);
            name.push_back(m.name);
            density.push_back(float(m.density));
            stiffness.push_back(float(spring_stiffness(m.youngs_modulus_kpa, lattice.spacing, m.poisson_ratio)));
            damping.push_back(float(m.damping_ratio));
            youngs.push_back(float(m.youngs_modulus_kpa));
            poisson.push_back(float(m.poisson_ratio));
            volume_term = volume_term || m.poisson_ratio != 0.25;
        }
        const std::size_t m = lattice.materials.size();
        w.dataset(g + "/label", label, {m});
        w.strings(g + "/name", name);
        w.dataset(g + "/density", density, {m});
        w.dataset(g + "/stiffness", stiffness, {m});
        w.dataset(g + "/damping", damping, {m});
        w.dataset(g + "/youngs_modulus_kpa", youngs, {m});
        // Written where some row has a volume term: a file of springs alone reads as it always did.
        if (volume_term) w.dataset(g + "/poisson_ratio", poisson, {m});
        if (!s.tissue_origin.empty()) write_tissue_origin(w, s);
    }
    {
        const std::string g = "particles";
        w.group(g);
        const auto& p = lattice.particles;
        const std::size_t n = p.size();
        w.dataset(g + "/rest_position", p.rest_position, {n, 3});
        w.dataset(g + "/lattice_index", p.lattice_index, {n, 3});
        w.dataset(g + "/mass", p.mass, {n});
        w.dataset(g + "/material", p.material, {n});
        w.dataset(g + "/anchored", p.anchored, {n});
        if (p.supported()) {
            if (p.support_stiffness.size() != n || p.support_point.size() != n)
                throw InputError("scenario: the support arrays differ in length from the particles");
            w.dataset(g + "/support_stiffness", p.support_stiffness, {n});
            w.dataset(g + "/support_point", p.support_point, {n, 3});
            if (p.support_damping.size() != n) throw InputError("scenario: the support damping array differs in length from the particles");
            w.dataset(g + "/support_damping", p.support_damping, {n});
        }
    }
    {
        const std::string g = "springs";
        w.group(g);
        const auto& sp = lattice.springs;
        w.dataset(g + "/pairs", sp.pairs, {sp.size(), 2});
        w.dataset(g + "/rest_length", sp.rest_length, {sp.size()});
        w.dataset(g + "/stiffness", sp.stiffness, {sp.size()});
    }
    write_surfaces(w, s);
    {
        const std::string g = "solver";
        w.group(g);
        w.attribute(g, "dt_ms", s.solver.dt_ms);
        w.attribute(g, "substeps", std::int32_t(s.solver.substeps));
        w.attribute(g, "damping", s.solver.damping);
        w.attribute(g, "gravity", s.solver.gravity.data(), {3});
        w.attribute(g, "balanced_gravity", s.solver.balanced_gravity.data(), {3});
        w.attribute(g, "critical_dt_ms", s.solver.critical_dt_ms);
        w.attribute(g, "critical_dt_bound_ms", s.solver.critical_dt_bound_ms);
        if (s.solver.damped_critical_dt_ms > 0) w.attribute(g, "damped_critical_dt_ms", s.solver.damped_critical_dt_ms);
        w.attribute(g, "safety_factor", s.solver.safety_factor);
    }
}

// ---------------------------------------------------------------------------------------------
// Reading

Eigen::Matrix4d read_matrix(const h5::Reader& r, const std::string& object, const char* name) {
    const auto values = r.numbers<double>(object, name, 16);
    Eigen::Matrix4d m;
    for (int row = 0; row < 4; ++row)
        for (int c = 0; c < 4; ++c) m(row, c) = values[std::size_t(4 * row + c)];
    return m;
}

/// The step policy's cross-field rules (docs/scenario-format.md "/solver"): the stored critical
/// and damped steps within their proven ceilings for these springs, masses and dampers, the
/// damped step within the undamped one, the safety factor in heartprep's range. (dt_ms needs no
/// rule: the solver splits it into substeps of at most safety_factor × the damped step.)
void check_time_steps(const h5::Reader& r, const Scenario& s) {
    const auto& solver = s.solver;
    const auto& lattice = s.lattice;
    auto ms = [](double value) { return std::to_string(value) + " ms"; };
    if (!(solver.safety_factor >= min_safety_factor && solver.safety_factor <= max_safety_factor))
        r.fail("/solver", "safety_factor is " + std::to_string(solver.safety_factor) + ": it must lie in [" +
                              std::to_string(min_safety_factor) + ", " + std::to_string(max_safety_factor) +
                              "] (a fraction of the stable step)");
    const double ceiling = critical_step_ceiling_ms(lattice.particles, lattice.springs);
    if (!std::isfinite(solver.critical_dt_ms) || solver.critical_dt_ms > ceiling * (1.0 + 1e-6))
        r.fail("/solver", "critical_dt_ms is " + ms(solver.critical_dt_ms) + ", above the proven ceiling of " + ms(ceiling) +
                              " for these springs and masses: the file is damaged or not from heartprep (rebuild it)");
    if (solver.damped_critical_dt_ms != 0) {
        const double damped = solver.damped_critical_dt_ms;
        if (!(damped > 0) || !std::isfinite(damped)) r.fail("/solver", "damped_critical_dt_ms must be positive and finite");
        if (damped > solver.critical_dt_ms * (1.0 + 1e-12))
            r.fail("/solver", "damped_critical_dt_ms " + ms(damped) + " exceeds critical_dt_ms " + ms(solver.critical_dt_ms) +
                                  ": damping never lengthens the stable step");
        const double damped_ceiling = damped_step_ceiling_ms(lattice.particles, lattice.springs, damping_ratios(lattice.materials), solver.damping);
        if (damped > damped_ceiling * (1.0 + 1e-6))
            r.fail("/solver", "damped_critical_dt_ms is " + ms(damped) + ", above the proven ceiling of " + ms(damped_ceiling) +
                                  " for these springs, masses and dampers: the damping changed without the step recomputed (rebuild it)");
    }
}

/// /source: the input volume's name, grid and labels, and a carved defect.
void read_source(const h5::Reader& r, Scenario& s) {
    auto& geometry = s.source.geometry;
    s.source.file_name = r.string_attribute("source", "file_name");
    auto dims = r.numbers<std::int32_t>("source", "dims", 3);
    auto spacing = r.numbers<double>("source", "spacing", 3);
    for (int a = 0; a < 3; ++a) {
        if (dims[std::size_t(a)] <= 0 || spacing[std::size_t(a)] <= 0) r.fail("/source", "dims and spacing must be positive");
        if (dims[std::size_t(a)] > plausible::max_voxels_per_axis)
            r.fail("/source", "dims " + std::to_string(dims[0]) + " x " + std::to_string(dims[1]) + " x " + std::to_string(dims[2]) +
                                  ": at most " + std::to_string(plausible::max_voxels_per_axis) + " voxels along an axis");
        if (!plausible::voxel_spacing_mm.contains(spacing[std::size_t(a)]))
            r.fail("/source", plausible::outside("spacing", spacing[std::size_t(a)], plausible::voxel_spacing_mm));
        geometry.dims[std::size_t(a)] = dims[std::size_t(a)];
        geometry.spacing[a] = spacing[std::size_t(a)];
    }
    const Eigen::Matrix4d m = read_matrix(r, "source", "voxel_to_world");
    geometry.direction = m.topLeftCorner<3, 3>() * geometry.spacing.cwiseInverse().asDiagonal();
    geometry.origin = m.topRightCorner<3, 1>();
    auto labels = [&](const char* name) {
        auto values = r.numbers<std::int32_t>("source", name, -1);
        return std::vector<int>(values.begin(), values.end());
    };
    s.source.tissue_labels = labels("tissue_labels");
    s.source.cavity_labels = labels("cavity_labels");
    s.source.anchor_labels = labels("anchor_labels");
    s.source.anchor_border = r.number<std::int32_t>("source", "anchor_border") != 0;
    if (r.has_attribute("source", "tissue_volume_mm3")) {
        s.source.tissue_volume_mm3 = r.number<double>("source", "tissue_volume_mm3");
        if (!(s.source.tissue_volume_mm3 > 0.0) || !std::isfinite(s.source.tissue_volume_mm3))
            r.fail("/source", "tissue_volume_mm3 must be a positive number");
    }
    if (r.has_attribute("source", "defect")) {
        s.source.defect = r.string_attribute("source", "defect");
        if (s.source.defect != "vsd" && s.source.defect != "asd")
            r.fail("/source", "defect must be vsd or asd, got '" + s.source.defect + "'");
        auto vector = [&](const char* name) {
            const auto v = r.numbers<double>("source", name, 3);
            const Eigen::Vector3d out(v[0], v[1], v[2]);
            if (!out.allFinite()) r.fail("/source", std::string(name) + " must be finite");
            return out;
        };
        s.source.defect_centre = vector("defect_centre");
        s.source.defect_axis = vector("defect_axis");
        if (!(std::abs(s.source.defect_axis.norm() - 1.0) < 1e-3)) r.fail("/source", "defect_axis must be a unit vector");
        s.source.defect_diameter_mm = r.number<double>("source", "defect_diameter_mm");
        if (!plausible::defect_diameter_mm.contains(s.source.defect_diameter_mm))
            r.fail("/source", plausible::outside("defect_diameter_mm", s.source.defect_diameter_mm, plausible::defect_diameter_mm) +
                                  " (heartprep carves no other)");
        // The opening was carved into this label map: its centre lies in the map's box.
        const Eigen::Vector3d ijk =
            (geometry.direction.inverse() * (s.source.defect_centre - geometry.origin)).cwiseQuotient(geometry.spacing);
        for (int a = 0; a < 3; ++a)
            if (!(ijk[a] >= -0.5 && ijk[a] <= double(geometry.dims[std::size_t(a)]) - 0.5)) {
                std::ostringstream text;
                text << "defect_centre " << s.source.defect_centre.x() << ", " << s.source.defect_centre.y() << ", "
                     << s.source.defect_centre.z() << " mm lies outside the label map it was carved into (voxel index "
                     << ijk[a] << " along axis " << a << ", of 0 to " << geometry.dims[std::size_t(a)] - 1 << ")";
                r.fail("/source", text.str());
            }
    }
}

/// /lattice: spacing, dims within the source volume's extent, and a non-degenerate index-to-world map.
void read_lattice(const h5::Reader& r, const ScenarioSource& source, Lattice& lattice) {
    lattice.spacing = r.number<double>("lattice", "spacing");
    if (!(lattice.spacing > 0)) r.fail("/lattice", "spacing must be positive");
    if (!plausible::lattice_spacing_mm.contains(lattice.spacing))
        r.fail("/lattice", plausible::outside("spacing", lattice.spacing, plausible::lattice_spacing_mm));
    auto dims = r.numbers<std::int32_t>("lattice", "dims", 3);
    for (int a = 0; a < 3; ++a) {
        if (dims[std::size_t(a)] <= 0) r.fail("/lattice", "dims must be positive");
        lattice.dims[std::size_t(a)] = dims[std::size_t(a)];
    }
    // heartprep's lattice covers the source volume: ceil(voxels × voxel size / spacing) cells
    // per axis (lattice.cpp axis_weights). One more is allowed for the rounding of the stored
    // values; a larger count is damage, and readers that size a grid by it would ask for
    // gigabytes (a 2e9 read as "out of memory").
    for (int a = 0; a < 3; ++a) {
        const double extent = double(source.geometry.dims[std::size_t(a)]) * source.geometry.spacing[a];
        const double most = std::ceil(extent / lattice.spacing) + 1;
        if (double(lattice.dims[std::size_t(a)]) > most)
            r.fail("/lattice", "dims " + std::to_string(lattice.dims[0]) + " x " + std::to_string(lattice.dims[1]) + " x " +
                                   std::to_string(lattice.dims[2]) + ": at most " + std::to_string(std::llround(most)) + " cells of " +
                                   std::to_string(lattice.spacing) + " mm fit the " + std::to_string(extent) +
                                   " mm of the source volume along axis " + std::to_string(a));
    }
    lattice.index_to_world = read_matrix(r, "lattice", "index_to_world");
    // An affine map whose three axes are the lattice spacing long (a rotation times the spacing).
    const Eigen::Matrix4d& m = lattice.index_to_world;
    if (!m.allFinite() || m.row(3) != Eigen::RowVector4d(0, 0, 0, 1))
        r.fail("/lattice", "index_to_world must be a finite affine matrix (last row 0 0 0 1)");
    for (int a = 0; a < 3; ++a) {
        const double length = m.block<3, 1>(0, a).norm();
        if (!(std::abs(length - lattice.spacing) <= 1e-3 * lattice.spacing))
            r.fail("/lattice", "index_to_world axis " + std::to_string(a) + " is " + std::to_string(length) +
                                   " mm long, not the lattice spacing of " + std::to_string(lattice.spacing) + " mm");
    }
    if (!(std::abs(m.topLeftCorner<3, 3>().determinant()) > 0.5 * std::pow(lattice.spacing, 3)))
        r.fail("/lattice", "index_to_world is degenerate: its axes do not span 3D space");
}

/// /materials: the table the particles refer to.
void read_materials(const h5::Reader& r, Lattice& lattice) {
    std::size_t m = 0;
    auto label = r.dataset<std::int32_t>("materials/label", {-1}, &m);
    auto name = r.strings("materials/name", long(m));
    auto density = r.dataset<float>("materials/density", {long(m)});
    auto stiffness = r.dataset<float>("materials/stiffness", {long(m)});
    auto damping = r.dataset<float>("materials/damping", {long(m)});
    if (m == 0) r.fail("materials/label", "no material");
    std::vector<float> youngs;
    if (r.exists("materials/youngs_modulus_kpa")) {
        youngs = r.dataset<float>("materials/youngs_modulus_kpa", {long(m)});
        for (std::size_t i = 0; i < m; ++i)  // informative (the stiffness is the contract), but printed by inspect
            if (!(youngs[i] > 0) || !std::isfinite(youngs[i])) r.fail("materials/youngs_modulus_kpa", "must be positive and finite");
    }
    // Poisson's ratio: a volume term on the lattice's cells adds to the springs' 1/4 (volume_cells.h).
    // A file without it (every file of springs alone) reads as 1/4.
    std::vector<float> poisson(m, 0.25f);
    if (r.exists("materials/poisson_ratio")) {
        poisson = r.dataset<float>("materials/poisson_ratio", {long(m)});
        for (std::size_t i = 0; i < m; ++i)
            if (!(poisson[i] >= 0.25f && poisson[i] <= 0.499f))
                r.fail("materials/poisson_ratio", "row " + std::to_string(i) + " is " + std::to_string(poisson[i]) +
                                                      ": expected 0.25 (the springs alone) to 0.499");
    }
    for (std::size_t i = 0; i < m; ++i) {
        if (!(density[i] > 0) || !std::isfinite(density[i])) r.fail("materials/density", "must be positive and finite");
        if (!(stiffness[i] > 0) || !std::isfinite(stiffness[i])) r.fail("materials/stiffness", "must be positive and finite");
        if (!(damping[i] >= 0) || !std::isfinite(damping[i])) r.fail("materials/damping", "must be non-negative and finite");
        Material material;
        material.label = label[i];
        material.name = name[i];
        material.density = density[i];
        material.damping_ratio = damping[i];
        material.poisson_ratio = poisson[i];
        // The face-spring stiffness is the contract; Young's modulus follows from k = E·h/(2(1 + ν)).
        material.youngs_modulus_kpa = !youngs.empty()           ? youngs[i]
                                      : poisson[i] == 0.25f ? stiffness[i] / (0.4e-3 * lattice.spacing)
                                                            : stiffness[i] / ((0.5 / (1.0 + poisson[i])) * 1e-3 * lattice.spacing);
        lattice.materials.push_back(material);
    }
    require_plausible(r, "materials/density", density, plausible::density_g_per_mm3);
    require_plausible(r, "materials/stiffness", stiffness, plausible::stiffness_n_per_mm);
    require_plausible(r, "materials/damping", damping, plausible::damping_ratio);
}

/// /materials/origin, wall_thickness_mm, grown_from, tissue_volume_mm3: where each material's tissue
/// came from. A file without them (every build of the labels as they are, and every older file)
/// reads as all labelled.
void read_tissue_origin(const h5::Reader& r, Scenario& s) {
    if (!r.exists("materials/origin")) return;
    const long m = long(s.lattice.materials.size());
    const auto origin = r.strings("materials/origin", m);
    const auto thickness = r.dataset<float>("materials/wall_thickness_mm", {m});
    const auto from = r.dataset<std::int32_t>("materials/grown_from", {m});
    const auto volume = r.dataset<float>("materials/tissue_volume_mm3", {m});
    for (std::size_t i = 0; i < std::size_t(m); ++i) {
        TissueOrigin o;
        if (origin[i] != "labelled" && origin[i] != "grown")
            r.fail("materials/origin", "entry " + std::to_string(i) + " is '" + origin[i] + "', expected labelled or grown");
        o.grown = origin[i] == "grown";
        o.thickness_mm = thickness[i];
        if (o.grown && !plausible::wall_thickness_mm.contains(o.thickness_mm))
            r.fail("materials/wall_thickness_mm", "entry " + std::to_string(i) + ": " +
                                                     plausible::outside("a grown wall's thickness", o.thickness_mm, plausible::wall_thickness_mm));
        if (!o.grown && o.thickness_mm != 0.0f)
            r.fail("materials/wall_thickness_mm", "entry " + std::to_string(i) + " is labelled tissue and must be 0");
        o.grown_from = from[i];
        o.volume_mm3 = volume[i];
        if (!(o.volume_mm3 >= 0.0) || !std::isfinite(o.volume_mm3))
            r.fail("materials/tissue_volume_mm3", "entry " + std::to_string(i) + " is not a non-negative finite volume");
        s.tissue_origin.push_back(o);
    }
}

/// /particles: rest positions, lattice indices (one particle per node), masses, materials, anchors
/// and supports.
void read_particles(const h5::Reader& r, Lattice& lattice) {
    auto& p = lattice.particles;
    std::size_t n = 0;
    auto rest = r.dataset<float>("particles/rest_position", {-1, 3}, &n);
    r.require_finite("particles/rest_position", rest);
    require_plausible(r, "particles/rest_position", rest, plausible::coordinate_mm);
    p.rest_position = h5::rows_of<3>(rest);
    p.lattice_index = h5::rows_of<3>(r.dataset<std::int32_t>("particles/lattice_index", {long(n), 3}));
    for (std::size_t i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a)
            if (p.lattice_index[i][std::size_t(a)] < 0 || p.lattice_index[i][std::size_t(a)] >= lattice.dims[std::size_t(a)])
                r.fail("particles/lattice_index", "row " + std::to_string(i) + " lies outside /lattice dims");
    {  // one particle per lattice node
        std::unordered_map<std::uint64_t, std::size_t> owner;
        owner.reserve(n);
        for (std::size_t i = 0; i < n; ++i) {
            const auto& c = p.lattice_index[i];
            const std::uint64_t key = (std::uint64_t(c[2]) * std::uint64_t(lattice.dims[1]) + std::uint64_t(c[1])) *
                                          std::uint64_t(lattice.dims[0]) + std::uint64_t(c[0]);
            if (const auto [at, fresh] = owner.emplace(key, i); !fresh)
                r.fail("particles/lattice_index", "rows " + std::to_string(at->second) + " and " + std::to_string(i) +
                                                      " name the same lattice node (" + std::to_string(c[0]) + ", " +
                                                      std::to_string(c[1]) + ", " + std::to_string(c[2]) + ")");
        }
    }
    p.mass = r.dataset<float>("particles/mass", {long(n)});
    for (std::size_t i = 0; i < n; ++i)
        if (!(p.mass[i] > 0) || !std::isfinite(p.mass[i]))
            r.fail("particles/mass", "entry " + std::to_string(i) + " is not a positive finite mass");
    require_plausible(r, "particles/mass", p.mass, plausible::particle_mass_g);
    p.material = r.dataset<std::int32_t>("particles/material", {long(n)});
    require_indices(r, "particles/material", p.material, lattice.materials.size());
    p.anchored = r.dataset<std::uint8_t>("particles/anchored", {long(n)});
    for (std::size_t i = 0; i < n; ++i)
        if (p.anchored[i] > 1) r.fail("particles/anchored", "entry " + std::to_string(i) + " is neither 0 nor 1");
    if (n == 0) r.fail("particles/mass", "no particles");
    // Supports (optional: a file without them has none).
    const bool has_stiffness = r.exists("particles/support_stiffness"), has_point = r.exists("particles/support_point");
    if (has_stiffness != has_point)
        r.fail(has_stiffness ? "particles/support_point" : "particles/support_stiffness",
               "missing: support_stiffness and support_point come together");
    if (has_stiffness) {
        p.support_stiffness = r.dataset<float>("particles/support_stiffness", {long(n)});
        for (std::size_t i = 0; i < n; ++i)
            if (!(p.support_stiffness[i] >= 0) || !std::isfinite(p.support_stiffness[i]))
                r.fail("particles/support_stiffness", "entry " + std::to_string(i) + " is not a non-negative finite stiffness (N/mm)");
        auto point = r.dataset<float>("particles/support_point", {long(n), 3});
        r.require_finite("particles/support_point", point);
        require_plausible(r, "particles/support_point", point, plausible::coordinate_mm);
        require_plausible(r, "particles/support_stiffness", p.support_stiffness, plausible::stiffness_n_per_mm);
        for (std::size_t i = 0; i < n; ++i)
            if (p.anchored[i] && p.support_stiffness[i] > 0)
                r.fail("particles/support_stiffness", "entry " + std::to_string(i) +
                                                          " supports an anchored particle (a particle is held by one or the other)");
        p.support_point = h5::rows_of<3>(point);
        p.support_damping.assign(n, 0.0f);  // optional: undamped supports
        if (r.exists("particles/support_damping")) {
            p.support_damping = r.dataset<float>("particles/support_damping", {long(n)});
            for (std::size_t i = 0; i < n; ++i)
                if (!(p.support_damping[i] >= 0) || !std::isfinite(p.support_damping[i]))
                    r.fail("particles/support_damping", "entry " + std::to_string(i) + " is not a non-negative finite damping (N·ms/mm)");
            require_plausible(r, "particles/support_damping", p.support_damping, plausible::support_damping_n_ms_per_mm);
        }
    }
}

/// /springs: pairs (each once, ordered), rest lengths and stiffnesses.
void read_springs(const h5::Reader& r, Lattice& lattice) {
    auto& sp = lattice.springs;
    const std::size_t n = lattice.particles.size();
    std::size_t count = 0;
    auto pairs = r.dataset<std::int32_t>("springs/pairs", {-1, 2}, &count);
    require_indices(r, "springs/pairs", pairs, n);
    sp.pairs = h5::rows_of<2>(pairs);
    for (std::size_t i = 0; i < count; ++i)
        if (sp.pairs[i][0] >= sp.pairs[i][1])
            r.fail("springs/pairs", "row " + std::to_string(i) + " is not ordered first < second");
    {  // each pair once: a duplicate would replace the other's slot in /packing
        std::vector<std::pair<std::uint64_t, std::size_t>> keys(count);
        for (std::size_t i = 0; i < count; ++i) keys[i] = {(std::uint64_t(sp.pairs[i][0]) << 32) | std::uint32_t(sp.pairs[i][1]), i};
        std::sort(keys.begin(), keys.end());
        for (std::size_t k = 1; k < count; ++k)
            if (keys[k].first == keys[k - 1].first) {
                const std::size_t a = std::min(keys[k - 1].second, keys[k].second), b = std::max(keys[k - 1].second, keys[k].second);
                r.fail("springs/pairs", "rows " + std::to_string(a) + " and " + std::to_string(b) + " join the same particles (" +
                                            std::to_string(sp.pairs[a][0]) + ", " + std::to_string(sp.pairs[a][1]) + ")");
            }
    }
    sp.rest_length = r.dataset<float>("springs/rest_length", {long(count)});
    sp.stiffness = r.dataset<float>("springs/stiffness", {long(count)});
    for (std::size_t i = 0; i < count; ++i) {
        if (!(sp.rest_length[i] > 0) || !std::isfinite(sp.rest_length[i]))
            r.fail("springs/rest_length", "entry " + std::to_string(i) + " is not a positive finite length");
        if (!(sp.stiffness[i] >= 0) || !std::isfinite(sp.stiffness[i]))
            r.fail("springs/stiffness", "entry " + std::to_string(i) + " is not a non-negative finite stiffness");
    }
    require_plausible(r, "springs/rest_length", sp.rest_length, plausible::rest_length_mm);
    require_plausible(r, "springs/stiffness", sp.stiffness, plausible::stiffness_n_per_mm);
}


/// /solver: the step settings, within their plausible ranges and below the critical step.
void read_solver(const h5::Reader& r, Scenario& s) {
    auto& solver = s.solver;
    solver.dt_ms = r.number<double>("solver", "dt_ms");
    solver.substeps = r.number<std::int32_t>("solver", "substeps");
    solver.damping = r.number<double>("solver", "damping");
    auto gravity = r.numbers<double>("solver", "gravity", 3);
    solver.gravity = Eigen::Vector3d(gravity[0], gravity[1], gravity[2]);
    if (r.has_attribute("solver", "balanced_gravity")) {
        auto balanced = r.numbers<double>("solver", "balanced_gravity", 3);
        solver.balanced_gravity = Eigen::Vector3d(balanced[0], balanced[1], balanced[2]);
        if (!solver.balanced_gravity.allFinite()) r.fail("/solver", "balanced_gravity must be finite");
    }
    solver.critical_dt_ms = r.number<double>("solver", "critical_dt_ms");
    if (r.has_attribute("solver", "critical_dt_bound_ms"))
        solver.critical_dt_bound_ms = r.number<double>("solver", "critical_dt_bound_ms");
    if (r.has_attribute("solver", "damped_critical_dt_ms"))
        solver.damped_critical_dt_ms = r.number<double>("solver", "damped_critical_dt_ms");
    if (r.has_attribute("solver", "safety_factor")) solver.safety_factor = r.number<double>("solver", "safety_factor");
    if (!(solver.dt_ms > 0)) r.fail("/solver", "dt_ms must be positive");
    if (solver.substeps < 1) r.fail("/solver", "substeps must be at least 1");
    if (!(solver.damping >= 0)) r.fail("/solver", "damping must be non-negative");
    if (!(solver.critical_dt_ms > 0)) r.fail("/solver", "critical_dt_ms must be positive");
    using plausible::outside;
    if (!plausible::time_step_ms.contains(solver.dt_ms)) r.fail("/solver", outside("dt_ms", solver.dt_ms, plausible::time_step_ms));
    if (!plausible::drag_per_ms.contains(solver.damping)) r.fail("/solver", outside("damping", solver.damping, plausible::drag_per_ms));
    for (const auto& [name, g] : {std::pair{"|gravity|", solver.gravity.norm()}, std::pair{"|balanced_gravity|", solver.balanced_gravity.norm()}})
        if (!plausible::gravity_mm_per_ms2.contains(g)) r.fail("/solver", outside(name, g, plausible::gravity_mm_per_ms2));
    check_time_steps(r, s);
}

Scenario read_contents(const h5::Reader& r) {
    Scenario s;
    r.header("heartsim.scenario", scenario_oldest_format_version, scenario_format_version, "mm g ms");
    s.generator = r.string_attribute("/", "generator");
    s.source.sha256 = r.string_attribute("/", "source_sha256");
    if (r.has_attribute("/", "batch_key")) s.batch_key = r.string_attribute("/", "batch_key");
    if (r.exists("build_warnings")) s.build_warnings = r.strings("build_warnings", -1);

    read_source(r, s);
    read_lattice(r, s.source, s.lattice);
    read_materials(r, s.lattice);
    read_tissue_origin(r, s);
    read_particles(r, s.lattice);
    read_springs(r, s.lattice);
    read_visual(r, s);
    read_packing_and_mapping(r, s);
    read_solver(r, s);
    return s;
}

}  // namespace

SolverOptions options_from(const SolverSettings& settings) {
    SolverOptions options;
    static_cast<StepSettings&>(options) = settings;
    return options;
}

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

namespace {

void write_scenario_file(const std::filesystem::path& path, const Scenario& scenario,
                         const std::function<void(const std::filesystem::path&)>& check) {
    const std::string xdmf = scenario_xdmf(path.filename().string(), scenario);
    check_xdmf_destination(path);
    h5::write_file(
        path,
        [&](h5::Writer& w) {
            write_contents(w, scenario);
            if (scenario.landmarks) write_landmarks(w, *scenario.landmarks);
        },
        check, {xdmf_file_beside(path, xdmf)});
}

}  // namespace

void write_scenario(const std::filesystem::path& path, const Scenario& scenario) { write_scenario_file(path, scenario, {}); }

void write_readable_scenario(const std::filesystem::path& path, const Scenario& scenario) {
    write_scenario_file(path, scenario, [&](const std::filesystem::path& temporary) {
        try {
            read_scenario(temporary);
        } catch (const InputError& e) {
            // The reader names the temporary file: keep only the dataset and the reason.
            std::string reason = e.what();
            if (const auto at = reason.find(temporary.string()); at != std::string::npos)
                reason.erase(at, temporary.string().size() + (reason.compare(at + temporary.string().size(), 2, ": ") == 0 ? 2 : 0));
            throw InputError("the scenario would not be readable (" + reason + "); nothing was written to " + path.string());
        }
    });
}

Scenario read_scenario(const std::filesystem::path& path) {
    // A label map given where a scenario belongs (`heartsim case.nii.gz`): say what to run first.
    std::error_code error;
    if (label_volume_path_problem(path).empty() && std::filesystem::is_regular_file(path, error) && H5Fis_hdf5(path.c_str()) <= 0)
        throw InputError(path.string() + ": a label map, not a scenario: build one first, `heartprep build " + path.string() +
                         " -o CASE.h5`, then run `heartsim CASE.h5`");
    const h5::Reader reader(path);
    Scenario scenario = read_contents(reader);
    if (reader.exists("landmarks")) scenario.landmarks = read_landmarks(reader, scenario.visual.has_value());
    return scenario;
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

std::string label_map_sha256(const std::filesystem::path& path) {
    // The header parsers of volume_header_checks.h, not ITK: a batch hashes its cases from several
    // threads, and ITK's image IO factories are not for concurrent first use.
    const std::string extension = text::lowercase(path.extension().string());
    std::filesystem::path data;
    if (extension == ".nrrd" || extension == ".nhdr") data = volume_header_checks::nrrd_data_location(path).file;
    else if (extension == ".mhd" || extension == ".mha") data = volume_header_checks::metaimage_data_location(path).file;
    if (data.empty() || data == path) return sha256_file(path);
    return sha256_text(sha256_file(path) + "\n" + sha256_file(data));
}

std::string sha256_text(const std::string& text) {
    Sha256 hash;
    hash.add(text.data(), text.size());
    return hash.hex();
}

}  // namespace heartsim
