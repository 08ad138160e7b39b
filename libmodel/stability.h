/// @file stability.h
/// @brief The critical time step of explicit (Verlet / central-difference) integration of a
/// spring network: dt_crit = 2 / ω_max, with ω_max² the largest eigenvalue of M⁻¹K at rest;
/// and the stable step with dashpots, drag and support dampers (docs/solver.md "Step policy").
#pragma once

#include <functional>

#include "libmodel/lattice.h"
#include "libmodel/volume_cells.h"

#include <vector>

namespace heartsim {

struct StabilityEstimate {
    /// Largest eigenvalue of M⁻¹K estimated by Lanczos iteration (the largest Ritz value of the
    /// symmetric M^(−1/2) K M^(−1/2), anchored particles removed), 1/ms². A Ritz value is a
    /// Rayleigh quotient and never exceeds the true value: it approaches it from below.
    double max_eigenvalue = 0.0;
    /// 2 / sqrt(max_eigenvalue), ms: the estimate of the critical step.
    double critical_dt_ms = 0.0;
    /// Gershgorin bound (largest absolute row sum of M^(−1/2) K M^(−1/2)): a proven upper bound
    /// on the largest eigenvalue, 1/ms².
    double eigenvalue_bound = 0.0;
    /// 2 / sqrt(eigenvalue_bound), ms: a proven lower bound on the critical step.
    double critical_dt_bound_ms = 0.0;
    int iterations = 0;
    /// The Ritz residual bound |A·y − θ·y| fell below tolerance·θ (then λmax − θ is far smaller).
    bool converged = false;
};

/// Estimates the critical time step of the stiffness at rest: K = k n nᵀ + (t/L)(I − n nᵀ) per
/// spring (t its tension at rest: zero unless the rest state is pre-stressed), plus k_s·I per
/// supported particle; damping ignored. Deterministic: fixed start vector, serial reductions.
/// A network with no free particle or no spring gives infinite steps.
/// `cells`, unless null: the volume term's cells (volume_cells.h), (Δλ/|V₀|)·g gᵀ each at rest, g = ∂V/∂x.
StabilityEstimate estimate_critical_time_step(const Particles& particles, const Springs& springs,
                                              int max_iterations = 300, double tolerance = 1e-6,
                                              const VolumeCells* cells = nullptr);

/// A proven ceiling on the critical step, ms, in one pass over the springs: 2/√ of a proven
/// lower bound on λ_max(M⁻¹K), the largest over free particles of trace(K_ii)/(3 m_i) (the top
/// eigenvalue of a diagonal block bounds it from below, Cauchy interlacing). A stored critical
/// step above it cannot be right: the runtime refuses such a file. Infinite without springs.
/// `cells`, unless null: the volume term's cells add the trace of their blocks (a scenario that
/// declares a Poisson's ratio above 1/4 with a step for its springs alone is refused).
double critical_step_ceiling_ms(const Particles& particles, const Springs& springs, const VolumeCells* cells = nullptr);

/// A proven ceiling on the damped stable step (stable_step_ms), ms, in one pass over the
/// springs: stable_step_ms of lower bounds on λ_K (as critical_step_ceiling_ms) and on λ_C (the
/// largest over free particles of trace(C_ii)/(3 m_i): the particle's spring dashpots and
/// support damper, plus the drag γ). A stored damped step above it is stale or damaged (damping
/// raised without the step recomputed); the scenario reader refuses it.
double damped_step_ceiling_ms(const Particles& particles, const Springs& springs, const std::vector<double>& damping_ratio,
                              double drag_per_ms);
/// The dashpot of a spring of stiffness k between masses m_a and m_b with damping ratio ζ:
/// c = 2ζ√(kμ), μ = m_a m_b / (m_a + m_b), N·ms/mm (docs/scenario-format.md).
double dashpot_coefficient(double stiffness, double mass_a, double mass_b, double damping_ratio);

/// The damping ratio ζ of each material row, for the functions below.
std::vector<double> damping_ratios(const std::vector<Material>& materials);

/// The dashpot c of spring (a, b) of `stiffness`: dashpot_coefficient with ζ the mean of the two
/// particles' rows of `damping_ratio` (a row past its end: 0). The same bits with a and b swapped.
/// One rule for the CPU solver, the GL backend and estimate_damping_eigenvalue.
double spring_dashpot(const Particles& particles, const std::vector<double>& damping_ratio, double stiffness, std::size_t a, std::size_t b);

/// Largest eigenvalue of M^(−1/2) C M^(−1/2), 1/ms, by the same Lanczos iteration: C the damping
/// matrix of the spring dashpots (c n nᵀ per spring, ζ the mean of the two particles' rows of
/// `damping_ratio`, missing rows 0), the support dashpots (c_s per supported particle) and the
/// global drag γ·M. Zero without any damping.
double estimate_damping_eigenvalue(const Particles& particles, const Springs& springs,
                                   const std::vector<double>& damping_ratio, double drag_per_ms);

/// The largest substep h for which Verlet with backward-difference damping is stable in every
/// mode of the linearised network: h² λ_K + 2 h λ_C < 4 (energy argument: M − h²K/4 − hC/2 ≻ 0,
/// with λ_max(h²K + 2hC) ≤ h² λ_K + 2h λ_C by Weyl's inequality). λ_K = max_eigenvalue (1/ms²),
/// λ_C = estimate_damping_eigenvalue (1/ms). Equals the critical step 2/√λ_K without damping;
/// infinite when both are 0.
double stable_step_ms(double max_eigenvalue, double damping_eigenvalue);

/// The range of the step's safety factor (a fraction of the damped critical step), heartprep's
/// option and the scenario reader's check.
inline constexpr double min_safety_factor = 1e-3, max_safety_factor = 0.99;
/// The step policy, one for heartprep (which stores it in /solver) and the solver (which takes
/// what the file gives and derives the rest), docs/solver.md "Step policy".
struct TimeStepLimits {
    double damped_critical_dt_ms = 0.0;  ///< the stable step with dashpots, supports and drag, ms
    double dt_ms = 0.0;                  ///< safety_factor × damped_critical_dt_ms, ms
};

/// The damped critical step from the undamped `critical_dt_ms` (2/√λ_K) and the damping
/// eigenvalue λ_C (stable_step_ms), and the step, `safety_factor` × that. A stored damped step
/// (`stored_damped_dt_ms` > 0) is kept instead, capped at `critical_dt_ms`; then
/// `damping_eigenvalue` (a Lanczos estimate, costly) is not called.
TimeStepLimits time_step_limits(double critical_dt_ms, double stored_damped_dt_ms, double safety_factor,
                                const std::function<double()>& damping_eigenvalue);

/// The limits under explicit mass scaling: the inertia of every particle × `mass_scale` (S ≥ 1),
/// its weight, the dashpots and the drag force unchanged. λ_K of M⁻¹K and λ_C of M^(−½)CM^(−½)
/// both divide by S, so the critical step grows by √S and the damped one solves
/// h²λ_K + 2hλ_C = 4S, λ_K and λ_C recovered from the unscaled `critical_dt_ms` (2/√λ_K) and
/// `damped_critical_dt_ms` (stable_step_ms). S = 1 gives the unscaled limits, the same bits.
/// docs/solver.md "Mass scaling".
struct ScaledTimeSteps {
    double critical_dt_ms = 0.0;
    double damped_critical_dt_ms = 0.0;
};
ScaledTimeSteps scale_time_steps(double critical_dt_ms, double damped_critical_dt_ms, double mass_scale);

/// The substeps of one step of `dt_ms`: the fewest equal ones no longer than `limit_ms` (the
/// safety factor × the damped critical step), 1 when `subdivide` is false or the limit is not
/// finite. Throws InputError when that needs more than `max_substeps`. One rule for both backends.
int substeps_for_step(double dt_ms, double limit_ms, bool subdivide, int max_substeps);

/// The step under mass scaling, from the step at S = 1 (`unscaled_dt_ms`): a step that fits in
/// one substep at S = 1 (≤ safety × the unscaled damped step: heartprep's policy) grows with the
/// stable step, × scaled_damped / unscaled_damped (√S where stiffness limits the step, up to S
/// where damping does), so that each substep still covers as much as the stability bound allows
/// and a simulated second takes that many times fewer substeps; a longer
/// step stays as it is and takes fewer substeps (substeps_for_step). S = 1: `unscaled_dt_ms`.
double scaled_step_ms(double unscaled_dt_ms, double safety_factor, double unscaled_damped_dt_ms, double scaled_damped_dt_ms);

/// The range `heartsim run --mass-scale` and the readers of recordings and states take.
inline constexpr double min_mass_scale = 1.0, max_mass_scale = 1024.0;
inline bool valid_mass_scale(double mass_scale) { return mass_scale >= min_mass_scale && mass_scale <= max_mass_scale; }

}  // namespace heartsim
