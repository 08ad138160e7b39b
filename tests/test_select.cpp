// Tissue selection: islands, anchors and the errors a technician can run into.
#include "libmodel/errors.h"
#include "libmodel/phantom.h"
#include "libmodel/segment_names.h"
#include "libmodel/select.h"

#include <gtest/gtest.h>

using namespace heartsim;

namespace {

LabelVolume two_blobs() {
    // A 6×6×6 block (216 voxels) and a detached 2×2×2 block (8 voxels) of label 1, label 2 beside.
    LabelVolume v;
    v.geometry.dims = {20, 12, 12};
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = 2; k < 8; ++k)
        for (int j = 2; j < 8; ++j)
            for (int i = 2; i < 8; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    for (int k = 2; k < 4; ++k)
        for (int j = 2; j < 4; ++j)
            for (int i = 12; i < 14; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    v.labels[v.geometry.linear(16, 6, 6)] = 2;
    return v;
}

}  // namespace

TEST(Select, DropsIslandsBelowTheThresholdAndReportsThem) {
    const auto v = two_blobs();
    SelectionReport report;
    const auto s = select_tissue(v, {.min_island_mm3 = 10.0}, null_progress(), &report);
    ASSERT_EQ(report.islands.size(), 2u);
    EXPECT_EQ(report.islands[0].voxels, 216u);
    EXPECT_TRUE(report.islands[0].kept);
    EXPECT_EQ(report.islands[1].voxels, 8u);
    EXPECT_FALSE(report.islands[1].kept);
    EXPECT_EQ(report.islands_dropped, 1u);
    EXPECT_EQ(report.voxels_dropped, 8u);
    EXPECT_EQ(s.tissue.count(), 216u);
    EXPECT_FALSE(s.tissue.at(12, 2, 2));

    const auto all = select_tissue(v, {.min_island_mm3 = 0.0}, null_progress(), &report);
    EXPECT_EQ(all.tissue.count(), 224u);
    EXPECT_EQ(report.islands_dropped, 0u);
}

TEST(Select, DiagonalNeighboursAreSeparateIslands) {
    // 6-connectivity: two voxels touching only at an edge are two islands.
    LabelVolume v;
    v.geometry.dims = {4, 4, 4};
    v.labels.assign(64, 0);
    v.labels[v.geometry.linear(1, 1, 1)] = 1;
    v.labels[v.geometry.linear(2, 2, 1)] = 1;
    SelectionReport report;
    select_tissue(v, {.min_island_mm3 = 0.0}, null_progress(), &report);
    EXPECT_EQ(report.islands.size(), 2u);
}

TEST(Select, AnchorsFromLabelsAndFromTheBorder) {
    auto v = two_blobs();
    for (int j = 0; j < 12; ++j)
        for (int k = 0; k < 12; ++k) v.labels[v.geometry.linear(0, j, k)] = 1;  // a slab on the i = 0 face
    SelectionReport report;
    auto s = select_tissue(v, {.anchor_border = true, .min_island_mm3 = 0.0}, null_progress(), &report);
    EXPECT_EQ(report.anchor_voxels, 144u);
    s = select_tissue(v, {.anchor_labels = {2}, .min_island_mm3 = 0.0}, null_progress(), &report);
    EXPECT_EQ(report.anchor_voxels, 1u);
    EXPECT_TRUE(s.anchors.at(16, 6, 6));
}

TEST(Select, ClearErrors) {
    const auto v = two_blobs();
    try {
        select_tissue(v, {.tissue_labels = {7}});
        FAIL() << "expected an error";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("tissue label 7 does not occur"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("0,1,2"), std::string::npos) << e.what();
    }
    EXPECT_THROW(select_tissue(v, {.tissue_labels = {1}, .cavity_labels = {1}}), InputError);
    EXPECT_THROW(select_tissue(v, {.cavity_labels = {9}}), InputError);
    // Label 0 occurs (it is the background) but is no structure: refused, not simulated as tissue.
    for (const SelectionOptions& zero : {SelectionOptions{.tissue_labels = {0}}, SelectionOptions{.tissue_labels = {1}, .cavity_labels = {0}}}) {
        try {
            select_tissue(v, zero);
            ADD_FAILURE() << "label 0 was accepted";
        } catch (const OptionError& e) {  // options wrong whatever the data: heartprep exits 2 for it
            EXPECT_NE(std::string(e.what()).find("label 0 is the background"), std::string::npos) << e.what();
            EXPECT_EQ(std::string(e.what()).find("--"), std::string::npos) << "libmodel names no flag: " << e.what();
        }
    }
    try {
        select_tissue(v, {.min_island_mm3 = 1e6});
        FAIL() << "expected an error";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("empty selection"), std::string::npos) << e.what();
    }
}

TEST(Phantom, SeptalDefectJoinsTheTwoCavitiesAndItsAbsenceSeparatesThem) {
    // The blood pool (label 2) is one 6-connected component exactly when the VSD is open.
    auto blood_components = [](double vsd_diameter) {
        PhantomOptions o;
        o.vsd_diameter_mm = vsd_diameter;
        const LabelVolume v = make_phantom(o);
        SelectionReport report;
        select_tissue(v, {.tissue_labels = {2}, .min_island_mm3 = 0.0}, null_progress(), &report);
        return report.islands.size();
    };
    EXPECT_EQ(blood_components(8.0), 1u);
    EXPECT_EQ(blood_components(0.0), 2u);
}

TEST(Phantom, MyocardiumIsOnePieceAndShapesHaveTheirVolumes) {
    const LabelVolume heart = make_phantom({});
    SelectionReport report;
    select_tissue(heart, {.min_island_mm3 = 0.0}, null_progress(), &report);
    EXPECT_EQ(report.islands.size(), 1u);

    PhantomOptions sphere{.shape = PhantomShape::sphere, .voxel_mm = 0.5};
    sphere.radius_mm = 10.0;
    const LabelVolume s = make_phantom(sphere);
    select_tissue(s, {.min_island_mm3 = 0.0}, null_progress(), &report);
    const double exact = 4.0 / 3.0 * M_PI * 1000.0;
    EXPECT_NEAR(report.tissue_volume_mm3, exact, 0.01 * exact);

    EXPECT_THROW(make_phantom({.vsd_position = 1.5}), InputError);
    EXPECT_THROW(make_phantom({.wall_mm = -1.0}), InputError);
    PhantomOptions bad_shell{.shape = PhantomShape::shell};
    bad_shell.inner_radius_mm = 30.0;
    EXPECT_THROW(make_phantom(bad_shell), InputError);
}

// -------------------------------------------------------------------------------------------
// Segment names. The names are those of public label sets, whose meaning their papers give:
// HVSMR 2016 (1 myocardium, 2 blood pool), ACDC 2017 (1 RV cavity, 2 myocardium, 3 LV cavity),
// MM-WHS 2017 (myocardium of the left ventricle, left ventricle blood cavity, ascending aorta,
// pulmonary artery), and 3D Slicer's own placeholder names.

TEST(SegmentNames, PublicLabelSetsAreClassifiedByTheirMeaning) {
    for (const char* muscle : {"myocardium", "Myocardium", "LV myocardium", "myocardium of the left ventricle", "Myo",
                               "left ventricular wall", "interventricular septum", "heart muscle"})
        EXPECT_EQ(classify_segment_name(muscle), SegmentKind::heart_muscle) << muscle;
    for (const char* other : {"blood pool", "Blood_pool", "RV cavity", "LV cavity", "left ventricle blood cavity",
                              "ascending aorta", "pulmonary artery", "vessel wall", "aortic wall", "Background", "pericardial fat"})
        EXPECT_EQ(classify_segment_name(other), SegmentKind::not_muscle) << other;
    for (const char* placeholder : {"Segment_1", "Segment 12", "Label 3", "7", ""})
        EXPECT_EQ(classify_segment_name(placeholder), SegmentKind::unnamed) << placeholder;
    for (const char* unclear : {"heart", "left ventricle", "left atrium"})
        EXPECT_EQ(classify_segment_name(unclear), SegmentKind::unclear) << unclear;
}

TEST(SegmentNames, NamesResolveCaseInsensitivelyAndNumbersStayLabels) {
    const SegmentNames acdc = {{1, "RV cavity"}, {2, "Myocardium"}, {3, "LV cavity"}};
    EXPECT_EQ(resolve_label_choice({"myocardium"}, acdc, "--tissue"), std::vector<int>{2});
    EXPECT_EQ(resolve_label_choice({" lv CAVITY ", "rv_cavity"}, acdc, "--cavity"), (std::vector<int>{3, 1}));
    EXPECT_EQ(resolve_label_choice({"3", "Myocardium", "2"}, acdc, "--tissue"), (std::vector<int>{3, 2}));
    // A number is a label even where a segment bears that number as its name.
    EXPECT_EQ(resolve_label_choice({"2"}, {{1, "2"}, {2, "myocardium"}}, "--tissue"), std::vector<int>{2});
    EXPECT_TRUE(resolve_label_choice({}, acdc, "--cavity").empty());
    try {
        resolve_label_choice({"aorta"}, acdc, "--tissue");
        ADD_FAILURE() << "an unknown name must be refused";
    } catch (const InputError& error) {
        EXPECT_STREQ(error.what(), "--tissue 'aorta' names no segment; segments: 1 'RV cavity', 2 'Myocardium', 3 'LV cavity'");
    }
    EXPECT_THROW(resolve_label_choice({"myocardium"}, {}, "--tissue"), InputError);
}

TEST(SegmentNames, DefaultTissueIsLabelOneUnlessItsNameSaysBloodAndAnotherSaysMuscle) {
    std::string note;
    EXPECT_EQ(default_tissue_labels({}, &note), std::vector<int>{1});  // HVSMR: no names
    EXPECT_TRUE(note.empty());
    EXPECT_EQ(default_tissue_labels({{1, "myocardium"}, {2, "blood pool"}}, &note), std::vector<int>{1});
    EXPECT_TRUE(note.empty());
    EXPECT_EQ(default_tissue_labels({{1, "RV cavity"}, {2, "Myocardium"}, {3, "LV cavity"}}, &note), std::vector<int>{2});
    EXPECT_NE(note.find("label 1 'RV cavity' is not heart muscle"), std::string::npos) << note;
    note.clear();
    EXPECT_EQ(default_tissue_labels({{1, "Segment_1"}, {2, "LV myocardium"}, {3, "RV myocardium"}}, &note), (std::vector<int>{2, 3}));
    EXPECT_FALSE(note.empty());
    note.clear();
    // Nothing named as muscle: label 1 stays (and tissue_name_warnings speaks).
    EXPECT_EQ(default_tissue_labels({{1, "blood pool"}, {2, "aorta"}}, &note), std::vector<int>{1});
    EXPECT_TRUE(note.empty());
}

TEST(SegmentNames, WarningsNameTheChoiceAndWhereTheMuscleIs) {
    const SegmentNames hvsmr = {{1, "myocardium"}, {2, "blood pool"}};
    EXPECT_TRUE(tissue_name_warnings({1}, hvsmr).empty());
    EXPECT_TRUE(tissue_name_warnings({1}, {}).empty());
    const auto pool = tissue_name_warnings({2}, hvsmr);
    ASSERT_EQ(pool.size(), 1u);
    EXPECT_NE(pool[0].find("tissue label 2 'blood pool' is not heart muscle by its name ('blood')"), std::string::npos) << pool[0];
    EXPECT_NE(pool[0].find("the heart muscle is segment 1 'myocardium'"), std::string::npos) << pool[0];
    EXPECT_EQ(tissue_name_warnings({1}, {{1, "heart"}}).size(), 1u);
    EXPECT_TRUE(tissue_name_warnings({1}, {{1, "Segment_1"}}).empty());
    EXPECT_EQ(tissue_name_warnings({1}, {{1, "Segment_1"}, {2, "myocardium"}}).size(), 1u);
}

TEST(SegmentNames, MaterialsAreNamedAfterTheirSegment) {
    EXPECT_EQ(material_name(2, {{2, " LV myocardium "}}), "LV myocardium");
    EXPECT_EQ(material_name(1, {}), "myocardium");  // HVSMR's label 1
    EXPECT_EQ(material_name(3, {}), "label_3");
    EXPECT_EQ(material_name(1, {{1, "Segment_1"}}), "myocardium");
    EXPECT_EQ(material_name(1, {{1, "blood pool"}}), "blood pool");
}
