// The finite-element reference of the felt force (tests/bench/fe_indentation.py, CalculiX) against
// Hertz's closed form at small depth: a rigid sphere (R = 5 mm) pressed 0.05 R and 0.1 R into the
// nearly incompressible (nu = 0.49) neo-Hookean cylinder on a coarse mesh gives F / F_Hertz within
// 4 % of 1 and a force growing as d^1.5 between the two depths (the exponent within 0.1). The
// script itself fails when the bottom's reaction and the sphere's differ (equilibrium). Skips with
// a message where CalculiX's ccx or python3 is absent (scripts/install-deps.sh installs both).
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

namespace heartsim {
namespace {

TEST(FeIndentation, ForceApproachesHertzAtSmallDepth) {
    if (test::run_command("command -v ccx").exit_code != 0) GTEST_SKIP() << "CalculiX's ccx is not on the PATH (Debian: calculix-ccx)";
    if (test::run_command("command -v python3").exit_code != 0) GTEST_SKIP() << "python3 is not on the PATH";
    test::TempDir dir;
    const std::string csv = (dir / "fe.csv").string();
    const std::string script = std::string(HEARTSIM_SOURCE_DIR) + "/tests/bench/fe_indentation.py";
    const test::CommandResult run = test::run_command("python3 " + test::quoted(script) +
                                                      " --nu 0.49 --depths 0.05,0.1 --element-size 0.4 --outer-size 6 --threads 1"
                                                      " --workdir " + test::quoted(dir / "work") + " --csv " + test::quoted(dir / "fe.csv"));
    ASSERT_EQ(run.exit_code, 0) << run.output;

    std::ifstream in(csv);
    std::string line;
    ASSERT_TRUE(std::getline(in, line)) << "empty " << csv;
    EXPECT_EQ(line, "nu,d_over_R,depth_mm,force_N,force_over_hertz");
    std::map<double, double> force, ratio;  // by d/R
    while (std::getline(in, line)) {
        std::istringstream fields(line);
        double nu = 0, d = 0, depth = 0, f = 0, r = 0;
        char comma = 0;
        ASSERT_TRUE(fields >> nu >> comma >> d >> comma >> depth >> comma >> f >> comma >> r) << line;
        EXPECT_DOUBLE_EQ(nu, 0.49);
        EXPECT_NEAR(depth, 5.0 * d, 1e-9);
        // Hertz for E = 10 kPa, R = 5 mm: 4/3 · E/(1 − ν²) · √R · d^1.5 (N, mm).
        const double hertz = 4.0 / 3.0 * 0.01 / (1 - nu * nu) * std::sqrt(5.0) * std::pow(depth, 1.5);
        EXPECT_NEAR(f / hertz, r, 1e-4) << line;
        force[d] = f;
        ratio[d] = f / hertz;
    }
    ASSERT_EQ(force.size(), 2u) << run.output;
    for (const auto& entry : ratio) EXPECT_NEAR(entry.second, 1.0, 0.04) << "d/R = " << entry.first << "\n" << run.output;
    const double exponent = std::log(force[0.1] / force[0.05]) / std::log(2.0);
    EXPECT_NEAR(exponent, 1.5, 0.1) << run.output;
}

}  // namespace
}  // namespace heartsim
