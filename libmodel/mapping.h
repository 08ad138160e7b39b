/// @file mapping.h
/// @brief Ties every visual-mesh vertex to a simulation-surface triangle (Mosegaard & Sørensen,
/// EGVE 2005), so a coarse simulation deforms a detailed mesh. The formula (SCENARIO.md, with
/// the normal weights of SimulationSurface: of each thin-wall triangle and its reverse only one
/// counts, see docs/architecture.md "Departures"):
///   n_i = normalise(Σ over surface triangles (a,b,c) containing i with normal_weight 1 of (x_b − x_a) × (x_c − x_a))
///   p   = λa·x_a + λb·x_b + λc·x_c + d · normalise(λa·n_a + λb·n_b + λc·n_c)
/// The weights λ (summing to 1) and offset d are solved so that p reproduces the visual vertex
/// at rest exactly, not merely taken from a closest-point projection.
#pragma once

#include "mesh.h"
#include "progress.h"
#include "simulation_surface.h"

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

struct VisualMapping {
    std::vector<std::int32_t> triangle;               ///< V: row in the simulation-surface triangles
    std::vector<std::array<float, 3>> barycentric;    ///< V×3: λa, λb, λc, summing to 1
    std::vector<float> offset;                        ///< V: d, mm along the interpolated normal
};

struct MappingReport {
    double max_rest_error_mm = 0.0;     ///< max |p(rest) − visual vertex| over vertices (float32 evaluation)
    double mean_offset_mm = 0.0;        ///< mean |d|
    double max_offset_mm = 0.0;         ///< max |d|
    std::size_t outside_triangle = 0;   ///< vertices whose weights fall outside [0, 1] (extrapolated)
    /// Vertices for which no candidate triangle gave an exact solution: mapped by closest-point
    /// projection instead (not exact at rest; expected 0).
    std::size_t unsolved = 0;
    /// Vertices mapped onto a triangle with a particle whose (weighted) normal sum nearly cancels
    /// (|Σ area vectors| < 0.3 Σ |area vectors|): their deformed positions follow an unstable
    /// normal. The normal weights remove the thin walls whose two sides are exact reverses; those
    /// triangulated differently on each side (staircase, diagonal walls) remain: 0.4–2.5 % of
    /// the visual vertices on the real cases (docs/simulation-surface-and-mapping.md).
    std::size_t unstable_normal = 0;
    std::size_t candidate_solves = 0;   ///< Newton solves over all vertices (for profiling)
    double seconds = 0.0;               ///< wall time of map_visual_mesh
    std::vector<std::string> warnings;  ///< e.g. a visual mesh far from the tissue
};

struct MappingOptions {
    /// Warn when the mean |offset| exceeds this many lattice spacings (a mesh far from the tissue).
    double far_warning_spacings = 2.0;
    double lattice_spacing_mm = 1.0;    ///< to scale the warning
};

/// Particle normals n_i of the formula above (N×3; zero for particles on no counted triangle), in
/// float32: area vectors of the counted triangles in file order, each added to its three
/// particles in the order a, b, c, then normalised (zero stays zero).
std::vector<Eigen::Vector3f> particle_normals(const std::vector<std::array<float, 3>>& positions,
                                              const SimulationSurface& surface);

/// Evaluates the formula for every visual vertex at particle positions `positions` (N×3, mm),
/// in float32 exactly as the runtime's vertex shader does, in this order:
///   p = (λa·x_a + λb·x_b) + λc·x_c;  m = (λa·n_a + λb·n_b) + λc·n_c;  p + d·(m / sqrt(m·m))
/// (m = 0 gives p). Normals from particle_normals(positions, surface).
std::vector<Eigen::Vector3f> apply_mapping(const VisualMapping& mapping, const std::vector<std::array<float, 3>>& positions,
                                           const SimulationSurface& surface);

/// Solves the mapping of `visual_positions` (V, world mm) onto the simulation surface
/// (`surface` over particles at `rest_positions`). Candidate triangles (those with normal weight
/// 1: a twin of weight 0 spans the same triangle with the same normals) come from a CGAL AABB
/// tree. Throws InputError for an empty visual mesh, an empty simulation surface or weights that
/// are not one 0/1 per triangle.
VisualMapping map_visual_mesh(const std::vector<Eigen::Vector3d>& visual_positions,
                              const std::vector<std::array<float, 3>>& rest_positions, const SimulationSurface& surface,
                              const MappingOptions& options = {}, Progress& progress = null_progress(),
                              MappingReport* report = nullptr);

}  // namespace heartsim
