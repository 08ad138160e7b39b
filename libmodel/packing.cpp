#include "libmodel/packing.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace heartsim {

PackingScheme parse_packing_scheme(const std::string& name) {
    if (name == "slices") return PackingScheme::slices;
    if (name == "bricks") return PackingScheme::bricks;
    throw InputError("unknown packing scheme '" + name + "' (expected slices or bricks)");
}

const char* to_string(PackingScheme scheme) { return scheme == PackingScheme::slices ? "slices" : "bricks"; }

namespace {

/// Interleaves the low 10 bits of x, y, z (Morton / Z-order code).
std::uint32_t morton(std::uint32_t x, std::uint32_t y, std::uint32_t z) {
    auto spread = [](std::uint32_t v) {
        v &= 0x3ff;
        v = (v | (v << 16)) & 0x030000ff;
        v = (v | (v << 8)) & 0x0300f00f;
        v = (v | (v << 4)) & 0x030c30c3;
        v = (v | (v << 2)) & 0x09249249;
        return v;
    };
    return spread(x) | (spread(y) << 1) | (spread(z) << 2);
}

}  // namespace

std::vector<std::array<std::int32_t, 18>> neighbour_table(const Lattice& lattice) {
    const auto& p = lattice.particles;
    const ParticleGrid grid(lattice);
    std::vector<std::array<std::int32_t, 18>> table(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) {
        const auto& l = p.lattice_index[i];
        for (std::size_t slot = 0; slot < 18; ++slot) {
            const auto& o = neighbour_offsets[slot];
            table[i][slot] = grid.at(l[0] + o[0], l[1] + o[1], l[2] + o[2]);
        }
    }
    return table;
}

std::vector<std::int32_t> spring_of_slot(const std::vector<std::array<std::int32_t, 18>>& neighbours, const Springs& springs) {
    const std::size_t n = neighbours.size();
    std::vector<std::int32_t> slot_spring(n * 18, -1);
    auto find_slot = [&](std::int32_t a, std::int32_t b, int preferred) {
        if (a < 0 || std::size_t(a) >= n) return -1;
        const auto& row = neighbours[std::size_t(a)];
        if (preferred >= 0 && row[std::size_t(preferred)] == b) return preferred;
        for (int s = 0; s < 18; ++s)
            if (row[std::size_t(s)] == b) return s;
        return -1;
    };
    for (std::size_t q = 0; q < springs.size(); ++q) {
        const auto [a, b] = springs.pairs[q];
        const int sa = find_slot(a, b, -1);
        const int sb = find_slot(b, a, sa >= 0 ? opposite_slot(sa) : -1);
        if (sa < 0 || sb < 0)
            throw InputError("spring " + std::to_string(q) + " joins particles " + std::to_string(a) + " and " + std::to_string(b) +
                             ", which the neighbour table does not list as neighbours");
        slot_spring[std::size_t(a) * 18 + std::size_t(sa)] = std::int32_t(q);
        slot_spring[std::size_t(b) * 18 + std::size_t(sb)] = std::int32_t(q);
    }
    return slot_spring;
}

Packing pack_particles(Lattice& lattice, const PackingOptions& options, Progress& progress, PackingReport* report_out,
                       std::vector<std::int32_t>* new_index_of_old) {
    ProgressStage stage(progress, "pack", 3);
    auto& p = lattice.particles;
    const std::size_t n = p.size();
    Packing packing;
    packing.scheme = options.scheme;

    // Sort key per particle, and the texture it lands in.
    std::vector<std::uint64_t> key(n);
    std::vector<std::array<std::int32_t, 2>> texel(n);
    if (options.scheme == PackingScheme::slices) {
        const int tile_w = lattice.dims[0], tile_h = lattice.dims[1], tiles = lattice.dims[2];
        const int columns = std::max(1, int(std::ceil(std::sqrt(double(tiles) * tile_h / tile_w))));
        const int rows = (tiles + columns - 1) / columns;
        packing.width = columns * tile_w;
        packing.height = rows * tile_h;
        for (std::size_t i = 0; i < n; ++i) {
            const auto& l = p.lattice_index[i];
            const int x = (l[2] % columns) * tile_w + l[0];
            const int y = (l[2] / columns) * tile_h + l[1];
            texel[i] = {x, y};
            key[i] = std::uint64_t(y) * std::uint64_t(packing.width) + std::uint64_t(x);
        }
    } else {
        for (std::size_t i = 0; i < n; ++i) {
            const auto& l = p.lattice_index[i];
            const std::uint32_t brick = morton(std::uint32_t(l[0]) >> 2, std::uint32_t(l[1]) >> 2, std::uint32_t(l[2]) >> 2);
            const std::uint32_t within = morton(std::uint32_t(l[0]) & 3, std::uint32_t(l[1]) & 3, std::uint32_t(l[2]) & 3);
            key[i] = (std::uint64_t(brick) << 6) | within;
        }
        int width = options.texture_width;
        if (width <= 0) {
            width = 1;
            while (std::size_t(width) * std::size_t(width) < n) width *= 2;
        }
        packing.width = width;
        packing.height = int((n + std::size_t(width) - 1) / std::size_t(width));
    }
    if (packing.width > max_texture_side || packing.height > max_texture_side)
        throw InputError("the position texture would be " + std::to_string(packing.width) + " x " + std::to_string(packing.height) +
                         " texels, above the " + std::to_string(max_texture_side) +
                         " a GPU guarantees: use {PackingOptions::scheme} bricks or a coarser {LayoutOptions::spacing_mm}");

    // The permutation: new position r holds old particle order[r]. Keys are unique per cell.
    std::vector<std::int32_t> order(n);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) { return key[std::size_t(a)] < key[std::size_t(b)]; });
    std::vector<std::int32_t> new_index(n);
    for (std::size_t r = 0; r < n; ++r) new_index[std::size_t(order[r])] = std::int32_t(r);
    stage.update(1);

    auto permute = [&](auto& values) {
        auto copy = values;
        for (std::size_t r = 0; r < n; ++r) values[r] = copy[std::size_t(order[r])];
    };
    permute(p.rest_position);
    permute(p.lattice_index);
    permute(p.mass);
    permute(p.material);
    permute(p.anchored);
    if (p.supported()) {
        permute(p.support_stiffness);
        permute(p.support_point);
        permute(p.support_damping);
    }
    if (options.scheme == PackingScheme::slices) {
        permute(texel);
        packing.texture_coord = std::move(texel);
    } else {
        packing.texture_coord.resize(n);
        for (std::size_t r = 0; r < n; ++r)
            packing.texture_coord[r] = {std::int32_t(r % std::size_t(packing.width)), std::int32_t(r / std::size_t(packing.width))};
    }

    // Springs: remap, order each pair, then sort springs by (first, second) so a sweep over
    // springs walks the particles in memory order.
    auto& s = lattice.springs;
    std::vector<std::size_t> spring_order(s.size());
    for (auto& pair : s.pairs) {
        const std::int32_t a = new_index[std::size_t(pair[0])], b = new_index[std::size_t(pair[1])];
        pair = {std::min(a, b), std::max(a, b)};
    }
    std::iota(spring_order.begin(), spring_order.end(), std::size_t(0));
    std::sort(spring_order.begin(), spring_order.end(), [&](std::size_t a, std::size_t b) { return s.pairs[a] < s.pairs[b]; });
    auto permute_springs = [&](auto& values) {
        auto copy = values;
        for (std::size_t r = 0; r < values.size(); ++r) values[r] = copy[spring_order[r]];
    };
    permute_springs(s.pairs);
    permute_springs(s.rest_length);
    permute_springs(s.stiffness);
    stage.update(2);

    packing.neighbours = neighbour_table(lattice);
    stage.update(3);

    if (new_index_of_old) *new_index_of_old = std::move(new_index);
    if (report_out) {
        PackingReport report;
        report.width = packing.width;
        report.height = packing.height;
        report.occupancy = double(n) / (double(packing.width) * packing.height);
        report.texture_bytes = std::size_t(packing.width) * std::size_t(packing.height) * 16;
        report.neighbour_bytes = n * 18 * sizeof(std::int32_t);
        std::size_t near = 0;
        for (const auto& pair : s.pairs) near += pair[1] - pair[0] < PackingReport::locality_window;
        report.springs_within_window = s.size() ? double(near) / double(s.size()) : 0.0;
        *report_out = report;
    }
    return packing;
}

}  // namespace heartsim
