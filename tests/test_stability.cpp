// The critical time step against closed forms and a dense eigen-solver.
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/select.h"
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "libmodel/supports.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>

using namespace heartsim;

namespace {

using test::block_lattice;

/// M^(−1/2) K M^(−1/2) and M^(−1/2) C M^(−1/2) assembled densely from the springs, supports and
/// materials, written here from the formulas of docs/scenario-format.md (c = 2ζ√(kμ) per spring,
/// ζ the mean of the two particles' rows; support springs and dashpots; drag γ·M).
struct DenseSystem {
    Eigen::MatrixXd k, c;
};

DenseSystem assemble(const Particles& p, const Springs& s, const std::vector<double>& damping_ratio, double drag) {
    auto ratio = [&](std::int32_t i) {
        const auto row = std::size_t(p.material[std::size_t(i)]);
        return row < damping_ratio.size() ? damping_ratio[row] : 0.0;
    };
    const Eigen::Index n = Eigen::Index(p.size());
    DenseSystem d{Eigen::MatrixXd::Zero(3 * n, 3 * n), Eigen::MatrixXd::Zero(3 * n, 3 * n)};
    auto add = [&](Eigen::MatrixXd& m, Eigen::Index a, Eigen::Index b, const Eigen::Matrix3d& block) {
        m.block<3, 3>(3 * a, 3 * a) += block;
        m.block<3, 3>(3 * b, 3 * b) += block;
        m.block<3, 3>(3 * a, 3 * b) -= block;
        m.block<3, 3>(3 * b, 3 * a) -= block;
    };
    for (std::size_t i = 0; i < s.size(); ++i) {
        const auto [a, b] = s.pairs[i];
        Eigen::Vector3d u(p.rest_position[std::size_t(b)][0] - p.rest_position[std::size_t(a)][0],
                          p.rest_position[std::size_t(b)][1] - p.rest_position[std::size_t(a)][1],
                          p.rest_position[std::size_t(b)][2] - p.rest_position[std::size_t(a)][2]);
        u.normalize();
        const double ma = p.mass[std::size_t(a)], mb = p.mass[std::size_t(b)];
        const double zeta = 0.5 * (ratio(a) + ratio(b));
        add(d.k, a, b, s.stiffness[i] * u * u.transpose());
        add(d.c, a, b, 2 * zeta * std::sqrt(s.stiffness[i] * ma * mb / (ma + mb)) * u * u.transpose());
    }
    for (Eigen::Index i = 0; i < n; ++i) {
        if (p.supported()) d.k.block<3, 3>(3 * i, 3 * i) += p.support_stiffness[std::size_t(i)] * Eigen::Matrix3d::Identity();
        if (!p.support_damping.empty()) d.c.block<3, 3>(3 * i, 3 * i) += p.support_damping[std::size_t(i)] * Eigen::Matrix3d::Identity();
        d.c.block<3, 3>(3 * i, 3 * i) += drag * p.mass[std::size_t(i)] * Eigen::Matrix3d::Identity();
    }
    Eigen::VectorXd scale(3 * n);
    for (Eigen::Index i = 0; i < 3 * n; ++i) scale[i] = p.anchored[std::size_t(i / 3)] ? 0.0 : 1.0 / std::sqrt(p.mass[std::size_t(i / 3)]);
    d.k = scale.asDiagonal() * d.k * scale.asDiagonal();
    d.c = scale.asDiagonal() * d.c * scale.asDiagonal();
    return d;
}

double largest(const Eigen::MatrixXd& m) {
    return Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(m, Eigen::EigenvaluesOnly).eigenvalues().maxCoeff();
}

/// Largest eigenvalue of M⁻¹K from the assembled dense matrices (free particles only).
double dense_largest_eigenvalue(const Particles& p, const Springs& s) { return largest(assemble(p, s, {}, 0.0).k); }

/// The exact edge of stability of Verlet with backward-difference damping: the h where an
/// eigenvalue ρ = −1 of the step appears, i.e. λ_max(h²K + 2hC) = 4 (scaled), by bisection.
double exact_stable_step(const DenseSystem& d) {
    double low = 0, high = 10;
    for (int i = 0; i < 100; ++i) {
        const double h = 0.5 * (low + high);
        (largest(h * h * d.k + 2 * h * d.c) < 4 ? low : high) = h;
    }
    return low;
}

/// A block with two materials (ζ 0.1 and 0.4), some particles a third of the mass (the light
/// particles of thin walls), posterior supports with their dashpots.
Lattice mixed_block() {
    Lattice lattice = block_lattice(5, 4, 3);
    lattice.materials.push_back(lattice.materials[0]);
    lattice.materials[1].damping_ratio = 0.4;
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        if (i % 3 == 0) lattice.particles.material[i] = 1;
        if (i % 5 == 0) lattice.particles.mass[i] /= 3;
    }
    add_supports(lattice, {});
    return lattice;
}

}  // namespace

TEST(Stability, DampedStableStepIsBelowTheExactEdgeAndClose) {
    const Lattice lattice = mixed_block();
    ASSERT_TRUE(lattice.particles.supported());
    for (double drag : {0.0, 0.05}) {
        const DenseSystem d = assemble(lattice.particles, lattice.springs, {0.1, 0.4}, drag);
        const auto estimate = estimate_critical_time_step(lattice.particles, lattice.springs, 300, 1e-10);
        const double damping = estimate_damping_eigenvalue(lattice.particles, lattice.springs, {0.1, 0.4}, drag);
        EXPECT_NEAR(damping, largest(d.c), 1e-6 * largest(d.c)) << "Lanczos on the damping matrix";
        EXPECT_NEAR(estimate.max_eigenvalue, largest(d.k), 1e-6 * largest(d.k));
        const double step = stable_step_ms(estimate.max_eigenvalue, damping);
        const double exact = exact_stable_step(d);
        std::printf("  drag %g: stable step %.5g ms, exact edge %.5g ms (%.3f of it), undamped critical %.5g ms\n", drag, step, exact,
                    step / exact, estimate.critical_dt_ms);
        EXPECT_LE(step, exact * (1 + 1e-6)) << "Weyl's inequality makes the estimate safe";
        EXPECT_GE(step, 0.85 * exact) << "and not much smaller";
        EXPECT_LT(step, estimate.critical_dt_ms) << "damping shortens the step";
    }
    // Without damping it is the critical step.
    EXPECT_DOUBLE_EQ(stable_step_ms(4.0, 0.0), 1.0);
}

TEST(Stability, TheSolverTurnsUnstableAtTheExactEdge) {
    // The solver's own float step on the same block: stable just below the exact edge (a random
    // perturbation dies out), unstable just above it (it grows). So the edge the
    // step policy keeps a margin from is where the integrator really fails.
    const Lattice lattice = mixed_block();
    const double exact = exact_stable_step(assemble(lattice.particles, lattice.springs, {0.1, 0.4}, 0.0));
    std::mt19937 generator(7);
    std::normal_distribution<double> noise(0.0, 1e-3);
    std::vector<Eigen::Vector3d> x0, v0(lattice.particles.size(), Eigen::Vector3d::Zero());
    for (const auto& r : lattice.particles.rest_position) x0.emplace_back(r[0] + noise(generator), r[1] + noise(generator), r[2] + noise(generator));
    for (double factor : {0.97, 1.03}) {
        SolverOptions options;
        options.dt_ms = factor * exact;
        options.subdivide = false;
        options.gravity.setZero();
        Solver solver(lattice, {}, options);
        EXPECT_LE(solver.damped_critical_dt_ms(), exact * (1 + 1e-6));
        solver.set_state(x0, v0);
        StepReport report;
        for (int block = 0; block < 40 && !report.diverged; ++block) report = solver.step(100);
        double displacement = 0;
        for (std::size_t i = 0; i < solver.size(); ++i)
            displacement = std::max(displacement, (solver.position(i) - Eigen::Vector3d(lattice.particles.rest_position[i][0],
                                                                                          lattice.particles.rest_position[i][1],
                                                                                          lattice.particles.rest_position[i][2])).norm());
        if (factor < 1) {
            EXPECT_FALSE(report.diverged) << report.message;
            EXPECT_LT(displacement, 1e-4) << "mm after 4000 steps at " << factor << " × the edge";
        } else {
            // The perturbation (≤ 0.005 mm) grows geometrically: past 0.1 mm, or the watchdog stops it.
            EXPECT_TRUE(report.diverged || displacement > 0.1)
                << "4000 steps at " << factor << " × the edge, largest displacement " << displacement << " mm";
        }
    }
}

TEST(Stability, TwoMassesOnOneSpringHaveOmegaSquaredTwoKOverM) {
    const Lattice lattice = block_lattice(2, 1, 1);
    ASSERT_EQ(lattice.particles.size(), 2u);
    ASSERT_EQ(lattice.springs.size(), 1u);
    const double k = lattice.springs.stiffness[0], m = lattice.particles.mass[0];
    const auto estimate = estimate_critical_time_step(lattice.particles, lattice.springs);
    EXPECT_NEAR(estimate.max_eigenvalue, 2 * k / m, 1e-9 * 2 * k / m);
    EXPECT_NEAR(estimate.critical_dt_ms, 2.0 / std::sqrt(2 * k / m), 1e-6 * estimate.critical_dt_ms);
    EXPECT_LE(estimate.critical_dt_bound_ms, estimate.critical_dt_ms * (1 + 1e-12));
}

TEST(Stability, LanczosMatchesDenseEigenvaluesOnBlocks) {
    for (auto dims : {std::array<int, 3>{3, 3, 3}, std::array<int, 3>{5, 4, 3}, std::array<int, 3>{2, 6, 2}}) {
        Lattice lattice = block_lattice(dims[0], dims[1], dims[2]);
        const double exact = dense_largest_eigenvalue(lattice.particles, lattice.springs);
        const auto estimate = estimate_critical_time_step(lattice.particles, lattice.springs, 300, 1e-10);
        EXPECT_LE(estimate.max_eigenvalue, exact * (1 + 1e-9)) << "a Rayleigh quotient cannot exceed λmax";
        EXPECT_NEAR(estimate.max_eigenvalue, exact, 1e-6 * exact);
        EXPECT_GE(estimate.eigenvalue_bound, exact * (1 - 1e-9)) << "Gershgorin must bound λmax";

        // Anchoring some particles removes their rows: compare again.
        for (std::size_t i = 0; i < lattice.particles.size(); i += 4) lattice.particles.anchored[i] = 1;
        const double anchored_exact = dense_largest_eigenvalue(lattice.particles, lattice.springs);
        const auto anchored = estimate_critical_time_step(lattice.particles, lattice.springs, 300, 1e-10);
        EXPECT_NEAR(anchored.max_eigenvalue, anchored_exact, 1e-6 * anchored_exact);
        EXPECT_GE(anchored.eigenvalue_bound, anchored_exact * (1 - 1e-9));
    }
}

TEST(Stability, CriticalStepScalesAsSqrtMassOverStiffness) {
    // Doubling the lattice spacing multiplies k by 2 and m by 8: ω² by 1/4, dt by 2.
    const auto fine = block_lattice(4, 4, 4, 1.0);
    const auto coarse = block_lattice(4, 4, 4, 2.0);
    const auto a = estimate_critical_time_step(fine.particles, fine.springs, 300, 1e-10);
    const auto b = estimate_critical_time_step(coarse.particles, coarse.springs, 300, 1e-10);
    EXPECT_NEAR(b.critical_dt_ms / a.critical_dt_ms, 2.0, 2e-3);
}

TEST(Stability, TheCeilingBoundsTheExactCriticalStepFromAbove) {
    // Two masses on one spring: the diagonal block's trace is k, so the ceiling is 2√(3m/k);
    // the exact step is 2/√(2k/m), √6 below it.
    {
        const Lattice pair = block_lattice(2, 1, 1);
        const double k = pair.springs.stiffness[0], m = pair.particles.mass[0];
        EXPECT_NEAR(critical_step_ceiling_ms(pair.particles, pair.springs), 2.0 * std::sqrt(3.0 * m / k), 1e-9);
    }
    // Blocks, with supports and light particles, and with anchors: always at or above the exact
    // step, and close enough (within 10×) that a stored step 2¹⁶ times too long cannot pass.
    std::vector<Lattice> cases{block_lattice(4, 3, 3), mixed_block(), block_lattice(5, 4, 3)};
    for (std::size_t i = 0; i < cases[2].particles.size(); i += 4) cases[2].particles.anchored[i] = 1;
    for (const Lattice& lattice : cases) {
        const double exact = 2.0 / std::sqrt(dense_largest_eigenvalue(lattice.particles, lattice.springs));
        const double ceiling = critical_step_ceiling_ms(lattice.particles, lattice.springs);
        EXPECT_GE(ceiling, exact * (1 - 1e-9));
        EXPECT_LT(ceiling, 10 * exact);
    }
}

TEST(Stability, TheSolverRefusesAStoredStepAboveTheCeilingAndTooManySubsteps) {
    const Lattice lattice = mixed_block();
    const double exact = 2.0 / std::sqrt(dense_largest_eigenvalue(lattice.particles, lattice.springs));
    SolverOptions options;
    options.critical_dt_ms = exact;  // what heartprep stores: accepted
    EXPECT_NO_THROW(Solver(lattice, {}, options));
    options.critical_dt_ms = exact * 65536;  // one flipped exponent bit
    try {
        Solver solver(lattice, {}, options);
        ADD_FAILURE() << "a stored critical step 2¹⁶ times too long was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("critical_dt_ms"), std::string::npos) << e.what();
    }
    // A dt a million times the stable step would need a million substeps per step, and 1e300 ms
    // more than an int holds: both refused, neither overflowed.
    options.critical_dt_ms = exact;
    options.dt_ms = 1e6 * exact;
    EXPECT_THROW(Solver(lattice, {}, options), InputError);
    options.dt_ms = 1e300;
    EXPECT_THROW(Solver(lattice, {}, options), InputError);
}
