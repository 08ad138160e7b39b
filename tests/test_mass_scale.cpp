// Explicit mass scaling (docs/solver.md "Mass scaling") and `--real-time auto` (runtime/core/real_time.h):
// the critical and damped steps and the period of a two-mass oscillator against their closed forms,
// the static force of a held press unchanged, the gl backend equal to the cpu one, and the
// governor's choice from the speed it sees.
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/core/real_time.h"
#include "runtime/core/trajectory.h"

#include "formats/scenario.h"
#include "formats/state.h"

#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <map>
#include <regex>

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;

namespace {

constexpr double pi = 3.14159265358979323846;

/// Two free particles of mass m (g) on one spring of stiffness k (N/mm), rest length 10 mm.
struct TwoMasses {
    Particles particles;
    Springs springs;
    TwoMasses(double m, double k) {
        particles.rest_position = {{0.0f, 0.0f, 0.0f}, {10.0f, 0.0f, 0.0f}};
        particles.lattice_index = {{0, 0, 0}, {1, 0, 0}};
        particles.mass = {float(m), float(m)};
        particles.material = {0, 0};
        particles.anchored = {0, 0};
        springs.pairs = {{0, 1}};
        springs.rest_length = {10.0f};
        springs.stiffness = {float(k)};
    }
};

/// The oscillator's period, ms: the mean time between upward zero crossings of the stretch
/// (linearly interpolated), over `periods` periods, started stretched by 0.1 mm at rest.
double measured_period(ReferenceSolver& solver, int periods) {
    solver.set_state({{-0.05, 0, 0}, {10.05, 0, 0}}, {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()});
    std::vector<double> crossings;
    double before = solver.position(1).x() - solver.position(0).x() - 10.0;
    for (int step = 0; step < 1000000 && int(crossings.size()) <= periods; ++step) {
        const double t0 = solver.simulated_time_ms();
        solver.step(1);
        const double now = solver.position(1).x() - solver.position(0).x() - 10.0;
        if (before < 0 && now >= 0) crossings.push_back(t0 + (solver.simulated_time_ms() - t0) * (-before) / (now - before));
        before = now;
    }
    return (crossings.back() - crossings.front()) / double(crossings.size() - 1);
}

}  // namespace

// ω² = k/μ = 2k/m for the relative motion; the inertia S·m gives ω²/S: the critical step 2/ω grows
// by √S (the Lanczos estimate equals the closed form for one mode), and so does the period.
TEST(MassScale, TheCriticalStepAndThePeriodOfATwoMassOscillatorGrowBySqrtS) {
    const double m = 2.0, k = 0.5;
    const TwoMasses two(m, k);
    for (const double s : {1.0, 4.0, 9.0}) {
        const double omega = std::sqrt(2.0 * k / (s * m));
        SolverOptions options;
        options.gravity = Eigen::Vector3d::Zero();
        options.mass_scale = s;
        options.dt_ms = 2.0 * pi / omega / 400.0;  // 400 steps per period: Verlet's period error ~ (ωh)²/24 < 1e-5
        ReferenceSolver solver(two.particles, two.springs, {}, options);
        EXPECT_NEAR(solver.load_report().critical_dt_ms, 2.0 / omega, 1e-6 * 2.0 / omega) << "S = " << s;
        EXPECT_NEAR(solver.load_report().unscaled_critical_dt_ms, 2.0 / std::sqrt(2.0 * k / m), 1e-6) << "S = " << s;
        EXPECT_EQ(solver.substeps_per_step(), 1);
        EXPECT_NEAR(measured_period(solver, 5), 2.0 * pi / omega, 1e-4 * 2.0 * pi / omega) << "S = " << s;
    }
}

// With a dashpot c on the spring (ζ of the material), the damped central-difference step solves
// h²λ_K + 2hλ_C = 4 with λ_K = 2k/(S·m) and λ_C = 2c/(S·m) for the relative mode.
TEST(MassScale, TheDampedStepSolvesTheScaledStabilityBound) {
    const double m = 1.5, k = 0.8, zeta = 0.7;
    const TwoMasses two(m, k);
    const double c = dashpot_coefficient(k, m, m, zeta);
    for (const double s : {1.0, 2.0, 16.0}) {
        SolverOptions options;
        options.gravity = Eigen::Vector3d::Zero();
        options.damping_ratio = {zeta};
        options.mass_scale = s;
        const ReferenceSolver solver(two.particles, two.springs, {}, options);
        const double lk = 2.0 * k / (s * m), lc = 2.0 * c / (s * m);
        const double h = (-2.0 * lc + std::sqrt(4.0 * lc * lc + 16.0 * lk)) / (2.0 * lk);  // the positive root
        EXPECT_NEAR(solver.damped_critical_dt_ms(), h, 1e-6 * h) << "S = " << s;
        EXPECT_LT(solver.damped_critical_dt_ms(), solver.load_report().critical_dt_ms);
    }
}

// Weight, springs and supports are untouched by S: a probe held pressed into an anchored block
// under gravity comes to the same equilibrium, and feels the same force, at S = 4 as at S = 1.
TEST(MassScale, AHeldPressFeelsTheSameStaticForce) {
    Lattice lattice = test::block_lattice(10, 10, 8, 1.5, 0.5);
    float bottom = 1e30f, top = -1e30f;
    for (const auto& p : lattice.particles.rest_position) bottom = std::min(bottom, p[2]), top = std::max(top, p[2]);
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        const auto& p = lattice.particles.rest_position[i];
        lattice.particles.anchored[i] = p[2] == bottom ? 1 : 0;
        centre += Eigen::Vector3d(p[0], p[1], p[2]) / double(lattice.particles.size());
    }
    const double radius = 3.0, depth = 1.5;
    std::array<Eigen::Vector3d, 2> force;
    std::array<double, 2> drift{};
    for (int run = 0; run < 2; ++run) {
        SolverOptions options;
        options.gravity = Eigen::Vector3d(0.0, 0.0, -9.81e-3);
        options.damping = 0.02;  // drag, 1/ms: settles both in a few hundred ms
        options.mass_scale = run == 0 ? 1.0 : 4.0;
        options.dt_ms = 1.0;
        Solver solver(lattice, {}, options);
        solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(radius)});
        const Eigen::Vector3d above(centre.x(), centre.y(), double(top) + radius + 1.0);
        const Eigen::Vector3d pressed(centre.x(), centre.y(), double(top) + radius - depth);
        solver.set_pose(0, {.position = above});
        for (int step = 1; step <= 200; ++step) {  // in over 200 ms, then held
            solver.set_pose(0, {.position = above + (pressed - above) * (step / 200.0)});
            ASSERT_FALSE(solver.step(1).diverged);
        }
        for (int step = 0; step < 3000; ++step) ASSERT_FALSE(solver.step(1).diverged);
        const Eigen::Vector3d before = solver.instrument_forces().hand[0].force_n;
        for (int step = 0; step < 500; ++step) solver.step(1);
        force[run] = solver.instrument_forces().hand[0].force_n;
        drift[run] = (force[run] - before).norm() / force[run].norm();
        EXPECT_LT(drift[run], 1e-3) << "not settled at S = " << options.mass_scale;
    }
    EXPECT_GT(force[0].z(), 0.005) << "the tissue should push the probe back up";
    EXPECT_LT((force[1] - force[0]).norm(), 0.005 * force[0].norm())
        << "S = 1: " << force[0].transpose() << " N, S = 4: " << force[1].transpose() << " N";
}

// A change of S during a run keeps the velocities (u = v·h rescaled) and the constants follow: the
// solver stepped at S = 1, switched to 4 and back to 1 equals one never switched at S = 1 when
// the substep does not change, and the substeps follow the scaled limit.
TEST(MassScale, SetMassScaleChangesTheSubstepsAndRefusesAScaleOutOfRange) {
    Lattice lattice = test::block_lattice(6, 6, 6, 1.5, 0.3);
    SolverOptions options;
    options.dt_ms = 1.0;
    Solver solver(lattice, {}, options);
    const int unscaled = solver.substeps_per_step();
    ASSERT_GT(unscaled, 2) << "the block's step should need several substeps";
    solver.step(5);
    solver.set_mass_scale(16.0);
    EXPECT_EQ(solver.mass_scale(), 16.0);
    EXPECT_EQ(solver.substeps_per_step(),
              int(std::ceil(1.0 / (options.safety_factor * solver.damped_critical_dt_ms()) * (1 - 1e-12))));
    EXPECT_LT(solver.substeps_per_step(), unscaled);
    EXPECT_NEAR(solver.load_report().critical_dt_ms, 4.0 * solver.load_report().unscaled_critical_dt_ms, 1e-12);
    EXPECT_FALSE(solver.step(20).diverged);
    for (const double wrong : {0.5, 0.0, -1.0, 2000.0, std::nan("")}) {
        EXPECT_THROW(solver.set_mass_scale(wrong), InputError) << wrong;
        EXPECT_EQ(solver.mass_scale(), 16.0);
    }
    solver.set_mass_scale(1.0);
    EXPECT_EQ(solver.substeps_per_step(), unscaled);
    EXPECT_EQ(solver.time_step_ms(), 1.0) << "a step of several substeps keeps its length";

    // heartprep's policy, one substep per step: the step grows with the stable step instead.
    SolverOptions one;  // dt_ms 0: safety × the damped step
    Solver policy(lattice, {}, one);
    ASSERT_EQ(policy.substeps_per_step(), 1);
    const double step = policy.time_step_ms(), damped = policy.damped_critical_dt_ms();
    policy.set_mass_scale(4.0);
    EXPECT_EQ(policy.substeps_per_step(), 1);
    EXPECT_NEAR(policy.time_step_ms(), step * policy.damped_critical_dt_ms() / damped, 1e-12);
    // Between √S (a stiffness-limited step) and S (a damping-limited one: h ≈ 2/λ_C, λ_C ∝ 1/S).
    EXPECT_GE(policy.time_step_ms(), 2.0 * step * (1 - 1e-12));
    EXPECT_LE(policy.time_step_ms(), 4.0 * step * (1 + 1e-12));
}

// The gl backend takes S as the cpu one does, at construction and during the run.
TEST(MassScale, GlMatchesCpuWithMassScaling) {
    REQUIRE_GL();
    const Scenario scenario = read_scenario(test::built_phantom("--cavity 2 --anchor-border --particles 6000"));
    SolverOptions options = options_from(scenario.solver);
    options.mass_scale = 4.0;
    auto cpu = make_cpu_backend(scenario, options);
    auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options);
    ASSERT_EQ(cpu->substeps_per_step(), gl->substeps_per_step());
    ASSERT_EQ(cpu->substep_ms(), gl->substep_ms());
    Trajectory trajectory;
    {
        Eigen::Vector3d top = Eigen::Vector3d::Constant(-1e30);  // the highest particle (largest z)
        for (const auto& p : scenario.lattice.particles.rest_position)
            if (p[2] > top.z()) top = Eigen::Vector3d(p[0], p[1], p[2]);
        InstrumentKeyframe a;
        a.hand = 0, a.kind = InstrumentKind::probe, a.semi_axes = Eigen::Vector3d::Constant(2.0 * scenario.lattice.spacing);
        a.pose.position = top + Eigen::Vector3d(0, 0, a.semi_axes.z());
        InstrumentKeyframe b = a;
        b.time_ms = 60.0 * cpu->time_step_ms();
        b.pose.position.z() -= 3.0 * scenario.lattice.spacing;
        trajectory.keyframes = {a, b};
    }
    auto halfway = [](Backend& backend) {
        return [&backend](int step, const StepReport&) {
            if (step == 49) backend.set_mass_scale(2.0);
        };
    };
    run_scripted(*cpu, trajectory, {.steps = 100, .on_step = halfway(*cpu)});
    run_scripted(*gl, trajectory, {.steps = 100, .on_step = halfway(*gl)});
    EXPECT_EQ(cpu->options().mass_scale, 2.0);
    EXPECT_EQ(gl->options().mass_scale, 2.0);
    EXPECT_EQ(cpu->substeps_per_step(), gl->substeps_per_step());
    const auto x = cpu->positions(), y = gl->positions();
    const auto& rest = scenario.lattice.particles.rest_position;
    double error = 0, moved = 0;
    for (std::size_t i = 0; i < x.size(); ++i)
        for (int c = 0; c < 3; ++c) {
            error = std::max(error, double(std::abs(x[i][c] - y[i][c])));
            moved = std::max(moved, double(std::abs(x[i][c] - rest[i][c])));
        }
    EXPECT_GT(moved, 0.5 * scenario.lattice.spacing);
    EXPECT_LT(error, 1e-4 * 100.0) << "max |x_gl - x_cpu| mm";  // the tolerance of RuntimeBackend.GlMatchesCpu* for a 100 mm model
    const Eigen::Vector3d f = cpu->instrument_forces().hand[0].force_n, g = gl->instrument_forces().hand[0].force_n;
    EXPECT_GT(f.norm(), 0.0);
    EXPECT_LT((f - g).norm(), 1e-2 * f.norm()) << f.transpose() << " vs " << g.transpose();
}

// The governor, with the machine's speed injected (a test double): where the simulation keeps up
// it keeps S = 1; where it runs at 0.3 of real time it takes the smallest S of the ladder at which
// the simulated time per substep the backend itself takes predicts 1.25× real time.
TEST(RealTimeAuto, ChoosesTheSmallestScaleThatKeepsUpFromTheSpeedItSees) {
    const Scenario scenario = read_scenario(test::built_phantom("--cavity 2 --anchor-border --particles 6000"));
    {
        auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
        MassScaleGovernor governor(*backend, 3.0);
        EXPECT_FALSE(governor.observe(0.0, 0.0));
        const auto said = governor.observe(600.0, 600.0);
        ASSERT_TRUE(said);
        EXPECT_NE(said->find("kept"), std::string::npos) << *said;
        EXPECT_EQ(backend->options().mass_scale, 1.0);
        EXPECT_FALSE(governor.observe(3000.0, 3000.0)) << "a later window that keeps up says nothing";
    }
    auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
    std::map<double, double> per_substep;  // simulated ms per substep, the backend's own, at each rung
    for (double s : MassScaleGovernor::ladder) {
        backend->set_mass_scale(s);
        per_substep[s] = backend->time_step_ms() / backend->substeps_per_step();
    }
    backend->set_mass_scale(1.0);
    ASSERT_GT(per_substep[16.0], 3.0 * per_substep[1.0]) << "a substep should cover about √16 = 4 times the time";
    double expected = 16.0;
    for (double s : MassScaleGovernor::ladder)
        if (0.3 * per_substep[s] / per_substep[1.0] >= MassScaleGovernor::margin) {
            expected = s;
            break;
        }
    MassScaleGovernor governor(*backend, 0.3);
    governor.observe(0.0, 0.0);
    EXPECT_FALSE(governor.observe(400.0, 400.0)) << "the first window is half a second";
    const auto said = governor.observe(500.0, 500.0);
    ASSERT_TRUE(said);
    EXPECT_EQ(backend->options().mass_scale, expected) << *said;
    EXPECT_GT(expected, 1.0);
    EXPECT_NE(said->find("mass scale " + std::to_string(int(expected))), std::string::npos) << *said;
}

// End to end: a tiny model keeps up here by a wide margin (measured, not injected) and stays at
// S = 1; with the speed injected as 0.3 the run takes S > 1, says so, and the saved state keeps it.
TEST(RealTimeAuto, HeadlessRunsChooseAndSaveTheirScale) {
    const fs::path tiny = test::built_phantom("--cavity 2 --anchor-border --particles 1500");
    test::TempDir dir;
    auto run = [&](const std::string& environment, const fs::path& state) {
        return test::run_command(environment + " " + quoted(HEARTSIM_EXE) + " run " + quoted(tiny) +
                                 " --headless --backend cpu --real-time auto --seconds 40 --save-state " + quoted(state));
    };
    const auto fast = run("", dir / "fast.h5");
    ASSERT_EQ(fast.exit_code, 0) << fast.output;
    EXPECT_NE(fast.output.find("at mass scale 1: kept"), std::string::npos) << fast.output;
    EXPECT_EQ(read_state(dir / "fast.h5").mass_scale, 1.0);
    const auto slow = run("HEARTSIM_ASSUME_REAL_TIME_FACTOR=0.3", dir / "slow.h5");
    ASSERT_EQ(slow.exit_code, 0) << slow.output;
    std::smatch m;
    const std::regex chosen("at mass scale 1: mass scale ([0-9]+), ");
    ASSERT_TRUE(std::regex_search(slow.output, m, chosen)) << slow.output;
    EXPECT_GT(std::stod(m[1]), 1.0);
    EXPECT_EQ(read_state(dir / "slow.h5").mass_scale, std::stod(m[1]));
    // Options that contradict each other.
    const auto both = test::run_command(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(tiny) +
                                        " --headless --mass-scale 4 --real-time auto");
    EXPECT_EQ(both.exit_code, 2) << both.output;
    EXPECT_NE(both.output.find("give one of them"), std::string::npos) << both.output;
    const auto low = test::run_command(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(tiny) + " --headless --mass-scale 0.5");
    EXPECT_EQ(low.exit_code, 2) << low.output;
    EXPECT_NE(low.output.find("--mass-scale"), std::string::npos) << low.output;
}
