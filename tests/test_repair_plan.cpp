// `heartsim plan-repair` (runtime/surgery/repair_plan.h): the patch and stitches planned over a septal
// defect, checked against the synthetic two-chamber block (whose septum's faces are known planes),
// the CSV read back as `heartsim run --trajectory` reads it, every real heart with a VSD built into
// it, and the command's errors and help.
#include "defect_block_scenario.h"
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/label_conventions.h"
#include "runtime/view/png.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/core/trajectory.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <regex>

using namespace heartsim;
using namespace heartsim::test::defect_block;
namespace fs = std::filesystem;
using test::quoted;

namespace {

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

/// The block (septum 6 mm thick across local x at x = 0) built by heartprep, once per test
/// program: with an 8 mm VSD through the septum at local (0.5, −4, 6) mm, with an ASD there (the
/// block's pools stand for the atria then), and intact.
struct BlockScenarios {
    test::TempDir dir;
    Block block = make_block();
    fs::path with_defect = dir / "vsd.h5", atrial = dir / "asd.h5", intact = dir / "intact.h5";
    static constexpr double diameter_mm = 8.0;
    BlockScenarios() {
        build_block_scenario(block, dir / "block.nrrd", with_defect, "vsd", 4000);
        build_block_scenario(block, dir / "block.nrrd", atrial, "asd", 4000);
        build_block_scenario(block, dir / "block.nrrd", intact, "", 4000);
    }
};

const BlockScenarios& block_scenarios() {
    static const BlockScenarios built;
    return built;
}

/// The angle of `p` round the line through `centre` along unit `axis`, from `first` (across the
/// axis), counter-clockwise seen from the side `axis` points to, degrees in [0, 360).
double angle_round(const Eigen::Vector3d& p, const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, const Eigen::Vector3d& first) {
    const Eigen::Vector3d d = p - centre - (p - centre).dot(axis) * axis;
    const double a = std::atan2(axis.cross(first).dot(d), first.dot(d)) * 180.0 / std::numbers::pi;
    return a < 0 ? a + 360.0 : a;
}

/// The posteroinferior direction (0, 1, −1)/√2 of LPS made perpendicular to the unit `axis`.
Eigen::Vector3d posteroinferior_across(const Eigen::Vector3d& axis) {
    const Eigen::Vector3d p = Eigen::Vector3d(0, 1, -1).normalized();
    return (p - p.dot(axis) * axis).normalized();
}

/// A tricuspid and an aortic ring of 48 points (radius 6 mm) in the plane across the defect's axis
/// through its centre: the tricuspid ring's point nearest the rim (radius D/2) 3 mm beyond it
/// along `toward` (unit, across the axis), the aortic ring's 4 mm beyond it along −toward. The
/// zone's middle (libmodel/surgery/conduction_zone.h: t − a + p) is then 2·toward + p, and
/// `toward` itself where it is p, the posteroinferior direction across the axis.
Landmarks rings_toward(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, double diameter_mm, const Eigen::Vector3d& toward) {
    const Eigen::Vector3d v = axis.cross(toward);
    auto ring = [&](const std::string& name, const Eigen::Vector3d& middle, const Eigen::Vector3d& u) {
        Landmark l;
        l.name = name;
        l.kind = LandmarkKind::ring;
        for (int k = 0; k < 48; ++k) {
            const double a = 2.0 * std::numbers::pi * k / 48.0;
            l.points.push_back(middle + 6.0 * (std::cos(a) * u + std::sin(a) * v));
        }
        l.centre = middle, l.normal = axis, l.diameter_mm = 12.0;
        return l;
    };
    const double r = 0.5 * diameter_mm;
    Landmarks rings;
    rings.found.push_back(ring("tricuspid_ring", centre + (r + 3.0 + 6.0) * toward, -toward));  // its first point nearest the rim
    rings.found.push_back(ring("aortic_ring", centre - (r + 4.0 + 6.0) * toward, toward));
    return rings;
}

}  // namespace

// On the block the septum's faces are the planes x = ±3 mm (local): every stitch site lies on the
// face of the chosen side within a voxel, on the circle of radius D/2 + rim round the defect's
// axis, the sites evenly spaced; the patch sits on the axis, facing the wall, half its thickness
// off the face; the wall measures 6 mm.
TEST(RepairPlan, OnTheBlockTheStitchesLieOnTheSeptumsFaceRoundTheOpening) {
    const BlockScenarios& built = block_scenarios();
    const Block& block = built.block;
    const Scenario scenario = read_scenario(built.with_defect);
    const double voxel = block.volume.geometry.spacing.maxCoeff(), half_wall = 0.5 * block.septum_mm;
    const RepairPlan plan = plan_repair(scenario, {.stitches = 8, .rim_mm = 2.0});
    ASSERT_EQ(plan.stitches.size(), 8u);
    // The side: the face whose outward normal (±x of the block, in the world) points more to the
    // patient's right and anterior.
    const Eigen::Vector3d septum_normal = block.world(Eigen::Vector3d::UnitX());
    const Eigen::Vector3d right_anterior = Eigen::Vector3d(-1, -1, 0).normalized();
    const double face_side = septum_normal.dot(right_anterior) > 0 ? 1.0 : -1.0;  // the right face is at local x = face_side · 3
    EXPECT_GT(plan.outward.dot(face_side * septum_normal), std::cos(3.0 * std::numbers::pi / 180.0));
    EXPECT_TRUE(plan.on_right);
    EXPECT_NEAR(plan.stitch_radius_mm, 0.5 * BlockScenarios::diameter_mm + 2.0, 1e-12);
    const Eigen::Vector3d& centre = scenario.source.defect_centre;
    const Eigen::Vector3d axis = scenario.source.defect_axis.normalized();
    const Eigen::Vector3d first = (plan.stitches[0].site - centre - (plan.stitches[0].site - centre).dot(axis) * axis).normalized();
    // Stitch 1 at the circle's most superior point: its direction across the axis is superior (+z)
    // made perpendicular to the axis.
    const Eigen::Vector3d superior = (Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ().dot(axis) * axis).normalized();
    EXPECT_GT(first.dot(superior), 1.0 - 1e-9);
    for (std::size_t k = 0; k < plan.stitches.size(); ++k) {
        SCOPED_TRACE("stitch " + std::to_string(k + 1));
        const Eigen::Vector3d site = plan.stitches[k].site;
        const Eigen::Vector3d local = block.rotation.transpose() * site;
        EXPECT_NEAR(local.x(), face_side * half_wall, voxel);  // on the right face
        const Eigen::Vector3d off_axis = site - centre - (site - centre).dot(axis) * axis;
        EXPECT_NEAR(off_axis.norm(), 0.5 * BlockScenarios::diameter_mm + 2.0, 1e-6);
        const double turn = angle_round(site, centre, plan.outward, first) - 360.0 * double(k) / 8.0;
        EXPECT_NEAR(std::remainder(turn, 360.0), 0.0, 1e-6);
        EXPECT_GT((site - centre).dot(plan.outward), 0.0);  // on the chosen side of mid-wall
        EXPECT_NEAR(plan.stitches[k].wall_mm, block.septum_mm, 2 * voxel);
    }
    EXPECT_NEAR(plan.wall_mm, block.septum_mm, voxel);
    // The patch: on the axis, facing the wall (along −outward), its underside on the face.
    const Eigen::Vector3d from_centre = plan.patch_centre - centre;
    EXPECT_LT((from_centre - from_centre.dot(axis) * axis).norm(), 1e-6);
    EXPECT_GT(plan.patch_facing.dot(-face_side * septum_normal), std::cos(3.0 * std::numbers::pi / 180.0));
    EXPECT_NEAR((block.rotation.transpose() * plan.patch_centre).x(), face_side * (half_wall + 0.5 * plan.patch_thickness_mm), voxel);
    EXPECT_NEAR(plan.patch_diameter_mm, BlockScenarios::diameter_mm + 2.0 * (2.0 + 2.0), 1e-12);
    EXPECT_LT(plan.fit_residual_mm, voxel);
    EXPECT_TRUE((plan.patch_orientation * Eigen::Vector3d::UnitZ()).isApprox(plan.patch_facing, 1e-9));
    EXPECT_TRUE((plan.needle_orientation * Eigen::Vector3d::UnitZ()).isApprox(plan.outward, 1e-9));
}

// --side: right and left are the two sides, a and b the axis's tail and head; the sites of the
// left repair lie on the block's other face.
TEST(RepairPlan, TheSideRuleTakesTheRightAnteriorFaceAndTheOptionTurnsIt) {
    const BlockScenarios& built = block_scenarios();
    const Scenario scenario = read_scenario(built.with_defect);
    const Eigen::Vector3d axis = scenario.source.defect_axis.normalized();
    std::map<RepairSide, RepairPlan> plans;
    for (RepairSide side : {RepairSide::right, RepairSide::left, RepairSide::a, RepairSide::b})
        plans.emplace(side, plan_repair(scenario, {.side = side}));
    EXPECT_TRUE(plans.at(RepairSide::a).outward.isApprox(-axis, 1e-12));
    EXPECT_TRUE(plans.at(RepairSide::b).outward.isApprox(axis, 1e-12));
    EXPECT_TRUE(plans.at(RepairSide::left).outward.isApprox(-plans.at(RepairSide::right).outward, 1e-12));
    const Eigen::Vector3d right_anterior = Eigen::Vector3d(-1, -1, 0).normalized();
    EXPECT_GT(plans.at(RepairSide::right).outward.dot(right_anterior), plans.at(RepairSide::left).outward.dot(right_anterior));
    EXPECT_TRUE(plans.at(RepairSide::right).on_right);
    EXPECT_FALSE(plans.at(RepairSide::left).on_right);
    EXPECT_NE(plans.at(RepairSide::a).on_right, plans.at(RepairSide::b).on_right);
    // An atrial defect goes on the right atrium's side by the same rule, and the plan says so.
    test::TempDir dir;
    const auto r = heartsim_command("plan-repair " + quoted(built.atrial) + " -o " + quoted(dir / "asd.csv"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("the right atrium's side, from which a surgeon closes an atrial septal defect"), std::string::npos) << r.output;
    const RepairPlan atrial = plan_repair(read_scenario(built.atrial));
    EXPECT_GT(atrial.outward.dot(plans.at(RepairSide::right).outward), 0.99);
    const double voxel = built.block.volume.geometry.spacing.maxCoeff();
    for (const auto& [side, plan] : plans) {
        SCOPED_TRACE(to_string(side));
        const double face = (built.block.rotation.transpose() * plan.outward).x() > 0 ? 1.0 : -1.0;
        for (const RepairStitch& s : plan.stitches) EXPECT_NEAR((built.block.rotation.transpose() * s.site).x(), face * 3.0, voxel);
    }
}

// The view plan-repair prints, `--clip defect --look-at X,Y,Z,D`: centred midway between the
// defect's centre and the patch's, at the distance where the patch's diameter spans two thirds of
// the picture's height through the camera's 30° field of view. Played for 30 ms (the patch laid at
// 0 ms) and drawn: the patch, edge on in the section across the opening, is a strip of its
// diameter, measured in the picture along its longest extent.
TEST(RepairPlan, TheViewItPrintsFramesThePatchAcrossTheOpening) {
    const BlockScenarios& built = block_scenarios();
    test::TempDir dir;
    const fs::path csv = dir / "repair.csv", picture = dir / "repair.png";
    const auto r = heartsim_command("plan-repair " + quoted(built.with_defect) + " -o " + quoted(csv));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    std::smatch m;
    const std::string number = "(-?[0-9]+\\.[0-9])";
    ASSERT_TRUE(std::regex_search(r.output, m, std::regex("see it +add --clip defect --look-at " + number + "," + number + "," + number + "," +
                                                          number + " ")))
        << r.output;
    const Eigen::Vector3d point(std::stod(m[1]), std::stod(m[2]), std::stod(m[3]));
    const double distance = std::stod(m[4]);
    const RepairPlan plan = plan_repair(read_scenario(built.with_defect));
    EXPECT_LT((point - 0.5 * (plan.defect_centre + plan.patch_centre)).norm(), 0.09) << r.output;
    const double tan_half = std::tan(15.0 * std::numbers::pi / 180.0);  // Camera's 30° vertical field of view
    EXPECT_NEAR(plan.patch_diameter_mm / (2.0 * distance * tan_half), 2.0 / 3.0, 0.01) << r.output;

    const int width = 480, height = 360;
    const auto run = heartsim_command("run " + quoted(built.with_defect) + " --headless --backend cpu --trajectory " + quoted(csv) +
                                      " --seconds 0.03 --size " + std::to_string(width) + "x" + std::to_string(height) +
                                      " --clip defect --look-at " + std::string(m[1]) + "," + std::string(m[2]) + "," + std::string(m[3]) +
                                      "," + std::string(m[4]) + " --screenshot " + quoted(picture));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    ASSERT_NE(run.output.find("patch laid"), std::string::npos) << run.output;
    // The patch's pixels (pericardium's colour, lit: green 0.96 of red, blue 0.78 to 0.95 of it).
    const Image image = read_png(picture);
    std::vector<Eigen::Vector2d> patch;
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x) {
            const std::uint8_t* c = &image.pixels[std::size_t(image.channels) * (std::size_t(y) * std::size_t(image.width) + std::size_t(x))];
            const double red = c[0], green = c[1], blue = c[2];
            if (red > 50 && std::abs(green / red - 0.957) < 0.04 && blue / red > 0.78 && blue / red < 0.95 && blue < green)
                patch.emplace_back(x + 0.5, y + 0.5);
        }
    ASSERT_GT(patch.size(), 100u) << "the patch shows";
    // Its longest extent: along the principal axis of its pixels.
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& p : patch) mean += p;
    mean /= double(patch.size());
    Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
    for (const auto& p : patch) covariance += (p - mean) * (p - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(covariance);
    const Eigen::Vector2d along = solver.eigenvectors().col(1);
    double low = 1e9, high = -1e9;
    for (const auto& p : patch) low = std::min(low, (p - mean).dot(along)), high = std::max(high, (p - mean).dot(along));
    const double seen = high - low, projected = plan.patch_diameter_mm / (2.0 * distance * tan_half) * height;
    std::printf("  the patch %.1f mm across at %.1f mm: projects to %.1f px, seen %.1f px long (%.1f %% of the %d px height)\n",
                plan.patch_diameter_mm, distance, projected, seen, 100.0 * seen / height, height);
    EXPECT_NEAR(seen, projected, 0.12 * projected);
    EXPECT_NEAR(mean.x(), 0.5 * width, 0.1 * height) << "the patch in the middle of the picture";
    EXPECT_NEAR(mean.y(), 0.5 * height, 0.1 * height) << "the patch in the middle of the picture";
}

// The CSV is what the plan made, read back as `heartsim run --trajectory` reads it: hand 0 lays
// the patch once, at 0 ms; hand 1's needle presses once per stitch, at the site, 60 + 220·k ms
// (after the patch's 20 ms, 40 ms of approach; each stitch 40 + 150 + 30 ms), and lets go 150 ms
// later; the printed --seconds covers the gesture.
TEST(RepairPlan, TheCsvHoldsOnePatchLayAndANeedlePressPerStitch) {
    const BlockScenarios& built = block_scenarios();
    test::TempDir dir;
    const fs::path csv = dir / "repair.csv";
    const auto r = heartsim_command("plan-repair " + quoted(built.with_defect) + " -o " + quoted(csv) + " --stitches=6");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    for (const char* word : {"side        right", "wall ", "patch ", "run it      heartsim run", "--clip defect"})
        EXPECT_NE(r.output.find(word), std::string::npos) << word << "\n" << r.output;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(r.output, m, std::regex("--seconds ([0-9.]+)"))) << r.output;
    const double seconds = std::stod(m[1]);
    const RepairPlan plan = plan_repair(read_scenario(built.with_defect), {.stitches = 6});
    const Trajectory trajectory = read_trajectory(csv);
    ASSERT_EQ(trajectory.keyframes.size(), plan.trajectory.keyframes.size());
    struct Press {
        double time_ms;
        InstrumentKind kind;
        Eigen::Vector3d position;
        Eigen::Quaterniond orientation;
        Eigen::Vector3d semi_axes;
    };
    std::map<int, std::vector<Press>> presses;
    std::map<int, std::vector<double>> releases;
    std::map<int, bool> held;
    double last = 0;
    for (const InstrumentKeyframe& k : trajectory.keyframes) {
        if (k.grab && !held[k.hand]) presses[k.hand].push_back({k.time_ms, k.kind, k.pose.position, k.pose.orientation, k.semi_axes});
        if (!k.grab && held[k.hand]) releases[k.hand].push_back(k.time_ms);
        held[k.hand] = k.grab;
        last = std::max(last, k.time_ms);
    }
    ASSERT_EQ(presses[0].size(), 1u);
    EXPECT_EQ(presses[0][0].kind, InstrumentKind::patch);
    EXPECT_EQ(presses[0][0].time_ms, 0.0);
    EXPECT_TRUE(presses[0][0].position.isApprox(plan.patch_centre, 1e-12));
    EXPECT_TRUE((presses[0][0].orientation * Eigen::Vector3d::UnitZ()).isApprox(plan.patch_facing, 1e-9));
    EXPECT_NEAR(presses[0][0].semi_axes.x(), 0.5 * plan.patch_diameter_mm, 1e-12);
    EXPECT_NEAR(presses[0][0].semi_axes.z(), 0.25, 1e-12);
    ASSERT_EQ(presses[1].size(), 6u);
    ASSERT_EQ(releases[1].size(), 6u);
    for (std::size_t k = 0; k < 6; ++k) {
        SCOPED_TRACE("stitch " + std::to_string(k + 1));
        EXPECT_EQ(presses[1][k].kind, InstrumentKind::needle);
        EXPECT_DOUBLE_EQ(presses[1][k].time_ms, 60.0 + 220.0 * double(k));
        EXPECT_DOUBLE_EQ(releases[1][k], presses[1][k].time_ms + 150.0);
        EXPECT_TRUE(presses[1][k].position.isApprox(plan.stitches[k].site, 1e-12));
        EXPECT_TRUE((presses[1][k].orientation * Eigen::Vector3d::UnitZ()).isApprox(plan.outward, 1e-9));
        EXPECT_EQ(presses[1][k].semi_axes, Eigen::Vector3d(0.25, 0.25, 6.0));
        // 40 ms before the press the needle was 4 mm outside the site, and 15 ms after its release
        // it is there again: drawn straight back out along its shaft before it goes across to the
        // next site, never through the rim between them.
        const InstrumentKeyframe before = trajectory.at(1, presses[1][k].time_ms - 40.0);
        EXPECT_TRUE(before.pose.position.isApprox(plan.stitches[k].site + 4.0 * plan.outward, 1e-9));
        const InstrumentKeyframe out = trajectory.at(1, releases[1][k] + 15.0);
        EXPECT_TRUE(out.pose.position.isApprox(plan.stitches[k].site + 4.0 * plan.outward, 1e-9));
        const InstrumentKeyframe halfway_out = trajectory.at(1, releases[1][k] + 7.5);
        EXPECT_NEAR((halfway_out.pose.position - plan.stitches[k].site).dot(plan.outward), 2.0, 1e-9);
        EXPECT_NEAR((halfway_out.pose.position - plan.stitches[k].site - 2.0 * plan.outward).norm(), 0.0, 1e-9);
    }
    // The last stitch's release, 30 ms back out, 300 ms to settle.
    EXPECT_DOUBLE_EQ(last, releases[1].back() + 30.0 + 300.0);
    EXPECT_DOUBLE_EQ(plan.end_ms, last);
    EXPECT_GE(1000.0 * seconds, last);
    EXPECT_LT(1000.0 * seconds, last + 100.0 + 1e-9);
}

// Every real heart present, a 10 mm VSD built into it by heartprep (at a septum point on the
// HVSMR hearts, which label both ventricles' blood alike; found on the MM-WHS hearts): plan-repair
// finds all its stitch sites (by default one every 3 mm round the rim; eight, 45° apart, for the
// label map's check, which a site on a trabecula or at the septum's crest would fail), each on the
// chosen side of mid-wall, on the boundary between the myocardium and that side's blood in the
// label map. The side is the right ventricle's unless its rim lies more than 4 mm off a plane and
// the left's does not, and the plan says which and why.
TEST(RepairPlan, EveryRealHeartWithAVsdGetsAllItsStitches) {
    const std::vector<test::RealCase> real = test::real_cases();
    if (real.empty()) GTEST_SKIP() << "real data absent (../shared/data/real): nothing to plan on";
    const std::map<std::string, std::string> septum_points = {{"hvsmr16_pat0", "40.7,-14.4,-10.4"},
                                                              {"hvsmr16_pat1", "11.4,-25.6,5.2"},
                                                              {"hvsmr16_pat5", "26.8,-17.3,-4.9"},
                                                              {"hvsmr16_pat6", "26.9,-12.1,-20.0"}};
    test::TempDir dir;
    for (const test::RealCase& c : real) {
        SCOPED_TRACE(c.name);
        const auto point = septum_points.find(c.name);
        if (c.label_options.empty() && point == septum_points.end()) {
            std::printf("%s: no septum point known for this HVSMR case: skipped\n", c.name.c_str());
            continue;
        }
        const fs::path scenario = dir / (c.name + ".h5"), csv = dir / (c.name + ".csv");
        const std::string at = point == septum_points.end() ? "" : " --at=" + point->second;
        const auto build = test::heartprep("build " + quoted(c.label_map) + " -o " + quoted(scenario) + " --defect vsd" + at +
                                           " --particles 3000 -q" + c.label_options);
        ASSERT_EQ(build.exit_code, 0) << build.output;
        const auto r = heartsim_command("plan-repair " + quoted(scenario) + " -o " + quoted(csv) + " --stitches=8");
        ASSERT_EQ(r.exit_code, 0) << r.output;
        const Scenario read = read_scenario(scenario);
        const RepairPlan by_default = plan_repair(read);
        EXPECT_EQ(by_default.stitches.size(), std::size_t(std::ceil(2.0 * std::numbers::pi * by_default.stitch_radius_mm / 3.0)));
        const std::size_t stitches = 8;
        const RepairPlan plan = plan_repair(read, {.stitches = int(stitches)});
        // The automatic side, by its rule, from each side's rim where 36 lines enter it (plans of 36 stitches).
        const RepairPlan right = plan_repair(read, {.side = RepairSide::right, .stitches = 36});
        const RepairPlan left = plan_repair(read, {.side = RepairSide::left, .stitches = 36});
        const bool rough = right.fit_residual_mm > 4.0 && left.fit_residual_mm <= 4.0;
        EXPECT_DOUBLE_EQ(plan.right_residual_mm, right.fit_residual_mm);
        EXPECT_DOUBLE_EQ(plan.left_residual_mm, left.fit_residual_mm);
        EXPECT_EQ(plan.on_right, !rough) << r.output;
        EXPECT_TRUE(plan.outward.isApprox((rough ? left : right).outward, 1e-12));
        EXPECT_NE(r.output.find(rough ? "the left ventricle's side" : "the right ventricle's side"), std::string::npos) << r.output;
        if (rough) {
            EXPECT_NE(r.output.find("closed from the left"), std::string::npos) << r.output;
        }
        ASSERT_EQ(plan.stitches.size(), stitches);
        for (const RepairStitch& s : plan.stitches) EXPECT_GT((s.site - plan.defect_centre).dot(plan.outward), 0.0) << r.output;
        // Against the label map (the opening, 5 mm round the axis, leaves the label at 7 mm as it
        // was) with the walls heartprep grows where it shows only blood (libmodel/walls.h, its
        // defaults): 2 mm outward of each site lies the chosen side's blood (the blood pool where the
        // chambers are not labelled apart), 1 mm inward the myocardium or, where the septum meets
        // the right ventricle's free wall, that grown wall.
        const std::string convention_name = c.label_options.empty() ? "hvsmr2016" : c.label_options.substr(c.label_options.rfind(' ') + 1);
        const LabelConvention& convention = *find_label_convention(convention_name);
        LabelVolume labels = read_label_volume(c.label_map);
        const std::vector<WallStructure> walls =
            convention_walls(convention, WallThicknesses{}, *std::max_element(labels.labels.begin(), labels.labels.end()) + 1);
        grow_walls(labels, walls);
        std::vector<int> wall_labels{convention.myocardium};
        for (const WallStructure& w : walls) wall_labels.push_back(w.wall_label);
        const Eigen::Matrix4d to_voxel = labels.geometry.voxel_to_world().inverse();
        auto label_at = [&](const Eigen::Vector3d& p) {
            const Eigen::Vector4d v = to_voxel * p.homogeneous();
            const int i = int(std::lround(v.x())), j = int(std::lround(v.y())), k = int(std::lround(v.z()));
            return labels.geometry.contains(i, j, k) ? labels.labels[labels.geometry.linear(i, j, k)] : -1;
        };
        const int chamber = rough ? convention.left_ventricle : convention.right_ventricle;
        const std::vector<int> side_blood = chamber != 0 ? std::vector<int>{chamber} : convention.blood;
        for (std::size_t k = 0; k < plan.stitches.size(); ++k) {
            const Eigen::Vector3d& site = plan.stitches[k].site;
            const int outside = label_at(site + 2.0 * plan.outward), inside = label_at(site - 1.0 * plan.outward);
            EXPECT_NE(std::find(side_blood.begin(), side_blood.end(), outside), side_blood.end()) << "stitch " << k + 1 << ": " << outside;
            EXPECT_NE(std::find(wall_labels.begin(), wall_labels.end(), inside), wall_labels.end()) << "stitch " << k + 1 << ": " << inside;
        }
        std::size_t presses = 0;
        bool held = false;
        for (const InstrumentKeyframe& k : read_trajectory(csv).keyframes)
            if (k.hand == 1) presses += k.grab && !held, held = k.grab;
        EXPECT_EQ(presses, stitches);
    }
}

// The block's defect given rings that make it perimembranous, its conduction zone's middle the
// posteroinferior direction p across the axis (rings_toward): 12 stitches, one every 30° from
// stitch 1 (at angle 0), p at angle φ. With the zone off every stitch lies on the circle of
// D/2 + 2 mm, inside the zone's band (D/2 + 3 mm), and those within 60° of p bite it; with it on,
// those within 70° (the arc and its 10° margin) lie at D/2 + 4.5 mm and none bites it.
TEST(RepairPlan, OnAPerimembranousDefectTheStitchesSpareTheConductionZone) {
    const BlockScenarios& built = block_scenarios();
    Scenario scenario = read_scenario(built.with_defect);
    const Eigen::Vector3d& centre = scenario.source.defect_centre;
    const Eigen::Vector3d axis = scenario.source.defect_axis.normalized();
    const double d = BlockScenarios::diameter_mm;
    const Eigen::Vector3d p = posteroinferior_across(axis);
    // The block's own scenario has no rings: no zone, and the plan says why.
    const RepairPlan without = plan_repair(scenario, {.stitches = 12});
    EXPECT_FALSE(without.zone.found);
    EXPECT_FALSE(without.zone.reason.empty());
    scenario.landmarks = rings_toward(centre, axis, d, p);

    const RepairPlan off = plan_repair(scenario, {.stitches = 12, .conduction_zone = ConductionZoneMode::off});
    const RepairPlan on = plan_repair(scenario, {.stitches = 12});
    const ConductionZone zone = scenario_conduction_zone(scenario);
    ASSERT_TRUE(zone.found) << zone.reason;
    ASSERT_TRUE(on.zone.found) << on.zone.reason;
    EXPECT_FALSE(off.zone.found);
    EXPECT_NEAR(zone.tricuspid_mm, 3.0, 1e-6);
    EXPECT_NEAR(zone.aortic_mm, 4.0, 1e-6);
    EXPECT_TRUE(zone.direction.isApprox(p, 1e-9)) << zone.direction.transpose() << " against " << p.transpose();
    EXPECT_TRUE(on.zone.direction.isApprox(p, 1e-9));
    EXPECT_DOUBLE_EQ(zone.outer_mm, 0.5 * d + 3.0);
    // φ: p's angle from stitch 1 (superior made perpendicular to the axis), as the stitches' are.
    const Eigen::Vector3d first = (Eigen::Vector3d::UnitZ() - axis.z() * axis).normalized();
    const double phi = angle_round(centre + p, centre, on.outward, first);
    EXPECT_NEAR(std::remainder(on.zone_angle_deg - phi, 360.0), 0.0, 1e-6);
    int biting = 0, moved = 0;
    ASSERT_EQ(off.stitches.size(), 12u);
    ASSERT_EQ(on.stitches.size(), 12u);
    for (int k = 0; k < 12; ++k) {
        SCOPED_TRACE("stitch " + std::to_string(k + 1));
        const double from_middle = std::abs(std::remainder(30.0 * k - phi, 360.0));
        ASSERT_GT(std::abs(from_middle - 60.0), 0.5) << "a stitch on the arc's edge: the count would hang on rounding";
        ASSERT_GT(std::abs(from_middle - 70.0), 0.5);
        const bool bites = from_middle <= 60.0, spared = from_middle <= 70.0;
        biting += bites, moved += spared;
        const Eigen::Vector3d off_site = off.stitches[std::size_t(k)].site, on_site = on.stitches[std::size_t(k)].site;
        auto from_axis = [&](const Eigen::Vector3d& x) { return (x - centre - (x - centre).dot(axis) * axis).norm(); };
        EXPECT_NEAR(from_axis(off_site), 0.5 * d + 2.0, 1e-6);
        EXPECT_EQ(zone.holds(off_site), bites);
        EXPECT_EQ(on.stitches[std::size_t(k)].would_bite_zone, bites);
        EXPECT_EQ(on.stitches[std::size_t(k)].spares_zone, spared);
        EXPECT_NEAR(from_axis(on_site), spared ? 0.5 * d + 4.5 : 0.5 * d + 2.0, 1e-6);
        EXPECT_NEAR(on.stitches[std::size_t(k)].angle_deg, 30.0 * k, 1e-9);
        EXPECT_FALSE(zone.holds(on_site));
    }
    std::printf("12 stitches, the zone's middle at %.1f°: %d bite it with the zone off, %d move out with it on\n", phi, biting, moved);
    EXPECT_GT(biting, 0);
    EXPECT_LT(biting, 12);
    std::vector<Eigen::Vector3d> off_sites, on_sites;
    for (const RepairStitch& s : off.stitches) off_sites.push_back(s.site);
    for (const RepairStitch& s : on.stitches) on_sites.push_back(s.site);
    EXPECT_EQ(int(points_in_zone(zone, off_sites).size()), biting);
    EXPECT_TRUE(points_in_zone(zone, on_sites).empty());
    // The patch reaches 2 mm beyond the stitches moved out.
    EXPECT_NEAR(on.patch_diameter_mm, d + 2.0 * (4.5 + 2.0), 1e-12);
    EXPECT_NEAR(off.patch_diameter_mm, d + 2.0 * (2.0 + 2.0), 1e-12);

    // A run of each plan reports the stitches it tied inside the zone, from their tissue points:
    // as many as bite it with the zone off, none with it on.
    test::TempDir dir;
    const fs::path zoned = dir / "zoned.h5";
    write_scenario(zoned, scenario);
    for (const char* mode : {"off", "auto"}) {
        SCOPED_TRACE(mode);
        const fs::path csv = dir / (std::string(mode) + ".csv");
        const auto planned = heartsim_command("plan-repair " + quoted(zoned) + " -o " + quoted(csv) + " --stitches=12 --conduction-zone " + mode);
        ASSERT_EQ(planned.exit_code, 0) << planned.output;
        const bool zoned_plan = std::string(mode) == "auto";
        EXPECT_NE(planned.output.find(zoned_plan ? "  conduction  perimembranous: its rim comes 3.0 mm from the tricuspid ring and 4.0 mm from the aortic ring"
                                                 : "  conduction  no zone: not marked (--conduction-zone off)"),
                  std::string::npos)
            << planned.output;
        const std::smatch seconds = [&] {
            std::smatch m;
            std::regex_search(planned.output, m, std::regex("--seconds ([0-9.]+)"));
            return m;
        }();
        ASSERT_FALSE(seconds.empty()) << planned.output;
        const auto run = heartsim_command("run " + quoted(zoned) + " --headless --backend cpu --trajectory " + quoted(csv) + " --seconds " +
                                          seconds[1].str());
        ASSERT_EQ(run.exit_code, 0) << run.output;
        const std::string expected = "stitches in the conduction zone: " + std::to_string(zoned_plan ? 0 : biting) + " of 12";
        EXPECT_NE(run.output.find(expected + (zoned_plan ? "\n" : " (stitch ")), std::string::npos) << expected << "\n" << run.output;
        const std::size_t line = run.output.find("stitches in the conduction zone:");
        if (line != std::string::npos) std::printf("%s: %s\n", mode, run.output.substr(line, run.output.find('\n', line) - line).c_str());
    }
}

// MM-WHS CT 1002, its chambers labelled apart, a 10 mm VSD where heartprep puts one (nearest the
// aorta's blood, beneath the aortic valve: perimembranous): its rim lies near the tricuspid and
// aortic rings, so the plan marks a conduction zone on the rim's posteroinferior side, and no
// stitch of the plan lies in it, where the plan with the zone off bites it.
TEST(RepairPlan, TheRealPerimembranousDefectGetsAConductionZoneItsStitchesSpare) {
    const std::vector<test::RealCase> real = test::real_cases();
    const auto c = std::find_if(real.begin(), real.end(), [](const test::RealCase& r) { return r.name == "mmwhs_ct1002"; });
    if (c == real.end()) GTEST_SKIP() << "mmwhs_ct1002 absent (../shared/data/real): no real perimembranous defect to plan on";
    test::TempDir dir;
    const fs::path scenario_path = dir / "ct1002.h5", csv = dir / "repair.csv";
    const auto build = test::heartprep("build " + quoted(c->label_map) + " -o " + quoted(scenario_path) + test::vsd_options(*c) +
                                       " --particles 3000 -q" + c->label_options);
    ASSERT_EQ(build.exit_code, 0) << build.output;
    const auto r = heartsim_command("plan-repair " + quoted(scenario_path) + " -o " + quoted(csv));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("  conduction  perimembranous: its rim comes "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("sparing the conduction zone: 4.5 mm beyond the edge, shallow"), std::string::npos) << r.output;
    const Scenario scenario = read_scenario(scenario_path);
    const RepairPlan plan = plan_repair(scenario);
    ASSERT_TRUE(plan.zone.found) << plan.zone.reason;
    EXPECT_LE(plan.zone.tricuspid_mm, 10.0);
    EXPECT_LE(plan.zone.aortic_mm, 10.0);
    // Posteroinferior: toward +y and −z more than away.
    EXPECT_GT(plan.zone.direction.dot(Eigen::Vector3d(0, 1, -1).normalized()), 0.0) << plan.zone.direction.transpose();
    int spared = 0;
    for (const RepairStitch& s : plan.stitches) {
        spared += s.spares_zone;
        EXPECT_FALSE(plan.zone.holds(s.site)) << "a stitch at " << s.angle_deg << "°";
    }
    EXPECT_GT(spared, 0);
    const RepairPlan off = plan_repair(scenario, {.conduction_zone = ConductionZoneMode::off});
    int biting = 0;
    for (const RepairStitch& s : off.stitches) biting += plan.zone.holds(s.site);
    EXPECT_GT(biting, 0);
    std::printf("mmwhs_ct1002: rim %.1f mm from the tricuspid ring, %.1f mm from the aortic ring; %d of %zu stitches moved out of "
                "the zone, %d of %zu bite it with the zone off\n",
                plan.zone.tricuspid_mm, plan.zone.aortic_mm, spared, plan.stitches.size(), biting, off.stitches.size());
}

TEST(RepairPlan, ItsErrorsSayWhatIsWrong) {
    const BlockScenarios& built = block_scenarios();
    test::TempDir dir;
    const std::string out = " -o " + quoted(dir / "repair.csv");
    // A scenario without a defect: the data's fault, exit 1, and how to make one.
    auto r = heartsim_command("plan-repair " + quoted(built.intact) + out);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("heartsim: error: " + built.intact.string() + ": the scenario has no defect"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("heartprep build LABELS -o CASE.h5 --defect vsd"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir / "repair.csv"));
    EXPECT_THROW(plan_repair(read_scenario(built.intact)), InputError);
    // Without a detailed mesh.
    Scenario bare = read_scenario(built.with_defect);
    bare.visual.reset();
    bare.mapping.reset();
    write_scenario(dir / "bare.h5", bare);
    r = heartsim_command("plan-repair " + quoted(dir / "bare.h5") + out);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("no detailed mesh (/visual)"), std::string::npos) << r.output;
    // Stitches 30 mm beyond the opening lie off the block's septum: the first stitch's line names it.
    r = heartsim_command("plan-repair " + quoted(built.with_defect) + out + " --rim=30");
    EXPECT_EQ(r.exit_code, 1) << r.output;
    // One every 3 mm round the circle of radius D/2 + 30 mm.
    const int stitches = int(std::ceil(2.0 * std::numbers::pi * (0.5 * BlockScenarios::diameter_mm + 30.0) / 3.0));
    EXPECT_NE(r.output.find("stitch 1 of " + std::to_string(stitches)), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("meets no wall"), std::string::npos) << r.output;
    // The command line: exit 2, the option named.
    for (const auto& [arguments, mentions] : std::vector<std::pair<std::string, std::string>>{
             {out + " --stitches=2", "--stitches"},
             {out + " --side=up", "--side"},
             {out + " --rim=0", "--rim"},
             {out + " --thickness=-1", "--thickness"},
             // Beyond what a heart holds or a trajectory can say (a kilometre's bite makes work
             // without bound; a 1001 mm patch is a semi-axis run refuses), and NaN.
             {out + " --rim=1e6", "--rim: must lie in the plausible range"},
             {out + " --patch-diameter=1001", "--patch-diameter: must lie in the plausible range"},
             {out + " --rough-rim=nan", "--rough-rim: must lie in the plausible range [0.01, 100] mm, not nan"},
             {out + " --patch-diameter=10", "--patch-diameter 10.0 mm does not reach beyond the stitches"},
             {out + " --conduction-zone=maybe", "--conduction-zone"},
             {out + " --zone-rim=2.5", "--zone-rim 2.50 mm: the stitches moved out of the conduction zone must lie beyond its band "
                                       "(--zone-band 3.00 mm)"},
             {out + " --zone-band=5", "--zone-rim 4.50 mm: the stitches moved out of the conduction zone must lie beyond its band "
                                      "(--zone-band 5.00 mm)"},
             {out + " --zone-half-width=200", "--zone-half-width: must lie in the plausible range"},
             {"", "--output is required"},
             {" -o " + quoted(dir / "repair.txt"), "the trajectory is a CSV file"}}) {
        r = heartsim_command("plan-repair " + quoted(built.with_defect) + arguments);
        EXPECT_EQ(r.exit_code, 2) << arguments << ": " << r.output;
        EXPECT_NE(r.output.find(mentions), std::string::npos) << arguments << ": " << r.output;
    }
    EXPECT_THROW(plan_repair(read_scenario(built.with_defect), {.stitches = 2}), OptionError);
    // --help teaches: the sides, the options with their units and defaults, an example.
    r = heartsim_command("plan-repair --help");
    EXPECT_EQ(r.exit_code, 0) << r.output;
    for (const char* word : {"--side", "right", "--stitches", "--rim", "--patch-diameter", "--thickness", "mm", "--trajectory", "--clip defect",
                             "Example", "--defect vsd", "--conduction-zone", "--zone-rim", "--zone-band", "--zone-half-width",
                             "--zone-margin", "--zone-reach", "bundle of His"})
        EXPECT_NE(r.output.find(word), std::string::npos) << word << "\n" << r.output;
}
