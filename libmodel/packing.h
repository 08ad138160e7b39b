/// @file packing.h
/// @brief The GPU layout of the particles (Sørensen & Mosegaard's position texture): particles reordered
/// for memory locality, a fixed 18-slot neighbour table, and a texel per particle. Void cells
/// are never stored: arrays hold particles only; the texture's void texels exist only on the GPU.
#pragma once

#include "libmodel/lattice.h"
#include "libmodel/progress.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

enum class PackingScheme {
    /// Sørensen & Mosegaard's position texture: each lattice z-slice is a tile of dims[0] × dims[1] texels,
    /// tiles side by side in a near-square grid; particles ordered by texel, row by row.
    slices,
    /// 4×4×4 bricks of cells in Morton (Z-order) of the brick coordinates, cells within a brick in
    /// Morton order too; texels assigned in that order, row by row, in a texture `width` wide.
    /// Neighbours mostly share a brick, so a step touches few cache lines.
    bricks,
};

/// "slices" or "bricks"; throws InputError otherwise.
PackingScheme parse_packing_scheme(const std::string& name);
const char* to_string(PackingScheme scheme);

/// The largest position texture side every GL 4.3 GPU supports (GL_MAX_TEXTURE_SIZE ≥ 16384):
/// pack_particles refuses a larger layout and a scenario reader a larger /packing.
inline constexpr int max_texture_side = 16384;

/// /packing in the scenario.
struct Packing {
    PackingScheme scheme = PackingScheme::bricks;
    int width = 0;   ///< texture width, texels
    int height = 0;  ///< texture height, texels
    /// N×18: particle index at each neighbour slot (lattice.h `neighbour_offsets` order), −1 if none.
    std::vector<std::array<std::int32_t, 18>> neighbours;
    std::vector<std::array<std::int32_t, 2>> texture_coord;  ///< N×2: texel (x, y) of each particle
};

struct PackingOptions {
    PackingScheme scheme = PackingScheme::bricks;
    /// Texture width for the bricks scheme, texels; 0 = the smallest power of two ≥ sqrt(N).
    int texture_width = 0;
};

struct PackingReport {
    int width = 0, height = 0;
    double occupancy = 0.0;            ///< N / (width·height)
    std::size_t texture_bytes = 0;     ///< one RGBA32F position texture: 16 bytes per texel
    std::size_t neighbour_bytes = 0;   ///< N × 18 × 4
    /// Fraction of springs whose two particles are fewer than `locality_window` apart in memory:
    /// a cache-locality figure (4 KB of float4 positions; larger is better).
    double springs_within_window = 0.0;
    static constexpr int locality_window = 256;
};

/// Reorders `lattice`'s particles in place by `options.scheme` (springs are remapped, kept
/// first < second and sorted by first index) and returns the neighbour table and texels.
/// Deterministic. `new_index_of_old`, when given, receives the permutation (old index → new
/// index) so that data referring to particles (a simulation surface) can follow. Throws
/// InputError if the texture would exceed 16384 texels on a side.
Packing pack_particles(Lattice& lattice, const PackingOptions& options = {}, Progress& progress = null_progress(),
                       PackingReport* report = nullptr, std::vector<std::int32_t>* new_index_of_old = nullptr);

/// The neighbour table of `lattice` in its current order (used by pack_particles and by tests).
std::vector<std::array<std::int32_t, 18>> neighbour_table(const Lattice& lattice);

/// The per-slot view of the springs that gather-based kernels (CPU and GPU) need: entry
/// i·18 + s is the row in `springs` of the spring held at particle i's slot s, −1 for none.
/// Throws InputError when a spring joins particles that `neighbours` does not list as neighbours.
std::vector<std::int32_t> spring_of_slot(const std::vector<std::array<std::int32_t, 18>>& neighbours, const Springs& springs);

/// The slot opposite to `slot` (the offset negated).
constexpr int opposite_slot(int slot) {
    if (slot < 6) return slot ^ 1;
    const int group = 6 + ((slot - 6) / 4) * 4;
    return group + 3 - (slot - group);
}

}  // namespace heartsim
