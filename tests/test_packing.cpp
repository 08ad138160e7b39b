// Packing: the neighbour table against the lattice itself, for both schemes.
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/select.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <map>
#include <set>

using namespace heartsim;

namespace {

Lattice sphere_lattice(double radius = 12.0, double spacing = 1.5) {
    auto mask = test::make_mask(int(2 * radius / 1.0) + 6, 1.0, [&](const Eigen::Vector3d& x) { return x.norm() < radius; });
    LabelVolume volume{mask.geometry, std::vector<std::int32_t>(mask.values.begin(), mask.values.end())};
    const Selection selection = select_tissue(volume, {.min_island_mm3 = 0});
    return layout_particles(selection, {1}, volume, {.spacing_mm = spacing});
}

}  // namespace

class PackingScheme_ : public ::testing::TestWithParam<PackingScheme> {};

TEST_P(PackingScheme_, NeighbourSlotsHoldExactlyTheLatticeNeighbours) {
    Lattice lattice = sphere_lattice();
    const Lattice before = lattice;
    std::vector<std::int32_t> new_index;
    PackingReport report;
    const Packing packing = pack_particles(lattice, {.scheme = GetParam()}, null_progress(), &report, &new_index);
    const auto& p = lattice.particles;
    const std::size_t n = p.size();
    ASSERT_EQ(n, before.particles.size());
    ASSERT_EQ(packing.neighbours.size(), n);

    // The permutation moves every particle's data with it.
    for (std::size_t old = 0; old < n; ++old) {
        const auto now = std::size_t(new_index[old]);
        EXPECT_EQ(p.lattice_index[now], before.particles.lattice_index[old]);
        EXPECT_EQ(p.rest_position[now], before.particles.rest_position[old]);
        EXPECT_EQ(p.mass[now], before.particles.mass[old]);
    }

    std::map<std::array<int, 3>, std::int32_t> at;
    for (std::size_t i = 0; i < n; ++i) at[p.lattice_index[i]] = std::int32_t(i);
    std::size_t filled = 0;
    for (std::size_t i = 0; i < n; ++i)
        for (int slot = 0; slot < 18; ++slot) {
            const auto& o = neighbour_offsets[std::size_t(slot)];
            const auto& l = p.lattice_index[i];
            auto found = at.find({l[0] + o[0], l[1] + o[1], l[2] + o[2]});
            const std::int32_t expected = found == at.end() ? -1 : found->second;
            ASSERT_EQ(packing.neighbours[i][std::size_t(slot)], expected) << "particle " << i << " slot " << slot;
            if (expected >= 0) {
                ++filled;
                EXPECT_EQ(packing.neighbours[std::size_t(expected)][std::size_t(opposite_slot(slot))], std::int32_t(i));
            }
        }
    // Consistent with /springs: every spring is a pair of slots, and every filled slot a spring.
    EXPECT_EQ(filled, 2 * lattice.springs.size());
    std::set<std::array<std::int32_t, 2>> springs(lattice.springs.pairs.begin(), lattice.springs.pairs.end());
    EXPECT_EQ(springs.size(), lattice.springs.size());
    for (const auto& [a, b] : lattice.springs.pairs) {
        ASSERT_LT(a, b);
        const auto& row = packing.neighbours[std::size_t(a)];
        EXPECT_NE(std::find(row.begin(), row.end(), b), row.end());
    }
    // The same springs as before packing, renamed.
    std::set<std::array<std::int32_t, 2>> renamed;
    for (const auto& [a, b] : before.springs.pairs) {
        const auto x = new_index[std::size_t(a)], y = new_index[std::size_t(b)];
        renamed.insert({std::min(x, y), std::max(x, y)});
    }
    EXPECT_EQ(renamed, springs);

    // Texels: inside the texture, one particle each.
    std::set<std::array<std::int32_t, 2>> texels(packing.texture_coord.begin(), packing.texture_coord.end());
    EXPECT_EQ(texels.size(), n);
    for (const auto& [x, y] : packing.texture_coord) {
        EXPECT_GE(x, 0);
        EXPECT_GE(y, 0);
        EXPECT_LT(x, packing.width);
        EXPECT_LT(y, packing.height);
    }
    EXPECT_NEAR(report.occupancy, double(n) / (double(packing.width) * packing.height), 1e-12);
}

INSTANTIATE_TEST_SUITE_P(Schemes, PackingScheme_, ::testing::Values(PackingScheme::slices, PackingScheme::bricks));

TEST(Packing, SlicesTileTheLatticeAsThePositionTexture) {
    Lattice lattice = sphere_lattice(8.0, 2.0);
    const auto dims = lattice.dims;
    const Packing packing = pack_particles(lattice, {.scheme = PackingScheme::slices});
    // Within a tile, texel offsets equal the cell's (i, j); the tile is chosen by k.
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        const auto& l = lattice.particles.lattice_index[i];
        EXPECT_EQ(packing.texture_coord[i][0] % dims[0], l[0]);
        EXPECT_EQ(packing.texture_coord[i][1] % dims[1], l[1]);
    }
    // Particles are ordered by texel, row by row.
    for (std::size_t i = 1; i < lattice.particles.size(); ++i) {
        const auto& a = packing.texture_coord[i - 1];
        const auto& b = packing.texture_coord[i];
        EXPECT_LT(std::make_pair(a[1], a[0]), std::make_pair(b[1], b[0]));
    }
}

TEST(Packing, BricksKeepMoreSpringsWithinACacheWindowThanRasterOrder) {
    // In raster order only the i- and j-neighbours of a 40-cell-wide lattice are near in memory:
    // 4 of the 9 springs per particle. Bricks keep most neighbours in the same or the next brick.
    Lattice lattice = sphere_lattice(20.0, 1.0);
    std::size_t near = 0;
    for (const auto& [a, b] : lattice.springs.pairs) near += b - a < PackingReport::locality_window;
    const double raster = double(near) / double(lattice.springs.size());
    PackingReport report;
    pack_particles(lattice, {.scheme = PackingScheme::bricks}, null_progress(), &report);
    EXPECT_GT(report.springs_within_window, raster + 0.2) << "bricks " << report.springs_within_window << " vs raster " << raster;
}

TEST(Packing, OppositeSlotNegatesTheOffset) {
    for (int slot = 0; slot < 18; ++slot) {
        const auto& a = neighbour_offsets[std::size_t(slot)];
        const auto& b = neighbour_offsets[std::size_t(opposite_slot(slot))];
        EXPECT_EQ(a[0], -b[0]);
        EXPECT_EQ(a[1], -b[1]);
        EXPECT_EQ(a[2], -b[2]);
    }
    EXPECT_THROW(parse_packing_scheme("hilbert"), InputError);
}

TEST(Packing, SpringOfSlotPutsEverySpringAtTheSlotOfItsOffset) {
    Lattice lattice = sphere_lattice(8.0, 2.0);
    const Packing packing = pack_particles(lattice);
    const auto slot_spring = spring_of_slot(packing.neighbours, lattice.springs);
    std::size_t filled = 0;
    for (std::size_t i = 0; i < lattice.particles.size(); ++i)
        for (int slot = 0; slot < 18; ++slot) {
            const std::int32_t q = slot_spring[i * 18 + std::size_t(slot)];
            if (q < 0) continue;
            ++filled;
            const auto [a, b] = lattice.springs.pairs[std::size_t(q)];
            const std::size_t other = std::size_t(a) == i ? std::size_t(b) : std::size_t(a);
            const auto& li = lattice.particles.lattice_index[i];
            const auto& lo = lattice.particles.lattice_index[other];
            const auto& offset = neighbour_offsets[std::size_t(slot)];
            EXPECT_EQ(lo[0] - li[0], offset[0]);
            EXPECT_EQ(lo[1] - li[1], offset[1]);
            EXPECT_EQ(lo[2] - li[2], offset[2]);
        }
    EXPECT_EQ(filled, 2 * lattice.springs.size());

    Springs stray = lattice.springs;
    stray.pairs.push_back({0, std::int32_t(lattice.particles.size() - 1)});  // far apart: not neighbours
    stray.rest_length.push_back(1.0f);
    stray.stiffness.push_back(1.0f);
    EXPECT_THROW(spring_of_slot(packing.neighbours, stray), InputError);
}
