/// @file mesh_io.cpp
/// @brief Triangle meshes to and from files. STL, OBJ and PLY are written here (a few lines
/// each: true facet normals, a SPACE=LPS header that Slicer reads), and so is VTK's XML PolyData
/// (.vtp, for ParaView); glTF through assimp's
/// exporter, in glTF's own frame (metres, +Y up); every format read through assimp.
#include "mesh_io.h"

#include "atomic_file.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <Eigen/Geometry>

#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <string>

namespace heartsim {

namespace {

std::string lower_case_extension(const std::filesystem::path& path) { return text::lowercase(path.extension().string()); }

bool is_gltf(const std::string& extension) { return extension == ".glb" || extension == ".gltf"; }

/// World LPS mm → glTF (metres; +Y up = superior, +Z forward = anterior, +X = left: a proper
/// rotation, so windings and normals keep their sense), and back.
Eigen::Vector3d lps_mm_to_gltf(const Eigen::Vector3d& p) { return Eigen::Vector3d(p.x(), p.z(), -p.y()) * 1e-3; }
Eigen::Vector3d gltf_to_lps_mm(const Eigen::Vector3d& g) { return Eigen::Vector3d(g.x(), -g.z(), g.y()) * 1e3; }

/// The unit normal of triangle t (right-hand rule), computed in double; zero for a degenerate one.
Eigen::Vector3d facet_normal(const TriangleMesh& mesh, const std::array<std::int32_t, 3>& t) {
    const Eigen::Vector3d& a = mesh.positions[std::size_t(t[0])];
    const Eigen::Vector3d u = mesh.positions[std::size_t(t[1])] - a, w = mesh.positions[std::size_t(t[2])] - a;
    const Eigen::Vector3d n = u.cross(w);
    const double length = n.norm();
    return length > 0 ? Eigen::Vector3d(n / length) : Eigen::Vector3d::Zero();
}

/// The words every header we write carries: Slicer reads the SPACE tag, the rest is for people.
constexpr const char* header_words = "heartsim " HEARTSIM_VERSION " SPACE=LPS units=mm";

template <class T>
void put(std::ostream& out, T value) {
    out.write(reinterpret_cast<const char*>(&value), sizeof value);  // little-endian: x86-64, aarch64
}

/// Binary STL: 80-byte header, facet count, then per facet its true normal, three corners and a
/// zero attribute word.
void write_stl(std::ostream& out, const TriangleMesh& mesh) {
    char header[80] = {};
    std::snprintf(header, sizeof header, "%s", header_words);
    out.write(header, sizeof header);
    put(out, std::uint32_t(mesh.triangles.size()));
    for (const auto& t : mesh.triangles) {
        const Eigen::Vector3d n = facet_normal(mesh, t);
        for (int c = 0; c < 3; ++c) put(out, float(n[c]));
        for (const std::int32_t v : t)
            for (int c = 0; c < 3; ++c) put(out, float(mesh.positions[std::size_t(v)][c]));
        put(out, std::uint16_t(0));
    }
}

/// OBJ: positions (9 significant digits round-trip a float), vertex normals when the mesh has
/// them, triangles.
void write_obj(std::ostream& out, const TriangleMesh& mesh) {
    const bool normals = !mesh.normals.empty() && mesh.normals.size() == mesh.positions.size();
    out << "# " << header_words << "\n";
    char line[128];
    for (const auto& p : mesh.positions) {
        std::snprintf(line, sizeof line, "v %.9g %.9g %.9g\n", float(p.x()), float(p.y()), float(p.z()));
        out << line;
    }
    if (normals)
        for (const auto& n : mesh.normals) {
            std::snprintf(line, sizeof line, "vn %.9g %.9g %.9g\n", float(n.x()), float(n.y()), float(n.z()));
            out << line;
        }
    for (const auto& t : mesh.triangles) {
        if (normals) out << "f " << t[0] + 1 << "//" << t[0] + 1 << ' ' << t[1] + 1 << "//" << t[1] + 1 << ' ' << t[2] + 1 << "//" << t[2] + 1 << '\n';
        else out << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
    }
}

/// Binary little-endian PLY: float positions (and normals when the mesh has them), triangles as
/// uchar-counted int lists.
void write_ply(std::ostream& out, const TriangleMesh& mesh) {
    const bool normals = !mesh.normals.empty() && mesh.normals.size() == mesh.positions.size();
    out << "ply\nformat binary_little_endian 1.0\ncomment " << header_words << "\nelement vertex " << mesh.positions.size()
        << "\nproperty float x\nproperty float y\nproperty float z\n";
    if (normals) out << "property float nx\nproperty float ny\nproperty float nz\n";
    out << "element face " << mesh.triangles.size() << "\nproperty list uchar int vertex_indices\nend_header\n";
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
        for (int c = 0; c < 3; ++c) put(out, float(mesh.positions[v][c]));
        if (normals)
            for (int c = 0; c < 3; ++c) put(out, float(mesh.normals[v][c]));
    }
    for (const auto& t : mesh.triangles) {
        put(out, std::uint8_t(3));
        for (const std::int32_t v : t) put(out, v);
    }
}

/// Base64 (RFC 4648, padded), as VTK's XML readers decode a binary DataArray.
std::string base64(const unsigned char* data, std::size_t size) {
    static const char* digits = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string text;
    text.reserve((size + 2) / 3 * 4);
    for (std::size_t i = 0; i < size; i += 3) {
        const std::uint32_t a = data[i], b = i + 1 < size ? data[i + 1] : 0, c = i + 2 < size ? data[i + 2] : 0;
        const std::uint32_t word = (a << 16) | (b << 8) | c;
        text += digits[(word >> 18) & 63];
        text += digits[(word >> 12) & 63];
        text += i + 1 < size ? digits[(word >> 6) & 63] : '=';
        text += i + 2 < size ? digits[word & 63] : '=';
    }
    return text;
}

/// One binary DataArray of VTK's XML format: its byte count (UInt64) and its bytes, each
/// base64-encoded on its own, as vtkXMLWriter writes uncompressed inline data.
template <class T>
void vtk_array(std::ostream& out, const char* type, const char* name, int components, const std::vector<T>& values) {
    out << "        <DataArray type=\"" << type << "\"";
    if (name) out << " Name=\"" << name << "\"";
    out << " NumberOfComponents=\"" << components << "\" format=\"binary\">\n          ";
    const std::uint64_t bytes = values.size() * sizeof(T);
    out << base64(reinterpret_cast<const unsigned char*>(&bytes), sizeof bytes)
        << base64(reinterpret_cast<const unsigned char*>(values.data()), bytes) << "\n        </DataArray>\n";
}

/// VTK XML PolyData (.vtp): float32 points (and normals when the mesh has them), triangles as
/// connectivity and offsets, base64 binary inline (little-endian, UInt64 headers).
void write_vtp(std::ostream& out, const TriangleMesh& mesh) {
    const bool normals = !mesh.normals.empty() && mesh.normals.size() == mesh.positions.size();
    out << "<?xml version=\"1.0\"?>\n<!-- " << header_words << " -->\n"
        << "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <PolyData>\n"
        << "    <Piece NumberOfPoints=\"" << mesh.positions.size() << "\" NumberOfVerts=\"0\" NumberOfLines=\"0\" NumberOfStrips=\"0\" "
        << "NumberOfPolys=\"" << mesh.triangles.size() << "\">\n";
    auto floats = [](const std::vector<Eigen::Vector3d>& rows) {
        std::vector<float> values;
        values.reserve(3 * rows.size());
        for (const auto& p : rows)
            for (int c = 0; c < 3; ++c) values.push_back(float(p[c]));
        return values;
    };
    if (normals) {
        out << "      <PointData Normals=\"Normals\">\n";
        vtk_array(out, "Float32", "Normals", 3, floats(mesh.normals));
        out << "      </PointData>\n";
    }
    out << "      <Points>\n";
    vtk_array(out, "Float32", "Points", 3, floats(mesh.positions));
    out << "      </Points>\n      <Polys>\n";
    std::vector<std::int32_t> connectivity, offsets;
    connectivity.reserve(3 * mesh.triangles.size());
    offsets.reserve(mesh.triangles.size());
    for (const auto& t : mesh.triangles) {
        connectivity.insert(connectivity.end(), t.begin(), t.end());
        offsets.push_back(std::int32_t(connectivity.size()));
    }
    vtk_array(out, "Int32", "connectivity", 1, connectivity);
    vtk_array(out, "Int32", "offsets", 1, offsets);
    out << "      </Polys>\n    </Piece>\n  </PolyData>\n</VTKFile>\n";
}

/// A one-mesh scene. aiScene's destructor frees its meshes, materials and nodes with delete /
/// delete[], so everything below is allocated with new / new[] and owned by the scene.
std::unique_ptr<aiScene> scene_of(const TriangleMesh& mesh, const std::function<Eigen::Vector3d(const Eigen::Vector3d&)>& to_file) {
    auto scene = std::make_unique<aiScene>();
    scene->mRootNode = new aiNode();
    scene->mRootNode->mNumMeshes = 1;
    scene->mRootNode->mMeshes = new unsigned int[1]{0};
    // Several exporters (OBJ, glTF) expect at least one material.
    scene->mNumMaterials = 1;
    scene->mMaterials = new aiMaterial*[1]{new aiMaterial()};
    scene->mNumMeshes = 1;
    scene->mMeshes = new aiMesh*[1]{new aiMesh()};

    aiMesh& out = *scene->mMeshes[0];
    out.mMaterialIndex = 0;
    out.mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
    out.mNumVertices = unsigned(mesh.positions.size());
    out.mVertices = new aiVector3D[mesh.positions.size()];
    for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
        const Eigen::Vector3d p = to_file(mesh.positions[v]);
        out.mVertices[v] = aiVector3D(ai_real(p.x()), ai_real(p.y()), ai_real(p.z()));
    }
    if (mesh.normals.size() == mesh.positions.size() && !mesh.normals.empty()) {
        out.mNormals = new aiVector3D[mesh.normals.size()];
        for (std::size_t v = 0; v < mesh.normals.size(); ++v) {
            const Eigen::Vector3d n = to_file(mesh.normals[v]).normalized();  // the rotation; the scale does not matter
            out.mNormals[v] = aiVector3D(ai_real(n.x()), ai_real(n.y()), ai_real(n.z()));
        }
    }
    out.mNumFaces = unsigned(mesh.triangles.size());
    out.mFaces = new aiFace[mesh.triangles.size()];
    for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
        aiFace& face = out.mFaces[f];
        face.mNumIndices = 3;
        face.mIndices = new unsigned int[3];
        for (int c = 0; c < 3; ++c) face.mIndices[c] = unsigned(mesh.triangles[f][std::size_t(c)]);
    }
    return scene;
}

}  // namespace

bool is_writable_mesh_path(const std::filesystem::path& path) {
    const std::string extension = lower_case_extension(path);
    return extension == ".stl" || extension == ".obj" || extension == ".ply" || extension == ".vtp" || extension == ".glb";
}

const char* written_mesh_frame(const std::filesystem::path& path) {
    return text::lowercase(path.extension().string()) == ".glb" ? "glTF's frame, metres, +Y superior, +Z anterior" : "LPS mm";
}

void write_mesh(const std::filesystem::path& path, const TriangleMesh& mesh) {
    if (!is_writable_mesh_path(path))
        throw OutputError("cannot write mesh '" + path.string() + "': unknown extension '" + path.extension().string() + "' (expected " +
                          writable_mesh_formats + ")");
    const std::string extension = lower_case_extension(path);
    for (const auto& t : mesh.triangles)
        for (auto index : t)
            if (index < 0 || std::size_t(index) >= mesh.positions.size())
                throw OutputError("cannot write mesh '" + path.string() + "': a triangle refers to a missing vertex");
    for (std::size_t v = 0; v < mesh.positions.size(); ++v)
        for (const auto c : mesh.positions[v])
            if (!std::isfinite(c))
                throw OutputError("cannot write mesh '" + path.string() + "': vertex " + std::to_string(v) +
                                  " has a non-finite coordinate; nothing was written");

    if (extension == ".glb") {
        const auto scene = scene_of(mesh, lps_mm_to_gltf);
        write_file_atomically(path, [&](const std::filesystem::path& temporary) {
            Assimp::Exporter exporter;
            errno = 0;
            if (exporter.Export(scene.get(), "glb2", temporary.string()) != aiReturn_SUCCESS)
                throw OutputError("cannot write mesh '" + path.string() + "': " +
                                  (disk_full(errno) ? std::string(std::strerror(errno)) + " (disk full?)" : exporter.GetErrorString()));
        });
        return;
    }
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        errno = 0;
        std::ofstream out(temporary, std::ios::binary);
        if (extension == ".stl") write_stl(out, mesh);
        else if (extension == ".obj") write_obj(out, mesh);
        else if (extension == ".vtp") write_vtp(out, mesh);
        else write_ply(out, mesh);
        out.close();
        if (!out)
            throw OutputError("cannot write mesh '" + path.string() + "': " +
                              (disk_full(errno) ? std::string(std::strerror(errno)) + " (disk full?)" : "writing failed (disk full?)"));
    });
}

TriangleMesh read_mesh(const std::filesystem::path& path) {
    std::error_code error;
    if (!std::filesystem::is_regular_file(path, error))
        throw InputError(path.string() + ": cannot read the mesh: no such file");

    Assimp::Importer importer;
    // Per-face normals (STL), colours and texture coordinates would keep JoinIdenticalVertices
    // from welding vertices at the same position; we only want the geometry.
    importer.SetPropertyInteger(AI_CONFIG_PP_RVC_FLAGS, aiComponent_NORMALS | aiComponent_TANGENTS_AND_BITANGENTS |
                                                            aiComponent_COLORS | aiComponent_TEXCOORDS |
                                                            aiComponent_BONEWEIGHTS | aiComponent_ANIMATIONS |
                                                            aiComponent_TEXTURES | aiComponent_LIGHTS |
                                                            aiComponent_CAMERAS | aiComponent_MATERIALS);
    // PreTransformVertices bakes node transforms in, so meshes placed by a scene graph (glTF)
    // come out where the file puts them.
    // ValidateDataStructure refuses what a loader let through (a face index past the vertices).
    const aiScene* scene = nullptr;
    try {
        scene = importer.ReadFile(path.string(), aiProcess_ValidateDataStructure | aiProcess_RemoveComponent | aiProcess_Triangulate |
                                                     aiProcess_JoinIdenticalVertices | aiProcess_PreTransformVertices);
    } catch (const std::bad_alloc&) {
        scene = nullptr;
    }
    if (!scene) {
        // assimp catches an allocation that failed and reports only "std::bad_alloc".
        const std::string reason = importer.GetErrorString();
        if (reason.empty() || reason.find("bad_alloc") != std::string::npos)
            throw InputError(path.string() + ": cannot read the mesh: it declares more vertices or faces than memory holds (a damaged header?)");
        if (reason.find("orphaned") != std::string::npos || reason.find("contains no faces") != std::string::npos)  // assimp's words
            throw InputError(path.string() + ": cannot read the mesh: it holds no faces (cut short, or only vertices)");
        throw InputError(path.string() + ": cannot read the mesh: " + reason);
    }

    // glTF is metres with +Y up (its specification): back to LPS mm by the inverse of what we write.
    const bool gltf = is_gltf(lower_case_extension(path));
    TriangleMesh mesh;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh& part = *scene->mMeshes[m];
        const auto first_vertex = std::int32_t(mesh.positions.size());
        for (unsigned v = 0; v < part.mNumVertices; ++v) {
            const Eigen::Vector3d p(part.mVertices[v].x, part.mVertices[v].y, part.mVertices[v].z);
            if (!p.allFinite())
                throw InputError(path.string() + ": cannot read the mesh: vertex " + std::to_string(mesh.positions.size()) + " is not finite");
            const Eigen::Vector3d mm = gltf ? gltf_to_lps_mm(p) : p;
            for (int c = 0; c < 3; ++c)
                if (!plausible::coordinate_mm.contains(mm[c]))
                    throw InputError(path.string() + ": cannot read the mesh: " +
                                     plausible::outside("vertex " + std::to_string(mesh.positions.size()) + " coordinate", mm[c], plausible::coordinate_mm));
            mesh.positions.push_back(mm);
        }
        for (unsigned f = 0; f < part.mNumFaces; ++f) {
            const aiFace& face = part.mFaces[f];
            if (face.mNumIndices != 3) continue;  // points and lines left after triangulation
            mesh.triangles.push_back({first_vertex + std::int32_t(face.mIndices[0]),
                                      first_vertex + std::int32_t(face.mIndices[1]),
                                      first_vertex + std::int32_t(face.mIndices[2])});
        }
    }
    if (mesh.triangles.empty()) throw InputError(path.string() + ": cannot read the mesh: it holds no triangles");
    return mesh;
}

}  // namespace heartsim
