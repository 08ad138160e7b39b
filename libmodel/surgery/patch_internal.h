/// @file patch_internal.h
/// @brief What patch.cpp, patch_step.cpp and patch_pass.cpp share besides PatchModel itself: a
/// float triple in double and the barycentric weights of a point's projection onto a triangle.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cmath>

namespace heartsim::patch_internal {

inline Eigen::Vector3d vec(const std::array<float, 3>& p) { return {double(p[0]), double(p[1]), double(p[2])}; }

/// Barycentric weights of p's projection onto the plane of triangle (a, b, c); (−1, −1, −1) where
/// the triangle has no area.
inline Eigen::Vector3d barycentric(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
    const Eigen::Vector3d v0 = b - a, v1 = c - a, v2 = p - a;
    const double d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
    const double denominator = d00 * d11 - d01 * d01;
    if (!(std::abs(denominator) > 1e-18)) return {-1, -1, -1};
    const double v = (d11 * d20 - d01 * d21) / denominator, w = (d00 * d21 - d01 * d20) / denominator;
    return {1.0 - v - w, v, w};
}

}  // namespace heartsim::patch_internal
