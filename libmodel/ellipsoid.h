/// @file ellipsoid.h
/// @brief The point of an ellipsoid's surface nearest to a point inside it: where a probe puts a
/// particle it pressed into (solver.cpp `project`; the gl backend's copy is in
/// runtime/gl/shaders/solver_shaders.h `ellipsoid_nearest`, the same steps in double).
#pragma once

#include <Eigen/Core>

namespace heartsim {

/// The point of the surface (x/a)² + (y/b)² + (z/c)² = 1 nearest to `inside`, both in the
/// ellipsoid's own frame (centre at the origin, axes along x, y, z; semi_axes = (a, b, c) > 0).
/// `inside` must not lie outside the surface.
///
/// The nearest point is x_i = a_i² y_i / (a_i² + t) for the root t in (−m, 0] of
/// F(t) = Σ (a_i y_i / (a_i² + t))² − 1, m the smallest a_i² (Lagrange's condition: the offset
/// from the point is along the surface normal). F falls from +∞ to F(0) ≤ 0 on that interval
/// when the point has a component along a shortest axis; 80 bisections find t to the last bit.
/// When it has none, or one too small to place the root (the point lies on the plane of the
/// other axes, e.g. on the long axis of a needle), and the root would sit at the pole t = −m,
/// the nearest points form a circle or a pair and this returns the one along the shortest axis
/// that the point leans to: z if z is a shortest axis, else the first one, positive side when
/// the point leans to neither. The centre of a sphere goes to (0, 0, c).
///
/// A radial projection (scaling the point out to the surface) is not the nearest point: inside a
/// 3 × 3 × 8 mm needle it sends a point near the axis towards a tip, up to 7.5 mm away, where
/// the nearest surface is 3 mm to the side.
Eigen::Vector3d nearest_point_on_ellipsoid(const Eigen::Vector3d& inside, const Eigen::Vector3d& semi_axes);

}  // namespace heartsim
