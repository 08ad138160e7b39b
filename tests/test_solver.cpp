// The CPU solver against truths: closed-form oscillators, conservation laws, convergence order,
// analytic static deflections, exact instrument constraints, force balance, the critical step,
// determinism across thread counts and kernels, and a stress run on a real heart.
#include "libmodel/ellipsoid.h"
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/select.h"
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "formats/volume_io.h"
#include "stress_gesture.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <random>
#include <unistd.h>

using namespace heartsim;

namespace {

struct Model {
    Lattice lattice;
    Packing packing;
};

/// An nx × ny × nz block of particles at `spacing` mm, packed in bricks.
Model block(int nx, int ny, int nz, double spacing = 1.5, double damping_ratio = 0.0) {
    Model model{test::block_lattice(nx, ny, nz, spacing, damping_ratio), {}};
    model.packing = pack_particles(model.lattice);
    return model;
}

SolverOptions quiet(double dt_factor, const Model& model, double damping_ratio = 0.0) {
    SolverOptions o;
    o.gravity.setZero();
    o.critical_dt_ms = estimate_critical_time_step(model.lattice.particles, model.lattice.springs, 5000, 1e-12).critical_dt_ms;
    o.dt_ms = dt_factor * o.critical_dt_ms;
    o.subdivide = damping_ratio > 0;  // dashpots shorten the stable step: let the solver subdivide
    o.damping_ratio = {damping_ratio};
    return o;
}

/// A smooth displacement (mostly low modes): stretch along x, shear, a bend.
std::vector<Eigen::Vector3d> smooth_displacement(const Particles& p, double amplitude) {
    std::vector<Eigen::Vector3d> x(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) {
        const Eigen::Vector3d r(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        x[i] = r + amplitude * Eigen::Vector3d(0.05 * r.x() + 0.02 * r.y(), 0.03 * std::sin(0.3 * r.x()), 0.02 * r.z());
    }
    return x;
}

Eigen::AlignedBox3d bounds(const Particles& p) {
    Eigen::AlignedBox3d box;
    for (const auto& r : p.rest_position) box.extend(Eigen::Vector3d(r[0], r[1], r[2]));
    return box;
}

std::vector<Eigen::Vector3d> zeros(std::size_t n) { return std::vector<Eigen::Vector3d>(n, Eigen::Vector3d::Zero()); }

template <class Real>
Eigen::Vector3d momentum(const BasicSolver<Real>& solver, const Particles& p, const std::vector<Eigen::Vector3d>& before) {
    Eigen::Vector3d total = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < p.size(); ++i) total += double(p.mass[i]) * (solver.position(i) - before[i]) / solver.substep_ms();
    return total;
}

template <class Real>
std::vector<Eigen::Vector3d> all_positions(const BasicSolver<Real>& solver) {
    std::vector<Eigen::Vector3d> x(solver.size());
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = solver.position(i);
    return x;
}

bool inside(const Eigen::Vector3d& x, const InstrumentPose& pose, const Eigen::Vector3d& semi_axes) {
    const Eigen::Vector3d local = pose.orientation.toRotationMatrix().transpose() * (x - pose.position);
    return local.cwiseQuotient(semi_axes).squaredNorm() < 1.0;
}

std::size_t resident_bytes() {
    std::ifstream statm("/proc/self/statm");
    std::size_t pages = 0, resident = 0;
    statm >> pages >> resident;
    return resident * std::size_t(sysconf(_SC_PAGESIZE));
}

}  // namespace

TEST(Solver, TwoFreeMassesOscillateWithPeriodTwoPiOverSqrtTwoKOverM) {
    const Model model = block(2, 1, 1);
    const double k = model.lattice.springs.stiffness[0], m = model.lattice.particles.mass[0];
    const double rest = model.lattice.springs.rest_length[0];
    const double period = 2 * M_PI / std::sqrt(2 * k / m);
    Solver solver(model.lattice, model.packing.neighbours, quiet(0.1, model));
    auto x = all_positions(solver);
    x[0].x() -= 0.05 * rest, x[1].x() += 0.05 * rest;  // stretch by 10%, symmetric
    solver.set_state(x, zeros(2));
    // Zero crossings of the extension, linearly interpolated, over about ten periods.
    std::vector<double> crossings;
    double previous = (solver.position(1) - solver.position(0)).norm() - rest;
    while (solver.simulated_time_ms() < 10.5 * period) {
        const double t0 = solver.simulated_time_ms();
        { const StepReport r = solver.step(); ASSERT_FALSE(r.diverged) << r.message; }
        const double e = (solver.position(1) - solver.position(0)).norm() - rest;
        if ((previous > 0) != (e > 0)) crossings.push_back(t0 + solver.substep_ms() * previous / (previous - e));
        previous = e;
    }
    ASSERT_GE(crossings.size(), 19u);
    const double measured = 2 * (crossings.back() - crossings.front()) / double(crossings.size() - 1);
    EXPECT_NEAR(measured, period, 0.005 * period) << "k " << k << " N/mm, m " << m << " g";
}

TEST(Solver, UndampedEnergyStaysWithinOnePercentOverOneHundredThousandSteps) {
    const Model model = block(4, 3, 3);
    SolverOptions options = quiet(0.1, model);
    Solver solver(model.lattice, model.packing.neighbours, options);
    solver.set_state(smooth_displacement(model.lattice.particles, 1.0), zeros(solver.size()));
    const double initial = solver.energy().total();
    ASSERT_GT(initial, 0);
    double worst = 0;
    for (int chunk = 0; chunk < 1000; ++chunk) {
        { const StepReport r = solver.step(100); ASSERT_FALSE(r.diverged) << r.message; }
        worst = std::max(worst, std::abs(solver.energy().total() - initial) / initial);
    }
    EXPECT_LT(worst, 0.01) << "largest relative energy deviation over 1e5 steps";
}

TEST(Solver, MomentumIsConservedToRoundOffWithoutAnchorsOrGravity) {
    const Model model = block(4, 3, 3);
    std::mt19937 random(7);
    std::normal_distribution<double> normal(0.0, 0.01);
    std::vector<Eigen::Vector3d> v(model.lattice.particles.size());
    for (auto& vi : v) vi = Eigen::Vector3d(normal(random), normal(random), normal(random)) + Eigen::Vector3d(0.02, -0.01, 0.005);
    const auto x0 = smooth_displacement(model.lattice.particles, 1.0);
    auto check = [&](auto& solver, double tolerance, int steps) {
        solver.set_state(x0, v);
        auto before = all_positions(solver);
        solver.step();
        const Eigen::Vector3d initial = momentum(solver, model.lattice.particles, before);
        double scale = 0;
        for (std::size_t i = 0; i < v.size(); ++i) scale += model.lattice.particles.mass[i] * v[i].norm();
        for (int s = 0; s < steps; ++s) {
            before = all_positions(solver);
            { const StepReport r = solver.step(); ASSERT_FALSE(r.diverged) << r.message; }
        }
        const Eigen::Vector3d final = momentum(solver, model.lattice.particles, before);
        // Round-off bound: each step rounds each position once, by at most half an ulp of the
        // largest coordinate, and a rounding error δ stays in the velocity as δ/h.
        double largest = 0, mass = 0;
        for (std::size_t i = 0; i < v.size(); ++i) largest = std::max(largest, solver.position(i).cwiseAbs().maxCoeff());
        for (float m : model.lattice.particles.mass) mass += m;
        using Real = typename std::remove_cvref_t<decltype(solver)>::Scalar;
        const double bound = steps * mass * 0.5 * largest * std::numeric_limits<Real>::epsilon() / solver.substep_ms();
        EXPECT_LT((final - initial).norm(), tolerance * bound) << initial.transpose() << " -> " << final.transpose() << " |P| scale " << scale;
    };
    ReferenceSolver reference(model.lattice, model.packing.neighbours, quiet(0.4, model, 0.3));
    check(reference, 1.0, 20000);
    Solver single(model.lattice, model.packing.neighbours, quiet(0.4, model, 0.3));
    check(single, 1.0, 20000);
}

TEST(Solver, ErrorDropsFourfoldWhenTheStepHalves) {
    const Model model = block(3, 3, 2);
    const double critical = quiet(1, model).critical_dt_ms;
    const double end_time = 16 * critical;
    const auto x0 = smooth_displacement(model.lattice.particles, 2.0);
    auto run = [&](double divisor) {
        SolverOptions o = quiet(1.0 / divisor, model);
        ReferenceSolver solver(model.lattice, model.packing.neighbours, o);
        solver.set_state(x0, zeros(solver.size()));
        solver.step(int(std::lround(end_time / o.dt_ms)));
        EXPECT_NEAR(solver.simulated_time_ms(), end_time, 1e-9 * end_time);
        return all_positions(solver);
    };
    const auto reference = run(1024);
    std::vector<double> errors;
    for (double divisor : {4.0, 8.0, 16.0, 32.0}) {
        const auto x = run(divisor);
        double e = 0;
        for (std::size_t i = 0; i < x.size(); ++i) e = std::max(e, (x[i] - reference[i]).norm());
        errors.push_back(e);
    }
    for (std::size_t i = 1; i < errors.size(); ++i) {
        const double ratio = errors[i - 1] / errors[i];
        EXPECT_GT(ratio, 3.5) << "step " << i;
        EXPECT_LT(ratio, 4.5) << "step " << i;
    }
}

TEST(Solver, HangingChainReachesTheAnalyticStaticDeflection) {
    // A vertical chain of n particles along k, the top one anchored, gravity along −k: spring i
    // (from the top) carries the weight of the n − i particles below it, extension w/k exactly.
    const int n = 10;
    Model model = block(1, 1, n);
    auto& p = model.lattice.particles;
    std::size_t top = 0;
    for (std::size_t i = 0; i < p.size(); ++i)
        if (p.lattice_index[i][2] == n - 1) top = i;
    p.anchored[top] = 1;
    SolverOptions o = quiet(0.5, model, 0.5);
    const Eigen::Vector3d axis = (Eigen::Vector3d(p.rest_position[top][0], p.rest_position[top][1], p.rest_position[top][2]) -
                                  Eigen::Vector3d(p.rest_position[0][0], p.rest_position[0][1], p.rest_position[0][2]))
                                     .normalized() *
                                 (p.lattice_index[top][2] > p.lattice_index[0][2] ? 1.0 : -1.0);
    o.gravity = -9.81e-3 * axis;
    o.damping = 0.05;
    Solver solver(model.lattice, model.packing.neighbours, o);
    for (int i = 0; i < 200; ++i) { const StepReport r = solver.step(500); ASSERT_FALSE(r.diverged) << r.message; }
    const double k = model.lattice.springs.stiffness[0], m = p.mass[0];
    for (std::size_t i = 0; i < p.size(); ++i) {
        const int below_top = n - 1 - p.lattice_index[i][2];  // springs between it and the top
        double expected = 0;
        for (int s = 1; s <= below_top; ++s) expected += (n - s) * m * 9.81e-3 / k;
        const Eigen::Vector3d r(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        const double measured = -(solver.position(i) - r).dot(axis);
        if (below_top == 0) EXPECT_EQ(measured, 0.0);
        else EXPECT_NEAR(measured, expected, 0.01 * expected) << "particle " << below_top << " below the top";
    }
}

TEST(Solver, HangingColumnMatchesTheLinearStaticSolutionOfTheNetwork) {
    // A 2×2×6 column hanging from its anchored top layer: the static deflection against the
    // exact solution K u = M g of the linearised network (dense, Eigen), within 1%.
    Model model = block(2, 2, 6);
    auto& p = model.lattice.particles;
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][2] == 5;
    const Eigen::Vector3d g(0, 0, -9.81e-3);  // lattice k is world +z here (identity direction): hang down
    SolverOptions o = quiet(0.5, model, 0.7);
    o.gravity = g;
    o.damping = 0.05;
    Solver solver(model.lattice, model.packing.neighbours, o);
    for (int i = 0; i < 100; ++i) { const StepReport r = solver.step(1000); ASSERT_FALSE(r.diverged) << r.message; }

    const Eigen::Index n = Eigen::Index(p.size());
    Eigen::MatrixXd k = Eigen::MatrixXd::Zero(3 * n, 3 * n);
    const auto& s = model.lattice.springs;
    for (std::size_t q = 0; q < s.size(); ++q) {
        const auto [a, b] = s.pairs[q];
        Eigen::Vector3d d(p.rest_position[b][0] - p.rest_position[a][0], p.rest_position[b][1] - p.rest_position[a][1],
                          p.rest_position[b][2] - p.rest_position[a][2]);
        d.normalize();
        const Eigen::Matrix3d block3 = s.stiffness[q] * d * d.transpose();
        k.block<3, 3>(3 * a, 3 * a) += block3, k.block<3, 3>(3 * b, 3 * b) += block3;
        k.block<3, 3>(3 * a, 3 * b) -= block3, k.block<3, 3>(3 * b, 3 * a) -= block3;
    }
    std::vector<Eigen::Index> free;
    for (Eigen::Index i = 0; i < n; ++i)
        if (!p.anchored[std::size_t(i)])
            for (int c = 0; c < 3; ++c) free.push_back(3 * i + c);
    Eigen::MatrixXd kf(free.size(), free.size());
    Eigen::VectorXd f(free.size());
    for (std::size_t r = 0; r < free.size(); ++r) {
        for (std::size_t c = 0; c < free.size(); ++c) kf(Eigen::Index(r), Eigen::Index(c)) = k(free[r], free[c]);
        f[Eigen::Index(r)] = p.mass[std::size_t(free[r] / 3)] * g[free[r] % 3];
    }
    const Eigen::VectorXd u = kf.ldlt().solve(f);
    double max_expected = 0, max_error = 0;
    for (std::size_t r = 0; r < free.size(); ++r) {
        const std::size_t i = std::size_t(free[r] / 3);
        const int c = int(free[r] % 3);
        const double measured = solver.position(i)[c] - p.rest_position[i][std::size_t(c)];
        max_expected = std::max(max_expected, std::abs(u[Eigen::Index(r)]));
        max_error = std::max(max_error, std::abs(measured - u[Eigen::Index(r)]));
    }
    ASSERT_GT(max_expected, 0);
    EXPECT_LT(max_error, 0.01 * max_expected) << "largest deflection " << max_expected << " mm";
}

TEST(Solver, NoParticleIsInsideTheProbeAfterAStepAndTheForcePushesTheProbeOut) {
    Model model = block(8, 8, 4);
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) model.lattice.particles.anchored[i] = model.lattice.particles.lattice_index[i][2] == 0;
    SolverOptions o = quiet(0.5, model, 0.3);
    Solver solver(model.lattice, model.packing.neighbours, o);
    const Eigen::Vector3d semi_axes(2.0, 3.0, 1.5);
    solver.set_instrument(1, {.kind = InstrumentKind::probe, .semi_axes = semi_axes});
    // Come down on the top face from above, tilted.
    const Eigen::AlignedBox3d box = bounds(model.lattice.particles);
    const double top = box.max().z();
    InstrumentPose pose{box.center() + Eigen::Vector3d(0.3, -0.2, 0), Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 1, 0).normalized()))};
    pose.position.z() = top + 3.0;
    solver.set_pose(1, pose);
    solver.step();
    std::size_t most_touched = 0;
    for (int s = 0; s < 400; ++s) {
        pose.position.z() = top + 3.0 - 5.0 * std::min(1.0, s / 200.0);  // down to 2 mm into the top face
        solver.set_pose(1, pose);
        { const StepReport r = solver.step(); ASSERT_FALSE(r.diverged) << r.message; }
        for (std::size_t i = 0; i < solver.size(); ++i) {
            const auto contact = solver.contact_particles(1);
            ASSERT_FALSE(inside(solver.position(i), pose, semi_axes))
                << "particle " << i << " step " << s << " r2 "
                << (pose.orientation.toRotationMatrix().transpose() * (solver.position(i) - pose.position)).cwiseQuotient(semi_axes).squaredNorm()
                << " in contact " << (std::find(contact.begin(), contact.end(), std::int32_t(i)) != contact.end()) << " anchored "
                << int(model.lattice.particles.anchored[i]);
        }
        most_touched = std::max(most_touched, solver.contact_particles(1).size());
    }
    EXPECT_GT(most_touched, 3u);
    const InstrumentForces forces = solver.instrument_forces();
    EXPECT_EQ(forces.hand[0].particles, 0u);
    EXPECT_GT(forces.hand[1].force_n.z(), 0) << "the tissue pushes the probe back up: " << forces.hand[1].force_n.transpose();
}

TEST(Solver, AProbePutsAParticleAtTheNearestPointOfItsSurface) {
    // A needle (1 × 1 × 4 mm) placed around a particle 0.15 mm from its axis: the particle goes
    // 0.85 mm to the side, where the surface is nearest, not 2 mm along the needle towards a tip
    // (where a radial projection in the needle's scaled frame would put it: local z 2.56).
    Model model = block(4, 4, 4);
    Solver solver(model.lattice, model.packing.neighbours, quiet(0.5, model));
    const Eigen::Vector3d semi_axes(1, 1, 4);
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = semi_axes});
    const std::size_t i = 21;
    const Eigen::Vector3d start = solver.position(i);
    const InstrumentPose pose{start - Eigen::Vector3d(0.15, 0, 0.5), Eigen::Quaterniond::Identity()};
    solver.set_pose(0, pose);
    { const StepReport r = solver.step(); ASSERT_FALSE(r.diverged) << r.message; }
    const Eigen::Vector3d local = solver.position(i) - pose.position;
    const Eigen::Vector3d nearest = nearest_point_on_ellipsoid(Eigen::Vector3d(0.15, 0, 0.5), semi_axes);
    EXPECT_FALSE(inside(solver.position(i), pose, semi_axes));
    EXPECT_LT((local - nearest).norm(), 1e-4) << "at " << local.transpose() << ", the nearest surface point is " << nearest.transpose();
    EXPECT_NEAR(local.z(), 0.5, 0.1) << "pushed along the needle";
    EXPECT_LT((solver.position(i) - start).norm(), 0.9);
}

TEST(Solver, GrabbedParticlesFollowTheToolExactlyAndAreFreeAfterRelease) {
    Model model = block(6, 6, 4);
    SolverOptions o = quiet(0.5, model, 0.2);
    o.gravity = Eigen::Vector3d(0, 9.81e-3, 0);
    Solver solver(model.lattice, model.packing.neighbours, o);
    solver.set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d(2.5, 2.5, 2.0)});
    InstrumentPose pose{bounds(model.lattice.particles).max(), Eigen::Quaterniond::Identity()};  // a corner
    solver.set_pose(0, pose);
    solver.step();
    const std::size_t captured = solver.begin_grab(0);
    ASSERT_GT(captured, 2u);
    const auto held = solver.contact_particles(0);
    std::vector<Eigen::Vector3d> local;
    for (auto i : held) local.push_back(solver.position(std::size_t(i)) - pose.position);
    for (int s = 1; s <= 300; ++s) {
        pose.position += Eigen::Vector3d(0.01, -0.005, 0.02);
        pose.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.002 * s, Eigen::Vector3d(0.2, 1, 0.3).normalized()));
        solver.set_pose(0, pose);
        { const StepReport r = solver.step(); ASSERT_FALSE(r.diverged) << r.message; }
        for (std::size_t q = 0; q < held.size(); ++q) {
            const Eigen::Vector3d expected = pose.position + pose.orientation.toRotationMatrix() * local[q];
            ASSERT_LT((solver.position(std::size_t(held[q])) - expected).norm(), 1e-5 * (1 + expected.norm())) << "step " << s;
        }
    }
    const Eigen::Vector3d pull = solver.instrument_forces().hand[0].force_n;
    EXPECT_GT(pull.norm(), 0);
    EXPECT_LT(pull.dot(Eigen::Vector3d(0.01, -0.005, 0.02)), 0) << "the tissue pulls the tool back";
    solver.release(0);
    EXPECT_TRUE(solver.contact_particles(0).empty());
    const Eigen::Vector3d before = solver.position(std::size_t(held[0]));
    for (int s = 0; s < 50; ++s) solver.step();
    EXPECT_GT((solver.position(std::size_t(held[0])) - before).norm(), 1e-3) << "released particles move again";
}

namespace {

/// A paddle (8 × 3 × 8 mm, broadside) starting in the middle of a 16.5 × 13.5 × 16.5 mm block
/// whose back and side faces are anchored, driven out through its free face and 20 mm on in 60
/// steps, then held still. Records the largest spring strain in the block at any step, and after every step
/// checks the rule itself: no particle the probe pushed has a spring stretched past the pierce
/// strain, measured against its neighbours where they were before the step (one substep per step).
struct Sweep {
    double strain = 0, pushed_strain = 0;
    std::size_t pierced = 0;
};
Sweep needle_out_of_a_block(double pierce_strain) {
    Model model = block(12, 10, 12);
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) {
        const auto& c = model.lattice.particles.lattice_index[i];
        model.lattice.particles.anchored[i] = c[0] == 0 || c[0] == 11 || c[2] == 0 || c[2] == 11 || c[1] == 0;
    }
    SolverOptions o = quiet(0.5, model);
    o.probe_pierce_strain = pierce_strain;
    Solver solver(model.lattice, model.packing.neighbours, o);
    EXPECT_EQ(solver.substeps_per_step(), 1);
    const Eigen::AlignedBox3d box = bounds(model.lattice.particles);
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(4, 1.5, 4)});
    InstrumentPose pose{box.center() + Eigen::Vector3d(0.3, 0, 0.2), Eigen::Quaterniond::Identity()};
    solver.set_pose(0, pose);
    const double start = pose.position.y(), end = box.max().y() + 20.0;
    const auto& springs = model.lattice.springs;
    std::vector<std::vector<std::size_t>> springs_of(solver.size());
    for (std::size_t q = 0; q < springs.pairs.size(); ++q) {
        springs_of[std::size_t(springs.pairs[q][0])].push_back(q);
        springs_of[std::size_t(springs.pairs[q][1])].push_back(q);
    }
    Sweep result;
    for (int s = 1; s <= 500; ++s) {
        pose.position.y() = start + (end - start) * std::min(1.0, s / 60.0);
        solver.set_pose(0, pose);
        const std::vector<Eigen::Vector3d> before = all_positions(solver);
        const StepReport r = solver.step();
        EXPECT_FALSE(r.diverged) << r.message;
        for (std::size_t q = 0; q < springs.pairs.size(); ++q) {
            const auto [a, b] = springs.pairs[q];
            const double length = (solver.position(std::size_t(a)) - solver.position(std::size_t(b))).norm();
            result.strain = std::max(result.strain, length / double(springs.rest_length[q]) - 1);
        }
        for (const std::int32_t i : solver.contact_particles(0))
            for (const std::size_t q : springs_of[std::size_t(i)]) {
                const auto [a, b] = springs.pairs[q];
                const std::size_t j = std::size_t(a) == std::size_t(i) ? std::size_t(b) : std::size_t(a);
                const double length = (solver.position(std::size_t(i)) - before[j]).norm();
                result.pushed_strain = std::max(result.pushed_strain, std::abs(length / double(springs.rest_length[q]) - 1));
            }
    }
    result.pierced = solver.pierced_particles();
    std::printf("  pierce strain %.1f: largest strain in the block %.3f, of a pushed particle %.3f; pierced %zu times\n", pierce_strain, result.strain,
                result.pushed_strain, result.pierced);
    return result;
}

}  // namespace

// A needle driven out of the tissue pierces it (SolverOptions::probe_pierce_strain) where pushing
// a particle on would stretch one of its springs past the limit, instead of carrying it along
// (in the stress gesture, until its springs were five times their rest length and flung it back).
TEST(Solver, ANeedleDrivenOutOfTheTissuePiercesItInsteadOfStretchingItPastTheLimit) {
    const double limit = SolverOptions{}.probe_pierce_strain;
    const Sweep pierced = needle_out_of_a_block(limit);
    const Sweep dragged = needle_out_of_a_block(0.0);
    EXPECT_GT(pierced.pierced, 0u);
    EXPECT_EQ(dragged.pierced, 0u);
    EXPECT_LE(pierced.pushed_strain, limit * (1 + 1e-5)) << "a pushed particle's spring past the pierce strain";
    EXPECT_GT(dragged.pushed_strain, limit) << "without piercing the needle should stretch what it pushes past the limit";
}

// A grab takes one piece of tissue (SolverOptions::grab_reach): at rest everything inside the
// grabber, and of a row of particles crumpled together from 19.5 mm apart, the run of
// neighbours within reach of the one nearest the centre.
TEST(Solver, AGrabTakesOnePieceOfTissueNotAClumpCrumpledFromFarApart) {
    Model model = block(14, 4, 4);
    const Particles& particles = model.lattice.particles;
    const Eigen::Vector3d semi_axes(2.0, 2.0, 2.0);
    for (const double reach : {SolverOptions{}.grab_reach, 0.0}) {
        SCOPED_TRACE("grab_reach " + std::to_string(reach));
        SolverOptions o = quiet(0.5, model);
        o.grab_reach = reach;
        Solver solver(model.lattice, model.packing.neighbours, o);
        solver.set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = semi_axes});
        // At rest, inside the block: every particle inside is held.
        const Eigen::AlignedBox3d box = bounds(particles);
        const InstrumentPose middle{box.center() + Eigen::Vector3d(0.2, 0.1, -0.1), Eigen::Quaterniond::Identity()};
        solver.set_pose(0, middle);
        std::size_t inside_at_rest = 0;
        for (std::size_t i = 0; i < solver.size(); ++i) inside_at_rest += inside(solver.position(i), middle, semi_axes);
        EXPECT_EQ(solver.begin_grab(0), inside_at_rest);
        EXPECT_GT(inside_at_rest, 4u);
        solver.release(0);
        // The row y = z = 0 crumpled into a 1 mm ball 4 mm off the block's -y face, in rest order.
        const Eigen::Vector3d clump(box.center().x(), box.min().y() - 4.0, box.min().z());
        std::vector<Eigen::Vector3d> x(particles.size()), v = zeros(particles.size());
        std::vector<std::size_t> row;
        for (std::size_t i = 0; i < particles.size(); ++i) {
            x[i] = Eigen::Vector3d(particles.rest_position[i][0], particles.rest_position[i][1], particles.rest_position[i][2]);
            if (particles.lattice_index[i][1] == 0 && particles.lattice_index[i][2] == 0) {
                row.push_back(i);
                x[i] = clump + Eigen::Vector3d(0.07 * particles.lattice_index[i][0] - 0.45, 0.0, 0.0);
            }
        }
        ASSERT_EQ(row.size(), 14u);
        solver.set_state(x, v);
        solver.set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = semi_axes});  // placed at once by the next pose
        solver.set_pose(0, {clump, Eigen::Quaterniond::Identity()});
        const std::size_t held = solver.begin_grab(0);
        if (reach <= 0) {
            EXPECT_EQ(held, row.size()) << "without a reach the grab holds the whole clump";
            continue;
        }
        // The nearest to the centre is lattice x 6 (0.07·x − 0.45 is nearest 0 there): it and the
        // row's particles up to 2 × 2 mm from it at rest, 1.5 mm apart: x 4 … 8.
        std::vector<int> held_x;
        for (const std::int32_t i : solver.contact_particles(0)) held_x.push_back(particles.lattice_index[std::size_t(i)][0]);
        EXPECT_EQ(held_x, (std::vector<int>{4, 5, 6, 7, 8}));
    }
}

TEST(Solver, ProbeForceBalancesTheAnchorReactionAtEquilibrium) {
    Model model = block(6, 6, 3);
    auto& p = model.lattice.particles;
    int lowest = 1 << 30;
    for (const auto& l : p.lattice_index) lowest = std::min(lowest, l[2]);
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][2] == lowest;
    SolverOptions o = quiet(0.5, model, 1.0);
    o.damping = 0.1;
    Solver solver(model.lattice, model.packing.neighbours, o);
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(2.2, 2.2, 2.2)});
    // The sphere's bottom goes 0.6 mm into the top face.
    const Eigen::AlignedBox3d box = bounds(p);
    const InstrumentPose pose{Eigen::Vector3d(box.center().x() + 0.2, box.center().y() + 0.1, box.max().z() + 2.2 - 0.6),
                              Eigen::Quaterniond::Identity()};
    solver.set_pose(0, pose);
    for (int i = 0; i < 60; ++i) { const StepReport r = solver.step(500); ASSERT_FALSE(r.diverged) << r.message; }
    const auto before = all_positions(solver);
    solver.step();
    double largest_motion = 0;
    for (std::size_t i = 0; i < before.size(); ++i) largest_motion = std::max(largest_motion, (solver.position(i) - before[i]).norm());
    EXPECT_LT(largest_motion, 1e-6) << "not at rest yet, mm per step";
    const Eigen::Vector3d probe = solver.instrument_forces().hand[0].force_n;
    const Eigen::Vector3d anchors = solver.anchor_force();
    ASSERT_GT(probe.norm(), 0);
    EXPECT_GT(probe.z(), 0);
    EXPECT_LT((probe + anchors).norm(), 0.01 * probe.norm()) << "probe " << probe.transpose() << " anchors " << anchors.transpose();
}

TEST(Solver, StableBelowTheCriticalStepWatchdogAboveNeverNonFinite) {
    const Model model = block(4, 3, 3);
    std::mt19937 random(3);
    std::uniform_real_distribution<double> uniform(-0.015, 0.015);
    std::vector<Eigen::Vector3d> x0;
    for (const auto& r : model.lattice.particles.rest_position)
        x0.emplace_back(r[0] + uniform(random), r[1] + uniform(random), r[2] + uniform(random));
    for (double factor : {0.5, 0.75, 0.9, 0.97, 1.03, 1.1, 1.5, 2.0}) {
        for (bool watchdog : {true, false}) {
            SolverOptions o = quiet(factor, model);
            o.watchdog = watchdog;
            Solver solver(model.lattice, model.packing.neighbours, o);
            solver.set_state(x0, zeros(solver.size()));
            StepReport report;
            for (int i = 0; i < 30 && !report.diverged; ++i) report = solver.step(100);
            if (watchdog) {
                EXPECT_EQ(report.diverged, factor > 1) << "dt = " << factor << " × critical: " << report.message;
            }
            for (std::size_t i = 0; i < solver.size(); ++i) ASSERT_TRUE(solver.position(i).allFinite()) << factor;
            ASSERT_TRUE(solver.anchor_force().allFinite());
            ASSERT_TRUE(solver.instrument_forces().hand[0].force_n.allFinite());
            if (report.diverged) {
                EXPECT_NE(report.message.find("watchdog"), std::string::npos);
            }
        }
    }
}

TEST(Solver, AutomaticSubstepsKeepTheStepBelowTheSafetyFraction) {
    const Model model = block(3, 3, 3);
    SolverOptions o;
    o.dt_ms = 1.0;
    Solver solver(model.lattice, model.packing.neighbours, o);
    const double critical = solver.load_report().damped_critical_dt_ms;
    EXPECT_TRUE(solver.load_report().critical_dt_estimated);
    EXPECT_LE(critical, solver.load_report().critical_dt_ms);
    EXPECT_LE(solver.substep_ms(), o.safety_factor * critical * (1 + 1e-12));
    EXPECT_GT(solver.substep_ms(), o.safety_factor * critical * (1 - 1.0 / solver.substeps_per_step()) * 0.999);
    EXPECT_NEAR(solver.substep_ms() * solver.substeps_per_step(), 1.0, 1e-12);
    const StepReport report = solver.step(3);
    EXPECT_EQ(report.steps, 3);
    EXPECT_EQ(report.substeps, 3LL * solver.substeps_per_step());
}

// The portable, AVX2 and AVX-512 kernels fuse the same five multiply-adds of a slot (one rounding
// each): the same bits, with one or two threads. SSE2 has no fused multiply-add and rounds them
// apart: the same bits for one and two threads, and positions within rounding of the others'.
// Every kernel is requested on every CPU; one the CPU lacks falls back (avx512 → avx2 → sse2)
// and must give its fallback's bits. SlotArithmetic, for replays, overrides the kernel.
TEST(Solver, SameBitsForOneAndTwoThreadsAndEveryFusedKernel) {
    Model model = block(20, 16, 16, 1.5, 0.1);
    const Eigen::AlignedBox3d box = bounds(model.lattice.particles);
    const Eigen::Vector3d c = box.center(), corner = box.min();
    const bool has_avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    const bool has_avx512 = has_avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq");
    struct Result {
        std::uint64_t hash;
        std::vector<std::array<float, 3>> positions;
        SolverKernel kernel;
    };
    auto run = [&](int threads, SolverKernel kernel, bool compact = true, SlotArithmetic arithmetic = SlotArithmetic::as_kernel) {
        tbb::global_control control(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        SolverOptions o;
        o.kernel = kernel;
        o.arithmetic = arithmetic;
        o.compact_uniform_slots = compact;
        o.damping = 0.01;
        Solver solver(model.lattice, model.packing.neighbours, o);
        solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(3, 2, 4)});
        solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d(3, 3, 3)});
        solver.set_pose(1, {corner, Eigen::Quaterniond::Identity()});
        solver.step();
        solver.begin_grab(1);
        for (int s = 0; s < 1000; ++s) {
            solver.set_pose(0, {c + Eigen::Vector3d(0, 0, 14 - 0.01 * s), Eigen::Quaterniond(Eigen::AngleAxisd(0.001 * s, Eigen::Vector3d::UnitX()))});
            solver.set_pose(1, {corner - Eigen::Vector3d(0.003 * s, 0, 0), Eigen::Quaterniond::Identity()});
            { const StepReport r = solver.step(); EXPECT_FALSE(r.diverged) << r.message; }
        }
        EXPECT_EQ(solver.load_report().uniform_slots, compact);
        return Result{solver.state_hash(), solver.positions(), solver.load_report().kernel};
    };
    const Result fused = run(1, SolverKernel::portable), separate = run(1, SolverKernel::sse2);
    EXPECT_EQ(fused.kernel, SolverKernel::portable);
    EXPECT_EQ(separate.kernel, SolverKernel::sse2);
    EXPECT_EQ(run(2, SolverKernel::sse2).hash, separate.hash);
    EXPECT_EQ(run(2, SolverKernel::sse2, false).hash, separate.hash) << "per-slot constants and per-entry tables must agree";
    const SolverKernel avx2_runs_as = has_avx2 ? SolverKernel::avx2 : SolverKernel::sse2;
    const SolverKernel avx512_runs_as = has_avx512 ? SolverKernel::avx512 : avx2_runs_as;
    if (!has_avx512) std::printf("  this CPU has no AVX-512 (F, VL, DQ): avx512 must fall back to %s and give its bits\n", to_string(avx512_runs_as));
    if (!has_avx2) std::printf("  this CPU has no AVX2 with FMA: avx2 and avx512 must fall back to sse2 and give its bits\n");
    for (const SolverKernel kernel : {SolverKernel::avx2, SolverKernel::avx512})
        for (const bool compact : {true, false}) {
            const Result r = run(2, kernel, compact);
            const SolverKernel expected = kernel == SolverKernel::avx2 ? avx2_runs_as : avx512_runs_as;
            EXPECT_EQ(r.kernel, expected) << to_string(kernel);
            EXPECT_EQ(r.hash, fuses_multiply_adds(expected) ? fused.hash : separate.hash)
                << to_string(kernel) << (compact ? ", per-slot constants" : ", per-entry tables");
        }
    // A replay's arithmetic overrides the kernel: separate runs as sse2, fused never as sse2.
    const Result as_recorded_before = run(2, SolverKernel::avx512, true, SlotArithmetic::separate);
    EXPECT_EQ(as_recorded_before.kernel, SolverKernel::sse2);
    EXPECT_EQ(as_recorded_before.hash, separate.hash);
    const Result fused_on_request = run(2, SolverKernel::sse2, true, SlotArithmetic::fused);
    EXPECT_EQ(fused_on_request.kernel, SolverKernel::portable);
    EXPECT_EQ(fused_on_request.hash, fused.hash);
    // Rounding apart from fused: positions a few ulps of the coordinates (~1e-6 mm each) apart,
    // far below the motion (the probe presses 10 mm, the grabber pulls 3 mm).
    double largest = 0;
    for (std::size_t i = 0; i < fused.positions.size(); ++i)
        for (int a = 0; a < 3; ++a) largest = std::max(largest, double(std::abs(fused.positions[i][a] - separate.positions[i][a])));
    std::printf("  largest |x_sse2 - x_fused| after 1000 steps: %.3g mm\n", largest);
    EXPECT_GT(largest, 0.0) << "sse2 rounds five operations per slot apart: some bit must differ";
    EXPECT_LT(largest, 1e-3);
}

// External loads against Newton's second law. In a free block without gravity or drag the
// springs' forces cancel in pairs, so with Verlet (x_{n+1} = x_n + u_n + h²(f + F)/m,
// u_{n+1} = x_{n+1} − x_n) and u_0 = 0 the momentum is Σ m·u_n = n·h²·ΣF and the centre of mass,
// after N substeps, has moved by exactly h²·ΣF·N(N+1)/(2M), however the loads deform the block.
TEST(Solver, LoadsMoveTheCentreOfMassByTheClosedFormOfNewtonsSecondLaw) {
    const Model model = block(5, 4, 4);
    const Particles& p = model.lattice.particles;
    double total_mass = 0;
    for (float m : p.mass) total_mass += m;
    const int substeps = 400;
    auto check = [&](auto& solver) {
        using Real = typename std::remove_cvref_t<decltype(solver)>::Scalar;
        const double h = solver.substep_ms();
        // Loads on four particles spread through the block; their sum moves the centre of mass
        // 0.3 mm over the run.
        std::vector<ParticleLoad> loads{{3, {1.0, -0.5, 0.25}}, {17, {0.5, 1.0, 0.0}}, {40, {-0.25, 0.0, 1.0}}, {71, {0.75, 0.25, -0.5}}};
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (const ParticleLoad& load : loads) sum += load.force_n;
        const double scale = 0.3 / (h * h * sum.norm() * substeps * (substeps + 1) / (2 * total_mass));
        sum.setZero();
        for (ParticleLoad& load : loads) load.force_n *= scale, sum += load.force_n;
        solver.set_loads(loads);
        ASSERT_EQ(solver.loads().size(), loads.size());
        auto centre = [&] {
            Eigen::Vector3d c = Eigen::Vector3d::Zero();
            for (std::size_t i = 0; i < p.size(); ++i) c += double(p.mass[i]) * solver.position(i);
            return Eigen::Vector3d(c / total_mass);
        };
        const Eigen::Vector3d before = centre();
        double largest = 0;
        for (int s = 0; s < substeps; ++s) {
            const StepReport r = solver.step();
            ASSERT_FALSE(r.diverged) << r.message;
            for (std::size_t i = 0; i < p.size(); ++i) largest = std::max(largest, solver.position(i).cwiseAbs().maxCoeff());
        }
        const Eigen::Vector3d expected = h * h * sum * substeps * (substeps + 1) / (2 * total_mass);
        const Eigen::Vector3d moved = centre() - before;
        // Rounding: each substep rounds each position twice (the kernel's x + u, then the load's
        // term) by at most half an ulp of the largest coordinate, and the motions, which carry the
        // momentum, to a relative epsilon each, summed over the run twice (n·u_n, then Σ).
        const double eps = std::numeric_limits<Real>::epsilon();
        const double bound = substeps * largest * eps + 4.0 * substeps * eps * expected.norm();
        std::printf("  %s: centre of mass moved (%.6g, %.6g, %.6g) mm, closed form (%.6g, %.6g, %.6g), difference %.3g mm, bound %.3g\n",
                    sizeof(Real) == 4 ? "float" : "double", moved.x(), moved.y(), moved.z(), expected.x(), expected.y(), expected.z(),
                    (moved - expected).norm(), bound);
        EXPECT_NEAR(expected.norm(), 0.3, 1e-9);
        EXPECT_LT((moved - expected).norm(), bound);
    };
    SolverOptions options = quiet(0.5, model);
    ASSERT_EQ(options.damping, 0.0);
    ASSERT_EQ(options.mass_scale, 1.0);
    ReferenceSolver reference(model.lattice, model.packing.neighbours, options);
    ASSERT_EQ(reference.substeps_per_step(), 1);
    check(reference);
    Solver single(model.lattice, model.packing.neighbours, options);
    check(single);
}

// Loads act only where the step integrates: on an anchored particle or one a grabber holds a
// load changes nothing, to the bit.
TEST(Solver, ALoadOnAnAnchoredOrHeldParticleChangesNothing) {
    Model model = block(6, 4, 4);
    Particles& p = model.lattice.particles;
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][0] == 0 ? 1 : 0;
    const std::size_t anchored = std::size_t(std::find(p.anchored.begin(), p.anchored.end(), 1) - p.anchored.begin());
    std::size_t far = 0;  // the free particle of largest x: the grabber's
    for (std::size_t i = 0; i < p.size(); ++i)
        if (p.rest_position[i][0] > p.rest_position[far][0]) far = i;
    const Eigen::Vector3d at(p.rest_position[far][0], p.rest_position[far][1], p.rest_position[far][2]);
    auto run = [&](bool loaded) {
        SolverOptions o = quiet(0.5, model);
        o.gravity = {0, 0, -9.81e-3};
        Solver solver(model.lattice, model.packing.neighbours, o);
        solver.set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(0.5)});
        solver.set_pose(0, {at, Eigen::Quaterniond::Identity()});
        EXPECT_EQ(solver.begin_grab(0), 1u);
        std::vector<ParticleLoad> loads{{std::int32_t(anchored), {5, 5, 5}}, {std::int32_t(far), {-5, 5, -5}}};
        std::sort(loads.begin(), loads.end(), [](const auto& a, const auto& b) { return a.particle < b.particle; });
        if (loaded) solver.set_loads(loads);
        for (int s = 0; s < 50; ++s) {
            solver.set_pose(0, {at + Eigen::Vector3d(0.01 * s, 0, 0), Eigen::Quaterniond::Identity()});
            EXPECT_FALSE(solver.step().diverged);
        }
        return solver.state_hash();
    };
    EXPECT_EQ(run(true), run(false));
}

// Loads set by a task run beside a step's spring pass (run_beside_next_step, as the patch's step
// runs on the cpu backend), from the positions the step starts with, are the loads set before the
// step: two solvers, one each way, stay identical to the bit through 200 steps of a probe pressing
// a block under gravity with position-dependent loads (springs back to rest on a row of particles).
TEST(Solver, LoadsSetBesideAStepAreTheLoadsSetBeforeIt) {
    const Model model = block(24, 10, 10);
    SolverOptions o = quiet(0.5, model);
    o.gravity = {0, 0, -9.81e-3};
    Solver before(model.lattice, model.packing.neighbours, o), beside(model.lattice, model.packing.neighbours, o);
    const auto& rest = model.lattice.particles.rest_position;
    std::vector<std::int32_t> loaded;
    for (std::size_t i = 0; i < rest.size(); i += 37) loaded.push_back(std::int32_t(i));
    auto loads_of = [&](const Solver& solver) {
        std::vector<ParticleLoad> loads;
        for (std::int32_t i : loaded) {
            const Eigen::Vector3d at(rest[std::size_t(i)][0], rest[std::size_t(i)][1], rest[std::size_t(i)][2]);
            loads.push_back({i, -1e-3 * (solver.position(std::size_t(i)) - at) + Eigen::Vector3d(0, 0, 2e-5)});
        }
        return loads;
    };
    Eigen::AlignedBox3d box;
    for (const auto& r : rest) box.extend(Eigen::Vector3d(r[0], r[1], r[2]));
    const Instrument probe{.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(1.5)};
    for (Solver* solver : {&before, &beside}) solver->set_instrument(0, probe);
    std::size_t touched = 0;
    for (int s = 0; s < 200; ++s) {
        const InstrumentPose pose{Eigen::Vector3d(box.center().x(), box.center().y(), box.max().z() + 1.5 - 0.03 * s), Eigen::Quaterniond::Identity()};
        before.set_pose(0, pose);
        beside.set_pose(0, pose);
        before.set_loads(loads_of(before));
        beside.run_beside_next_step([&] { beside.set_loads(loads_of(beside)); });
        ASSERT_FALSE(before.step().diverged);
        ASSERT_FALSE(beside.step().diverged);
        ASSERT_EQ(before.state_hash(), beside.state_hash()) << "step " << s;
        touched = std::max(touched, before.contact_particles(0).size());
    }
    EXPECT_GT(touched, 0u) << "the probe pressed the block";
    // What the task throws, the step throws.
    beside.run_beside_next_step([&] { beside.set_loads({{-1, {1, 0, 0}}}); });
    EXPECT_THROW(beside.step(), InputError);
}

// set_loads refuses a list that is not sorted, repeats a particle, names one out of range or has a
// non-finite force, naming what was wrong; the loads in force stay, to the bit.
TEST(Solver, BadLoadsAreRefusedAndTheLoadsInForceStay) {
    const Model model = block(4, 3, 3);
    const SolverOptions options = quiet(0.5, model);
    Solver solver(model.lattice, model.packing.neighbours, options), twin(model.lattice, model.packing.neighbours, options);
    const std::vector<ParticleLoad> good{{1, {0.01, 0, 0}}, {5, {0, -0.02, 0.01}}};
    solver.set_loads(good);
    twin.set_loads(good);
    const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
    const std::int32_t n = std::int32_t(solver.size());
    const std::vector<std::pair<std::vector<ParticleLoad>, std::string>> bad{
        {{{5, {1, 0, 0}}, {1, {1, 0, 0}}}, "sorted"},
        {{{2, {1, 0, 0}}, {2, {0, 1, 0}}}, "twice"},
        {{{-1, {1, 0, 0}}}, "outside [0, " + std::to_string(n) + ")"},
        {{{0, {1, 0, 0}}, {n, {1, 0, 0}}}, "particle " + std::to_string(n)},
        {{{3, {nan, 0, 0}}}, "not finite"},
        {{{3, {0, 0, -inf}}}, "not finite"},
    };
    for (const auto& [loads, words] : bad) {
        try {
            solver.set_loads(loads);
            ADD_FAILURE() << "accepted a list that should be refused for: " << words;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
        }
        ASSERT_EQ(solver.loads().size(), good.size());
        for (std::size_t q = 0; q < good.size(); ++q) {
            EXPECT_EQ(solver.loads()[q].particle, good[q].particle);
            EXPECT_EQ(solver.loads()[q].force_n, good[q].force_n);
        }
    }
    for (int s = 0; s < 20; ++s) solver.step(), twin.step();
    EXPECT_EQ(solver.state_hash(), twin.state_hash());
    solver.set_loads({});  // an empty list removes them
    EXPECT_TRUE(solver.loads().empty());
}

// reset_tissue() removes the loads: a free block without gravity that a load has moved is back at
// rest and stays there; reset() too.
TEST(Solver, ResetTissueRemovesTheLoads) {
    const Model model = block(4, 3, 3);
    const Particles& p = model.lattice.particles;
    Solver solver(model.lattice, model.packing.neighbours, quiet(0.5, model));
    auto from_rest = [&] {
        double largest = 0;
        for (std::size_t i = 0; i < p.size(); ++i)
            largest = std::max(largest, (solver.position(i) - Eigen::Vector3d(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2])).norm());
        return largest;
    };
    for (int round = 0; round < 2; ++round) {
        solver.set_loads({{4, {0.002, 0, 0}}, {9, {0, 0.002, 0}}});
        ASSERT_FALSE(solver.step(100).diverged);
        EXPECT_GT(from_rest(), 0.1) << "the loads should move the block";
        if (round == 0) solver.reset_tissue();
        else solver.reset();
        EXPECT_TRUE(solver.loads().empty());
        ASSERT_FALSE(solver.step(100).diverged);
        EXPECT_LT(from_rest(), 1e-5) << "mm, 100 steps after the reset";
    }
}

TEST(Solver, RefusesInconsistentInput) {
    Model model = block(3, 2, 2);
    auto table = model.packing.neighbours;
    table[0].fill(-1);
    EXPECT_THROW(Solver(model.lattice, table, {}), InputError);
    Lattice bad = model.lattice;
    bad.particles.mass[1] = 0;
    EXPECT_THROW(Solver(bad, model.packing.neighbours, {}), InputError);
    Solver solver(model.lattice, {}, {});  // slots from the springs alone
    EXPECT_EQ(solver.load_report().springs, model.lattice.springs.size());
    EXPECT_THROW(solver.begin_grab(0), InputError);
    EXPECT_THROW(solver.set_instrument(2, {}), InputError);
    EXPECT_THROW(solver.set_pose(0, {Eigen::Vector3d(NAN, 0, 0), Eigen::Quaterniond::Identity()}), InputError);
}

TEST(Solver, StressRealHeartWithTwoFastDeepInstruments) {
    const auto path = test::real_case("hvsmr16_pat1");
    if (path.empty()) GTEST_SKIP() << "real data absent";
    const LabelVolume volume = read_label_volume(path);
    const Selection selection = select_tissue(volume, {});
    Lattice lattice = layout_particles(selection, {1}, volume, {.particle_budget = 8000});
    const Packing packing = pack_particles(lattice);
    SolverOptions o;
    o.damping = 0.01;
    Solver solver(lattice, packing.neighbours, o);
    Eigen::AlignedBox3d box;
    for (const auto& r : lattice.particles.rest_position) box.extend(Eigen::Vector3d(r[0], r[1], r[2]));
    const double diagonal = box.diagonal().norm();
    std::size_t memory_after_warmup = 0;
    std::size_t events = 0;
    test::StressGesture gesture(solver, lattice.particles, 11);  // tests/stress_gesture.h
    for (int s = 0; s < 600; ++s) {
        gesture.before_step(solver, s);
        const StepReport report = solver.step();
        events += report.diverged;
        const InstrumentForces f = solver.instrument_forces();
        ASSERT_TRUE(f.hand[0].force_n.allFinite() && f.hand[1].force_n.allFinite());
        if (s == 100) memory_after_warmup = resident_bytes();
    }
    for (std::size_t i = 0; i < solver.size(); ++i) {
        const Eigen::Vector3d x = solver.position(i);
        ASSERT_TRUE(x.allFinite());
        ASSERT_LT((x - box.center()).norm(), 2 * diagonal) << "particle " << i << " left the scene";
    }
    EXPECT_LT(resident_bytes(), memory_after_warmup + (std::size_t(2) << 20)) << "memory grows with steps";
    RecordProperty("watchdog_events", int(events));
    // The probe's pierce, the one-piece grab and the speed bound of 4 took the stress gesture to
    // no event in 40 runs of 10,000 steps on the four real hearts at 30k (docs/benchmarks-solver.md "Stress").
    EXPECT_EQ(events, 0u) << "the watchdog should not need to step in at hand speeds";
}

// The probe's projection target: the nearest surface point, checked against a search over the
// surface (no sample may be nearer) and against closed forms on the degenerate axes.
TEST(Ellipsoid, NearestPointIsOnTheSurfaceAndNoSurfaceSampleIsNearer) {
    const std::vector<Eigen::Vector3d> shapes{{3, 3, 8}, {2, 3, 1.5}, {2, 2, 2}, {4, 4, 1}, {1, 5, 2.5}};
    std::mt19937 random(11);
    std::uniform_real_distribution<double> unit(-1, 1);
    for (const Eigen::Vector3d& a : shapes) {
        // The surface sampled on a fine (θ, φ) grid: spacing below 0.04 mm on these sizes.
        std::vector<Eigen::Vector3d> surface;
        const int rings = 600, segments = 1200;
        for (int r = 0; r <= rings; ++r)
            for (int s = 0; s < segments; ++s) {
                const double theta = M_PI * r / rings, phi = 2 * M_PI * s / segments;
                surface.emplace_back(a.x() * std::sin(theta) * std::cos(phi), a.y() * std::sin(theta) * std::sin(phi), a.z() * std::cos(theta));
            }
        for (int trial = 0; trial < 40; ++trial) {
            Eigen::Vector3d y(unit(random), unit(random), unit(random));
            y = y.cwiseProduct(a) * 0.999;
            if (y.cwiseQuotient(a).squaredNorm() >= 1) continue;
            if (trial < 4) y[trial % 3] = 0;  // on a plane of symmetry
            const Eigen::Vector3d x = nearest_point_on_ellipsoid(y, a);
            ASSERT_NEAR(x.cwiseQuotient(a).squaredNorm(), 1.0, 1e-9) << "shape " << a.transpose() << " point " << y.transpose();
            double best = std::numeric_limits<double>::infinity();
            for (const Eigen::Vector3d& q : surface) best = std::min(best, (q - y).norm());
            EXPECT_LE((x - y).norm(), best + 1e-9) << "a surface sample is nearer: shape " << a.transpose() << " point " << y.transpose();
            EXPECT_GE((x - y).norm(), best - 0.02) << "shape " << a.transpose() << " point " << y.transpose();
        }
    }
    // On a needle's axis the nearest surface is to the side: (0, 0, z) inside a 3 × 3 × 8 needle
    // is 3·√(1 − z²/55) mm from it for |z| up to 8 − 9/8 (the end of the medial axis), where a
    // radial projection would go 8 − |z| to the tip.
    for (double z : {0.0, 1.0, -4.0, 6.5}) {
        const Eigen::Vector3d x = nearest_point_on_ellipsoid(Eigen::Vector3d(0, 0, z), Eigen::Vector3d(3, 3, 8));
        EXPECT_NEAR((x - Eigen::Vector3d(0, 0, z)).norm(), 3 * std::sqrt(1 - z * z / (8 * 8 - 9)), 1e-9) << "z " << z;
        EXPECT_NEAR(x.z(), z * 64 / (64 - 9), 1e-9);
    }
    // The centre of a sphere: its radius along z.
    EXPECT_TRUE(nearest_point_on_ellipsoid(Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(2)).isApprox(Eigen::Vector3d(0, 0, 2)));
}
