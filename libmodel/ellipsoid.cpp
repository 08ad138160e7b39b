/// @file ellipsoid.cpp
/// @brief The nearest surface point of an ellipsoid from inside (ellipsoid.h).
#include "ellipsoid.h"

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
    auto f = [&](double t) {
        double sum = 0;
        for (int i = 0; i < 3; ++i) {
            const double q = semi_axes[i] * y[i] / (a2[i] + t);
            sum += q * q;
        }
        return sum - 1;
    };
    double low = -m, high = 0;  // f(low⁺) > 0 ≥ f(high)
    for (int iteration = 0; iteration < 80; ++iteration) {
        const double middle = 0.5 * (low + high);
        if (middle <= low || middle >= high) break;
        (f(middle) > 0 ? low : high) = middle;
    }
    for (int i = 0; i < 3; ++i) x[i] = a2[i] * y[i] / (a2[i] + high);
    return x;
}

}  // namespace heartsim
