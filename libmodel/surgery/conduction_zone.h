/// @file conduction_zone.h
/// @brief The rim of a perimembranous ventricular septal defect along which the atrioventricular
/// conduction axis runs: the stretch a surgeon's stitches must spare. World LPS mm (+x the
/// patient's left, +y posterior, +z superior).
///
/// The anatomy. The atrioventricular conduction axis penetrates the central fibrous body at the
/// apex of the triangle of Koch, where the septal leaflet's hinge of the tricuspid valve meets the
/// membranous septum beneath the aortic root; in a perimembranous defect the bundle of His then
/// runs along the defect's posteroinferior rim, on the left ventricular side of the crest, toward
/// the muscular septum (Milo S, Ho SY, Wilkinson JL, Anderson RH, "Surgical anatomy and
/// atrioventricular conduction tissues of hearts with isolated ventricular septal defects",
/// J Thorac Cardiovasc Surg 1980;79:244-255; Becker AE, Anderson RH, Pathology of Congenital Heart
/// Disease, Butterworths 1981). Surgeons therefore place the stitches along that rim 3 to 5 mm back
/// from the edge, superficially and on the right ventricular side, where the other rims take
/// stitches close to the edge (Mavroudis C, Backer CL, Pediatric Cardiac Surgery, "Ventricular
/// septal defect").
///
/// The rule (conduction_zone()):
///   perimembranous  the defect's rim (the circle of radius D/2 round its axis in the plane across it
///                   through its centre) comes within `ring_reach_mm` (10 mm by default) of a point of
///                   the tricuspid ring and of a point of the aortic ring (the scenario's /landmarks,
///                   libmodel/landmarks.h): the opening lies where the septal leaflet's hinge and
///                   the aortic root meet, the membranous septum. A defect farther from either is
///                   muscular (or outlet, or inlet), with no conduction axis along its rim: no zone.
///   direction       with t, a the directions across the axis from the centre to the tricuspid
///                   ring's and the aortic ring's nearest points (the ring's septal part: the
///                   points nearest the rim), and p the posteroinferior direction (0, 1, −1)/√2 of
///                   LPS made perpendicular to the axis, each a unit vector: the zone's middle
///                   points along t − a + p (toward the tricuspid ring's septal part, away from the
///                   aortic root, biased posteroinferior), made unit.
///   arc             every direction across the axis within `half_width_deg` (60° by default: a
///                   third of the rim) of the middle.
///   band            from the axis out to `band_mm` (3 mm by default) beyond the opening's edge:
///                   a stitch whose tissue point lies within the arc and within D/2 + band of the
///                   axis bites the conduction axis's course. Along the axis the band reaches
///                   through the whole wall (a bite on either face counts).
/// Without the rings (a label map whose chambers are not labelled apart, HVSMR 2016's) there is no
/// zone, and the reason says which ring is missing and why; it is never guessed.
///
///     const ConductionZone zone = conduction_zone(centre, axis, 10.0, *scenario.landmarks);
///     if (zone.found && zone.holds(stitch_point)) ...   // the stitch bites the conduction axis's course
#pragma once

#include "libmodel/landmarks.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace heartsim {

struct ConductionZoneOptions {
    /// The defect is perimembranous when its rim comes within this of both the tricuspid and the
    /// aortic ring's points, mm. 10 mm: a ring's points lie on the detailed surface, a voxel or two
    /// off the hinge itself, and a rim that reaches the membranous septum lies within a few
    /// millimetres of both hinges; a mid-muscular defect's lies centimetres from them.
    double ring_reach_mm = 10.0;
    double band_mm = 3.0;          ///< the zone reaches this far beyond the opening's edge, mm
    double half_width_deg = 60.0;  ///< the arc's half-width round the axis, degrees, in (0, 180]
};

/// The conduction zone of one defect, or why it has none.
struct ConductionZone {
    bool found = false;
    /// Why there is a zone (which rings, how near) or why there is none (a ring missing, and why;
    /// the rim too far from a ring: muscular).
    std::string reason;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< the defect's centre, mid-wall
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();   ///< unit, the defect's axis
    /// Unit, across the axis: the middle of the arc (zero where none was found).
    Eigen::Vector3d direction = Eigen::Vector3d::Zero();
    double half_width_deg = 0.0;
    double edge_mm = 0.0;   ///< D/2: the opening's edge, from the axis
    double outer_mm = 0.0;  ///< D/2 + band: the zone's outer edge, from the axis
    /// The rim's nearest approach to each ring's points, mm (NaN where that ring is missing), and
    /// those points.
    double tricuspid_mm = 0.0, aortic_mm = 0.0;
    Eigen::Vector3d tricuspid_point = Eigen::Vector3d::Zero(), aortic_point = Eigen::Vector3d::Zero();
    /// The angle between `p`'s direction across the axis and the arc's middle, degrees in [0, 180];
    /// 0 for a point on the axis.
    double angle_from_middle_deg(const Eigen::Vector3d& p) const;
    /// Whether the direction across the axis toward `p` lies within the arc (any distance).
    bool in_arc(const Eigen::Vector3d& p) const;
    /// Whether `p` lies in the zone: in the arc, off the axis and within outer_mm of it. False
    /// where no zone was found.
    bool holds(const Eigen::Vector3d& p) const;
};

/// The conduction zone of the defect centred at `centre` (mid-wall), along the unit `axis`, of
/// diameter `diameter_mm` (> 0), by the rule above, from `landmarks`' tricuspid_ring and
/// aortic_ring. No zone (found false, the reason said) where either ring is missing or the rim
/// lies farther than options.ring_reach_mm from it. Pure: throws nothing for a defect of another
/// kind; the caller asks only for a vsd.
ConductionZone conduction_zone(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, double diameter_mm, const Landmarks& landmarks,
                               const ConductionZoneOptions& options = {});

/// The indices (from 0) of `points` that lie in `zone` (ConductionZone::holds), in order.
std::vector<int> points_in_zone(const ConductionZone& zone, const std::vector<Eigen::Vector3d>& points);

}  // namespace heartsim
