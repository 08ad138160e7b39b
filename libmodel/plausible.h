/// @file plausible.h
/// @brief The plausible range of each physical value heartsim reads from a file or a command
/// line (docs/scenario-format.md "Plausible ranges"). Each is far wider than any heart or haptic
/// device needs, so a value outside it is a damaged file, a unit mistake or a typo, and is refused
/// with its name, value and range rather than simulated (a 1e30 mm probe, a 1e-30 g particle).
#pragma once

#include "libmodel/errors.h"

#include <cmath>
#include <sstream>
#include <string>

namespace heartsim::plausible {

struct Range {
    double low, high;
    const char* unit;
    bool contains(double v) const { return v >= low && v <= high; }  // false for NaN
};

inline constexpr Range lattice_spacing_mm{0.01, 100.0, "mm"};
inline constexpr Range voxel_spacing_mm{1e-3, 100.0, "mm"};  ///< a label map's voxels: µm-scale micro-CT to 10 cm
inline constexpr int max_voxels_per_axis = 65536;  ///< a label map's dims, each axis (a 2¹⁶-voxel edge: far beyond any scanner)
inline constexpr Range particle_mass_g{1e-12, 1e4, "g"};
inline constexpr Range density_g_per_mm3{1e-6, 0.1, "g/mm³"};
inline constexpr Range stiffness_n_per_mm{0.0, 1e4, "N/mm"};
inline constexpr Range damping_ratio{0.0, 100.0, ""};
/// A tissue's Poisson's ratio: 1/4 (the lattice's springs alone) up to nearly incompressible.
inline constexpr Range poisson_ratio{0.25, 0.499, ""};
inline constexpr Range rest_length_mm{1e-4, 1e4, "mm"};
inline constexpr Range coordinate_mm{-1e6, 1e6, "mm"};
inline constexpr Range support_damping_n_ms_per_mm{0.0, 1e4, "N·ms/mm"};
inline constexpr Range time_step_ms{1e-9, 100.0, "ms"};
inline constexpr Range gravity_mm_per_ms2{0.0, 1.0, "mm/ms²"};  ///< |g| up to about 100 g
inline constexpr Range drag_per_ms{0.0, 100.0, "1/ms"};
inline constexpr Range semi_axis_mm{1e-3, 500.0, "mm"};
inline constexpr Range device_force_n{1e-6, 1e3, "N"};
inline constexpr Range device_mass_g{1e-3, 1e6, "g"};
/// A septal defect's diameter, as heartprep carves one and a scenario records it: from a
/// pinhole to wider than any heart's septum.
inline constexpr Range defect_diameter_mm{0.5, 60.0, "mm"};
/// A wall heartprep grows around a chamber's or vessel's blood (libmodel/walls.h): from a tenth of a
/// millimetre to beyond any ventricle's wall (a hypertrophied one is about 3 cm).
inline constexpr Range wall_thickness_mm{0.1, 40.0, "mm"};
/// The planners' gestures (heartsim plan-incision and plan-repair): an incision up to 30 cm, the
/// retractors up to 20 cm apart, a blade up to 10 cm deep and from 0.1 mm/s to 10 m/s, stitches up
/// to 3 cm beyond the opening, a patch up to 20 cm across and 1 cm thick. A value outside is a
/// typo or a unit mistake, and a trajectory built from it would be refused or run for ever.
inline constexpr Range incision_length_mm{0.5, 300.0, "mm"};
inline constexpr Range retraction_mm{0.0, 200.0, "mm"};
inline constexpr Range blade_depth_mm{0.1, 100.0, "mm"};
inline constexpr Range blade_speed_mm_per_ms{1e-4, 10.0, "mm/ms"};
inline constexpr Range stitch_rim_mm{0.1, 30.0, "mm"};
inline constexpr Range patch_diameter_mm{0.5, 200.0, "mm"};
inline constexpr Range patch_thickness_mm{0.01, 10.0, "mm"};
inline constexpr Range rim_roughness_mm{0.01, 100.0, "mm"};
/// A conduction zone's arc (plan-repair --zone-half-width, --zone-margin): half-widths up to the
/// whole rim, degrees.
inline constexpr Range zone_half_width_deg{0.1, 180.0, "degrees"};
inline constexpr Range zone_margin_deg{0.0, 180.0, "degrees"};
/// heartprep build's material options: density as typed (g/cm³; within density_g_per_mm3 × 1000 after
/// float rounding: from foam to twice lead), and
/// Young's modulus from a gel (1 Pa) to a stiff plastic (1 GPa).
inline constexpr Range density_g_per_cm3{0.01, 50.0, "g/cm³"};
inline constexpr Range youngs_modulus_kpa{1e-3, 1e6, "kPa"};

/// "name is V unit, outside the plausible range [low, high] unit".
inline std::string outside(const std::string& name, double value, const Range& range) {
    std::ostringstream text;
    const std::string unit = *range.unit ? std::string(" ") + range.unit : std::string();
    text << name << " is " << value << unit << ", outside the plausible range [" << range.low << ", " << range.high << "]" << unit;
    return text.str();
}

/// InputError(`context` + ": " + outside(...)) unless `value` lies in `range`.
inline void require(double value, const Range& range, const std::string& name, const std::string& context) {
    if (!range.contains(value)) throw InputError(context + ": " + outside(name, value, range));
}

}  // namespace heartsim::plausible
