/// @file lattice.h
/// @brief The particle lattice: a regular grid of cells at `spacing` mm aligned with the
/// volume's axes, a particle per cell whose tissue fraction passes a threshold, springs to the
/// 18 nearest neighbours (6 face, 12 edge), each once. Arrays are structures of arrays with the
/// exact layout of the scenario file and the GPU buffers (float32 / int32 / uint8).
#pragma once

#include "libmodel/progress.h"
#include "libmodel/select.h"
#include "libmodel/volume.h"

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

/// A tissue's mechanical description in physical terms.
struct Material {
    int label = 1;                           ///< label value in the input volume
    std::string name = "myocardium";
    double density = 1.06e-3;                ///< g/mm³ (1.06 g/cm³, myocardium)
    double youngs_modulus_kpa = 10.0;        ///< kPa; passive myocardium is of the order of 10–50
    /// Poisson's ratio ν, in [1/4, 1/2): the springs give the tissue its shear modulus and ν = 1/4,
    /// a volume term on the lattice's cells the rest (volume_cells.h). 1/4 here, the springs alone;
    /// heartprep's default is myocardium's (tools/heartprep, docs/scenario-format.md).
    double poisson_ratio = 0.25;
    /// Damping ratio of each spring's relative motion (fraction of critical damping of the
    /// two-particle oscillator), dimensionless. See docs/scenario-format.md.
    double damping_ratio = 0.1;
};

/// Stiffness of every spring (face and edge alike), N/mm, for Young's modulus `youngs_modulus_kpa`
/// and Poisson's ratio `poisson_ratio` on a lattice of `spacing_mm`. With equal face and edge
/// stiffness k the 18-neighbour cubic network is elastically isotropic (C11 − C12 = 2·C44) with
/// shear modulus μ = k/h and λ = μ (Poisson's ratio 1/4, Young's modulus E = 5k/(2h)); so the
/// springs carry μ = E/(2(1 + ν)), k = μ·h (0.4·E·h at ν = 1/4), and the volume term the rest of λ
/// (volume_cells.h). 1 kPa = 1e-3 N/mm².
double spring_stiffness(double youngs_modulus_kpa, double spacing_mm, double poisson_ratio = 0.25);

/// The 18 neighbour offsets in lattice index space, in the scenario's slot order: the 6 face
/// offsets (+i, −i, +j, −j, +k, −k), then the 12 edge offsets (ij-plane, ik-plane, jk-plane,
/// each as (+,+), (+,−), (−,+), (−,−)).
extern const std::array<std::array<int, 3>, 18> neighbour_offsets;

struct LayoutOptions {
    /// Lattice spacing, mm. 0 chooses the spacing that meets `particle_budget`.
    double spacing_mm = 0.0;
    /// Target particle count when the spacing is chosen: the largest count not above it.
    std::size_t particle_budget = 30000;
    /// A cell gets a particle when its tissue fraction is at least this, in (0, 1].
    double occupancy = 0.5;
    /// Thin walls. (1) A wall thinner than half a cell has no cell reaching `occupancy`: a cell
    /// whose tissue fraction is a ridge across a lattice axis (at least its two face neighbours'
    /// along it) and at least `ridge_fraction` also gets a particle, so the wall is not lost.
    /// (2) A particle whose two face neighbours along an axis are both empty is a wall one
    /// particle thick there, with no bending stiffness and no cell of particles for the visual
    /// mesh to be embedded in: the neighbour on the side holding more tissue also gets a
    /// particle, if it holds at least `thicken_fraction`. Particles are only added: no wall is
    /// lost and no hole opened. The spacing chosen for the budget counts the added particles.
    bool thicken_walls = true;
    double ridge_fraction = 0.2;
    double thicken_fraction = 0.05;
    /// One material per tissue label; a label without an entry gets the first material's values.
    std::vector<Material> materials{Material{}};
};

/// Particles: N entries each, in lattice order (k slowest, i fastest) until packing reorders them.
struct Particles {
    std::vector<std::array<float, 3>> rest_position;   ///< N×3, world LPS mm
    std::vector<std::array<std::int32_t, 3>> lattice_index; ///< N×3, cell (i,j,k)
    std::vector<float> mass;                           ///< N, g
    std::vector<std::int32_t> material;                ///< N, row in the material table
    std::vector<std::uint8_t> anchored;                ///< N, 1 = does not move
    /// Supports (supports.h): a zero-rest-length spring from each particle to a fixed point,
    /// f = k·(support_point − x). Both empty (no supports) or N each; k = 0 where unsupported.
    std::vector<float> support_stiffness;              ///< N, N/mm
    std::vector<std::array<float, 3>> support_point;   ///< N×3, world LPS mm (the rest position, or
                                                       ///< moved by balance_rest_state to carry a pre-load)
    std::vector<float> support_damping;                ///< N, N·ms/mm: the support's dashpot, f = −c·v
    std::size_t size() const { return mass.size(); }
    bool supported() const { return !support_stiffness.empty(); }
};
static_assert(sizeof(std::array<float, 3>) == 12, "rest positions must be packed float32 triples");

/// Springs: S entries each; pairs (first < second), each spring once.
struct Springs {
    std::vector<std::array<std::int32_t, 2>> pairs;  ///< S×2 particle indices
    std::vector<float> rest_length;                  ///< S, mm
    std::vector<float> stiffness;                    ///< S, N/mm
    std::size_t size() const { return rest_length.size(); }
};

struct Lattice {
    double spacing = 0.0;                 ///< mm
    std::array<int, 3> dims{0, 0, 0};     ///< cells along the volume's i, j, k axes
    /// Lattice index (continuous, cell centres at integers) to world LPS mm.
    Eigen::Matrix4d index_to_world = Eigen::Matrix4d::Identity();
    std::vector<Material> materials;      ///< the material table rows particles refer to
    Particles particles;
    Springs springs;
};

struct LayoutReport {
    double spacing = 0.0;                 ///< mm, chosen or given
    std::size_t particles = 0;
    std::size_t anchored = 0;
    std::size_t face_springs = 0;
    std::size_t edge_springs = 0;
    std::size_t spacing_trials = 0;       ///< lattices counted while meeting the budget
    double total_mass = 0.0;              ///< g
    double occupied_volume_mm3 = 0.0;     ///< Σ fraction × cell volume over particles
    std::size_t ridges = 0;               ///< particles on walls thinner than half a cell (below the occupancy)
    std::size_t thickened = 0;            ///< particles added to thicken walls (LayoutOptions::thicken_walls)
    /// Particles still one particle thick along some axis (too little tissue beside them), and
    /// their share of the occupied volume.
    std::size_t thin_particles = 0;
    double thin_volume_share = 0.0;
    std::vector<std::string> warnings;
};

/// The particle at each lattice cell, for lookups by lattice index (dims from the lattice, i
/// fastest). Throws InputError for a particle whose lattice index lies outside the dims.
class ParticleGrid {
public:
    explicit ParticleGrid(const Lattice& lattice);
    /// The particle at cell (i, j, k), or −1 where there is none or the cell is outside.
    std::int32_t at(long i, long j, long k) const {
        if (i < 0 || j < 0 || k < 0 || i >= dims_[0] || j >= dims_[1] || k >= dims_[2]) return -1;
        return cells_[std::size_t((k * dims_[1] + j) * dims_[0] + i)];
    }
    std::int32_t at(const std::array<std::int32_t, 3>& c) const { return at(c[0], c[1], c[2]); }

private:
    std::array<long, 3> dims_{};
    std::vector<std::int32_t> cells_;
};

/// Per particle, whether it is a wall one particle thick: along some lattice axis both face
/// neighbours are empty (or outside the lattice).
std::vector<char> thin_wall_particles(const Lattice& lattice);

/// How many particles are one particle thick (thin_wall_particles) and their share of the tissue
/// volume (Σ mass/density).
struct ThinWallSummary {
    std::size_t particles = 0;
    double volume_share = 0.0;
};
ThinWallSummary summarise_thin_walls(const Lattice& lattice);

/// A box of `material`: dims[0] × dims[1] × dims[2] voxels of `spacing` mm (the volume's origin
/// at voxel 0's centre, identity direction), laid out at that spacing, a particle per voxel at its
/// centre. The uniform lattice of the tests, the benchmarks and heartsim info's measurement.
Lattice uniform_block(const std::array<int, 3>& dims, double spacing, const Material& material = {});

/// Lays out particles and springs over `selection`. Throws InputError for a non-positive or
/// non-finite spacing, an occupancy outside (0, 1], or when no cell passes the occupancy.
Lattice layout_particles(const Selection& selection, const std::vector<int>& tissue_labels,
                         const LabelVolume& volume, const LayoutOptions& options = {},
                         Progress& progress = null_progress(), LayoutReport* report = nullptr);

}  // namespace heartsim
