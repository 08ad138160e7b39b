/// @file mesh_io.h
/// @brief Triangle meshes to and from STL, OBJ, PLY and glTF (.glb/.gltf), and to VTK XML
/// PolyData (.vtp). STL, OBJ, PLY and VTP hold world LPS millimetres as they are, with `SPACE=LPS units=mm` in their
/// header (STL's 80 bytes, an OBJ comment, a PLY comment: Slicer reads the tag); STL facets carry
/// their true normals. glTF is metres with +Y up by its specification, so a .glb holds
/// (x, z, −y) / 1000 of LPS mm: +X left, +Y superior, +Z anterior (the heart faces a glTF
/// viewer's default camera); reading a .glb/.gltf applies the inverse.
#pragma once

#include "libmodel/mesh.h"

#include <filesystem>

namespace heartsim {

/// Writes `mesh` to `path`; the format follows the extension (.stl binary, .obj, .ply binary
/// little-endian, .vtp VTK XML PolyData with base64 binary arrays, .glb). read_mesh does not read
/// .vtp (assimp has no reader for it). Atomic: written to a temporary file beside `path` and renamed. Throws
/// OutputError (unwritable place, unknown extension, a non-finite vertex) naming the file.
void write_mesh(const std::filesystem::path& path, const TriangleMesh& mesh);

/// The mesh formats write_mesh writes, as the commands name them: ".stl, .obj, .ply, .vtp or .glb".
inline constexpr const char* writable_mesh_formats = ".stl, .obj, .ply, .vtp or .glb";

/// Whether write_mesh writes a file named `path` (by its extension, in any case), so a command can
/// refuse a wrong -o before its work starts.
bool is_writable_mesh_path(const std::filesystem::path& path);

/// The frame and unit write_mesh uses for `path`, for the commands' "wrote" line: "glTF's frame,
/// metres, +Y superior, +Z anterior" for a .glb, else "LPS mm".
const char* written_mesh_frame(const std::filesystem::path& path);

/// Reads a triangle mesh (all meshes of the file merged, polygons triangulated, identical
/// vertices joined). Throws InputError naming the file when it is missing, unreadable or holds
/// no triangles.
TriangleMesh read_mesh(const std::filesystem::path& path);

}  // namespace heartsim
