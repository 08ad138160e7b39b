/// @file test_mesh_io.cpp
/// @brief Mesh files through assimp: round trips for every written format, and the errors that
/// name the file.
#include "formats/mesh_io.h"
#include "libmodel/errors.h"
#include "libmodel/surface.h"
#include "test_support.h"

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

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
/// position triples, matched through each position rounded to float: STL, OBJ and PLY store
/// float coordinates in mm (OBJ as text with 9 significant digits, which round-trips a float
/// exactly). glTF stores float metres, so a vertex comes back within `tolerance_mm` (a float's
/// rounding of the metre value, times 1000) and is matched to the nearest.
void expect_same_geometry(const TriangleMesh& expected, const TriangleMesh& actual, double tolerance_mm = 0) {
    ASSERT_EQ(expected.triangles.size(), actual.triangles.size());
    ASSERT_EQ(expected.positions.size(), actual.positions.size());
    auto key = [](const Eigen::Vector3d& p) { return std::array<float, 3>{float(p.x()), float(p.y()), float(p.z())}; };
    std::map<std::array<float, 3>, std::int32_t> expected_vertex_at;
    for (std::size_t v = 0; v < expected.positions.size(); ++v) expected_vertex_at[key(expected.positions[v])] = std::int32_t(v);
    ASSERT_EQ(expected_vertex_at.size(), expected.positions.size()) << "sample vertices must be distinct as floats";

    std::vector<std::int32_t> expected_of_actual(actual.positions.size(), -1);
    for (std::size_t v = 0; v < actual.positions.size(); ++v) {
        if (tolerance_mm > 0) {
            std::size_t nearest = 0;
            for (std::size_t e = 1; e < expected.positions.size(); ++e)
                if ((expected.positions[e] - actual.positions[v]).squaredNorm() < (expected.positions[nearest] - actual.positions[v]).squaredNorm())
                    nearest = e;
            ASSERT_LE((expected.positions[nearest] - actual.positions[v]).norm(), tolerance_mm) << "vertex " << v;
            expected_of_actual[v] = std::int32_t(nearest);
            continue;
        }
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
    // glTF: float metres; a float's relative rounding 6e-8 of ~0.33 m is 2e-5 mm.
    expect_same_geometry(mesh, back, GetParam() == ".glb" ? 1e-4 : 0.0);
    const MeshReport report = analyse_mesh(back);
    EXPECT_TRUE(report.closed());
    EXPECT_TRUE(report.manifold());
    EXPECT_NEAR(report.volume, analyse_mesh(mesh).volume, 1e-5 * analyse_mesh(mesh).volume);
}

INSTANTIATE_TEST_SUITE_P(Formats, MeshRoundTrip, ::testing::Values(".stl", ".obj", ".ply", ".glb"),
                         [](const auto& info) { return info.param.substr(1); });

TEST(MeshIo, StlFacetsCarryTheirTrueNormalsAndTheHeaderSaysLps) {
    // Read by hand, not through our reader: the 80-byte header, then per facet a normal that is
    // the unit cross product of its edges (right-hand rule) and points out of the sphere. (assimp's
    // STL exporter wrote the mean of the corners' vertex normals.)
    const TriangleMesh mesh = sample_mesh();
    test::TempDir dir;
    write_mesh(dir / "sphere.stl", mesh);
    std::ifstream in(dir / "sphere.stl", std::ios::binary);
    char header[80];
    in.read(header, 80);
    EXPECT_NE(std::string(header, 80).find("SPACE=LPS"), std::string::npos);
    std::uint32_t count = 0;
    in.read(reinterpret_cast<char*>(&count), 4);
    ASSERT_EQ(count, mesh.triangles.size());
    const Eigen::Vector3d centre(-120.25, 35.5, 310.75);
    double worst_degrees = 0;
    for (std::uint32_t f = 0; f < count; ++f) {
        float values[12];
        std::uint16_t attribute;
        in.read(reinterpret_cast<char*>(values), sizeof values);
        in.read(reinterpret_cast<char*>(&attribute), 2);
        ASSERT_TRUE(in) << "facet " << f;
        const Eigen::Vector3d n(values[0], values[1], values[2]), a(values[3], values[4], values[5]), b(values[6], values[7], values[8]),
            c(values[9], values[10], values[11]);
        // Facets are written in the mesh's order: the truth from its double corners.
        const auto& t = mesh.triangles[f];
        const Eigen::Vector3d& p0 = mesh.positions[std::size_t(t[0])];
        const Eigen::Vector3d truth = (mesh.positions[std::size_t(t[1])] - p0).cross(mesh.positions[std::size_t(t[2])] - p0).normalized();
        EXPECT_EQ(a.cast<float>(), p0.cast<float>()) << "facet " << f;
        EXPECT_NEAR(n.norm(), 1.0, 1e-6) << "facet " << f;
        worst_degrees = std::max(worst_degrees, std::atan2(n.cross(truth).norm(), n.dot(truth)) * 180.0 / M_PI);  // not acos: flat near 0
        EXPECT_GT(n.dot((a + b + c) / 3.0 - centre), 0.0) << "facet " << f << " normal points inwards";
    }
    EXPECT_LT(worst_degrees, 1e-4) << "largest angle between a written normal and its facet's (a float's rounding)";
    in.get();
    EXPECT_TRUE(in.eof()) << "nothing after the last facet";
}

TEST(MeshIo, ObjAndPlyHeadersSayLps) {
    test::TempDir dir;
    for (const char* name : {"sphere.obj", "sphere.ply"}) {
        write_mesh(dir / name, sample_mesh());
        std::ifstream in(dir / name, std::ios::binary);
        std::string head(200, '\0');
        in.read(head.data(), std::streamsize(head.size()));
        EXPECT_NE(head.find(std::string(std::string(name) == "sphere.obj" ? "# " : "comment ") + "heartsim"), std::string::npos) << name;
        EXPECT_NE(head.find("SPACE=LPS units=mm"), std::string::npos) << name;
    }
}

TEST(MeshIo, GlbIsInMetresWithYUpAsGltfViewersExpect) {
    // Read back through assimp directly (no conversion), as a glTF viewer would: metres, +Y the
    // patient's superior, +Z anterior (−LPS y), +X left.
    const TriangleMesh mesh = sample_mesh();
    test::TempDir dir;
    write_mesh(dir / "sphere.glb", mesh);
    Assimp::Importer importer;
    const aiScene* scene = importer.ReadFile((dir / "sphere.glb").string(), aiProcess_PreTransformVertices);
    ASSERT_NE(scene, nullptr) << importer.GetErrorString();
    Eigen::AlignedBox3d seen, expected;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m)
        for (unsigned v = 0; v < scene->mMeshes[m]->mNumVertices; ++v) {
            const aiVector3D& p = scene->mMeshes[m]->mVertices[v];
            seen.extend(Eigen::Vector3d(p.x, p.y, p.z));
        }
    for (const auto& p : mesh.positions) expected.extend(Eigen::Vector3d(p.x(), p.z(), -p.y()) / 1000.0);
    EXPECT_LT((seen.min() - expected.min()).norm(), 1e-7) << seen.min().transpose() << " m, expected " << expected.min().transpose();
    EXPECT_LT((seen.max() - expected.max()).norm(), 1e-7) << seen.max().transpose() << " m, expected " << expected.max().transpose();
    EXPECT_NEAR(seen.center().y(), 0.31075, 1e-5) << "the sphere's superior coordinate, in metres, is glTF's up";
}

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

/// read_mesh(path) throws InputError "PATH: cannot read the mesh: …" mentioning `reason`.
void expect_unreadable_mesh(const std::filesystem::path& path, const std::string& reason) {
    try {
        read_mesh(path);
        ADD_FAILURE() << path << " was read; expected: " << reason;
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find(path.string() + ": cannot read the mesh"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find(reason), std::string::npos) << e.what();
    }
}

/// An ASCII PLY declaring `vertices` vertices and one face, followed by `body`.
void write_ascii_ply(const std::filesystem::path& path, const std::string& vertices, const std::string& body) {
    std::ofstream(path) << "ply\nformat ascii 1.0\nelement vertex " << vertices << "\nproperty float x\nproperty float y\nproperty float z\n"
                        << "element face 1\nproperty list uchar int vertex_indices\nend_header\n" << body;
}

TEST(MeshIo, AFaceIndexPastTheVerticesIsRefused) {
    // Face 0 uses vertex 77 of 3: the PLY loader let it through and the mesh came out with two
    // vertices and one triangle.
    test::TempDir dir;
    write_ascii_ply(dir / "oob.ply", "3", "0 0 0\n1 0 0\n0 1 0\n3 0 1 77\n");
    expect_unreadable_mesh(dir / "oob.ply", "out of range");
}

TEST(MeshIo, ANonFiniteOrImplausiblyFarVertexIsRefusedNamingTheMeshFile) {
    // It used to pass, and `heartprep map` then blamed the scenario for "visual vertex 0".
    test::TempDir dir;
    write_ascii_ply(dir / "nan.ply", "3", "nan 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    expect_unreadable_mesh(dir / "nan.ply", "vertex 0 is not finite");
    write_ascii_ply(dir / "far.ply", "3", "0 0 0\n1e30 0 0\n0 1 0\n3 0 1 2\n");  // a unit mistake, not a heart
    expect_unreadable_mesh(dir / "far.ply", "vertex 1 coordinate is 1e+30 mm, outside the plausible range");
}

TEST(MeshIo, AHeaderDeclaringBillionsOfVerticesIsAnInputErrorNotBadAlloc) {
    if (test::under_address_sanitizer) GTEST_SKIP() << "AddressSanitizer stops the process at a 48 GB allocation instead of throwing bad_alloc";
    test::TempDir dir;
    write_ascii_ply(dir / "huge.ply", "4000000000", "0 0 0\n");
    expect_unreadable_mesh(dir / "huge.ply", "more vertices or faces than memory holds");
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
