// The scalpel's physics cut against truths counted apart from it: the springs a straight sweep
// through a block cuts are exactly the springs whose ends lie on opposite sides of the blade's
// plane; the block falls into the two pieces on either side, which then move independently
// (momentum stays with the piece that has it); a partial cut leaves one piece whose slit opens
// under load; a lifted blade, or one pushed along itself, cuts nothing; a reset heals the cut.
// Then the abuse a user's script can do (docs/reliability.md "Cutting"): a thousand springs cut in
// one step, every spring cut, a blade of no length or of the shortest, a blade pose that is not a
// number, cutting what the other hand holds, cutting a cut again, each against counts made here
// by brute force and against Newton's laws.
#include "libmodel/cutting.h"
#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/solver.h"
#include "libmodel/stability.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
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

// ------------------------------------------------------------------------------------------------
// Abuse

namespace {

/// The plane through `point` with unit normal `normal`.
struct Plane {
    Eigen::Vector3d point, normal;
    double distance(const Eigen::Vector3d& x) const { return (x - point).dot(normal); }
};

/// The springs whose rest ends lie strictly on opposite sides of `plane` (lower index first),
/// counted by brute force in double, without the blade.
std::set<std::array<std::int32_t, 2>> springs_across(const Model& model, const Plane& plane) {
    std::set<std::array<std::int32_t, 2>> across;
    for (const auto& [a, b] : model.lattice.springs.pairs)
        if (plane.distance(rest_of(model, std::size_t(a))) * plane.distance(rest_of(model, std::size_t(b))) < 0)
            across.insert({std::min(a, b), std::max(a, b)});
    return across;
}

/// The nearest any rest position comes to `plane`, mm: the plane must keep clear of the particles
/// for a float test and a double count to agree on every spring.
double clearance(const Model& model, const Plane& plane) {
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) nearest = std::min(nearest, std::abs(plane.distance(rest_of(model, i))));
    return nearest;
}

/// A blade `size` mm long lying in `plane`, centred on its point, drawn `size` mm across it: the
/// square it sweeps covers everything within size/2 of the point. From, to: its two poses.
struct PlaneSweep {
    InstrumentPose from, to;
    Eigen::Vector3d semi_axes;
};
PlaneSweep square_sweep(const Plane& plane, double size) {
    const Eigen::Vector3d helper = std::abs(plane.normal.y()) < 0.9 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitX();
    const Eigen::Vector3d blade = plane.normal.cross(helper).normalized();  // in the plane
    const Eigen::Vector3d across = plane.normal.cross(blade);               // in the plane, ⟂ blade
    PlaneSweep s;
    s.from.orientation = s.to.orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), blade);
    s.from.position = plane.point - 0.5 * size * blade - 0.5 * size * across;
    s.to.position = s.from.position + size * across;
    s.semi_axes = {1.0, 0.2, 0.5 * size};
    return s;
}

/// One step in which each given hand's lowered scalpel makes its sweep; the blades lift after it.
StepReport cut_in_one_step(Solver& solver, const std::vector<std::pair<int, PlaneSweep>>& sweeps) {
    for (const auto& [hand, s] : sweeps) {
        solver.set_instrument(hand, {.kind = InstrumentKind::scalpel, .semi_axes = s.semi_axes});
        solver.set_pose(hand, s.from);
        EXPECT_EQ(solver.begin_grab(hand), 0u);
        solver.set_pose(hand, s.to);
    }
    const StepReport report = solver.step(1);
    for (const auto& [hand, s] : sweeps) solver.release(hand);
    return report;
}

bool all_finite(const Solver& solver) {
    for (const auto& p : solver.positions())
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return false;
    return true;
}

bool forces_finite(const Solver& solver) {
    const InstrumentForces f = solver.instrument_forces();
    return f.hand[0].force_n.allFinite() && f.hand[1].force_n.allFinite();
}

/// The cut list as a set; fails the test if a spring is listed twice or not lower index first.
std::set<std::array<std::int32_t, 2>> cut_set(const Solver& solver) {
    const auto& list = solver.cut_springs();
    const std::set<std::array<std::int32_t, 2>> set(list.begin(), list.end());
    EXPECT_EQ(set.size(), list.size()) << "a spring is listed twice";
    for (const auto& [a, b] : list) EXPECT_LT(a, b);
    return set;
}

Eigen::Vector3d centre_of_mass(const Model& model, const Solver& solver, const std::vector<std::size_t>& which) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double mass = 0;
    for (std::size_t i : which) {
        const double m = model.lattice.particles.mass[i];
        sum += m * solver.position(i), mass += m;
    }
    return sum / mass;
}

}  // namespace

// One blade, 3 model diagonals long, drawn 3 diagonals in one step through a block of 1,960
// particles along a plane tilted to every lattice axis: it cuts every spring whose ends lie on
// either side of the plane (over a thousand, counted here from the rest positions), each once,
// and nothing else. The block's left face is anchored; the piece beyond the plane falls free under
// gravity: no spring joins it to the left piece any more, so the forces on it sum to zero (only
// its internal springs act, in equal and opposite pairs) and its centre of mass falls exactly as
// ½·g·t² while the particles in it stay finite and the watchdog stays quiet.
TEST(Cutting, AThousandSpringsCutInOneStepAreTheSpringsAcrossTheBladesPlaneAndTheSeveredPieceFallsFree) {
    const Model model = block(10, 14, 14, [](const std::array<std::int32_t, 3>& c) { return c[0] == 0; });
    const Extent e = extent(model);
    const Plane plane{0.5 * (e.low + e.high) + Eigen::Vector3d(0.0137, 0.0, 0.0), Eigen::Vector3d(1.0, 0.2, 0.1).normalized()};
    ASSERT_GT(clearance(model, plane), 1e-3);
    const auto expected = springs_across(model, plane);
    std::printf("  %zu springs cross the plane\n", expected.size());
    ASSERT_GE(expected.size(), 1000u);

    SolverOptions o = options_for(model);
    o.gravity = {0.0, 9.81e-3, 0.0};
    Solver solver(model.lattice, model.packing.neighbours, o);
    const double diagonal = (e.high - e.low).norm();
    const StepReport report = cut_in_one_step(solver, {{0, square_sweep(plane, 3.0 * diagonal)}});
    EXPECT_FALSE(report.diverged) << report.message;
    EXPECT_EQ(solver.last_cut_count(), expected.size());
    EXPECT_TRUE(cut_set(solver) == expected);

    // Two pieces, split by the plane.
    const std::vector<int> label = pieces(model, solver.cut_springs());
    EXPECT_EQ(count_distinct(label), 2u);
    std::vector<std::size_t> severed;
    for (std::size_t i = 0; i < label.size(); ++i) {
        if (plane.distance(rest_of(model, i)) > 0) severed.push_back(i);
        ASSERT_EQ(label[i] == label[0], plane.distance(rest_of(model, i)) < 0) << "particle " << i;
    }
    ASSERT_GT(severed.size(), 500u);

    const Eigen::Vector3d start = centre_of_mass(model, solver, severed);
    const double start_ms = solver.simulated_time_ms();
    const int steps = int(std::ceil(6.0 / solver.time_step_ms()));
    const StepReport fall = solver.step(steps);
    EXPECT_FALSE(fall.diverged) << fall.message;
    EXPECT_EQ(solver.watchdog_events(), 0u);
    ASSERT_TRUE(all_finite(solver));
    // From rest at t = 0 (the cut came before the first substep), so the fall is ½·g·t² from the
    // rest centre of mass (start is one step in).
    const double t = solver.simulated_time_ms();
    Eigen::Vector3d rest_centre = Eigen::Vector3d::Zero();
    double mass = 0;
    for (std::size_t i : severed) rest_centre += double(model.lattice.particles.mass[i]) * rest_of(model, i), mass += model.lattice.particles.mass[i];
    rest_centre /= mass;
    const Eigen::Vector3d expected_centre = rest_centre + 0.5 * o.gravity * t * t;
    const Eigen::Vector3d centre = centre_of_mass(model, solver, severed);
    std::printf("  the severed piece fell %.4f mm in %.2f ms (½gt² = %.4f mm; %.4f mm at the cut, t = %.3f ms)\n", (centre - rest_centre).y(), t,
                0.5 * o.gravity.y() * t * t, (start - rest_centre).y(), start_ms);
    ASSERT_GT(0.5 * o.gravity.y() * t * t, 0.1);
    EXPECT_LE((centre - expected_centre).norm(), 1e-3 * 0.5 * o.gravity.norm() * t * t);
    Eigen::Vector3d net = Eigen::Vector3d::Zero();
    double magnitude = 0;
    for (std::size_t i : severed) {
        const Eigen::Vector3d f = solver.particle_force(i);
        net += f, magnitude += f.norm();
    }
    std::printf("  forces on the severed piece: net %.3g N, Σ|f| %.3g N\n", net.norm(), magnitude);
    EXPECT_LE(net.norm(), 1e-4 * magnitude + 1e-9);
}

// A sweep between every two neighbouring layers along x, y and z cuts every spring of the block
// (each listed once, whichever plane reached it first): no spring is left, so no force acts on any
// particle, the elastic energy is zero, and under gravity every particle falls as ½·g·t² from
// where it rested, finite, without a watchdog event. reset() then heals every cut: the solver is
// the solver it was made as, bit for bit, and steps as a fresh one does.
TEST(Cutting, EverySpringCutLeavesFreeParticlesThatFallAndAResetHealsThemAll) {
    const Model model = block(5, 4, 4);
    const Extent e = extent(model);
    SolverOptions o = options_for(model);
    o.gravity = {0.0, 0.0, -9.81e-3};
    Solver solver(model.lattice, model.packing.neighbours, o);
    const std::uint64_t fresh_hash = solver.state_hash();

    std::set<std::array<std::int32_t, 2>> all;
    for (const auto& [a, b] : model.lattice.springs.pairs) all.insert({std::min(a, b), std::max(a, b)});
    const double size = 3.0 * (e.high - e.low).norm();
    int planes = 0;
    for (int axis = 0; axis < 3; ++axis) {
        std::set<double> layers;
        for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) layers.insert(rest_of(model, i)[axis]);
        for (auto it = layers.begin(); std::next(it) != layers.end(); ++it) {
            Plane plane{0.5 * (e.low + e.high), Eigen::Vector3d::Unit(axis)};
            plane.point[axis] = 0.5 * (*it + *std::next(it));
            const StepReport r = cut_in_one_step(solver, {{planes % 2, square_sweep(plane, size)}});
            ASSERT_FALSE(r.diverged) << r.message;
            ++planes;
        }
    }
    const auto cut = cut_set(solver);
    std::printf("  %d sweeps cut %zu of %zu springs\n", planes, cut.size(), all.size());
    EXPECT_TRUE(cut == all);
    EXPECT_EQ(count_distinct(pieces(model, solver.cut_springs())), model.lattice.particles.size());
    EXPECT_EQ(solver.energy().elastic, 0.0);
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i) ASSERT_EQ(solver.particle_force(i), Eigen::Vector3d::Zero()) << i;

    const StepReport fall = solver.step(int(std::ceil(6.0 / solver.time_step_ms())));
    EXPECT_FALSE(fall.diverged) << fall.message;
    EXPECT_EQ(solver.watchdog_events(), 0u);
    ASSERT_TRUE(all_finite(solver));
    const double t = solver.simulated_time_ms();
    const Eigen::Vector3d drop = 0.5 * o.gravity * t * t;
    ASSERT_GT(drop.norm(), 0.1);
    for (std::size_t i = 0; i < model.lattice.particles.size(); ++i)
        ASSERT_LE((solver.position(i) - (rest_of(model, i) + drop)).norm(), 1e-3 * drop.norm() + 1e-4) << "particle " << i;

    solver.reset();
    EXPECT_TRUE(solver.cut_springs().empty());
    EXPECT_EQ(solver.state_hash(), fresh_hash);
    Solver fresh(model.lattice, model.packing.neighbours, o);
    for (Solver* s : {&solver, &fresh}) {
        // A grabber that pulls the block's middle: the healed springs must carry the pull as new ones do.
        s->set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(2.0)});
        s->set_pose(1, {.position = 0.5 * (e.low + e.high)});
        s->begin_grab(1);
        s->set_pose(1, {.position = 0.5 * (e.low + e.high) + Eigen::Vector3d(0, 0, 1.0)});
        s->step(20);
    }
    EXPECT_EQ(solver.state_hash(), fresh.state_hash());
    EXPECT_EQ(solver.instrument_forces().hand[1].force_n, fresh.instrument_forces().hand[1].force_n);
    EXPECT_GT(solver.instrument_forces().hand[1].force_n.norm(), 0.0);
}

// A blade of no length is refused (the instrument kept as it was), and so is a blade whose length
// is not a number. The shortest blade a trajectory may give (semi-axis 1e-3 mm: 2 µm) cuts only
// the springs whose crossing of its plane lies in the 2 µm strip it sweeps: none in a strip
// between the crossings, and in one around a layer of particles exactly the springs that cross
// the plane at that layer's height (the crossing points computed here in double).
TEST(Cutting, ABladeOfNoLengthIsRefusedAndTheShortestCutsOnlyWhatItsStripCrosses) {
    const Model model = block(6, 4, 4);
    const Extent e = extent(model);
    Solver solver(model.lattice, model.packing.neighbours, options_for(model));
    for (const double bad : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
        try {
            solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {1.0, 0.2, bad}});
            ADD_FAILURE() << "a blade with semi-axis " << bad << " was taken";
        } catch (const InputError& error) {
            EXPECT_NE(std::string(error.what()).find("semi-axes must be positive and finite"), std::string::npos) << error.what();
        }
        EXPECT_EQ(solver.instrument(0).kind, InstrumentKind::none);
    }
    InstrumentPose still;
    EXPECT_FALSE(blade_sweep(still, {.position = {0, 10, 0}}, 0.0, 1.0f).cuts_anything);

    const double plane_x = e.low.x() + 2.5 * 1.5 + 0.013;
    const double layer_z = e.low.z() + 1.5;  // the second layer
    const double semi = 1e-3, length = 2 * semi;
    auto crossing_in_strip = [&](double z0) {
        std::set<std::array<std::int32_t, 2>> expected;
        for (const auto& [a, b] : model.lattice.springs.pairs) {
            const Eigen::Vector3d p = rest_of(model, std::size_t(a)), q = rest_of(model, std::size_t(b));
            if ((p.x() - plane_x) * (q.x() - plane_x) >= 0) continue;
            const Eigen::Vector3d at = p + (plane_x - p.x()) / (q.x() - p.x()) * (q - p);
            if (at.z() > z0 && at.z() < z0 + length) expected.insert({std::min(a, b), std::max(a, b)});
        }
        return expected;
    };
    for (const double z0 : {layer_z + 0.3, layer_z - semi}) {
        solver.reset();
        sweep(solver, {plane_x, e.low.y() - 2.0, z0}, {plane_x, e.high.y() + 2.0, z0}, length);
        const auto expected = crossing_in_strip(z0);
        std::printf("  a 2 µm blade at z0 = %.4f mm: %zu springs cut, %zu cross its strip\n", z0, solver.cut_springs().size(), expected.size());
        EXPECT_TRUE(cut_set(solver) == expected);
    }
    EXPECT_GT(crossing_in_strip(layer_z - semi).size(), 5u);
    EXPECT_TRUE(crossing_in_strip(layer_z + 0.3).empty());
}

// A blade pose that is not a number (NaN or infinite position, NaN or zero quaternion) is refused
// with a message that says so, while the blade is lowered and mid-gesture: the blade stays where
// it was, nothing is cut by it, and no position or force ever holds a NaN. The same blade then
// cuts as it should (the springs across its plane) and its hand feels no force.
TEST(Cutting, ANonFiniteBladePoseIsRefusedAndNothingNonFiniteReachesTheStateOrTheForces) {
    const Model model = block(6, 4, 4);
    const Extent e = extent(model);
    const Plane plane{0.5 * (e.low + e.high) + Eigen::Vector3d(0.0137, 0, 0), Eigen::Vector3d::UnitX()};
    Solver solver(model.lattice, model.packing.neighbours, options_for(model));
    const PlaneSweep s = square_sweep(plane, 3.0 * (e.high - e.low).norm());
    solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = s.semi_axes});
    solver.set_pose(0, s.from);
    solver.begin_grab(0);
    const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
    std::vector<InstrumentPose> bad(5, s.from);
    bad[0].position.x() = nan;
    bad[1].position.z() = inf;
    bad[2].position.y() = -inf;
    bad[3].orientation = Eigen::Quaterniond(nan, 0, 0, 0);
    bad[4].orientation = Eigen::Quaterniond(0, 0, 0, 0);
    for (const InstrumentPose& pose : bad) {
        try {
            solver.set_pose(0, pose);
            ADD_FAILURE() << "a non-finite blade pose was taken";
        } catch (const InputError& error) {
            EXPECT_NE(std::string(error.what()).find("must be finite with a non-zero quaternion"), std::string::npos) << error.what();
        }
        const StepReport r = solver.step(1);
        EXPECT_FALSE(r.diverged) << r.message;
        EXPECT_TRUE(solver.cut_springs().empty());
        ASSERT_TRUE(all_finite(solver));
        ASSERT_TRUE(forces_finite(solver));
        EXPECT_EQ(solver.energy().total(), solver.energy().total());  // not NaN
    }
    solver.set_pose(0, s.to);
    solver.step(1);
    EXPECT_TRUE(cut_set(solver) == springs_across(model, plane));
    EXPECT_GT(solver.cut_springs().size(), 20u);
    ASSERT_TRUE(all_finite(solver));
    EXPECT_EQ(solver.instrument_forces().hand[0].force_n, Eigen::Vector3d::Zero());
}

// One hand holds the middle of a bar clamped at both ends and lifts it while the other cuts right
// through what it holds: the cut is the springs across the blade's plane, and the held particles
// stay held, each exactly where the grabber carries it (its rest position plus the lift), and
// finite; released, the two halves hang from their clamps, finite, without a watchdog event.
TEST(Cutting, CuttingWhatTheOtherHandHoldsKeepsItHeld) {
    const int nx = 10;
    const Model model = block(nx, 5, 5, [&](const std::array<std::int32_t, 3>& c) { return c[0] == 0 || c[0] == nx - 1; });
    const Extent e = extent(model);
    const Eigen::Vector3d middle = 0.5 * (e.low + e.high);
    const Plane plane{middle + Eigen::Vector3d(0.0137, 0, 0), Eigen::Vector3d(1.0, 0.1, -0.05).normalized()};
    ASSERT_GT(clearance(model, plane), 1e-3);
    SolverOptions o = options_for(model);
    o.damping = 0.05;
    Solver solver(model.lattice, model.packing.neighbours, o);
    solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(2.6)});
    solver.set_pose(1, {.position = middle});
    const std::size_t held = solver.begin_grab(1);
    ASSERT_GT(held, 10u);
    const std::vector<std::int32_t> grabbed = solver.contact_particles(1);
    bool straddles[2] = {false, false};
    for (std::int32_t i : grabbed) straddles[plane.distance(rest_of(model, std::size_t(i))) > 0] = true;
    ASSERT_TRUE(straddles[0] && straddles[1]) << "the blade must pass through what the grabber holds";

    const Eigen::Vector3d lift(0.0, 0.0, 1.0);
    solver.set_pose(1, {.position = middle + lift});
    cut_in_one_step(solver, {{0, square_sweep(plane, 3.0 * (e.high - e.low).norm())}});
    EXPECT_TRUE(cut_set(solver) == springs_across(model, plane));
    const StepReport r = solver.step(40);
    EXPECT_FALSE(r.diverged) << r.message;
    ASSERT_TRUE(all_finite(solver));
    ASSERT_TRUE(forces_finite(solver));
    if (solver.watchdog_events() == 0) {
        EXPECT_EQ(solver.contact_particles(1), grabbed);
        for (std::int32_t i : grabbed)
            ASSERT_LE((solver.position(std::size_t(i)) - (rest_of(model, std::size_t(i)) + lift)).norm(), 1e-4) << "particle " << i;
    } else {
        EXPECT_TRUE(solver.contact_particles(1).empty()) << "a restore left particles held";
    }
    solver.release(1);
    const StepReport hang = solver.step(int(std::ceil(20.0 / solver.time_step_ms())));
    EXPECT_FALSE(hang.diverged) << hang.message;
    EXPECT_EQ(solver.watchdog_events(), 0u);
    ASSERT_TRUE(all_finite(solver));
    EXPECT_EQ(count_distinct(pieces(model, solver.cut_springs())), 2u);
}

// Cutting a cut again cuts nothing new: the same sweep, the sweep drawn back, and two scalpels
// drawn along the same plane in one step each leave the list as one cut makes it, each spring
// listed once.
TEST(Cutting, CuttingACutAgainCutsNothingNewAndListsEachSpringOnce) {
    const Model model = block(6, 5, 5);
    const Extent e = extent(model);
    const Plane plane{0.5 * (e.low + e.high) + Eigen::Vector3d(0.0137, 0, 0), Eigen::Vector3d(1.0, -0.15, 0.2).normalized()};
    ASSERT_GT(clearance(model, plane), 1e-3);
    const auto expected = springs_across(model, plane);
    const PlaneSweep s = square_sweep(plane, 3.0 * (e.high - e.low).norm());
    PlaneSweep back = s;
    std::swap(back.from, back.to);

    Solver solver(model.lattice, model.packing.neighbours, options_for(model));
    cut_in_one_step(solver, {{0, s}});
    EXPECT_TRUE(cut_set(solver) == expected);
    for (const PlaneSweep& again : {s, back}) {
        cut_in_one_step(solver, {{0, again}});
        EXPECT_EQ(solver.last_cut_count(), 0u);
        EXPECT_EQ(solver.cut_springs().size(), expected.size());
    }
    cut_in_one_step(solver, {{0, s}, {1, back}});
    EXPECT_EQ(solver.last_cut_count(), 0u);
    EXPECT_TRUE(cut_set(solver) == expected);

    // Both hands through the same uncut plane in one step: each spring once.
    Solver both(model.lattice, model.packing.neighbours, options_for(model));
    cut_in_one_step(both, {{0, s}, {1, back}});
    EXPECT_EQ(both.last_cut_count(), expected.size());
    EXPECT_TRUE(cut_set(both) == expected);
    EXPECT_EQ(both.cut_springs().size(), expected.size());
}
