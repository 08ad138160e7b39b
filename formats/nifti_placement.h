/// @file nifti_placement.h
/// @brief Private to formats/volume_io.cpp: where a NIfTI file's qform and sform put the grid, and
/// how far apart the two are. Both may be set, and they may disagree. ITK's NiftiImageIO picks one
/// (itkNiftiImageIO.cxx, SetImageIOOrientationFromNIfTI: the ITK 5.2 we build with, measured by
/// test_volume_io, and the newer ITK inside 3D Slicer 5): the sform when its columns are a
/// rotation times a scaling and either the qform code is 0 or the sform code is 1 (scanner
/// anatomy) or the two agree within 1e-4; otherwise the qform. heartprep keeps ITK's choice, so a
/// label map lands where 3D Slicer shows it, and says so when the two disagree: a file that two
/// tools read differently (nibabel takes the sform whenever its code is set) is worth a look.
/// Nothing here touches ITK.
#pragma once

#include "formats/volume_header_checks.h"
#include "libmodel/volume.h"

#include <Eigen/Core>

#include <string>

namespace heartsim::volume_header_checks {

/// Where a NIfTI transform puts the grid, as ITK uses it: LPS origin and unit axes (the spacing
/// comes from pixdim either way).
struct NiftiPlacement {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();               ///< LPS mm
    Eigen::Matrix3d direction = Eigen::Matrix3d::Identity();        ///< unit columns, LPS
    bool rotation = true;  ///< the columns, normalised, are orthonormal (within ITK's 1e-4)
};

/// The qform: NIfTI-1's quaternion (nifti1.h, "METHOD 2"), qfac = pixdim[0]'s sign.
NiftiPlacement qform_placement(const NiftiFields& fields);
/// The sform: rows srow_x, srow_y, srow_z ("METHOD 3"), its columns normalised as ITK does.
NiftiPlacement sform_placement(const NiftiFields& fields);
/// A qform or sform code with its meaning ("1, scanner anatomy").
std::string xform_code_name(int code);

/// How far apart two placements put the grid: at the first voxel, in orientation, and at worst
/// over the volume's eight corner voxels.
struct PlacementDifference {
    double origin_mm = 0.0;
    double angle_degrees = 0.0;
    double largest_mm = 0.0;
    bool mirrored = false;  ///< one is the other's mirror image (opposite handedness)
};

PlacementDifference compare_placements(const NiftiPlacement& first, const NiftiPlacement& second, const VolumeGeometry& grid);

}  // namespace heartsim::volume_header_checks
