// How a heart is held (libmodel/supports.h) against truths: the closed-form sag of a block on
// support springs, a balanced rest state that does not move, Newton's third law between the
// probe, the anchors, the supports and the weight, the critical step of a support, free pieces
// dropped or refused, the scenario file's round trip, a real heart held where it was imaged, and
// the same heart pulled hard beside its supports without the watchdog taking folds for divergence.
#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/select.h"
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "libmodel/supports.h"
#include "soak_gesture.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <optional>

#include <cmath>
#include <limits>

using namespace heartsim;

namespace {

const Eigen::Vector3d one_g(0.0, 9.81e-3, 0.0);  // mm/ms², towards posterior (+y in LPS)

using test::block_lattice;

struct Model {
    Lattice lattice;
    Packing packing;
};

Model packed(Lattice lattice) {
    Model model{std::move(lattice), {}};
    model.packing = pack_particles(model.lattice);
    return model;
}

double total_mass(const Particles& p) {
    double m = 0;
    for (float x : p.mass) m += x;
    return m;
}

Eigen::Vector3d rest(const Particles& p, std::size_t i) {
    return {p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]};
}

/// Steps until no particle moves more than `tolerance` mm in a step (damped runs settle), or
/// more than 4 float ulps of the largest coordinate: the velocity is kept apart from the position
/// (docs/solver.md "Precision"), so a force of rounding size still moves a particle by an ulp
/// now and then instead of being lost in the position's rounding.
void settle(Solver& solver, int max_blocks, double tolerance = 1e-7) {
    double largest = 0;
    for (std::size_t i = 0; i < solver.size(); ++i) largest = std::max(largest, solver.position(i).cwiseAbs().maxCoeff());
    tolerance = std::max(tolerance, 4.0 * largest * std::numeric_limits<float>::epsilon());
    for (int block = 0; block < max_blocks; ++block) {
        const StepReport r = solver.step(200);
        ASSERT_FALSE(r.diverged) << r.message;
        std::vector<Eigen::Vector3d> before(solver.size());
        for (std::size_t i = 0; i < solver.size(); ++i) before[i] = solver.position(i);
        solver.step(1);
        double motion = 0;
        for (std::size_t i = 0; i < solver.size(); ++i) motion = std::max(motion, (solver.position(i) - before[i]).norm());
        if (motion < tolerance) return;
    }
    FAIL() << "did not settle";
}

}  // namespace

TEST(Supports, ABlockOnAnElasticFoundationSagsByItsWeightOverTheTotalStiffness) {
    // Only the foundation (stiffness per volume): k_i ∝ m_i, so every particle sags by the same
    // g·m_i/k_i, the springs stay unstretched, and the block translates by exactly M·g / Σk.
    Lattice lattice = block_lattice(6, 5, 4);
    const SupportReport report =
        add_supports(lattice, {.region = SupportRegion::boundary, .stiffness_kpa_per_mm = 0.0, .embedding_kpa_per_mm2 = 0.05});
    ASSERT_GT(report.total_stiffness, 0.0);
    const double expected = total_mass(lattice.particles) * one_g.norm() / report.total_stiffness;
    Model model = packed(std::move(lattice));
    SolverOptions options;
    options.gravity = one_g;
    options.damping = 0.05;
    Solver solver(model.lattice, model.packing.neighbours, options);
    settle(solver, 400);
    for (std::size_t i = 0; i < solver.size(); ++i) {
        const Eigen::Vector3d sag = solver.position(i) - rest(model.lattice.particles, i);
        EXPECT_NEAR(sag.y(), expected, 0.01 * expected) << "particle " << i;
        EXPECT_NEAR(sag.x(), 0.0, 1e-3 * expected);
        EXPECT_NEAR(sag.z(), 0.0, 1e-3 * expected);
    }
}

TEST(Supports, AtEquilibriumTheSupportsCarryTheWholeWeight) {
    // Posterior supports (the block's back face) and the foundation: whatever the shape of the
    // sag, Σ support forces = −M·g once the block is at rest (no anchors).
    Lattice lattice = block_lattice(6, 5, 4);
    const SupportReport report = add_supports(lattice, {});
    EXPECT_EQ(report.supported, 6u * 4u) << "one particle per line along y: the 6 × 4 back face";
    const double weight = total_mass(lattice.particles) * one_g.norm();
    Model model = packed(std::move(lattice));
    SolverOptions options;
    options.gravity = one_g;
    Solver solver(model.lattice, model.packing.neighbours, options);
    settle(solver, 400);
    const Eigen::Vector3d supports = solver.support_force();
    EXPECT_NEAR(supports.y(), -weight, 0.01 * weight);
    EXPECT_LT(supports.head<1>().norm() + std::abs(supports.z()), 0.01 * weight);
}

TEST(Supports, ABalancedRestStateDoesNotMove) {
    // The same block, its rest state balanced under gravity: 10⁴ steps later nothing has moved.
    Lattice lattice = block_lattice(8, 6, 5);
    add_supports(lattice, {});
    const RestBalanceReport balance = balance_rest_state(lattice, one_g);
    ASSERT_TRUE(balance.balanced);
    EXPECT_GT(balance.max_sag_mm, 1e-3) << "gravity would sag the unbalanced block";
    EXPECT_LT(rest_force_residual(lattice, one_g).max_particle_n, 1e-6 * total_mass(lattice.particles) * one_g.norm());
    Model model = packed(std::move(lattice));
    SolverOptions options;
    options.gravity = one_g;
    options.balanced_gravity = one_g;
    Solver solver(model.lattice, model.packing.neighbours, options);
    const StepReport r = solver.step(10000);
    ASSERT_FALSE(r.diverged) << r.message;
    double largest = 0;
    for (std::size_t i = 0; i < solver.size(); ++i) largest = std::max(largest, (solver.position(i) - rest(model.lattice.particles, i)).norm());
    EXPECT_LE(largest, 1e-4) << "mm after 10⁴ steps; the unbalanced state would sag up to " << balance.max_sag_mm << " mm";
}

TEST(Supports, ProbeForceBalancesTheAnchorsAndTheSupportsAtEquilibrium) {
    // Newton: the tissue at rest pushes on the probe, the anchors and the supports; those forces
    // sum to its weight. Anchors on the left face, supports on the back, gravity on, the probe
    // pressing the front (anterior) face.
    Lattice lattice = block_lattice(7, 6, 5);
    auto& p = lattice.particles;
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][0] == 0;
    add_supports(lattice, {});
    balance_rest_state(lattice, one_g);
    const double weight = total_mass(lattice.particles) * one_g.norm();
    double anchored_mass = 0;
    for (std::size_t i = 0; i < p.size(); ++i) anchored_mass += p.anchored[i] ? p.mass[i] : 0.0f;
    Model model = packed(std::move(lattice));
    SolverOptions options;
    options.gravity = one_g;
    options.balanced_gravity = one_g;
    options.damping = 0.05;
    Solver solver(model.lattice, model.packing.neighbours, options);
    Eigen::AlignedBox3d box;
    for (std::size_t i = 0; i < solver.size(); ++i) box.extend(rest(model.lattice.particles, i));
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(2.5, 2.5, 2.5)});
    // A sphere 0.8 mm into the front face (−y), centred on it.
    solver.set_pose(0, {Eigen::Vector3d(box.center().x() + 0.3, box.min().y() - 2.5 + 0.8, box.center().z() + 0.2), Eigen::Quaterniond::Identity()});
    settle(solver, 600);
    const Eigen::Vector3d probe = solver.instrument_forces().hand[0].force_n;
    ASSERT_GT(probe.norm(), 1e-4);
    EXPECT_LT(probe.y(), 0.0) << "the tissue pushes the probe back out of the front face";
    // Tissue on the world: probe + anchors − (supports on tissue) = weight of the free particles.
    const Eigen::Vector3d free_weight = (total_mass(model.lattice.particles) - anchored_mass) * one_g;
    const Eigen::Vector3d balance = probe + solver.anchor_force() - solver.support_force() - free_weight;
    EXPECT_LT(balance.norm(), 0.01 * probe.norm()) << "probe " << probe.transpose() << ", weight " << weight;
}

TEST(Supports, OneParticleOnASupportOscillatesWithOmegaSquaredKOverM) {
    Lattice lattice = block_lattice(1, 1, 1);
    lattice.particles.support_stiffness = {0.02f};
    lattice.particles.support_point = lattice.particles.rest_position;
    lattice.particles.support_damping = {0.0f};
    const double k = lattice.particles.support_stiffness[0], m = lattice.particles.mass[0];
    const StabilityEstimate estimate = estimate_critical_time_step(lattice.particles, lattice.springs);
    EXPECT_NEAR(estimate.max_eigenvalue, k / m, 1e-9 * k / m);
    EXPECT_GE(estimate.eigenvalue_bound, k / m * (1 - 1e-12));
    // And the solver's period is 2π√(m/k) (Verlet's phase error at h = T/200 is far below 0.1 %).
    const double period = 2 * M_PI * std::sqrt(m / k);
    Model model = packed(std::move(lattice));
    SolverOptions options;
    options.gravity.setZero();
    options.dt_ms = period / 200;
    Solver solver(model.lattice, model.packing.neighbours, options);
    solver.set_state({rest(model.lattice.particles, 0) + Eigen::Vector3d(0.1, 0, 0)}, {Eigen::Vector3d::Zero()});
    solver.step(100);  // half a period: at −0.1 mm
    EXPECT_NEAR(solver.position(0).x() - rest(model.lattice.particles, 0).x(), -0.1, 1e-4);
}

TEST(Supports, ASmallFreePieceIsDroppedAndCountedALargeOneIsRefused) {
    // Two blocks 3 cells apart: the big one anchored, the small one (2×2×2) held by nothing.
    LabelVolume v;
    v.geometry.dims = {12, 4, 4};
    v.geometry.spacing = Eigen::Vector3d::Constant(1.5);
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = 0; k < 4; ++k)
        for (int j = 0; j < 4; ++j)
            for (int i = 0; i < 12; ++i)
                if (i < 7 || (i >= 10 && j < 2 && k < 2)) v.labels[v.geometry.linear(i, j, k)] = 1;
    SelectionOptions keep_all;
    keep_all.min_island_mm3 = 0;
    const Selection selection = select_tissue(v, keep_all);
    Lattice lattice = layout_particles(selection, {1}, v, {.spacing_mm = 1.5, .occupancy = 0.5});
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) lattice.particles.anchored[i] = lattice.particles.lattice_index[i][0] == 0;
    ASSERT_EQ(lattice.particles.size(), 7u * 16u + 8u);
    const std::size_t springs_before = lattice.springs.size();

    Lattice refused = lattice;
    try {
        drop_free_pieces(refused, {.drop_below_particles = 8});
        FAIL() << "a free piece of 8 particles dropped below 8 must be refused";
    } catch (const InputError& e) {
        const std::string message = e.what();
        EXPECT_NE(message.find("8 of the 120 particles"), std::string::npos) << message;
        // libmodel names the options that would help by their meaning; heartprep spells its flags.
        EXPECT_NE(message.find("{FreePieceOptions::allow_free}"), std::string::npos) << message;
        EXPECT_NE(message.find("{SupportOptions::region}"), std::string::npos) << message;
    }

    Lattice kept = lattice;
    const FreePieceReport allowed = drop_free_pieces(kept, {.drop_below_particles = 8, .allow_free = true});
    EXPECT_EQ(allowed.free_pieces_kept, 1u);
    EXPECT_EQ(kept.particles.size(), lattice.particles.size());

    const FreePieceReport report = drop_free_pieces(lattice, {.drop_below_particles = 9});
    EXPECT_EQ(report.pieces, 2u);
    EXPECT_EQ(report.piece_sizes, (std::vector<std::size_t>{112, 8}));
    EXPECT_EQ(report.dropped_pieces, 1u);
    EXPECT_EQ(report.dropped_particles, 8u);
    EXPECT_EQ(lattice.particles.size(), 112u);
    // The 2×2×2 cube had 12 face and 12 edge springs.
    EXPECT_EQ(lattice.springs.size(), springs_before - 24u);
    for (const auto& [a, b] : lattice.springs.pairs) EXPECT_LT(std::size_t(b), lattice.particles.size());
    for (const auto& c : lattice.particles.lattice_index) EXPECT_LT(c[0], 7);
    // What remains is one held piece.
    const Pieces pieces = find_pieces(lattice.particles, lattice.springs);
    EXPECT_EQ(pieces.size.size(), 1u);
    EXPECT_TRUE(pieces.held[0]);
}

TEST(Supports, HeartprepWritesSupportsAndTheBalancedGravityAndTheReaderGetsThemBack) {
    test::TempDir dir;
    const auto input = std::filesystem::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz";
    const auto held = dir / "held.h5", loose = dir / "loose.h5";
    auto run = test::heartprep("build " + test::quoted(input) + " -o " + test::quoted(held) + " --particles 3000 --no-visual -q");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario s = read_scenario(held);
    ASSERT_TRUE(s.lattice.particles.supported());
    EXPECT_EQ(s.solver.balanced_gravity, s.solver.gravity);
    EXPECT_LT(rest_force_residual(s.lattice, s.solver.gravity).max_particle_n, 1e-6);
    std::size_t damped = 0;
    for (float c : s.lattice.particles.support_damping) damped += c > 0;
    EXPECT_GT(damped, 0u);
    // With --support none, the phantom (nothing anchored) is one free piece: refused, no file.
    run = test::heartprep("build " + test::quoted(input) + " -o " + test::quoted(loose) + " --particles 3000 --no-visual -q --support none");
    EXPECT_NE(run.exit_code, 0);
    EXPECT_NE(run.output.find("held by nothing"), std::string::npos) << run.output;
    EXPECT_FALSE(std::filesystem::exists(loose));
    // --allow-free --rest-state imaged: the old, unsupported model, read back without supports.
    run = test::heartprep("build " + test::quoted(input) + " -o " + test::quoted(loose) +
                          " --particles 3000 --no-visual -q --support none --allow-free --rest-state imaged");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario free = read_scenario(loose);
    EXPECT_FALSE(free.lattice.particles.supported());
    EXPECT_EQ(free.solver.balanced_gravity, Eigen::Vector3d::Zero());
    // Unstressed at rest, to the rounding of float coordinates (~1e-5 mm at 100 mm) times k and 18 springs.
    EXPECT_LT(rest_force_residual(free.lattice, Eigen::Vector3d::Zero()).max_particle_n, 2e-6) << "unstressed at rest";
}

namespace {

/// The real case `name` as `heartprep build` makes it with the defaults (no visual mesh); nullopt
/// where ../shared/data/real is absent. A failed build fails the test.
std::optional<Scenario> default_build(const std::string& name, const std::string& more = "") {
    const auto input = test::real_case(name);
    if (input.empty()) return std::nullopt;
    test::TempDir dir;
    const auto output = dir / (name + ".h5");
    const auto run = test::heartprep("build " + test::quoted(input) + " -o " + test::quoted(output) + " --no-visual -q " + more);
    EXPECT_EQ(run.exit_code, 0) << run.output;
    return read_scenario(output);
}

}  // namespace

TEST(Supports, ARealHeartBuiltWithTheDefaultsStaysWhereItWasImagedForFiveSeconds) {
    const std::optional<Scenario> built = default_build("hvsmr16_pat1");
    if (!built) GTEST_SKIP() << "real data absent (../shared/data/real/hvsmr16_pat1): the default build is not checked";
    const Scenario& s = *built;
    Solver solver(s.lattice, s.packing->neighbours, options_from(s.solver));
    const StepReport r = solver.step(int(std::ceil(5000.0 / solver.time_step_ms())));
    ASSERT_FALSE(r.diverged) << r.message;
    double largest = 0;
    for (std::size_t i = 0; i < solver.size(); ++i) largest = std::max(largest, (solver.position(i) - rest(s.lattice.particles, i)).norm());
    EXPECT_LE(largest, 0.5) << "mm after 5 s with no instrument";
    std::printf("[pat1 default build] %zu particles, largest displacement after 5 s: %.3g mm\n", solver.size(), largest);
}

// The soak's 20 mm pulls beside the stiffest supports of a real heart (tests/soak_gesture.h)
// fold its lattice, and a stable step then snaps a light surface particle through a neighbour
// faster than twice the shortest rest length per substep: the old speed bound took that for
// divergence and restored the heart at rest with the grab released. A snap is one fast substep,
// slower in the next; a diverging particle would move faster every substep. The heart is built
// of its labelled myocardium alone (--walls labelled): its ventricles' wall is what the pulls
// fold (with the atria's and vessels' walls grown, the same pulls spread and nothing snaps).
TEST(Supports, FoldSnapsOfARealHeartPulledBesideItsStiffestSupportsAreNotDivergence) {
    const std::optional<Scenario> built = default_build("hvsmr16_pat5", "--walls labelled");
    if (!built) GTEST_SKIP() << "real data absent (../shared/data/real/hvsmr16_pat5): the soak's pulls are not checked";
    const Scenario& s = *built;
    const SolverOptions options = options_from(s.solver);
    Solver solver(s.lattice, s.packing->neighbours, options);
    ASSERT_EQ(solver.substeps_per_step(), 1) << "a step is one substep here, so a step's displacement is a substep's";
    const double shortest = *std::min_element(s.lattice.springs.rest_length.begin(), s.lattice.springs.rest_length.end());
    test::SoakGesture gesture(solver, s, test::held_hardest(s), 1);

    std::vector<std::array<float, 3>> before = solver.positions();
    std::vector<double> moved(solver.size(), 0.0);  // each particle's last step, in shortest rest lengths
    double fastest = 0;
    int snaps = 0, growing = 0;
    for (int step = 0; step < 4000; ++step) {
        gesture.before_step(solver);
        const StepReport report = solver.step();
        ASSERT_FALSE(report.diverged) << "step " << step << ": " << report.message;
        const std::vector<std::array<float, 3>> after = solver.positions();
        for (std::size_t i = 0; i < after.size(); ++i) {
            const double d = std::sqrt(std::pow(double(after[i][0]) - before[i][0], 2) + std::pow(double(after[i][1]) - before[i][1], 2) +
                                       std::pow(double(after[i][2]) - before[i][2], 2)) /
                             shortest;
            ASSERT_TRUE(std::isfinite(d)) << "particle " << i << " at step " << step;
            if (moved[i] > 2.0) growing += d >= moved[i];  // the step after a snap
            snaps += d > 2.0;
            fastest = std::max(fastest, d);
            moved[i] = d;
        }
        before = after;
    }
    std::printf("[pat5 soak, 4000 steps] %lld grabs, %zu slipped, %d snaps past 2 shortest rest lengths in a substep, the fastest %.3g\n",
                gesture.grabs(), solver.slipped_particles(), snaps, fastest);
    EXPECT_EQ(solver.watchdog_events(), 0u);
    EXPECT_GT(snaps, 0) << "the pulls should fold the lattice into snaps the old bound of 2 refused";
    EXPECT_EQ(growing, 0) << "a snap followed by a faster step is growth, not a snap";
    EXPECT_LT(fastest, options.max_displacement_fraction);
}
