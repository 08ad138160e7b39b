// The detailed mesh opened along a cut, against truths that need no cutting code: a box's volume
// (each piece's enclosed volume from the divergence theorem, summing to the box's less the slit),
// the blade's plane (the caps lie on it), Euler's count of closed pieces (connected components),
// and the solver's own pieces (each side's vertices carried by the particles on that side only,
// so when one piece moves rigidly its vertices move with it and the other's stay put).
#include "libmodel/surgery/incision.h"
#include "libmodel/surgery/incision_state.h"
#include "libmodel/mapping.h"
#include "libmodel/packing.h"
#include "libmodel/simulation_surface.h"
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "box_mesh.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <functional>
#include <map>
#include <numeric>

using namespace heartsim;
using test::box_mesh;
using test::BoxMesh;

namespace {

/// Connected components of a triangle list (through shared vertices): a label per vertex used.
std::vector<int> components(const std::vector<std::array<std::int32_t, 3>>& triangles, std::size_t vertices) {
    std::vector<int> parent(vertices);
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int a) {
        while (parent[std::size_t(a)] != a) a = parent[std::size_t(a)] = parent[std::size_t(parent[std::size_t(a)])];
        return a;
    };
    for (const auto& t : triangles) {
        parent[std::size_t(find(t[1]))] = find(t[0]);
        parent[std::size_t(find(t[2]))] = find(t[0]);
    }
    std::vector<int> label(vertices);
    for (std::size_t v = 0; v < vertices; ++v) label[v] = find(int(v));
    return label;
}

std::size_t count_components(const std::vector<std::array<std::int32_t, 3>>& triangles, std::size_t vertices) {
    const std::vector<int> label = components(triangles, vertices);
    std::vector<int> roots;
    for (const auto& t : triangles) roots.push_back(label[std::size_t(t[0])]);
    std::sort(roots.begin(), roots.end());
    return std::size_t(std::unique(roots.begin(), roots.end()) - roots.begin());
}

/// The plane x = `x`, as a strip of two triangles reaching `margin` beyond [low, high] in y and
/// z from `z_from` to `z_to`: its normal is +x (the + side).
CutSurface plane_x(double x, const Eigen::Vector3d& low, const Eigen::Vector3d& high, double z_from, double z_to, double margin) {
    CutSurface s;
    s.points = {{x, low.y() - margin, z_from}, {x, high.y() + margin, z_from}, {x, high.y() + margin, z_to}, {x, low.y() - margin, z_to}};
    s.triangles = {{0, 1, 2}, {0, 2, 3}};
    return s;
}

}  // namespace

// closed_manifold's check of the faces from `from` on (open_along's check of its patch and caps)
// against its definition counted face by face: each directed edge of those faces occurs once among
// all the faces and its reverse once, else the message names the lowest offending edge. A closed
// box, then the box with a face flipped, dropped or doubled before, at and after `from`.
TEST(Incision, TheCheckOfTheAddedFacesAgreesWithEdgeCountsOverTheWholeMesh) {
    const BoxMesh box = box_mesh(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(3, 2, 2), 0.5);
    using Triangles = std::vector<std::array<std::int32_t, 3>>;
    auto expected = [](const Triangles& triangles, std::size_t from, std::string& why) {
        auto count = [&](std::int32_t a, std::int32_t b) {
            int n = 0;
            for (const auto& t : triangles)
                for (std::size_t k = 0; k < 3; ++k) n += t[k] == a && t[(k + 1) % 3] == b;
            return n;
        };
        bool closed = true;
        std::pair<std::int32_t, std::int32_t> lowest;
        for (std::size_t t = from; t < triangles.size(); ++t)
            for (std::size_t k = 0; k < 3; ++k) {
                const std::pair<std::int32_t, std::int32_t> e{triangles[t][k], triangles[t][(k + 1) % 3]};
                if (count(e.first, e.second) == 1 && count(e.second, e.first) == 1) continue;
                if (closed || e < lowest) lowest = e;
                closed = false;
            }
        if (!closed)
            why = "edge (" + std::to_string(lowest.first) + ", " + std::to_string(lowest.second) + ") occurs " +
                  std::to_string(count(lowest.first, lowest.second)) + " time(s), its reverse " + std::to_string(count(lowest.second, lowest.first));
        return closed;
    };
    const std::size_t n = box.triangles.size();
    ASSERT_GT(n, 40u);
    std::vector<std::pair<std::string, Triangles>> cases{{"closed", box.triangles}};
    for (const std::size_t at : {std::size_t(3), n / 2, n - 2}) {
        Triangles flipped = box.triangles, dropped = box.triangles, doubled = box.triangles;
        std::swap(flipped[at][1], flipped[at][2]);
        dropped.erase(dropped.begin() + std::ptrdiff_t(at));
        doubled.push_back(doubled[at]);
        cases.push_back({"flipped " + std::to_string(at), flipped});
        cases.push_back({"dropped " + std::to_string(at), dropped});
        cases.push_back({"doubled " + std::to_string(at), doubled});
    }
    int broken = 0;
    for (const auto& [name, triangles] : cases)
        for (const std::size_t from : {std::size_t(1), std::size_t(4), n / 2, n / 2 + 1, n - 3}) {
            std::string want, got;
            const bool closed = expected(triangles, from, want);
            broken += !closed;
            EXPECT_EQ(closed_manifold(triangles, &got, from), closed) << name << ", from " << from;
            EXPECT_EQ(got, want) << name << ", from " << from;
            EXPECT_EQ(closed_manifold(triangles, nullptr, from), closed) << name << ", from " << from;
        }
    EXPECT_GT(broken, 20);  // the broken faces mostly lie among the checked ones
}

// A plane right through a box: two closed pieces whose volumes sum to the box's, less the slit's
// (gap × cross-section), within 1 %; every cap vertex on the plane (within the slit's half width);
// every vertex away from the plane exactly where it was.
TEST(Incision, APlaneThroughABoxLeavesTwoClosedPiecesOfTheBoxsVolume) {
    const Eigen::Vector3d low(0, 0, 0), high(18, 9, 6);
    const BoxMesh box = box_mesh(low, high, 0.75);
    IncisionMesh mesh = incision_mesh(box.positions, {}, box.triangles);
    ASSERT_TRUE(closed_manifold(mesh.triangles));
    const double gap = 0.03, x = 7.3;
    const IncisionResult result = open_along(mesh, plane_x(x, low, high, -2.0, 8.0, 2.0), gap);
    ASSERT_TRUE(result.opened) << result.failure;
    std::string why;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
    EXPECT_EQ(count_components(mesh.triangles, mesh.rest.size()), 2u);
    // The pieces' volumes.
    const std::vector<int> label = components(mesh.triangles, mesh.rest.size());
    std::map<int, std::vector<std::array<std::int32_t, 3>>> piece;
    for (const auto& t : mesh.triangles) piece[label[std::size_t(t[0])]].push_back(t);
    ASSERT_EQ(piece.size(), 2u);
    double total = 0.0;
    for (const auto& [root, triangles] : piece) {
        const double volume = enclosed_volume(mesh.rest, triangles);
        EXPECT_GT(volume, 0.0) << "a piece is inside out";
        const bool left = mesh.rest[std::size_t(root)].x() < x;
        const double expected = (left ? x - 0.5 * gap : high.x() - x - 0.5 * gap) * high.y() * high.z();
        EXPECT_NEAR(volume, expected, 1e-3 * expected);
        total += volume;
    }
    const double box_volume = high.prod();
    EXPECT_NEAR(total, box_volume - gap * high.y() * high.z(), 0.01 * box_volume);
    // The caps on the plane; each side's cap facing away from its own piece.
    std::size_t caps = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        if (!mesh.cap[t]) continue;
        ++caps;
        const auto& tri = mesh.triangles[t];
        const Eigen::Vector3d n = (mesh.rest[std::size_t(tri[1])] - mesh.rest[std::size_t(tri[0])])
                                      .cross(mesh.rest[std::size_t(tri[2])] - mesh.rest[std::size_t(tri[0])]);
        for (std::int32_t v : tri) EXPECT_NEAR(mesh.rest[std::size_t(v)].x(), x, 0.5 * gap + 1e-9);
        const bool left = mesh.rest[std::size_t(tri[0])].x() < x;
        EXPECT_GT(left ? n.x() : -n.x(), 0.0) << "cap triangle " << t << " faces into its piece: x " << mesh.rest[std::size_t(tri[0])].x() << " " << mesh.rest[std::size_t(tri[1])].x() << " " << mesh.rest[std::size_t(tri[2])].x() << " ids " << tri[0] << " " << tri[1] << " " << tri[2] << " n " << n.transpose();
    }
    EXPECT_EQ(caps, result.cap_triangles);
    EXPECT_GT(caps, 0u);
    // Vertices away from the cut: the same, bit for bit.
    for (std::size_t v = 0; v < box.positions.size(); ++v) {
        if (std::abs(box.positions[v][0] - x) > 0.5) {
            ASSERT_EQ(mesh.rest[v], Eigen::Vector3d(box.positions[v][0], box.positions[v][1], box.positions[v][2]));
        }
    }
}

// A slit from the top face down to half the box's height: one closed piece; the crack's front
// (the blade's lower edge inside the box) shared by both caps; the slit's mouth open on the top
// face; the volume the box's less the slit's.
TEST(Incision, ASlitHalfwayDownLeavesOneClosedPieceWithTheCrackFrontShared) {
    const Eigen::Vector3d low(0, 0, 0), high(12, 12, 8);
    const BoxMesh box = box_mesh(low, high, 0.7);
    IncisionMesh mesh = incision_mesh(box.positions, {}, box.triangles);
    const double gap = 0.02, x = 5.9;
    // From z = 4 (inside) to z = 10 (above the top), across the whole width in y.
    const IncisionResult result = open_along(mesh, plane_x(x, low, high, 4.0, 10.0, 2.0), gap);
    ASSERT_TRUE(result.opened) << result.failure;
    std::string why;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
    EXPECT_EQ(count_components(mesh.triangles, mesh.rest.size()), 1u);
    const double volume = enclosed_volume(mesh.rest, mesh.triangles);
    // The slit: gap wide over its area (y 12 × z 4), less where it narrows to the front.
    EXPECT_NEAR(volume, high.prod() - gap * 12 * 4, 0.5 * gap * 12 * 4);
    // Cap vertices: on the plane; those on the front (z = 4) shared, not moved.
    std::size_t front = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        if (mesh.cap[t])
            for (std::int32_t v : mesh.triangles[t]) {
                const Eigen::Vector3d& p = mesh.rest[std::size_t(v)];
                EXPECT_NEAR(p.x(), x, 0.5 * gap + 1e-9);
                EXPECT_GE(p.z(), 4.0 - 1e-9);
                if (std::abs(p.z() - 4.0) < 1e-9) {
                    EXPECT_EQ(p.x(), x) << "a vertex of the crack's front moved";
                    ++front;
                }
            }
    EXPECT_GT(front, 0u);
    // A second, crossing slit (y = const) through the opened mesh keeps it closed.
    CutSurface across;
    across.points = {{-2, 6.1, 5.0}, {-2, 6.1, 10.0}, {14, 6.1, 10.0}, {14, 6.1, 5.0}};
    across.triangles = {{0, 1, 2}, {0, 2, 3}};
    const IncisionResult second = open_along(mesh, across, gap);
    ASSERT_TRUE(second.opened) << second.failure;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
}

// A blade whose edge grazes the surface: its tip runs out of the box's top (z = 10) at x = 6.6,
// inside the stroke's last pose (x = 6.9), so the cut's curve on the top face crosses the swept
// surface in one edge from its tip edge to its end edge, a top-face triangle's. Neither end of
// that edge is parted (both are the crack's front), yet the tissue under it is cut: the mesh still
// opens there, closed and in one piece, its volume the box's less at most the slit's.
TEST(Incision, ABladeWhoseEdgeGrazesTheSurfaceOpensAndStaysClosed) {
    const Eigen::Vector3d low(0, 0, 0), high(10, 10, 10);
    const BoxMesh box = box_mesh(low, high, 1.0);
    IncisionMesh mesh = incision_mesh(box.positions, {}, box.triangles);
    CutSurface strip;
    // y = 2.5 crosses the top face's squares at their middle, where either diagonal crosses
    // x = 6.5: the curve from x = 6.6 to 6.9 lies in one triangle.
    strip.points = {{4, 2.5, 13}, {6.9, 2.5, 13}, {6.9, 2.5, 9.7}, {4, 2.5, 12.6}};
    strip.triangles = {{0, 1, 3}, {1, 2, 3}};
    const double gap = 0.02;
    const IncisionResult result = open_along(mesh, strip, gap);
    ASSERT_TRUE(result.opened) << result.failure;
    EXPECT_GT(result.cap_triangles, 0u);
    std::string why;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
    EXPECT_EQ(count_components(mesh.triangles, mesh.rest.size()), 1u);
    // The cut inside the box: the triangle (6.6, 10), (6.9, 10), (6.9, 9.7) of the strip's plane.
    const double slit = gap * 0.5 * 0.3 * 0.3;
    EXPECT_NEAR(enclosed_volume(mesh.rest, mesh.triangles), high.prod() - 0.5 * slit, 0.5 * slit + 1e-9);
}

// A blade drawn right through a box along a bent path, inside the box from its tip to its end
// (a slit in the middle of the wall, open only where the path enters and leaves): the blade's line
// at the bend joins two points of the crack's front through the inside of the swept surface, and
// the mesh still closes up, one piece.
TEST(Incision, ASlitInsideTheWallAlongABentPathStaysClosed) {
    const Eigen::Vector3d low(0, 0, 0), high(12, 12, 8);
    const BoxMesh box = box_mesh(low, high, 0.7);
    IncisionMesh mesh = incision_mesh(box.positions, {}, box.triangles);
    CutSurface bent;
    bent.points = {{5.9, -2, 2}, {5.9, -2, 6}, {6.4, 6, 2}, {6.4, 6, 6}, {5.9, 14, 2}, {5.9, 14, 6}};
    bent.triangles = {{0, 1, 3}, {0, 3, 2}, {2, 3, 5}, {2, 5, 4}};
    const IncisionResult result = open_along(mesh, bent, 0.02);
    ASSERT_TRUE(result.opened) << result.failure;
    std::string why;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
    EXPECT_EQ(count_components(mesh.triangles, mesh.rest.size()), 1u);
    EXPECT_NEAR(enclosed_volume(mesh.rest, mesh.triangles), high.prod(), 0.01 * high.prod());
}

// A blade outside the mesh, or one ending before the surface, changes nothing.
TEST(Incision, ABladeThatMissesTheMeshChangesNothing) {
    const Eigen::Vector3d low(0, 0, 0), high(6, 6, 6);
    const BoxMesh box = box_mesh(low, high, 1.0);
    IncisionMesh mesh = incision_mesh(box.positions, {}, box.triangles);
    const IncisionResult outside = open_along(mesh, plane_x(8.0, low, high, -1.0, 7.0, 1.0), 0.02);
    EXPECT_FALSE(outside.opened);
    EXPECT_TRUE(outside.failure.empty());
    EXPECT_EQ(mesh.triangles, box.triangles);
}

namespace {

/// A block of particles and, around it, a box mesh on the tissue's boundary (half a spacing
/// outside the outermost particles), embedded in the lattice.
struct CutModel {
    Lattice lattice;
    Packing packing;
    SimulationSurface surface;
    BoxMesh box;
    VisualMapping mapping;
    Eigen::Vector3d low, high;  ///< the box
};

CutModel cut_model(int nx, int ny, int nz) {
    CutModel m;
    m.lattice = test::block_lattice(nx, ny, nz, 1.5, 0.0);
    m.packing = pack_particles(m.lattice);
    m.low = Eigen::Vector3d::Constant(1e30);
    m.high = Eigen::Vector3d::Constant(-1e30);
    for (const auto& r : m.lattice.particles.rest_position) {
        m.low = m.low.cwiseMin(Eigen::Vector3d(r[0], r[1], r[2]));
        m.high = m.high.cwiseMax(Eigen::Vector3d(r[0], r[1], r[2]));
    }
    m.low.array() -= 0.75;
    m.high.array() += 0.75;
    m.box = box_mesh(m.low, m.high, 0.6);
    m.surface = build_simulation_surface(m.lattice);
    std::vector<Eigen::Vector3d> positions;
    for (const auto& p : m.box.positions) positions.emplace_back(p[0], p[1], p[2]);
    m.mapping = map_visual_mesh(positions, m.lattice, m.surface);
    return m;
}

SolverOptions no_gravity(const Lattice& lattice) {
    SolverOptions o;
    o.gravity.setZero();
    o.critical_dt_ms = estimate_critical_time_step(lattice.particles, lattice.springs, 5000, 1e-12).critical_dt_ms;
    o.dt_ms = 0.5 * o.critical_dt_ms;
    o.damping_ratio = {0.0};
    return o;
}

std::vector<std::array<float, 3>> positions_of(const Solver& solver, std::size_t n) {
    std::vector<std::array<float, 3>> out(n);
    for (std::size_t i = 0; i < n; ++i) {
        const Eigen::Vector3d p = solver.position(i);
        out[i] = {float(p.x()), float(p.y()), float(p.z())};
    }
    return out;
}

/// The blade's plane x = const, a hundredth of a millimetre beside a particle column four and a
/// half spacings into the block (no particle lies on it).
double blade_plane(const CutModel& m) { return m.low.x() + 4.5 * 1.5 + 0.011; }

/// A scalpel lowered below the block's front on the plane x = blade_plane(m), its blade up through
/// the whole block, drawn across it in ten steps (after each, `after(k)`), then lifted.
void draw_blade_across(Solver& solver, const CutModel& m, const std::function<void(int)>& after = {}) {
    const double x = blade_plane(m), below = m.low.z() - 2.0, length = m.high.z() - m.low.z() + 4.0;
    solver.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {2.0, 0.3, 0.5 * length}});
    solver.set_pose(0, {.position = {x, m.low.y() - 2.0, below}});
    solver.begin_grab(0);
    for (int k = 1; k <= 10; ++k) {
        solver.set_pose(0, {.position = {x, m.low.y() - 2.0 + k * (m.high.y() - m.low.y() + 4.0) / 10, below}});
        solver.step(1);
        if (after) after(k);
    }
    solver.release(0);
}

}  // namespace

// The scalpel swept through a block in the solver, then the mesh opened from the solver's own
// stroke log: closed, in two pieces; every vertex carried only by particles of its own side of the
// blade, no triangle spanning the two sides; when the right piece of particles moves rigidly, the
// right piece of the mesh moves with it, bit for bit as the mapping evaluates, and the left one
// stays.
TEST(Incision, AStrokeThroughABlockOpensTheMeshAlongTheSolversCut) {
    CutModel m = cut_model(10, 5, 4);
    Solver solver(m.lattice, m.packing.neighbours, no_gravity(m.lattice));
    const double x = blade_plane(m);
    draw_blade_across(solver, m);
    ASSERT_EQ(solver.strokes().strokes().size(), 1u);
    EXPECT_TRUE(solver.strokes().strokes()[0].lifted);

    const std::size_t n = m.lattice.particles.size();
    IncisionState incisions(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    const IncisionUpdate update = incisions.update(solver.strokes(), positions_of(solver, n), false);
    ASSERT_TRUE(update.opened) << (update.failures.empty() ? "" : update.failures[0]);
    EXPECT_EQ(update.strokes, 1u);
    const IncisionMesh& mesh = incisions.mesh();
    std::string why;
    EXPECT_TRUE(closed_manifold(mesh.triangles, &why)) << why;
    EXPECT_EQ(count_components(mesh.triangles, mesh.rest.size()), 2u);
    EXPECT_EQ(incisions.drawn_triangles().size(), mesh.triangles.size());
    for (std::size_t t = incisions.cap_first(); t < mesh.triangles.size(); ++t)
        for (std::int32_t v : incisions.drawn_triangles()[t]) EXPECT_NEAR(mesh.rest[std::size_t(v)].x(), x, 0.05);

    auto side = [&](const Eigen::Vector3d& p) { return p.x() > x; };
    const VisualMapping& mapping = incisions.mapping();
    ASSERT_EQ(mapping.particles.size(), mesh.rest.size());
    for (std::size_t v = 0; v < mesh.rest.size(); ++v)
        for (int k = 0; k < 8; ++k) {
            if (mapping.weights[v][std::size_t(k)] == 0.0f) continue;
            const auto& r = m.lattice.particles.rest_position[std::size_t(mapping.particles[v][std::size_t(k)])];
            ASSERT_EQ(side(Eigen::Vector3d(r[0], r[1], r[2])), side(mesh.rest[v])) << "vertex " << v << " (of " << m.box.positions.size() << " before the cut) at " << mesh.rest[v].transpose()
                << " is carried across the cut by particle at " << r[0] << " " << r[1] << " " << r[2] << " weight " << mapping.weights[v][std::size_t(k)] << " x " << x;
        }
    for (const auto& t : mesh.triangles)
        ASSERT_TRUE(side(mesh.rest[std::size_t(t[0])]) == side(mesh.rest[std::size_t(t[1])]) &&
                    side(mesh.rest[std::size_t(t[0])]) == side(mesh.rest[std::size_t(t[2])]))
            << "a triangle bridges the cut";

    // The right piece moved by 2 mm along x: the mesh follows its own piece.
    std::vector<std::array<float, 3>> moved = positions_of(solver, n);
    for (auto& p : moved)
        if (p[0] > x) p[0] += 2.0f;
    const std::vector<Eigen::Vector3f> drawn = apply_mapping(mapping, moved, m.surface);
    for (std::size_t v = 0; v < mesh.rest.size(); ++v) {
        const double shift = double(drawn[v].x()) - mesh.rest[v].x();
        ASSERT_NEAR(shift, side(mesh.rest[v]) ? 2.0 : 0.0, 1e-3) << "vertex " << v;
    }

    // A reset heals the cut: the next update restores the uncut mesh.
    solver.reset_tissue();
    EXPECT_TRUE(incisions.pending(solver.strokes(), false));
    incisions.update(solver.strokes(), positions_of(solver, n), false);
    EXPECT_FALSE(incisions.cut());
    EXPECT_EQ(incisions.mesh().triangles, m.box.triangles);
}

// A grabber closed over an incision, used as a retractor, takes one side: of the particles
// inside it, those still joined to the one nearest its centre by springs the blade did not cut;
// without the cut the same grabber takes both sides.
TEST(Incision, AGrabberOverTheCutTakesTheSideNearestItsCentre) {
    CutModel m = cut_model(10, 5, 4);
    const double x = blade_plane(m);
    const Eigen::Vector3d centre(x + 1.0, 0.5 * (m.low.y() + m.high.y()), m.high.z() - 0.75);  // nearest a particle of the + side
    auto grab = [&](Solver& solver) {
        solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(2.0)});
        solver.set_pose(1, {.position = centre});
        return solver.begin_grab(1);
    };
    Solver whole(m.lattice, m.packing.neighbours, no_gravity(m.lattice));
    const std::size_t both = grab(whole);
    std::size_t left_whole = 0;
    for (std::int32_t i : whole.contact_particles(1)) left_whole += m.lattice.particles.rest_position[std::size_t(i)][0] < x;
    EXPECT_GT(left_whole, 0u) << "the grabber reaches across the plane";

    Solver solver(m.lattice, m.packing.neighbours, no_gravity(m.lattice));
    draw_blade_across(solver, m);
    ASSERT_GT(solver.cut_springs().size(), 0u);
    const std::size_t one = grab(solver);
    std::printf("  the grabber holds %zu particles over the whole block, %zu over the cut one\n", both, one);
    EXPECT_GT(one, 0u);
    EXPECT_EQ(one, both - left_whole);
    for (std::int32_t i : solver.contact_particles(1)) EXPECT_GT(m.lattice.particles.rest_position[std::size_t(i)][0], x);
}

// While the blade is still down, a preview shows the mesh opened as far as the blade has gone
// (closed, in one piece while the cut is partial); once it lifts, the mesh is the one a state that
// never previewed makes from the same stroke, bit for bit.
TEST(Incision, APreviewWhileTheBladeIsDownLeavesNoTraceOnceItLifts) {
    CutModel m = cut_model(10, 5, 4);
    Solver solver(m.lattice, m.packing.neighbours, no_gravity(m.lattice));
    const std::size_t n = m.lattice.particles.size();
    IncisionState previewed(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    std::string why;
    draw_blade_across(solver, m, [&](int k) {
        if (k != 5) return;  // halfway across: a slit from the front face
        const IncisionUpdate u = previewed.preview(solver.strokes(), positions_of(solver, n));
        EXPECT_TRUE(u.opened);
        EXPECT_TRUE(previewed.previewing());
        EXPECT_TRUE(closed_manifold(previewed.drawn_triangles(), &why)) << why;
        EXPECT_EQ(count_components(previewed.mesh().triangles, previewed.mesh().rest.size()), 1u);
    });
    ASSERT_TRUE(previewed.pending(solver.strokes(), false));
    previewed.update(solver.strokes(), positions_of(solver, n), false);
    EXPECT_FALSE(previewed.previewing());
    IncisionState direct(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    direct.update(solver.strokes(), positions_of(solver, n), false);
    EXPECT_EQ(previewed.drawn_triangles(), direct.drawn_triangles());
    EXPECT_EQ(previewed.mesh().rest, direct.mesh().rest);
    EXPECT_EQ(previewed.mapping().particles, direct.mapping().particles);
    EXPECT_EQ(previewed.mapping().weights, direct.mapping().weights);
    EXPECT_EQ(count_components(direct.mesh().triangles, direct.mesh().rest.size()), 2u);
}

namespace {

/// A cut through the whole block along the plane where coordinate `axis` is `at`.
struct PlaneCut {
    int axis;
    double at;
};

/// The plane between particle columns `column` and `column` + 1 along `axis` (a hundredth of a
/// millimetre off the middle).
PlaneCut between_columns(const CutModel& m, int axis, int column) {
    return {axis, m.low[axis] + 0.75 + (column + 0.5) * 1.5 + 0.011};
}

/// The poses of a blade drawing `cut` through the block, `steps` steps, and its length: the blade
/// along +z (along +x for a cut across z), moved along the plane's next axis from 2 mm before the
/// block to 2 mm past it.
std::vector<InstrumentPose> plane_cut_poses(const CutModel& m, const PlaneCut& cut, int steps, double& length) {
    const int blade = cut.axis == 2 ? 0 : 2, along = cut.axis == 1 ? 0 : 1;
    length = m.high[blade] - m.low[blade] + 4.0;
    const Eigen::Quaterniond orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), Eigen::Vector3d::Unit(blade));
    std::vector<InstrumentPose> poses;
    for (int k = 0; k <= steps; ++k) {
        Eigen::Vector3d p;
        p[cut.axis] = cut.at;
        p[blade] = m.low[blade] - 2.0;
        p[along] = m.low[along] - 2.0 + k * (m.high[along] - m.low[along] + 4.0) / steps;
        poses.push_back({p, orientation});
    }
    return poses;
}

/// Nine cuts across a block 20 particles long, between every second pair of particle columns, in
/// an order that puts each beside earlier ones: ten pieces of two columns each.
std::vector<PlaneCut> nine_cuts(const CutModel& m) {
    std::vector<PlaneCut> cuts;
    for (int column : {9, 7, 11, 5, 13, 3, 15, 1, 17}) cuts.push_back(between_columns(m, 0, column));
    return cuts;
}

}  // namespace

// Nine strokes through a block, each beside earlier ones, each opened as its blade lifts: after
// every lift the mesh is a closed 2-manifold and every vertex is carried by particles on its own
// side of every cut so far (by the signs of their distances to the planes, not by the cut's own
// test); at the end, ten closed pieces. A lift tests a carrier against a face of its strip only
// where the carrier's segment passes within a spacing of it (a face's bucket), each face once.
TEST(Incision, ManyStrokesKeepTheMeshClosedAndEachLiftTestsOnlyItsOwnStrip) {
    const CutModel m = cut_model(20, 6, 4);
    IncisionState incisions(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    const auto& rest = m.lattice.particles.rest_position;
    const std::vector<PlaneCut> cuts = nine_cuts(m);
    StrokeLog log;
    std::string why;
    for (std::size_t c = 0; c < cuts.size(); ++c) {
        double length = 0.0;
        const std::vector<InstrumentPose> poses = plane_cut_poses(m, cuts[c], 4, length);
        for (std::size_t k = 1; k < poses.size(); ++k) log.sweep(0, poses[k - 1], poses[k], length);
        log.lift(0);
        // Before the lift: the carriers of the vertices within two spacings of the plane (those
        // the lift tests) whose segments pass within a spacing of it (the bucket of a face of the
        // plane is a spacing wide): only they may meet its faces.
        std::size_t near_plane = 0;
        {
            const IncisionMesh& mesh = incisions.mesh();
            const VisualMapping& mapping = incisions.mapping();
            const int a = cuts[c].axis;
            for (std::size_t v = 0; v < mesh.rest.size(); ++v) {
                if (std::abs(mesh.rest[v][a] - cuts[c].at) > 2 * 1.5) continue;
                for (int k = 0; k < 8; ++k) {
                    if (mapping.weights[v][std::size_t(k)] == 0.0f) continue;
                    const double p = rest[std::size_t(mapping.particles[v][std::size_t(k)])][std::size_t(a)];
                    near_plane += std::min(p, mesh.rest[v][a]) <= cuts[c].at + 1.5 * 1.001 && std::max(p, mesh.rest[v][a]) >= cuts[c].at - 1.5 * 1.001;
                }
            }
        }
        const IncisionUpdate u = incisions.update(log, rest, false);
        ASSERT_TRUE(u.opened) << "cut " << c << ": " << (u.failures.empty() ? "" : u.failures[0]);
        ASSERT_TRUE(closed_manifold(incisions.drawn_triangles(), &why)) << "cut " << c << ": " << why;
        EXPECT_EQ(u.cut_faces, 2u) << "cut " << c << ": a straight stroke sweeps one quad";
        EXPECT_GT(u.carriers_tested, 0u) << "cut " << c;
        EXPECT_LE(u.face_tests, near_plane * u.cut_faces) << "cut " << c << " tested carriers against earlier cuts";
        std::printf("  cut %zu: %zu carriers tested, %zu within a spacing of the plane, %zu segment-face tests, %zu vertices embedded again\n", c,
                    u.carriers_tested, near_plane, u.face_tests, u.reembedded);

        const IncisionMesh& mesh = incisions.mesh();
        const VisualMapping& mapping = incisions.mapping();
        for (std::size_t v = 0; v < mesh.rest.size(); ++v)
            for (int k = 0; k < 8; ++k) {
                if (mapping.weights[v][std::size_t(k)] == 0.0f) continue;
                const auto& r = rest[std::size_t(mapping.particles[v][std::size_t(k)])];
                for (std::size_t d = 0; d <= c; ++d) {
                    const int a = cuts[d].axis;
                    ASSERT_GT((mesh.rest[v][a] - cuts[d].at) * (double(r[std::size_t(a)]) - cuts[d].at), 0.0)
                        << "after cut " << c << ", vertex " << v << " at " << mesh.rest[v].transpose() << " is carried across cut " << d;
                }
            }
    }
    EXPECT_EQ(count_components(incisions.mesh().triangles, incisions.mesh().rest.size()), 10u);
}

// A preview while a blade is down, after other strokes have lifted, leaves no trace once it lifts:
// the mesh and the mapping are those of a state that never previewed, bit for bit.
TEST(Incision, APreviewAfterEarlierStrokesLeavesNoTraceOnceItLifts) {
    const CutModel m = cut_model(20, 6, 4);
    const auto& rest = m.lattice.particles.rest_position;
    const std::vector<PlaneCut> cuts = nine_cuts(m);
    IncisionState previewed(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    IncisionState direct(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    StrokeLog log;
    for (std::size_t c = 0; c < 4; ++c) {
        double length = 0.0;
        const std::vector<InstrumentPose> poses = plane_cut_poses(m, cuts[c], 4, length);
        for (std::size_t k = 1; k < poses.size(); ++k) {
            log.sweep(0, poses[k - 1], poses[k], length);
            if (c == 3 && k == 2) {  // the last stroke halfway across: a slit from the block's side
                const IncisionUpdate u = previewed.preview(log, rest);
                EXPECT_TRUE(u.opened);
                EXPECT_TRUE(previewed.previewing());
                std::string why;
                EXPECT_TRUE(closed_manifold(previewed.drawn_triangles(), &why)) << why;
            }
        }
        log.lift(0);
        previewed.update(log, rest, false);
        direct.update(log, rest, false);
    }
    EXPECT_FALSE(previewed.previewing());
    EXPECT_EQ(previewed.drawn_triangles(), direct.drawn_triangles());
    EXPECT_EQ(previewed.mesh().rest, direct.mesh().rest);
    EXPECT_EQ(previewed.mapping().particles, direct.mapping().particles);
    EXPECT_EQ(previewed.mapping().weights, direct.mapping().weights);
    // A fifth stroke opened in both, after the preview was given back: the same again.
    double length = 0.0;
    const std::vector<InstrumentPose> poses = plane_cut_poses(m, cuts[4], 4, length);
    for (std::size_t k = 1; k < poses.size(); ++k) log.sweep(0, poses[k - 1], poses[k], length);
    log.lift(0);
    previewed.update(log, rest, false);
    direct.update(log, rest, false);
    EXPECT_EQ(previewed.drawn_triangles(), direct.drawn_triangles());
    EXPECT_EQ(previewed.mapping().particles, direct.mapping().particles);
    EXPECT_EQ(previewed.mapping().weights, direct.mapping().weights);
}

// Two through-cuts crossing at a right angle (one across x, then one across y, each through the
// whole block along z, a hundredth of a millimetre beside a column of the box mesh's vertices):
// the first's slit moves a vertex of the bottom face 0.015 mm across the mesh edge beside it,
// folding a triangle onto its neighbour. Corefinement cannot take a surface that crosses itself
// (with its checks off, as in a release build, it reads past its arrays), so the second cut is
// refused with a message that says so, and the mesh stays as the first cut left it: closed, in
// two pieces, bit for bit.
TEST(Incision, ACutAcrossAnEarlierSlitThatFoldedATriangleIsRefusedAndTheMeshKept) {
    const CutModel m = cut_model(12, 12, 4);
    IncisionState incisions(m.lattice, m.box.positions, {}, m.box.triangles, m.mapping, m.surface);
    const auto& rest = m.lattice.particles.rest_position;
    const std::vector<PlaneCut> cuts{between_columns(m, 0, 5), between_columns(m, 1, 5)};
    StrokeLog log;
    {
        double length = 0.0;
        const std::vector<InstrumentPose> poses = plane_cut_poses(m, cuts[0], 4, length);
        for (std::size_t k = 1; k < poses.size(); ++k) log.sweep(0, poses[k - 1], poses[k], length);
        log.lift(0);
        const IncisionUpdate first = incisions.update(log, rest, false);
        ASSERT_TRUE(first.opened) << (first.failures.empty() ? "" : first.failures[0]);
    }
    const std::vector<std::array<std::int32_t, 3>> first_triangles = incisions.drawn_triangles();
    const std::vector<Eigen::Vector3d> first_rest = incisions.mesh().rest;

    double length = 0.0;
    const std::vector<InstrumentPose> poses = plane_cut_poses(m, cuts[1], 4, length);
    for (std::size_t k = 1; k < poses.size(); ++k) log.sweep(0, poses[k - 1], poses[k], length);
    log.lift(0);
    const IncisionUpdate second = incisions.update(log, rest, false);
    EXPECT_FALSE(second.opened);
    ASSERT_EQ(second.failures.size(), 1u);
    EXPECT_NE(second.failures[0].find("folds onto itself"), std::string::npos) << second.failures[0];
    EXPECT_EQ(incisions.drawn_triangles(), first_triangles);
    EXPECT_EQ(incisions.mesh().rest, first_rest);
    std::string why;
    EXPECT_TRUE(closed_manifold(incisions.drawn_triangles(), &why)) << why;
    EXPECT_EQ(count_components(incisions.mesh().triangles, incisions.mesh().rest.size()), 2u);
}
