// `heartsim plan-operation` (runtime/surgery/operation_plan.h) end to end, as a user runs it: the
// operation planned, played by `heartsim run --trajectory` to the moment the plan says the defect
// is exposed, and the defect's rim then looked at from the eye the plan printed, by rays against
// the detailed mesh the run saved: rays that the intact wall blocks before the incision pass
// through the opening after it. Then the whole operation closes the defect.
#include "formats/scenario.h"
#include "formats/state.h"
#include "libmodel/ray_triangle.h"
#include "libmodel/surgery/sight.h"
#include "libmodel/surgery/surgery_site.h"
#include "runtime/surgery/operation_plan.h"
#include "runtime/view/camera.h"
#include "runtime/view/png.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <numbers>
#include <regex>

using namespace heartsim;
namespace fs = std::filesystem;
using test::quoted;

namespace {

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

const fs::path& vsd_phantom() { return test::built_vsd_phantom(); }

Eigen::Vector3d printed_point(const std::string& output, const std::string& label) {
    std::smatch m;
    if (!std::regex_search(output, m, std::regex(label + ": ([-0-9.]+), ([-0-9.]+), ([-0-9.]+) mm"))) return Eigen::Vector3d::Constant(NAN);
    return {std::stod(m[1]), std::stod(m[2]), std::stod(m[3])};
}

double printed_number(const std::string& output, const std::string& pattern) {
    std::smatch m;
    return std::regex_search(output, m, std::regex(pattern)) ? std::stod(m[1]) : NAN;
}

/// How many of 24 points of the defect's rim are seen from `eye` on the closed mesh (positions,
/// triangles): each rim point is where the line along the defect's axis, 1.5 mm beyond the
/// opening's edge, enters the septum from the eye's side (the stretch holding mid-wall); it is seen
/// when the segment from the eye meets no triangle until within 0.5 mm of it.
struct RimSight {
    int seen = 0, rim = 0;
};
RimSight rim_seen_from(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<std::int32_t, 3>>& triangles,
                       const Scenario& scenario, const Eigen::Vector3d& eye) {
    const Eigen::Vector3d centre = scenario.source.defect_centre;
    Eigen::Vector3d outward = scenario.source.defect_axis.normalized();
    if (outward.dot(eye - centre) < 0) outward = -outward;
    const Eigen::Vector3d u = outward.unitOrthogonal(), v = outward.cross(u);
    const double radius = 0.5 * scenario.source.defect_diameter_mm + 1.5;
    RimSight sight;
    for (int k = 0; k < 24; ++k) {
        const double angle = 2.0 * std::numbers::pi * k / 24;
        const Eigen::Vector3d p = centre + radius * (std::cos(angle) * u + std::sin(angle) * v);
        double top = NAN;
        for (const TissueStretch& s : tissue_stretches(positions, triangles, p, outward))
            if (s.holds(0.0)) top = s.top;
        if (!std::isfinite(top)) continue;
        ++sight.rim;
        const Eigen::Vector3d rim = p + top * outward, along = rim - eye;
        const double stop = 1.0 - 0.5 / along.norm();
        bool blocked = false;
        for (const auto& t : triangles) {
            const auto& a = positions[std::size_t(t[0])];
            const auto& b = positions[std::size_t(t[1])];
            const auto& c = positions[std::size_t(t[2])];
            const auto hit = line_triangle(eye, along, Eigen::Vector3d(a[0], a[1], a[2]), Eigen::Vector3d(b[0], b[1], b[2]),
                                           Eigen::Vector3d(c[0], c[1], c[2]));
            if (hit && hit->along > 0.0 && hit->along < stop) {
                blocked = true;
                break;
            }
        }
        sight.seen += blocked ? 0 : 1;
    }
    return sight;
}

/// Plans `approach` on `scenario`, runs it to the printed exposure, and returns the rim seen from
/// the printed eye before (the scenario's intact mesh) and then (the run's saved mesh).
std::pair<RimSight, RimSight> exposure(const fs::path& scenario, const std::string& approach, const fs::path& folder) {
    const fs::path csv = folder / (approach + ".csv"), state = folder / (approach + ".exposed.h5");
    const auto plan = heartsim_command("plan-operation " + quoted(scenario) + " -o " + quoted(csv) + " --approach " + approach);
    EXPECT_EQ(plan.exit_code, 0) << plan.output;
    const Eigen::Vector3d eye = printed_point(plan.output, "surgeon's eye");
    const double exposed_s = printed_number(plan.output, "defect exposed at: ([0-9.]+) s");
    EXPECT_TRUE(eye.allFinite() && std::isfinite(exposed_s)) << plan.output;
    if (!eye.allFinite() || !std::isfinite(exposed_s)) return {};
    const auto run = heartsim_command("run " + quoted(scenario) + " --headless --backend cpu --trajectory " + quoted(csv) + " --seconds " +
                                      std::to_string(exposed_s) + " --save-state " + quoted(state));
    EXPECT_EQ(run.exit_code, 0) << run.output;
    const Scenario read = read_scenario(scenario);
    const SimulationState saved = read_state(state);
    EXPECT_FALSE(saved.visual_triangles.empty()) << "the incision did not open the detailed mesh";
    const RimSight before = rim_seen_from(read.visual->positions, read.visual->triangles, read, eye);
    const RimSight after = rim_seen_from(saved.visual_positions, saved.visual_triangles.empty() ? read.visual->triangles : saved.visual_triangles,
                                         read, eye);
    return {before, after};
}

}  // namespace

// The opening is what lets the eye see the defect: from the printed eye, the intact heart's wall
// hides every point of the rim; at the printed exposure, with the incision cut and retracted, rays
// reach most of it through the opening without meeting tissue.
TEST(OperationPlan, AtTheExposureTheEyeSeesTheDefectsRimThroughTheOpening) {
    test::TempDir dir;
    const auto [before, after] = exposure(vsd_phantom(), "right-ventricular", dir.path());
    ASSERT_GE(before.rim, 20);
    EXPECT_EQ(before.seen, 0) << "the intact wall should hide the rim";
    EXPECT_EQ(after.rim, before.rim);
    EXPECT_GE(2 * after.seen, after.rim) << after.seen << " of " << after.rim << " rim points seen through the opening";
}

// The incision runs where the plan says: across the line of sight, on the approach's wall, with the
// wall between the defect's face and the surgeon's eye.
TEST(OperationPlan, TheIncisionCrossesTheWallOnTheLineOfSight) {
    const Scenario scenario = read_scenario(vsd_phantom());
    OperationPlanOptions options;
    options.approach = OperationApproach::right_ventricular;
    const OperationPlan plan = plan_operation(scenario, options);
    EXPECT_NEAR(plan.cut.dot(plan.sight), 0.0, 1e-9);
    EXPECT_NEAR(plan.side.dot(plan.sight), 0.0, 1e-9);
    EXPECT_NEAR(plan.cut.norm(), 1.0, 1e-9);
    // Along the line from the face: blood, then the wall, then nothing up to the eye.
    const TissueOccupancy tissue(scenario.lattice.particles.rest_position, scenario.lattice.spacing);
    const std::vector<SightSpan> spans = tissue_along(tissue, plan.target + 1.0 * plan.sight, plan.eye);
    ASSERT_EQ(spans.size(), 1u);
    EXPECT_NEAR(spans.front().from + 1.0, plan.blood_mm, 1e-6);
    EXPECT_LE(plan.wall_mm, 15.0);
    // The scalpel's first keyframe is outside the heart on that line's side, the retractors' grips within the wall.
    const InstrumentKeyframe& first = plan.trajectory.keyframes.front();
    EXPECT_EQ(first.kind, InstrumentKind::scalpel);
    EXPECT_GT((first.pose.position - plan.target).dot(plan.sight), plan.blood_mm + plan.wall_mm);
    // Each retractor's centre lies in the wall: a particle within its half-width across (1.2 spacings).
    for (const Eigen::Vector3d& grip : plan.grips) {
        double nearest = INFINITY;
        for (const auto& r : scenario.lattice.particles.rest_position) nearest = std::min(nearest, (Eigen::Vector3d(r[0], r[1], r[2]) - grip).norm());
        EXPECT_LE(nearest, 1.2 * scenario.lattice.spacing);
    }
}

// The whole operation, as printed: the run ends with the defect closed.
TEST(OperationPlan, TheOperationClosesThePhantomsDefect) {
    test::TempDir dir;
    const fs::path csv = dir / "op.csv";
    const auto plan = heartsim_command("plan-operation " + quoted(vsd_phantom()) + " -o " + quoted(csv));
    ASSERT_EQ(plan.exit_code, 0) << plan.output;
    const double seconds = printed_number(plan.output, "run it .*--seconds ([0-9.]+)");
    ASSERT_TRUE(std::isfinite(seconds)) << plan.output;
    const auto run = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --trajectory " + quoted(csv) + " --seconds " +
                                      std::to_string(seconds));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("defect closed: yes"), std::string::npos) << run.output;
}

// `--eye` puts the camera at the eye looking at the --look-at point, the surgeon's view keeping the
// patient's left up as nearly as the line of sight allows; an eye on the point is refused.
TEST(OperationPlan, TheEyeLooksAtThePointWithThePatientsLeftUp) {
    LookAt look = parse_look_at("10,20,30");
    parse_eye("-40,-60,50", look);
    Camera camera = fit_camera(Eigen::AlignedBox3f(Eigen::Vector3f(-50, -50, -50), Eigen::Vector3f(50, 50, 50)), ViewDirection::surgeon, 4.0f / 3.0f);
    aim_camera_at(camera, look);
    EXPECT_TRUE(camera.eye().isApprox(Eigen::Vector3f(-40, -60, 50), 1e-4f)) << camera.eye().transpose();
    EXPECT_EQ(camera.target, Eigen::Vector3f(10, 20, 30));
    const Eigen::Vector3f forward = camera.orientation * -Eigen::Vector3f::UnitZ(), up = camera.orientation * Eigen::Vector3f::UnitY();
    EXPECT_TRUE(forward.isApprox((Eigen::Vector3f(10, 20, 30) - Eigen::Vector3f(-40, -60, 50)).normalized(), 1e-5f));
    EXPECT_NEAR(up.dot(forward), 0.0f, 1e-5f);
    EXPECT_GT(up.x(), 0.5f) << "the patient's left (+x) should be up in the surgeon's view";
    EXPECT_NEAR(camera.orientation.toRotationMatrix().determinant(), 1.0f, 1e-5f);
    EXPECT_THROW(parse_eye("10,20,30", look), OptionError);
    EXPECT_THROW(parse_eye("1,2", look), OptionError);
    EXPECT_THROW(parse_eye("1,2,3,4", look), OptionError);
}

// Errors a user meets: no defect, an unknown approach, --eye without --look-at.
TEST(OperationPlan, RefusesWhatItCannotPlan) {
    test::TempDir dir;
    const fs::path plain = dir / "plain.h5", labels = dir / "p.nii.gz";
    ASSERT_EQ(test::heartprep("phantom -o " + quoted(labels) + " --vsd-diameter 0").exit_code, 0);
    ASSERT_EQ(test::heartprep("build " + quoted(labels) + " --particles 2000 -q -o " + quoted(plain)).exit_code, 0);
    const auto none = heartsim_command("plan-operation " + quoted(plain) + " -o " + quoted(dir / "op.csv"));
    EXPECT_EQ(none.exit_code, 1) << none.output;
    EXPECT_NE(none.output.find("no defect"), std::string::npos) << none.output;
    EXPECT_FALSE(fs::exists(dir / "op.csv"));
    const auto bad = heartsim_command("plan-operation " + quoted(vsd_phantom()) + " -o " + quoted(dir / "op.csv") + " --approach transaortic");
    EXPECT_EQ(bad.exit_code, 2) << bad.output;
    EXPECT_NE(bad.output.find("--approach"), std::string::npos) << bad.output;
    const auto eye = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --steps 0 --eye 1,2,3 --screenshot " + quoted(dir / "x.png"));
    EXPECT_EQ(eye.exit_code, 2) << eye.output;
    EXPECT_NE(eye.output.find("--look-at"), std::string::npos) << eye.output;
}

// The plan's view (Trajectory::view) is written as the CSV's `# view:` line and read back equal, to
// the bit, whatever its floats; a trajectory without one reads back without one.
TEST(PlannedView, RoundTripsThroughTheTrajectoryCsv) {
    test::TempDir dir;
    Trajectory t;
    t.add(0.0, 0, InstrumentKind::scalpel, {1, 2, 3}, Eigen::Quaterniond::Identity(), {2, 0.3, 10}, true);
    t.add(100.0, 0, InstrumentKind::scalpel, {1, 2, 13}, Eigen::Quaterniond::Identity(), {2, 0.3, 10}, true);
    LookAt odd;
    odd.point = Eigen::Vector3f(1.0f / 3.0f, -123.456789f, 7e-4f);
    odd.eye = Eigen::Vector3f(-84.5f, 51.3f, 61.2f);
    LookAt far = odd;
    far.eye.reset();
    far.distance = 75.1f;
    for (const PlannedView& view : {PlannedView{ViewDirection::surgeon, odd}, PlannedView{ViewDirection::right, far},
                                    PlannedView{ViewDirection::inferior, std::nullopt}}) {
        t.view = view;
        write_trajectory_csv(t, dir / "t.csv", "# a plan\n");
        const Trajectory back = read_trajectory(dir / "t.csv");
        ASSERT_TRUE(back.view) << view_options(view);
        EXPECT_TRUE(*back.view == view) << view_options(view) << " read back as " << view_options(*back.view);
        EXPECT_TRUE(parse_view_options(view_options(view)) == view) << view_options(view);
        ASSERT_EQ(back.keyframes.size(), 2u);
        EXPECT_EQ(back.keyframes[1].pose.position, t.keyframes[1].pose.position);
    }
    // The fewest digits: the points as a user types them.
    LookAt typed = parse_look_at("1,-2.5,30");
    parse_eye("-84.5,51.3,61.2", typed);
    EXPECT_EQ(view_options({ViewDirection::surgeon, typed}), "--view surgeon --eye -84.5,51.3,61.2 --look-at 1,-2.5,30");
    t.view.reset();
    write_trajectory_csv(t, dir / "t.csv");
    EXPECT_FALSE(read_trajectory(dir / "t.csv").view);
    // The view line is the whole comment: a comment that only mentions a view is a comment.
    EXPECT_FALSE(parse_trajectory("# the view: anterior\n0,0,probe,0,0,0,1,0,0,0,1,1,1,0 # view: --view left\n", "x.csv").view);
}

// A `# view:` line the command line would refuse is refused, naming the file and the line and
// saying what is wrong; so is a second one. heartsim run says it before reading the scenario.
TEST(PlannedView, AMalformedViewLineIsRefusedWithTheFileAndLine) {
    test::TempDir dir;
    const std::string row = "0,0,probe,0,0,0,1,0,0,0,1,1,1,0\n";
    const std::pair<const char*, const char*> cases[] = {
        {"--view sideways", "expected anterior, posterior"},
        {"--view surgeon --eye 1,2,3 --look-at 1,2,3", "the eye is on the --look-at point"},
        {"--view surgeon --eye 1,2,3 --look-at 1,nan,3", "expected X,Y,Z or X,Y,Z,DISTANCE"},
        {"--view surgeon --look-at 1,2,3,0", "DISTANCE above 0"},
        {"--view surgeon --eye 1,2,3", "give it"},
        {"--look-at 1,2,3", "no --view"},
        {"--view surgeon --look-at", "without its value"},
        {"--view surgeon --zoom 2", "'--zoom' is none of these"},
        {"--view section", "needs --clip"},
        {"", "no --view"},
    };
    for (const auto& [line, says] : cases) {
        const fs::path csv = dir / "bad.csv";
        std::ofstream(csv) << "# a plan\n# view: " << line << "\n" << row;
        try {
            read_trajectory(csv);
            ADD_FAILURE() << "accepted '# view: " << line << "'";
        } catch (const InputError& e) {
            const std::string what = e.what();
            EXPECT_NE(what.find(csv.string() + " line 2: the planned view"), std::string::npos) << what;
            EXPECT_NE(what.find(says), std::string::npos) << what;
        }
    }
    const fs::path twice = dir / "twice.csv";
    std::ofstream(twice) << "# view: --view left\n" << row << "# view: --view right\n";
    try {
        read_trajectory(twice);
        ADD_FAILURE() << "accepted two view lines";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find(twice.string() + " line 3: a second '# view:' line (line 1"), std::string::npos) << e.what();
    }
    std::ofstream(dir / "bad.csv") << "# view: --view surgeon --eye 1,2,3 --look-at 1,2,3\n" << row;
    const auto run = heartsim_command("run " + quoted(dir / "missing.h5") + " --headless --trajectory " + quoted(dir / "bad.csv"));
    EXPECT_NE(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("bad.csv line 1: the planned view"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("the eye is on the --look-at point"), std::string::npos) << run.output;
}

// plan-incision records the view it prints, the camera 2.5 incision lengths from the incision's centre.
TEST(PlannedView, PlanIncisionRecordsTheViewItPrints) {
    test::TempDir dir;
    const auto plan = heartsim_command("plan-incision " + quoted(vsd_phantom()) + " -o " + quoted(dir / "cut.csv") + " --length 20");
    ASSERT_EQ(plan.exit_code, 0) << plan.output;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(plan.output, m, std::regex("the view the file records \\((--view [a-z]+ --look-at [-0-9.,]+);"))) << plan.output;
    const Trajectory read = read_trajectory(dir / "cut.csv");
    ASSERT_TRUE(read.view);
    EXPECT_EQ(view_options(*read.view), std::string(m[1]));
    EXPECT_EQ(read.view->direction, ViewDirection::anterior);  // the ventriculotomy, from the front
    ASSERT_TRUE(read.view->look && read.view->look->distance);
    EXPECT_EQ(*read.view->look->distance, 50.0f);
    EXPECT_FALSE(read.view->look->eye);
}

// plan-operation records the surgeon's view in its CSV, and `heartsim run --trajectory` opens
// there: a headless screenshot without view options is, pixel for pixel, the one taken with the
// options the plan printed, and differs from one where --view alone is given (the user's option wins).
TEST(OperationPlan, TheRunOpensWhereTheSurgeonStands) {
    test::TempDir dir;
    const fs::path csv = dir / "op.csv";
    const auto plan = heartsim_command("plan-operation " + quoted(vsd_phantom()) + " -o " + quoted(csv) + " --approach right-atrial");
    ASSERT_EQ(plan.exit_code, 0) << plan.output;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(plan.output, m, std::regex("(--view surgeon --eye ([-0-9.]+),([-0-9.]+),([-0-9.]+) --look-at [-0-9.,]+);")))
        << plan.output;
    const std::string options = m[1];
    const Eigen::Vector3d eye = printed_point(plan.output, "surgeon's eye");
    EXPECT_TRUE(Eigen::Vector3d(std::stod(m[2]), std::stod(m[3]), std::stod(m[4])).isApprox(eye, 1e-9)) << plan.output;
    EXPECT_EQ(plan.output.find("add --view"), std::string::npos) << "the plan still asks for the view by hand:\n" << plan.output;
    const Trajectory read = read_trajectory(csv);
    ASSERT_TRUE(read.view) << "no '# view:' line in the plan's CSV";
    EXPECT_EQ(view_options(*read.view), options);

    REQUIRE_GL();
    const std::string run = "run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(csv) + " --steps 2 --size 96x72 ";
    auto shot = [&](const std::string& extra, const std::string& name) {
        const auto r = heartsim_command(run + extra + " --screenshot " + quoted(dir / name));
        EXPECT_EQ(r.exit_code, 0) << r.output;
        return std::make_pair(r.output, read_png(dir / name));
    };
    const auto [planned_output, planned] = shot("", "planned.png");
    const auto [given_output, given] = shot(options, "given.png");
    const auto [view_output, view_only] = shot("--view surgeon", "view.png");
    EXPECT_NE(planned_output.find("view: as planned in " + csv.string() + ", " + options + " (--view, --eye or --look-at choose another)"),
              std::string::npos)
        << planned_output;
    EXPECT_EQ(given_output.find("as planned"), std::string::npos) << given_output;
    EXPECT_EQ(view_output.find("as planned"), std::string::npos) << view_output;
    ASSERT_EQ(planned.width, 96);
    ASSERT_EQ(planned.height, 72);
    EXPECT_TRUE(planned.pixels == given.pixels) << "the planned view's screenshot differs from the one with the options given";
    ASSERT_EQ(view_only.pixels.size(), planned.pixels.size());
    const test::ImageDifference difference = test::compare_images(planned, view_only, 16, nullptr);
    EXPECT_GT(difference.fraction_over, 0.1) << "with --view surgeon alone the fitted surgeon's view should replace the planned eye";
}

// Every real heart with a 10 mm VSD: both approaches planned (or one refused with its reason, and
// the table says so), and each planned approach's exposure shows the rim through the opening.
TEST(OperationPlan, OnEveryRealHeartTheExposureShowsTheDefect) {
    const std::vector<test::RealCase> real = test::real_cases();
    if (real.empty()) GTEST_SKIP() << "real data absent (../shared/data/real): nothing to plan on";
    test::TempDir dir;
    for (const test::RealCase& c : real) {
        SCOPED_TRACE(c.name);
        const std::string vsd = test::vsd_options(c);
        if (vsd.empty()) {
            std::printf("%s: no septum point known for this HVSMR case: skipped\n", c.name.c_str());
            continue;
        }
        const fs::path scenario = dir / (c.name + ".h5");
        const auto build = test::heartprep("build " + quoted(c.label_map) + " -o " + quoted(scenario) + vsd + " --particles 8000 -q" + c.label_options);
        ASSERT_EQ(build.exit_code, 0) << build.output;
        const auto all = heartsim_command("plan-operation " + quoted(scenario) + " -o " + quoted(dir / (c.name + ".csv")) + " --approach all");
        if (all.exit_code != 0) {
            // Refused whole only where the right heart cannot close it, saying why and what works.
            EXPECT_EQ(all.exit_code, 1) << all.output;
            EXPECT_NE(all.output.find("no operation through the right heart closes this defect"), std::string::npos) << all.output;
            EXPECT_NE(all.output.find("plan-repair"), std::string::npos) << all.output;
            EXPECT_NE(all.output.find("--rough-rim"), std::string::npos) << all.output;
            std::printf("%s: refused: the right rim is too rough to seal from the right\n", c.name.c_str());
            continue;
        }
        EXPECT_NE(all.output.find("| right-atrial |"), std::string::npos) << all.output;
        EXPECT_NE(all.output.find("| right-ventricular |"), std::string::npos) << all.output;
        for (const std::string approach : {"right-atrial", "right-ventricular"}) {
            if (all.output.find("no right " + std::string(approach == "right-atrial" ? "atriotomy" : "ventriculotomy")) != std::string::npos) continue;
            SCOPED_TRACE(approach);
            const fs::path folder = dir / c.name;
            fs::create_directories(folder);
            const auto [before, after] = exposure(scenario, approach, folder);
            std::printf("%s %s: rim seen from the eye %d of %d before the incision, %d of %d at the exposure\n", c.name.c_str(), approach.c_str(),
                        before.seen, before.rim, after.seen, after.rim);
            EXPECT_LT(before.seen, after.seen);
            EXPECT_GE(3 * after.seen, after.rim) << after.seen << " of " << after.rim;
        }
    }
}

// Every real heart with a 10 mm VSD at heartprep's default build (the operation gallery's): each
// approach plan-operation plans cuts its incision and, as the blade lifts, the detailed mesh the
// trainee sees opens along it (the run says so), where the blade's end meets a steep wall at a
// grazing angle as well as elsewhere.
TEST(OperationPlan, EveryPlannedIncisionOpensTheDrawnHeart) {
    const std::vector<test::RealCase> real = test::real_cases();
    if (real.empty()) GTEST_SKIP() << "real data absent (../shared/data/real): nothing to plan on";
    test::TempDir dir;
    int opened = 0;
    for (const test::RealCase& c : real) {
        SCOPED_TRACE(c.name);
        const std::string vsd = test::vsd_options(c);
        if (vsd.empty()) continue;
        const fs::path scenario = dir / (c.name + ".h5");
        const auto build = test::heartprep("build " + quoted(c.label_map) + " -o " + quoted(scenario) + vsd + " -q" + c.label_options);
        ASSERT_EQ(build.exit_code, 0) << build.output;
        const fs::path csv = dir / (c.name + ".csv");
        const auto all = heartsim_command("plan-operation " + quoted(scenario) + " -o " + quoted(csv) + " --approach all");
        for (const std::string approach : {"right-atrial", "right-ventricular"}) {
            const fs::path planned = dir / (c.name + "." + approach + ".csv");
            if (!fs::exists(planned)) continue;  // refused, with its reason (OnEveryRealHeartTheExposureShowsTheDefect)
            SCOPED_TRACE(approach);
            const double cut_ms = printed_number(all.output, "\\(--approach " + approach + "\\)[\\s\\S]*?cuts from 0 to ([0-9.]+) ms");
            ASSERT_TRUE(std::isfinite(cut_ms)) << all.output;
            const auto run = heartsim_command("run " + quoted(scenario) + " --headless --backend cpu --trajectory " + quoted(planned) +
                                              " --seconds " + std::to_string(1e-3 * (cut_ms + 10.0)));
            ASSERT_EQ(run.exit_code, 0) << run.output;
            std::smatch m;
            const bool open = std::regex_search(run.output, m, std::regex("incision: the detailed mesh opened along 1 stroke\\(s\\)"));
            EXPECT_TRUE(open) << run.output;
            std::printf("%s %s: %s\n", c.name.c_str(), approach.c_str(), open ? "the drawn heart opens" : "the drawn heart stays closed");
            opened += open ? 1 : 0;
        }
    }
    EXPECT_GT(opened, 0);
}
