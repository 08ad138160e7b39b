/// @file supports.h
/// @brief How a heart is held: support springs (zero rest length, from a particle to a fixed
/// point, stiffness per area in physical units), the lattice's connected pieces and the ones
/// nothing holds, and a rest state at static equilibrium under gravity (pre-stressed springs
/// and pre-loaded supports), so that the imaged shape is where the heart rests.
///
/// Physics and choices: docs/user-guide.md "How the heart is held"; file layout:
/// docs/scenario-format.md (/particles/support_*, /solver balanced_gravity).
#pragma once

#include "libmodel/lattice.h"
#include "libmodel/progress.h"

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

namespace heartsim {

/// Which particles get a support spring.
enum class SupportRegion {
    none,       ///< no supports (anchors alone hold the heart, or nothing does)
    posterior,  ///< the heart's back as seen from behind: in every lattice line along the axis
                ///< nearest to `posterior`, the particle farthest that way (supine patient:
                ///< the heart lies on the posterior mediastinum in its pericardium)
    boundary,   ///< every particle with an exposed cell face (the whole pericardial surface)
};
const char* to_string(SupportRegion region);
/// "none", "posterior" or "boundary"; throws InputError otherwise.
SupportRegion parse_support_region(const std::string& text);

struct SupportOptions {
    SupportRegion region = SupportRegion::posterior;
    /// Stiffness per supported area, kPa/mm (= 1e-3 N/mm per mm²): a particle with area A gets
    /// k = stiffness_kpa_per_mm · 1e-3 · A, N/mm. Area: one cell face (spacing²) per supported
    /// particle for `posterior` (the projected footprint), spacing² per exposed face for `boundary`.
    double stiffness_kpa_per_mm = 1.0;
    /// A weak elastic foundation on every free particle (the tissue and fluid around the heart),
    /// stiffness per tissue volume, kPa/mm² (= 1e-3 N/mm per mm³): k += embedding · 1e-3 · m/ρ.
    /// It holds what the lattice cannot: a one-particle-thick sheet or a particle on one or two
    /// springs has no linear stiffness across them, so no pre-stress could balance its weight.
    /// Default: a loose particle sags ~2 mm under its own weight, and the whole foundation is a
    /// fraction of the surface supports' stiffness. Not applied with region `none`.
    double embedding_kpa_per_mm2 = 0.005;
    /// Damping ratio of each support against its particle's mass: a dashpot c = 2ζ√(k·m), N·ms/mm.
    /// The tissue around the heart is viscous: undamped supports let the whole heart ring on
    /// them after an impact (its rigid mode has no spring dashpot to damp it).
    double damping_ratio = 1.0;
    /// A particle's support carries the tissue in its cell: its share of a face is at most
    /// min(1, fraction/full_fraction), fraction = m/(ρ·h³), as the layout scales a thin-wall
    /// particle's springs (LayoutOptions::occupancy), so k/m and the damped step stay bounded;
    /// with posterior supports the particles behind it along the line take the rest of the face.
    double full_fraction = 0.5;
    /// The direction the heart rests against, world LPS (default +y: posterior).
    Eigen::Vector3d posterior{0.0, 1.0, 0.0};
};

struct SupportReport {
    SupportRegion region = SupportRegion::none;
    double stiffness_kpa_per_mm = 0.0;
    double embedding_kpa_per_mm2 = 0.0;
    std::size_t supported = 0;      ///< particles on the region's surface supports
    double area_mm2 = 0.0;          ///< Σ supported area
    double embedding_stiffness = 0.0; ///< Σ k of the elastic foundation alone, N/mm
    double total_stiffness = 0.0;   ///< Σ k, N/mm: the stiffness against a rigid translation
};

/// Sets `lattice.particles.support_stiffness` (region supports plus the elastic foundation) and
/// `support_point` (the rest position); anchored particles get none. Region `none` clears both arrays. Throws InputError for a
/// negative or non-finite stiffness or a zero `posterior` direction.
SupportReport add_supports(Lattice& lattice, const SupportOptions& options = {});

/// The particles on surface supports (posterior or boundary) of a lattice as stored, which keeps
/// each particle's support stiffness k but not the options that made it: the elastic foundation
/// gives every free particle the same stiffness per tissue volume (k·ρ/m), a surface support adds
/// to it. Where every free particle has a support, those whose k·ρ/m exceeds the least by half
/// again (a surface support worth half the foundation under it) are on surface supports; where
/// some free particle has none there is no foundation, and every supported particle counts. The
/// one count heartprep build, inspect and batch give.
std::size_t count_surface_supported(const Lattice& lattice);

/// Connected pieces of the spring network, largest first: `piece[i]` is particle i's piece.
struct Pieces {
    std::vector<std::int32_t> piece;   ///< N
    std::vector<std::size_t> size;     ///< particles per piece, largest first
    std::vector<bool> held;            ///< the piece has an anchored or a supported particle
};
Pieces find_pieces(const Particles& particles, const Springs& springs);

struct FreePieceOptions {
    /// Free pieces (nothing anchors or supports them) with fewer particles than this are
    /// dropped; larger ones are an error unless `allow_free`.
    std::size_t drop_below_particles = 200;
    bool allow_free = false;        ///< keep free pieces of any size (they fall under gravity)
};

struct FreePieceReport {
    std::size_t pieces = 0;                 ///< before dropping
    std::vector<std::size_t> piece_sizes;   ///< particles, largest first, before dropping
    std::size_t dropped_pieces = 0;
    std::size_t dropped_particles = 0;
    std::size_t free_pieces_kept = 0;       ///< only with allow_free
    std::size_t free_particles_kept = 0;
};

/// Drops the small free pieces of `lattice` (particles and their springs; indices renumbered in
/// order). Throws InputError naming the largest free piece and the options that hold it when a
/// free piece reaches `drop_below_particles` and `allow_free` is off. Call before packing.
FreePieceReport drop_free_pieces(Lattice& lattice, const FreePieceOptions& options = {});

struct RestBalanceOptions {
    double tolerance = 1e-10;       ///< CG stops at |K·u − f| ≤ tolerance·|f|
    int max_iterations = 50000;
};

struct RestBalanceReport {
    bool balanced = false;          ///< false: gravity zero, nothing held, or no spring
    double max_sag_mm = 0.0;        ///< largest |u|: how far the imaged shape would sag without the balance
    double mean_sag_mm = 0.0;
    double max_prestrain = 0.0;     ///< largest |δ|/L over springs (δ: rest-length change)
    double weight_n = 0.0;          ///< Σ m|g| over the balanced particles, N
    int iterations = 0;             ///< conjugate-gradient iterations
    double relative_residual = 0.0; ///< |K·u − f| / |f| at the end
    std::size_t unbalanced_particles = 0;  ///< in free pieces (kept with allow_free): they still fall
    std::vector<std::string> warnings;
};

/// Makes the rest positions a static equilibrium under `gravity` (mm/ms²): solves the linear
/// static problem K·u = M·g at rest (springs k·n·nᵀ, supports k·I, anchored particles fixed;
/// matrix-free conjugate gradients, 3×3 block-Jacobi preconditioned), then sets each spring's
/// rest length to its rest distance minus the elongation n·(u_b − u_a) and each support point
/// to x − u. At the rest positions every spring then carries the tension, and every support the
/// load, that it would carry in the sagged shape: the exact force balance of the linear problem,
/// with stiffnesses unchanged (pressing meets the same stiffness). The rest distance is
/// evaluated in float as the solvers do, so rounding leaves no residual of its own.
/// Particles of free pieces are left as they are (counted in the report).
RestBalanceReport balance_rest_state(Lattice& lattice, const Eigen::Vector3d& gravity, const RestBalanceOptions& options = {},
                                     Progress& progress = null_progress());

/// Σ over free particles of the force at the rest positions (springs + supports + m·g), N, and
/// the largest such force on one particle: zero for a balanced rest state.
struct RestResidual {
    Eigen::Vector3d total = Eigen::Vector3d::Zero();
    double max_particle_n = 0.0;
};
RestResidual rest_force_residual(const Lattice& lattice, const Eigen::Vector3d& gravity);

}  // namespace heartsim
