#include "libmodel/phantom.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"

#include <tbb/parallel_for.h>

#include <cmath>
#include <cstdio>

namespace heartsim {

PhantomShape parse_phantom_shape(const std::string& name) {
    if (name == "heart") return PhantomShape::heart;
    if (name == "sphere") return PhantomShape::sphere;
    if (name == "shell") return PhantomShape::shell;
    throw InputError("unknown phantom shape '" + name + "' (expected heart, sphere or shell)");
}

namespace {

void require_positive(double value, const char* option) {
    if (!(value > 0.0) || !std::isfinite(value))
        throw InputError(std::string(option) + " must be a positive number, got " + std::to_string(value));
}

/// Inside the axis-aligned ellipsoid with centre c and semi-axes s.
bool in_ellipsoid(const Eigen::Vector3d& x, const Eigen::Vector3d& c, const Eigen::Vector3d& s) {
    return (x - c).cwiseQuotient(s).squaredNorm() <= 1.0;
}

/// Fills a grid covering [low, high] (mm) plus margin with label(x) at voxel centres.
/// With `cut_at_top`, no margin above `high.z()`: the shape is cut by the volume's top face, as a
/// crop cuts the great vessels of a real scan.
template <class LabelAt>
LabelVolume sample(const PhantomOptions& o, Eigen::Vector3d low, Eigen::Vector3d high, LabelAt label_at,
                   bool cut_at_top = false) {
    low.array() -= o.margin_mm;
    high.array() += o.margin_mm;
    if (cut_at_top) high.z() -= o.margin_mm;
    const Eigen::Vector3d extent = high - low;
    const double voxel = o.size > 0 ? extent.maxCoeff() / o.size : o.voxel_mm;
    // A label map's voxels must be ones a reader accepts (written, the file would be refused, or
    // an infinite one would not be written at all).
    if (!plausible::voxel_spacing_mm.contains(voxel))
        throw InputError(plausible::outside("the voxel size", voxel, plausible::voxel_spacing_mm) +
                         (o.size > 0 ? ": the shape's extent divided by {PhantomOptions::size}; shrink the shape or change {PhantomOptions::size}" : ": change {PhantomOptions::voxel_mm}"));
    LabelVolume volume;
    auto& g = volume.geometry;
    // Counted in double first: a radius of 1e12 mm would overflow int and wrap to one voxel.
    Eigen::Vector3d counts;
    for (int a = 0; a < 3; ++a) counts[a] = std::max(1.0, std::ceil(extent[a] / voxel - 1e-9));
    const double voxels = counts.prod();
    if (!(voxels <= 2.0e9)) {
        char count[32];
        std::snprintf(count, sizeof count, "%.3g", voxels);
        throw InputError(std::string("phantom of ") + count + " voxels is too large (at most 2e9): " +
                         (o.size > 0 ? "lower {PhantomOptions::size}" : "raise {PhantomOptions::voxel_mm} or shrink the shape"));
    }
    for (int a = 0; a < 3; ++a) g.dims[std::size_t(a)] = int(counts[a]);
    g.spacing = Eigen::Vector3d::Constant(voxel);
    // Centre the grid on the box so the shape sits symmetrically; a cut top face stays at high.z.
    const Eigen::Vector3d covered(g.dims[0] * voxel, g.dims[1] * voxel, g.dims[2] * voxel);
    g.origin = 0.5 * (low + high) - 0.5 * covered + Eigen::Vector3d::Constant(0.5 * voxel);
    if (cut_at_top) g.origin.z() = high.z() - covered.z() + 0.5 * voxel;
    volume.labels.assign(g.voxel_count(), 0);
    tbb::parallel_for(0, g.dims[2], [&](int k) {
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i)
                volume.labels[g.linear(i, j, k)] = label_at(g.to_world(Eigen::Vector3d(i, j, k)));
    });
    return volume;
}

LabelVolume make_heart(const PhantomOptions& o) {
    require_positive(o.lv_radius_mm, "{PhantomOptions::lv_radius_mm}");
    require_positive(o.lv_length_mm, "{PhantomOptions::lv_length_mm}");
    require_positive(o.wall_mm, "{PhantomOptions::wall_mm}");
    require_positive(o.rv_wall_mm, "{PhantomOptions::rv_wall_mm}");
    if (!(o.vsd_diameter_mm >= 0.0) || !std::isfinite(o.vsd_diameter_mm))
        throw InputError("{PhantomOptions::vsd_diameter_mm} must be 0 (no defect) or a positive number of mm");
    if (!(o.vsd_position >= 0.0 && o.vsd_position <= 1.0))
        throw InputError("{PhantomOptions::vsd_position} must be in [0, 1] (0 apex, 1 base), got " + std::to_string(o.vsd_position));

    const double r = o.lv_radius_mm, length = o.lv_length_mm, w = o.wall_mm;
    // LV centred at the origin; the base plane cuts both ventricles open at 60% of the long
    // semi-axis above the equator, as the valve planes open a real heart. The base lies on the
    // volume's top face, so anchoring the border (SelectionOptions::anchor_border) anchors it as it anchors cut vessels in a crop.
    const Eigen::Vector3d lv_centre(0, 0, 0);
    const Eigen::Vector3d lv_cavity(r, r, length);
    const Eigen::Vector3d lv_outer = lv_cavity + Eigen::Vector3d::Constant(w);
    const double base_z = 0.6 * length;
    // RV cavity: on the patient's right (−x in LPS) and slightly anterior (−y), shorter than
    // the LV; what of it lies inside the LV's outer wall is septum, not RV, giving a crescent.
    const Eigen::Vector3d rv_centre(-(r + 0.5 * w), -0.2 * r, 0.15 * length);
    const Eigen::Vector3d rv_cavity(0.9 * r, 1.6 * r, 0.85 * length);
    const Eigen::Vector3d rv_outer = rv_cavity + Eigen::Vector3d::Constant(o.rv_wall_mm);

    // VSD: a cylinder along x through the septum at the requested height.
    const double apex_z = -length;
    const double vsd_z = apex_z + o.vsd_position * (base_z - apex_z);
    const double vsd_radius = 0.5 * o.vsd_diameter_mm;
    const double vsd_y = 0.5 * rv_centre.y();
    if (o.vsd_diameter_mm > 0) {
        const double rv_apex_z = rv_centre.z() - rv_cavity.z();
        if (vsd_z - vsd_radius < rv_apex_z || vsd_z + vsd_radius > base_z)
            throw InputError("the VSD ({PhantomOptions::vsd_diameter_mm} " + std::to_string(o.vsd_diameter_mm) + " mm at {PhantomOptions::vsd_position} " +
                             std::to_string(o.vsd_position) + ") does not fit in the septum between the RV apex and the base");
    }

    Eigen::Vector3d low = (lv_centre - lv_outer).cwiseMin(rv_centre - rv_outer);
    Eigen::Vector3d high = (lv_centre + lv_outer).cwiseMax(rv_centre + rv_outer);
    high.z() = base_z;
    return sample(o, low, high, [&](const Eigen::Vector3d& x) -> std::int32_t {
        if (x.z() > base_z) return 0;
        const bool in_lv_cavity = in_ellipsoid(x, lv_centre, lv_cavity);
        const bool in_lv_outer = in_ellipsoid(x, lv_centre, lv_outer);
        const bool in_rv_cavity = in_ellipsoid(x, rv_centre, rv_cavity) && !in_lv_outer;
        const bool in_rv_outer = in_ellipsoid(x, rv_centre, rv_outer);
        if (in_lv_cavity || in_rv_cavity) return 2;
        if (!in_lv_outer && !in_rv_outer) return 0;
        const bool in_defect = vsd_radius > 0 && x.x() < 0 && in_ellipsoid(x, rv_centre, rv_cavity) &&
                               std::hypot(x.y() - vsd_y, x.z() - vsd_z) <= vsd_radius;
        return in_defect ? 2 : 1;
    }, /*cut_at_top=*/true);
}

}  // namespace

LabelVolume make_phantom(const PhantomOptions& o) {
    if (o.size < 0) throw InputError("{PhantomOptions::size} must be positive");
    if (o.size == 0) require_positive(o.voxel_mm, "{PhantomOptions::voxel_mm}");
    if (!(o.margin_mm >= 0.0)) throw InputError("{PhantomOptions::margin_mm} must be non-negative");
    switch (o.shape) {
    case PhantomShape::heart:
        return make_heart(o);
    case PhantomShape::sphere: {
        require_positive(o.radius_mm, "{PhantomOptions::radius_mm}");
        const Eigen::Vector3d extent = Eigen::Vector3d::Constant(o.radius_mm);
        return sample(o, -extent, extent, [&](const Eigen::Vector3d& x) { return std::int32_t(x.norm() <= o.radius_mm); });
    }
    case PhantomShape::shell: {
        require_positive(o.radius_mm, "{PhantomOptions::radius_mm}");
        require_positive(o.inner_radius_mm, "{PhantomOptions::inner_radius_mm}");
        if (o.inner_radius_mm >= o.radius_mm) throw InputError("{PhantomOptions::inner_radius_mm} must be smaller than {PhantomOptions::radius_mm}");
        const Eigen::Vector3d extent = Eigen::Vector3d::Constant(o.radius_mm);
        return sample(o, -extent, extent, [&](const Eigen::Vector3d& x) -> std::int32_t {
            const double d = x.norm();
            return d <= o.inner_radius_mm ? 2 : (d <= o.radius_mm ? 1 : 0);
        });
    }
    }
    throw InputError("unknown phantom shape");
}

}  // namespace heartsim
