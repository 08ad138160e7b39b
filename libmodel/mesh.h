/// @file mesh.h
/// @brief An indexed triangle mesh in world coordinates (LPS, mm), triangles counter-clockwise
/// seen from outside, and the checks that say whether it is a closed 2-manifold.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace heartsim {

struct TriangleMesh {
    std::vector<Eigen::Vector3d> positions;            ///< #V world positions, mm
    std::vector<Eigen::Vector3d> normals;              ///< #V unit normals, or empty
    std::vector<std::array<std::int32_t, 3>> triangles; ///< #F vertex indices, CCW from outside
};

/// Topology and measures of a triangle mesh, computed from its connectivity alone.
struct MeshReport {
    std::size_t vertices = 0;          ///< vertices used by at least one triangle
    std::size_t unused_vertices = 0;   ///< vertices no triangle uses
    std::size_t edges = 0;             ///< distinct undirected edges
    std::size_t faces = 0;
    std::size_t boundary_edges = 0;    ///< edges used by one triangle
    std::size_t nonmanifold_edges = 0; ///< edges used by more than two triangles
    std::size_t misoriented_edges = 0; ///< edges two triangles traverse in the same direction
    std::size_t nonmanifold_vertices = 0; ///< vertices whose triangle fan is not one disk
    std::size_t degenerate_faces = 0;  ///< faces with a repeated vertex or zero area
    std::size_t components = 0;        ///< connected components (through shared edges)
    long euler_characteristic = 0;     ///< V − E + F over used vertices
    double area = 0.0;                 ///< mm²
    double volume = 0.0;               ///< signed enclosed volume, mm³ (positive for outward CCW)
    bool closed() const { return boundary_edges == 0 && faces > 0; }
    bool manifold() const {
        return nonmanifold_edges == 0 && nonmanifold_vertices == 0 && misoriented_edges == 0;
    }
};

/// Connectivity and measures of `mesh`. O(F log F).
MeshReport analyse_mesh(const TriangleMesh& mesh);

/// Area-weighted vertex normals, unit length (zero where a vertex has no area around it).
void compute_vertex_normals(TriangleMesh& mesh);

/// Axis-aligned bounds of the positions: {min, max}. Both zero for an empty mesh.
std::array<Eigen::Vector3d, 2> bounds(const TriangleMesh& mesh);

}  // namespace heartsim
