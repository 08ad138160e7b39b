/// @file ellipsoid.cpp
/// @brief The nearest surface point of an ellipsoid from inside (ellipsoid.h).
#include "libmodel/ellipsoid.h"

#include <cmath>

namespace heartsim {

Eigen::Vector3d nearest_point_on_ellipsoid(const Eigen::Vector3d& y, const Eigen::Vector3d& semi_axes) {
    const Eigen::Vector3d a2 = semi_axes.cwiseProduct(semi_axes);
    const double m = a2.minCoeff();
    bool shortest[3];
    double w2 = 0;  // the point's squared component in the shortest axes
    double g = 0;   // F(−m) + 1 without the shortest axes' terms
    for (int i = 0; i < 3; ++i) {
        shortest[i] = a2[i] <= m * (1 + 1e-12);
        if (shortest[i]) w2 += y[i] * y[i];
        else {
            const double q = semi_axes[i] * y[i] / (a2[i] - m);
            g += q * q;
        }
    }
    Eigen::Vector3d x;
    if (g <= 1 && w2 <= 1e-18 * m) {
        // The root is at the pole t = −m: the other axes' coordinates are finite there and the
        // shortest axes take up the rest of the surface equation.
        const double w = std::sqrt(w2);
        int fallback = shortest[2] ? 2 : (shortest[0] ? 0 : 1);
        const double along = std::sqrt(m * (1 - g));
        for (int i = 0; i < 3; ++i) {
            if (!shortest[i]) x[i] = a2[i] * y[i] / (a2[i] - m);
            else if (w > 0) x[i] = along * y[i] / w;
            else x[i] = i == fallback ? along : 0.0;
        }
        return x;
    }
    // F(t) > 0 without a division (the gl backend runs this in double, slow on many GPUs): with
    // d_i = (a_i² + t)² > 0 and p_i = (a_i y_i)², Σ p_i / d_i > 1  ⇔  Σ p_i Π_{j≠i} d_j > Π d_j.
    const Eigen::Vector3d p = semi_axes.cwiseProduct(y).cwiseAbs2();
    auto above = [&](double t) {
        const double d0 = (a2[0] + t) * (a2[0] + t), d1 = (a2[1] + t) * (a2[1] + t), d2 = (a2[2] + t) * (a2[2] + t);
        return p[0] * d1 * d2 + p[1] * d0 * d2 + p[2] * d0 * d1 > d0 * d1 * d2;
    };
    double low = -m, high = 0;  // F(low⁺) > 0 ≥ F(high)
    for (int iteration = 0; iteration < 80; ++iteration) {
        const double middle = 0.5 * (low + high);
        if (middle <= low || middle >= high) break;
        (above(middle) ? low : high) = middle;
    }
    for (int i = 0; i < 3; ++i) x[i] = a2[i] * y[i] / (a2[i] + high);
    return x;
}

}  // namespace heartsim
