// Landmarks (libmodel/landmarks.h): distance maps against brute force; a ring through a square
// window and grooves between boxes of blood, whose answers are known; the real MM-WHS hearts,
// checked against their label maps; a build's /landmarks, written, read back and inspected.
#include "libmodel/landmarks.h"

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/errors.h"
#include "libmodel/label_conventions.h"
#include "libmodel/select.h"
#include "libmodel/surface.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <random>
#include <set>
#include <tuple>

using namespace heartsim;

namespace {

double brute_distance(const std::vector<Eigen::Vector3d>& centres, const Eigen::Vector3d& p) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& c : centres) best = std::min(best, (c - p).squaredNorm());
    return std::sqrt(best);
}

/// World centres of the voxels of `label` with a 6-neighbour of another label: the nearest voxel
/// of a label to a point outside it is always one of these.
std::vector<Eigen::Vector3d> boundary_centres(const LabelVolume& v, int label) {
    const auto& g = v.geometry;
    std::vector<Eigen::Vector3d> out;
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                if (v.labels[g.linear(i, j, k)] != label) continue;
                bool edge = false;
                for (int a = 0; a < 3; ++a)
                    for (int s : {-1, 1}) {
                        std::array<int, 3> n{i, j, k};
                        n[std::size_t(a)] += s;
                        if (!g.contains(n[0], n[1], n[2]) || v.labels[g.linear(n[0], n[1], n[2])] != label) edge = true;
                    }
                if (edge) out.push_back(g.to_world(Eigen::Vector3d(i, j, k)));
            }
    return out;
}

/// A label map of `dims` voxels of `spacing`, labelled by `label(i, j, k)`.
LabelVolume make_volume(std::array<int, 3> dims, Eigen::Vector3d spacing, const std::function<int(int, int, int)>& label) {
    LabelVolume v;
    v.geometry.dims = dims;
    v.geometry.spacing = spacing;
    v.labels.resize(v.geometry.voxel_count());
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) v.labels[v.geometry.linear(i, j, k)] = label(i, j, k);
    return v;
}

Mask mask_of(const LabelVolume& v, const std::function<bool(int)>& chosen) {
    Mask m;
    m.geometry = v.geometry;
    m.values.resize(v.labels.size());
    for (std::size_t n = 0; n < v.labels.size(); ++n) m.values[n] = chosen(v.labels[n]);
    return m;
}

bool in_box(int i, int j, int k, std::array<int, 3> low, std::array<int, 3> high) {
    return i >= low[0] && j >= low[1] && k >= low[2] && i < high[0] && j < high[1] && k < high[2];
}

/// Every landmark point is one of the surface's vertices.
void expect_on_surface(const Landmarks& landmarks, const TriangleMesh& surface) {
    std::set<std::array<double, 3>> vertices;
    for (const auto& p : surface.positions) vertices.insert({p.x(), p.y(), p.z()});
    for (const Landmark& l : landmarks.found)
        for (const auto& p : l.points) EXPECT_TRUE(vertices.count({p.x(), p.y(), p.z()})) << l.name << " has a point off the surface";
}

/// read_scenario refuses `file`, naming `object` and saying `reason`.
void expect_refusal(const std::filesystem::path& file, const std::string& object, const std::string& reason) {
    try {
        read_scenario(file);
        ADD_FAILURE() << "read " << file << " without complaint";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find(object), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find(reason), std::string::npos) << e.what();
    }
}

}  // namespace

TEST(LandmarkDistanceMap, IsTheExactDistanceToTheNearestVoxelCentreOnAnAnisotropicGrid) {
    VolumeGeometry g;
    g.dims = {19, 14, 11};
    g.spacing = {0.7, 1.1, 1.6};
    std::mt19937 random(7);
    std::vector<std::uint8_t> inside(g.voxel_count(), 0);
    std::vector<Eigen::Vector3d> centres;
    for (int n = 0; n < 12; ++n) {
        const int i = int(random() % 19), j = int(random() % 14), k = int(random() % 11);
        inside[g.linear(i, j, k)] = 1;
        centres.push_back(g.to_world(Eigen::Vector3d(i, j, k)));
    }
    const std::vector<float> d = distance_map(g, inside);
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i)
                ASSERT_NEAR(d[g.linear(i, j, k)], brute_distance(centres, g.to_world(Eigen::Vector3d(i, j, k))), 1e-4);
    EXPECT_TRUE(std::isinf(distance_map(g, std::vector<std::uint8_t>(g.voxel_count(), 0))[0]));
}

TEST(Landmarks, TheRingOfTwoBloodsTouchingThroughASquareWindowIsTheWindowsRim) {
    // Left atrium (2) below, left ventricle (3) above, a wall (1) two voxels thick between them
    // with a 12 x 12 voxel window through which the atrium's blood reaches the ventricle's.
    const Eigen::Vector3d spacing(1.0, 1.0, 1.25);
    const LabelVolume v = make_volume({40, 40, 40}, spacing, [](int i, int j, int k) {
        if (in_box(i, j, k, {14, 14, 18}, {26, 26, 20})) return 2;  // the window, atrium side
        if (in_box(i, j, k, {8, 8, 6}, {32, 32, 18})) return 2;
        if (in_box(i, j, k, {8, 8, 20}, {32, 32, 34})) return 3;
        return in_box(i, j, k, {6, 6, 4}, {34, 34, 36}) ? 1 : 0;
    });
    const TriangleMesh surface = marching_cubes(mask_of(v, [](int l) { return l == 1; }));
    ChamberLabels chambers;
    chambers.left_atrium = 2, chambers.left_ventricle = 3;
    const Landmarks landmarks = find_landmarks(v, chambers, surface);
    expect_on_surface(landmarks, surface);

    const Landmark* ring = landmarks.find("mitral_ring");
    ASSERT_NE(ring, nullptr);
    // The window's faces lie at k = 19.5, its rim at i, j = 13.5 and 25.5: a square 12 mm a side
    // about (19.5, 19.5) mm.
    const Eigen::Vector3d centre(19.5, 19.5, 19.5 * 1.25);
    EXPECT_LT((ring->centre - centre).norm(), 1e-9);
    EXPECT_GT(ring->normal.dot(Eigen::Vector3d::UnitZ()), 1 - 1e-9) << "from the atrium's blood to the ventricle's";
    // The rim's faces lie 5.5 mm (a side's middle) to 5.5·√2 mm (a corner) from the centre.
    EXPECT_GE(ring->diameter_mm, 11.0);
    EXPECT_LE(ring->diameter_mm, 11.0 * std::sqrt(2.0));
    EXPECT_GE(ring->points.size(), 24u);
    double previous = -10;
    for (const auto& p : ring->points) {
        // On the rim: at the window's edge across, half a voxel (and the wall's vertex) from its plane.
        const Eigen::Vector3d r = p - centre;
        const double across = std::max(std::abs(r.x()), std::abs(r.y()));
        EXPECT_NEAR(across, 6.0, 0.5 + 1e-9) << p.transpose();
        EXPECT_LE(std::abs(r.z()), 0.625 + 1e-9) << p.transpose();
        // In order round the centre.
        double angle = std::atan2(r.y(), r.x());
        if (previous > -10 && angle < previous - 1e-9) angle += 2 * std::numbers::pi;
        EXPECT_GE(angle, previous - 1e-9);
        previous = angle;
    }
    EXPECT_NEAR(ring->length_mm, 4 * 12.0, 8.0) << "the perimeter of the 12 mm square, cut at its corners";

    // The groove round the wall's outside lies halfway between the two bloods' voxel centres
    // (k = 17 and k = 20): at k = 18.5. No right heart is labelled: its landmarks are missing.
    const Landmark* groove = landmarks.find("left_av_groove");
    ASSERT_NE(groove, nullptr);
    for (const auto& p : groove->points) EXPECT_NEAR(p.z(), 18.5 * 1.25, 1.25) << p.transpose();
    for (const char* name : {"right_av_groove", "rca_course", "tricuspid_ring", "lad_course", "aortic_ring"}) {
        EXPECT_EQ(landmarks.find(name), nullptr) << name;
        bool listed = false;
        for (const auto& m : landmarks.missing) listed = listed || (m.name == name && m.reason.find("no label") != std::string::npos);
        EXPECT_TRUE(listed) << name << " is listed missing, with the label it lacks";
    }
}

namespace {

/// Two ventricles side by side in one muscle block with a septum between them, the atria above
/// them, apart, and the great arteries apart behind: a heart whose grooves are known.
LabelVolume two_ventricles() {
    return make_volume({50, 40, 64}, {0.9, 0.9, 1.2}, [](int i, int j, int k) {
        if (in_box(i, j, k, {7, 11, 7}, {23, 29, 47})) return 3;   // left ventricle
        if (in_box(i, j, k, {27, 11, 7}, {43, 29, 47})) return 5;  // right ventricle
        if (in_box(i, j, k, {7, 11, 55}, {23, 29, 60})) return 2;  // left atrium
        if (in_box(i, j, k, {27, 11, 55}, {43, 29, 60})) return 4; // right atrium
        if (in_box(i, j, k, {7, 34, 55}, {15, 38, 60})) return 6;  // aorta
        if (in_box(i, j, k, {30, 34, 55}, {38, 38, 60})) return 7; // pulmonary artery
        return in_box(i, j, k, {4, 8, 4}, {46, 32, 50}) ? 1 : 0;
    });
}

}  // namespace

TEST(Landmarks, TheAnteriorDescendingCourseRunsDownTheFrontOverTheSeptum) {
    const LabelVolume v = two_ventricles();
    const TriangleMesh surface = marching_cubes(mask_of(v, [](int l) { return l == 1; }));
    const Landmarks landmarks = find_landmarks(v, chamber_labels_from_names(find_label_convention("mmwhs-ordinal")->names), surface);
    expect_on_surface(landmarks, surface);
    // The septum's middle: halfway between the ventricles' facing voxel centres, i = 22 and 27.
    const double septum_x = 24.5 * 0.9, front_y = 7.5 * 0.9, back_y = 31.5 * 0.9;
    const Landmark* anterior = landmarks.find("interventricular_anterior_groove");
    const Landmark* posterior = landmarks.find("interventricular_posterior_groove");
    const Landmark* lad = landmarks.find("lad_course");
    ASSERT_TRUE(anterior && posterior && lad);
    for (const auto& p : anterior->points) {
        EXPECT_NEAR(p.x(), septum_x, 1.0) << p.transpose();
        EXPECT_LT(p.y(), 0.5 * (front_y + back_y)) << "anterior is towards -y";
    }
    for (const auto& p : posterior->points) EXPECT_GT(p.y(), 0.5 * (front_y + back_y));
    // Down the front face from the base (the atria's side, +z) towards the apex; at its ends it
    // may turn onto the block's top or bottom face, still over the septum and in front.
    const double top_z = 49.5 * 1.2, bottom_z = 3.5 * 1.2;
    for (std::size_t i = 0; i < lad->points.size(); ++i) {
        const auto& p = lad->points[i];
        EXPECT_NEAR(p.x(), septum_x, 1.0) << p.transpose();
        const bool front = std::abs(p.y() - front_y) < 1e-9, cap = std::abs(p.z() - top_z) < 1e-9 || std::abs(p.z() - bottom_z) < 1e-9;
        EXPECT_TRUE(front || (cap && p.y() < 0.5 * (front_y + back_y))) << "on the front face: " << p.transpose();
        if (i && front) EXPECT_LT(p.z(), lad->points[i - 1].z()) << "from base to apex";
    }
    EXPECT_GT(lad->points.front().z(), lad->points.back().z());
    EXPECT_GT(lad->length_mm, 0.75 * (46 - 7) * 1.2) << "along the ventricles' length";
    // The atria are walled off from the ventricles: no ring, said so.
    EXPECT_EQ(landmarks.find("mitral_ring"), nullptr);
    for (const auto& m : landmarks.missing)
        if (m.name == "mitral_ring") EXPECT_NE(m.reason.find("do not touch"), std::string::npos) << m.reason;
}

TEST(Landmarks, ALabelMapWithOneBloodPoolGivesNoneAndSaysWhy) {
    const LabelVolume v = make_volume({20, 20, 20}, {1, 1, 1}, [](int i, int j, int k) {
        return in_box(i, j, k, {6, 6, 6}, {14, 14, 14}) ? 2 : in_box(i, j, k, {4, 4, 4}, {16, 16, 16}) ? 1 : 0;
    });
    const TriangleMesh surface = marching_cubes(mask_of(v, [](int l) { return l == 1; }));
    const ChamberLabels chambers = chamber_labels_from_names(find_label_convention("hvsmr2016")->names);
    const Landmarks landmarks = find_landmarks(v, chambers, surface, {}, "HVSMR 2016 labels one blood pool for every chamber");
    EXPECT_TRUE(landmarks.found.empty());
    ASSERT_EQ(landmarks.missing.size(), landmark_names().size());
    for (const auto& m : landmarks.missing) EXPECT_NE(m.reason.find("HVSMR 2016 labels one blood pool"), std::string::npos) << m.name;
}

namespace {

struct MmwhsCase {
    const char* folder;
    const char* file;
    const char* convention;
};

/// The part of `v` that holds its non-zero labels, with `margin` voxels round them.
LabelVolume crop(const LabelVolume& v, int margin) {
    const auto& g = v.geometry;
    std::array<int, 3> low = g.dims, high{-1, -1, -1};
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i)
                if (v.labels[g.linear(i, j, k)] != 0)
                    low = {std::min(low[0], i), std::min(low[1], j), std::min(low[2], k)},
                    high = {std::max(high[0], i), std::max(high[1], j), std::max(high[2], k)};
    for (int a = 0; a < 3; ++a)
        low[std::size_t(a)] = std::max(0, low[std::size_t(a)] - margin),
        high[std::size_t(a)] = std::min(g.dims[std::size_t(a)] - 1, high[std::size_t(a)] + margin);
    LabelVolume out;
    out.geometry = g;
    out.geometry.dims = {high[0] - low[0] + 1, high[1] - low[1] + 1, high[2] - low[2] + 1};
    out.geometry.origin = g.to_world(Eigen::Vector3d(low[0], low[1], low[2]));
    out.labels.resize(out.geometry.voxel_count());
    for (int k = 0; k < out.geometry.dims[2]; ++k)
        for (int j = 0; j < out.geometry.dims[1]; ++j)
            for (int i = 0; i < out.geometry.dims[0]; ++i)
                out.labels[out.geometry.linear(i, j, k)] = v.labels[g.linear(i + low[0], j + low[1], k + low[2])];
    return out;
}

/// The checks of one heart's landmarks against its label map.
void check_real_heart(const LabelVolume& v, const LabelConvention& c, const TriangleMesh& surface, const Landmarks& landmarks,
                      bool whole_heart) {
    expect_on_surface(landmarks, surface);
    EXPECT_EQ(landmarks.found.size() + landmarks.missing.size(), landmark_names().size());
    for (const auto& m : landmarks.missing) EXPECT_FALSE(m.reason.empty()) << m.name;
    const double voxel = v.geometry.spacing.maxCoeff();
    const auto la = boundary_centres(v, c.left_atrium), lv = boundary_centres(v, c.left_ventricle),
               ra = boundary_centres(v, c.right_atrium), rv = boundary_centres(v, c.right_ventricle);
    // The anterior descending artery runs over the septum's junction: the muscle between it and
    // either cavity is a ventricular wall, at most about 12 mm thick in an adult (the upper limit
    // of normal left ventricular wall thickness), plus the vertex's own step of 1 mm.
    const Landmark* lad = landmarks.find("lad_course");
    ASSERT_NE(lad, nullptr) << "the anterior interventricular groove covers the left ventricle's wall too";
    for (const auto& p : lad->points) {
        EXPECT_LE(brute_distance(lv, p), 13.0) << "lad point " << p.transpose();
        EXPECT_LE(brute_distance(rv, p), 13.0) << "lad point " << p.transpose();
    }
    EXPECT_GE(lad->length_mm, 30.0);
    double lad_lv = 0, lad_rv = 0;
    for (const auto& p : lad->points) lad_lv = std::max(lad_lv, brute_distance(lv, p)), lad_rv = std::max(lad_rv, brute_distance(rv, p));
    std::printf("%s: anterior descending course %zu points, %.1f mm, at most %.1f mm from the left ventricle's blood and %.1f mm "
                "from the right's\n",
                whole_heart ? "walls grown" : "labelled wall", lad->points.size(), lad->length_mm, lad_lv, lad_rv);
    // From base to apex: it ends farther from the atria than it starts.
    EXPECT_GT(brute_distance(la, lad->points.back()), brute_distance(la, lad->points.front()));
    if (!whole_heart) return;
    // The atrioventricular rings lie between atrial and ventricular blood: each point within two
    // voxels of both (a rim face is half a voxel from each; the wall's surface vertex beside it
    // less than a voxel farther).
    const double near = 2.0 * voxel;
    for (const auto& [name, atrium, ventricle] : {std::tuple{"tricuspid_ring", &ra, &rv}, std::tuple{"mitral_ring", &la, &lv}}) {
        const Landmark* ring = landmarks.find(name);
        ASSERT_NE(ring, nullptr) << name;
        double far = 0;
        for (const auto& p : ring->points) {
            EXPECT_LE(brute_distance(*atrium, p), near) << name << " " << p.transpose();
            EXPECT_LE(brute_distance(*ventricle, p), near) << name << " " << p.transpose();
            far = std::max({far, brute_distance(*atrium, p), brute_distance(*ventricle, p)});
        }
        std::printf("%s: %zu points, %.1f mm across, each at most %.2f mm from both bloods' voxel centres (bound %.2f)\n", name,
                    ring->points.size(), ring->diameter_mm, far, near);
    }
    // Anatomy: each atrioventricular valve's ring is wider than its ventricle's outflow ring,
    // and all lie between 10 and 50 mm across.
    const Landmark *tricuspid = landmarks.find("tricuspid_ring"), *mitral = landmarks.find("mitral_ring"),
                   *aortic = landmarks.find("aortic_ring"), *pulmonary = landmarks.find("pulmonary_ring");
    ASSERT_TRUE(tricuspid && mitral && aortic && pulmonary);
    EXPECT_GT(mitral->diameter_mm, aortic->diameter_mm);
    EXPECT_GT(tricuspid->diameter_mm, pulmonary->diameter_mm);
    for (const Landmark* ring : {tricuspid, mitral, aortic, pulmonary}) {
        EXPECT_GT(ring->diameter_mm, 10.0) << ring->name;
        EXPECT_LT(ring->diameter_mm, 50.0) << ring->name;
    }
    // The coronary courses in the atrioventricular grooves lie near both their bloods.
    for (const auto& [name, atrium, ventricle] : {std::tuple{"rca_course", &ra, &rv}, std::tuple{"lcx_course", &la, &lv}}) {
        const Landmark* course = landmarks.find(name);
        ASSERT_NE(course, nullptr) << name;
        for (const auto& p : course->points) {
            EXPECT_LE(brute_distance(*atrium, p), 13.0) << name << " " << p.transpose();
            EXPECT_LE(brute_distance(*ventricle, p), 13.0) << name << " " << p.transpose();
        }
    }
}

}  // namespace

TEST(LandmarkRealHearts, EachMmwhsHeartsLandmarksLieWhereItsLabelMapSays) {
    const auto dir = test::real_data_dir();
    for (const MmwhsCase& c : {MmwhsCase{"mmwhs_ct1002", "ct_train_1002_label.nii.gz", "mmwhs"},
                               MmwhsCase{"mmwhs_wh", "mmwhs_wh-label.nii.gz", "mmwhs-ordinal"}}) {
        SCOPED_TRACE(c.folder);
        if (dir.empty() || !std::filesystem::exists(dir / c.folder / c.file)) GTEST_SKIP() << "real data absent (../shared/data/real): " << c.folder;
        const LabelVolume v = crop(read_label_volume(dir / c.folder / c.file), 12);
        const LabelConvention& convention = *find_label_convention(c.convention);
        const ChamberLabels chambers = chamber_labels_from_names(convention.names);
        // The labelled myocardium alone (MM-WHS: the left ventricle's wall), as built without walls.
        SelectionOptions select;
        select.tissue_labels = {convention.myocardium};
        const Mask myocardium = select_tissue(v, select).tissue;
        const TriangleMesh wall = extract_surface(myocardium);
        check_real_heart(v, convention, wall, find_landmarks(v, chambers, wall), false);
        // The whole heart: a wall 2.5 mm thick grown into the background round every blood label.
        Mask heart = myocardium;
        std::vector<std::uint8_t> blood(v.labels.size());
        for (std::size_t n = 0; n < blood.size(); ++n) blood[n] = v.labels[n] != 0 && v.labels[n] != convention.myocardium;
        const std::vector<float> d = distance_map(v.geometry, blood);
        for (std::size_t n = 0; n < blood.size(); ++n)
            if (v.labels[n] == 0 && d[n] <= 2.5f) heart.values[n] = 1;
        const TriangleMesh whole = extract_surface(heart);
        check_real_heart(v, convention, whole, find_landmarks(v, chambers, whole), true);
    }
}

TEST(LandmarkBuild, ABuildStoresTheLandmarksOnItsSurfaceAndInspectListsThem) {
    test::TempDir dir;
    const auto input = dir / "two_ventricles.nrrd";
    write_label_volume(input, two_ventricles());
    const auto output = dir / "two_ventricles.h5";
    const auto build = test::run_command(test::quoted(HEARTPREP_EXE) + " build " + test::quoted(input.string()) +
                                         " --labels mmwhs-ordinal -q -o " + test::quoted(output.string()));
    ASSERT_EQ(build.exit_code, 0) << build.output;
    const Scenario s = read_scenario(output);
    ASSERT_TRUE(s.landmarks && s.visual);
    const Landmark* lad = s.landmarks->find("lad_course");
    ASSERT_NE(lad, nullptr);
    for (const auto& p : lad->points) {
        double nearest = 1e9;
        for (const auto& x : s.visual->positions) nearest = std::min(nearest, (Eigen::Vector3d(x[0], x[1], x[2]) - p).norm());
        EXPECT_LE(nearest, 1e-4) << "a vertex of /visual, to float32 rounding";
    }
    const auto inspect = test::run_command(test::quoted(HEARTPREP_EXE) + " inspect --json " + test::quoted(output.string()));
    ASSERT_EQ(inspect.exit_code, 0) << inspect.output;
    EXPECT_NE(inspect.output.find("\"lad_course\""), std::string::npos);
    EXPECT_NE(inspect.output.find("\"missing\""), std::string::npos);

    // Written and read back as they were; a ring without a unit normal, or a landmark both found
    // and missing, is refused by name.
    write_scenario(dir / "copy.h5", s);
    const Scenario back = read_scenario(dir / "copy.h5");
    ASSERT_TRUE(back.landmarks);
    ASSERT_EQ(back.landmarks->found.size(), s.landmarks->found.size());
    for (std::size_t i = 0; i < s.landmarks->found.size(); ++i) {
        const Landmark &a = s.landmarks->found[i], &b = back.landmarks->found[i];
        EXPECT_EQ(a.name, b.name);
        EXPECT_EQ(a.kind, b.kind);
        EXPECT_EQ(a.between, b.between);
        EXPECT_EQ(a.points, b.points);
        EXPECT_EQ(a.length_mm, b.length_mm);
        EXPECT_EQ(a.coverage, b.coverage);
    }
    ASSERT_EQ(back.landmarks->missing.size(), s.landmarks->missing.size());
    for (std::size_t i = 0; i < s.landmarks->missing.size(); ++i) {
        EXPECT_EQ(back.landmarks->missing[i].name, s.landmarks->missing[i].name);
        EXPECT_EQ(back.landmarks->missing[i].reason, s.landmarks->missing[i].reason);
    }
    Scenario damaged = s;
    Landmark ring = *lad;
    ring.name = "mitral_ring";
    ring.kind = LandmarkKind::ring;
    ring.normal = {0, 0, 1};
    ring.diameter_mm = 20;
    damaged.landmarks->found.push_back(ring);
    write_scenario(dir / "both.h5", damaged);
    expect_refusal(dir / "both.h5", "landmarks/missing", "both found and missing");
    std::erase_if(damaged.landmarks->missing, [](const MissingLandmark& m) { return m.name == "mitral_ring"; });
    write_scenario(dir / "ring.h5", damaged);
    EXPECT_NO_THROW(read_scenario(dir / "ring.h5"));
    damaged.landmarks->found.back().normal = {0, 0, 2};
    write_scenario(dir / "normal.h5", damaged);
    expect_refusal(dir / "normal.h5", "landmarks/mitral_ring", "unit vector");

    // One blood pool (HVSMR 2016's labels): every landmark missing, and the reason in inspect.
    const auto pool = dir / "pool.nrrd";
    write_label_volume(pool, make_volume({24, 24, 24}, {1, 1, 1}, [](int i, int j, int k) {
                           return in_box(i, j, k, {7, 7, 7}, {17, 17, 17}) ? 2 : in_box(i, j, k, {4, 4, 4}, {20, 20, 20}) ? 1 : 0;
                       }));
    const auto pool_out = dir / "pool.h5";
    const auto built = test::run_command(test::quoted(HEARTPREP_EXE) + " build " + test::quoted(pool.string()) +
                                         " --labels hvsmr2016 -q -o " + test::quoted(pool_out.string()));
    ASSERT_EQ(built.exit_code, 0) << built.output;
    const Scenario p = read_scenario(pool_out);
    ASSERT_TRUE(p.landmarks);
    EXPECT_TRUE(p.landmarks->found.empty());
    EXPECT_EQ(p.landmarks->missing.size(), landmark_names().size());
    const auto table = test::run_command(test::quoted(HEARTPREP_EXE) + " inspect " + test::quoted(pool_out.string()));
    EXPECT_NE(table.output.find("mitral_ring: missing: HVSMR 2016 labels one blood pool for every chamber"), std::string::npos) << table.output;
}

TEST(LandmarkRealHearts, AnHvsmrHeartHasOneBloodPoolSoEveryLandmarkIsMissingWithTheReason) {
    const auto input = test::real_case("hvsmr16_pat1");
    if (input.empty()) GTEST_SKIP() << "real data absent (../shared/data/real/hvsmr16_pat1)";
    const LabelVolume v = read_label_volume(input);
    const LabelConvention& hvsmr = *find_label_convention("hvsmr2016");
    const ChamberLabels chambers = chamber_labels_from_names(hvsmr.names);
    EXPECT_EQ(chambers.left_ventricle, 0);
    EXPECT_EQ(chambers.right_ventricle, 0);
    const TriangleMesh surface = marching_cubes(mask_of(v, [&](int l) { return l == hvsmr.myocardium; }));
    const Landmarks landmarks = find_landmarks(v, chambers, surface, {}, "HVSMR 2016 labels one blood pool for every chamber");
    EXPECT_TRUE(landmarks.found.empty());
    EXPECT_EQ(landmarks.missing.size(), landmark_names().size());
    for (const auto& m : landmarks.missing) EXPECT_NE(m.reason.find("one blood pool"), std::string::npos) << m.name << ": " << m.reason;
}
