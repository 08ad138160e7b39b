/// @file surgery_site.h
/// @brief Where the scripted operations act on the heart, found on plain arrays: the incision's
/// place on a lattice's rest positions, and the repair's stitch sites and patch on a closed
/// triangle mesh round a septal defect. The plans built on them (runtime/surgery/incision_plan.h,
/// runtime/surgery/repair_plan.h) turn these places into trajectories; the rules are theirs, described in
/// those headers. All positions world LPS mm (+x the patient's left, +y posterior, +z superior).
///
///     const IncisionSite site = incision_site(rest, spacing, {.approach = IncisionApproach::atriotomy});
///     const StitchCircle circle = stitch_circle(centre, axis, /*on_b=*/true, 7.0, 15);
///     const StitchSites found = find_stitch_sites(mesh_positions, mesh_triangles, circle, 3.0);
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace heartsim {

// ---- The incision ----------------------------------------------------------------------------

enum class IncisionApproach { ventriculotomy, atriotomy };

struct IncisionSiteOptions {
    IncisionApproach approach = IncisionApproach::ventriculotomy;
    double length_mm = 30.0;     ///< the stroke's length along z, mm
    double depth_mm = 0.0;       ///< the blade's reach behind the entry, mm; 0: through the wall (6 mm assumed for the atriotomy's search)
    double clearance_mm = 2.0;   ///< the blade's tip in front of the entry, mm
    /// The approach chamber's own wall: one flag per rest position, 1 where the particle is that
    /// chamber's tissue (the right ventricle's free wall, the right atrium's wall). Empty, or no
    /// flag set: the chamber is not told apart and the place is found on the whole heart.
    std::vector<std::uint8_t> chamber_wall;
    /// Without a chamber wall: the particles whose extent in z gives the atriotomy its upper half,
    /// one flag per rest position (the labelled ventricular wall, where walls were grown round one
    /// blood pool that reaches up the great vessels: the right atrium lies beside the ventricles'
    /// upper half, the venae cavae above it). Empty or none set: every particle.
    std::vector<std::uint8_t> height_from;
};

/// An incision's place: the entry particle and the blade's frame there.
struct IncisionSite {
    std::size_t particle = 0;                            ///< the chosen particle (index into the rest positions)
    Eigen::Vector3d entry = Eigen::Vector3d::Zero();     ///< its rest position
    /// The entry moved a quarter spacing along `side`: a point of the blade's plane.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d blade = Eigen::Vector3d::UnitY();    ///< where the blade points (into the heart), a world axis
    Eigen::Vector3d cut = Eigen::Vector3d::UnitZ();      ///< the direction the blade is drawn
    Eigen::Vector3d side = Eigen::Vector3d::UnitX();     ///< the blade plane's normal, cut × side = blade
    double wall_mm = 0.0;                                ///< the tissue's thickness along the blade from the entry (wall_thickness)
    /// The atriotomy found a place whose wall holds the whole incision (else the most rightward
    /// point was taken); always true for the ventriculotomy.
    bool whole_wall = true;
    /// The place was chosen on options.chamber_wall (false: on the whole heart's rule).
    bool on_chamber_wall = false;
};

/// The incision's place on the rest positions `rest` (N×3, N > 0) of a lattice of spacing
/// `spacing` (mm), by options.approach's rule (runtime/surgery/incision_plan.h).
IncisionSite incision_site(const std::vector<std::array<float, 3>>& rest, double spacing, const IncisionSiteOptions& options);

/// The world axis `v` lies along (0, 1 or 2) and its sign; `v` is a signed unit axis.
std::pair<int, double> axis_of(const Eigen::Vector3d& v);

/// The tissue's thickness from particle `from` along the unit vector `direction`, mm: how far a
/// point marched from it in quarter spacings stays within 0.75 spacing of a particle, and half a
/// spacing more (the tissue reaches half a spacing beyond its last particle).
double wall_thickness(const std::vector<std::array<float, 3>>& rest, double spacing, std::size_t from, const Eigen::Vector3d& direction);

/// The particle that is frontmost along `blade` (the smallest rest coordinate along it) among
/// those within `radius` of the line through `point` along `blade` (a world axis, ±); −1 if none.
int frontmost_near(const std::vector<std::array<float, 3>>& rest, const Eigen::Vector3d& point, const Eigen::Vector3d& blade, double radius);

// ---- The repair of a septal defect -------------------------------------------------------------

/// A stretch of a line inside the tissue, between the heights where it enters (from above) and
/// leaves it, mm along the line's `up` from the point it was given at.
struct TissueStretch {
    double top = 0.0, bottom = 0.0;
    double length() const { return top - bottom; }
    bool holds(double h) const { return bottom <= h && h <= top; }
};

/// The tissue's stretches along the line through `point` along the unit vector `up`, from the top
/// down, of the closed mesh (`positions` V×3, `triangles` F×3 indices, counter-clockwise seen from
/// outside): every crossing (libmodel/ray_triangle.h, edges included), each entering crossing
/// paired with the next leaving one. Followed downward from far above, crossings alternate
/// entering and leaving; a crossing counted twice (a line through an edge) is dropped.
std::vector<TissueStretch> tissue_stretches(const std::vector<std::array<float, 3>>& positions,
                                            const std::vector<std::array<std::int32_t, 3>>& triangles, const Eigen::Vector3d& point,
                                            const Eigen::Vector3d& up);

/// The circle the stitches lie on: `count` points of radius `radius_mm` (or each its own, `radii`)
/// round the defect's axis, evenly spaced in angle, in the plane through its centre across it; stitch 1 at the circle's most superior point (most
/// anterior where the axis is within 25° of superior-inferior), the others counter-clockwise seen
/// from the chosen side (`outward`).
struct StitchCircle {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();   ///< the defect's centre, mid-wall
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();    ///< unit, from side a's pool to side b's
    Eigen::Vector3d outward = Eigen::Vector3d::UnitZ(); ///< unit, ±axis: from the septum into the chosen side's pool
    Eigen::Vector3d first = Eigen::Vector3d::UnitX();   ///< unit, across the axis: toward stitch 1
    Eigen::Vector3d second = Eigen::Vector3d::UnitY();  ///< outward × first
    bool starts_anterior = false;                       ///< stitch 1 at the most anterior point (else the most superior)
    double radius_mm = 0.0;
    int count = 0;
    /// Each stitch's own distance from the axis, mm, where some stitches lie off the circle (those
    /// a plan moves out of a conduction zone, libmodel/surgery/conduction_zone.h); empty: every
    /// stitch at radius_mm.
    std::vector<double> radii;
    /// Stitch k's distance from the axis: radii[k], or radius_mm.
    double radius_of(int k) const { return radii.empty() ? radius_mm : radii[std::size_t(k)]; }
    /// Stitch k's point (k from 0), at radius_of(k) from the axis, and its angle round the axis
    /// from stitch 1, degrees.
    Eigen::Vector3d point(int k) const;
    double angle_deg(int k) const;
};
/// The circle round `centre` and the unit `axis`, on side b (outward = +axis) or side a (−axis).
StitchCircle stitch_circle(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, bool on_b, double radius_mm, int count);

/// One stitch's site: where the line through its circle point along the axis, followed from far
/// outside along −outward, first enters the tissue within the window of the centre's plane.
struct StitchSite {
    Eigen::Vector3d point = Eigen::Vector3d::Zero();  ///< on the circle
    double angle_deg = 0.0;                           ///< round the axis from stitch 1
    Eigen::Vector3d site = Eigen::Vector3d::Zero();   ///< on the wall's surface
    double height_mm = 0.0;                           ///< the site's distance from the centre's plane along outward
    double wall_mm = 0.0;                             ///< the length of the tissue's stretch that begins at the site
};

/// The stitch sites of `circle` on the closed mesh, and what was found on the way.
struct StitchSites {
    std::vector<StitchSite> sites;  ///< one a stitch, in order; those before `missing` where one is missing
    /// T, the median length of the stretches that hold the centre's plane (mid-wall), mm; 0 where
    /// no line crosses tissue at mid-wall.
    double thickness_mm = 0.0;
    bool mid_wall_found = false;
    double window_mm = 0.0;         ///< T + the margin: how far from the centre's plane a site may lie
    /// The first stitch (from 0) whose line meets no wall within the window; −1 when none.
    int missing = -1;
    StitchSite missing_line;        ///< its point and angle (no site)
    /// The nearest |top| of the tissue the missing line enters, mm; infinite where it crosses none.
    double missing_nearest_mm = 0.0;
    /// The sites' wall_mm: median, least and largest (NaN where a stitch is missing).
    double wall_median_mm = 0.0, wall_min_mm = 0.0, wall_max_mm = 0.0;
};
/// Each stitch's site on the mesh (`positions` V×3, `triangles` F×3, closed, outward-wound), the
/// window being T + `window_margin_mm`. Stops at the first line that meets no wall (`missing`).
StitchSites find_stitch_sites(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<std::int32_t, 3>>& triangles,
                              const StitchCircle& circle, double window_margin_mm);

/// A patch laid on the stitch sites: the plane fitted to them by least squares, its normal toward
/// the tissue (along −outward); the patch centred on the axis, half its thickness off that plane on
/// the chosen side, its first in-plane axis (tool +x) toward stitch 1.
struct PatchPlacement {
    Eigen::Vector3d facing = Eigen::Vector3d::UnitZ();  ///< unit, tool +z: toward the tissue
    double residual_mm = 0.0;                           ///< the largest distance of a site from the plane
    double tilt_deg = 0.0;                              ///< the angle between facing and −outward
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};
/// The patch of thickness `thickness_mm` on `sites` (at least 3) round `circle`. Throws InputError
/// where the sites' plane lies almost along the axis (its normal more than about 84° from it: no
/// wall across the opening for a patch to cover).
PatchPlacement place_patch(const std::vector<StitchSite>& sites, const StitchCircle& circle, double thickness_mm);

}  // namespace heartsim
