// The tissue's own Poisson's ratio (libmodel/volume_cells.h): the volume of a cell against the
// trilinear map's exact integral, its gradient against finite differences, and a column pulled by
// its ends against the Young's modulus and Poisson's ratio it declares.
#include "libmodel/sim/solver.h"
#include "libmodel/volume_cells.h"
#include "libmodel/errors.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <cstdio>
#include <random>

using namespace heartsim;

namespace {

/// ∫ det(∂x/∂ξ) over [0,1]³ for the trilinear map through the corners (corner c at
/// ((c&1), (c>>1)&1, (c>>2)&1)), by 3-point Gauss–Legendre per axis: exact, det being of degree at
/// most 2 in each ξ.
double trilinear_volume(const double (&p)[8][3]) {
    const double node[3] = {0.5 - 0.5 * std::sqrt(0.6), 0.5, 0.5 + 0.5 * std::sqrt(0.6)};
    const double weight[3] = {5.0 / 18, 8.0 / 18, 5.0 / 18};
    double volume = 0;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            for (int c = 0; c < 3; ++c) {
                const double xi[3] = {node[a], node[b], node[c]};
                Eigen::Matrix3d jacobian = Eigen::Matrix3d::Zero();
                for (int q = 0; q < 8; ++q) {
                    const int bit[3] = {q & 1, (q >> 1) & 1, (q >> 2) & 1};
                    for (int d = 0; d < 3; ++d) {
                        double derivative = bit[d] ? 1.0 : -1.0;  // ∂N_q/∂ξ_d
                        for (int e = 0; e < 3; ++e)
                            if (e != d) derivative *= bit[e] ? xi[e] : 1.0 - xi[e];
                        for (int k = 0; k < 3; ++k) jacobian(k, d) += p[q][k] * derivative;
                    }
                }
                volume += weight[a] * weight[b] * weight[c] * jacobian.determinant();
            }
    return volume;
}

}  // namespace

TEST(VolumeCells, ACellsVolumeIsTheTrilinearMapsAndItsGradientTheDerivative) {
    std::mt19937 random(7);
    std::uniform_real_distribution<double> jitter(-0.3, 0.3);
    for (int trial = 0; trial < 20; ++trial) {
        double p[8][3];
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k) p[q][k] = 2.0 * ((q >> k) & 1) + (trial == 0 ? 0.0 : jitter(random));
        double gradient[8][3];
        const double volume = cell_volume12<double>(p, gradient) / 12.0;
        const double exact = trilinear_volume(p);
        if (trial == 0) EXPECT_NEAR(volume, 8.0, 1e-12);
        EXPECT_NEAR(volume, exact, 1e-12 * std::abs(exact)) << "trial " << trial;
        // Any common origin: the cell moved 100 mm has the same volume.
        double moved[8][3];
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k) moved[q][k] = p[q][k] + 100.0 * (k + 1);
        EXPECT_NEAR(cell_volume12<double>(moved, nullptr) / 12.0, exact, 1e-9 * std::abs(exact)) << "trial " << trial;
        // ∂V/∂p by central differences.
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k) {
                const double step = 1e-5;
                double plus[8][3], minus[8][3];
                std::copy(&p[0][0], &p[0][0] + 24, &plus[0][0]);
                std::copy(&p[0][0], &p[0][0] + 24, &minus[0][0]);
                plus[q][k] += step, minus[q][k] -= step;
                const double derivative = (cell_volume12<double>(plus, nullptr) - cell_volume12<double>(minus, nullptr)) / (2 * step);
                EXPECT_NEAR(gradient[q][k], derivative, 1e-6) << "trial " << trial << " corner " << q << " axis " << k;
            }
        // A mirrored cell (x → −x) has the opposite volume.
        for (int q = 0; q < 8; ++q) p[q][0] = -p[q][0];
        EXPECT_NEAR(cell_volume12<double>(p, nullptr) / 12.0, -exact, 1e-9 * std::abs(exact));
    }
}

// Lamé's λ from the springs (μ) and the cells (Δλ): Δλ = μ(4ν − 1)/(1 − 2ν), zero at ν = 1/4, and
// λ + 2μ over μ = 2(1 − ν)/(1 − 2ν) as for any isotropic solid.
TEST(VolumeCells, TheAddedModulusMakesUpLamesFirstParameter) {
    for (double nu : {0.25, 0.3, 0.45, 0.49}) {
        const double mu = shear_modulus(10.0, nu), lambda = mu + added_lame_modulus(10.0, nu);
        EXPECT_NEAR(lambda / (2 * (lambda + mu)), nu, 1e-12);
        EXPECT_NEAR(mu * (3 * lambda + 2 * mu) / (lambda + mu), 1e-2, 1e-14);  // E = 10 kPa
    }
    EXPECT_THROW(added_lame_modulus(10.0, 0.2), InputError);
    EXPECT_THROW(added_lame_modulus(10.0, 0.5), InputError);
}

// A column pulled by equal and opposite loads on its end layers, free otherwise (no anchor, no
// gravity), settles into uniaxial tension: in its middle the axial strain is σ/E and the lateral
// strain −ν times it. Measured for the springs alone (ν = 1/4) and with the volume term.
TEST(VolumeCells, AColumnPulledByItsEndsHasTheYoungsModulusAndPoissonsRatioItDeclares) {
    const int n = 12, nz = 30;
    const double spacing = 1.0, youngs = 10.0;
    for (double nu : {0.25, 0.45}) {
        Material material;
        material.youngs_modulus_kpa = youngs;
        material.poisson_ratio = nu;
        material.damping_ratio = 0.5;
        const Lattice lattice = uniform_block({n, n, nz}, spacing, material);
        const Particles& p = lattice.particles;
        SolverOptions options;
        options.gravity.setZero();
        options.damping = 0.02;
        Solver solver(lattice, {}, options);
        EXPECT_EQ(solver.volume_cell_count(), nu > 0.25 ? std::size_t((n - 1) * (n - 1) * (nz - 1)) : 0u);
        // σ = 0.1 kPa (a strain of 1 %): the load per end particle is σ·h² (each carries h² of the end).
        const double stress = 0.01 * youngs * 1e-3;  // N/mm²
        std::vector<ParticleLoad> loads;
        for (std::size_t i = 0; i < p.size(); ++i) {
            const int k = p.lattice_index[i][2];
            if (k == 0 || k == nz - 1)
                loads.push_back({std::int32_t(i), Eigen::Vector3d(0, 0, (k == 0 ? -1 : 1) * stress * spacing * spacing)});
        }
        solver.set_loads(loads);
        double previous = 0;
        for (int round = 0; round < 400; ++round) {
            const StepReport r = solver.step(200);
            ASSERT_FALSE(r.diverged) << r.message;
            const double z = solver.position(0).z();
            if (round > 10 && std::abs(z - previous) < 1e-7) break;
            previous = z;
        }
        // The middle layers' mean height and the middle columns' width, against rest.
        auto mean_of = [&](auto&& pick, auto&& value) {
            double sum = 0;
            int count = 0;
            for (std::size_t i = 0; i < p.size(); ++i)
                if (pick(p.lattice_index[i])) sum += value(i), ++count;
            return sum / count;
        };
        const int k0 = nz / 2 - 4, k1 = nz / 2 + 4;
        const double height = mean_of([&](auto c) { return c[2] == k1; }, [&](std::size_t i) { return solver.position(i).z(); }) -
                              mean_of([&](auto c) { return c[2] == k0; }, [&](std::size_t i) { return solver.position(i).z(); });
        const double width = mean_of([&](auto c) { return c[0] == n - 1 && c[2] >= k0 && c[2] <= k1; }, [&](std::size_t i) { return solver.position(i).x(); }) -
                             mean_of([&](auto c) { return c[0] == 0 && c[2] >= k0 && c[2] <= k1; }, [&](std::size_t i) { return solver.position(i).x(); });
        const double axial = height / ((k1 - k0) * spacing) - 1, lateral = width / ((n - 1) * spacing) - 1;
        const double measured_e = stress / axial * 1e3, measured_nu = -lateral / axial;
        std::printf("  nu %.2f: axial strain %.5f, lateral %.5f: E %.3f kPa (declared %.1f), nu %.4f\n", nu, axial, lateral, measured_e,
                    youngs, measured_nu);
        // E: the finite column's outer springs and its outer half cell (no cell reaches past the
        // outer particles) leave it a few per cent soft; ν as declared.
        EXPECT_NEAR(measured_e, youngs, 0.1 * youngs);
        EXPECT_NEAR(measured_nu, nu, 0.02);
    }
}

// The cells' forces are the gradient of the energy the solver reports: a free, undamped block let
// go from a uniaxial compression (x → 0.98·x, at rest) keeps its total energy to the Verlet step's
// O(h²) wobble (1 % at a twentieth of the critical step). The volume term carries most of that energy at ν = 0.45: in uniaxial strain
// W = ½(λ + 2μ)ε², and (λ + 2μ) is 3.8·E at ν = 0.45 against 1.2·E for the springs alone (the
// block's outer half cell without a cell takes some of it off).
TEST(VolumeCells, AFreeBlockKeepsItsEnergyAndTheCellsCarryTheDilatation) {
    double start[2] = {0, 0};
    int run = 0;
    for (double nu : {0.25, 0.45}) {
        Material material;
        material.poisson_ratio = nu;
        material.damping_ratio = 0.0;
        const Lattice lattice = uniform_block({6, 6, 6}, 1.5, material);
        SolverOptions options;
        options.gravity.setZero();
        options.safety_factor = 0.05;  // a twentieth of the critical step: the energy's wobble is O((hω)²)
        Solver solver(lattice, {}, options);
        const Particles& p = lattice.particles;
        std::vector<Eigen::Vector3d> x(p.size()), v(p.size(), Eigen::Vector3d::Zero());
        for (std::size_t i = 0; i < p.size(); ++i) x[i] = Eigen::Vector3d(0.98 * p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        solver.set_state(x, v);
        const double e0 = solver.energy().total();
        double worst = 0;
        for (int s = 0; s < 200; ++s) {
            const StepReport r = solver.step(10);
            ASSERT_FALSE(r.diverged) << r.message;
            worst = std::max(worst, std::abs(solver.energy().total() - e0));
        }
        std::printf("  nu %.2f: energy %.4g mJ at the start, largest change %.3g of it over 2000 steps\n", nu, e0, worst / e0);
        EXPECT_LT(worst, 0.01 * e0);
        start[run++] = e0;
    }
    EXPECT_GT(start[1] / start[0], 2.0);
    EXPECT_LT(start[1] / start[0], 3.8 / 1.2);
}
