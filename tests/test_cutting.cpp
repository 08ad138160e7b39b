// The scalpel's physics cut against truths counted apart from it: the springs a straight sweep
// through a block cuts are exactly the springs whose ends lie on opposite sides of the blade's
// plane; the block falls into the two pieces on either side, which then move independently
// (momentum stays with the piece that has it); a partial cut leaves one piece whose slit opens
// under load; a lifted blade, or one pushed along itself, cuts nothing; a reset heals the cut.
#include "libmodel/cutting.h"
#include "libmodel/packing.h"
#include "libmodel/solver.h"
#include "libmodel/stability.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <set>

using namespace heartsim;

namespace {

struct Model {
    Lattice lattice;
    Packing packing;
};

Model block(int nx, int ny, int nz, const std::function<bool(const std::array<std::int32_t, 3>&)>& anchored = {}) {
    Model model{test::block_lattice(nx, ny, nz, 1.5, 0.0), {}};
    if (anchored) {
        Particles& p = model.lattice.particles;
        for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = anchored(p.lattice_index[i]) ? 1 : 0;
    }
    model.packing = pack_particles(model.lattice);
    return model;
}

SolverOptions options_for(const Model& model) {
    SolverOptions o;
    o.gravity.setZero();
    o.critical_dt_ms = estimate_critical_time_step(model.lattice.particles, model.lattice.springs, 5000, 1e-12).critical_dt_ms;
    o.dt_ms = 0.5 * o.critical_dt_ms;
    o.damping_ratio = {0.0};
    return o;
}

Eigen::Vector3d rest_of(const Model& model, std::size_t packed) {
    const auto& r = model.lattice.particles.rest_position[packed];
    return {r[0], r[1], r[2]};
}

/// The pieces of the network left when `cut` springs are removed: a label per packed particle.
std::vector<int> pieces(const Model& model, const std::vector<std::array<std::int32_t, 2>>& cut) {
    const std::size_t n = model.lattice.particles.size();
    std::vector<int> parent(n);
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int a) {
        while (parent[std::size_t(a)] != a) a = parent[std::size_t(a)] = parent[std::size_t(parent[std::size_t(a)])];
        return a;
    };
    const std::set<std::array<std::int32_t, 2>> removed(cut.begin(), cut.end());
    for (const auto& [a, b] : model.lattice.springs.pairs) {
        const std::array<std::int32_t, 2> key{std::min(a, b), std::max(a, b)};
        if (!removed.count(key)) parent[std::size_t(find(a))] = find(b);
    }
    std::vector<int> label(n);
    for (std::size_t i = 0; i < n; ++i) label[i] = find(int(i));
    return label;
}

std::size_t count_distinct(std::vector<int> labels) {
    std::sort(labels.begin(), labels.end());
    return std::size_t(std::unique(labels.begin(), labels.end()) - labels.begin());
}

struct Extent {
    Eigen::Vector3d low = Eigen::Vector3d::Constant(1e30), high = Eigen::Vector3d::Constant(-1e30);
};
Extent extent(const Model& model) {
    Extent e;
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) {
        e.low = e.low.cwiseMin(rest_of(model, i));
        e.high = e.high.cwiseMax(rest_of(model, i));
    }
    return e;
}

/// A scalpel whose blade points along +z, from `from` to `to` (tip positions), lowered for one step.
void sweep(Solver& solver, const Eigen::Vector3d& from, const Eigen::Vector3d& to, double blade_length_mm, bool lowered = true) {
    solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * blade_length_mm}});
    solver.set_pose(0, {.position = from});
    if (lowered) EXPECT_EQ(solver.begin_grab(0), 0u);
    solver.set_pose(0, {.position = to});
    solver.step(1);
    solver.release(0);
}

}  // namespace

TEST(Cutting, ASegmentCrossesATriangleOnlyThroughItsInterior) {
    InstrumentPose a, b;
    a.position = {0, 0, 0};
    b.position = {0, 10, 0};
    // Blade along +z, 4 mm, swept along +y: the square x = 0, y ∈ [0, 10], z ∈ [0, 4].
    const BladeSweep s = blade_sweep(a, b, 4.0, 0.0f);
    ASSERT_TRUE(s.cuts_anything);
    auto crosses = [&](Eigen::Vector3f p, Eigen::Vector3f q) { return spring_crosses(s, p.data(), q.data()); };
    EXPECT_TRUE(crosses({-1, 5, 2}, {1, 5, 2}));
    EXPECT_TRUE(crosses({-1, 1, 3.5f}, {1, 2, 3.5f}));     // near the other triangle's corner
    EXPECT_TRUE(crosses({-1, 9, 0.5f}, {1, 8, 0.5f}));
    EXPECT_FALSE(crosses({-1, 5, 4.5f}, {1, 5, 4.5f}));    // above the blade's end
    EXPECT_FALSE(crosses({-1, 11, 2}, {1, 11, 2}));        // beyond the sweep
    EXPECT_FALSE(crosses({0.5f, 5, 2}, {1, 5, 2}));        // both ends on one side
    EXPECT_FALSE(crosses({0, 4, 2}, {0, 6, 2}));           // in the plane: nothing to separate
    // A blade through a particle: of its two springs along x, exactly one is cut.
    EXPECT_NE(crosses({-1, 5, 2}, {0, 5, 2}), crosses({0, 5, 2}, {1, 5, 2}));
    // No area: held still, or pushed along its own axis.
    EXPECT_FALSE(blade_sweep(a, a, 4.0, 0.0f).cuts_anything);
    InstrumentPose deeper = a;
    deeper.position.z() = 3;
    EXPECT_FALSE(blade_sweep(a, deeper, 4.0, 0.0f).cuts_anything);
}

// A straight sweep right through a block cuts exactly the springs with ends on both sides of the
// blade's plane (counted here from the rest positions, without the sweep) and leaves two pieces,
// the particles on either side; set moving apart, each keeps its own momentum: nothing joins them.
TEST(Cutting, AStraightSweepThroughABlockCutsTheSpringsCrossingItsPlaneIntoTwoPieces) {
    const Model model = block(8, 5, 5);
        const Extent e = extent(model);
    const double plane_x = e.low.x() + 3.5 * 1.5 + 0.013;
    std::set<std::array<std::int32_t, 2>> expected;
    for (const auto& [a, b] : model.lattice.springs.pairs)
        if ((rest_of(model, std::size_t(a)).x() - plane_x) * (rest_of(model, std::size_t(b)).x() - plane_x) < 0)
            expected.insert({std::min(a, b), std::max(a, b)});
    ASSERT_GT(expected.size(), 50u);

    Solver solver(model.lattice, model.packing.neighbours, options_for(model));
    const double below = e.low.z() - 2.0, length = e.high.z() - e.low.z() + 4.0;
    sweep(solver, {plane_x, e.low.y() - 2.0, below}, {plane_x, e.high.y() + 2.0, below}, length);
    const auto& cut = solver.cut_springs();
    EXPECT_EQ(solver.last_cut_count(), cut.size());
    const std::set<std::array<std::int32_t, 2>> found(cut.begin(), cut.end());
    EXPECT_TRUE(found == expected);
    EXPECT_EQ(cut.size(), expected.size());

    const std::vector<int> label = pieces(model, cut);
    EXPECT_EQ(count_distinct(label), 2u);
    for (std::size_t i = 0; i < label.size(); ++i)
        for (std::size_t j = 0; j < label.size(); ++j)
            if ((rest_of(model, i).x() < plane_x) == (rest_of(model, j).x() < plane_x)) ASSERT_EQ(label[i], label[j]);

    // The right piece set moving at 0.01 mm/ms: the left one stays at rest (to float rounding of
    // its coordinates), the right one travels rigidly.
    std::vector<Eigen::Vector3d> x(label.size()), v(label.size(), Eigen::Vector3d::Zero());
    for (std::size_t i = 0; i < x.size(); ++i) {
        x[i] = rest_of(model, i);
        if (x[i].x() > plane_x) v[i] = {0.01, 0.0, 0.0};
    }
    solver.set_state(x, v);
    const int steps = 400;
    ASSERT_FALSE(solver.step(steps).diverged);
    const double travelled = steps * solver.time_step_ms() * 0.01;
    std::printf("  %zu springs cut; the right piece travelled %.3f mm\n", cut.size(), travelled);
    ASSERT_GT(travelled, 0.1);
    for (std::size_t i = 0; i < x.size(); ++i) {
        const Eigen::Vector3d moved = solver.position(i) - x[i];
        if (x[i].x() < plane_x) ASSERT_LT(moved.norm(), 1e-4) << "particle " << i << " of the left piece moved";
        else ASSERT_NEAR(moved.x(), travelled, 1e-3 * travelled) << "particle " << i << " of the right piece";
    }

    // reset_tissue heals the cut: the same sweep cuts the same springs again.
    solver.reset_tissue();
    EXPECT_TRUE(solver.cut_springs().empty());
    sweep(solver, {plane_x, e.low.y() - 2.0, below}, {plane_x, e.high.y() + 2.0, below}, length);
    EXPECT_EQ(solver.cut_springs().size(), expected.size());
}

// A lifted blade (no begin_grab) and a blade pushed along its own length cut nothing.
TEST(Cutting, ALiftedBladeAndAPlungeCutNothing) {
    const Model model = block(6, 4, 4);
    const Extent e = extent(model);
    Solver solver(model.lattice, model.packing.neighbours, options_for(model));
    const Eigen::Vector3d c = 0.5 * (e.low + e.high) + Eigen::Vector3d(0.013, 0, 0);
    sweep(solver, {c.x(), e.low.y() - 2, e.low.z() - 2}, {c.x(), e.high.y() + 2, e.low.z() - 2}, 20.0, /*lowered=*/false);
    EXPECT_TRUE(solver.cut_springs().empty());
    sweep(solver, {c.x(), c.y(), e.low.z() - 12}, {c.x(), c.y(), e.low.z() - 2}, 20.0);
    EXPECT_TRUE(solver.cut_springs().empty());
}

// A slit cut into the bottom half of a bar clamped at both ends: the bar stays one piece, and
// under load (its own weight, made heavy) the slit opens where a sagging bar's bottom is in
// tension: the particles facing each other across it part much more than in the uncut bar.
TEST(Cutting, APartialCutLeavesOnePieceWhoseSlitOpensUnderLoad) {
    const int nx = 12;
    const Model model = block(nx, 4, 6, [&](const std::array<std::int32_t, 3>& c) { return c[0] == 0 || c[0] == nx - 1; });
        const Extent e = extent(model);
    const double plane_x = 0.5 * (e.low.x() + e.high.x()) + 0.013;  // between columns 5 and 6
    SolverOptions o = options_for(model);
    o.gravity = {0.0, 0.0, -0.05};  // about five g: a sag of a few tenths of a millimetre
    o.damping = 0.02;
    o.subdivide = true;

    // The two particles facing each other across the slit on the bottom face, mid-width.
    std::size_t left = 0, right = 0;
    double best_left = 1e30, best_right = 1e30;
    const Eigen::Vector3d bottom_middle(plane_x, 0.5 * (e.low.y() + e.high.y()), e.low.z());
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) {
        const Eigen::Vector3d r = rest_of(model, i);
        const double d = (r - bottom_middle).norm();
        if (r.x() < plane_x && d < best_left) best_left = d, left = i;
        if (r.x() > plane_x && d < best_right) best_right = d, right = i;
    }
    auto settled_gap = [&](bool slit) {
        Solver solver(model.lattice, model.packing.neighbours, o);
        if (slit) {
            // The blade from below the bar up to its mid-height, swept across its whole width.
            const double below = e.low.z() - 2.0, length = 2.0 + 0.5 * (e.high.z() - e.low.z());
            sweep(solver, {plane_x, e.low.y() - 2.0, below}, {plane_x, e.high.y() + 2.0, below}, length);
            EXPECT_GT(solver.cut_springs().size(), 0u);
            EXPECT_EQ(count_distinct(pieces(model, solver.cut_springs())), 1u);
        }
        const StepReport r = solver.step(int(std::ceil(400.0 / solver.time_step_ms())));
        EXPECT_FALSE(r.diverged) << r.message;
        return (solver.position(right) - solver.position(left)).x();
    };
    const double rest_gap = (rest_of(model, right) - rest_of(model, left)).x();
    const double uncut = settled_gap(false), cut = settled_gap(true);
    std::printf("  gap across the bottom: rest %.4f mm, uncut %.4f mm, slit %.4f mm\n", rest_gap, uncut, cut);
    EXPECT_GT(cut - rest_gap, 3.0 * (uncut - rest_gap));
    EXPECT_GT(cut - rest_gap, 0.05);
}
