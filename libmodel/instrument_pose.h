/// @file instrument_pose.h
/// @brief Where an instrument is: the tool frame's pose in the world, and the pose between two.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace heartsim {

/// Tool frame → world: x_world = orientation · x_tool + position (mm, LPS).
struct InstrumentPose {
    Eigen::Vector3d position = Eigen::Vector3d::Zero();
    Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};

/// The pose a fraction `t` of the way from `a` to `b`: the position linearly, the orientation by
/// slerp. Both backends move the instruments through a step's substeps with it.
inline InstrumentPose interpolate(const InstrumentPose& a, const InstrumentPose& b, double t) {
    return {a.position + t * (b.position - a.position), a.orientation.slerp(t, b.orientation)};
}

}  // namespace heartsim
