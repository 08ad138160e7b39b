// The critical time step against closed forms and a dense eigen-solver.
#include "libmodel/lattice.h"
#include "libmodel/select.h"
#include "libmodel/stability.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>

using namespace heartsim;

namespace {

using test::block_lattice;

/// Largest eigenvalue of M⁻¹K from the assembled dense matrices (free particles only).
double dense_largest_eigenvalue(const Particles& p, const Springs& s) {
    const Eigen::Index n = Eigen::Index(p.size());
    Eigen::MatrixXd k = Eigen::MatrixXd::Zero(3 * n, 3 * n);
    for (std::size_t i = 0; i < s.size(); ++i) {
        const auto [a, b] = s.pairs[i];
        Eigen::Vector3d d(p.rest_position[std::size_t(b)][0] - p.rest_position[std::size_t(a)][0],
                          p.rest_position[std::size_t(b)][1] - p.rest_position[std::size_t(a)][1],
                          p.rest_position[std::size_t(b)][2] - p.rest_position[std::size_t(a)][2]);
        d.normalize();
        const Eigen::Matrix3d block = s.stiffness[i] * d * d.transpose();
        k.block<3, 3>(3 * a, 3 * a) += block;
        k.block<3, 3>(3 * b, 3 * b) += block;
        k.block<3, 3>(3 * a, 3 * b) -= block;
        k.block<3, 3>(3 * b, 3 * a) -= block;
    }
    Eigen::VectorXd scale(3 * n);
    for (Eigen::Index i = 0; i < 3 * n; ++i) scale[i] = p.anchored[std::size_t(i / 3)] ? 0.0 : 1.0 / std::sqrt(p.mass[std::size_t(i / 3)]);
    const Eigen::MatrixXd a = scale.asDiagonal() * k * scale.asDiagonal();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(a, Eigen::EigenvaluesOnly);
    return solver.eigenvalues().maxCoeff();
}

}  // namespace

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
