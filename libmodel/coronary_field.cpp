#include "libmodel/coronary_field.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace heartsim {

std::vector<CoronaryCourse> coronary_courses(const Landmarks& landmarks) {
    struct Artery {
        const char* landmark;
        double radius_mm;
    };
    // Dodge et al. 1992: mean proximal lumen diameters of normal arteries, halved.
    constexpr Artery arteries[] = {{"lad_course", 1.85}, {"rca_course", 1.95}, {"lcx_course", 1.7}};
    std::vector<CoronaryCourse> courses;
    for (const Artery& artery : arteries) {
        const Landmark* found = landmarks.find(artery.landmark);
        if (!found || found->points.size() < 2) continue;
        // A course's points sit on surface vertices, so it zigzags by a vertex's spacing; the
        // artery follows its mean line: three passes of (1, 2, 1)/4 over the inner points.
        std::vector<Eigen::Vector3d> points = found->points;
        for (int pass = 0; pass < 3; ++pass) {
            const std::vector<Eigen::Vector3d> before = points;
            for (std::size_t k = 1; k + 1 < points.size(); ++k) points[k] = 0.25 * (before[k - 1] + 2.0 * before[k] + before[k + 1]);
        }
        courses.push_back({artery.landmark, std::move(points), artery.radius_mm});
    }
    return courses;
}

namespace {

void check_courses(const std::vector<CoronaryCourse>& courses, double spacing_mm, double reach) {
    if (!(spacing_mm > 0.0) || !std::isfinite(spacing_mm))
        throw InputError("coronary field: the grid spacing must be positive, got " + std::to_string(spacing_mm));
    if (!(reach >= 1.0) || !std::isfinite(reach))
        throw InputError("coronary field: the reach must be at least one radius, got " + std::to_string(reach));
    for (const CoronaryCourse& c : courses) {
        if (!(c.radius_mm > 0.0) || !std::isfinite(c.radius_mm))
            throw InputError("coronary field: course " + c.name + " has radius " + std::to_string(c.radius_mm) +
                             " mm; expected a positive radius");
        for (const Eigen::Vector3d& p : c.points)
            if (!p.allFinite()) throw InputError("coronary field: course " + c.name + " has a non-finite point");
    }
}

/// The point of segment [a, b] nearest to p.
Eigen::Vector3d nearest_on_segment(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double length2 = ab.squaredNorm();
    if (length2 <= 0.0) return a;
    const double t = std::clamp((p - a).dot(ab) / length2, 0.0, 1.0);
    return a + t * ab;
}

/// Lowers the field's nodes within reach of segment [a, b] of a course of radius r.
void stamp_segment(CoronaryField& f, const Eigen::Vector3d& a, const Eigen::Vector3d& b, double r) {
    const double reach_mm = f.reach * r;
    const Eigen::Vector3d lo = a.cwiseMin(b).array() - reach_mm;
    const Eigen::Vector3d hi = a.cwiseMax(b).array() + reach_mm;
    const int n[3] = {f.nx, f.ny, f.nz};
    int first[3], last[3];
    for (int axis = 0; axis < 3; ++axis) {
        first[axis] = std::max(0, static_cast<int>(std::floor((lo[axis] - f.origin[axis]) / f.spacing_mm)));
        last[axis] = std::min(n[axis] - 1, static_cast<int>(std::ceil((hi[axis] - f.origin[axis]) / f.spacing_mm)));
    }
    for (int k = first[2]; k <= last[2]; ++k)
        for (int j = first[1]; j <= last[1]; ++j)
            for (int i = first[0]; i <= last[0]; ++i) {
                const Eigen::Vector3d node = f.origin + f.spacing_mm * Eigen::Vector3d(i, j, k);
                const Eigen::Vector3d offset = node - nearest_on_segment(node, a, b);
                const double d = offset.norm() / r;
                const std::size_t at = f.index(i, j, k);
                if (d >= f.distance[at]) continue;
                f.distance[at] = static_cast<float>(d);
                f.away[at] = d > 0.0 ? Eigen::Vector3f((offset / offset.norm()).cast<float>()) : Eigen::Vector3f::Zero();
            }
}

}  // namespace

CoronaryField coronary_field(const std::vector<CoronaryCourse>& courses, double spacing_mm, double reach,
                             std::size_t max_nodes) {
    check_courses(courses, spacing_mm, reach);
    CoronaryField f;
    f.reach = reach;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    double widest = 0.0;
    for (const CoronaryCourse& c : courses) {
        widest = std::max(widest, c.radius_mm);
        for (const Eigen::Vector3d& p : c.points) {
            lo = lo.cwiseMin(p);
            hi = hi.cwiseMax(p);
        }
    }
    if (widest == 0.0 || !lo.allFinite()) return f;
    f.spacing_mm = spacing_mm;
    const double margin = reach * widest;
    for (;;) {
        const Eigen::Vector3d extent = (hi - lo).array() + 2.0 * margin;
        f.nx = static_cast<int>(std::ceil(extent.x() / f.spacing_mm)) + 2;
        f.ny = static_cast<int>(std::ceil(extent.y() / f.spacing_mm)) + 2;
        f.nz = static_cast<int>(std::ceil(extent.z() / f.spacing_mm)) + 2;
        if (static_cast<std::size_t>(f.nx) * f.ny * f.nz <= max_nodes) break;
        f.spacing_mm *= 1.25;
    }
    f.origin = lo.array() - margin - f.spacing_mm;
    const std::size_t nodes = static_cast<std::size_t>(f.nx) * f.ny * f.nz;
    f.distance.assign(nodes, static_cast<float>(reach));
    f.away.assign(nodes, Eigen::Vector3f::Zero());
    for (const CoronaryCourse& c : courses)
        for (std::size_t s = 0; s + 1 < c.points.size(); ++s) stamp_segment(f, c.points[s], c.points[s + 1], c.radius_mm);
    return f;
}

}  // namespace heartsim
