/// @file render_geometry.h
/// @brief The renderer's geometry made on the host (runtime/gl/renderer.cpp): the instruments'
/// sphere, the section view's double-sided sheets, a patch as a closed sheet of its thickness.
#pragma once

#include "runtime/gl/renderer.h"

#include "formats/scenario.h"

#include <array>
#include <cstdint>
#include <vector>

namespace heartsim {

/// One visual vertex as the mapping vertex shader reads it (std430, shaders/render_shaders.h).
struct VertexRecord {
    std::int32_t particle[3];
    float lambda[3];
    float offset;
    float rest_normal[3];
    float rest_frame_normal[3];
    std::int32_t carrier[8];
    float weight[8];
    float rest_position[3];  ///< where the surface detail is looked up
    float grown;             ///< the carriers' weighted share of grown wall (the section's cut colour)
};
static_assert(sizeof(VertexRecord) == 132);

/// Each particle's share of a wall heartprep grew (/materials/origin): 1 or 0; empty where the
/// scenario grew none.
std::vector<float> grown_particles(const Scenario& scenario);

/// The normals pass's incidence lists over the counted triangles (normal_weight) of `surface`:
/// per surface particle in row order (counting sort), its triangles from start[k] to start[k + 1].
struct SurfaceIncidence {
    std::vector<std::uint32_t> start{0}, surface_list;
    std::vector<std::array<std::int32_t, 4>> incidence;
};
SurfaceIncidence surface_incidence(const SimulationSurface& surface, std::size_t particles);

/// The simulation surface drawn as itself: one record per particle, (i, i, i), λ = (1, 0, 0),
/// d = 0 (the mapping shader then gives p = x_i exactly), its rest position and grown share.
std::vector<VertexRecord> particle_records(const std::vector<std::array<float, 3>>& rest, const std::vector<float>& grown);

/// The unit sphere the instruments are drawn with (latitude-longitude, 32 × 16).
void unit_sphere(std::vector<float>& vertices, std::vector<std::uint32_t>& indices);

/// Per triangle of `elements` (3 indices each), 1 where the same triangle is also drawn reversed:
/// the simulation surface's double-sided sheets at one-particle-thick walls (scenario-format.md
/// /simsurface). The section view lights both sides of those: they enclose no tissue to cut.
std::vector<std::uint32_t> sheet_triangles(const std::vector<std::uint32_t>& elements);

/// A patch's mid-surface made a closed sheet `thickness` thick: the surface moved half the
/// thickness along its vertex normals each way (the far side wound the other way), and a rim of
/// quads along its boundary edges, wound so that every face is counter-clockwise seen from
/// outside. The section view then shows where the plane cuts it as back faces, as it does the
/// wall's. `vertices`: position, normal (6 floats each); `elements`: 3 per triangle.
void patch_sheet(const DrawnPatch& patch, std::vector<float>& vertices, std::vector<std::uint32_t>& elements);

}  // namespace heartsim
