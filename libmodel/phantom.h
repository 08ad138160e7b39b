/// @file phantom.h
/// @brief Synthetic label maps we generate ourselves: the bundled two-ventricle heart with a
/// configurable ventricular septal defect (Sørensen & Mosegaard's teaching cases), and analytic shapes
/// (sphere, thick shell) for accuracy tests and benchmarks. Labels follow HVSMR:
/// 0 background, 1 myocardium, 2 blood pool.
#pragma once

#include "libmodel/volume.h"

#include <string>

namespace heartsim {

enum class PhantomShape { heart, sphere, shell };

/// Parses "heart", "sphere", "shell"; throws InputError otherwise.
PhantomShape parse_phantom_shape(const std::string& name);

struct PhantomOptions {
    PhantomShape shape = PhantomShape::heart;
    double voxel_mm = 1.0;        ///< isotropic voxel size, mm
    int size = 0;                 ///< if > 0: voxels along the longest axis (voxel_mm is derived)
    double margin_mm = 4.0;       ///< background around the shape, mm

    // Heart: a left ventricle (truncated prolate ellipsoid, long axis +z from apex to base) and
    // a right ventricle wrapped around its septal side (patient's right, −x in LPS).
    double lv_radius_mm = 18.0;   ///< LV cavity short semi-axis, mm
    double lv_length_mm = 40.0;   ///< LV cavity long semi-axis (apex to equator), mm
    double wall_mm = 8.0;         ///< LV wall and septum thickness, mm
    double rv_wall_mm = 4.0;      ///< RV free-wall thickness, mm
    double vsd_diameter_mm = 8.0; ///< ventricular septal defect diameter, mm; 0 = intact septum
    double vsd_position = 0.7;    ///< VSD height along the septum: 0 apex, 1 base

    // Sphere and shell.
    double radius_mm = 20.0;      ///< sphere radius, or shell outer radius, mm
    double inner_radius_mm = 12.0;///< shell inner radius, mm (the inside is label 2)
};

/// Builds the phantom. Throws InputError for inconsistent options (non-positive sizes, a VSD
/// wider than the septum is tall, inner radius not below the outer one), naming the option.
LabelVolume make_phantom(const PhantomOptions& options);

}  // namespace heartsim
