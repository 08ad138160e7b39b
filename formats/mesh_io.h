/// @file mesh_io.h
/// @brief Triangle meshes to and from STL, OBJ, PLY and glTF (.glb/.gltf) through assimp.
/// Coordinates are written as they are (world LPS, mm); no axis conversion.
#pragma once

#include "libmodel/mesh.h"

#include <filesystem>

namespace heartsim {

/// Writes `mesh` to `path`; the format follows the extension (.stl binary, .obj, .ply binary,
/// .glb). Atomic: written to a temporary file beside `path` and renamed. Throws OutputError
/// (unwritable place, unknown extension) naming the file.
void write_mesh(const std::filesystem::path& path, const TriangleMesh& mesh);

/// Reads a triangle mesh (all meshes of the file merged, polygons triangulated, identical
/// vertices joined). Throws InputError naming the file when it is missing, unreadable or holds
/// no triangles.
TriangleMesh read_mesh(const std::filesystem::path& path);

}  // namespace heartsim
