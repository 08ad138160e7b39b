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
#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
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
