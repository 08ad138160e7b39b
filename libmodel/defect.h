/// @file defect.h
/// @brief A septal defect carved into a label map: a round opening of a chosen diameter through
/// the wall between two blood pools (a ventricular septal defect between the ventricles, an atrial
/// one between the atria), as the teaching scenarios of a simulator start from "an MRI with a
/// septal defect added".
///
/// The opening is a cylinder through the wall along the wall's local normal: the normal is the
/// direction from the nearest blood on one side to the nearest blood on the other, the cylinder's
/// centre the middle of the wall along it. Wall voxels whose centres lie in the cylinder and that
/// connect to the wall at the centre become blood: each takes the label of the pool on its side
/// (the carved myocardium opens into that pool). Every other voxel keeps its label.
///
/// Where the chambers are labelled apart (label_conventions.h: MM-WHS), the site can be found
/// without a point: the septum is the wall whose middle is equally far from both chambers' blood
/// and at most `max_wall_mm` thick; `site` chooses where on it (DefectSite).
#pragma once

#include "libmodel/progress.h"
#include "libmodel/segment_names.h"
#include "libmodel/volume.h"

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

enum class DefectType {
    vsd,  ///< ventricular septal defect: between the ventricles
    asd,  ///< atrial septal defect: between the atria
};

/// Where on the septum an automatic defect goes (chambers labelled apart). Of the places on the
/// septum's middle surface where the opening fits (a rim of wall all round it):
enum class DefectSite {
    perimembranous,  ///< vsd: nearest the aorta's blood (the membranous septum below the aortic valve)
    muscular,        ///< vsd: halfway between the perimembranous site and the apex (mid-muscular)
    apical,          ///< vsd: farthest from the aorta (apical muscular)
    secundum,        ///< asd: nearest the middle of the atrial septum (the fossa ovalis)
};

/// "vsd"/"asd"; throws OptionError naming {DefectOptions::type} otherwise.
DefectType parse_defect_type(const std::string& text);
/// "perimembranous", "muscular", "apical", "secundum"; throws OptionError otherwise.
DefectSite parse_defect_site(const std::string& text);
std::string to_string(DefectType type);
std::string to_string(DefectSite site);
/// The site used when none is chosen: perimembranous for a vsd, secundum for an asd.
DefectSite default_defect_site(DefectType type);

struct DefectOptions {
    DefectType type = DefectType::vsd;
    double diameter_mm = 10.0;               ///< the opening's diameter
    std::optional<Eigen::Vector3d> at;       ///< a point in or near the septum, LPS mm; none = find it
    std::optional<DefectSite> site;          ///< with `at` unset; none = default_defect_site
    std::vector<int> wall_labels;            ///< the labels the opening goes through (myocardium)
    std::vector<int> blood_labels;           ///< every blood label the wall may separate
    /// The two pools the opening must join (left and right ventricle, or atrium); 0 and 0 where the
    /// volume does not tell them apart (then any two blood labels, or one pool on both sides).
    int side_a = 0, side_b = 0;
    int aorta = 0;                           ///< the aorta's blood label, for the perimembranous site (0: none)
    double max_wall_mm = 20.0;               ///< the thickest wall taken for a septum
    double search_mm = 5.0;                  ///< how far from `at` the wall may be
    /// Unlabelled voxels (0) this thick between the wall and a pool are a seam of the
    /// segmentation, not the outside: the wall is taken to reach the pool across them, and those
    /// in the opening open with it.
    double gap_mm = 1.5;
};

struct DefectReport {
    DefectType type = DefectType::vsd;
    std::optional<DefectSite> site;          ///< the automatic site, if one was found
    Eigen::Vector3d centre{0, 0, 0};         ///< the opening's centre, mid-wall, LPS mm
    Eigen::Vector3d normal{0, 0, 1};         ///< its axis, from side a's pool to side b's, LPS
    double diameter_mm = 0.0;                ///< requested
    /// The opening's equivalent diameter 2·sqrt(area/π): its area is that of the clear passage,
    /// the lines parallel to the axis (a quarter voxel apart) that cross the wall's slab without
    /// meeting wall, connected to the axis.
    double measured_diameter_mm = 0.0;
    double wall_thickness_mm = 0.0;          ///< the wall's thickness along the axis at the centre
    std::size_t voxels_carved = 0;
    int label_a = 0, label_b = 0;            ///< the blood labels on the two sides
    /// The two pools connect through the opening: a flood fill through blood (6-connected) from
    /// side a's pool at the axis reaches side b's.
    bool connected = false;
    double distance_to_aorta_mm = -1.0;      ///< from the centre to the aorta's blood (automatic vsd sites)
    std::size_t sites_tried = 0;             ///< automatic: places on the septum tried before one fitted
    double seconds = 0.0;
};

/// Carves the defect into `volume` (labels changed in place; every voxel outside the opening
/// unchanged). `names` only name labels in messages. Throws InputError, changing nothing, when
/// there is no wall near `at`, the wall there is not between two blood regions (or not between
/// side_a's and side_b's), it is thicker than max_wall_mm, the opening does not fit (the
/// message says the largest that does), or no automatic site fits; OptionError for a diameter
/// that is not positive, or an automatic site without chambers labelled apart.
DefectReport carve_defect(LabelVolume& volume, const DefectOptions& options, const SegmentNames& names = {},
                          Progress& progress = null_progress());

}  // namespace heartsim
