/// @file plan_text.h
/// @brief How the planners (runtime/surgery/repair_plan.h, operation_plan.h) write numbers and
/// points in what they print and in their refusals.
#pragma once

#include <Eigen/Core>

#include <cstdio>
#include <string>

namespace heartsim::plan_text {

/// "x, y, z" to `decimals` places.
inline std::string coordinates(const Eigen::Vector3d& p, int decimals = 1) {
    char text[96];
    std::snprintf(text, sizeof text, "%.*f, %.*f, %.*f", decimals, p.x(), decimals, p.y(), decimals, p.z());
    return text;
}

/// "(x, y, z)" to `decimals` places.
inline std::string point(const Eigen::Vector3d& p, int decimals = 1) { return "(" + coordinates(p, decimals) + ")"; }

/// "x,y,z" to 0.1 mm: a point as heartsim run's --look-at and --eye take it.
inline std::string option_point(const Eigen::Vector3d& p) {
    char text[96];
    std::snprintf(text, sizeof text, "%.1f,%.1f,%.1f", p.x(), p.y(), p.z());
    return text;
}

/// `value` to `decimals` places.
inline std::string number(double value, int decimals = 1) {
    char text[48];
    std::snprintf(text, sizeof text, "%.*f", decimals, value);
    return text;
}

}  // namespace heartsim::plan_text
