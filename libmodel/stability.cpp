#include "libmodel/stability.h"

#include "libmodel/errors.h"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace heartsim {

namespace {

struct SpringDirection {
    Eigen::Vector3d unit;  ///< from first to second particle at rest
    double stiffness;
    double tension_over_length = 0.0;  ///< t/L at rest, N/mm (0 for an unstressed spring)
};

struct Lanczos {
    double value = 0.0;
    int iterations = 0;
    bool converged = false;
};

/// Largest eigenvalue of a symmetric positive semi-definite operator on 3 values per particle,
/// `multiply(v, w)`: w = A v; particles whose `weight` is 0 (anchored) are left out of the start
/// vector. Lanczos: the Krylov space of a power iteration, but the largest Ritz value converges
/// in tens of steps where the power iteration's Rayleigh quotient needs hundreds (the top of a
/// lattice's spectrum is a dense band). Plain three-term recurrence, no reorthogonalisation:
/// lost orthogonality only duplicates converged Ritz values, it does not move the largest one.
/// The start vector is random but seeded: the highest mode of a lattice alternates in sign,
/// which a smooth start would barely contain. A Ritz value is a Rayleigh quotient: it never
/// exceeds the true value and approaches it from below.
template <class Multiply>
Lanczos largest_eigenvalue(const std::vector<double>& weight, Multiply&& multiply, int max_iterations, double tolerance) {
    Lanczos result;
    const std::size_t n = weight.size();
    std::mt19937_64 generator(20061);
    std::uniform_real_distribution<double> uniform(-1.0, 1.0);
    Eigen::VectorXd q(3 * n), previous = Eigen::VectorXd::Zero(3 * n), w(3 * n);
    for (Eigen::Index i = 0; i < q.size(); ++i) q[i] = uniform(generator) * (weight[std::size_t(i / 3)] > 0);
    if (q.norm() == 0) return result;
    q.normalize();
    std::vector<double> alpha, beta;  // the tridiagonal matrix T: diagonal and off-diagonal
    double beta_previous = 0.0;
    for (int iteration = 1; iteration <= max_iterations; ++iteration) {
        multiply(q, w);
        const double a = q.dot(w);
        w -= a * q + beta_previous * previous;
        alpha.push_back(a);
        const double b = w.norm();
        result.iterations = iteration;

        // Largest eigenvalue of T and its residual bound β·|last component of its eigenvector|.
        const Eigen::Index m = Eigen::Index(alpha.size());
        Eigen::MatrixXd t = Eigen::MatrixXd::Zero(m, m);
        for (Eigen::Index i = 0; i < m; ++i) {
            t(i, i) = alpha[std::size_t(i)];
            if (i + 1 < m) t(i, i + 1) = t(i + 1, i) = beta[std::size_t(i)];
        }
        Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(t);
        const double ritz = solver.eigenvalues()[m - 1];
        const double residual = b * std::abs(solver.eigenvectors()(m - 1, m - 1));
        result.value = ritz;
        if (residual <= tolerance * std::abs(ritz) || b <= 1e-14 * std::abs(ritz)) {
            result.converged = true;
            break;
        }
        beta.push_back(b);
        previous = q;
        q = w / b;
        beta_previous = b;
    }
    return result;
}

/// M^(−1/2) per particle; anchored particles have infinite mass (0: their rows vanish).
std::vector<double> inverse_sqrt_masses(const Particles& particles) {
    std::vector<double> inverse_sqrt_mass(particles.size(), 0.0);
    for (std::size_t i = 0; i < particles.size(); ++i)
        if (!particles.anchored[i] && particles.mass[i] > 0) inverse_sqrt_mass[i] = 1.0 / std::sqrt(double(particles.mass[i]));
    return inverse_sqrt_mass;
}

/// Spring s from its first particle to its second at rest, and its length.
Eigen::Vector3d rest_vector(const Particles& particles, const Springs& springs, std::size_t s) {
    const auto [a, b] = springs.pairs[s];
    const auto& xa = particles.rest_position[std::size_t(a)];
    const auto& xb = particles.rest_position[std::size_t(b)];
    return {double(xb[0]) - xa[0], double(xb[1]) - xa[1], double(xb[2]) - xa[2]};
}

/// Spring s at rest: its direction, stiffness and, when the rest state is pre-stressed
/// (supports.h), t/L with t = k (L − L₀) its tension; a rest length within float rounding (1e-6
/// relative) of the rest distance is unstressed.
SpringDirection spring_direction(const Particles& particles, const Springs& springs, std::size_t s) {
    const Eigen::Vector3d d = rest_vector(particles, springs, s);
    const double length = d.norm();
    SpringDirection direction{length > 0 ? Eigen::Vector3d(d / length) : Eigen::Vector3d::Zero(), double(springs.stiffness[s])};
    const double stretch = length - double(springs.rest_length[s]);
    if (length > 0 && std::abs(stretch) > 1e-6 * length) direction.tension_over_length = direction.stiffness * stretch / length;
    return direction;
}

/// w += the springs' part of M^(−1/2) A M^(−1/2) v for A assembled from one 3×3 block per spring:
/// `block(s, r)` is that block applied to the scaled relative vector r = v_a/√m_a − v_b/√m_b.
template <class Block>
void add_spring_blocks(const Springs& springs, const std::vector<double>& inverse_sqrt_mass, const Eigen::VectorXd& v, Eigen::VectorXd& w,
                       Block&& block) {
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const auto [a, b] = springs.pairs[s];
        const double ma = inverse_sqrt_mass[std::size_t(a)], mb = inverse_sqrt_mass[std::size_t(b)];
        const Eigen::Vector3d force = block(s, Eigen::Vector3d(v.segment<3>(3 * a) * ma - v.segment<3>(3 * b) * mb));
        w.segment<3>(3 * a) += force * ma;
        w.segment<3>(3 * b) -= force * mb;
    }
}

}  // namespace

StabilityEstimate estimate_critical_time_step(const Particles& particles, const Springs& springs,
                                              int max_iterations, double tolerance, const VolumeCells* cells) {
    const std::size_t n = particles.size();
    StabilityEstimate estimate;
    estimate.critical_dt_ms = estimate.critical_dt_bound_ms = std::numeric_limits<double>::infinity();

    const std::vector<double> inverse_sqrt_mass = inverse_sqrt_masses(particles);
    std::vector<SpringDirection> direction(springs.size());
    std::vector<double> row_bound(3 * n, 0.0);
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const auto [a, b] = springs.pairs[s];
        // A spring stretched at rest adds the geometric stiffness (t/L)(I − n nᵀ).
        direction[s] = spring_direction(particles, springs, s);
        // Gershgorin: row (i, r) of the 3×3 block k n nᵀ has absolute sum k |n_r| Σ|n_c|, in the
        // diagonal block scaled by 1/m_i and in the off-diagonal block by 1/sqrt(m_i m_j).
        const Eigen::Vector3d& u = direction[s].unit;
        const double k = direction[s].stiffness;
        const double ma = inverse_sqrt_mass[std::size_t(a)], mb = inverse_sqrt_mass[std::size_t(b)];
        const double g = direction[s].tension_over_length;
        for (int r = 0; r < 3; ++r) {
            // |(t/L)(δ_rc − n_r n_c)| summed over c is at most |t/L|·(1 + |n_r| Σ|n_c|).
            const double block = k * std::abs(u[r]) * u.cwiseAbs().sum() + std::abs(g) * (1.0 + std::abs(u[r]) * u.cwiseAbs().sum());
            row_bound[3 * std::size_t(a) + r] += block * (ma * ma + ma * mb);
            row_bound[3 * std::size_t(b) + r] += block * (mb * mb + ma * mb);
        }
    }
    // Supports: a diagonal k_s/m per free particle.
    if (particles.supported())
        for (std::size_t i = 0; i < n; ++i)
            for (int r = 0; r < 3; ++r)
                row_bound[3 * i + std::size_t(r)] += double(particles.support_stiffness[i]) * inverse_sqrt_mass[i] * inverse_sqrt_mass[i];
    // The volume term at rest: (Δλ/|V₀|) g gᵀ per cell, g the volume's gradient at the rest positions.
    std::vector<std::array<double, 24>> cell_gradient(cells ? cells->size() : 0);
    for (std::size_t c = 0; c < cell_gradient.size(); ++c) {
        const auto& corner = cells->corner[c];
        double g[8][3];
        rest_cell_volume12(particles, corner, g);
        const double scale = std::sqrt(cells->modulus[c] / std::abs(cells->rest_volume[c])) / 12.0;  // g in twelfths
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k) cell_gradient[c][std::size_t(3 * q + k)] = scale * g[q][k] * inverse_sqrt_mass[std::size_t(corner[std::size_t(q)])];
        // Gershgorin: row (a, r) of the scaled block sums |ĝ_ar| Σ|ĝ|.
        double sum = 0;
        for (double v : cell_gradient[c]) sum += std::abs(v);
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k)
                row_bound[3 * std::size_t(corner[std::size_t(q)]) + std::size_t(k)] += std::abs(cell_gradient[c][std::size_t(3 * q + k)]) * sum;
    }
    for (double row : row_bound) estimate.eigenvalue_bound = std::max(estimate.eigenvalue_bound, row);
    if (estimate.eigenvalue_bound <= 0.0) return estimate;
    estimate.critical_dt_bound_ms = 2.0 / std::sqrt(estimate.eigenvalue_bound);

    // Lanczos on A = M^(−1/2) K M^(−1/2) (largest_eigenvalue below).
    auto multiply = [&](const Eigen::VectorXd& v, Eigen::VectorXd& w) {
        w.setZero();
        add_spring_blocks(springs, inverse_sqrt_mass, v, w, [&](std::size_t s, const Eigen::Vector3d& relative) -> Eigen::Vector3d {
            const Eigen::Vector3d& unit = direction[s].unit;
            return direction[s].stiffness * unit * unit.dot(relative) +
                   direction[s].tension_over_length * (relative - unit * unit.dot(relative));
        });
        if (particles.supported())
            for (std::size_t i = 0; i < n; ++i)
                w.segment<3>(3 * Eigen::Index(i)) += double(particles.support_stiffness[i]) * inverse_sqrt_mass[i] * inverse_sqrt_mass[i] *
                                                     v.segment<3>(3 * Eigen::Index(i));
        for (std::size_t c = 0; c < cell_gradient.size(); ++c) {
            const auto& corner = cells->corner[c];
            double along = 0;
            for (int q = 0; q < 8; ++q)
                for (int k = 0; k < 3; ++k) along += cell_gradient[c][std::size_t(3 * q + k)] * v[3 * Eigen::Index(corner[std::size_t(q)]) + k];
            for (int q = 0; q < 8; ++q)
                for (int k = 0; k < 3; ++k) w[3 * Eigen::Index(corner[std::size_t(q)]) + k] += cell_gradient[c][std::size_t(3 * q + k)] * along;
        }
    };
    const Lanczos lanczos = largest_eigenvalue(inverse_sqrt_mass, multiply, max_iterations, tolerance);
    estimate.max_eigenvalue = lanczos.value;
    estimate.iterations = lanczos.iterations;
    estimate.converged = lanczos.converged;
    if (estimate.max_eigenvalue > 0) estimate.critical_dt_ms = 2.0 / std::sqrt(estimate.max_eigenvalue);
    return estimate;
}

namespace {

/// max over free particles of (trace[i] + 3·own[i]) / (3 m_i), with `trace` the summed spring
/// terms of each particle's 3×3 diagonal block and `own` its support's isotropic term (absent:
/// none): the largest eigenvalue of one diagonal block of M^(−½)AM^(−½) is at least its mean,
/// and bounds λ_max(M⁻¹A) from below (Cauchy interlacing).
double diagonal_block_floor(const Particles& particles, const std::vector<double>& trace, const std::vector<float>& own) {
    double lower = 0.0;
    for (std::size_t i = 0; i < particles.size(); ++i) {
        if (particles.anchored[i] || !(particles.mass[i] > 0)) continue;
        const double support = own.empty() ? 0.0 : 3.0 * double(own[i]);
        lower = std::max(lower, (trace[i] + support) / (3.0 * double(particles.mass[i])));
    }
    return lower;
}

/// A lower bound on λ_max(M⁻¹K), the volume term's cells (unless null) counted.
double stiffness_eigenvalue_floor(const Particles& particles, const Springs& springs, const VolumeCells* cells = nullptr) {
    // Trace of each particle's 3×3 diagonal block of K: k + 2t/L per spring (the trace of
    // k n nᵀ + (t/L)(I − n nᵀ)) plus 3 k_s for its support, plus (Δλ/|V₀|)·|∂V/∂x_c|² per cell
    // it is corner c of (the trace of its block of (Δλ/|V₀|) g gᵀ at rest).
    std::vector<double> trace(particles.size(), 0.0);
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const SpringDirection d = spring_direction(particles, springs, s);
        const double block = d.stiffness + 2.0 * d.tension_over_length;
        trace[std::size_t(springs.pairs[s][0])] += block;
        trace[std::size_t(springs.pairs[s][1])] += block;
    }
    for (std::size_t c = 0; cells && c < cells->size(); ++c) {
        const auto& corner = cells->corner[c];
        double g[8][3];
        rest_cell_volume12(particles, corner, g);
        const double scale = cells->modulus[c] / (144.0 * std::abs(cells->rest_volume[c]));  // g in twelfths
        for (int q = 0; q < 8; ++q) trace[std::size_t(corner[std::size_t(q)])] += scale * (g[q][0] * g[q][0] + g[q][1] * g[q][1] + g[q][2] * g[q][2]);
    }
    const std::vector<float> none;
    return diagonal_block_floor(particles, trace, particles.supported() ? particles.support_stiffness : none);
}

}  // namespace

double critical_step_ceiling_ms(const Particles& particles, const Springs& springs, const VolumeCells* cells) {
    const double lower = stiffness_eigenvalue_floor(particles, springs, cells);
    return lower > 0 ? 2.0 / std::sqrt(lower) : std::numeric_limits<double>::infinity();
}

double damped_step_ceiling_ms(const Particles& particles, const Springs& springs, const std::vector<double>& damping_ratio,
                              double drag_per_ms) {
    // Trace of each particle's diagonal block of C: c per spring dashpot (c n nᵀ), 3 c_s for its
    // support damper; M^(−½)(γM)M^(−½) = γI adds γ to every block's eigenvalues.
    std::vector<double> trace(particles.size(), 0.0);
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const auto [a, b] = springs.pairs[s];
        const double c = spring_dashpot(particles, damping_ratio, double(springs.stiffness[s]), std::size_t(a), std::size_t(b));
        trace[std::size_t(a)] += c;
        trace[std::size_t(b)] += c;
    }
    const double lower = diagonal_block_floor(particles, trace, particles.support_damping);
    return stable_step_ms(stiffness_eigenvalue_floor(particles, springs), lower + std::max(0.0, drag_per_ms));
}

double dashpot_coefficient(double stiffness, double mass_a, double mass_b, double damping_ratio) {
    const double reduced = mass_a * mass_b / (mass_a + mass_b);
    return 2.0 * damping_ratio * std::sqrt(stiffness * reduced);
}

std::vector<double> damping_ratios(const std::vector<Material>& materials) {
    std::vector<double> ratios;
    for (const Material& material : materials) ratios.push_back(material.damping_ratio);
    return ratios;
}

double spring_dashpot(const Particles& particles, const std::vector<double>& damping_ratio, double stiffness, std::size_t a, std::size_t b) {
    auto ratio = [&](std::size_t i) {
        const auto row = std::size_t(particles.material[i]);
        return row < damping_ratio.size() ? damping_ratio[row] : 0.0;
    };
    return dashpot_coefficient(stiffness, double(particles.mass[a]), double(particles.mass[b]), 0.5 * (ratio(a) + ratio(b)));
}

double estimate_damping_eigenvalue(const Particles& particles, const Springs& springs,
                                   const std::vector<double>& damping_ratio, double drag_per_ms) {
    const std::size_t n = particles.size();
    const std::vector<double> inverse_sqrt_mass = inverse_sqrt_masses(particles);
    const double drag = std::max(0.0, drag_per_ms);
    if (std::none_of(inverse_sqrt_mass.begin(), inverse_sqrt_mass.end(), [](double m) { return m > 0; })) return 0.0;
    // Per spring: its dashpot c and unit direction at rest.
    std::vector<double> dashpot(springs.size(), 0.0);
    std::vector<Eigen::Vector3d> unit(springs.size(), Eigen::Vector3d::Zero());
    bool damped = false;
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const auto [a, b] = springs.pairs[s];
        const Eigen::Vector3d d = rest_vector(particles, springs, s);
        if (d.norm() > 0) unit[s] = d.normalized();
        dashpot[s] = spring_dashpot(particles, damping_ratio, double(springs.stiffness[s]), std::size_t(a), std::size_t(b));
        damped = damped || dashpot[s] > 0;
    }
    std::vector<double> support(n, 0.0);
    if (!particles.support_damping.empty())
        for (std::size_t i = 0; i < n; ++i) {
            support[i] = double(particles.support_damping[i]) * inverse_sqrt_mass[i] * inverse_sqrt_mass[i];
            damped = damped || support[i] > 0;
        }
    if (!damped) return drag;
    auto multiply = [&](const Eigen::VectorXd& v, Eigen::VectorXd& w) {
        w.setZero();
        add_spring_blocks(springs, inverse_sqrt_mass, v, w, [&](std::size_t s, const Eigen::Vector3d& relative) -> Eigen::Vector3d {
            return dashpot[s] * unit[s] * unit[s].dot(relative);
        });
        for (std::size_t i = 0; i < n; ++i) w.segment<3>(3 * Eigen::Index(i)) += support[i] * v.segment<3>(3 * Eigen::Index(i));
    };
    return largest_eigenvalue(inverse_sqrt_mass, multiply, 300, 1e-6).value + drag;
}

double stable_step_ms(double max_eigenvalue, double damping_eigenvalue) {
    const double lambda = std::max(0.0, max_eigenvalue), b = std::max(0.0, damping_eigenvalue);
    if (lambda == 0 && b == 0) return std::numeric_limits<double>::infinity();
    return 4.0 / (b + std::sqrt(b * b + 4.0 * lambda));  // the root of λh² + 2bh − 4, without cancellation
}

TimeStepLimits time_step_limits(double critical_dt_ms, double stored_damped_dt_ms, double safety_factor,
                                const std::function<double()>& damping_eigenvalue) {
    TimeStepLimits limits;
    limits.damped_critical_dt_ms = stored_damped_dt_ms > 0 ? std::min(stored_damped_dt_ms, critical_dt_ms)
                                                           : stable_step_ms(4.0 / (critical_dt_ms * critical_dt_ms), damping_eigenvalue());
    limits.dt_ms = safety_factor * limits.damped_critical_dt_ms;
    return limits;
}

int substeps_for_step(double dt_ms, double limit, bool subdivide, int max_substeps) {
    if (!subdivide || !std::isfinite(limit) || !(limit > 0)) return 1;
    // In double first: a huge dt over a tiny limit must not overflow the int.
    const double needed = std::ceil(dt_ms / limit * (1 - 1e-12));
    if (!(needed <= double(max_substeps)))
        throw InputError("solver: the time step of " + std::to_string(dt_ms) + " ms needs " +
                         (std::isfinite(needed) ? std::to_string(std::llround(needed)) : std::string("unboundedly many")) +
                         " substeps of the stable " + std::to_string(limit) + " ms (at most " + std::to_string(max_substeps) +
                         "): use a shorter step or rebuild the scenario");
    return std::max(1, int(needed));
}

double scaled_step_ms(double unscaled_dt_ms, double safety_factor, double unscaled_damped_dt_ms, double scaled_damped_dt_ms) {
    if (scaled_damped_dt_ms == unscaled_damped_dt_ms || !std::isfinite(scaled_damped_dt_ms) || !std::isfinite(unscaled_damped_dt_ms) ||
        !(unscaled_damped_dt_ms > 0) || !(unscaled_dt_ms <= safety_factor * unscaled_damped_dt_ms * (1 + 1e-9)))
        return unscaled_dt_ms;
    return unscaled_dt_ms * (scaled_damped_dt_ms / unscaled_damped_dt_ms);
}

ScaledTimeSteps scale_time_steps(double critical_dt_ms, double damped_critical_dt_ms, double mass_scale) {
    if (mass_scale == 1.0 || !std::isfinite(critical_dt_ms)) return {critical_dt_ms, damped_critical_dt_ms};
    const double lambda_k = 4.0 / (critical_dt_ms * critical_dt_ms);
    // From h²λ_K + 2hλ_C = 4 at h = the damped step; rounding may leave a tiny negative: none.
    const double lambda_c = std::isfinite(damped_critical_dt_ms) && damped_critical_dt_ms > 0
                                ? std::max(0.0, (4.0 - damped_critical_dt_ms * damped_critical_dt_ms * lambda_k) / (2.0 * damped_critical_dt_ms))
                                : 0.0;
    return {critical_dt_ms * std::sqrt(mass_scale),
            std::min(critical_dt_ms * std::sqrt(mass_scale), stable_step_ms(lambda_k / mass_scale, lambda_c / mass_scale))};
}

}  // namespace heartsim
