/// @file sight.h
/// @brief What a surgeon sees through an opening in the heart's wall, on a lattice's rest
/// positions: whether a point lies in the tissue, the lines of sight from a septal defect out
/// through the blood and one free wall, and whether a line from an eye to a point passes the wall
/// only where an incision has opened it. The operation's plan (runtime/surgery/operation_plan.h)
/// chooses its incision among these lines. World LPS mm (+x the patient's left, +y posterior,
/// +z superior).
///
/// The tissue is the lattice's: a point lies in it within 0.75 spacing of a particle (the rule of
/// surgery_site.h wall_thickness), sampled along a line every quarter spacing.
///
///     const TissueOccupancy tissue(rest, spacing);
///     const SightLines lines = sight_lines(tissue, {.target = face, .outward = outward});
///     for (const SightLine& line : lines.lines) if (accepts(line)) ...
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <functional>
#include <unordered_map>
#include <vector>

namespace heartsim {

/// The lattice's tissue: which points lie within 0.75 spacing of a particle.
class TissueOccupancy {
public:
    /// `rest` N×3 positions of a lattice of `spacing` mm (N ≥ 0, spacing > 0).
    TissueOccupancy(const std::vector<std::array<float, 3>>& rest, double spacing);
    bool inside(const Eigen::Vector3d& point) const { return particle_at(point) >= 0; }
    /// The nearest particle within 0.75 spacing of `point`, or −1 (outside the tissue).
    int particle_at(const Eigen::Vector3d& point) const;
    double spacing() const { return spacing_; }

private:
    static std::int64_t key(std::int64_t i, std::int64_t j, std::int64_t k) { return (i * 73856093) ^ (j * 19349663) ^ (k * 83492791); }
    const std::vector<std::array<float, 3>>& rest_;
    double spacing_;
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells_;
};

/// A stretch of a line inside the tissue, mm from the line's start.
struct SightSpan {
    double from = 0.0, to = 0.0;
    double length() const { return to - from; }
};

/// The stretches of the segment from `a` to `b` inside the tissue, in order from `a`, sampled
/// every quarter spacing (a stretch begins and ends at its first and last sample inside).
std::vector<SightSpan> tissue_along(const TissueOccupancy& tissue, const Eigen::Vector3d& a, const Eigen::Vector3d& b);

/// Where the ray from `from` along unit `way` leaves the tissue, sampled every quarter spacing
/// from one step out: `exit` is the first sample outside whose next sample is outside too (a
/// single one may fall in the gap the 0.75-spacing rule leaves at a lattice cell's centre, 0.87
/// spacing from its corners), `last_inside` the last sample inside before it (0 where none is).
/// Where the ray does not leave before `reach`, exit is `reach`. The repair's intrusion check and
/// its needle's depth both measure with it (runtime/surgery/repair.h).
struct WayOut {
    double last_inside = 0.0;  ///< mm from `from`
    double exit = 0.0;         ///< mm from `from`
};
WayOut way_out(const TissueOccupancy& tissue, const Eigen::Vector3d& from, const Eigen::Vector3d& way, double reach);

/// A line of sight from the defect out of the heart: from the target through blood, then through
/// one wall, then out, meeting no tissue again within `reach_mm`.
struct SightLine {
    Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  ///< unit, from the target out of the heart
    double wall_in_mm = 0.0;    ///< where it enters the wall, mm from the target (the blood's path)
    double wall_out_mm = 0.0;   ///< where it leaves it, out of the heart
    int wall_particle = -1;     ///< the particle nearest the wall's middle on the line
    Eigen::Vector3d exit(const Eigen::Vector3d& target) const { return target + wall_out_mm * direction; }
    /// The middle of the wall on the line: where an incision through it is centred.
    Eigen::Vector3d wall_middle(const Eigen::Vector3d& target) const { return target + (0.5 * (wall_in_mm + wall_out_mm)) * direction; }
    double wall_mm() const { return wall_out_mm - wall_in_mm; }
};

struct SightOptions {
    Eigen::Vector3d target = Eigen::Vector3d::Zero();       ///< where the lines start: the defect's face on the surgeon's side
    Eigen::Vector3d outward = Eigen::Vector3d::UnitZ();     ///< unit: the lines lie within cone_deg of it
    double cone_deg = 80.0;
    int directions = 4000;        ///< spread evenly over the sphere (a Fibonacci lattice); those in the cone are tried
    double start_mm = 1.0;        ///< the line starts this far out from the target (off the septum's own face)
    double min_blood_mm = 4.0;    ///< at least this much blood before the wall
    double max_wall_mm = 15.0;    ///< a thicker wall is no free wall to cut through
    double reach_mm = 150.0;      ///< beyond the wall, no tissue within this
    /// The wall the line leaves through must be one this accepts (its particle, the line); empty: any.
    std::function<bool(int particle, const SightLine& line)> accepts;
};

/// The lines of sight found, and how many of the cone's directions failed each test.
struct SightLines {
    std::vector<SightLine> lines;
    int tried = 0;
    int no_blood = 0;       ///< met tissue within min_blood_mm (the septum's own rim, a muscle band)
    int thick_wall = 0;     ///< the first wall thicker than max_wall_mm
    int more_tissue = 0;    ///< tissue again beyond the first wall (another chamber, a vessel)
    int never_out = 0;      ///< no wall within reach: the line leaves the model through no tissue
    int not_accepted = 0;   ///< left through a wall that options.accepts refused
};

SightLines sight_lines(const TissueOccupancy& tissue, const SightOptions& options);

/// An incision's opening once retracted: a box centred in the wall, `half_length` along the cut,
/// `half_width` across it (along `side`), `half_depth` along the line of sight.
struct Opening {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d cut = Eigen::Vector3d::UnitZ(), side = Eigen::Vector3d::UnitX(), sight = Eigen::Vector3d::UnitY();
    double half_length = 0.0, half_width = 0.0, half_depth = 0.0;
    bool holds(const Eigen::Vector3d& point) const;
};

/// Whether the segment from `eye` to `point` meets the tissue only inside `opening` and within
/// `end_slack_mm` of `point` (a point on the tissue's surface is itself in the tissue).
bool seen_through(const TissueOccupancy& tissue, const Eigen::Vector3d& eye, const Eigen::Vector3d& point, const Opening& opening,
                  double end_slack_mm);

}  // namespace heartsim
