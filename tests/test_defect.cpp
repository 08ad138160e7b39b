// Septal defects carved into label maps (libmodel/defect.h), and heartprep's `defect` command and
// `build --defect`: a synthetic two-chamber block whose septum is known, then the real hearts.
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/defect.h"
#include "libmodel/errors.h"
#include "libmodel/label_conventions.h"
#include "libmodel/mesh.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <deque>
#include <numbers>

using namespace heartsim;

namespace {

constexpr int wall = 1, left = 3, right = 5, aorta = 6;

/// A closed box (myocardium walls 3 mm thick) holding two pools, left (x below the septum) and
/// right, parted by a septum `septum_mm` thick across x at x = 0, `height_mm` tall (z) and 40 mm
/// deep (y); an anisotropic grid turned by a rotation, so nothing lines up with the voxel axes by
/// chance. With `with_aorta`, a pool of aorta blood sits above the septum's top end (z high),
/// walled off from both pools.
struct Block {
    LabelVolume volume;
    Eigen::Matrix3d rotation;
    double septum_mm, height_mm;
    /// Local block coordinates (x across the septum) of a voxel centre.
    Eigen::Vector3d local(int i, int j, int k) const {
        const Eigen::Vector3d world = volume.geometry.to_world(Eigen::Vector3d(i, j, k));
        return rotation.transpose() * world;
    }
    Eigen::Vector3d world(const Eigen::Vector3d& local) const { return rotation * local; }
};

Block make_block(double septum_mm = 6.0, double height_mm = 40.0, bool with_aorta = false) {
    Block b;
    b.septum_mm = septum_mm;
    b.height_mm = height_mm;
    b.rotation = (Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.25, Eigen::Vector3d::UnitY())).toRotationMatrix();
    auto& g = b.volume.geometry;
    g.spacing = Eigen::Vector3d(0.5, 0.6, 0.7);
    g.direction = b.rotation;
    const double half_x = 25.0, half_y = 23.0, half_z = 0.5 * height_mm + 3.0 + (with_aorta ? 14.0 : 0.0) + 3.0;
    const Eigen::Vector3d extent(2 * half_x, 2 * half_y, 2 * half_z);
    for (int a = 0; a < 3; ++a) g.dims[std::size_t(a)] = int(std::ceil(extent[a] / g.spacing[a])) + 1;
    // Centre the grid on the local origin.
    g.origin = b.rotation * (-0.5 * Eigen::Vector3d(g.dims[0] - 1, g.dims[1] - 1, g.dims[2] - 1).cwiseProduct(g.spacing));
    b.volume.labels.assign(g.voxel_count(), 0);
    const double top = 0.5 * height_mm;
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                const Eigen::Vector3d p = b.local(i, j, k);
                int label = 0;
                const bool in_box = std::abs(p.x()) < 22.0 && std::abs(p.y()) < 20.0 && p.z() > -top - 3.0 && p.z() < top + 3.0;
                if (in_box) {
                    const bool cavity = std::abs(p.y()) < 17.0 && std::abs(p.z()) < top && std::abs(p.x()) < 19.0;
                    label = !cavity ? wall : std::abs(p.x()) <= 0.5 * septum_mm ? wall : p.x() < 0 ? left : right;
                }
                if (with_aorta && p.z() >= top + 3.0 && p.z() < top + 17.0 && std::abs(p.x()) < 10.0 && std::abs(p.y()) < 10.0)
                    label = p.z() < top + 6.0 || std::abs(p.x()) > 7.0 || std::abs(p.y()) > 7.0 ? wall : aorta;
                b.volume.labels[g.linear(i, j, k)] = label;
            }
    return b;
}

DefectOptions block_options(bool sided) {
    DefectOptions o;
    o.wall_labels = {wall};
    o.blood_labels = {left, right, aorta};
    if (sided) {
        o.side_a = left;
        o.side_b = right;
        o.aorta = aorta;
    }
    return o;
}

/// Whether any voxel of label `from` reaches one of label `to` through voxels of either label
/// (6-connected), over the whole volume.
bool pools_connect(const LabelVolume& v, int from, int to) {
    const auto& g = v.geometry;
    std::vector<std::uint8_t> seen(v.labels.size());
    std::deque<std::array<int, 3>> queue;
    for (int k = 0; k < g.dims[2] && queue.empty(); ++k)
        for (int j = 0; j < g.dims[1] && queue.empty(); ++j)
            for (int i = 0; i < g.dims[0] && queue.empty(); ++i)
                if (v.labels[g.linear(i, j, k)] == from) queue.push_back({i, j, k}), seen[g.linear(i, j, k)] = 1;
    while (!queue.empty()) {
        const auto p = queue.front();
        queue.pop_front();
        if (v.labels[g.linear(p[0], p[1], p[2])] == to) return true;
        for (const auto& d : std::array<std::array<int, 3>, 6>{{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}}}) {
            const int i = p[0] + d[0], j = p[1] + d[1], k = p[2] + d[2];
            if (!g.contains(i, j, k) || seen[g.linear(i, j, k)]) continue;
            const int l = v.labels[g.linear(i, j, k)];
            if (l != from && l != to) continue;
            seen[g.linear(i, j, k)] = 1;
            queue.push_back({i, j, k});
        }
    }
    return false;
}

}  // namespace

TEST(SeptalDefect, ABlocksSeptumGetsAHoleOfTheDiameterAskedThroughItAndNothingElseChanges) {
    for (bool sided : {false, true}) {
        SCOPED_TRACE(sided ? "chambers labelled apart" : "any blood label");
        const Block block = make_block();
        LabelVolume v = block.volume;
        ASSERT_FALSE(pools_connect(v, left, right));
        DefectOptions o = block_options(sided);
        o.diameter_mm = 10.0;
        o.at = block.world({1.0, 2.0, -3.0});  // in the septum, off its middle
        const DefectReport r = carve_defect(v, o);

        // The axis is the septum's normal (local x), the centre on its middle plane.
        const Eigen::Vector3d axis = block.rotation.transpose() * r.normal;
        EXPECT_GT(std::abs(axis.x()), std::cos(2.0 * std::numbers::pi / 180.0)) << axis.transpose();
        const Eigen::Vector3d centre = block.rotation.transpose() * r.centre;
        EXPECT_NEAR(centre.x(), 0.0, 0.5);
        EXPECT_NEAR(centre.y(), 2.0, 0.7);
        EXPECT_NEAR(centre.z(), -3.0, 0.7);
        EXPECT_NEAR(r.wall_thickness_mm, block.septum_mm, 0.7);
        EXPECT_TRUE(r.connected);

        // Every changed voxel was septum inside a cylinder one voxel wider than asked around the
        // axis, and took the pool on its side; the hole's area in the septum's mid-layer, counted
        // here, is a disc of the diameter asked within one voxel.
        const auto& g = v.geometry;
        const double voxel = g.spacing.maxCoeff();
        double mid_layer_area = 0.0;
        const double layer = 0.5;  // mm either side of the septum's mid-plane
        std::size_t changed = 0;
        for (int k = 0; k < g.dims[2]; ++k)
            for (int j = 0; j < g.dims[1]; ++j)
                for (int i = 0; i < g.dims[0]; ++i) {
                    const std::size_t at = g.linear(i, j, k);
                    if (v.labels[at] == block.volume.labels[at]) continue;
                    ++changed;
                    const Eigen::Vector3d p = block.local(i, j, k);
                    EXPECT_EQ(block.volume.labels[at], wall);
                    EXPECT_LE(std::abs(p.x()), 0.5 * block.septum_mm + 1e-9);
                    EXPECT_LE(std::hypot(p.y() - centre.y(), p.z() - centre.z()), 5.0 + voxel);
                    // The side of the opening's mid-plane: before it along the axis, pool a.
                    const double t = (g.to_world(Eigen::Vector3d(i, j, k)) - r.centre).dot(r.normal);
                    EXPECT_EQ(v.labels[at], t < 0 ? r.label_a : r.label_b);
                    if (std::abs(p.x()) <= layer) mid_layer_area += g.voxel_volume() / (2 * layer);
                }
        EXPECT_EQ(changed, r.voxels_carved);
        const double diameter = 2.0 * std::sqrt(mid_layer_area / std::numbers::pi);
        EXPECT_NEAR(diameter, 10.0, voxel);
        EXPECT_NEAR(r.measured_diameter_mm, 10.0, voxel);
        if (sided) {
            EXPECT_TRUE(pools_connect(v, left, right));
            EXPECT_EQ(std::min(r.label_a, r.label_b), left);
            EXPECT_EQ(std::max(r.label_a, r.label_b), right);
        }
        // Through the whole septum: the axis is blood from one pool to the other.
        for (double t = -0.5 * block.septum_mm - 1.0; t <= 0.5 * block.septum_mm + 1.0; t += 0.1) {
            const Eigen::Vector3d p = g.direction.transpose() * (block.world(centre + Eigen::Vector3d(t, 0, 0)) - g.origin);
            const Eigen::Vector3d ijk = p.cwiseQuotient(g.spacing);
            const int l = v.labels[g.linear(int(std::lround(ijk.x())), int(std::lround(ijk.y())), int(std::lround(ijk.z())))];
            EXPECT_TRUE(l == left || l == right) << "t = " << t << ": label " << l;
        }
    }
}

TEST(SeptalDefect, SitesFoundWithoutAPointLieOnTheSeptumInTheirOrderFromTheAorta) {
    const Block block = make_block(6.0, 50.0, true);
    double previous = -1.0;
    for (DefectSite site : {DefectSite::perimembranous, DefectSite::muscular, DefectSite::apical}) {
        SCOPED_TRACE(to_string(site));
        LabelVolume v = block.volume;
        DefectOptions o = block_options(true);
        o.diameter_mm = 8.0;
        o.site = site;
        const DefectReport r = carve_defect(v, o);
        const Eigen::Vector3d centre = block.rotation.transpose() * r.centre;
        EXPECT_NEAR(centre.x(), 0.0, 0.5);
        EXPECT_TRUE(r.connected);
        EXPECT_TRUE(pools_connect(v, left, right));
        // The aorta sits above the septum's top (z = 25 mm): the sites go down the septum, each
        // keeping a rim of wall around the opening.
        EXPECT_GT(centre.z(), previous < 0 ? -25.0 : -1e9);
        const double from_top = 25.0 - centre.z();
        EXPECT_GT(from_top, 4.0 - 1e-9);
        EXPECT_GT(from_top, previous) << "sites in the order perimembranous, muscular, apical";
        previous = from_top;
        if (site == DefectSite::perimembranous) {
            EXPECT_LT(from_top, 4.0 + 4.0);
        } else if (site == DefectSite::apical) {
            EXPECT_GT(from_top, 50.0 - 4.0 - 3.0);
        }
    }
}

TEST(SeptalDefect, RefusesAPointOutsideASeptumOrAHoleLargerThanTheSeptumAndChangesNothing) {
    const Block block = make_block(6.0, 20.0);
    auto refused = [&](DefectOptions o, const std::string& words) {
        LabelVolume v = block.volume;
        try {
            carve_defect(v, o);
            ADD_FAILURE() << "no refusal; expected one saying '" << words << "'";
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
        }
        EXPECT_EQ(v.labels, block.volume.labels);
    };
    DefectOptions in_pool = block_options(false);
    in_pool.at = block.world({-12.0, 0.0, 0.0});  // in the left pool, 9 mm from every wall
    refused(in_pool, "no septum at");
    DefectOptions outer = block_options(false);
    outer.at = block.world({-10.0, 0.0, 11.5});  // the top wall: blood below, background above
    refused(outer, "not between two blood regions");
    DefectOptions wide = block_options(false);
    wide.at = block.world({0.0, 0.0, 0.0});
    wide.diameter_mm = 26.0;  // the septum is 20 mm tall
    refused(wide, "does not fit");
    refused(wide, "at most");
    DefectOptions unplaced = block_options(false);  // no point, and the chambers not labelled apart
    LabelVolume v = block.volume;
    EXPECT_THROW(carve_defect(v, unplaced), OptionError);
}

TEST(LabelConventions, NameTheMmwhsAndHvsmrLabelsAndRecogniseTheirSets) {
    const LabelConvention* mmwhs = find_label_convention("MMWHS");
    ASSERT_NE(mmwhs, nullptr);
    EXPECT_EQ(mmwhs->myocardium, 205);
    EXPECT_EQ(classify_segment_name(mmwhs->names.at(205)), SegmentKind::heart_muscle);
    for (int blood : mmwhs->blood) EXPECT_EQ(classify_segment_name(mmwhs->names.at(blood)), SegmentKind::not_muscle) << blood;
    EXPECT_EQ(matching_label_convention({205, 420, 500, 550, 600, 820, 850}), mmwhs);
    EXPECT_EQ(matching_label_convention({1, 2, 3, 4, 5, 6, 7}), find_label_convention("mmwhs-ordinal"));
    EXPECT_EQ(matching_label_convention({1, 2}), find_label_convention("hvsmr2016"));
    EXPECT_EQ(matching_label_convention({1, 2, 3}), nullptr);
    EXPECT_EQ(find_label_convention("nope"), nullptr);
}

namespace {

struct MmwhsCase {
    const char* folder;
    const char* file;
    const char* convention;
};

/// An automatic defect on a real MM-WHS heart: run through heartprep, then checked here on the
/// label map it wrote.
void check_automatic_defect(const MmwhsCase& c, const std::string& type, const std::string& site) {
    const auto input = test::real_data_dir() / c.folder / c.file;
    if (test::real_data_dir().empty() || !std::filesystem::exists(input)) GTEST_SKIP() << "real case absent: " << input;
    const LabelConvention& convention = *find_label_convention(c.convention);
    const int a = type == "vsd" ? convention.left_ventricle : convention.left_atrium;
    const int b = type == "vsd" ? convention.right_ventricle : convention.right_atrium;
    test::TempDir dir;
    const auto output = dir / "defect.nii.gz";
    const auto run = test::run_command(test::quoted(HEARTPREP_EXE) + " defect " + test::quoted(input.string()) + " --labels " +
                                       c.convention + " --type " + type + " --site " + site + " --diameter 10 -o " +
                                       test::quoted(output.string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("connected through the opening"), std::string::npos) << run.output;
    const LabelVolume before = read_label_volume(input), after = read_label_volume(output);
    ASSERT_EQ(before.labels.size(), after.labels.size());
    EXPECT_TRUE(after.geometry.voxel_to_world().isApprox(before.geometry.voxel_to_world(), 1e-6));
    // Every changed voxel was wall (the myocardium, or for an atrial septum an unlabelled one)
    // and became blood of one of the two pools; the pools, apart before, now connect.
    std::size_t changed = 0;
    for (std::size_t i = 0; i < before.labels.size(); ++i) {
        if (before.labels[i] == after.labels[i]) continue;
        ++changed;
        EXPECT_TRUE(before.labels[i] == convention.myocardium || before.labels[i] == 0) << before.labels[i];
        EXPECT_TRUE(after.labels[i] == a || after.labels[i] == b) << after.labels[i];
    }
    // A 10 mm opening through a wall a few mm thick: between a disc 1 mm thick and a cylinder 20 mm long.
    const double voxel_mm3 = before.geometry.voxel_volume();
    EXPECT_GT(double(changed) * voxel_mm3, std::numbers::pi * 25.0 * 1.0);
    EXPECT_LT(double(changed) * voxel_mm3, std::numbers::pi * 36.0 * 20.0);
    if (type == "vsd") EXPECT_FALSE(pools_connect(before, a, b));
    EXPECT_TRUE(pools_connect(after, a, b));
}

}  // namespace

TEST(SeptalDefectRealHearts, AnAutomaticVsdJoinsTheVentriclesOfEveryMmwhsHeart) {
    for (const MmwhsCase& c : {MmwhsCase{"mmwhs_ct1002", "ct_train_1002_label.nii.gz", "mmwhs"},
                               MmwhsCase{"mmwhs_wh", "mmwhs_wh-label.nii.gz", "mmwhs-ordinal"}})
        for (const char* site : {"perimembranous", "muscular"}) {
            SCOPED_TRACE(std::string(c.folder) + " " + site);
            check_automatic_defect(c, "vsd", site);
        }
}

TEST(SeptalDefectRealHearts, AnAutomaticAsdJoinsTheAtriaOfEveryMmwhsHeart) {
    for (const MmwhsCase& c : {MmwhsCase{"mmwhs_ct1002", "ct_train_1002_label.nii.gz", "mmwhs"},
                               MmwhsCase{"mmwhs_wh", "mmwhs_wh-label.nii.gz", "mmwhs-ordinal"}}) {
        SCOPED_TRACE(c.folder);
        check_automatic_defect(c, "asd", "secundum");
    }
}

TEST(HeartprepDefect, WritesTheLabelMapWithTheHoleInTheInputsGridAndRefusesWithoutWriting) {
    const Block block = make_block();
    test::TempDir dir;
    const auto input = dir / "block.nrrd";
    write_label_volume(input, block.volume);
    const Eigen::Vector3d at = block.world({0.5, -4.0, 6.0});
    const std::string point = std::to_string(at.x()) + "," + std::to_string(at.y()) + "," + std::to_string(at.z());
    const std::string heartprep = test::quoted(HEARTPREP_EXE);
    const auto output = dir / "vsd.nrrd";
    const auto run = test::run_command(heartprep + " defect " + test::quoted(input.string()) + " --type vsd --diameter 8 --at " + point +
                                       " -o " + test::quoted(output.string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("connected through the opening"), std::string::npos) << run.output;
    const LabelVolume after = read_label_volume(output);
    EXPECT_TRUE(after.geometry.voxel_to_world().isApprox(block.volume.geometry.voxel_to_world(), 1e-9));
    // The same hole as the library makes, voxel for voxel.
    LabelVolume expected = block.volume;
    DefectOptions o = block_options(false);
    o.blood_labels = {left, right};
    o.diameter_mm = 8.0;
    o.at = at;
    carve_defect(expected, o);
    EXPECT_EQ(after.labels, expected.labels);
    EXPECT_NE(after.labels, block.volume.labels);

    // Refusals: exit 1 for the data (an opening larger than the septum), exit 2 for the command
    // line; no file either way.
    const auto refused = dir / "refused.nrrd";
    auto attempt = [&](const std::string& options) {
        return test::run_command(heartprep + " defect " + test::quoted(input.string()) + " " + options + " -o " + test::quoted(refused.string()));
    };
    const auto too_wide = attempt("--diameter 45 --at " + point);
    EXPECT_EQ(too_wide.exit_code, 1) << too_wide.output;
    EXPECT_NE(too_wide.output.find("does not fit"), std::string::npos) << too_wide.output;
    const auto no_point = attempt("--type vsd");
    EXPECT_EQ(no_point.exit_code, 2) << no_point.output;
    EXPECT_NE(no_point.output.find("--at"), std::string::npos) << no_point.output;
    const auto both = attempt("--at " + point + " --site muscular");
    EXPECT_EQ(both.exit_code, 2) << both.output;
    EXPECT_FALSE(std::filesystem::exists(refused));

    // build --defect: the scenario records the defect, and inspect shows it.
    const auto scenario_path = dir / "vsd.h5";
    const auto build = test::run_command(heartprep + " build " + test::quoted(input.string()) + " --defect vsd --diameter 8 --at " + point +
                                         " --particles 4000 -q -o " + test::quoted(scenario_path.string()));
    ASSERT_EQ(build.exit_code, 0) << build.output;
    const Scenario scenario = read_scenario(scenario_path);
    EXPECT_EQ(scenario.source.defect, "vsd");
    EXPECT_DOUBLE_EQ(scenario.source.defect_diameter_mm, 8.0);
    const Eigen::Vector3d centre = block.rotation.transpose() * scenario.source.defect_centre;
    EXPECT_NEAR(centre.x(), 0.0, 0.5);
    EXPECT_NEAR((block.rotation.transpose() * scenario.source.defect_axis).x() * (block.rotation.transpose() * scenario.source.defect_axis).x(),
                1.0, 1e-3);
    const auto inspect = test::run_command(heartprep + " inspect " + test::quoted(scenario_path.string()));
    EXPECT_NE(inspect.output.find("defect      vsd, 8.0 mm"), std::string::npos) << inspect.output;
    // Without --defect the same build has no defect recorded and keeps the septum whole.
    const auto plain_path = dir / "plain.h5";
    ASSERT_EQ(test::run_command(heartprep + " build " + test::quoted(input.string()) + " --particles 4000 -q -o " +
                                test::quoted(plain_path.string())).exit_code, 0);
    const Scenario plain = read_scenario(plain_path);
    EXPECT_TRUE(plain.source.defect.empty());
    // The detailed surface encloses the tissue: the defect's build lacks the carved septum, and
    // its surface has one more handle (a hole through the wall: Euler characteristic 2 less).
    auto measure = [](const Scenario& s) {
        TriangleMesh mesh;
        for (const auto& p : s.visual->positions) mesh.positions.emplace_back(p[0], p[1], p[2]);
        mesh.triangles = s.visual->triangles;
        return analyse_mesh(mesh);
    };
    const MeshReport with_hole = measure(scenario), whole = measure(plain);
    EXPECT_EQ(with_hole.euler_characteristic, whole.euler_characteristic - 2);
    std::size_t carved = 0;
    for (std::size_t i = 0; i < after.labels.size(); ++i) carved += after.labels[i] != block.volume.labels[i];
    const double carved_mm3 = double(carved) * block.volume.geometry.voxel_volume();
    EXPECT_NEAR(whole.volume - with_hole.volume, carved_mm3, 0.1 * carved_mm3);
}

TEST(SeptalDefectRealHearts, AVsdAtAGivenSeptumPointOfEveryHvsmrHeartOpensTheSeptumThrough) {
    // Points in each patient's interventricular septum (LPS mm), found on the images: a wall with
    // the thick-walled left ventricle's blood on one side and the right ventricle's on the other
    // (far apart walking through blood).
    const std::pair<const char*, Eigen::Vector3d> cases[] = {{"hvsmr16_pat0", {46.0, -18.0, -10.4}},
                                                             {"hvsmr16_pat1", {11.4, -25.6, 5.2}},
                                                             {"hvsmr16_pat5", {26.8, -17.3, -4.9}},
                                                             {"hvsmr16_pat6", {26.9, -12.1, -20.0}}};
    for (const auto& [name, at] : cases) {
        SCOPED_TRACE(name);
        const auto input = test::real_case(name);
        if (input.empty()) {
            std::printf("skipped %s: real case absent\n", name);
            continue;
        }
        const LabelVolume before = read_label_volume(input);
        LabelVolume after = before;
        DefectOptions o;
        o.wall_labels = {1};
        o.blood_labels = {2};
        o.diameter_mm = 10.0;
        o.at = at;
        const DefectReport r = carve_defect(after, o);
        const auto& g = before.geometry;
        const double voxel = g.spacing.maxCoeff();
        EXPECT_TRUE(r.connected);
        EXPECT_NEAR(r.measured_diameter_mm, 10.0, voxel);
        EXPECT_LT((r.centre - at).norm(), 5.0);
        EXPECT_GT(r.wall_thickness_mm, 2.0);
        // Only myocardium near the axis changed, into blood.
        std::size_t changed = 0;
        for (int k = 0; k < g.dims[2]; ++k)
            for (int j = 0; j < g.dims[1]; ++j)
                for (int i = 0; i < g.dims[0]; ++i) {
                    const std::size_t v = g.linear(i, j, k);
                    if (before.labels[v] == after.labels[v]) continue;
                    ++changed;
                    EXPECT_EQ(before.labels[v], 1);
                    EXPECT_EQ(after.labels[v], 2);
                    const Eigen::Vector3d rel = g.to_world(Eigen::Vector3d(i, j, k)) - r.centre;
                    EXPECT_LE((rel - rel.dot(r.normal) * r.normal).norm(), 5.0 + voxel);
                }
        EXPECT_EQ(changed, r.voxels_carved);
        // Before, the axis crossed myocardium; after, it runs in blood from one pool to the other.
        auto label_at = [&](const LabelVolume& v, const Eigen::Vector3d& world) {
            const Eigen::Vector3d ijk = g.voxel_to_world().inverse().topLeftCorner<3, 3>() * (world - g.origin);
            return v.labels[g.linear(int(std::lround(ijk.x())), int(std::lround(ijk.y())), int(std::lround(ijk.z())))];
        };
        bool crossed_wall = false;
        for (double t = -0.5 * r.wall_thickness_mm - 1.0; t <= 0.5 * r.wall_thickness_mm + 1.0; t += 0.2) {
            crossed_wall = crossed_wall || label_at(before, r.centre + t * r.normal) == 1;
            EXPECT_EQ(label_at(after, r.centre + t * r.normal), 2) << "t = " << t;
        }
        EXPECT_TRUE(crossed_wall);
    }
}
