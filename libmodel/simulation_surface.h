/// @file simulation_surface.h
/// @brief The simulation surface: a closed, outward-oriented triangle mesh whose vertices are
/// the lattice's boundary particles. The runtime renders it for picking (the seed's picking
/// buffer) and the mapping ties the detailed visual mesh to it.
#pragma once

#include "lattice.h"
#include "mesh.h"
#include "progress.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

struct SimulationSurfaceReport {
    std::size_t triangles = 0;
    std::size_t boundary_particles = 0;     ///< particles used as vertices
    std::size_t components = 0;
    long euler_characteristic = 0;
    std::size_t nonmanifold_edges = 0;      ///< where the particle set forces them (see docs)
    std::size_t nonmanifold_vertices = 0;
    /// Triangles whose reverse is present too: both sides of a one-particle-thick wall (see docs).
    std::size_t thin_wall_triangles = 0;
    std::size_t duplicate_triangles_removed = 0;  ///< expected 0; a safety net, reported
    std::vector<std::string> warnings;
};

/// Triangles (particle indices, counter-clockwise seen from outside) over the boundary
/// particles of `lattice`. Deterministic. See docs/simulation-surface-and-mapping.md for the
/// construction (marching cubes on the dual grid, snapped to occupied corners) and for what
/// happens at one-particle-thick walls. Throws InputError for particles outside the lattice or
/// two particles in one cell.
std::vector<std::array<std::int32_t, 3>> build_simulation_surface(const Lattice& lattice, Progress& progress = null_progress(),
                                                                  SimulationSurfaceReport* report = nullptr);

/// The simulation surface as a mesh at the particles' positions `positions` (N×3, world mm),
/// for export and checks. Vertices are all N particles (unused ones included).
TriangleMesh simulation_surface_mesh(const std::vector<std::array<float, 3>>& positions,
                                     const std::vector<std::array<std::int32_t, 3>>& triangles);

}  // namespace heartsim
