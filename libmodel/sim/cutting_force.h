/// @file cutting_force.h
/// @brief The scalpel's cutting resistance: the force the tissue exerts on a blade, from the
/// springs its steps cut (cutting.h). Shared by the cpu solver and the gl backend, which both take
/// each step's constants from blade_step() (the gl backend as uniforms of its blade pass,
/// runtime/gl/shaders/solver_shaders.h `blade_pass`), apply the same double operations to the
/// step's count (next_blade_state) and compute the force from the state with blade_force(), so
/// both backends give the same force. Model and constants: docs/haptics.md "The scalpel's force".
///
/// Units: mm, ms, N; energy mJ (N·mm); toughness N/mm (mJ/mm²).
///
///     const BladeStep step = blade_step(options.cutting_resistance, frame, from, to, length, step_ms);
///     state = next_blade_state(state, step, springs_cut_this_step);
///     const Eigen::Vector3d f = blade_force(state, options.cutting_resistance, length);
///
/// The energy to cut is G_c × the area cut; the area is the springs cut × the area one spring
/// stands for on the swept surface (area_per_spring). The work of the force against the blade's
/// motion pays for it: |f| = G_c · A / d over a stretch of travel d. The energy and the travel are
/// summed over the blade's last λ of travel (an exponential window in distance, λ = 2 lattice
/// spacings: a blade meets the springs a layer at a time, several in one step and none in the
/// next dozen), F = Σ w·E / Σ w·d. The direction is that of the blade midpoint's velocity m̄ and
/// the blade's speed s̄ (the mean of its tip's and end's), both filtered in time (τ):
///
///     f = −min(F, G_c · length) · m̄ · s̄ / max(s̄, v_min)²
///
/// For a blade moving steadily without turning, m̄ = s̄ û and f = −F û. A turning blade feels the
/// share |m̄|/s̄ (none when turned about its middle, which a 3-DOF device could not render). The
/// window in distance does not care how often the pose moved (a 1 kHz device, faster steps: the
/// steps that stand still add nothing), and a blade that stops keeps F until its filtered speed
/// falls below v_min, then lets go as (s̄/v_min)².
#pragma once

#include "libmodel/instrument_pose.h"
#include "libmodel/lattice.h"
#include "libmodel/sim/solver_options.h"

#include <Eigen/Core>

#include <cstddef>

namespace heartsim {

/// The lattice the springs were laid out on: its spacing h and its axes in the world frame.
struct LatticeFrame {
    double spacing_mm = 1.0;
    Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();  ///< columns: the unit lattice axes i, j, k, world frame
};

/// The frame of `lattice`: its spacing and the normalised columns of index_to_world.
LatticeFrame lattice_frame(const Lattice& lattice);

/// S(n) = Σ |n·d| over the 9 spring directions d of the 18-neighbour lattice (one of each ± pair,
/// in units of h: the 3 axes and the 6 face diagonals (±1, 1, 0), …), n a unit normal in the
/// lattice's axes. A plane with normal n crosses S(n)/h² springs per unit area: a spring of
/// direction d·h crosses it when its lower end lies within |n·d|·h of it, and there is one
/// spring of each direction per h³. With |a + b| + |a − b| = 2·max(|a|, |b|), for
/// |n₁| ≥ |n₂| ≥ |n₃|: S = 5|n₁| + 3|n₂| + |n₃|, from 5 (a plane normal to an axis: the axis
/// spring and 4 diagonals per h²) to √35 ≈ 5.92 (n ∝ (5, 3, 1)).
double lattice_crossings(const Eigen::Vector3d& unit_normal_in_lattice_axes);

/// The area one cut spring stands for on a surface with normal `normal` (world frame, any
/// length), mm²: h² / S(Rᵀn̂), R the lattice's axes. h²/5 for a plane normal to a lattice axis.
double area_per_spring(const LatticeFrame& frame, const Eigen::Vector3d& normal);

/// One step's constants of a blade's force: what both backends apply to the step's count.
struct BladeStep {
    double energy_per_spring = 0.0;  ///< G_c · area_per_spring, mJ (N·mm; 0 where the sweep has no area)
    double travel = 0.0;             ///< d, the mean travel of the blade's tip and end over the step, mm
    double distance_keep = 1.0;      ///< exp(−d/λ): the share of the energy and travel sums kept
    Eigen::Vector3d motion_rate = Eigen::Vector3d::Zero();  ///< m = Δm/Δt, the midpoint's velocity, mm/ms
    double travel_rate = 0.0;  ///< s = d/Δt, the blade's speed, mm/ms
    double keep = 0.0;   ///< exp(−Δt/τ): the share of the filtered velocity and speed kept (0 without smoothing)
    double alpha = 1.0;  ///< 1 − keep: the share of this step's
};

/// One hand's blade (all zero while it is lifted).
struct BladeState {
    double energy = 0.0;                                    ///< Σ w·E over the window in distance, mJ
    double travel = 0.0;                                    ///< Σ w·d, mm
    Eigen::Vector3d motion_rate = Eigen::Vector3d::Zero();  ///< m̄, mm/ms
    double travel_rate = 0.0;                               ///< s̄, mm/ms
};

/// A blade just lowered: no energy over one spacing of travel (none without smoothing), so that
/// the first layer of springs it cuts counts as spread over a spacing, as in a steady cut, and not
/// over the fraction of a spacing it moved before reaching them.
BladeState lowered_blade(const CuttingResistance& resistance, const LatticeFrame& frame);

/// The constants for a blade `length_mm` long swept from `from` to `to` in a step of `step_ms`.
BladeStep blade_step(const CuttingResistance& resistance, const LatticeFrame& frame, const InstrumentPose& from, const InstrumentPose& to,
                     double length_mm, double step_ms);

/// One step: energy ← distance_keep · energy + springs · energy_per_spring, travel ←
/// distance_keep · travel + d, and each of m̄ and s̄ ← keep · itself + alpha · the step's; in double,
/// in this order (no fused multiply-add; the gl blade pass evaluates the same operations).
BladeState next_blade_state(const BladeState& previous, const BladeStep& step, std::size_t springs_cut);

/// The force on a blade `length_mm` long, N: −min(energy / travel, G_c · length) · m̄ · s̄ /
/// max(s̄, v_min)² (zero before any travel). The gl backend reads the state back with its forces
/// and calls this on the host.
Eigen::Vector3d blade_force(const BladeState& state, const CuttingResistance& resistance, double length_mm);

}  // namespace heartsim
