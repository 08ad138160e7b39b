// Septal defects carved into label maps (libmodel/defect.h): a synthetic two-chamber block whose
// septum is known, then the real HVSMR hearts (heartprep's command: test_defect_cli.cpp).
#include "defect_block.h"
#include "formats/volume_io.h"
#include "libmodel/defect.h"
#include "libmodel/errors.h"
#include "libmodel/label_conventions.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <deque>
#include <numbers>

using namespace heartsim;
using namespace heartsim::test::defect_block;

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

TEST(SeptalDefect, AnAortaNamedButAbsentPlacesNoSiteByItsDistance) {
    // The labels name an aorta (as MM-WHS's convention does) but the map holds none of its voxels:
    // no distance from it exists, so the sites placed by it are refused, the map untouched; the
    // secundum site, placed without it, and a given point still work.
    const Block block = make_block(6.0, 50.0, false);
    for (DefectSite site : {DefectSite::perimembranous, DefectSite::muscular, DefectSite::apical}) {
        SCOPED_TRACE(to_string(site));
        LabelVolume v = block.volume;
        DefectOptions o = block_options(true);
        o.diameter_mm = 8.0;
        o.site = site;
        try {
            carve_defect(v, o);
            ADD_FAILURE() << "an aorta with no voxel placed a site";
        } catch (const OptionError& e) {
            const std::string what = e.what();
            EXPECT_NE(what.find("no voxel of label " + std::to_string(aorta)), std::string::npos) << what;
            EXPECT_NE(what.find("{DefectOptions::at}"), std::string::npos) << what;
        }
        EXPECT_EQ(v.labels, block.volume.labels);
    }
    LabelVolume v = block.volume;
    DefectOptions at_point = block_options(true);
    at_point.diameter_mm = 8.0;
    at_point.at = block.world({0.0, 0.0, 0.0});
    const DefectReport r = carve_defect(v, at_point);
    EXPECT_TRUE(r.connected);
    EXPECT_TRUE(pools_connect(v, left, right));
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

TEST(SeptalDefectRealHearts, AVsdAtAGivenSeptumPointOfEveryHvsmrHeartOpensTheSeptumThrough) {
    // Points in each patient's interventricular septum (LPS mm), found on the images: a wall with
    // the thick-walled left ventricle's blood on one side and the right ventricle's on the other
    // (far apart walking through blood).
    const std::pair<const char*, Eigen::Vector3d> cases[] = {{"hvsmr16_pat0", {40.7, -14.4, -10.4}},
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
