/// @file mapping.h
/// @brief Ties every visual-mesh vertex to the particles that carry it, so a coarse simulation
/// deforms a detailed mesh. One formula for every vertex:
///   p = Σ_{k<8} w_k·x_{i_k} + d · normalise(λa·n_a + λb·n_b + λc·n_c)
///   n_i = normalise(Σ over surface triangles (a,b,c) containing i with normal_weight 1 of (x_b − x_a) × (x_c − x_a))
/// Two kinds of vertex use it (docs/simulation-surface-and-mapping.md §2):
///  * **embedded** (d = 0): the vertex is an affine combination of up to 8 particles of one
///    lattice cell (trilinear weights where the cell is complete, the minimum-norm affine weights
///    of its particles otherwise), as SOFA's barycentric mapping on a regular grid. Well
///    conditioned (Σ|w| small) and exact for every affine motion of the lattice.
///  * **tangent-space** (Mosegaard & Sørensen, EGVE 2005; SCENARIO.md): i = (a, b, c) of a
///    simulation-surface triangle, w = λ, offset d along the interpolated particle normal. Used
///    where no cell embeds the vertex better (a one-particle-thick wall has no cell with corners
///    off its plane).
/// A vertex is embedded where a cell embeds it well (sensitivity bound A ≤ 5, MappingOptions),
/// else it takes the kind with the smaller bound (MappingReport::amplification).
/// The weights and offset reproduce the visual vertex at rest exactly, not merely a projection.
#pragma once

#include "libmodel/lattice.h"
#include "libmodel/mesh.h"
#include "libmodel/progress.h"
#include "libmodel/simulation_surface.h"

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

/// Per visual vertex, the formula's terms. `triangle` and `barycentric` give the normal frame
/// (λ of m = Σ λ·n): for a tangent-space vertex its triangle and weights; for an embedded vertex
/// the nearest surface triangle and the closest point's weights, which the runtime uses only to
/// turn the shading normal (d = 0).
struct VisualMapping {
    std::vector<std::int32_t> triangle;               ///< V: row in the simulation-surface triangles
    std::vector<std::array<float, 3>> barycentric;    ///< V×3: λa, λb, λc, summing to 1
    std::vector<float> offset;                        ///< V: d, mm along the interpolated normal
    /// V×8 each, or both empty (a scenario written before them: the carriers are then the
    /// triangle's a, b, c with weights λ). Unused slots repeat the first particle with weight 0.
    std::vector<std::array<std::int32_t, 8>> particles;  ///< the carrying particles i_k
    std::vector<std::array<float, 8>> weights;           ///< w_k, summing to 1
};

/// The carriers of vertex v: the stored ones, or (a, b, c, a, a, a, a, a) with (λ, 0, …, 0).
void mapping_carriers(const VisualMapping& mapping, const SimulationSurface& surface, std::size_t v,
                      std::array<std::int32_t, 8>& particles, std::array<float, 8>& weights);

struct MappingReport {
    double max_rest_error_mm = 0.0;     ///< max |p(rest) − visual vertex| over vertices (float32 evaluation)
    double mean_offset_mm = 0.0;        ///< mean |d| over the tangent-space vertices
    double max_offset_mm = 0.0;         ///< max |d|
    std::size_t tangent = 0;            ///< vertices mapped in tangent space (d along the normal)
    std::size_t embedded = 0;           ///< vertices embedded in a lattice cell (d = 0)
    std::size_t embedded_convex = 0;    ///< of those, with all weights in [0, 1] (a convex combination)
    /// The sensitivity bound A of each vertex: to first order, moving every particle by at most δ
    /// moves the vertex by at most A·δ. Embedded: A = Σ|w_k| (exact). Tangent-space:
    /// A = Σ|λ| + |d|/|m|·Σ|λ_j|·P_j/|S_j|, with S_j particle j's summed area vector and P_j the
    /// summed perimeters of its counted triangles (|δS_j| ≤ P_j·δ).
    double max_amplification = 0.0;
    double mean_amplification = 0.0;
    std::size_t over_amplification = 0;  ///< vertices with A above MappingOptions::max_amplification
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

enum class MappingMethod {
    automatic,  ///< embedded where a cell embeds the vertex well, else the kind with the smaller bound A
    tangent,    ///< tangent space only: Mosegaard & Sørensen's method (for comparison)
};

/// "auto" or "tangent" (the command-line spelling); throws InputError naming MappingOptions::method otherwise.
MappingMethod parse_mapping_method(const std::string& text);

struct MappingOptions {
    /// Warn when the mean |offset| exceeds this many lattice spacings (a mesh far from the tissue).
    double far_warning_spacings = 2.0;
    double lattice_spacing_mm = 1.0;    ///< to scale the warning
    MappingMethod method = MappingMethod::automatic;
    /// Warn about vertices whose sensitivity bound A exceeds this: a random 1 µm motion of the
    /// particles could move them by more than A µm.
    double max_amplification = 10.0;
    /// A vertex whose best cell embedding has A at most this is embedded (exact under any affine
    /// motion of the lattice); otherwise the kind with the smaller A, embedded or tangent-space.
    double embed_below_amplification = 5.0;
};

/// Particle normals n_i of the formula above (N×3; zero for particles on no counted triangle), in
/// float32: area vectors of the counted triangles in file order, each added to its three
/// particles in the order a, b, c, then normalised (zero stays zero).
std::vector<Eigen::Vector3f> particle_normals(const std::vector<std::array<float, 3>>& positions,
                                              const SimulationSurface& surface);

/// Evaluates the formula for every visual vertex at particle positions `positions` (N×3, mm),
/// in float32 exactly as the runtime's vertex shader does, in this order:
///   p = w_0·x_0; p = p + w_k·x_k for k = 1..7;  m = (λa·n_a + λb·n_b) + λc·n_c;
///   p + d·(m / sqrt(m·m))   (m = 0 gives p)
/// Normals from particle_normals(positions, surface).
std::vector<Eigen::Vector3f> apply_mapping(const VisualMapping& mapping, const std::vector<std::array<float, 3>>& positions,
                                           const SimulationSurface& surface);

/// Maps `visual_positions` (V, world mm) onto the lattice's particles (at their rest positions):
/// per vertex the embedded or the tangent-space kind, whichever has the smaller sensitivity bound
/// (options.method). The lattice's indices, dims and index_to_world give the cells; its rest
/// positions the particles: trilinear weights assume them at their lattice points (as the layout
/// puts them), the affine weights are solved on them; the float rest error is reported either
/// way. Throws InputError as the overload below.
VisualMapping map_visual_mesh(const std::vector<Eigen::Vector3d>& visual_positions, const Lattice& lattice,
                              const SimulationSurface& surface, const MappingOptions& options = {},
                              Progress& progress = null_progress(), MappingReport* report = nullptr);

/// Tangent-space mapping only (no lattice to embed in) of `visual_positions` (V, world mm) onto
/// the simulation surface (`surface` over particles at `rest_positions`). Candidate triangles (those with normal weight
/// 1: a twin of weight 0 spans the same triangle with the same normals) come from a CGAL AABB
/// tree. Throws InputError for an empty visual mesh, an empty simulation surface or weights that
/// are not one 0/1 per triangle.
VisualMapping map_visual_mesh(const std::vector<Eigen::Vector3d>& visual_positions,
                              const std::vector<std::array<float, 3>>& rest_positions, const SimulationSurface& surface,
                              const MappingOptions& options = {}, Progress& progress = null_progress(),
                              MappingReport* report = nullptr);

}  // namespace heartsim
