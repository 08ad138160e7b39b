/// @file render_geometry.h
/// @brief The renderer's geometry made on the host (runtime/gl/renderer.cpp): the instruments'
/// sphere, the section view's double-sided sheets, a patch as a closed sheet of its thickness.
#pragma once

#include "runtime/gl/renderer.h"

#include <cstdint>
#include <vector>

namespace heartsim {

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
