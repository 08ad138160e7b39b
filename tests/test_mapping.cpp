// The visual-mesh mapping against truths: at rest it gives back every visual vertex (float32
// evaluation, 1e-4 mm) on phantoms and real hearts; a rigid motion of the particles moves the
// mapped mesh rigidly; under a smooth displacement field its error shrinks with the spacing.
#include "formats/volume_io.h"
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/select.h"
#include "libmodel/simulation_surface.h"
#include "libmodel/surface.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>

using namespace heartsim;

namespace {

struct Scene {
    Lattice lattice;
    SimulationSurface surface;
    TriangleMesh visual;
    VisualMapping mapping;
    MappingReport report;
    SimulationSurfaceReport surface_report;
    double seconds_surface = 0.0, seconds_mapping = 0.0;
};

/// Lattice at `spacing` over `tissue`, its simulation surface, the visual mesh of the same mask
/// (marching cubes + windowed-sinc, as heartprep does) and the mapping between them.
Scene build_scene(const Mask& tissue, double spacing) {
    Scene scene;
    LabelVolume volume;
    volume.geometry = tissue.geometry;
    volume.labels.assign(tissue.values.begin(), tissue.values.end());
    const Selection selection{tissue, Mask{tissue.geometry, std::vector<std::uint8_t>(tissue.values.size(), 0)}};
    LayoutOptions layout;
    layout.spacing_mm = spacing;
    scene.lattice = layout_particles(selection, {1}, volume, layout);
    scene.visual = extract_surface(tissue);
    const auto start = std::chrono::steady_clock::now();
    scene.surface = build_simulation_surface(scene.lattice, null_progress(), &scene.surface_report);
    const auto middle = std::chrono::steady_clock::now();
    MappingOptions options;
    options.lattice_spacing_mm = scene.lattice.spacing;
    scene.mapping = map_visual_mesh(scene.visual.positions, scene.lattice.particles.rest_position, scene.surface, options,
                                    null_progress(), &scene.report);
    const auto end = std::chrono::steady_clock::now();
    scene.seconds_surface = std::chrono::duration<double>(middle - start).count();
    scene.seconds_mapping = std::chrono::duration<double>(end - middle).count();
    return scene;
}

/// max |apply_mapping(positions) − expected| over the visual vertices.
double max_error(const Scene& scene, const std::vector<std::array<float, 3>>& positions,
                 const std::vector<Eigen::Vector3d>& expected) {
    const auto mapped = apply_mapping(scene.mapping, positions, scene.surface);
    double error = 0.0;
    for (std::size_t v = 0; v < mapped.size(); ++v) error = std::max(error, (mapped[v].cast<double>() - expected[v]).norm());
    return error;
}

Mask sphere_mask(double radius, double voxel) {
    const int n = int(std::ceil(2 * radius / voxel)) + 6;
    return test::make_mask(n, voxel, [&](const Eigen::Vector3d& x) { return x.norm() <= radius; });
}

Mask shell_mask(double inner, double outer, double voxel) {
    const int n = int(std::ceil(2 * outer / voxel)) + 6;
    return test::make_mask(n, voxel, [&](const Eigen::Vector3d& x) { return x.norm() >= inner && x.norm() <= outer; });
}

void expect_exact_at_rest(const Scene& scene, const char* what) {
    const double error = max_error(scene, scene.lattice.particles.rest_position, scene.visual.positions);
    std::printf("%s: %zu particles, %zu surface triangles, %zu visual vertices; max rest error %.3g mm, mean |d| %.3f mm, "
                "max |d| %.3f mm, %zu extrapolated, %zu unsolved, %zu on unstable normals; surface %.4f s, mapping %.4f s\n",
                what, scene.lattice.particles.size(), scene.surface.size(), scene.visual.positions.size(), error,
                scene.report.mean_offset_mm, scene.report.max_offset_mm, scene.report.outside_triangle, scene.report.unsolved,
                scene.report.unstable_normal, scene.seconds_surface, scene.seconds_mapping);
    EXPECT_LT(error, 1e-4);
    EXPECT_NEAR(scene.report.max_rest_error_mm, error, 1e-9);
    EXPECT_EQ(scene.report.unsolved, 0u);
    ASSERT_EQ(scene.mapping.triangle.size(), scene.visual.positions.size());
    for (std::size_t v = 0; v < scene.mapping.barycentric.size(); ++v) {
        const auto& l = scene.mapping.barycentric[v];
        ASSERT_NEAR(double(l[0]) + double(l[1]) + double(l[2]), 1.0, 1e-6);
    }
}

}  // namespace

TEST(Mapping, EmptyInputsAreRefused) {
    const std::vector<std::array<float, 3>> particles{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    const SimulationSurface triangle = SimulationSurface::all_counted({{0, 1, 2}});
    EXPECT_THROW(map_visual_mesh({}, particles, triangle), InputError);
    EXPECT_THROW(map_visual_mesh({Eigen::Vector3d(0.2, 0.2, 0.1)}, particles, SimulationSurface{}), InputError);
    EXPECT_THROW(map_visual_mesh({Eigen::Vector3d(0.2, 0.2, 0.1)}, particles, SimulationSurface::all_counted({{0, 1, 3}})), InputError);
    // Normal weights: one per triangle, each 0 or 1.
    SimulationSurface bad = triangle;
    bad.normal_weight.clear();
    EXPECT_THROW(map_visual_mesh({Eigen::Vector3d(0.2, 0.2, 0.1)}, particles, bad), InputError);
    EXPECT_THROW(particle_normals(particles, bad), InputError);
    bad.normal_weight = {2};
    EXPECT_THROW(map_visual_mesh({Eigen::Vector3d(0.2, 0.2, 0.1)}, particles, bad), InputError);
}

TEST(Mapping, ParticleNormalsOfAClosedBlockPointOutwards) {
    // The 8 corners of a unit cube, 12 triangles: each corner's normal is the normalised sum of
    // its faces' area vectors, along the diagonal away from the centre.
    std::vector<std::array<float, 3>> x;
    for (int c = 0; c < 8; ++c) x.push_back({float(c & 1), float((c >> 1) & 1), float((c >> 2) & 1)});
    const std::vector<std::array<std::int32_t, 3>> cube{{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                                                        {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    const auto normals = particle_normals(x, SimulationSurface::all_counted(cube));
    for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3f away = (Eigen::Vector3f(x[std::size_t(c)][0], x[std::size_t(c)][1], x[std::size_t(c)][2]) -
                                      Eigen::Vector3f::Constant(0.5f)).normalized();
        EXPECT_NEAR(normals[std::size_t(c)].norm(), 1.0f, 1e-6f);
        EXPECT_GT(normals[std::size_t(c)].dot(away), 0.8f) << "corner " << c;
    }
}

TEST(Mapping, SphereIsExactAtRest) {
    const Scene scene = build_scene(sphere_mask(12.0, 0.8), 2.5);
    expect_exact_at_rest(scene, "sphere r=12 mm, h=2.5 mm");
    EXPECT_EQ(scene.report.outside_triangle, 0u);
    EXPECT_TRUE(scene.report.warnings.empty());
}

TEST(Mapping, ThickShellIsExactAtRest) {
    const Scene scene = build_scene(shell_mask(8.0, 14.0, 0.8), 2.0);
    expect_exact_at_rest(scene, "shell 8..14 mm, h=2 mm");
}

TEST(Mapping, RigidMotionMovesTheMappedMeshRigidly) {
    const Scene scene = build_scene(shell_mask(8.0, 14.0, 0.8), 2.0);
    const Eigen::Affine3d motion = Eigen::Translation3d(12.0, -7.0, 30.0) *
                                   Eigen::AngleAxisd(0.7, Eigen::Vector3d(1.0, 2.0, -0.5).normalized());
    std::vector<std::array<float, 3>> moved;
    for (const auto& p : scene.lattice.particles.rest_position) {
        const Eigen::Vector3d q = motion * Eigen::Vector3d(p[0], p[1], p[2]);
        moved.push_back({float(q.x()), float(q.y()), float(q.z())});
    }
    std::vector<Eigen::Vector3d> expected;
    for (const auto& v : scene.visual.positions) expected.push_back(motion * v);
    const double error = max_error(scene, moved, expected);
    std::printf("rigid motion: max error %.3g mm\n", error);
    EXPECT_LT(error, 1e-4);
}

TEST(Mapping, FarVisualMeshIsWarned) {
    Scene scene = build_scene(sphere_mask(10.0, 1.0), 2.5);
    std::vector<Eigen::Vector3d> far;
    for (const auto& v : scene.visual.positions) far.push_back(v * 2.0);
    MappingOptions options;
    options.lattice_spacing_mm = scene.lattice.spacing;
    MappingReport report;
    map_visual_mesh(far, scene.lattice.particles.rest_position, scene.surface, options, null_progress(), &report);
    ASSERT_FALSE(report.warnings.empty());
    EXPECT_NE(report.warnings.front().find("far from the tissue"), std::string::npos);
}

TEST(Mapping, IsDeterministic) {
    const Scene scene = build_scene(sphere_mask(10.0, 1.0), 2.5);
    const VisualMapping again = map_visual_mesh(scene.visual.positions, scene.lattice.particles.rest_position, scene.surface);
    EXPECT_EQ(again.triangle, scene.mapping.triangle);
    EXPECT_EQ(again.barycentric, scene.mapping.barycentric);
    EXPECT_EQ(again.offset, scene.mapping.offset);
}

TEST(Mapping, ErrorUnderASmoothDisplacementShrinksWithTheSpacing) {
    // u(x) = a·(sin(y/L), sin(z/L), sin(x/L)): applied to the particles, then compared with the
    // same field applied to the visual vertices directly.
    const double a = 1.0, L = 6.0;
    auto field = [&](const Eigen::Vector3d& x) {
        return Eigen::Vector3d(a * std::sin(x.y() / L), a * std::sin(x.z() / L), a * std::sin(x.x() / L));
    };
    const Mask mask = shell_mask(7.0, 15.0, 0.5);
    double previous = std::numeric_limits<double>::infinity();
    for (double spacing : {3.0, 2.0, 1.4, 1.0}) {
        const Scene scene = build_scene(mask, spacing);
        std::vector<std::array<float, 3>> moved;
        for (const auto& p : scene.lattice.particles.rest_position) {
            const Eigen::Vector3d x(p[0], p[1], p[2]);
            const Eigen::Vector3d y = x + field(x);
            moved.push_back({float(y.x()), float(y.y()), float(y.z())});
        }
        const auto mapped = apply_mapping(scene.mapping, moved, scene.surface);
        double max = 0.0, sum = 0.0;
        for (std::size_t v = 0; v < mapped.size(); ++v) {
            const Eigen::Vector3d& x = scene.visual.positions[v];
            const double e = (mapped[v].cast<double>() - (x + field(x))).norm();
            max = std::max(max, e);
            sum += e * e;
        }
        const double rms = std::sqrt(sum / double(mapped.size()));
        std::printf("displacement a=%.1f mm L=%.1f mm, spacing %.1f mm: %zu particles, rms error %.4f mm, max %.4f mm "
                    "(rest error %.2g mm)\n",
                    a, L, spacing, scene.lattice.particles.size(), rms, max, scene.report.max_rest_error_mm);
        EXPECT_LT(rms, previous) << "spacing " << spacing;
        previous = rms;
    }
}

TEST(Mapping, DisplacedThinSheetMovesBothSidesConsistently) {
    // A plate one particle thick (14×14 particles, h = 2 mm) and visual vertices 0.9 mm above and
    // below it. Only one side of the double-sided sheet counts in the normals, so the normals are
    // the plate's (not the rounding noise of two cancelling sides): vertices below get negative
    // offsets, and a smooth bend carries both layers along, keeping them 1.8 mm apart, with no
    // jumps between neighbours and no dependence on the order the area vectors are summed in.
    const double h = 2.0, half = 0.9;
    Lattice lattice;
    lattice.spacing = h;
    lattice.dims = {16, 16, 3};
    lattice.index_to_world.topLeftCorner<3, 3>() = Eigen::Matrix3d::Identity() * h;
    for (int j = 1; j <= 14; ++j)
        for (int i = 1; i <= 14; ++i) {
            lattice.particles.rest_position.push_back({float(i * h), float(j * h), float(h)});
            lattice.particles.lattice_index.push_back({i, j, 1});
            lattice.particles.mass.push_back(1.0f);
            lattice.particles.material.push_back(0);
            lattice.particles.anchored.push_back(0);
        }
    SimulationSurfaceReport surface_report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &surface_report);
    ASSERT_EQ(surface_report.thin_wall_triangles, surface.size());
    // The visual layers: a 40×40 grid over the plate's interior, above and below.
    std::vector<Eigen::Vector3d> visual;
    const int n = 40;
    for (int side : {1, -1})
        for (int b = 0; b < n; ++b)
            for (int a = 0; a < n; ++a)
                visual.emplace_back(3.1 * h + a * (8.0 * h / (n - 1)), 3.1 * h + b * (8.0 * h / (n - 1)), h + side * half);
    const std::size_t layer = std::size_t(n * n);
    MappingReport report;
    const VisualMapping mapping = map_visual_mesh(visual, lattice.particles.rest_position, surface, {}, null_progress(), &report);
    EXPECT_EQ(report.unstable_normal, 0u);
    EXPECT_EQ(report.unsolved, 0u);
    EXPECT_LT(report.max_rest_error_mm, 1e-4);
    for (std::size_t v = 0; v < layer; ++v) {
        // One layer on the counted side (d = +0.9), the other behind it (d = −0.9).
        EXPECT_NEAR(double(mapping.offset[v]), -double(mapping.offset[v + layer]), 1e-5);
        EXPECT_NEAR(std::abs(double(mapping.offset[v])), half, 1e-5);
    }
    // A smooth bend with a twist, then a rigid motion.
    const double a = 1.5, L = 7.0;
    const Eigen::Affine3d motion = Eigen::Translation3d(3.0, -2.0, 5.0) * Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized());
    auto deform = [&](const Eigen::Vector3d& x) {
        return motion * Eigen::Vector3d(x.x(), x.y(), x.z() + a * std::sin(x.x() / L) * std::cos(x.y() / L));
    };
    std::vector<std::array<float, 3>> moved;
    for (const auto& p : lattice.particles.rest_position) {
        const Eigen::Vector3d y = deform(Eigen::Vector3d(p[0], p[1], p[2]));
        moved.push_back({float(y.x()), float(y.y()), float(y.z())});
    }
    const auto mapped = apply_mapping(mapping, moved, surface);
    // The same with the triangles (and so the area-vector sums) in reverse order: the runtime may
    // sum in any order; on a sheet whose both sides counted, this moved vertices by millimetres.
    SimulationSurface reversed;
    reversed.triangles.assign(surface.triangles.rbegin(), surface.triangles.rend());
    reversed.normal_weight.assign(surface.normal_weight.rbegin(), surface.normal_weight.rend());
    VisualMapping remapped = mapping;
    for (auto& t : remapped.triangle) t = std::int32_t(surface.size()) - 1 - t;
    const auto mapped_reversed = apply_mapping(remapped, moved, reversed);
    double order = 0.0, thickness = 0.0, jump = 0.0, error = 0.0;
    for (std::size_t v = 0; v < visual.size(); ++v) {
        order = std::max(order, double((mapped[v] - mapped_reversed[v]).norm()));
        error = std::max(error, (mapped[v].cast<double>() - deform(visual[v])).norm());
    }
    for (std::size_t v = 0; v < layer; ++v) thickness = std::max(thickness, std::abs(double((mapped[v] - mapped[v + layer]).norm()) - 2 * half));
    for (int side = 0; side < 2; ++side)
        for (int b = 0; b < n; ++b)
            for (int c = 0; c + 1 < n; ++c) {
                // Grid neighbours (0.41 mm apart): the mapping's error against the field changes
                // smoothly from one to the next (no vertex jumps).
                const std::size_t v = std::size_t(side) * layer + std::size_t(b * n + c);
                const Eigen::Vector3d e0 = mapped[v].cast<double>() - deform(visual[v]);
                const Eigen::Vector3d e1 = mapped[v + 1].cast<double>() - deform(visual[v + 1]);
                jump = std::max(jump, (e1 - e0).norm());
            }
    std::printf("thin sheet: %zu particles, %zu triangles (%zu sheet regions); bent and moved: max error vs the field %.3g mm, "
                "layer thickness error %.3g mm, largest change of that error between neighbours %.3g mm, summation-order "
                "difference %.3g mm\n",
                lattice.particles.size(), surface.size(), surface_report.sheet_regions, error, thickness, jump, order);
    EXPECT_LT(order, 1e-4);
    EXPECT_LT(thickness, 1e-3);
    EXPECT_LT(jump, 0.05);
    EXPECT_LT(error, 0.5);
}

class RealCaseMapping : public ::testing::TestWithParam<const char*> {};

TEST_P(RealCaseMapping, IsExactAtRest) {
    const auto input = test::real_case(GetParam());
    if (input.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    const LabelVolume volume = read_label_volume(input);
    const Selection selection = select_tissue(volume);
    const Lattice lattice = layout_particles(selection, {1}, volume);
    TriangleMesh visual = extract_surface(selection.tissue);
    const auto start = std::chrono::steady_clock::now();
    SimulationSurfaceReport surface_report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &surface_report);
    const auto middle = std::chrono::steady_clock::now();
    MappingOptions options;
    options.lattice_spacing_mm = lattice.spacing;
    MappingReport report;
    const VisualMapping mapping = map_visual_mesh(visual.positions, lattice.particles.rest_position, surface, options,
                                                  null_progress(), &report);
    const auto end = std::chrono::steady_clock::now();
    const auto mapped = apply_mapping(mapping, lattice.particles.rest_position, surface);
    double error = 0.0;
    for (std::size_t v = 0; v < mapped.size(); ++v) error = std::max(error, (mapped[v].cast<double>() - visual.positions[v]).norm());
    std::printf("%s: spacing %.3f mm, %zu particles; surface %zu triangles over %zu particles, %zu components, chi %ld, "
                "%zu non-manifold edges, %zu non-manifold vertices, %zu thin-wall triangles in %zu sheet regions (%zu unseeded, "
                "%zu conflicts), %.4f s; "
                "mapping of %zu vertices %.3f s (%.2f solves per vertex): max rest error %.3g mm, mean |d| %.3f mm, max |d| %.3f mm, "
                "%zu extrapolated, %zu unsolved, %zu on unstable normals\n",
                GetParam(), lattice.spacing, lattice.particles.size(), surface.size(), surface_report.boundary_particles,
                surface_report.components, surface_report.euler_characteristic, surface_report.nonmanifold_edges,
                surface_report.nonmanifold_vertices, surface_report.thin_wall_triangles, surface_report.sheet_regions,
                surface_report.sheet_regions_unseeded, surface_report.sheet_orientation_conflicts,
                std::chrono::duration<double>(middle - start).count(), visual.positions.size(),
                std::chrono::duration<double>(end - middle).count(), double(report.candidate_solves) / double(visual.positions.size()), error, report.mean_offset_mm, report.max_offset_mm,
                report.outside_triangle, report.unsolved, report.unstable_normal);
    for (const auto& w : report.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_LT(error, 1e-4);
    EXPECT_EQ(report.unsolved, 0u);
}

INSTANTIATE_TEST_SUITE_P(Hvsmr, RealCaseMapping,
                         ::testing::Values("hvsmr16_pat0", "hvsmr16_pat1", "hvsmr16_pat5", "hvsmr16_pat6"));
