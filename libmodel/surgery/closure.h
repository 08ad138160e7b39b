/// @file closure.h
/// @brief Whether a patch closes a septal defect in the deformed state: a flood fill from the
/// opening at mid-wall toward the patch's side, looking for a way past the patch, and the largest
/// gap between the patch and the tissue along the opening's rim (docs/closure.md).
///
///     const ClosureResult r = check_closure(visual_positions, visual_triangles,
///                                           patch_positions, patch_triangles, 0.5, defect);
///     // r.closed: no voxel path out of the opening past the patch; r.largest_rim_gap_mm: the worst gap on the rim
///
/// The defect is a round opening (a cylinder of diameter D along a unit axis, centred mid-wall)
/// through the septum. The check works in the defect's frame: s = (p − centre)·axis, ρ the distance
/// from the axis. Steps:
///  1. the wall's thickness T: the tissue intervals of lines parallel to the axis at ρ = D/2 +
///     rim_offset (eight around), each the one containing or nearest s = 0; T the median length;
///  2. the rim: rays along −axis at ρ = D/2 + rim_offset onto the tissue's surface on the patch
///     side, within D/2 + margin + T/2 of the centre; the rim gap at each hit, the distance to the
///     patch's mid-surface less half its thickness;
///  3. the region: the cylinder ρ ≤ D/2 + margin, 0 ≤ s ≤ s_top, s_top 2 mm above the larger of the
///     highest rim point (at least 0; T/2 where none was found) + thickness and the patch's highest
///     point over the cylinder + thickness/2; a grid of voxel_mm aligned with the defect's frame;
///  4. tissue voxels: centres inside the closed mesh, by the winding number along rows parallel to
///     the grid's first axis (every crossing of the row counts, also those outside the region);
///     patch voxels: centres within thickness/2 + ½·√3·voxel of the patch's mid-surface, so a thin
///     patch leaves no diagonal hole at the grid's resolution;
///  5. a 6-connected flood fill over the region's free voxels from the opening at mid-wall
///     (s < 1 mm, ρ < D/2 − voxel) toward the region's top layer (s ≥ s_top − voxel). Nothing below
///     mid-wall is in the region: blood that reaches the patch's side around the septum, through
///     the far side's chamber, has not passed the patch;
///  6. the verdict: closed only where rim points were found, the patch covers the opening (every
///     point of its disc has the patch over it along the axis, within the wall's reach) and the
///     fill found no way out; cannot tell where no rim point was found or the wall does not hold
///     the centre; else open, with why.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// The opening, in the deformed state.
struct DefectFrame {
    Eigen::Vector3d centre{0, 0, 0};  ///< the opening's centre, mid-wall, world mm (deformed state)
    Eigen::Vector3d axis{0, 0, 0};    ///< unit, from the far side toward the side the patch is on (must be set)
    double diameter_mm = 0.0;         ///< the opening's diameter, mm
};

struct ClosureOptions {
    double voxel_mm = 0.25;      ///< the flood fill's grid spacing, mm
    double margin_mm = 5.0;      ///< the region: a cylinder of radius D/2 + margin around the axis, mm
    int rim_samples = 72;        ///< points along the rim (evenly spaced angles)
    double rim_offset_mm = 0.5;  ///< the rim: the tissue surface on the patch's side this far outside the opening's radius, mm
    /// The stitches' tissue points (world mm, in the order tied), to name those a leak passes
    /// between (ClosureResult::leak_between); none: no names.
    std::vector<Eigen::Vector3d> stitches;
};

struct ClosureResult {
    /// The verdict "yes": a patch covers the opening (`covered` is 1), rim points were found and
    /// the fill found no way out (`sealed`). Never true together with `cannot_tell`.
    bool closed = false;
    /// The verdict "cannot tell": no rim point meets the wall (rim_points is 0), or the wall does
    /// not hold the centre (on fewer than half the lines of step 1 the wall's interval contains
    /// s = 0): the defect's centre is in blood, not in the opening, and the fill from there says
    /// nothing about the patch. `closed` is false; `why` says so.
    bool cannot_tell = false;
    /// Not closed: why, for a trainer ("the patch does not cover the opening: it lies 34 mm from
    /// the defect's axis", "cannot tell: no rim point meets the wall …"). Empty when closed.
    std::string why;
    /// No 6-connected path of free voxels inside the region from the opening at mid-wall to the
    /// region's top layer, beyond the patch: the fill's own answer, which alone is no verdict (a
    /// patch laid away from the opening can cap the region with tissue beyond it).
    bool sealed = false;
    /// The share of the opening's disc (ρ ≤ D/2) whose line along the axis meets the patch
    /// within the wall's reach: from the wall's far face (s = −T/2) to the rim's radius above the
    /// highest rim point plus half the thickness. 0 with no patch.
    double covered = 0.0;
    /// The largest over the rim points of (distance to the patch's mid-surface − half its
    /// thickness), clamped at 0, mm. The diameter where there is no patch or no rim point was found.
    double largest_rim_gap_mm = 0.0;
    double wall_thickness_mm = 0.0;   ///< T: the septum's thickness along the axis near the rim, mm
    double top_mm = 0.0;              ///< s_top: the region's top above the wall's middle, mm
    std::size_t voxels = 0;           ///< voxels in the region
    std::size_t reached = 0;          ///< free voxels the fill reached from the opening
    int rim_points = 0;               ///< rim samples where the tissue surface was found
    /// Where it leaks, when not closed (docs/closure.md step 6), world mm: where the way out under
    /// the patch passes the rim widest (LeakWay::rim), at the rim's radius and the way's mean
    /// height there; with no patch, the defect's centre (no_patch); where the way never passes
    /// the rim (a hole through the patch: through_patch), the first voxel of the top layer it
    /// reaches; where the fill found none but the patch does not cover the opening (uncovered),
    /// the middle of the uncovered part at mid-wall. Empty when closed or cannot tell.
    std::optional<Eigen::Vector3d> leak_mm;
    /// uncovered: the patch does not cover the opening and the fill found no way out (the region
    /// capped beyond it); leak_mm is the middle of the part of the opening it leaves uncovered, at
    /// mid-wall.
    enum class LeakWay { no_patch, rim, through_patch, uncovered };
    LeakWay leak_way = LeakWay::no_patch;  ///< which of those leak_mm is
    /// When the leak passes the rim and stitches were given: the stitches (indices into
    /// ClosureOptions::stitches) either side of leak_mm round the axis, the nearest clockwise and
    /// counter-clockwise seen from the patch's side (the same one when there is one stitch).
    std::optional<std::array<std::size_t, 2>> leak_between;
    double seconds = 0.0;             ///< wall-clock time of the check
};

/// Checks whether the patch closes the defect.
///
/// `tissue_positions` V×3 world mm and `tissue_triangles` F×3 vertex indices: a closed triangle
/// mesh (the deformed detailed mesh), outward normals by counter-clockwise order. Self-overlaps
/// count as tissue (the winding number is ≥ 1 there).
/// `patch_positions` P×3 world mm and `patch_triangles` Q×3: the patch's mid-surface (any
/// orientation, open or closed); no triangles means no patch. `patch_thickness_mm` ≥ 0.
/// `defect`: the opening in the same world frame; its axis points toward the patch's side.
///
/// Throws InputError for an empty tissue mesh, an index out of range, a non-finite position, a
/// zero or non-unit axis (|‖axis‖ − 1| > 1e-3), a diameter that is not positive, a negative
/// thickness; when no wall is found around the opening; when the opening has no free voxel at
/// mid-wall ("the opening is not open at mid-wall …") or the region's top layer none on the
/// patch's side. Throws OptionError for options out of range or a grid of more than 200 million
/// voxels.
ClosureResult check_closure(const std::vector<std::array<float, 3>>& tissue_positions,
                            const std::vector<std::array<std::int32_t, 3>>& tissue_triangles,
                            const std::vector<std::array<float, 3>>& patch_positions,
                            const std::vector<std::array<std::int32_t, 3>>& patch_triangles,
                            double patch_thickness_mm, const DefectFrame& defect, const ClosureOptions& options = {});

/// A point's distance from the defect's axis, mm.
double distance_from_axis(const DefectFrame& defect, const Eigen::Vector3d& point);

/// The check's options for a repair of `defect`: the cylinder reaching 3 mm beyond
/// `patch_reach_mm` from the axis (the patch's edge; a leak under the patch comes out there; 0: no
/// patch, the default margin), the rim where the stitches bite (their tissue points' mean
/// distance from the axis, never nearer the opening than the default offset), and the stitches,
/// to name those a leak passes between.
ClosureOptions repair_closure_options(const DefectFrame& defect, double patch_reach_mm, const std::vector<Eigen::Vector3d>& stitches);

/// Where a leak passes the rim, for a trainer: "between stitches 3 and 4" (counted from 1 in the
/// order tied), "beside stitch 1, the only one", "where no stitch holds the patch" with none,
/// "through the patch" where the way out does not pass the rim, "no patch covers the opening",
/// "where the patch does not cover the opening"; empty when closed or cannot tell.
std::string leak_place(const ClosureResult& result);

}  // namespace heartsim
