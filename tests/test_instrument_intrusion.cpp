// A patch or a needle never touches the tissue's solver (runtime/surgery/repair.h), so nothing
// stops one carried through intact tissue: the run reports it (TissueIntrusion), as a user sees it
// in `heartsim run`'s summary. On the phantom's two ventricles with a VSD: a patch carried from
// outside the heart straight through the intact free wall to the septum is reported; the same
// carry through a planned incision's opening is not; a needle tying plan-repair's stitches at the
// septum's surface is not, nor one biting deep where it ties; one that goes deep and ties nothing is.
#include "runtime/core/trajectory.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <regex>
#include <sstream>
#include <vector>

using namespace heartsim;
namespace fs = std::filesystem;
using test::quoted;

namespace {

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

/// The phantom's two ventricles with an 8 mm VSD carved through its septum at a known point, 8,000
/// particles (as tests/test_operation_plan.cpp builds it).
const fs::path& vsd_phantom() {
    static test::TempDir dir;
    static fs::path built;
    if (built.empty()) {
        const fs::path labels = dir / "phantom.nii.gz", scenario = dir / "vsd.h5";
        const auto phantom = test::heartprep("phantom -o " + quoted(labels) + " --vsd-diameter 0");
        if (phantom.exit_code != 0) throw std::runtime_error(phantom.output);
        const auto build = test::heartprep("build " + quoted(labels) + " --defect vsd --at=-21.1,-1.1,-1.5 --diameter 8 --particles 8000 -q -o " +
                                           quoted(scenario));
        if (build.exit_code != 0) throw std::runtime_error(build.output);
        built = scenario;
    }
    return built;
}

double printed_number(const std::string& output, const std::string& pattern) {
    std::smatch m;
    return std::regex_search(output, m, std::regex(pattern)) ? std::stod(m[1]) : NAN;
}

/// The summary's lines about instruments in tissue.
std::vector<std::string> intrusion_lines(const std::string& output) {
    std::vector<std::string> lines;
    std::istringstream in(output);
    for (std::string line; std::getline(in, line);)
        if (line.rfind("instruments through tissue:", 0) == 0) lines.push_back(line);
    return lines;
}

/// The CSV's rows (no header, no comment) of `hand` holding `kind`.
std::vector<std::string> rows_of(const fs::path& csv, int hand, const std::string& kind) {
    std::ifstream in(csv);
    std::vector<std::string> rows;
    std::string prefix = ",";
    prefix += std::to_string(hand);
    prefix += ',';
    prefix += kind;
    prefix += ',';
    for (std::string line; std::getline(in, line);)
        if (line.find(prefix) != std::string::npos) rows.push_back(line);
    return rows;
}

/// A row with its time and its grab replaced.
std::string retimed(const std::string& row, double time_ms, int grab) {
    std::string out = std::to_string(time_ms);
    out += row.substr(row.find(','), row.rfind(',') - row.find(','));
    out += ',';
    out += std::to_string(grab);
    return out;
}

}  // namespace

// plan-operation's patch goes from 20 mm outside the opening to the septum. Carried along the same
// straight line with no incision made, it crosses the intact free wall (about 6 mm of the lattice's
// tissue along the line, on the phantom): the run names the patch, more than 2 mm deep, while it
// is on its way; the same carry in the planned operation, through the opening the retractors hold
// apart, meets no tissue, nor does the needle that follows it in.
TEST(InstrumentIntrusion, APatchCarriedThroughTheIntactWallIsReportedAndThroughTheOpeningIsNot) {
    test::TempDir dir;
    const fs::path plan = dir / "op.csv", wall = dir / "wall.csv";
    const auto planned = heartsim_command("plan-operation " + quoted(vsd_phantom()) + " -o " + quoted(plan) + " --approach right-ventricular");
    ASSERT_EQ(planned.exit_code, 0) << planned.output;
    const std::vector<std::string> patch = rows_of(plan, 0, "patch");
    ASSERT_GE(patch.size(), 2u);
    {
        std::ofstream out(wall);
        out << "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n"
            << retimed(patch.front(), 0, 0) << "\n"
            << retimed(patch[1], 400, 0) << "\n"
            << retimed(patch[1], 420, 1) << "\n";
    }
    const auto through = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(wall) +
                                          " --seconds 0.5");
    ASSERT_EQ(through.exit_code, 0) << through.output;
    const std::vector<std::string> lines = intrusion_lines(through.output);
    ASSERT_FALSE(lines.empty()) << through.output;
    double deepest = 0.0;
    for (const std::string& line : lines) {
        EXPECT_NE(line.find("the patch (hand 0) passed through tissue at ("), std::string::npos) << line;
        const double depth = printed_number(line, "mm, ([0-9.]+) mm deep, from ");
        const double from = printed_number(line, "deep, from ([0-9.]+) to"), to = printed_number(line, " to ([0-9.]+) ms");
        EXPECT_TRUE(std::isfinite(depth) && from <= to && to <= 400.0) << line;
        if (depth > deepest) deepest = depth;
    }
    EXPECT_GT(deepest, 2.0) << through.output;

    const double seconds = printed_number(planned.output, "run it .*--seconds ([0-9.]+)");
    ASSERT_TRUE(std::isfinite(seconds)) << planned.output;
    const auto operation = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(plan) +
                                            " --seconds " + std::to_string(seconds));
    ASSERT_EQ(operation.exit_code, 0) << operation.output;
    EXPECT_EQ(intrusion_lines(operation.output), std::vector<std::string>{"instruments through tissue: none"}) << operation.output;
}

// plan-repair's needle ties each stitch where the patch meets the septum's surface: at the surface
// is no passage through tissue, and the run says none.
TEST(InstrumentIntrusion, ANeedleTyingAtTheSurfaceIsNotReported) {
    test::TempDir dir;
    const fs::path plan = dir / "repair.csv";
    const auto planned = heartsim_command("plan-repair " + quoted(vsd_phantom()) + " -o " + quoted(plan) + " --stitches=8");
    ASSERT_EQ(planned.exit_code, 0) << planned.output;
    ASSERT_GE(rows_of(plan, 1, "needle").size(), 8u);
    const double seconds = printed_number(planned.output, "run it .*--seconds ([0-9.]+)");
    ASSERT_TRUE(std::isfinite(seconds)) << planned.output;
    const auto run = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(plan) +
                                      " --seconds " + std::to_string(seconds));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("stitch 8 tied"), std::string::npos) << run.output;
    EXPECT_EQ(intrusion_lines(run.output), std::vector<std::string>{"instruments through tissue: none"}) << run.output;
}

// A run whose hands hold neither a patch nor a needle says nothing about them.
TEST(InstrumentIntrusion, ARunWithoutThemSaysNothing) {
    const auto run = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --steps 10");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_TRUE(intrusion_lines(run.output).empty()) << run.output;
}

// A needle's bite is where it should meet the tissue: plan-repair's needle sent 4 mm into the
// septum at each stitch site (deeper than a lattice spacing, which alone is "the surface"), tying
// there and drawn back out along its shaft, is not reported; the same needle sent as deep at the
// first site and drawn out without tying has passed through tissue for nothing, and is.
TEST(InstrumentIntrusion, ANeedlesOwnBiteIsNotReportedAndAPassThatTiesNothingIs) {
    test::TempDir dir;
    const fs::path plan = dir / "repair.csv";
    const auto planned = heartsim_command("plan-repair " + quoted(vsd_phantom()) + " -o " + quoted(plan) + " --stitches=8");
    ASSERT_EQ(planned.exit_code, 0) << planned.output;
    const double seconds = printed_number(planned.output, "run it .*--seconds ([0-9.]+)");
    ASSERT_TRUE(std::isfinite(seconds)) << planned.output;
    const Trajectory trajectory = read_trajectory(plan);
    // The sites: where the needle's grab turns on; each row there moved 4 mm in along its shaft.
    std::vector<Eigen::Vector3d> sites;
    for (const InstrumentKeyframe& k : trajectory.keyframes)
        if (k.hand == 1 && k.kind == InstrumentKind::needle && k.grab) sites.push_back(k.pose.position);
    ASSERT_EQ(sites.size(), 8u);
    auto write = [&](const fs::path& csv, bool tie_first) {
        Trajectory deep = trajectory;
        bool first = true;
        for (InstrumentKeyframe& k : deep.keyframes) {
            if (k.hand != 1 || k.kind != InstrumentKind::needle) continue;
            const auto site = std::find_if(sites.begin(), sites.end(), [&](const Eigen::Vector3d& s) { return (s - k.pose.position).norm() < 1e-9; });
            if (site == sites.end()) continue;
            const bool at_first = site == sites.begin();
            k.pose.position -= 4.0 * (k.pose.orientation.normalized() * Eigen::Vector3d::UnitZ());
            if (at_first && !tie_first && k.grab) k.grab = false, first = false;
        }
        EXPECT_EQ(first, tie_first);
        write_trajectory_csv(deep, csv);
    };
    const fs::path bites = dir / "bites.csv", untied = dir / "untied.csv";
    write(bites, true);
    write(untied, false);
    const auto tied = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(bites) +
                                       " --seconds " + std::to_string(seconds));
    ASSERT_EQ(tied.exit_code, 0) << tied.output;
    EXPECT_NE(tied.output.find("stitch 8 tied"), std::string::npos) << tied.output;
    EXPECT_EQ(intrusion_lines(tied.output), std::vector<std::string>{"instruments through tissue: none"}) << tied.output;

    const auto pass = heartsim_command("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(untied) +
                                       " --seconds " + std::to_string(seconds));
    ASSERT_EQ(pass.exit_code, 0) << pass.output;
    EXPECT_NE(pass.output.find("stitch 7 tied"), std::string::npos) << pass.output;
    const std::vector<std::string> lines = intrusion_lines(pass.output);
    ASSERT_EQ(lines.size(), 1u) << pass.output;
    EXPECT_NE(lines[0].find("the needle (hand 1) passed through tissue at ("), std::string::npos) << lines[0];
    const double depth = printed_number(lines[0], "mm, ([0-9.]+) mm deep, from ");
    EXPECT_GT(depth, 2.5) << lines[0];
    EXPECT_LT(depth, 5.0) << lines[0];
    std::printf("  a deep bite where it ties: none; a pass that ties nothing: %s\n", lines[0].c_str());
}
