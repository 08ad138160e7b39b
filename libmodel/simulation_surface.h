/// @file simulation_surface.h
/// @brief The simulation surface: a closed, outward-oriented triangle mesh whose vertices are
/// the lattice's boundary particles. The runtime renders it for picking (Sørensen & Mosegaard's picking
/// buffer) and the mapping ties the detailed visual mesh to it.
#pragma once

#include "libmodel/lattice.h"
#include "libmodel/mesh.h"
#include "libmodel/progress.h"

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
    /// Connected regions of thin-wall pairs (edge-adjacent across edges that only two pairs
    /// share), each oriented consistently for the particle normals (see SimulationSurface).
    std::size_t sheet_regions = 0;
    /// Of those, regions with no thick (non-sheet) triangle along their border: oriented by the
    /// fallback rule (the lowest pair keeps its lower-index triangle).
    std::size_t sheet_regions_unseeded = 0;
    /// Links inside a region that the orientation could not honour (a non-orientable sheet,
    /// e.g. a Möbius band); expected 0.
    std::size_t sheet_orientation_conflicts = 0;
    std::vector<std::string> warnings;
};

/// The simulation surface: triangles over particles and, per triangle, whether it counts in the
/// particle normals.
///
/// At a one-particle-thick wall the surface is a double-sided sheet: every triangle there comes
/// with its exact reverse (its twin). Summing both twins into a particle normal cancels it, so
/// of each (triangle, reverse) pair exactly one counts (`normal_weight` 1) and its twin does not
/// (0). The kept side is chosen consistently over each connected sheet region (two edge-adjacent
/// kept triangles traverse their shared edge in opposite directions), seeded from the adjacent
/// thick triangle of lowest index where there is one (the kept triangle then traverses their
/// shared edge opposite to it: the same orientation), so particle normals are continuous along
/// the sheet and into the thick tissue. Every other triangle has weight 1. The particle normal is
///   n_i = normalise(Σ over triangles (a,b,c) containing i with normal_weight 1 of (x_b − x_a) × (x_c − x_a)).
/// See docs/simulation-surface-and-mapping.md.
struct SimulationSurface {
    std::vector<std::array<std::int32_t, 3>> triangles;  ///< particle indices, counter-clockwise from outside
    std::vector<std::uint8_t> normal_weight;             ///< one per triangle: 1 counts in particle normals, 0 not

    /// Triangles with weights from compute_normal_weights.
    static SimulationSurface with_computed_weights(std::vector<std::array<std::int32_t, 3>> triangles);
    /// Triangles all counted (weight 1), e.g. a surface with no thin walls, or an older file.
    static SimulationSurface all_counted(std::vector<std::array<std::int32_t, 3>> triangles);
    std::size_t size() const { return triangles.size(); }
    bool empty() const { return triangles.empty(); }
    friend bool operator==(const SimulationSurface&, const SimulationSurface&) = default;
};

/// Sheet statistics of compute_normal_weights (the sheet_* fields of SimulationSurfaceReport).
struct NormalWeightReport {
    std::size_t sheet_pairs = 0;
    std::size_t sheet_regions = 0;
    std::size_t sheet_regions_unseeded = 0;
    std::size_t sheet_orientation_conflicts = 0;
};

/// The normal weights of `triangles` (see SimulationSurface): 1 everywhere except the twin of each
/// (triangle, exact reverse) pair that is not kept. Serial and depends on the triangles and their
/// order only: deterministic.
std::vector<std::uint8_t> compute_normal_weights(const std::vector<std::array<std::int32_t, 3>>& triangles,
                                                 NormalWeightReport* report = nullptr);

/// The simulation surface over the boundary particles of `lattice`: triangles (particle indices,
/// counter-clockwise seen from outside) and their normal weights. Deterministic, for any thread
/// count. See docs/simulation-surface-and-mapping.md for the construction (marching cubes on the
/// dual grid, snapped to occupied corners) and for what happens at one-particle-thick walls.
/// Throws InputError for particles outside the lattice or two particles in one cell.
SimulationSurface build_simulation_surface(const Lattice& lattice, Progress& progress = null_progress(),
                                           SimulationSurfaceReport* report = nullptr);

/// The simulation surface as a mesh at the particles' positions `positions` (N×3, world mm),
/// for export and checks. Vertices are all N particles (unused ones included).
TriangleMesh simulation_surface_mesh(const std::vector<std::array<float, 3>>& positions,
                                     const std::vector<std::array<std::int32_t, 3>>& triangles);

}  // namespace heartsim
