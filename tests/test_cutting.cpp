// The scalpel's physics cut against truths counted apart from it: the springs a straight sweep
// through a block cuts are exactly the springs whose ends lie on opposite sides of the blade's
// plane; the block falls into the two pieces on either side, which then move independently
// (momentum stays with the piece that has it); a partial cut leaves one piece whose slit opens
// under load; a lifted blade, or one pushed along itself, cuts nothing; a reset heals the cut.
// Then the abuse a user's script can do (docs/reliability.md "Cutting"): a thousand springs cut in
// one step, every spring cut, a blade of no length or of the shortest, a blade pose that is not a
// number, cutting what the other hand holds, cutting a cut again, each against counts made here
// by brute force and against Newton's laws. Last the blade's force (libmodel/sim/cutting_force.h): the
// springs a plane of any orientation crosses per unit area, counted on a lattice, and the force on
// a blade drawn at constant speed through a block, against G_c × the springs cut (counted here from
// the rest positions) × the area each stands for / the travel.
#include "libmodel/sim/cutting.h"
#include "libmodel/sim/cutting_force.h"
#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/sim/solver.h"
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
// cuts as it should (the springs across its plane) and its hand feels the cut, against its motion.
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
    // Its hand feels the cut: a finite force against the blade's motion, within G_c × its length.
    const Eigen::Vector3d f = solver.instrument_forces().hand[0].force_n;
    ASSERT_TRUE(f.allFinite());
    EXPECT_LT(f.dot(s.to.position - s.from.position), 0.0);
    EXPECT_LE(f.norm(), SolverOptions{}.cutting_resistance.toughness_n_per_mm * 2 * s.semi_axes.z());
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

// The area a cut spring stands for: a plane of normal n crosses S(n)/h² springs of the 18-neighbour
// lattice per unit area, S = 5|n₁| + 3|n₂| + |n₃| (|n₁| ≥ |n₂| ≥ |n₃|). The closed form at the
// axis, face-diagonal, body-diagonal and maximal normals, and for each of those and two oblique
// ones, the springs counted one by one across a 120 h square of the plane on the lattice Z³.
TEST(Cutting, APlaneOfAnyOrientationCrossesTheLatticesSpringsAtTheDensityTheAreaPerSpringAssumes) {
    EXPECT_DOUBLE_EQ(lattice_crossings({0, 0, 1}), 5.0);
    EXPECT_NEAR(lattice_crossings(Eigen::Vector3d(1, 1, 0).normalized()), 4 * std::sqrt(2.0), 1e-12);
    EXPECT_NEAR(lattice_crossings(Eigen::Vector3d(1, 1, 1).normalized()), 3 * std::sqrt(3.0), 1e-12);
    EXPECT_NEAR(lattice_crossings(Eigen::Vector3d(5, -3, 1).normalized()), std::sqrt(35.0), 1e-12);
    const LatticeFrame unit;  // h = 1, the world's axes
    EXPECT_DOUBLE_EQ(area_per_spring({.spacing_mm = 1.5}, {0, 1, 0}), 1.5 * 1.5 / 5);
    const std::array<Eigen::Vector3i, 9> directions{{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 0}, {1, -1, 0}, {1, 0, 1}, {1, 0, -1}, {0, 1, 1}, {0, 1, -1}}};
    for (const Eigen::Vector3d& normal : {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(1, 1, 1), Eigen::Vector3d(5, 3, 1),
                                          Eigen::Vector3d(0.3, -0.7, 0.2), Eigen::Vector3d(-0.11, 0.23, 0.91)}) {
        const Eigen::Vector3d n = normal.normalized();
        const Eigen::Vector3d c(0.31, 0.17, 0.23);  // on no lattice plane
        const Eigen::Vector3d u = n.unitOrthogonal(), w = n.cross(u);
        const double side = 120.0;
        const int reach = int(std::ceil(side / std::sqrt(2.0))) + 2;
        long long crossing = 0;
        for (int i = -reach; i <= reach; ++i)
            for (int j = -reach; j <= reach; ++j)
                for (int k = -reach; k <= reach; ++k) {
                    const Eigen::Vector3d p(i, j, k);
                    const double sp = n.dot(p - c);
                    if (std::abs(sp) > 1.5) continue;
                    for (const Eigen::Vector3i& d : directions) {
                        const Eigen::Vector3d q = p + d.cast<double>();
                        const double sq = n.dot(q - c);
                        if (!(sp * sq < 0)) continue;
                        const Eigen::Vector3d x = p + sp / (sp - sq) * (q - p);
                        if (std::abs(u.dot(x - c)) < 0.5 * side && std::abs(w.dot(x - c)) < 0.5 * side) ++crossing;
                    }
                }
        const double expected = side * side / area_per_spring(unit, n);
        std::printf("  normal (%.3f, %.3f, %.3f): %lld springs cross %.0f h², %.0f expected (S = %.4f)\n", n.x(), n.y(), n.z(), crossing,
                    side * side, expected, lattice_crossings(n));
        EXPECT_NEAR(double(crossing), expected, 0.005 * expected);
        // The lattice's axes turned with the plane: the same area per spring.
        const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
        EXPECT_NEAR(area_per_spring({.spacing_mm = 1.0, .axes = turn}, turn * n), area_per_spring(unit, n), 1e-12);
    }
}

namespace {

/// A blade along +z (identity orientation), its tip at (x, y0, z0), drawn along +x by one lattice
/// spacing per step through a 40 × 4 × 8 block at rest (no gravity: no spring ever pulls, so the
/// block stays at its rest positions and the springs a step cuts follow from them alone). For
/// every step: the force on hand 0, the springs the solver says it cut, and the springs counted
/// here from the rest positions whose crossing of the plane y = y0 lies in the step's strip of the
/// blade (x_k ≤ x < x_{k+1}, z0 ≤ z ≤ z0 + L).
struct DrawnBlade {
    std::vector<Eigen::Vector3d> force;
    std::vector<std::size_t> cut, counted;
    double spacing = 0, travel = 0, step_ms = 0;
    Eigen::Vector3d lifted_force = Eigen::Vector3d::Constant(1);
    std::size_t lifted_cut = 1;
};

DrawnBlade draw_blade(const CuttingResistance& resistance, double smoothing_in_steps) {
    const Model model = block(40, 4, 8);
    const Extent e = extent(model);
    const double h = model.lattice.spacing;
    SolverOptions options = options_for(model);
    options.cutting_resistance = resistance;
    options.cutting_resistance.smoothing_ms = smoothing_in_steps * options.dt_ms;
    if (smoothing_in_steps == 0) options.cutting_resistance.smoothing_spacings = 0;  // each step's own
    Solver solver(model.lattice, model.packing.neighbours, options);
    DrawnBlade out;
    out.spacing = h, out.travel = h, out.step_ms = solver.time_step_ms();
    const double y0 = e.low.y() + 1.37 * h, z0 = e.low.z() + 1.6 * h, length = 20.0;  // the tip inside, the end above the block
    const double x0 = e.low.x() - 2.13 * h;
    const int steps = 46;
    auto tip = [&](int k) { return Eigen::Vector3d(x0 + k * h, y0, z0); };
    solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * length}});
    solver.set_pose(0, {.position = tip(0)});
    solver.begin_grab(0);
    for (int k = 0; k < steps; ++k) {
        solver.set_pose(0, {.position = tip(k + 1)});
        EXPECT_FALSE(solver.step(1).diverged);
        const InstrumentForce f = solver.instrument_forces().hand[0];
        out.force.push_back(f.force_n);
        out.cut.push_back(f.springs_cut);
        EXPECT_EQ(f.springs_cut, solver.last_cut_count());
        std::size_t counted = 0;
        for (const auto& [a, b] : model.lattice.springs.pairs) {
            const Eigen::Vector3d p = rest_of(model, std::size_t(a)), q = rest_of(model, std::size_t(b));
            if (!((p.y() - y0) * (q.y() - y0) < 0)) continue;
            const Eigen::Vector3d x = p + (y0 - p.y()) / (q.y() - p.y()) * (q - p);
            if (x.x() >= tip(k).x() && x.x() < tip(k + 1).x() && x.z() >= z0 && x.z() <= z0 + length) ++counted;
        }
        out.counted.push_back(counted);
    }
    // Lifted: nothing at once, and nothing while it moves on.
    solver.release(0);
    out.lifted_force = solver.instrument_forces().hand[0].force_n;
    solver.set_pose(0, {.position = tip(steps + 1)});
    solver.step(1);
    out.lifted_force += solver.instrument_forces().hand[0].force_n;
    out.lifted_cut = solver.instrument_forces().hand[0].springs_cut + solver.last_cut_count();
    return out;
}

}  // namespace

// The force on a blade drawn at constant speed through a block: unsmoothed, each step's force is
// G_c × (springs cut × h²/5) / travel (the plane y = y0 is normal to a lattice axis), against the
// motion (−x); smoothed (λ = 2 spacings of travel), the energy over the travel in that window,
// computed here from those counts, and inside the block, where every step cuts as many springs, it
// settles on that step force; lifted, the blade exerts nothing.
TEST(Cutting, ABladeDrawnThroughABlockFeelsTheToughnessTimesTheAreaItCutOverItsTravelAgainstItsMotion) {
    const CuttingResistance resistance{.toughness_n_per_mm = 0.3};
    for (const double smoothing_in_steps : {0.0, 4.0}) {
        const DrawnBlade run = draw_blade(resistance, smoothing_in_steps);
        const double h = run.spacing;
        const double keep = smoothing_in_steps > 0 ? std::exp(-run.travel / (resistance.smoothing_spacings * h)) : 0.0;  // per step
        // Over the window, mJ and mm; a blade lowered starts with no energy over a spacing of travel.
        double energy = 0, travel = smoothing_in_steps > 0 ? h : 0.0;
        double largest = 0;
        std::size_t total = 0;
        for (std::size_t k = 0; k < run.force.size(); ++k) {
            ASSERT_EQ(run.cut[k], run.counted[k]) << "step " << k;
            total += run.cut[k];
            const double step_force = resistance.toughness_n_per_mm * double(run.counted[k]) * (h * h / 5) / run.travel;  // N
            energy = keep * energy + step_force * run.travel;
            travel = keep * travel + run.travel;
            const double expected = energy / travel;
            if (smoothing_in_steps == 0) ASSERT_NEAR(expected, step_force, 1e-12 * step_force);
            largest = std::max(largest, step_force);
            ASSERT_NEAR(-run.force[k].x(), expected, 1e-12 + 1e-9 * expected) << "step " << k;
            ASSERT_EQ(run.force[k].y(), 0.0);
            ASSERT_EQ(run.force[k].z(), 0.0);
        }
        // Inside the block every step cuts the same springs: the last thirty steps' count, and after
        // the window's transient (e^−15 over thirty spacings) the force is that step's force.
        const std::size_t last = run.force.size() - 8;
        const std::size_t inside = run.counted[last];
        for (std::size_t k = last - 30; k <= last; ++k) ASSERT_EQ(run.counted[k], inside) << "step " << k;
        const double settled = resistance.toughness_n_per_mm * double(inside) * (h * h / 5) / h;
        EXPECT_NEAR(-run.force[last].x(), settled, 1e-3 * settled);
        std::printf("  %s: %zu springs cut, %zu a step inside the block; force %.4f N there (G_c × %zu × h²/5 / h = %.4f N)\n",
                    smoothing_in_steps > 0 ? "smoothed" : "each step's own", total, inside, -run.force[last].x(), inside, settled);
        EXPECT_GT(inside, 20u);
        EXPECT_GT(largest, 0.1);
        EXPECT_EQ(run.lifted_force, Eigen::Vector3d::Zero());
        EXPECT_EQ(run.lifted_cut, 0u);
    }
    // No toughness, no force (the springs are cut all the same).
    const DrawnBlade free = draw_blade({.toughness_n_per_mm = 0.0}, 4.0);
    for (std::size_t k = 0; k < free.force.size(); ++k) ASSERT_EQ(free.force[k], Eigen::Vector3d::Zero());
    EXPECT_GT(std::accumulate(free.cut.begin(), free.cut.end(), std::size_t(0)), 100u);
}

// A blade that moves at some steps only (its pose updated less often than the steps run, as a
// 1 kHz device's between faster steps) feels what one moving at every step feels: the energy
// over the distance of its last two spacings of travel. Held still in the tissue, it keeps the force of its cut
// until its smoothed speed falls below v_min, then lets go (the force fades as the speed squared).
// A blade turned about its middle (its midpoint still) gets no force; one turned about its tip the
// whole cut's; more springs than a whole blade drawn across its length sweeps count as that many.
TEST(Cutting, TheBladesForceIsTheEnergyOverTheDistanceOfItsLastSpacingsAndLetsGoOfAStoppedBlade) {
    const Model model = block(40, 4, 8);
    const Extent e = extent(model);
    const double h = model.lattice.spacing;
    SolverOptions options = options_for(model);
    options.cutting_resistance.smoothing_ms = 8 * options.dt_ms;
    const double y0 = e.low.y() + 1.37 * h, z0 = e.low.z() + 1.6 * h, length = 20.0, x0 = e.low.x() + 5.13 * h;
    // Every step one spacing, against two spacings every second step (standing still between).
    auto drawn = [&](int every, int steps) {
        Solver solver(model.lattice, model.packing.neighbours, options);
        solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * length}});
        solver.set_pose(0, {.position = {x0, y0, z0}});
        solver.begin_grab(0);
        std::vector<Eigen::Vector3d> force;
        for (int k = 0; k < steps; ++k) {
            solver.set_pose(0, {.position = {x0 + double((k + 1) / every * every) * h, y0, z0}});
            solver.step(1);
            force.push_back(solver.instrument_forces().hand[0].force_n);
        }
        return force;
    };
    const std::vector<Eigen::Vector3d> smooth = drawn(1, 24), stutter = drawn(2, 24);
    const double settled = options.cutting_resistance.toughness_n_per_mm * 29 * (h * h / 5) / h;  // 29 springs a spacing (the test above)
    EXPECT_NEAR(-smooth.back().x(), settled, 0.01 * settled);
    EXPECT_NEAR(-stutter.back().x(), settled, 0.01 * settled);
    std::printf("  drawn every step: %.4f N; every second step, standing still between: %.4f N and %.4f N (G_c × 29 × h²/5 / h = %.4f N)\n",
                -smooth.back().x(), -stutter[stutter.size() - 2].x(), -stutter.back().x(), settled);

    // Held still: the same force at the next step, and let go once the smoothed speed is far below v_min.
    Solver solver(model.lattice, model.packing.neighbours, options);
    solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * length}});
    solver.set_pose(0, {.position = {x0, y0, z0}});
    solver.begin_grab(0);
    solver.set_pose(0, {.position = {x0 + h, y0, z0}});
    solver.step(1);
    const Eigen::Vector3d first = solver.instrument_forces().hand[0].force_n;
    EXPECT_LT(first.x(), -0.1);
    solver.step(1);
    EXPECT_EQ(solver.last_cut_count(), 0u);
    EXPECT_NEAR(solver.instrument_forces().hand[0].force_n.x(), first.x(), 1e-9 * first.norm());
    const double speed = (1 - std::exp(-1.0 / 8)) * h / solver.time_step_ms();  // after the one moving step
    const int until = int(std::ceil(8 * std::log(10 * speed / options.cutting_resistance.min_speed_mm_per_ms)));
    solver.step(until);
    EXPECT_LT(solver.instrument_forces().hand[0].force_n.norm(), 0.011 * first.norm());
    std::printf("  held still: %.4f N, after %d steps %.2g N\n", -first.x(), until, solver.instrument_forces().hand[0].force_n.norm());

    // Turned a quarter turn about its middle in one step: it cuts, but its midpoint stays put (to
    // rounding): no force a 3-DOF device could render.
    const Eigen::Vector3d c(x0, y0, e.low.z() + 2.1 * h);
    const double short_blade = 4.0;
    Solver turned(model.lattice, model.packing.neighbours, options);
    const Eigen::Vector3d middle = c + Eigen::Vector3d(0, 0, 0.5 * short_blade);
    const Eigen::Quaterniond quarter(Eigen::AngleAxisd(0.5 * M_PI, Eigen::Vector3d::UnitX()));
    turned.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * short_blade}});
    turned.set_pose(0, {.position = c});
    turned.begin_grab(0);
    turned.set_pose(0, {.position = middle - quarter * Eigen::Vector3d(0, 0, 0.5 * short_blade), .orientation = quarter});
    turned.step(1);
    EXPECT_GT(turned.last_cut_count(), 0u);
    EXPECT_LT(turned.instrument_forces().hand[0].force_n.norm(), 1e-12);
    // Turned about its tip: its midpoint moves half as far as its end, the mean travel of its two
    // ends, so the whole cut is paid by a force against the midpoint's motion.
    const BladeStep about_tip = blade_step(options.cutting_resistance, turned.lattice_frame(), {.position = c},
                                           {.position = c, .orientation = quarter}, short_blade, 1.0);
    const Eigen::Vector3d end_motion = quarter * Eigen::Vector3d(0, 0, short_blade) - Eigen::Vector3d(0, 0, short_blade);
    EXPECT_NEAR(about_tip.motion_rate.norm(), about_tip.travel_rate, 1e-12);
    EXPECT_NEAR(about_tip.travel_rate, 0.5 * end_motion.norm(), 1e-12);
    EXPECT_NEAR(about_tip.motion_rate.normalized().dot(end_motion.normalized()), 1.0, 1e-12);
    // The cap: a whole blade drawn across its length through tissue, G_c × its length, however many
    // springs are counted.
    BladeStep across = blade_step(options.cutting_resistance, turned.lattice_frame(), {.position = c}, {.position = c + Eigen::Vector3d(0.2, 0, 0)},
                                  short_blade, 0.5);
    across.keep = 0, across.alpha = 1;
    const double cap = options.cutting_resistance.toughness_n_per_mm * short_blade;
    EXPECT_NEAR(blade_force(next_blade_state({}, across, 100000), options.cutting_resistance, short_blade).norm(), cap, 1e-12 * cap);
    EXPECT_LT(blade_force(next_blade_state({}, across, 1), options.cutting_resistance, short_blade).norm(), cap);
}
