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
#include <random>

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
    scene.mapping = map_visual_mesh(scene.visual.positions, scene.lattice, scene.surface, options, null_progress(), &scene.report);
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

TEST(Mapping, AUniformStretchOfABlockMovesItAffinely) {
    // Embedded vertices are affine combinations of lattice particles: any affine motion of the
    // particles moves them by the same affine map. A block's visual surface lies outside the
    // particle centres' hull by up to half a cell (extrapolated from the cells within).
    const Scene scene = build_scene(test::make_mask(40, 0.5, [](const Eigen::Vector3d& x) { return x.cwiseAbs().maxCoeff() <= 7.2; }), 2.0);
    const Eigen::Matrix3d stretch = Eigen::Vector3d(1.1, 0.95, 1.05).asDiagonal();
    const Eigen::Vector3d shift(0.4, -0.3, 0.2);
    std::vector<std::array<float, 3>> moved;
    for (const auto& p : scene.lattice.particles.rest_position) {
        const Eigen::Vector3d y = stretch * Eigen::Vector3d(p[0], p[1], p[2]) + shift;
        moved.push_back({float(y.x()), float(y.y()), float(y.z())});
    }
    const auto mapped = apply_mapping(scene.mapping, moved, scene.surface);
    double error = 0.0;
    for (std::size_t v = 0; v < mapped.size(); ++v)
        error = std::max(error, (mapped[v].cast<double>() - (stretch * scene.visual.positions[v] + shift)).norm());
    std::printf("block: %zu visual vertices, %zu embedded, %zu tangent; stretched (1.1, 0.95, 1.05): max error %.3g mm\n",
                mapped.size(), scene.report.embedded, scene.report.tangent, error);
    EXPECT_EQ(scene.report.tangent, 0u);
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
    // It says how many: every vertex of the doubled sphere lies outside the lattice's cells.
    EXPECT_EQ(report.tangent, far.size());
    EXPECT_NE(report.warnings.front().find(std::to_string(far.size()) + " of " + std::to_string(far.size()) + " visual vertices (100 %)"),
              std::string::npos)
        << report.warnings.front();
}

TEST(Mapping, IsDeterministic) {
    const Scene scene = build_scene(sphere_mask(10.0, 1.0), 2.5);
    MappingOptions options;
    options.lattice_spacing_mm = scene.lattice.spacing;
    const VisualMapping again = map_visual_mesh(scene.visual.positions, scene.lattice, scene.surface, options);
    EXPECT_EQ(again.triangle, scene.mapping.triangle);
    EXPECT_EQ(again.barycentric, scene.mapping.barycentric);
    EXPECT_EQ(again.offset, scene.mapping.offset);
    EXPECT_EQ(again.particles, scene.mapping.particles);
    EXPECT_EQ(again.weights, scene.mapping.weights);
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

/// The largest distance any visual vertex moves when every particle moves by exactly 1 µm in a
/// random direction (seeded).
double largest_response_to_1um(const VisualMapping& mapping, const std::vector<std::array<float, 3>>& rest,
                               const SimulationSurface& surface, unsigned seed) {
    std::mt19937 random(seed);
    std::normal_distribution<double> normal;
    std::vector<std::array<float, 3>> moved = rest;
    for (auto& p : moved) {
        Eigen::Vector3d d(normal(random), normal(random), normal(random));
        d *= 1e-3 / d.norm();
        for (int k = 0; k < 3; ++k) p[std::size_t(k)] = float(double(p[std::size_t(k)]) + d[k]);
    }
    const auto before = apply_mapping(mapping, rest, surface);
    const auto after = apply_mapping(mapping, moved, surface);
    double largest = 0.0;
    for (std::size_t v = 0; v < before.size(); ++v) largest = std::max(largest, double((after[v] - before[v]).norm()));
    return largest;
}

TEST_P(RealCaseMapping, IsExactAtRestWellConditionedAndMovesRigidly) {
    const std::string name = GetParam();
    const auto input = name == "phantom" ? std::filesystem::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz" : test::real_case(name);
    if (input.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    const LabelVolume volume = read_label_volume(input);
    const Selection selection = select_tissue(volume);
    LayoutReport layout;
    const Lattice lattice = layout_particles(selection, {1}, volume, {}, null_progress(), &layout);
    TriangleMesh visual = extract_surface(selection.tissue);
    const auto start = std::chrono::steady_clock::now();
    SimulationSurfaceReport surface_report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &surface_report);
    const auto middle = std::chrono::steady_clock::now();
    MappingOptions options;
    options.lattice_spacing_mm = lattice.spacing;
    MappingReport report;
    const VisualMapping mapping = map_visual_mesh(visual.positions, lattice, surface, options, null_progress(), &report);
    const auto end = std::chrono::steady_clock::now();
    const auto& rest = lattice.particles.rest_position;
    const auto mapped = apply_mapping(mapping, rest, surface);
    double error = 0.0;
    for (std::size_t v = 0; v < mapped.size(); ++v) error = std::max(error, (mapped[v].cast<double>() - visual.positions[v]).norm());
    std::printf("%s: spacing %.3f mm, %zu particles (%zu on thin-wall ridges, %zu thickening, %zu = %.1f%% of the volume still "
                "one thick); surface %zu triangles, %zu components, %zu thin-wall triangles, %.4f s; mapping of %zu vertices "
                "%.3f s: %zu embedded (%zu convex), %zu tangent (max |d| %.3f mm); max rest error %.3g mm; sensitivity bound "
                "mean %.2f max %.2f\n",
                name.c_str(), lattice.spacing, lattice.particles.size(), layout.ridges, layout.thickened, layout.thin_particles,
                100 * layout.thin_volume_share, surface.size(), surface_report.components, surface_report.thin_wall_triangles,
                std::chrono::duration<double>(middle - start).count(), visual.positions.size(),
                std::chrono::duration<double>(end - middle).count(), report.embedded, report.embedded_convex, report.tangent,
                report.max_offset_mm, error, report.mean_amplification, report.max_amplification);
    for (const auto& w : report.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_LT(error, 1e-4);
    EXPECT_EQ(report.unsolved, 0u);
    EXPECT_EQ(report.embedded + report.tangent, visual.positions.size());
    EXPECT_LE(report.max_amplification, options.max_amplification);
    EXPECT_EQ(report.over_amplification, 0u);

    // Sensitivity: every particle moved by 1 µm in a random direction moves no visual vertex by
    // more than 0.01 mm (three draws). The tangent-space mapping alone, for comparison.
    double largest = 0.0;
    for (unsigned seed : {1u, 2u, 3u}) largest = std::max(largest, largest_response_to_1um(mapping, rest, surface, seed));
    MappingOptions tangent_only = options;
    tangent_only.method = MappingMethod::tangent;
    const VisualMapping tangent_mapping = map_visual_mesh(visual.positions, lattice, surface, tangent_only);
    const double largest_tangent = largest_response_to_1um(tangent_mapping, rest, surface, 1u);
    std::printf("  1 um random particle motion moves a visual vertex by at most %.4f mm (tangent-space mapping only: %.4f mm)\n",
                largest, largest_tangent);
    EXPECT_LE(largest, 0.01);

    // A rigid motion of the particles moves the detailed mesh rigidly.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (const auto& p : rest) centre += Eigen::Vector3d(p[0], p[1], p[2]);
    centre /= double(rest.size());
    const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    const Eigen::Vector3d shift(3.0, -2.0, 5.0);
    auto rigid = [&](const Eigen::Vector3d& x) { return Eigen::Vector3d(centre + rotation * (x - centre) + shift); };
    std::vector<std::array<float, 3>> moved(rest.size());
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const Eigen::Vector3d y = rigid(Eigen::Vector3d(rest[i][0], rest[i][1], rest[i][2]));
        moved[i] = {float(y.x()), float(y.y()), float(y.z())};
    }
    const auto moved_mesh = apply_mapping(mapping, moved, surface);
    double rigid_error = 0.0;
    for (std::size_t v = 0; v < moved_mesh.size(); ++v)
        rigid_error = std::max(rigid_error, (moved_mesh[v].cast<double>() - rigid(visual.positions[v])).norm());
    std::printf("  rigid motion (0.5 rad, 6.2 mm): max error %.3g mm\n", rigid_error);
    EXPECT_LT(rigid_error, 1e-4);
}

INSTANTIATE_TEST_SUITE_P(Hvsmr, RealCaseMapping,
                         ::testing::Values("phantom", "hvsmr16_pat0", "hvsmr16_pat1", "hvsmr16_pat5", "hvsmr16_pat6"));
