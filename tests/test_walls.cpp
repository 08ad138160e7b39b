// Walls grown where a label map has only blood (libmodel/walls.h): the exact distance transform
// against brute force, a grown shell against the closed form of a thick sphere on an anisotropic
// grid, growth into background only, two walls merged, and on the real hearts (MM-WHS CT, HVSMR
// MRI) the share of the blood surface that faced background and is walled afterwards, counted here
// from the label maps alone. Then heartprep: --walls labelled builds the label map as it is, the
// default records each wall and its thickness, a scenario without those fields reads as labelled.
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/errors.h"
#include "libmodel/label_conventions.h"
#include "libmodel/walls.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <set>

using namespace heartsim;
namespace fs = std::filesystem;
using test::quoted;

namespace {

LabelVolume empty_volume(const std::array<int, 3>& dims, const Eigen::Vector3d& spacing) {
    LabelVolume v;
    v.geometry.dims = dims;
    v.geometry.spacing = spacing;
    v.labels.assign(v.geometry.voxel_count(), 0);
    return v;
}

/// Voxel centre of (i, j, k) relative to the grid's middle, mm.
Eigen::Vector3d centred(const VolumeGeometry& g, int i, int j, int k) {
    return Eigen::Vector3d((i - 0.5 * (g.dims[0] - 1)) * g.spacing[0], (j - 0.5 * (g.dims[1] - 1)) * g.spacing[1],
                           (k - 0.5 * (g.dims[2] - 1)) * g.spacing[2]);
}

/// Fills voxels whose centre lies within `radius` of `centre` (relative to the grid's middle) with `label`.
void paint_ball(LabelVolume& v, const Eigen::Vector3d& centre, double radius, int label) {
    const auto& g = v.geometry;
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i)
                if ((centred(g, i, j, k) - centre).norm() <= radius) v.labels[g.linear(i, j, k)] = label;
}

struct Coverage {
    std::size_t faces = 0;   ///< blood faces that faced background before growing
    std::size_t walled = 0;  ///< of those, faces whose background along the normal, within the thickness, is all wall now
};

/// For every face between a voxel of `blood` and a background voxel of `before`: walks outward
/// along the face's normal through the voxels within `thickness_mm` of the face to within one
/// voxel (the k-th voxel's centre is k·h − h/2 from the face, h the spacing along that axis: those
/// with k·h ≤ thickness, and always the first) and counts the face walled when every one of them
/// that was background is a voxel of `walls` in `after`. The walk ends early at a voxel that
/// was not background (a labelled wall, another chamber's blood) or at the volume's edge.
Coverage coverage(const LabelVolume& before, const LabelVolume& after, const std::vector<int>& blood, double thickness_mm,
                  const std::set<int>& walls) {
    const auto& g = before.geometry;
    Coverage c;
    const int step[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                if (std::find(blood.begin(), blood.end(), before.labels[g.linear(i, j, k)]) == blood.end()) continue;
                for (int d = 0; d < 6; ++d) {
                    const int axis = d / 2;
                    const double h = g.spacing[axis];
                    int x = i + step[d][0], y = j + step[d][1], z = k + step[d][2];
                    if (!g.contains(x, y, z) || before.labels[g.linear(x, y, z)] != 0) continue;
                    ++c.faces;
                    bool walled = true;
                    for (int n = 1; n == 1 || n * h <= thickness_mm; ++n) {
                        if (!g.contains(x, y, z) || before.labels[g.linear(x, y, z)] != 0) break;
                        if (!walls.count(after.labels[g.linear(x, y, z)])) {
                            walled = false;
                            break;
                        }
                        x += step[d][0], y += step[d][1], z += step[d][2];
                    }
                    c.walled += walled;
                }
            }
    return c;
}

}  // namespace

// The separable transform is exact: on a random anisotropic grid, every voxel's squared distance
// and nearest feature match a brute-force search over all features.
TEST(Walls, TheFeatureTransformIsTheExactEuclideanDistance) {
    const std::array<int, 3> dims{23, 17, 11};
    const Eigen::Vector3d spacing(0.7, 1.1, 0.45);
    std::mt19937 random(7);
    std::vector<std::uint8_t> feature(std::size_t(dims[0] * dims[1] * dims[2]), 0);
    std::vector<std::array<int, 3>> features;
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i)
                if (random() % 97 == 0) {
                    feature[std::size_t((k * dims[1] + j) * dims[0] + i)] = 1;
                    features.push_back({i, j, k});
                }
    ASSERT_GT(features.size(), 10u);
    std::vector<float> squared;
    std::vector<std::int32_t> nearest;
    feature_transform(dims, spacing, feature, squared, nearest);
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                double best = 1e30;
                for (const auto& f : features) {
                    const Eigen::Vector3d d((i - f[0]) * spacing[0], (j - f[1]) * spacing[1], (k - f[2]) * spacing[2]);
                    best = std::min(best, d.squaredNorm());
                }
                const std::size_t v = std::size_t((k * dims[1] + j) * dims[0] + i);
                ASSERT_NEAR(squared[v], best, 1e-4 * (1 + best)) << i << ", " << j << ", " << k;
                ASSERT_GE(nearest[v], 0);
                const int fi = nearest[v] % dims[0], fj = (nearest[v] / dims[0]) % dims[1], fk = nearest[v] / (dims[0] * dims[1]);
                ASSERT_TRUE(feature[std::size_t(nearest[v])]);
                const Eigen::Vector3d d((i - fi) * spacing[0], (j - fj) * spacing[1], (k - fk) * spacing[2]);
                ASSERT_NEAR(d.squaredNorm(), best, 1e-4 * (1 + best)) << "the nearest feature is a nearest one";
            }
}

// A ball of blood grown by t on an anisotropic grid is a thick spherical shell: its volume is
// 4/3·π·((r + t)³ − r³) within the voxelisation's error (the outer surface's area times an
// eighth of the mean spacing), and along each axis the wall is t thick to within a voxel.
TEST(Walls, ABallOfBloodGrowsAShellOfTheClosedFormsVolume) {
    const Eigen::Vector3d spacing(0.6, 0.8, 0.5);
    for (const double t : {1.5, 3.0}) {
        const double r = 10.0;
        const double extent = 2 * (r + t + 2);
        LabelVolume v = empty_volume({int(extent / spacing[0]), int(extent / spacing[1]), int(extent / spacing[2])}, spacing);
        paint_ball(v, Eigen::Vector3d::Zero(), r, 2);
        const WallGrowthReport report = grow_walls(v, {{"shell", {2}, t, 9}});
        ASSERT_EQ(report.walls.size(), 1u);
        const double exact = 4.0 / 3.0 * M_PI * (std::pow(r + t, 3) - std::pow(r, 3));
        const double tolerance = 4 * M_PI * std::pow(r + t, 2) * spacing.mean() / 8;
        EXPECT_NEAR(report.walls[0].volume_mm3, exact, tolerance) << "t = " << t;
        std::size_t counted = 0;
        for (auto label : v.labels) counted += label == 9;
        EXPECT_EQ(counted, report.walls[0].voxels);
        // Along +i, +j, +k from the middle: the wall's voxels span t.
        const auto& g = v.geometry;
        const int mid[3] = {g.dims[0] / 2, g.dims[1] / 2, g.dims[2] / 2};
        for (int axis = 0; axis < 3; ++axis) {
            int cells = 0;
            int at[3] = {mid[0], mid[1], mid[2]};
            for (; at[axis] < g.dims[std::size_t(axis)]; ++at[axis]) cells += v.labels[g.linear(at[0], at[1], at[2])] == 9;
            EXPECT_NEAR(cells * spacing[axis], t, spacing[axis]) << "axis " << axis << ", t = " << t;
        }
    }
}

// Growth takes background only: every labelled voxel keeps its label, and two blood pools that
// touch (a valve plane) get no wall between them. Two walls that meet are one: the gap between two
// balls is filled, each voxel by the nearer ball's wall.
TEST(Walls, GrowthTakesBackgroundOnlyAndTwoWallsThatMeetAreOne) {
    const Eigen::Vector3d spacing(0.5, 0.5, 0.7);
    LabelVolume v = empty_volume({80, 50, 40}, spacing);
    paint_ball(v, {-6.5, 0, 0}, 5.0, 2);
    paint_ball(v, {6.5, 0, 0}, 5.0, 3);  // 3 mm of background between them
    paint_ball(v, {-6.5, 6, 0}, 2.5, 1);  // a labelled wall over part of ball 2
    paint_ball(v, {6.5, 0, 5.5}, 2.0, 4);  // a third pool touching ball 3: an orifice
    const LabelVolume before = v;
    const auto report = grow_walls(v, {{"a", {2}, 2.0, 10}, {"b", {3}, 2.0, 11}, {"c", {4}, 1.0, 12}});
    for (std::size_t n = 0; n < v.labels.size(); ++n)
        if (before.labels[n] != 0) ASSERT_EQ(v.labels[n], before.labels[n]) << "voxel " << n << " was labelled";
    const auto& g = v.geometry;
    // The orifice between 3 and 4 stays open: 3's voxels still touch 4's.
    std::size_t touching = 0;
    for (int k = 0; k + 1 < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i)
                touching += v.labels[g.linear(i, j, k)] == 3 && v.labels[g.linear(i, j, k + 1)] == 4;
    EXPECT_GT(touching, 0u);
    // The gap on the line between the centres (x in (−1.5, 1.5) mm) is all wall, the nearer ball's.
    const int j = g.dims[1] / 2, k = g.dims[2] / 2;
    int gap = 0;
    for (int i = 0; i < g.dims[0]; ++i) {
        const double x = centred(g, i, j, k).x();
        if (std::abs(x) >= 1.5) continue;
        ++gap;
        const auto label = v.labels[g.linear(i, j, k)];
        if (std::abs(x) > 0.3) {
            EXPECT_EQ(label, x < 0 ? 10 : 11) << "x = " << x;
        } else {
            EXPECT_TRUE(label == 10 || label == 11) << "x = " << x;
        }
    }
    EXPECT_GT(gap, 4);
    EXPECT_GT(report.walls[2].voxels, 0u);
    // Refused: a thickness outside the plausible range, a wall label that is in the map.
    LabelVolume again = before;
    EXPECT_THROW(grow_walls(again, {{"a", {2}, 0.01, 10}}), InputError);
    EXPECT_THROW(grow_walls(again, {{"a", {2}, 2.0, 3}}), InputError);
    EXPECT_EQ(again.labels, before.labels) << "a refused growth changes nothing";
}

// On the real hearts, the default walls cover at least 95 % of the blood surface of every chamber
// and great vessel that faced background, each within its own thickness (counted from the label
// maps alone, along each face's normal); the orifices between two pools are not background and
// stay open.
TEST(Walls, RealHeartsAreWalledWhereTheirBloodFacedBackground) {
    std::size_t tried = 0;
    for (const test::RealCase& c : test::real_cases()) {
        const std::string convention_name = c.label_options.find("mmwhs-ordinal") != std::string::npos ? "mmwhs-ordinal"
                                            : c.label_options.find("mmwhs") != std::string::npos        ? "mmwhs"
                                                                                                        : "hvsmr2016";
        const LabelConvention& convention = *find_label_convention(convention_name);
        const LabelVolume before = read_label_volume(c.label_map);
        const int first = *std::max_element(before.labels.begin(), before.labels.end()) + 1;
        const std::vector<WallStructure> structures = convention_walls(convention, WallThicknesses{}, first);
        LabelVolume after = before;
        grow_walls(after, structures);
        std::set<int> walls;
        for (const auto& s : structures) walls.insert(s.wall_label);
        std::size_t changed_labelled = 0;
        for (std::size_t n = 0; n < before.labels.size(); ++n) changed_labelled += before.labels[n] != 0 && after.labels[n] != before.labels[n];
        EXPECT_EQ(changed_labelled, 0u) << c.name;
        for (const auto& s : structures) {
            const Coverage cover = coverage(before, after, s.blood_labels, s.thickness_mm, walls);
            std::printf("%s: %s, %zu blood faces faced background, %.2f%% walled within %.1f mm\n", c.name.c_str(), s.name.c_str(),
                        cover.faces, cover.faces ? 100.0 * double(cover.walled) / double(cover.faces) : 100.0, s.thickness_mm);
            if (cover.faces == 0) continue;
            EXPECT_GE(double(cover.walled), 0.95 * double(cover.faces)) << c.name << ": " << s.name;
        }
        ++tried;
    }
    if (tried == 0) GTEST_SKIP() << "no real hearts in " << test::real_data_dir() << " (the shared data folder is absent)";
}

// heartprep: --walls labelled builds the label map as it is (no wall fields in the file: a file
// without them reads as all labelled, as every older scenario does); the default grows the wall
// around blood that faced background, records it with its thickness, and says so; a thickness
// outside the plausible range is refused with the flag's name.
TEST(Walls, HeartprepGrowsByDefaultRecordsTheWallsAndBuildsTheLabelsAsTheyAreOnRequest) {
    test::TempDir dir;
    // A ball of blood (2) half covered by a labelled cap of myocardium (1): HVSMR's labels.
    LabelVolume v = empty_volume({60, 60, 60}, Eigen::Vector3d(0.8, 0.8, 0.8));
    paint_ball(v, Eigen::Vector3d::Zero(), 16.0, 1);
    for (int k = 0; k < 60; ++k)  // keep the cap's upper half only
        for (int j = 0; j < 60; ++j)
            for (int i = 0; i < 60; ++i)
                if (k < 30 && v.labels[v.geometry.linear(i, j, k)] == 1) v.labels[v.geometry.linear(i, j, k)] = 0;
    paint_ball(v, Eigen::Vector3d::Zero(), 12.0, 2);
    write_label_volume(dir / "ball.nii.gz", v);
    std::size_t myocardium = 0;
    for (auto label : v.labels) myocardium += label == 1;

    const auto labelled = test::heartprep("build " + quoted(dir / "ball.nii.gz") + " -o " + quoted(dir / "labelled.h5") +
                                          " --particles 3000 --walls labelled");
    ASSERT_EQ(labelled.exit_code, 0) << labelled.output;
    const Scenario a = read_scenario(dir / "labelled.h5");
    EXPECT_TRUE(a.tissue_origin.empty()) << "a build of the labels as they are writes no wall fields";
    EXPECT_EQ(a.source.tissue_labels, std::vector<int>{1});
    EXPECT_EQ(a.lattice.materials.size(), 1u);
    EXPECT_NEAR(a.source.tissue_volume_mm3, double(myocardium) * v.geometry.voxel_volume(), 1e-3);
    EXPECT_NE(labelled.output.find("as labelled; no wall grown"), std::string::npos) << labelled.output;

    const auto grown = test::heartprep("build " + quoted(dir / "ball.nii.gz") + " -o " + quoted(dir / "grown.h5") +
                                       " --particles 3000 --wall-blood-pool 2.5");
    ASSERT_EQ(grown.exit_code, 0) << grown.output;
    const Scenario b = read_scenario(dir / "grown.h5");
    ASSERT_EQ(b.tissue_origin.size(), b.lattice.materials.size());
    ASSERT_EQ(b.lattice.materials.size(), 2u);
    EXPECT_FALSE(b.tissue_origin[0].grown);
    EXPECT_TRUE(b.tissue_origin[1].grown);
    EXPECT_DOUBLE_EQ(b.tissue_origin[1].thickness_mm, 2.5);
    EXPECT_EQ(b.tissue_origin[1].grown_from, 2);
    EXPECT_EQ(b.source.tissue_labels, std::vector<int>{1}) << "the input's tissue labels; the grown wall's label is not the input's";
    EXPECT_NEAR(b.tissue_origin[0].volume_mm3, double(myocardium) * v.geometry.voxel_volume(), 1e-3);
    // The lower half of the ball faced background: a hemispherical shell of 2.5 mm grows there
    // (and a rim where the cap ends), so the wall is at least the half shell's closed form.
    const double half_shell = 2.0 / 3.0 * M_PI * (std::pow(14.5, 3) - std::pow(12.0, 3));
    EXPECT_GT(b.tissue_origin[1].volume_mm3, 0.9 * half_shell);
    EXPECT_LT(b.tissue_origin[1].volume_mm3, 1.3 * half_shell);
    EXPECT_NEAR(b.source.tissue_volume_mm3, b.tissue_origin[0].volume_mm3 + b.tissue_origin[1].volume_mm3, 1.0);
    std::size_t on_wall = 0;
    for (auto m : b.lattice.particles.material) on_wall += m == 1;
    EXPECT_GT(on_wall, 0u) << "particles carry the grown wall's material";
    EXPECT_NE(grown.output.find("blood pool wall 2.5 mm"), std::string::npos) << grown.output;
    const auto inspect = test::heartprep("inspect " + quoted(dir / "grown.h5"));
    EXPECT_NE(inspect.output.find("grown"), std::string::npos) << inspect.output;

    const auto refused = test::heartprep("build " + quoted(dir / "ball.nii.gz") + " -o " + quoted(dir / "no.h5") + " --wall-atria 0.01");
    EXPECT_NE(refused.exit_code, 0);
    EXPECT_NE(refused.output.find("--wall-atria"), std::string::npos) << refused.output;
    EXPECT_FALSE(fs::exists(dir / "no.h5"));
    const auto both = test::heartprep("build " + quoted(dir / "ball.nii.gz") + " -o " + quoted(dir / "no.h5") + " --walls labelled --wall-rv 4");
    EXPECT_NE(both.exit_code, 0);
    EXPECT_NE(both.output.find("--wall-rv"), std::string::npos) << both.output;
}

// An MM-WHS map without some of its convention's labels (here no atria, aorta or pulmonary
// artery: 1 myocardium round the left ventricle's blood 3, the right ventricle's blood 5 beside
// it): the walls take labels above every label the convention knows, so none is read as another
// structure's blood, and the right ventricle's wall grows.
TEST(Walls, AConventionsMapWithoutSomeOfItsLabelsGrowsItsWalls) {
    test::TempDir dir;
    LabelVolume v = empty_volume({70, 50, 50}, Eigen::Vector3d(0.8, 0.8, 0.8));
    paint_ball(v, Eigen::Vector3d(-6, 0, 0), 14.0, 1);
    paint_ball(v, Eigen::Vector3d(-6, 0, 0), 10.0, 3);
    paint_ball(v, Eigen::Vector3d(14, 0, 0), 9.0, 5);
    write_label_volume(dir / "partial.nii.gz", v);
    const auto run = test::heartprep("build " + quoted(dir / "partial.nii.gz") + " -o " + quoted(dir / "partial.h5") +
                                     " --labels mmwhs-ordinal --particles 3000");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    // The structures it leaves out are said.
    EXPECT_NE(run.output.find("holds no 2 'left atrium blood pool'"), std::string::npos) << run.output;
    const Scenario s = read_scenario(dir / "partial.h5");
    ASSERT_EQ(s.tissue_origin.size(), s.lattice.materials.size());
    bool right_ventricle = false;
    for (std::size_t m = 0; m < s.lattice.materials.size(); ++m) {
        if (!s.tissue_origin[m].grown) continue;
        EXPECT_GT(s.lattice.materials[m].label, 7) << s.lattice.materials[m].name;
        right_ventricle = right_ventricle || (s.tissue_origin[m].grown_from == 5 && s.tissue_origin[m].volume_mm3 > 0);
    }
    EXPECT_TRUE(right_ventricle) << run.output;
}
