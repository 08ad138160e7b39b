/// @file test_mesh_io.cpp
/// @brief Mesh files through assimp: round trips for every written format, and the errors that
/// name the file.
#include "formats/mesh_io.h"
#include "libmodel/errors.h"
#include "libmodel/surface.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <limits>

#include <fstream>
#include <map>

namespace heartsim {
namespace {

/// A smoothed sphere away from the origin, in world mm: irregular float coordinates, ~3k vertices.
TriangleMesh sample_mesh() {
    const Mask mask = test::make_mask(24, 1.0, [](const Eigen::Vector3d& x) { return x.norm() <= 9.0; });
    TriangleMesh mesh = extract_surface(mask);
    for (auto& p : mesh.positions) p += Eigen::Vector3d(-120.25, 35.5, 310.75);
    return mesh;
}

/// Vertex order may change on the way (assimp joins and reorders), so compare triangles as
/// position triples, matched through each position rounded to float: every format stores float
/// coordinates (OBJ as text with 9 significant digits, which round-trips a float exactly).
void expect_same_geometry(const TriangleMesh& expected, const TriangleMesh& actual) {
    ASSERT_EQ(expected.triangles.size(), actual.triangles.size());
    ASSERT_EQ(expected.positions.size(), actual.positions.size());
    auto key = [](const Eigen::Vector3d& p) { return std::array<float, 3>{float(p.x()), float(p.y()), float(p.z())}; };
    std::map<std::array<float, 3>, std::int32_t> expected_vertex_at;
    for (std::size_t v = 0; v < expected.positions.size(); ++v) expected_vertex_at[key(expected.positions[v])] = std::int32_t(v);
    ASSERT_EQ(expected_vertex_at.size(), expected.positions.size()) << "sample vertices must be distinct as floats";

    std::vector<std::int32_t> expected_of_actual(actual.positions.size(), -1);
    for (std::size_t v = 0; v < actual.positions.size(); ++v) {
        const auto found = expected_vertex_at.find(key(actual.positions[v]));
        ASSERT_TRUE(found != expected_vertex_at.end()) << "vertex " << v << " moved beyond float rounding";
        expected_of_actual[v] = found->second;
    }
    // Same triangles with the same orientation (any rotation of the corners).
    std::map<std::array<std::int32_t, 3>, int> expected_triangles;
    auto canonical = [](std::array<std::int32_t, 3> t) {
        while (t[0] != std::min({t[0], t[1], t[2]})) t = {t[1], t[2], t[0]};
        return t;
    };
    for (const auto& t : expected.triangles) ++expected_triangles[canonical(t)];
    for (const auto& t : actual.triangles) {
        const auto mapped = canonical({expected_of_actual[std::size_t(t[0])], expected_of_actual[std::size_t(t[1])],
                                       expected_of_actual[std::size_t(t[2])]});
        auto found = expected_triangles.find(mapped);
        ASSERT_TRUE(found != expected_triangles.end() && found->second > 0) << "triangle missing or flipped";
        --found->second;
    }
}

class MeshRoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(MeshRoundTrip, KeepsPositionsAndTriangles) {
    const TriangleMesh mesh = sample_mesh();
    test::TempDir dir;
    const auto path = dir / ("sphere" + GetParam());
    write_mesh(path, mesh);
    ASSERT_TRUE(std::filesystem::exists(path));
    // Atomic write: nothing but the target is left beside it.
    EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir.path()), std::filesystem::directory_iterator()), 1);
    const TriangleMesh back = read_mesh(path);
    expect_same_geometry(mesh, back);
    const MeshReport report = analyse_mesh(back);
    EXPECT_TRUE(report.closed());
    EXPECT_TRUE(report.manifold());
    EXPECT_NEAR(report.volume, analyse_mesh(mesh).volume, 1e-5 * analyse_mesh(mesh).volume);
}

INSTANTIATE_TEST_SUITE_P(Formats, MeshRoundTrip, ::testing::Values(".stl", ".obj", ".ply", ".glb"),
                         [](const auto& info) { return info.param.substr(1); });

TEST(MeshIo, OverwritesAnExistingFile) {
    test::TempDir dir;
    const auto path = dir / "mesh.stl";
    { std::ofstream(path) << "old content"; }
    write_mesh(path, sample_mesh());
    EXPECT_EQ(read_mesh(path).triangles.size(), sample_mesh().triangles.size());
}

TEST(MeshIo, UnknownExtensionIsAnOutputErrorNamingTheFile) {
    test::TempDir dir;
    const auto path = dir / "mesh.xyz";
    try {
        write_mesh(path, sample_mesh());
        FAIL() << "expected OutputError";
    } catch (const OutputError& error) {
        EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    }
    EXPECT_FALSE(std::filesystem::exists(path));
}

TEST(MeshIo, ANonFiniteVertexIsRefusedAndTheOldFileKept) {
    // No writer accepts a non-finite value: a NaN vertex is a diverged simulation or a bug.
    test::TempDir dir;
    const auto path = dir / "mesh.stl";
    write_mesh(path, sample_mesh());
    TriangleMesh broken = sample_mesh();
    broken.positions[3][1] = std::numeric_limits<float>::quiet_NaN();
    try {
        write_mesh(path, broken);
        FAIL() << "expected OutputError";
    } catch (const OutputError& error) {
        EXPECT_NE(std::string(error.what()).find("vertex 3"), std::string::npos) << error.what();
        EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    }
    EXPECT_EQ(read_mesh(path).positions.size(), sample_mesh().positions.size()) << "the old file is intact";
}

TEST(MeshIo, UnwritablePlaceIsAnOutputErrorNamingTheFile) {
    test::TempDir dir;
    const auto path = dir / "no" / "such" / "folder" / "mesh.stl";
    try {
        write_mesh(path, sample_mesh());
        FAIL() << "expected OutputError";
    } catch (const OutputError& error) {
        EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    }
}

TEST(MeshIo, MissingFileIsAnInputErrorNamingTheFile) {
    test::TempDir dir;
    const auto path = dir / "absent.stl";
    try {
        read_mesh(path);
        FAIL() << "expected InputError";
    } catch (const InputError& error) {
        EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    }
}

TEST(MeshIo, GarbageFileIsAnInputError) {
    test::TempDir dir;
    const auto path = dir / "garbage.ply";
    { std::ofstream(path) << "this is not a mesh\n"; }
    EXPECT_THROW(read_mesh(path), InputError);
}

TEST(MeshIo, FileWithoutTrianglesIsAnInputError) {
    test::TempDir dir;
    const auto path = dir / "points.obj";
    { std::ofstream(path) << "v 0 0 0\nv 1 0 0\nv 0 1 0\n"; }
    EXPECT_THROW(read_mesh(path), InputError);
}

TEST(MeshIo, ReadsQuadsAsTriangles) {
    test::TempDir dir;
    const auto path = dir / "quad.obj";
    { std::ofstream(path) << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"; }
    const TriangleMesh mesh = read_mesh(path);
    EXPECT_EQ(mesh.triangles.size(), 2u);
    EXPECT_NEAR(analyse_mesh(mesh).area, 1.0, 1e-12);
}

}  // namespace
}  // namespace heartsim
