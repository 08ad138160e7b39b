// The particle lattice against counts, lengths and masses that follow from geometry alone.
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/select.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <set>

using namespace heartsim;

namespace {

/// A label volume of `dims` voxels with label 1 in the voxel box [low, high).
LabelVolume block_volume(std::array<int, 3> dims, std::array<int, 3> low, std::array<int, 3> high, Eigen::Vector3d spacing,
                         Eigen::Matrix3d direction = Eigen::Matrix3d::Identity(), Eigen::Vector3d origin = Eigen::Vector3d::Zero()) {
    LabelVolume v;
    v.geometry.dims = dims;
    v.geometry.spacing = spacing;
    v.geometry.direction = direction;
    v.geometry.origin = origin;
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = low[2]; k < high[2]; ++k)
        for (int j = low[1]; j < high[1]; ++j)
            for (int i = low[0]; i < high[0]; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    return v;
}

Lattice layout(const LabelVolume& volume, LayoutOptions options, LayoutReport* report = nullptr,
               SelectionOptions selection_options = {}) {
    selection_options.min_island_mm3 = 0;
    const Selection selection = select_tissue(volume, selection_options);
    return layout_particles(selection, selection_options.tissue_labels, volume, options, null_progress(), report);
}

}  // namespace

class BlockLattice : public ::testing::TestWithParam<int> {};

TEST_P(BlockLattice, CountsLengthsAndMassFollowFromTheBlock) {
    const int n = GetParam();
    const double h = 2.0;  // two 1 mm voxels per cell
    const int offset = 4;  // even, so cells align with the block
    const int voxels = 2 * n + 2 * offset;
    const auto volume = block_volume({voxels, voxels + 2, voxels + 4}, {offset, offset, offset},
                                     {offset + 2 * n, offset + 2 * n, offset + 2 * n}, Eigen::Vector3d::Ones());
    LayoutReport report;
    const Material material{.density = 1.06e-3, .youngs_modulus_kpa = 20.0};
    const Lattice lattice = layout(volume, {.spacing_mm = h, .occupancy = 0.5, .materials = {material}}, &report);

    const std::size_t n3 = std::size_t(n) * n * n;
    EXPECT_EQ(lattice.particles.size(), n3);
    EXPECT_EQ(report.face_springs, std::size_t(3 * n * n * (n - 1)));
    EXPECT_EQ(report.edge_springs, std::size_t(6 * n * (n - 1) * (n - 1)));
    EXPECT_EQ(lattice.springs.size(), report.face_springs + report.edge_springs);

    // Rest lengths are exactly h and h√2; stiffness k = 0.4·E·h for both kinds.
    std::set<std::pair<int, int>> seen;
    for (std::size_t s = 0; s < lattice.springs.size(); ++s) {
        const auto [a, b] = lattice.springs.pairs[s];
        ASSERT_LT(a, b);
        ASSERT_TRUE(seen.insert({a, b}).second) << "spring " << a << "-" << b << " appears twice";
        const auto& xa = lattice.particles.rest_position[std::size_t(a)];
        const auto& xb = lattice.particles.rest_position[std::size_t(b)];
        const double distance = std::sqrt(std::pow(xa[0] - xb[0], 2) + std::pow(xa[1] - xb[1], 2) + std::pow(xa[2] - xb[2], 2));
        const float length = lattice.springs.rest_length[s];
        EXPECT_TRUE(std::abs(length - h) < 1e-6 || std::abs(length - h * std::sqrt(2.0)) < 1e-6) << length;
        EXPECT_NEAR(length, distance, 1e-5);
        EXPECT_NEAR(lattice.springs.stiffness[s], 0.4 * 20.0e-3 * h, 1e-9);
    }
    double mass = 0;
    for (float m : lattice.particles.mass) mass += m;
    const double block_volume_mm3 = std::pow(2.0 * n, 3);
    EXPECT_NEAR(mass, 1.06e-3 * block_volume_mm3, 1e-5 * mass);
    EXPECT_NEAR(report.total_mass, mass, 1e-6 * mass);
}

INSTANTIATE_TEST_SUITE_P(Sizes, BlockLattice, ::testing::Values(1, 2, 3, 5, 8));

TEST(Lattice, StiffnessRuleGivesTheRequestedYoungsModulus) {
    // Uniaxial strain ε along x of the infinite lattice: the stress σ_xx = C11 ε with
    // C11 = (k_face + 2 k_edge)/h (one face spring, four edge springs with cos⁴45° = 1/4, per cell).
    // For an isotropic solid with ν = 1/4, C11 = E(1−ν)/((1+ν)(1−2ν)) = 1.2 E.
    const double h = 1.7, youngs = 15.0;
    const double k = spring_stiffness(youngs, h);
    const double c11 = (k + 2.0 * k) / h;
    EXPECT_NEAR(c11, 1.2 * youngs * 1e-3, 1e-12);
}

TEST(Lattice, NeighbourSlotsAreTheEighteenNearestOffsetsEachWithItsOpposite) {
    std::set<std::array<int, 3>> offsets(neighbour_offsets.begin(), neighbour_offsets.end());
    EXPECT_EQ(offsets.size(), 18u);
    for (std::size_t slot = 0; slot < 18; ++slot) {
        const auto& o = neighbour_offsets[slot];
        const int squared = o[0] * o[0] + o[1] * o[1] + o[2] * o[2];
        EXPECT_EQ(squared, slot < 6 ? 1 : 2);
        EXPECT_TRUE(offsets.count({-o[0], -o[1], -o[2]}));
    }
}

TEST(Lattice, ParticlesSitAtCellCentresInTheWorldFrame) {
    // Rotated, anisotropic volume: the particle positions must equal the world affine of the
    // voxel grid applied to the cell centres, computed here independently.
    const Eigen::Matrix3d rotation = (Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())).toRotationMatrix();
    const Eigen::Vector3d spacing(0.5, 0.8, 1.25);
    const Eigen::Vector3d origin(-12.5, 40.0, 7.25);
    const auto volume = block_volume({40, 30, 20}, {8, 5, 4}, {28, 20, 14}, spacing, rotation, origin);
    const double h = 2.0;
    const Lattice lattice = layout(volume, {.spacing_mm = h, .occupancy = 0.5});
    ASSERT_GT(lattice.particles.size(), 10u);
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        const auto [a, b, c] = lattice.particles.lattice_index[i];
        // Cell (a,b,c) spans [a·h, (a+1)·h) mm from the volume's lower edge along each axis;
        // the voxel (0,0,0) centre sits half a voxel inside that edge.
        const Eigen::Vector3d along_axes((a + 0.5) * h, (b + 0.5) * h, (c + 0.5) * h);
        const Eigen::Vector3d expected = origin + rotation * (along_axes - 0.5 * spacing);
        const auto& x = lattice.particles.rest_position[i];
        EXPECT_NEAR(x[0], expected.x(), 1e-4);
        EXPECT_NEAR(x[1], expected.y(), 1e-4);
        EXPECT_NEAR(x[2], expected.z(), 1e-4);
    }
}

TEST(Lattice, OccupiedVolumeEqualsTissueVolumeWhenEveryCellCounts) {
    // With a tiny occupancy every touched cell gets a particle and Σ fraction·h³ is exactly the
    // tissue volume, whatever the misalignment between cells and voxels.
    const auto volume = block_volume({23, 19, 17}, {3, 2, 5}, {20, 15, 13}, Eigen::Vector3d(0.7, 0.9, 1.1));
    LayoutReport report;
    layout(volume, {.spacing_mm = 1.9, .occupancy = 1e-6}, &report);
    const double tissue = 17 * 13 * 8 * 0.7 * 0.9 * 1.1;
    EXPECT_NEAR(report.occupied_volume_mm3, tissue, 1e-4 * tissue);
}

TEST(Lattice, BudgetIsMetFromBelowAndCloseToIt) {
    auto mask = test::make_mask(60, 1.0, [](const Eigen::Vector3d& x) { return x.norm() < 25.0; });
    LabelVolume volume{mask.geometry, std::vector<std::int32_t>(mask.values.begin(), mask.values.end())};
    for (std::size_t budget : {500u, 3000u, 20000u}) {
        LayoutReport report;
        const Lattice lattice = layout(volume, {.particle_budget = budget}, &report);
        EXPECT_LE(lattice.particles.size(), budget);
        EXPECT_GE(double(lattice.particles.size()), 0.9 * double(budget)) << "spacing " << report.spacing;
    }
}

TEST(Lattice, AnchorBorderAnchorsOnlyCellsTouchingTheCut) {
    // A slab through the whole volume along k: anchored cells are exactly those in the first
    // and last cell layer along k.
    const auto volume = block_volume({12, 12, 20}, {2, 2, 0}, {10, 10, 20}, Eigen::Vector3d::Ones());
    SelectionOptions selection;
    selection.anchor_border = true;
    const Lattice lattice = layout(volume, {.spacing_mm = 2.0}, nullptr, selection);
    for (std::size_t i = 0; i < lattice.particles.size(); ++i) {
        const int c = lattice.particles.lattice_index[i][2];
        EXPECT_EQ(lattice.particles.anchored[i] != 0, c == 0 || c == lattice.dims[2] - 1) << "cell k = " << c;
    }
}

TEST(Lattice, RejectsBadSpacingAndOccupancy) {
    const auto volume = block_volume({8, 8, 8}, {2, 2, 2}, {6, 6, 6}, Eigen::Vector3d::Ones());
    EXPECT_THROW(layout(volume, {.spacing_mm = -1.0}), InputError);
    EXPECT_THROW(layout(volume, {.spacing_mm = std::nan("")}), InputError);
    EXPECT_THROW(layout(volume, {.spacing_mm = 1.0, .occupancy = 0.0}), InputError);
    EXPECT_THROW(layout(volume, {.spacing_mm = 1.0, .occupancy = 1.5}), InputError);
    EXPECT_THROW(layout(volume, {.spacing_mm = 50.0, .occupancy = 1.0}), InputError);  // no cell full
}

namespace {

/// Particles reachable from particle 0 along springs.
std::size_t connected_to_first(const Lattice& lattice) {
    const std::size_t n = lattice.particles.size();
    std::vector<std::vector<std::int32_t>> next(n);
    for (const auto& p : lattice.springs.pairs) {
        next[std::size_t(p[0])].push_back(p[1]);
        next[std::size_t(p[1])].push_back(p[0]);
    }
    std::vector<char> seen(n, 0);
    std::vector<std::int32_t> stack{0};
    seen[0] = 1;
    std::size_t count = 0;
    while (!stack.empty()) {
        const std::int32_t i = stack.back();
        stack.pop_back();
        ++count;
        for (std::int32_t j : next[std::size_t(i)])
            if (!seen[std::size_t(j)]) seen[std::size_t(j)] = 1, stack.push_back(j);
    }
    return count;
}

/// The largest distance from a tissue voxel centre to its nearest particle, mm.
double farthest_tissue_from_particles(const LabelVolume& volume, const Lattice& lattice) {
    double farthest = 0.0;
    const auto& g = volume.geometry;
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                if (volume.labels[g.linear(i, j, k)] != 1) continue;
                const Eigen::Vector3d x = g.to_world(Eigen::Vector3d(i, j, k));
                double nearest = 1e30;
                for (const auto& p : lattice.particles.rest_position)
                    nearest = std::min(nearest, (Eigen::Vector3d(p[0], p[1], p[2]) - x).norm());
                farthest = std::max(farthest, nearest);
            }
    return farthest;
}

}  // namespace

TEST(Lattice, ThinWallsAreKeptWholeAndThickenedWhereTheTissueAllows) {
    // Plates 0.5 mm voxels, 1.5 mm cells (three voxels per cell, cell c = voxels 3c..3c+2 along
    // k): a 1-voxel plate fills a third of its cells, below --occupancy 0.5.
    struct Plate {
        int first, thickness;
        const char* what;
        std::size_t layers;  // particle layers expected with thin-wall handling
    };
    for (const Plate plate : {Plate{15, 1, "1-voxel plate in one cell layer", 1}, Plate{16, 2, "2-voxel plate in one cell layer", 1},
                              Plate{17, 2, "2-voxel plate across two cell layers", 2}}) {
        SCOPED_TRACE(plate.what);
        const auto volume = block_volume({36, 36, 36}, {3, 3, plate.first}, {33, 33, plate.first + plate.thickness},
                                         Eigen::Vector3d::Constant(0.5));
        LayoutReport report;
        const Lattice lattice = layout(volume, {.spacing_mm = 1.5}, &report);
        ASSERT_GT(lattice.particles.size(), 0u);
        // Whole: one piece, every plate voxel within a cell's half-diagonal of a particle, and
        // every cell column over the plate (cells 1..10 along i and j) holds a particle: no hole.
        EXPECT_EQ(connected_to_first(lattice), lattice.particles.size());
        EXPECT_LE(farthest_tissue_from_particles(volume, lattice), 0.5 * std::sqrt(3.0) * 1.5 + 1e-9);
        std::set<std::array<int, 3>> cells;
        std::set<int> layers;
        for (const auto& c : lattice.particles.lattice_index) cells.insert(c), layers.insert(c[2]);
        for (int ci = 1; ci <= 10; ++ci)
            for (int cj = 1; cj <= 10; ++cj) {
                bool column = false;
                for (int layer : layers) column = column || cells.count({ci, cj, layer});
                EXPECT_TRUE(column) << "hole at cell column (" << ci << ", " << cj << ")";
            }
        EXPECT_EQ(layers.size(), plate.layers);
        // One layer is reported as thin (nothing beside it holds tissue); two layers are not.
        const std::vector<char> thin = thin_wall_particles(lattice);
        const std::size_t thin_count = std::size_t(std::count(thin.begin(), thin.end(), 1));
        EXPECT_EQ(report.thin_particles, thin_count);
        if (plate.layers == 1) {
            EXPECT_EQ(thin_count, lattice.particles.size());
            EXPECT_NEAR(report.thin_volume_share, 1.0, 1e-6);
        } else {
            EXPECT_EQ(thin_count, 0u);
        }
    }
    // Without thin-wall handling the 1-voxel plate is lost: no cell reaches the occupancy.
    const auto thin_plate = block_volume({36, 36, 36}, {3, 3, 15}, {33, 33, 16}, Eigen::Vector3d::Constant(0.5));
    EXPECT_THROW(layout(thin_plate, {.spacing_mm = 1.5, .thicken_walls = false}), InputError);
}

TEST(Lattice, AOneParticleWallWithTissueBesideItIsThickened) {
    // A 3-voxel plate, voxels 14..16 along k: cell 4 (voxels 12..14) holds a third of tissue,
    // cell 5 (15..17) two thirds. Cell 5 reaches the occupancy and is one particle thick; cell 4
    // beside it holds tissue, so it is added.
    const auto volume = block_volume({36, 36, 36}, {3, 3, 14}, {33, 33, 17}, Eigen::Vector3d::Constant(0.5));
    LayoutReport report;
    const Lattice lattice = layout(volume, {.spacing_mm = 1.5}, &report);
    std::set<int> layers;
    for (const auto& c : lattice.particles.lattice_index) layers.insert(c[2]);
    EXPECT_EQ(layers, (std::set<int>{4, 5}));
    EXPECT_GT(report.thickened, 0u);
    EXPECT_EQ(report.thin_particles, 0u);
    // Masses stay the tissue's: Σ m = density × tissue volume (every tissue voxel is in a cell
    // that has a particle).
    double mass = 0.0;
    for (float m : lattice.particles.mass) mass += m;
    const double tissue_mm3 = 30.0 * 30.0 * 3.0 * 0.125;
    EXPECT_NEAR(mass, lattice.materials[0].density * tissue_mm3, 1e-4 * mass);
    // And the thin-wall handling off keeps it one particle thick.
    LayoutReport kept;
    const Lattice one = layout(volume, {.spacing_mm = 1.5, .thicken_walls = false}, &kept);
    EXPECT_EQ(kept.thin_particles, one.particles.size());
}

TEST(Lattice, AThinTubeIsKeptWhole) {
    // A tube along k, radius 6 mm, wall one 0.5 mm voxel: no cell reaches the occupancy.
    const auto mask = test::make_mask(40, 0.5, [](const Eigen::Vector3d& x) {
        const double r = std::hypot(x.x(), x.y());
        return r >= 6.0 && r < 6.5 && std::abs(x.z()) < 8.0;
    });
    LabelVolume volume{mask.geometry, std::vector<std::int32_t>(mask.values.begin(), mask.values.end())};
    LayoutReport report;
    const Lattice lattice = layout(volume, {.spacing_mm = 1.5}, &report);
    ASSERT_GT(lattice.particles.size(), 0u);
    EXPECT_EQ(connected_to_first(lattice), lattice.particles.size()) << "the tube is one piece";
    EXPECT_LE(farthest_tissue_from_particles(volume, lattice), 0.5 * std::sqrt(3.0) * 1.5 + 1e-9);
    std::printf("thin tube: %zu particles (%zu ridges, %zu thickening), %zu still one thick (%.1f%% of the volume)\n",
                lattice.particles.size(), report.ridges, report.thickened, report.thin_particles, 100 * report.thin_volume_share);
}
