/// @file mapping_embedding.h
/// @brief Internal to the mapping: a visual vertex embedded in a lattice cell, as an affine
/// combination of up to 8 of the cell's particles (mapping.h, "embedded" vertices).
#pragma once

#include "libmodel/lattice.h"

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace heartsim::mapping_internal {

struct Embedding {
    std::array<std::int32_t, 8> particles{};
    std::array<double, 8> weights{};
    int count = 0;                  ///< carriers used (the rest: weight 0)
    double amplification = 0.0;     ///< Σ|w|; 0 when no cell embeds the vertex
    bool convex = false;            ///< every weight in [0, 1]
    /// Where no cell around the vertex embeds it: the particles within 6 cells the search took,
    /// up to 8 (0 where a cell embeds it). Fewer than 8 and none found: no subset of the
    /// particles it was given embeds the vertex either (under 4, or all in one plane).
    int far_found = 0;
    bool found() const { return count > 0; }
};

/// Finds particles by lattice cell.
class CellEmbedder {
public:
    /// `rest` are the particles' rest positions (world mm, in the lattice's particle order).
    CellEmbedder(const Lattice& lattice, const std::vector<Eigen::Vector3d>& rest);

    /// The best-conditioned embedding of `v` (world mm): over the 27 cells (2×2×2 particle blocks)
    /// around v's, trilinear weights where all 8 corners are particles, else the minimum-norm
    /// affine weights of the corners that are (at least 4, not coplanar); the smallest Σ|w| wins,
    /// v's own complete cell at once. Where no such cell is near (v more than a cell from the
    /// tissue), the 8 particles nearest v within 6 cells, or the 7 nearest and the nearest one off their
    /// plane. found() is false
    /// otherwise.
    Embedding embed(const Eigen::Vector3d& v) const;
    /// The same over the particles `usable` accepts only (the others count as absent): a vertex
    /// beside an incision embedded in the particles of its own side. `usable` is asked once a
    /// particle at most, and only of the particles the choice depends on.
    Embedding embed(const Eigen::Vector3d& v, const std::function<bool(std::int32_t)>& usable) const;

private:
    /// Minimum-norm affine weights of `ids` reproducing v; false when they span no volume.
    bool affine(const Eigen::Vector3d& v, const std::int32_t* ids, int count, Embedding& out) const;

    const std::vector<Eigen::Vector3d>& rest_;
    ParticleGrid grid_;
    Eigen::Matrix4d world_to_index_;
    double spacing_ = 1.0;
    /// The far search's bound on how near a particle s cells out can lie (world mm per cell of
    /// index distance, and how far a particle's rest position lies from its cell's lattice point).
    double mm_per_cell_ = 0.0;
    double off_lattice_ = 0.0;
};

}  // namespace heartsim::mapping_internal
