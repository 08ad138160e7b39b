/// @file triangle_point.h
/// @brief The point of a triangle nearest a point, as barycentric weights: the detailed mesh's
/// mapping and the patch's stitches both ask it.
#pragma once

#include <Eigen/Core>

#include <cmath>

namespace heartsim {

/// Closest point on triangle (a,b,c) to q as barycentric weights (Ericson, Real-Time Collision
/// Detection, 5.1.5).
inline Eigen::Vector3d closest_barycentric(const Eigen::Vector3d& q, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                           const Eigen::Vector3d& c) {
    const Eigen::Vector3d ab = b - a, ac = c - a, ap = q - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return {1, 0, 0};
    const Eigen::Vector3d bp = q - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return {0, 1, 0};
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        const double v = d1 / (d1 - d3);
        return {1 - v, v, 0};
    }
    const Eigen::Vector3d cp = q - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return {0, 0, 1};
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        const double w = d2 / (d2 - d6);
        return {1 - w, 0, w};
    }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return {0, 1 - w, w};
    }
    const double denominator = va + vb + vc;
    if (!(std::abs(denominator) > 0)) return {1.0 / 3, 1.0 / 3, 1.0 / 3};
    const double v = vb / denominator, w = vc / denominator;
    return {1 - v - w, v, w};
}

}  // namespace heartsim
