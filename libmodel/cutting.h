/// @file cutting.h
/// @brief The scalpel's geometry: the surface its blade sweeps between two poses, and the test
/// that decides whether a spring crosses it. Shared by the cpu solver and, operation for
/// operation, by the gl backend's cut pass (runtime/gl/shaders/solver_shaders.h `cut_pass`), so
/// that both cut the same springs from the same positions.
///
/// The blade is the segment from the tool's position (the tip) along the tool's +z axis, of
/// length 2·az (the instrument's third semi-axis). Between a step's start pose A and end pose B
/// it sweeps the ruled quad (tip_A, end_A, end_B, tip_B), taken as the two triangles
/// (tip_A, end_A, end_B) and (tip_A, end_B, tip_B). A blade pushed along its own length or held
/// still sweeps no area and cuts nothing.
///
///     const BladeSweep sweep = blade_sweep(from, to, 2 * semi_axes.z());
///     if (sweep.cuts_anything && spring_crosses(sweep, x_low, x_high)) cut(...);
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>

namespace heartsim {

struct InstrumentPose;

/// The swept quad in float (the precision of the positions it is tested against), with its
/// bounding box.
struct BladeSweep {
    /// The triangles' corners: tip_A, end_A, end_B, tip_B (mm, world frame).
    std::array<std::array<float, 3>, 4> corner{};
    std::array<float, 3> low{}, high{};  ///< the corners' bounding box
    bool cuts_anything = false;          ///< false when the quad has no area (the blade did not sweep)
};

/// The blade's tip and end at `pose` for a blade `length` mm long: tip = position, end = tip +
/// length · (orientation · ẑ).
std::array<Eigen::Vector3d, 2> blade_segment(const InstrumentPose& pose, double length);

/// The surface a blade `length` mm long sweeps from pose `from` to pose `to`.
BladeSweep blade_sweep(const InstrumentPose& from, const InstrumentPose& to, double length);

/// True when the segment p–q crosses one of the sweep's triangles: p and q on opposite sides of
/// its plane (a point on the plane counting as on the positive side, so that a blade through a
/// particle cuts the springs to one side of it), and the segment's line through the triangle or
/// on its edges. Evaluated in
/// float in a fixed order (no fused multiply-add), so the same inputs give the same answer on
/// the cpu and the gpu; the caller passes the end of lower particle index as `p`, so both ends of
/// a spring reach the same decision.
bool spring_crosses(const BladeSweep& sweep, const float* p, const float* q);

}  // namespace heartsim
