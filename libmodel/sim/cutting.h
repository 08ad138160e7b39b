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
///     const BladeSweep sweep = blade_sweep(from, to, 2 * semi_axes.z(), cut_search_margin(longest_rest_length));
///     if (near_sweep(sweep, x_low) && spring_crosses(sweep, x_low, x_high)) cut(...);
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "libmodel/instrument_pose.h"

#include <array>
#include <cstdint>
#include <vector>

namespace heartsim {

/// The swept quad in float (the precision of the positions it is tested against), with its
/// bounding box and the box a spring's lower end must lie in to be tested at all.
struct BladeSweep {
    /// The triangles' corners: tip_A, end_A, end_B, tip_B (mm, world frame).
    std::array<std::array<float, 3>, 4> corner{};
    std::array<float, 3> low{}, high{};  ///< the corners' bounding box
    /// The bounding box grown by the search margin (cut_search_margin), in float: low − margin,
    /// high + margin. The cpu solver and the gl cut pass both read it from here.
    std::array<float, 3> near_low{}, near_high{};
    bool cuts_anything = false;          ///< false when the quad has no area (the blade did not sweep)
};

/// How far from the swept quad's box the lower end of a spring that crosses it may lie: twice the
/// longest rest length, the stretch past which a state counts as torn (SolverOptions::
/// restore_strain_limit 1: never a restore point). A spring stretched farther may escape the
/// blade. Four times cost 10-14 % of a 30k-particle step while cutting (docs/benchmarks.md "Cutting").
inline float cut_search_margin(float longest_rest_length_mm) { return 2 * longest_rest_length_mm; }

/// The blade's tip and end at `pose` for a blade `length` mm long: tip = position, end = tip +
/// length · (orientation · ẑ).
std::array<Eigen::Vector3d, 2> blade_segment(const InstrumentPose& pose, double length);

/// The surface a blade `length` mm long sweeps from pose `from` to pose `to`, searched within
/// `margin` mm of its box (cut_search_margin).
BladeSweep blade_sweep(const InstrumentPose& from, const InstrumentPose& to, double length, float margin);

/// True when `p` lies in the sweep's search box (near_low, near_high), bounds included.
inline bool near_sweep(const BladeSweep& sweep, const float* p) {
    for (int d = 0; d < 3; ++d)
        if (p[d] < sweep.near_low[std::size_t(d)] || p[d] > sweep.near_high[std::size_t(d)]) return false;
    return true;
}

/// True when the segment p–q crosses one of the sweep's triangles: p and q on opposite sides of
/// its plane (a point on the plane counting as on the positive side, so that a blade through a
/// particle cuts the springs to one side of it), and the segment's line through the triangle or
/// on its edges. Evaluated in
/// float in a fixed order (no fused multiply-add), so the same inputs give the same answer on
/// the cpu and the gpu; the caller passes the end of lower particle index as `p`, so both ends of
/// a spring reach the same decision.
bool spring_crosses(const BladeSweep& sweep, const float* p, const float* q);


/// One scalpel stroke: the blade's poses from the step it first swept tissue space to the step it
/// was lifted, one per step in which it moved (a blade held still sweeps nothing and adds none).
/// The incision of the detailed mesh (libmodel/surgery/incision.h) is built from it.
struct BladeStroke {
    int hand = 0;
    double length = 0.0;                ///< the blade's length, mm (2·az)
    std::vector<InstrumentPose> poses;  ///< poses[0]: where the first sweep started; then each step's end
    bool lifted = false;                ///< released (grab 0); false while the blade is down
};

/// The strokes both backends' scalpels swept, in the order they began: what the cut pass cut,
/// pose for pose. reset_tissue() heals the springs and clears it.
class StrokeLog {
public:
    /// A step in which `hand`'s lowered blade swept from `from` to `to` (blade_sweep with
    /// cuts_anything true): continues the hand's open stroke, or begins one.
    void sweep(int hand, const InstrumentPose& from, const InstrumentPose& to, double length);
    /// The hand's blade lifted: its open stroke, if any, ends.
    void lift(int hand);
    void clear();
    const std::vector<BladeStroke>& strokes() const { return strokes_; }
    /// Grows with every sweep and lift: a reader that saw the same value saw the same log.
    std::uint64_t version() const { return version_; }
    /// How many times clear() ran: a reader holding rows of an older log must drop them.
    std::uint64_t clears() const { return clears_; }

private:
    std::vector<BladeStroke> strokes_;
    std::array<int, 2> open_{-1, -1};  ///< per hand, the row of its open stroke
    std::uint64_t version_ = 0;
    std::uint64_t clears_ = 0;
};

}  // namespace heartsim
