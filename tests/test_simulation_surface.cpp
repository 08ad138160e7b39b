// The simulation surface against facts that follow from the particle set alone: a block's
// boundary, the Euler characteristic of a torus, the two boundaries of a thick shell, and for
// every dual-cube configuration and random particle sets, closedness and boundary vertices.
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/mesh.h"
#include "libmodel/simulation_surface.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <random>
#include <set>

using namespace heartsim;

namespace {

/// A lattice of `dims` cells at `spacing` mm with a particle wherever `occupied(i,j,k)`.
Lattice make_lattice(std::array<int, 3> dims, double spacing, const std::function<bool(int, int, int)>& occupied,
                     Eigen::Matrix3d direction = Eigen::Matrix3d::Identity()) {
    Lattice lattice;
    lattice.spacing = spacing;
    lattice.dims = dims;
    lattice.index_to_world.topLeftCorner<3, 3>() = direction * spacing;
    lattice.index_to_world.topRightCorner<3, 1>() = Eigen::Vector3d(-3.0, 5.0, 7.0);
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                if (!occupied(i, j, k)) continue;
                const Eigen::Vector3d x = (lattice.index_to_world * Eigen::Vector4d(i, j, k, 1)).head<3>();
                lattice.particles.rest_position.push_back({float(x.x()), float(x.y()), float(x.z())});
                lattice.particles.lattice_index.push_back({i, j, k});
                lattice.particles.mass.push_back(1.0f);
                lattice.particles.material.push_back(0);
                lattice.particles.anchored.push_back(0);
            }
    return lattice;
}

MeshReport analyse(const Lattice& lattice, const std::vector<std::array<std::int32_t, 3>>& triangles) {
    return analyse_mesh(simulation_surface_mesh(lattice.particles.rest_position, triangles));
}

/// Every vertex is a particle with at least one of its 6 face neighbours missing.
void expect_vertices_on_boundary(const Lattice& lattice, const std::vector<std::array<std::int32_t, 3>>& triangles) {
    std::set<std::array<int, 3>> cells(lattice.particles.lattice_index.begin(), lattice.particles.lattice_index.end());
    std::size_t interior = 0;
    for (const auto& t : triangles)
        for (int v : t) {
            const auto ijk = lattice.particles.lattice_index[std::size_t(v)];
            bool boundary = false;
            for (int slot = 0; slot < 6; ++slot) {
                const auto& o = neighbour_offsets[std::size_t(slot)];
                boundary |= !cells.count({ijk[0] + o[0], ijk[1] + o[1], ijk[2] + o[2]});
            }
            interior += !boundary;
        }
    EXPECT_EQ(interior, 0u) << "vertices that are interior particles";
}

/// Closed as a chain: every directed edge a→b is matched by as many b→a (holds even where thin
/// walls make edges non-manifold); no triangle repeats a vertex.
void expect_closed_chain(const std::vector<std::array<std::int32_t, 3>>& triangles) {
    std::map<std::pair<int, int>, int> balance;
    std::size_t degenerate = 0;
    for (const auto& t : triangles) {
        degenerate += t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
        for (int e = 0; e < 3; ++e) {
            const int a = t[std::size_t(e)], b = t[std::size_t((e + 1) % 3)];
            balance[{std::min(a, b), std::max(a, b)}] += a < b ? 1 : -1;
        }
    }
    std::size_t unbalanced = 0;
    for (const auto& [edge, count] : balance) unbalanced += count != 0;
    EXPECT_EQ(unbalanced, 0u) << "edges not cancelled by an opposite traversal";
    EXPECT_EQ(degenerate, 0u);
}

void expect_closed_oriented_manifold(const MeshReport& report) {
    EXPECT_TRUE(report.closed());
    EXPECT_EQ(report.boundary_edges, 0u);
    EXPECT_EQ(report.nonmanifold_edges, 0u);
    EXPECT_EQ(report.nonmanifold_vertices, 0u);
    EXPECT_EQ(report.misoriented_edges, 0u);
    EXPECT_EQ(report.degenerate_faces, 0u);
}

}  // namespace

namespace {

std::array<std::int32_t, 3> canonical_triangle(std::array<std::int32_t, 3> t) {
    while (t[0] > t[1] || t[0] > t[2]) t = {t[1], t[2], t[0]};
    return t;
}

/// Of each (triangle, exact reverse) pair exactly one has weight 1; every other triangle has
/// weight 1. Returns the number of pairs.
std::size_t expect_one_of_each_pair(const SimulationSurface& surface) {
    EXPECT_EQ(surface.normal_weight.size(), surface.triangles.size());
    std::map<std::array<std::int32_t, 3>, std::size_t> row;
    for (std::size_t t = 0; t < surface.triangles.size(); ++t) row[canonical_triangle(surface.triangles[t])] = t;
    std::size_t pairs = 0, bad = 0;
    for (std::size_t t = 0; t < surface.triangles.size(); ++t) {
        const auto& tri = surface.triangles[t];
        const auto twin = row.find(canonical_triangle({tri[0], tri[2], tri[1]}));
        if (twin == row.end()) {
            bad += surface.normal_weight[t] != 1;
        } else {
            bad += surface.normal_weight[t] + surface.normal_weight[twin->second] != 1;
            pairs += t < twin->second;
        }
    }
    EXPECT_EQ(bad, 0u) << "triangles whose weight breaks the one-of-each-pair rule";
    return pairs;
}

/// The counted sheet triangles (those with a reverse) are consistently oriented: no directed edge
/// is used by two of them (two counted neighbours run their shared edge opposite ways). Thick
/// triangles are left out: where a sheet meets thick tissue, both sides of the thick surface
/// count, so one of them necessarily runs the shared edge the same way as the counted side.
void expect_counted_consistently_oriented(const SimulationSurface& surface) {
    std::set<std::array<std::int32_t, 3>> all;
    for (const auto& t : surface.triangles) all.insert(canonical_triangle(t));
    std::map<std::pair<int, int>, int> directed;
    for (std::size_t t = 0; t < surface.triangles.size(); ++t) {
        const auto& tri = surface.triangles[t];
        if (!surface.normal_weight[t] || !all.count(canonical_triangle({tri[0], tri[2], tri[1]}))) continue;
        for (int e = 0; e < 3; ++e) ++directed[{surface.triangles[t][std::size_t(e)], surface.triangles[t][std::size_t((e + 1) % 3)]}];
    }
    std::size_t twice = 0;
    for (const auto& [edge, count] : directed) twice += count > 1;
    EXPECT_EQ(twice, 0u) << "directed edges used by two counted triangles";
}

Eigen::Vector3d as_vector(const std::array<float, 3>& p) { return Eigen::Vector3d(p[0], p[1], p[2]); }

}  // namespace

class SimulationSurfaceBlock : public ::testing::TestWithParam<int> {};

TEST_P(SimulationSurfaceBlock, IsExactlyTheBlocksBoundary) {
    const int n = GetParam();
    const double h = 1.5;
    const Lattice lattice = make_lattice({n + 4, n + 3, n + 2}, h, [&](int i, int j, int k) {
        return i >= 2 && i < n + 2 && j >= 1 && j < n + 1 && k >= 1 && k < n + 1;
    });
    SimulationSurfaceReport surface_report;
    const auto triangles = build_simulation_surface(lattice, null_progress(), &surface_report).triangles;
    const MeshReport report = analyse(lattice, triangles);
    // The boundary of the cube spanned by the particle centres: 6 faces of (n−1)² squares, 2
    // triangles each; its vertices are the 6n² − 12n + 8 particles on the block's surface.
    EXPECT_EQ(triangles.size(), std::size_t(12 * (n - 1) * (n - 1)));
    EXPECT_EQ(report.vertices, std::size_t(6 * n * n - 12 * n + 8));
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 1u);
    EXPECT_EQ(report.euler_characteristic, 2);
    const double side = (n - 1) * h;
    EXPECT_NEAR(report.volume, side * side * side, 1e-6 * side * side * side);
    EXPECT_NEAR(report.area, 6 * side * side, 1e-6 * side * side);
    expect_vertices_on_boundary(lattice, triangles);
    EXPECT_EQ(surface_report.triangles, triangles.size());
    EXPECT_EQ(surface_report.euler_characteristic, 2);
    EXPECT_EQ(surface_report.nonmanifold_edges, 0u);
    EXPECT_EQ(surface_report.thin_wall_triangles, 0u);
    EXPECT_EQ(surface_report.duplicate_triangles_removed, 0u);
    EXPECT_TRUE(surface_report.warnings.empty());
}

INSTANTIATE_TEST_SUITE_P(Sizes, SimulationSurfaceBlock, ::testing::Values(2, 3, 5, 8));

TEST(SimulationSurface, MirroredLatticeStaysOutwardOriented) {
    const Eigen::Matrix3d mirror = Eigen::Vector3d(-1, 1, 1).asDiagonal();
    const Lattice lattice = make_lattice({6, 6, 6}, 2.0, [](int i, int j, int k) { return i > 0 && j > 0 && k > 0 && i < 5 && j < 5 && k < 5; }, mirror);
    const MeshReport report = analyse(lattice, build_simulation_surface(lattice).triangles);
    expect_closed_oriented_manifold(report);
    EXPECT_NEAR(report.volume, 6.0 * 6.0 * 6.0, 1e-4);
}

TEST(SimulationSurface, TorusHasEulerCharacteristicZero) {
    const double major = 9.0, minor = 3.6;  // in cells
    const int n = 28;
    const Lattice lattice = make_lattice({n, n, n}, 1.0, [&](int i, int j, int k) {
        const Eigen::Vector3d x(i - 13.5, j - 13.5, k - 13.5);
        const double ring = std::hypot(x.x(), x.y()) - major;
        return ring * ring + x.z() * x.z() <= minor * minor;
    });
    const auto triangles = build_simulation_surface(lattice).triangles;
    const MeshReport report = analyse(lattice, triangles);
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 1u);
    EXPECT_EQ(report.euler_characteristic, 0);
    EXPECT_GT(report.volume, 0.0);
    expect_vertices_on_boundary(lattice, triangles);
}

TEST(SimulationSurface, ThickShellHasTwoClosedComponents) {
    const int n = 30;
    const Lattice lattice = make_lattice({n, n, n}, 1.0, [&](int i, int j, int k) {
        const double r = Eigen::Vector3d(i - 14.5, j - 14.5, k - 14.5).norm();
        return r >= 7.0 && r <= 13.0;
    });
    const auto triangles = build_simulation_surface(lattice).triangles;
    const MeshReport report = analyse(lattice, triangles);
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 2u);
    EXPECT_EQ(report.euler_characteristic, 4);
    // Outer boundary outward, inner boundary facing the cavity: the enclosed volume is the shell's.
    const double shell = 4.0 / 3.0 * M_PI * (std::pow(13.0, 3) - std::pow(7.0, 3));
    EXPECT_NEAR(report.volume / shell, 1.0, 0.15);
    expect_vertices_on_boundary(lattice, triangles);
}

TEST(SimulationSurface, EveryDualCubeConfigurationIsClosedOnBoundaryParticles) {
    for (int configuration = 1; configuration < 256; ++configuration) {
        const Lattice lattice = make_lattice({2, 2, 2}, 1.0, [&](int i, int j, int k) { return (configuration >> (i + 2 * j + 4 * k)) & 1; });
        const auto triangles = build_simulation_surface(lattice).triangles;
        SCOPED_TRACE("configuration " + std::to_string(configuration));
        expect_closed_chain(triangles);
        expect_vertices_on_boundary(lattice, triangles);
        // Where the occupied corners span a solid, the surface encloses it: positive volume.
        EXPECT_GE(analyse(lattice, triangles).volume, -1e-9);
    }
    // All eight: the unit cube, 12 triangles, volume 1.
    const Lattice full = make_lattice({2, 2, 2}, 1.0, [](int, int, int) { return true; });
    const MeshReport report = analyse(full, build_simulation_surface(full).triangles);
    EXPECT_EQ(report.faces, 12u);
    EXPECT_NEAR(report.volume, 1.0, 1e-6);
}

TEST(SimulationSurface, RandomParticleSetsAreClosedChainsOnBoundaryParticles) {
    std::mt19937 random(7);
    for (int trial = 0; trial < 20; ++trial) {
        const double density = 0.3 + 0.03 * trial;
        std::bernoulli_distribution coin(density);
        std::vector<char> cells(10 * 10 * 10);
        for (auto& c : cells) c = coin(random);
        const Lattice lattice = make_lattice({10, 10, 10}, 1.0, [&](int i, int j, int k) { return cells[std::size_t((k * 10 + j) * 10 + i)] != 0; });
        SimulationSurfaceReport surface_report;
        const auto triangles = build_simulation_surface(lattice, null_progress(), &surface_report).triangles;
        SCOPED_TRACE("trial " + std::to_string(trial));
        expect_closed_chain(triangles);
        expect_vertices_on_boundary(lattice, triangles);
        EXPECT_EQ(surface_report.duplicate_triangles_removed, 0u);
        EXPECT_GE(analyse(lattice, triangles).volume, 0.0);
        expect_one_of_each_pair(build_simulation_surface(lattice));
    }
}

TEST(SimulationSurface, OneParticleThickWallIsDoubleSidedAndReported) {
    // A 6×6 sheet, one particle thick: both sides of the sheet, every triangle with its reverse.
    const Lattice lattice = make_lattice({8, 8, 3}, 1.0, [](int i, int j, int k) { return k == 1 && i >= 1 && i <= 6 && j >= 1 && j <= 6; });
    SimulationSurfaceReport report;
    const auto triangles = build_simulation_surface(lattice, null_progress(), &report).triangles;
    EXPECT_EQ(triangles.size(), std::size_t(2 * 2 * 25));
    EXPECT_EQ(report.thin_wall_triangles, triangles.size());
    EXPECT_GT(report.nonmanifold_edges, 0u);  // reported as counts; a thin wall is no cause for a warning
    expect_closed_chain(triangles);
    EXPECT_NEAR(analyse(lattice, triangles).volume, 0.0, 1e-9);
}

TEST(SimulationSurface, ThinSheetCountsOneSideConsistently) {
    // A 6×6 sheet one particle thick, alone: every triangle has its reverse; one of each pair
    // counts, all on the same side, so every sheet particle's normal is the sheet's normal, the
    // same sign everywhere (with no thick neighbour, the fallback rule fixes which side).
    const Lattice lattice = make_lattice({8, 8, 3}, 1.0, [](int i, int j, int k) { return k == 1 && i >= 1 && i <= 6 && j >= 1 && j <= 6; });
    SimulationSurfaceReport report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &report);
    EXPECT_EQ(expect_one_of_each_pair(surface), surface.triangles.size() / 2);
    expect_counted_consistently_oriented(surface);
    EXPECT_EQ(report.sheet_regions, 1u);
    EXPECT_EQ(report.sheet_regions_unseeded, 1u);
    EXPECT_EQ(report.sheet_orientation_conflicts, 0u);
    const auto normals = particle_normals(lattice.particles.rest_position, surface);
    const Eigen::Vector3f sheet = normals[0];
    for (std::size_t i = 0; i < normals.size(); ++i) {
        EXPECT_NEAR(normals[i].norm(), 1.0f, 1e-6f) << "particle " << i;
        EXPECT_NEAR(std::abs(normals[i].z()), 1.0f, 1e-6f) << "particle " << i;
        EXPECT_EQ(normals[i].z() > 0, sheet.z() > 0) << "particle " << i << ": the sheet's normal flips";
    }
    // The same counted side whatever the thread count.
    for (int threads : {1, 2}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        EXPECT_TRUE(build_simulation_surface(lattice) == surface) << threads << " threads";
    }
}

TEST(SimulationSurface, BentSheetHasWellDefinedNormalsOnBothPlates) {
    // An L of two one-particle plates meeting along a line (k = 1 floor, i = 1 wall). The inner
    // corner's dual cubes close a thin prism (thick triangles: a chamfer inside, two strips
    // outside), so the plates are two sheet regions, each seeded from its first thick neighbour.
    // Each plate's normals are uniform; no particle's normal cancels; neighbours never point
    // opposite ways except across the prism's chamfer (its two edges face both plates).
    const Lattice lattice = make_lattice({9, 8, 9}, 1.0, [](int i, int j, int k) {
        const bool floor = k == 1 && i >= 1 && i <= 7 && j >= 1 && j <= 6;
        const bool wall = i == 1 && k >= 1 && k <= 7 && j >= 1 && j <= 6;
        return floor || wall;
    });
    SimulationSurfaceReport report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &report);
    expect_one_of_each_pair(surface);
    expect_counted_consistently_oriented(surface);
    EXPECT_EQ(report.sheet_orientation_conflicts, 0u);
    EXPECT_EQ(report.sheet_regions, 2u);
    EXPECT_EQ(report.sheet_regions_unseeded, 0u);
    const auto normals = particle_normals(lattice.particles.rest_position, surface);
    int floor_sign = 0, wall_sign = 0;
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        EXPECT_NEAR(normals[i].norm(), 1.0f, 1e-6f) << "particle " << i;
        const auto ijk = lattice.particles.lattice_index[i];
        if (ijk[1] == 1 || ijk[1] == 6) continue;  // the plates' free rims
        if (ijk[0] >= 3) {
            EXPECT_NEAR(std::abs(normals[i].z()), 1.0f, 1e-5f) << "floor particle " << i;
            const int sign = normals[i].z() > 0 ? 1 : -1;
            if (!floor_sign) floor_sign = sign;
            EXPECT_EQ(sign, floor_sign) << "floor particle " << i;
        }
        if (ijk[2] >= 3) {
            EXPECT_NEAR(std::abs(normals[i].x()), 1.0f, 1e-5f) << "wall particle " << i;
            const int sign = normals[i].x() > 0 ? 1 : -1;
            if (!wall_sign) wall_sign = sign;
            EXPECT_EQ(sign, wall_sign) << "wall particle " << i;
        }
    }
}

TEST(SimulationSurface, SheetOnABlockCountsTheSideOfItsFirstThickNeighbour) {
    // A 4×6×4 block with a one-particle sheet sticking out of its +i face: the sheet region is
    // seeded from the thick triangle of lowest index along its border, so the counted sheet
    // triangle next to it runs their shared edge the other way (one orientation).
    const Lattice lattice = make_lattice({14, 8, 8}, 1.0, [](int i, int j, int k) {
        const bool block = i >= 1 && i <= 4 && j >= 1 && j <= 6 && k >= 1 && k <= 4;
        const bool sheet = i >= 5 && i <= 11 && j >= 1 && j <= 6 && k == 2;
        return block || sheet;
    });
    SimulationSurfaceReport report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &report);
    EXPECT_GT(expect_one_of_each_pair(surface), 0u);
    expect_counted_consistently_oriented(surface);
    EXPECT_EQ(report.sheet_regions, 1u);
    EXPECT_EQ(report.sheet_regions_unseeded, 0u);
    // Sheet particles away from the block: unit normals, all ±k with one sign.
    const auto normals = particle_normals(lattice.particles.rest_position, surface);
    int sign = 0;
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        const auto ijk = lattice.particles.lattice_index[i];
        if (ijk[0] < 7) continue;
        EXPECT_NEAR(normals[i].norm(), 1.0f, 1e-6f);
        EXPECT_NEAR(std::abs(normals[i].z()), 1.0f, 1e-5f) << "particle " << i;
        const int s = normals[i].z() > 0 ? 1 : -1;
        if (sign == 0) sign = s;
        EXPECT_EQ(s, sign) << "particle " << i;
    }
    // No particle's counted area vectors cancel: |Σ| ≥ 0.3 Σ|·| everywhere.
    std::vector<Eigen::Vector3d> sum(lattice.particles.size(), Eigen::Vector3d::Zero());
    std::vector<double> magnitude(lattice.particles.size(), 0.0);
    for (std::size_t t = 0; t < surface.triangles.size(); ++t) {
        if (!surface.normal_weight[t]) continue;
        const auto& tri = surface.triangles[t];
        const Eigen::Vector3d a = as_vector(lattice.particles.rest_position[std::size_t(tri[0])]);
        const Eigen::Vector3d c = (as_vector(lattice.particles.rest_position[std::size_t(tri[1])]) - a)
                                      .cross(as_vector(lattice.particles.rest_position[std::size_t(tri[2])]) - a);
        for (int v : tri) {
            sum[std::size_t(v)] += c;
            magnitude[std::size_t(v)] += c.norm();
        }
    }
    for (std::size_t i = 0; i < sum.size(); ++i)
        if (magnitude[i] > 0) EXPECT_GE(sum[i].norm(), 0.3 * magnitude[i]) << "particle " << i;
}

TEST(SimulationSurface, NormalWeightsOfSurfacesWithoutThinWallsAreAllOne) {
    const Lattice lattice = make_lattice({7, 7, 7}, 1.0, [](int i, int j, int k) { return i > 0 && j > 0 && k > 0 && i < 6 && j < 6 && k < 6; });
    const SimulationSurface surface = build_simulation_surface(lattice);
    EXPECT_EQ(surface.normal_weight, std::vector<std::uint8_t>(surface.triangles.size(), 1));
    EXPECT_TRUE(SimulationSurface::with_computed_weights(surface.triangles) == surface);
}

TEST(SimulationSurface, IsDeterministicAndFollowsTheParticlesNotTheirOrder) {
    const int n = 24;
    auto inside = [&](int i, int j, int k) { return Eigen::Vector3d(i - 11.5, j - 11.5, k - 11.5).norm() <= 10.5; };
    const Lattice lattice = make_lattice({n, n, n}, 1.0, inside);
    const auto first = build_simulation_surface(lattice).triangles;
    EXPECT_TRUE(build_simulation_surface(lattice) == build_simulation_surface(lattice));
    // Reverse the particle order: the same triangles over the same cells.
    Lattice reversed = lattice;
    auto& p = reversed.particles;
    std::reverse(p.rest_position.begin(), p.rest_position.end());
    std::reverse(p.lattice_index.begin(), p.lattice_index.end());
    auto as_cells = [](const Lattice& l, const std::vector<std::array<std::int32_t, 3>>& triangles) {
        std::multiset<std::array<std::array<int, 3>, 3>> out;
        for (const auto& t : triangles) {
            std::array<std::array<int, 3>, 3> cells{l.particles.lattice_index[std::size_t(t[0])], l.particles.lattice_index[std::size_t(t[1])],
                                                   l.particles.lattice_index[std::size_t(t[2])]};
            while (cells[0] > cells[1] || cells[0] > cells[2]) cells = {cells[1], cells[2], cells[0]};
            out.insert(cells);
        }
        return out;
    };
    EXPECT_EQ(as_cells(lattice, first), as_cells(reversed, build_simulation_surface(reversed).triangles));
}

TEST(SimulationSurface, SingleParticleGivesAnEmptySurfaceAndAWarning) {
    const Lattice lattice = make_lattice({3, 3, 3}, 1.0, [](int i, int j, int k) { return i == 1 && j == 1 && k == 1; });
    SimulationSurfaceReport report;
    EXPECT_TRUE(build_simulation_surface(lattice, null_progress(), &report).triangles.empty());
    EXPECT_FALSE(report.warnings.empty());
}

TEST(SimulationSurface, RejectsTwoParticlesInOneCell) {
    Lattice lattice = make_lattice({3, 3, 3}, 1.0, [](int, int, int) { return true; });
    lattice.particles.lattice_index[1] = lattice.particles.lattice_index[0];
    EXPECT_THROW(build_simulation_surface(lattice), InputError);
}

TEST(SimulationSurface, ThirtyThousandParticleBallTiming) {
    const int n = 40;  // a ball of about 30k particles
    const Lattice lattice = make_lattice({n, n, n}, 1.0, [&](int i, int j, int k) { return Eigen::Vector3d(i - 19.5, j - 19.5, k - 19.5).norm() <= 19.3; });
    const auto start = std::chrono::steady_clock::now();
    const auto triangles = build_simulation_surface(lattice).triangles;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("ball of %zu particles: %zu triangles in %.4f s\n", lattice.particles.size(), triangles.size(), seconds);
    expect_closed_oriented_manifold(analyse(lattice, triangles));
}
