/// @file mesh_io.cpp
/// @brief Triangle meshes to and from files through assimp's Exporter and Importer.
#include "mesh_io.h"

#include "atomic_file.h"

#include "libmodel/errors.h"

#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <memory>
#include <string>

namespace heartsim {

namespace {

std::string lower_case_extension(const std::filesystem::path& path) {
    std::string extension = path.extension().string();
    std::transform(extension.begin(), extension.end(), extension.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    return extension;
}

/// assimp exporter id for an extension, or empty when we do not write that format.
std::string exporter_for(const std::string& extension) {
    if (extension == ".stl") return "stlb";
    // "objnomtl": the plain "obj" exporter also writes a .mtl file named after the temporary file.
    if (extension == ".obj") return "objnomtl";
    if (extension == ".ply") return "plyb";
    if (extension == ".glb") return "glb2";
    return {};
}

/// A one-mesh scene. aiScene's destructor frees its meshes, materials and nodes with delete /
/// delete[], so everything below is allocated with new / new[] and owned by the scene.
std::unique_ptr<aiScene> scene_of(const TriangleMesh& mesh) {
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
        const auto& p = mesh.positions[v];
        out.mVertices[v] = aiVector3D(ai_real(p.x()), ai_real(p.y()), ai_real(p.z()));
    }
    if (mesh.normals.size() == mesh.positions.size() && !mesh.normals.empty()) {
        out.mNormals = new aiVector3D[mesh.normals.size()];
        for (std::size_t v = 0; v < mesh.normals.size(); ++v) {
            const auto& n = mesh.normals[v];
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

void write_mesh(const std::filesystem::path& path, const TriangleMesh& mesh) {
    const std::string format = exporter_for(lower_case_extension(path));
    if (format.empty())
        throw OutputError("cannot write mesh '" + path.string() + "': unknown extension '" + path.extension().string() +
                          "' (expected .stl, .obj, .ply or .glb)");
    for (const auto& t : mesh.triangles)
        for (auto index : t)
            if (index < 0 || std::size_t(index) >= mesh.positions.size())
                throw OutputError("cannot write mesh '" + path.string() + "': a triangle refers to a missing vertex");
    for (std::size_t v = 0; v < mesh.positions.size(); ++v)
        for (const auto c : mesh.positions[v])
            if (!std::isfinite(c))
                throw OutputError("cannot write mesh '" + path.string() + "': vertex " + std::to_string(v) +
                                  " has a non-finite coordinate; nothing was written");

    const auto scene = scene_of(mesh);
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        Assimp::Exporter exporter;
        if (exporter.Export(scene.get(), format, temporary.string()) != aiReturn_SUCCESS)
            throw OutputError("cannot write mesh '" + path.string() + "': " + exporter.GetErrorString());
    });
}

TriangleMesh read_mesh(const std::filesystem::path& path) {
    std::error_code error;
    if (!std::filesystem::is_regular_file(path, error))
        throw InputError("cannot read mesh '" + path.string() + "': no such file");

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
    const aiScene* scene =
        importer.ReadFile(path.string(), aiProcess_RemoveComponent | aiProcess_Triangulate |
                                             aiProcess_JoinIdenticalVertices | aiProcess_PreTransformVertices);
    if (!scene) throw InputError("cannot read mesh '" + path.string() + "': " + importer.GetErrorString());

    TriangleMesh mesh;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh& part = *scene->mMeshes[m];
        const auto first_vertex = std::int32_t(mesh.positions.size());
        for (unsigned v = 0; v < part.mNumVertices; ++v)
            mesh.positions.emplace_back(part.mVertices[v].x, part.mVertices[v].y, part.mVertices[v].z);
        for (unsigned f = 0; f < part.mNumFaces; ++f) {
            const aiFace& face = part.mFaces[f];
            if (face.mNumIndices != 3) continue;  // points and lines left after triangulation
            mesh.triangles.push_back({first_vertex + std::int32_t(face.mIndices[0]),
                                      first_vertex + std::int32_t(face.mIndices[1]),
                                      first_vertex + std::int32_t(face.mIndices[2])});
        }
    }
    if (mesh.triangles.empty()) throw InputError("cannot read mesh '" + path.string() + "': it holds no triangles");
    return mesh;
}

}  // namespace heartsim
