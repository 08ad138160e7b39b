/// @file stability.h
/// @brief The critical time step of explicit (Verlet / central-difference) integration of a
/// spring network: dt_crit = 2 / ω_max, with ω_max² the largest eigenvalue of M⁻¹K at rest.
#pragma once

#include "lattice.h"

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
StabilityEstimate estimate_critical_time_step(const Particles& particles, const Springs& springs,
                                              int max_iterations = 300, double tolerance = 1e-6);

}  // namespace heartsim
