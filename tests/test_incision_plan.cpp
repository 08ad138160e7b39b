// `heartsim plan-incision` (runtime/surgery/incision_plan.h) end to end, as a user runs it: the planned
// ventriculotomy and atriotomy played by `heartsim run --trajectory` on the phantom and on every
// real heart, the mesh opened and closed; its errors and help; `heartsim run --look-at`.
#include "formats/scenario.h"
#include "formats/state.h"
#include "formats/volume_io.h"
#include "incision_gesture.h"
#include "libmodel/surgery/incision.h"
#include "libmodel/label_conventions.h"
#include "runtime/view/camera.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/view/png.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

using namespace heartsim;
namespace fs = std::filesystem;
using test::quoted;

namespace {

const char* const approaches[] = {"ventriculotomy", "atriotomy"};

const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border --particles 8000"); }

/// Real case `c` built with its label options at 8,000 particles (walls grown, the default), once
/// for the whole binary; throws where the build fails.
const fs::path& built_real(const test::RealCase& c) {
    static test::TempDir dir;
    static std::map<std::string, fs::path> built;
    fs::path& path = built[c.name];
    if (path.empty()) {
        const fs::path output = dir / (c.name + ".h5");
        const auto build = test::heartprep("build " + quoted(c.label_map) + " -o " + quoted(output) + " --particles 8000 -q" + c.label_options);
        if (build.exit_code != 0) throw std::runtime_error("heartprep build of " + c.name + " failed: " + build.output);
        path = output;
    }
    return path;
}

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

/// The value after `--seconds ` in plan-incision's "run it" line; 0 when absent.
double suggested_seconds(const std::string& output) {
    std::smatch m;
    return std::regex_search(output, m, std::regex("run it .*--seconds ([0-9.]+)")) ? std::stod(m[1]) : 0.0;
}

/// The argument of `--look-at ` that plan-incision printed; empty when absent.
std::string suggested_look_at(const std::string& output) {
    std::smatch m;
    return std::regex_search(output, m, std::regex("--look-at ([-0-9.,]+)")) ? std::string(m[1]) : std::string();
}

/// Plans `approach` on `scenario`, plays it headless on the cpu backend with --save-state, and
/// checks the run and the opened mesh it saved.
void plan_and_run(const fs::path& scenario, const std::string& approach, const fs::path& folder) {
    SCOPED_TRACE(approach);
    const fs::path csv = folder / (approach + ".csv"), state = folder / (approach + ".h5");
    const auto plan = heartsim_command("plan-incision " + quoted(scenario) + " -o " + quoted(csv) + " --approach " + approach);
    ASSERT_EQ(plan.exit_code, 0) << plan.output;
    ASSERT_TRUE(fs::exists(csv));
    EXPECT_NE(plan.output.find("a right " + approach), std::string::npos) << plan.output;
    const double seconds = suggested_seconds(plan.output);
    ASSERT_GT(seconds, 0.0) << plan.output;
    // What the CSV holds is what the planner made (the run reads the same file).
    const Trajectory trajectory = read_trajectory(csv);
    EXPECT_TRUE(trajectory.uses_hand(0) && trajectory.uses_hand(1));
    double last = 0;
    for (const InstrumentKeyframe& k : trajectory.keyframes) last = std::max(last, k.time_ms);
    EXPECT_LE(last, 1000.0 * seconds);

    const auto run = heartsim_command("run " + quoted(scenario) + " --headless --backend cpu --trajectory " + quoted(csv) + " --seconds " +
                                      std::to_string(seconds) + " --save-state " + quoted(state));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_EQ(run.output.find("watchdog:"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("incision: the detailed mesh opened along"), std::string::npos) << run.output;
    const SimulationState saved = read_state(state);
    ASSERT_FALSE(saved.visual_triangles.empty());
    std::string why;
    EXPECT_TRUE(closed_manifold(saved.visual_triangles, &why)) << why;
    EXPECT_LT(saved.visual_cap_first, saved.visual_triangles.size());
    bool finite = !saved.visual_positions.empty();
    for (const auto& p : saved.visual_positions) finite = finite && std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
    EXPECT_TRUE(finite);
}

}  // namespace

// The planner's ventriculotomy is the tests' incision (incision_gesture.h wraps it): the same
// keyframes, the blade's plane a quarter spacing beside the chosen particle's column.
TEST(IncisionPlan, TheVentriculotomyIsTheTestsIncision) {
    const Scenario scenario = read_scenario(phantom());
    const IncisionPlan plan = plan_incision(scenario, {.length_mm = 20});
    const test::Incision wrapped = test::anterior_incision(scenario, {.length_mm = 20});
    ASSERT_EQ(plan.trajectory.keyframes.size(), wrapped.trajectory.keyframes.size());
    for (std::size_t i = 0; i < plan.trajectory.keyframes.size(); ++i) {
        const InstrumentKeyframe &a = plan.trajectory.keyframes[i], &b = wrapped.trajectory.keyframes[i];
        EXPECT_EQ(a.time_ms, b.time_ms);
        EXPECT_EQ(a.hand, b.hand);
        EXPECT_EQ(a.kind, b.kind);
        EXPECT_EQ(a.grab, b.grab);
        EXPECT_EQ(a.pose.position, b.pose.position);
        EXPECT_EQ(a.pose.orientation.coeffs(), b.pose.orientation.coeffs());
    }
    EXPECT_EQ(plan.centre, wrapped.centre);
    EXPECT_NEAR(plan.centre.x() - plan.entry.x(), 0.25 * scenario.lattice.spacing, 1e-9);
    EXPECT_EQ(plan.end_ms, wrapped.end_ms);
}

// The atriotomy: on the rightmost wall of the upper half, the blade pointing +x, the plane
// y = y_c a quarter spacing beside the particle, the cut along z, the retractors pulling along y.
TEST(IncisionPlan, TheAtriotomyCutsTheRightmostUpperWallMedially) {
    const Scenario scenario = read_scenario(phantom());
    const IncisionPlan plan = plan_incision(scenario, {.approach = IncisionApproach::atriotomy});
    const auto& rest = scenario.lattice.particles.rest_position;
    double z_low = 1e9, z_high = -1e9;
    for (const auto& p : rest) z_low = std::min(z_low, double(p[2])), z_high = std::max(z_high, double(p[2]));
    EXPECT_GE(plan.entry.z(), 0.5 * (z_low + z_high) - 1e-6);
    EXPECT_EQ(plan.blade, Eigen::Vector3d::UnitX());
    EXPECT_EQ(plan.cut, Eigen::Vector3d::UnitZ());
    EXPECT_NEAR(std::abs(plan.centre.y() - plan.entry.y()), 0.25 * scenario.lattice.spacing, 1e-9);
    EXPECT_EQ(plan.view, ViewDirection::right);
    // The scalpel's blade (tool +z) points +x in the world.
    const InstrumentKeyframe& first = plan.trajectory.keyframes.front();
    EXPECT_EQ(first.kind, InstrumentKind::scalpel);
    EXPECT_TRUE((first.pose.orientation * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX(), 1e-12));
    EXPECT_LT(first.pose.position.x(), plan.entry.x());  // the tip starts outside, to the right
    EXPECT_TRUE(plan.grip_found[0] && plan.grip_found[1]);
    EXPECT_LT(plan.grips[1].y(), plan.centre.y());  // hand 1 on the anterior edge
    EXPECT_GT(plan.grips[0].y(), plan.centre.y());
}

TEST(IncisionPlan, ThePhantomPlaysBothApproachesAndOpens) {
    test::TempDir dir;
    for (const char* approach : approaches) plan_and_run(phantom(), approach, dir.path());
}

// Every real heart present (8,000 particles), both approaches: planned, played headless on the
// cpu backend with no watchdog event, the detailed mesh opened, closed and finite.
TEST(IncisionPlan, EveryRealHeartPlaysBothApproachesAndOpens) {
    const std::vector<test::RealCase> real = test::real_cases();
    if (real.empty()) GTEST_SKIP() << "real data absent (../shared/data/real): nothing to plan on";
    test::TempDir dir;
    int cases = 0;
    for (const test::RealCase& c : real) {
        const std::string& name = c.name;
        SCOPED_TRACE(name);
        const fs::path& scenario = built_real(c);
        fs::create_directories(dir / name);
        for (const char* approach : approaches) plan_and_run(scenario, approach, dir / name);
        ++cases;
    }
    if (cases == 0) GTEST_SKIP() << "no real label map under " << test::real_data_dir();
}

namespace {

/// The label of the voxel whose centre is nearest `p` (world LPS mm); 0 outside the map.
int label_at(const LabelVolume& v, const Eigen::Vector3d& p) {
    const Eigen::Vector3d ijk = v.geometry.spacing.cwiseInverse().asDiagonal() * (v.geometry.direction.transpose() * (p - v.geometry.origin));
    const int i = int(std::lround(ijk.x())), j = int(std::lround(ijk.y())), k = int(std::lround(ijk.z()));
    return v.geometry.contains(i, j, k) ? v.labels[v.geometry.linear(i, j, k)] : 0;
}

}  // namespace

// On each MM-WHS heart as built by default (walls grown), the planned blade, followed from its
// entry through the depth it cuts, first meets blood of the approach's chamber in the label map
// itself: the right ventricle's for the ventriculotomy, the right atrium's for the atriotomy.
TEST(IncisionPlan, OnEachMmwhsHeartTheBladeOpensTheApproachsChamber) {
    int tried = 0;
    for (const test::RealCase& c : test::real_cases()) {
        if (c.label_options.find("mmwhs") == std::string::npos) continue;
        SCOPED_TRACE(c.name);
        const LabelConvention& convention = *find_label_convention(c.label_options.find("ordinal") != std::string::npos ? "mmwhs-ordinal" : "mmwhs");
        const Scenario scenario = read_scenario(built_real(c));
        const LabelVolume labels = read_label_volume(c.label_map);
        for (const auto& [approach, chamber] : {std::pair{IncisionApproach::ventriculotomy, convention.right_ventricle},
                                                std::pair{IncisionApproach::atriotomy, convention.right_atrium}}) {
            SCOPED_TRACE(to_string(approach));
            const IncisionPlan plan = plan_incision(scenario, {.approach = approach});
            int met = 0;
            double at = 0;
            for (double t = 0; t <= plan.depth_mm && met == 0; t += 0.1) {
                const int l = label_at(labels, plan.entry + t * plan.blade);
                if (l != 0 && l != convention.myocardium) met = l, at = t;
            }
            EXPECT_EQ(met, chamber) << "the blade from (" << plan.entry.transpose() << ") along (" << plan.blade.transpose() << ") met label " << met
                                    << " at " << at << " mm of its " << plan.depth_mm << " mm";
            std::printf("%s %s: the blade meets label %d's blood %.1f mm behind its entry (it cuts %.1f mm)\n", c.name.c_str(),
                        to_string(approach), met, at, plan.depth_mm);
        }
        ++tried;
    }
    if (tried == 0) GTEST_SKIP() << "no MM-WHS heart under " << test::real_data_dir();
}

TEST(IncisionPlan, ItsErrorsSayWhatIsWrong) {
    test::TempDir dir;
    const std::string out = " -o " + quoted(dir / "cut.csv");
    // An unknown approach is a usage error naming the choices.
    auto r = heartsim_command("plan-incision " + quoted(phantom()) + out + " --approach sternotomy");
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_NE(r.output.find("--approach"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("ventriculotomy"), std::string::npos) << r.output;
    // A missing scenario names the file.
    const fs::path missing = dir / "no-such-case.h5";
    r = heartsim_command("plan-incision " + quoted(missing) + out);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("heartsim: error: " + missing.string()), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir / "cut.csv"));
    // Values out of range, a missing -o, an output that is no CSV, and the scenario as the output.
    for (const auto& [arguments, mentions] : std::vector<std::pair<std::string, std::string>>{
             {out + " --length 0", "--length"},
             {out + " --speed -1", "--speed"},
             {out + " --spread -2", "--spread"},
             {out + " --length 1e9", "--length: must lie in the plausible range"},
             {out + " --speed 1e-12", "--speed: must lie in the plausible range"},
             {"", "--output is required"},
             {" -o " + quoted(dir / "cut.txt"), "the trajectory is a CSV file"}}) {
        r = heartsim_command("plan-incision " + quoted(phantom()) + arguments);
        EXPECT_EQ(r.exit_code, 2) << arguments << ": " << r.output;
        EXPECT_NE(r.output.find(mentions), std::string::npos) << arguments << ": " << r.output;
    }
    // A folder that cannot hold the file: the last code, the file named.
    r = heartsim_command("plan-incision " + quoted(phantom()) + " -o " + quoted(dir / "no-folder" / "cut.csv"));
    EXPECT_EQ(r.exit_code, 7) << r.output;
    EXPECT_NE(r.output.find((dir / "no-folder" / "cut.csv").string() + ": folder " + (dir / "no-folder").string() + " does not exist"),
              std::string::npos)
        << r.output;
    // --help teaches: the approaches, the defaults, an example.
    r = heartsim_command("plan-incision --help");
    EXPECT_EQ(r.exit_code, 0) << r.output;
    for (const char* word : {"ventriculotomy", "atriotomy", "--length", "--spread", "--depth", "--speed", "--trajectory", "--look-at", "Example"})
        EXPECT_NE(r.output.find(word), std::string::npos) << word << "\n" << r.output;
}

// A scenario without a detailed mesh still plans (the run cuts the tissue; nothing opens on screen),
// and says so; one without particles is refused, naming the file.
TEST(IncisionPlan, AScenarioWithoutDetailedMeshStillPlans) {
    test::TempDir dir;
    Scenario scenario = read_scenario(phantom());
    scenario.visual.reset();
    scenario.mapping.reset();
    write_scenario(dir / "bare.h5", scenario);
    const auto r = heartsim_command("plan-incision " + quoted(dir / "bare.h5") + " -o " + quoted(dir / "cut.csv"));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("no detailed mesh"), std::string::npos) << r.output;
    EXPECT_TRUE(fs::exists(dir / "cut.csv"));

    Scenario empty = read_scenario(phantom());
    empty.lattice.particles = {};
    empty.lattice.springs = {};
    empty.visual.reset(), empty.mapping.reset(), empty.simulation_surface.reset(), empty.packing.reset();
    EXPECT_THROW(plan_incision(empty), InputError);
}

TEST(PlannedTrajectory, AKeyframeTheReaderWouldRefuseIsRefusedBeforeItIsWritten) {
    // The rules a trajectory's rows are read by, on keyframes a planner made: what check_planned_trajectory
    // lets through parses back whole, what it refuses the reader refuses too.
    const std::string header = "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n";
    InstrumentKeyframe fine;
    fine.kind = InstrumentKind::patch;
    fine.pose.position = {1, 2, 3};
    fine.semi_axes = {5, 5, 0.25};
    fine.grab = true;
    auto row = [](const InstrumentKeyframe& k) {
        char text[400];
        std::snprintf(text, sizeof text, "%.17g,%d,%s,%.17g,%.17g,%.17g,1,0,0,0,%.17g,%.17g,%.17g,%d\n", k.time_ms, k.hand, to_string(k.kind),
                      k.pose.position.x(), k.pose.position.y(), k.pose.position.z(), k.semi_axes.x(), k.semi_axes.y(), k.semi_axes.z(),
                      k.grab ? 1 : 0);
        return std::string(text);
    };
    EXPECT_NO_THROW(check_planned_trajectory({{fine}}));
    EXPECT_NO_THROW(parse_trajectory(header + row(fine), "fine.csv"));
    InstrumentKeyframe far = fine, wide = fine, grabbing_probe = fine;
    far.pose.position.x() = 2e6;  // --length 1e9 put the scalpel there
    wide.semi_axes.x() = 500.5;   // --patch-diameter 1001
    grabbing_probe.kind = InstrumentKind::probe;
    for (const InstrumentKeyframe& bad : {far, wide, grabbing_probe}) {
        EXPECT_THROW(check_planned_trajectory({{fine, bad}}), OptionError) << row(bad);
        EXPECT_THROW(parse_trajectory(header + row(bad), "bad.csv"), InputError) << row(bad);
    }
}

TEST(LookAt, ParsesAPointAndADistanceAndKeepsTheView) {
    const LookAt look = parse_look_at("1.5,-2,3,40");
    EXPECT_EQ(look.point, Eigen::Vector3f(1.5f, -2.0f, 3.0f));
    ASSERT_TRUE(look.distance);
    EXPECT_EQ(*look.distance, 40.0f);
    EXPECT_FALSE(parse_look_at("1,2,3").distance);
    for (const char* bad : {"1,2", "1,2,3,4,5", "1,,3", "a,b,c", "1,2,3,0", "1,2,3,-5", "1,2,nan", "", "1e30,0,0", "0,-2e6,0",
                            "0,0,0,1e30"})
        EXPECT_THROW(parse_look_at(bad), OptionError) << bad;
    Camera camera = fit_camera(Eigen::AlignedBox3f(Eigen::Vector3f(-50, -50, -50), Eigen::Vector3f(50, 50, 50)), ViewDirection::right, 4.0f / 3.0f);
    const Eigen::Quaternionf before = camera.orientation;
    aim_camera_at(camera, look);
    EXPECT_EQ(camera.target, look.point);
    EXPECT_EQ(camera.distance, 40.0f);
    EXPECT_TRUE(camera.orientation.coeffs().isApprox(before.coeffs()));
    // From the right (camera at −x): the eye 40 mm to the patient's right of the point.
    EXPECT_TRUE(camera.eye().isApprox(look.point - Eigen::Vector3f(40, 0, 0), 1e-5f));
}

// `--look-at` with the point plan-incision prints: the heart around the incision fills much more
// of the picture than in the fitted view, which shows the whole heart; its errors are usage errors.
TEST(LookAt, FramesThePlannedIncision) {
    test::TempDir dir;
    const auto plan = heartsim_command("plan-incision " + quoted(phantom()) + " -o " + quoted(dir / "cut.csv"));
    ASSERT_EQ(plan.exit_code, 0) << plan.output;
    const std::string look = suggested_look_at(plan.output);
    ASSERT_FALSE(look.empty()) << plan.output;
    const std::string run = "run " + quoted(phantom()) + " --headless --backend cpu --steps 0 --size 160x120 ";
    auto r = heartsim_command(run + "--look-at 1,2");
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_NE(r.output.find("--look-at '1,2': expected X,Y,Z or X,Y,Z,DISTANCE"), std::string::npos) << r.output;
    r = heartsim_command(run + "--look-at " + look);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_NE(r.output.find("--look-at aims the camera: headless it needs --screenshot"), std::string::npos) << r.output;

    REQUIRE_GL();
    // The share of the frame the tissue covers: pixels brighter than the dark background.
    auto tissue_share = [](const Image& image) {
        std::size_t tissue = 0;
        for (std::size_t i = 0; i + 2 < image.pixels.size(); i += std::size_t(image.channels))
            tissue += image.pixels[i] > 70 && image.pixels[i] > image.pixels[i + 2] + 20;
        return double(tissue) / double(image.width * image.height);
    };
    r = heartsim_command(run + "--screenshot " + quoted(dir / "fitted.png"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = heartsim_command(run + "--look-at " + look + " --screenshot " + quoted(dir / "close.png"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const double fitted = tissue_share(read_png(dir / "fitted.png")), close = tissue_share(read_png(dir / "close.png"));
    EXPECT_GT(close, 0.5) << "fitted view " << fitted;
    EXPECT_GT(close, fitted + 0.2);
}
