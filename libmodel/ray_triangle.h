/// @file ray_triangle.h
/// @brief Where a line or a ray meets a triangle (Möller & Trumbore, "Fast, minimum storage
/// ray-triangle intersection", 1997), in double: the one routine the patch's contact and the
/// repair's stitch lines use.
///
/// **Edge rule.** The triangle is closed: a line through an edge or a corner meets it (the
/// barycentric weights u ≥ 0, v ≥ 0, u + v ≤ 1, as rounded). So a line through an edge two
/// triangles share meets both; a caller that counts crossings drops the repeat (or keeps its lines
/// off edges). A line within |det| < 1e-14 of the triangle's plane (det = e1 · (d × e2), mm² times
/// |d|: parallel or the triangle degenerate) meets nothing.
///
///     if (const auto hit = line_triangle(origin, direction, a, b, c)) point = origin + hit->along * direction;
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>
#include <optional>

namespace heartsim {

/// Where a line meets a triangle.
struct LineTriangleHit {
    double along = 0.0;  ///< the line's parameter there: origin + along · direction (in units of |direction|)
    double u = 0.0;      ///< barycentric weight of corner b (corner a's is 1 − u − v)
    double v = 0.0;      ///< barycentric weight of corner c
    /// e1 · (direction × e2) with e1 = b − a, e2 = c − a: positive where the line, going along
    /// `direction`, passes the triangle from the side its counter-clockwise winding faces
    /// (direction · ((b − a) × (c − a)) < 0: it enters a closed, outward-wound surface there).
    double det = 0.0;
};

/// The line origin + s · direction (any s) against triangle (a, b, c), under the edge rule above;
/// nullopt where it misses. Positions in mm (any frame), `direction` need not be unit.
inline std::optional<LineTriangleHit> line_triangle(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, const Eigen::Vector3d& a,
                                                    const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
    const Eigen::Vector3d e1 = b - a, e2 = c - a, q = direction.cross(e2);
    const double det = e1.dot(q);
    if (std::abs(det) < 1e-14) return std::nullopt;
    const double inverse = 1.0 / det;
    const Eigen::Vector3d t = origin - a;
    const double u = t.dot(q) * inverse;
    if (u < 0.0 || u > 1.0) return std::nullopt;
    const Eigen::Vector3d r = t.cross(e1);
    const double v = direction.dot(r) * inverse;
    if (v < 0.0 || u + v > 1.0) return std::nullopt;
    return LineTriangleHit{e2.dot(r) * inverse, u, v, det};
}

/// The ray origin + s · direction, s ≥ 0, against triangle (a, b, c): s where it meets it, −1 where
/// it misses (line_triangle's edge rule; a hit at the origin itself counts).
inline double ray_triangle(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                           const Eigen::Vector3d& c) {
    const std::optional<LineTriangleHit> hit = line_triangle(origin, direction, a, b, c);
    return hit && hit->along >= 0.0 ? hit->along : -1.0;
}

}  // namespace heartsim
