/// @file test_surface.cpp
/// @brief The surface stage against analytic shapes: sphere, thick shell, torus, boxes of voxels
/// under rotated, mirrored and anisotropic geometry; smoothing, decimation, determinism.
#include "formats/volume_io.h"
#include "libmodel/errors.h"
#include "libmodel/surface.h"
#include "test_support.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <numbers>
#include <optional>
#include <random>


namespace heartsim {
namespace {

using test::make_mask;
constexpr double pi = std::numbers::pi;

void expect_closed_oriented_manifold(const MeshReport& report) {
    EXPECT_TRUE(report.closed()) << report.boundary_edges << " boundary edges";
    EXPECT_EQ(report.nonmanifold_edges, 0u);
    EXPECT_EQ(report.nonmanifold_vertices, 0u);
    EXPECT_EQ(report.misoriented_edges, 0u);
    EXPECT_EQ(report.degenerate_faces, 0u);
    EXPECT_EQ(report.unused_vertices, 0u);
}

Mask sphere_mask(double radius, const Eigen::Vector3d& centre = Eigen::Vector3d::Zero()) {
    return make_mask(48, 1.0, [&](const Eigen::Vector3d& x) { return (x - centre).norm() <= radius; });
}

double mean_radius_error(const TriangleMesh& mesh, const Eigen::Vector3d& centre, double radius) {
    double sum = 0.0;
    for (const auto& p : mesh.positions) sum += std::abs((p - centre).norm() - radius);
    return sum / double(mesh.positions.size());
}

double mean_radius(const TriangleMesh& mesh, const Eigen::Vector3d& centre) {
    double sum = 0.0;
    for (const auto& p : mesh.positions) sum += (p - centre).norm();
    return sum / double(mesh.positions.size());
}

Eigen::Vector3d vertex_centroid(const TriangleMesh& mesh) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const auto& p : mesh.positions) sum += p;
    return sum / double(mesh.positions.size());
}

/// Volume enclosed by the midpoint marching-cubes surface of an a×b×c box of voxels, in voxel
/// units: the box of voxel centres grown by ½ voxel on faces (½ of each face cell), with edge
/// cells chamfered (⅛ each) and corner cells cut to a tetrahedron (1/48 each). One voxel gives the
/// octahedron of volume 1/6.
double box_surface_volume_in_voxels(int a, int b, int c) {
    const double x = a - 1, y = b - 1, z = c - 1;
    return x * y * z + (x * y + y * z + z * x) + 0.5 * (x + y + z) + 1.0 / 6.0;
}

TEST(MarchingCubes, EveryCubeConfigurationIsAClosedOrientedManifold) {
    // A 2×2×2 mask holds exactly one full cell: all 256 corner patterns, each closed by padding.
    for (int pattern = 1; pattern < 256; ++pattern) {
        Mask mask;
        mask.geometry.dims = {2, 2, 2};
        mask.values.resize(8);
        for (int corner = 0; corner < 8; ++corner) mask.values[std::size_t(corner)] = (pattern >> corner) & 1;
        const MeshReport report = analyse_mesh(marching_cubes(mask));
        SCOPED_TRACE(testing::Message() << "pattern " << pattern);
        expect_closed_oriented_manifold(report);
        EXPECT_GT(report.volume, 0.0);
        // Inside voxels are 6-connected (inside corners never connect across a face), and a 2×2×2
        // set has no tunnels, so every component is a sphere.
        EXPECT_EQ(report.euler_characteristic, 2 * long(report.components));
    }
}

TEST(MarchingCubes, RandomMasksAreClosedOrientedManifolds) {
    std::mt19937 random(12345);
    for (int trial = 0; trial < 20; ++trial) {
        Mask mask;
        mask.geometry.dims = {9, 7, 8};
        mask.values.resize(mask.geometry.voxel_count());
        std::bernoulli_distribution inside(0.2 + 0.03 * trial);
        for (auto& value : mask.values) value = inside(random) ? 1 : 0;
        const MeshReport report = analyse_mesh(marching_cubes(mask));
        SCOPED_TRACE(testing::Message() << "trial " << trial);
        expect_closed_oriented_manifold(report);
        EXPECT_GT(report.volume, 0.0);
    }
}

TEST(MarchingCubes, EmptyMaskGivesEmptyMesh) {
    const Mask mask = make_mask(8, 1.0, [](const Eigen::Vector3d&) { return false; });
    const TriangleMesh mesh = marching_cubes(mask);
    EXPECT_TRUE(mesh.positions.empty());
    EXPECT_TRUE(mesh.triangles.empty());
}

TEST(MarchingCubes, SphereIsOneClosedGenusZeroSurface) {
    const Mask mask = sphere_mask(20.0);
    const MeshReport report = analyse_mesh(marching_cubes(mask));
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 1u);
    EXPECT_EQ(report.euler_characteristic, 2);
    // Before smoothing: the midpoint surface lies between the voxel centres and the voxel faces.
    const double analytic_volume = 4.0 / 3.0 * pi * std::pow(20.0, 3);
    EXPECT_NEAR(report.volume / analytic_volume, 1.0, 0.03);
}

TEST(Surface, SmoothedSphereHasAnalyticAreaAndVolume) {
    const double radius = 20.0;
    const TriangleMesh mesh = extract_surface(sphere_mask(radius));
    const MeshReport report = analyse_mesh(mesh);
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.euler_characteristic, 2);
    const double area = 4.0 * pi * radius * radius, volume = 4.0 / 3.0 * pi * std::pow(radius, 3);
    const double radius_error = mean_radius_error(mesh, Eigen::Vector3d::Zero(), radius);
    std::printf("sphere r=20 mm, 1 mm voxels: area %.2f (analytic %.2f, %+.3f%%), volume %.1f (analytic %.1f, "
                "%+.3f%%), mean |distance - r| %.4f mm\n",
                report.area, area, 100.0 * (report.area / area - 1.0), report.volume, volume,
                100.0 * (report.volume / volume - 1.0), radius_error);
    EXPECT_NEAR(report.area / area, 1.0, 0.01);
    EXPECT_NEAR(report.volume / volume, 1.0, 0.01);
    EXPECT_LT(radius_error, 0.15);
    ASSERT_EQ(mesh.normals.size(), mesh.positions.size());
    // Normals point outwards: along the radius on a sphere.
    double mean_alignment = 0.0;
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) mean_alignment += mesh.normals[v].dot(mesh.positions[v].normalized());
    EXPECT_GT(mean_alignment / double(mesh.positions.size()), 0.99);
}

TEST(Surface, ThickShellIsTwoSpheres) {
    const double inner = 12.0, outer = 20.0;
    const Mask mask = make_mask(48, 1.0, [&](const Eigen::Vector3d& x) { return x.norm() >= inner && x.norm() <= outer; });
    const MeshReport raw = analyse_mesh(marching_cubes(mask));
    expect_closed_oriented_manifold(raw);
    EXPECT_EQ(raw.components, 2u);
    EXPECT_EQ(raw.euler_characteristic, 4);

    const MeshReport report = analyse_mesh(extract_surface(mask));
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 2u);
    EXPECT_EQ(report.euler_characteristic, 4);
    const double area = 4.0 * pi * (outer * outer + inner * inner);
    const double volume = 4.0 / 3.0 * pi * (std::pow(outer, 3) - std::pow(inner, 3));
    std::printf("shell 12..20 mm: area %+.3f%%, volume %+.3f%%\n", 100.0 * (report.area / area - 1.0),
                100.0 * (report.volume / volume - 1.0));
    EXPECT_NEAR(report.area / area, 1.0, 0.01);
    EXPECT_NEAR(report.volume / volume, 1.0, 0.01);
}

TEST(Surface, TorusHasEulerCharacteristicZero) {
    const double major = 13.0, minor = 5.0;
    const Mask mask = make_mask(48, 1.0, [&](const Eigen::Vector3d& x) {
        const double ring = std::hypot(x.x(), x.y()) - major;
        return ring * ring + x.z() * x.z() <= minor * minor;
    });
    for (const auto& mesh : {marching_cubes(mask), extract_surface(mask)}) {
        const MeshReport report = analyse_mesh(mesh);
        expect_closed_oriented_manifold(report);
        EXPECT_EQ(report.components, 1u);
        EXPECT_EQ(report.euler_characteristic, 0);
    }
}

TEST(MarchingCubes, MaskFillingTheVolumeIsClosedAtTheBorder) {
    Mask mask;
    mask.geometry.dims = {6, 5, 4};
    mask.values.assign(mask.geometry.voxel_count(), 1);
    const MeshReport report = analyse_mesh(marching_cubes(mask));
    expect_closed_oriented_manifold(report);
    EXPECT_EQ(report.components, 1u);
    EXPECT_EQ(report.euler_characteristic, 2);
    EXPECT_NEAR(report.volume, box_surface_volume_in_voxels(6, 5, 4), 1e-9);
}

/// A box of voxels [first, first + size) in a volume with rotated (or mirrored) direction,
/// anisotropic spacing and an offset origin.
Mask box_in_placed_volume(const Eigen::Matrix3d& direction, const std::array<int, 3>& first, const std::array<int, 3>& size) {
    Mask mask;
    mask.geometry.dims = {10, 12, 8};
    mask.geometry.spacing = Eigen::Vector3d(0.7, 1.3, 2.1);
    mask.geometry.origin = Eigen::Vector3d(10.0, -20.0, 5.0);
    mask.geometry.direction = direction;
    mask.values.assign(mask.geometry.voxel_count(), 0);
    for (int k = first[2]; k < first[2] + size[2]; ++k)
        for (int j = first[1]; j < first[1] + size[1]; ++j)
            for (int i = first[0]; i < first[0] + size[0]; ++i) mask.values[mask.geometry.linear(i, j, k)] = 1;
    return mask;
}

void check_box_in_world(const Eigen::Matrix3d& direction) {
    const std::array<int, 3> first{2, 3, 1}, size{5, 7, 4};
    const Mask mask = box_in_placed_volume(direction, first, size);
    const TriangleMesh mesh = marching_cubes(mask);
    const MeshReport report = analyse_mesh(mesh);
    expect_closed_oriented_manifold(report);
    const double expected_volume = box_surface_volume_in_voxels(size[0], size[1], size[2]) * mask.geometry.voxel_volume();
    EXPECT_NEAR(report.volume, expected_volume, 1e-9 * expected_volume);

    // Along each voxel axis (a unit column of the direction matrix), the surface spans exactly
    // half a voxel beyond the box's outer voxel centres.
    for (int axis = 0; axis < 3; ++axis) {
        double low = 1e9, high = -1e9;
        for (const auto& p : mesh.positions) {
            const double index = (p - mask.geometry.origin).dot(direction.col(axis)) / mask.geometry.spacing[axis];
            low = std::min(low, index);
            high = std::max(high, index);
        }
        EXPECT_NEAR(low, first[std::size_t(axis)] - 0.5, 1e-9);
        EXPECT_NEAR(high, first[std::size_t(axis)] + size[std::size_t(axis)] - 0.5, 1e-9);
    }
}

TEST(MarchingCubes, RotatedAnisotropicBoxHasAnalyticExtentAndVolume) {
    const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    check_box_in_world(rotation);
}

TEST(MarchingCubes, MirroredDirectionKeepsOutwardOrientation) {
    const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    const Eigen::Matrix3d mirrored = rotation * Eigen::Vector3d(1.0, -1.0, 1.0).asDiagonal();
    ASSERT_LT(mirrored.determinant(), 0.0);
    check_box_in_world(mirrored);  // includes: positive volume equal to the analytic one
}

TEST(Smoothing, WindowedSincKeepsCentroidAndSizeWhereLaplacianShrinks) {
    const double radius = 15.0;
    const Eigen::Vector3d centre(3.0, -2.0, 1.5);
    const Mask mask = sphere_mask(radius, centre);
    const TriangleMesh raw = marching_cubes(mask);

    TriangleMesh windowed_sinc = raw;
    smooth_windowed_sinc(windowed_sinc, 20, 0.01);

    // Plain umbrella-Laplacian smoothing (λ = 0.5, as many passes) for comparison.
    TriangleMesh laplacian = raw;
    std::vector<std::vector<std::int32_t>> neighbours(raw.positions.size());
    for (const auto& t : raw.triangles)
        for (int c = 0; c < 3; ++c) neighbours[std::size_t(t[c])].push_back(t[(c + 1) % 3]);  // closed: each edge once per direction
    for (int pass = 0; pass < 20; ++pass) {
        auto next = laplacian.positions;
        for (std::size_t v = 0; v < next.size(); ++v) {
            Eigen::Vector3d mean = Eigen::Vector3d::Zero();
            for (auto n : neighbours[v]) mean += laplacian.positions[std::size_t(n)];
            mean /= double(neighbours[v].size());
            next[v] += 0.5 * (mean - laplacian.positions[v]);
        }
        laplacian.positions = std::move(next);
    }

    const double raw_volume = analyse_mesh(raw).volume;
    const double sinc_volume = analyse_mesh(windowed_sinc).volume;
    const double laplacian_volume = analyse_mesh(laplacian).volume;
    std::printf("volume: raw %.1f, windowed sinc %.1f, Laplacian %.1f (analytic %.1f)\n", raw_volume, sinc_volume,
                laplacian_volume, 4.0 / 3.0 * pi * std::pow(radius, 3));
    EXPECT_NEAR((vertex_centroid(windowed_sinc) - centre).norm(), 0.0, 0.01);
    EXPECT_NEAR(mean_radius(windowed_sinc, centre) / radius, 1.0, 0.01);
    EXPECT_GT(sinc_volume, raw_volume * 0.995);  // no shrinking...
    EXPECT_LT(laplacian_volume, raw_volume * 0.97);  // ...where plain Laplacian smoothing shrinks
    EXPECT_LT(mean_radius(laplacian, centre) / radius, 0.985);
}

TEST(Smoothing, CommutesWithTranslationAndScaling) {
    // A linear filter applied in normalised coordinates: moving and scaling the input moves and
    // scales the output the same way.
    const TriangleMesh raw = marching_cubes(sphere_mask(10.0));
    TriangleMesh reference = raw, moved = raw;
    for (auto& p : moved.positions) p = 1e3 * p + Eigen::Vector3d(1e5, -2e5, 3e4);
    smooth_windowed_sinc(reference, 20, 0.01);
    smooth_windowed_sinc(moved, 20, 0.01);
    double worst = 0.0;
    for (std::size_t v = 0; v < raw.positions.size(); ++v)
        worst = std::max(worst, ((moved.positions[v] - Eigen::Vector3d(1e5, -2e5, 3e4)) / 1e3 - reference.positions[v]).norm());
    EXPECT_LT(worst, 1e-8);
}

TEST(Smoothing, RejectsBadParameters) {
    TriangleMesh mesh = marching_cubes(sphere_mask(5.0));
    EXPECT_THROW(smooth_windowed_sinc(mesh, 0, 0.1), InputError);
    EXPECT_THROW(smooth_windowed_sinc(mesh, 20, 0.0), InputError);
    EXPECT_THROW(smooth_windowed_sinc(mesh, 20, 2.0), InputError);
}

TEST(Decimation, HalvesTrianglesKeepingAClosedManifoldAndTheVolume) {
    const double radius = 20.0;
    TriangleMesh mesh = extract_surface(sphere_mask(radius));
    const MeshReport before = analyse_mesh(mesh);
    decimate(mesh, 0.5);
    const MeshReport after = analyse_mesh(mesh);
    expect_closed_oriented_manifold(after);
    EXPECT_EQ(after.euler_characteristic, 2);
    EXPECT_NEAR(double(after.faces) / double(before.faces), 0.5, 0.02);
    EXPECT_NEAR(after.volume / before.volume, 1.0, 0.01);
    EXPECT_NEAR(after.volume / (4.0 / 3.0 * pi * std::pow(radius, 3)), 1.0, 0.01);
    std::printf("decimation 0.5: %zu -> %zu faces, volume %+.3f%%\n", before.faces, after.faces,
                100.0 * (after.volume / before.volume - 1.0));
}

TEST(Decimation, RefusesAnOpenMesh) {
    TriangleMesh mesh = marching_cubes(sphere_mask(8.0));
    mesh.triangles.pop_back();
    EXPECT_THROW(decimate(mesh, 0.5), InputError);
}

TEST(Surface, SameResultForAnyThreadCount) {
    const Mask mask = make_mask(64, 1.0, [](const Eigen::Vector3d& x) {
        const double r = (x - Eigen::Vector3d(2, 0, -1)).norm();
        return (r >= 14.0 && r <= 24.0 && x.z() < 15.0) || std::abs(x.x()) < 2.0;
    });
    auto run = [&](int threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        return extract_surface(mask);
    };
    const TriangleMesh one = run(1), two = run(2), four = run(4);
    ASSERT_FALSE(one.triangles.empty());
    for (const TriangleMesh* other : {&two, &four}) {
        ASSERT_EQ(one.positions.size(), other->positions.size());
        ASSERT_EQ(one.triangles, other->triangles);
        for (std::size_t v = 0; v < one.positions.size(); ++v)
            ASSERT_EQ(one.positions[v], other->positions[v]) << "vertex " << v;  // bitwise
    }
}

/// Cancels at the first progress update of a named stage.
class CancelDuring final : public Progress {
public:
    explicit CancelDuring(std::string stage) : stage_(std::move(stage)) {}
    void begin(std::string_view stage, std::uint64_t) override { active_ = stage == stage_; }
    void update(std::uint64_t) override { if (active_) cancel_ = true; }
    void end() override { active_ = false; }
    bool cancelled() const override { return cancel_; }
private:
    std::string stage_;
    bool active_ = false;
    std::atomic<bool> cancel_{false};
};

TEST(Surface, CancellationStopsEachStage) {
    const Mask mask = sphere_mask(20.0);
    for (const char* stage : {"marching cubes", "smoothing", "decimation"}) {
        CancelDuring progress(stage);
        EXPECT_THROW(extract_surface(mask, {.decimation = 0.5}, progress), Cancelled) << stage;
    }
}

/// Not a benchmark (no assertion on time): prints the surface stage's time on a real heart, on
/// one thread and on all, and checks the surface is a closed oriented manifold.
TEST(Surface, RealHeartLabelOne) {
    const auto file = test::real_case("hvsmr16_pat1");
    if (file.empty()) GTEST_SKIP() << "real data absent";
    const LabelVolume labels = read_label_volume(file);
    Mask mask{labels.geometry, {}};
    mask.values.resize(labels.labels.size());
    for (std::size_t v = 0; v < labels.labels.size(); ++v) mask.values[v] = labels.labels[v] == 1;
    for (int threads : {1, 0}) {
        std::optional<tbb::global_control> limit;
        if (threads > 0) limit.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        SurfaceReport report;
        const TriangleMesh mesh = extract_surface(mask, {}, null_progress(), &report);
        std::printf("hvsmr16_pat1 label 1 (%d×%d×%d), %s: %zu triangles, marching cubes %.3f s, smoothing %.3f s\n",
                    mask.geometry.dims[0], mask.geometry.dims[1], mask.geometry.dims[2],
                    threads == 1 ? "1 thread" : "all threads", report.triangles, report.seconds_marching_cubes,
                    report.seconds_smoothing);
        const MeshReport check = analyse_mesh(mesh);
        expect_closed_oriented_manifold(check);
        EXPECT_GT(check.volume, 0.0);
    }
}

}  // namespace
}  // namespace heartsim
