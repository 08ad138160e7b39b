/// @file walls.h
/// @brief Walls grown where a label map has only blood. Many segmentations label a chamber's
/// blood but not its wall (MM-WHS labels the left ventricle's wall alone; HVSMR's myocardium
/// leaves the atria and great vessels bare): built as they are, the heart is the labelled wall
/// and nothing else. `grow_walls` lines each named blood structure's surface, where it faces
/// background, with a wall of a given thickness in mm, grown outward into background only.
///
/// - Thickness is Euclidean in mm on the voxel grid's own spacing (anisotropic grids included):
///   a background voxel joins a structure's wall when its centre lies within the thickness of
///   that structure's blood surface, taken as a quarter of the mean spacing beyond the nearest
///   blood voxel's centre. The nearest blood voxel comes from an exact separable Euclidean feature
///   transform (Felzenszwalb & Huttenlocher, "Distance transforms of sampled functions", Theory of
///   Computing 8, 2012).
/// - Only background (label 0) is taken: no other label's voxel, so where two blood pools touch
///   (a valve plane, an arterial root) the opening stays open, and a labelled wall stays as it is.
/// - A voxel two structures claim goes to the nearer one (ties: the first listed), so two walls
///   that meet (the atria across an unlabelled interatrial septum) become one wall.
#pragma once

#include "libmodel/progress.h"
#include "libmodel/volume.h"

#include <Eigen/Core>
#include <array>
#include <cstdint>

#include <string>
#include <vector>

namespace heartsim {

/// One structure whose wall is grown.
struct WallStructure {
    std::string name;               ///< what the wall is, for reports: "right ventricle free wall"
    std::vector<int> blood_labels;  ///< the blood it lines: label values of the map
    double thickness_mm = 2.0;      ///< wall thickness outward from the blood's surface, mm (> 0)
    int wall_label = 0;             ///< label its grown voxels get: must not occur in the map, not 0
};

/// The wall thicknesses heartprep grows by default, mm: typical adult values (docs/user-guide.md
/// "Walls grown where the labels show only blood" gives the sources). Each is a heartprep build option.
struct WallThicknesses {
    double right_ventricle = 3.5;   ///< the right ventricle's free wall (normal adult: under 5 mm)
    double left_ventricle = 3.5;    ///< the left ventricle's blood where its labelled wall leaves it bare
    double atria = 2.0;             ///< each atrium's wall (and the interatrial septum, where unlabelled)
    double aorta = 2.0;             ///< the aorta's wall
    double pulmonary_artery = 1.5;  ///< the pulmonary trunk's wall
    double blood_pool = 2.0;        ///< one blood label for every chamber and vessel (HVSMR 2016)
};

/// What growing did, per structure (in the order given).
struct GrownWall {
    std::size_t voxels = 0;                 ///< voxels grown
    double volume_mm3 = 0.0;                ///< their volume, mm³
    /// Faces between the structure's blood voxels and background voxels before growing: the
    /// blood surface that faced nothing.
    std::size_t faces_to_background = 0;
    std::size_t blood_faces = 0;            ///< every face of its blood voxels towards another label or background
};

struct WallGrowthReport {
    std::vector<GrownWall> walls;  ///< one per structure
    double seconds = 0.0;
};

/// Grows each structure's wall into `volume`'s background (label 0), writing the structures'
/// wall labels there. A structure whose blood labels do not occur grows nothing.
/// Throws InputError for a thickness that is not a positive finite number (or outside
/// plausible::wall_thickness_mm), a wall label that is 0, repeated, or occurs in the map.
WallGrowthReport grow_walls(LabelVolume& volume, const std::vector<WallStructure>& structures,
                            Progress& progress = null_progress());

/// Squared Euclidean distance transform with features, exact, on a grid of `dims` voxels of
/// `spacing` mm (i fastest): for every voxel, the squared distance in mm² to the nearest voxel
/// where `feature` is non-zero (between centres), and that voxel's linear index in `nearest`
/// (−1 and +infinity where there is none). At most 2³¹ − 1 voxels. Separable: one pass per axis (Felzenszwalb &
/// Huttenlocher 2012), parallel over lines.
void feature_transform(const std::array<int, 3>& dims, const Eigen::Vector3d& spacing, const std::vector<std::uint8_t>& feature,
                       std::vector<float>& squared_distance, std::vector<std::int32_t>& nearest);

}  // namespace heartsim
