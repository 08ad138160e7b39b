/// @file landmarks.h
/// @brief The landmarks a surgeon steers by, found from a label map whose chambers are labelled
/// apart (MM-WHS) and put on the detailed surface: the grooves over the septum's junctions and
/// between atria and ventricles, the courses of the main coronary arteries along them, and the
/// rings of the four valves' orifices. World LPS mm.
///
/// How each is found (docs/scenario-format.md "/landmarks"):
///   distances   exact Euclidean distance (mm, anisotropic spacing) from every voxel centre to the
///               nearest voxel centre of each chamber's blood; at a point, trilinear.
///   groove      the detailed surface's vertices that face away from the blood (no blood label
///               along their outward normal for 3 voxels), whose distances to the two chambers'
///               blood differ by at most `groove_band_mm` and are both at most `groove_reach_mm`;
///               an atrioventricular groove's also within `av_plane_reach_mm` of its valve's plane
///               and no farther from the ring's axis than its radius plus `groove_reach_mm`.
///               The interventricular groove is split anterior / posterior about the left
///               ventricle's long axis (anterior: towards −y, the patient's front).
///   course      a groove's vertices in steps of `course_step_mm` along it (the anterior
///               interventricular groove from base to apex; an atrioventricular groove by angle
///               round its valve's ring, from the end farther from the crux to the crux), each
///               step's vertices averaged, the longest run of steps, then moved to the nearest
///               surface vertex: an ordered polyline, at least `min_course_mm` long.
///   ring        the voxel faces where two blood labels touch (the orifice); its plane fitted to
///               them (centre, normal from the first blood to the second); in each of
///               `ring_sectors` angular sectors about the centre, the face farthest out: the rim,
///               ordered by angle, closed. Diameter: twice the rim's mean radius.
/// Every point is then moved to the nearest vertex of the detailed surface; a point farther from it
/// than `max_surface_distance_mm` is not on that surface and is left out. A landmark that has no
/// label for a chamber it needs, whose chambers do not meet, or which the surface does not reach
/// is not made: it is listed missing with the reason, never guessed.
#pragma once

#include "libmodel/mesh.h"
#include "libmodel/segment_names.h"
#include "libmodel/volume.h"

#include <Eigen/Core>
#include <string>
#include <vector>

namespace heartsim {

/// The blood labels of the chambers and great arteries; 0 where a label map does not have one.
struct ChamberLabels {
    int left_atrium = 0, left_ventricle = 0, right_atrium = 0, right_ventricle = 0, aorta = 0, pulmonary_artery = 0;
};

/// The chambers' labels as their segment names say ("left ventricle blood pool", "LV", "right
/// atrium", "aorta", "pulmonary artery"); a name with a muscle word is no chamber's blood. HVSMR
/// 2016's "blood pool" names none.
ChamberLabels chamber_labels_from_names(const SegmentNames& names);

enum class LandmarkKind { groove, course, ring };

/// "groove", "course", "ring".
const char* to_string(LandmarkKind kind);
/// The kind named `text`; throws InputError for another word.
LandmarkKind parse_landmark_kind(const std::string& text);

struct Landmark {
    std::string name;                     ///< e.g. "lad_course", "mitral_ring" (landmark_names())
    LandmarkKind kind = LandmarkKind::groove;
    std::string between;                  ///< the two bloods it lies between: "left ventricle, right ventricle"
    /// On the detailed surface, world LPS mm. A groove: its vertices, in no order. A course: in
    /// order along the artery. A ring: in order around its centre, closed (last joins first).
    std::vector<Eigen::Vector3d> points;
    double length_mm = 0.0;               ///< a course's length; a ring's perimeter; 0 for a groove
    Eigen::Vector3d centre{0, 0, 0};      ///< ring: centre of the orifice (label map, not moved)
    Eigen::Vector3d normal{0, 0, 0};      ///< ring: unit normal of its plane, from the first blood to the second
    double diameter_mm = 0.0;             ///< ring: twice the rim's mean radius about the centre
    /// The farthest a point was moved from where the label map put it to reach the surface, mm.
    double surface_distance_mm = 0.0;
    /// The share of the label map's points the surface reached (the others are left out), (0, 1].
    double coverage = 1.0;
    bool closed() const { return kind == LandmarkKind::ring; }
};

/// A landmark that could not be made, and why.
struct MissingLandmark {
    std::string name;
    std::string reason;
};

struct Landmarks {
    std::vector<Landmark> found;
    std::vector<MissingLandmark> missing;
    /// The landmark named `name`, or nullptr.
    const Landmark* find(const std::string& name) const;
};

/// Every landmark's name, in the order find_landmarks gives them: the grooves
/// (interventricular_anterior_groove, interventricular_posterior_groove, right_av_groove,
/// left_av_groove), the courses (lad_course, rca_course, lcx_course), the rings (tricuspid_ring,
/// mitral_ring, aortic_ring, pulmonary_ring).
const std::vector<std::string>& landmark_names();

struct LandmarkOptions {
    double groove_band_mm = 1.0;          ///< |d_a − d_b| at most this on a groove
    double groove_reach_mm = 12.0;        ///< both distances at most this on a groove
    double av_plane_reach_mm = 12.0;      ///< an atrioventricular groove's vertices at most this far from its valve's plane
    double course_step_mm = 2.0;          ///< spacing of a course's points
    double min_course_mm = 20.0;          ///< a shorter course is a fragment of its groove: missing
    int ring_sectors = 48;                ///< angular sectors of a ring's rim
    double max_surface_distance_mm = 2.0; ///< farther from the surface: not on it, left out
};

/// The landmarks of `volume` on `surface` (triangles counter-clockwise seen from outside; its
/// normals are computed when absent). A landmark whose chambers `chambers` does not name is
/// missing with `unlabelled_reason` (e.g. "HVSMR 2016 labels one blood pool for every chamber"),
/// or a reason of its own when that is empty.
Landmarks find_landmarks(const LabelVolume& volume, const ChamberLabels& chambers, const TriangleMesh& surface,
                         const LandmarkOptions& options = {}, const std::string& unlabelled_reason = "");

/// Every landmark missing for `reason` (no surface to put them on, a label map with no chambers).
Landmarks missing_landmarks(const std::string& reason);

/// The exact Euclidean distance, mm, from each voxel centre of `geometry` to the nearest voxel
/// centre where `inside` is non-zero (0 there; +infinity where no voxel is inside): the square
/// root of feature_transform's squared distances (walls.h), with each axis' spacing (the grid's
/// direction is taken as a rotation). i fastest. Throws InputError, as feature_transform does,
/// for more than 2³¹ − 1 voxels or an `inside` of another size.
std::vector<float> distance_map(const VolumeGeometry& geometry, const std::vector<std::uint8_t>& inside);

}  // namespace heartsim
