// `heartsim` end to end: info, a headless run on both backends with the state file, and the
// error messages a user sees.
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/state.h"
#include "runtime/gl_context.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;

namespace {

test::CommandResult run_heartsim(const std::string& arguments) { return test::run_command(std::string(quoted(HEARTSIM_EXE)) + " " + arguments); }

bool have_gl(std::string* reason) {
    static int state = -1;
    static std::string why;
    if (state < 0) {
        try {
            GlContext::create_headless();
            state = 1;
        } catch (const std::exception& e) {
            why = e.what();
            state = 0;
        }
    }
    *reason = why;
    return state == 1;
}

const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border"); }

}  // namespace

TEST(HeartsimCli, InfoPrintsRendererAndLimits) {
    std::string reason;
    if (!have_gl(&reason)) GTEST_SKIP() << "no headless OpenGL 4.3 device: " << reason;
    const auto run = run_heartsim("info");
    EXPECT_EQ(run.exit_code, 0) << run.output;
    for (const char* word : {"renderer", "version", "max SSBO size", "work groups", "texture size"})
        EXPECT_NE(run.output.find(word), std::string::npos) << word << "\n" << run.output;
}

TEST(HeartsimCli, HeadlessRunOnBothBackendsWritesTheState) {
    test::TempDir dir;
    // A probe pressed 1 mm into the phantom's side, read from its rest positions.
    const Scenario scenario = read_scenario(phantom());
    std::size_t right = 0;
    const auto& rest = scenario.lattice.particles.rest_position;
    for (std::size_t i = 0; i < rest.size(); ++i)
        if (rest[i][0] > rest[right][0]) right = i;
    const double r = 1.5 * scenario.lattice.spacing;
    std::ofstream(dir / "t.csv") << "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n"
                                 << "0,0,probe," << rest[right][0] + r + 0.5 << "," << rest[right][1] << "," << rest[right][2]
                                 << ",1,0,0,0," << r << "," << r << "," << r << ",0\n"
                                 << 50 * scenario.solver.dt_ms << ",0,probe," << rest[right][0] + r - 1.0 << "," << rest[right][1] << ","
                                 << rest[right][2] << ",1,0,0,0," << r << "," << r << "," << r << ",0\n";
    std::string reason;
    std::vector<std::string> backends = {"cpu"};
    if (have_gl(&reason)) backends.push_back("gl");
    else std::printf("gl skipped: %s\n", reason.c_str());
    std::vector<SimulationState> states;
    for (const auto& backend : backends) {
        const fs::path out = dir / (backend + ".h5");
        const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend " + backend + " --steps 60 --trajectory " +
                                  quoted(dir / "t.csv") + " --save-state " + quoted(out) + " --stats");
        ASSERT_EQ(run.exit_code, 0) << run.output;
        EXPECT_NE(run.output.find("simulation step"), std::string::npos) << run.output;
        EXPECT_NE(run.output.find("force buffer"), std::string::npos) << run.output;
        states.push_back(read_state(out));
        EXPECT_EQ(states.back().backend, backend);
        EXPECT_EQ(states.back().steps, 60);
        EXPECT_EQ(states.back().positions.size(), rest.size());
        EXPECT_EQ(states.back().kind[0], 1);
        EXPECT_GT(states.back().particles[0], 0);
    }
    if (states.size() == 2) {
        double error = 0;
        for (std::size_t i = 0; i < rest.size(); ++i)
            for (int k = 0; k < 3; ++k) error = std::max(error, double(std::abs(states[0].positions[i][k] - states[1].positions[i][k])));
        EXPECT_LT(error, 1e-3);
    }
}

TEST(HeartsimCli, ErrorsNameTheCause) {
    test::TempDir dir;
    Scenario scenario = read_scenario(phantom());
    scenario.packing.reset();
    scenario.simulation_surface.reset();
    scenario.mapping.reset();
    write_scenario(dir / "unpacked.h5", scenario);
    auto run = run_heartsim("run " + quoted(dir / "unpacked.h5") + " --headless --backend cpu --steps 1");
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("/packing is missing"), std::string::npos) << run.output;

    // Without a display the window mode cannot start: it must say so and point to --headless.
    run = test::run_command("env -u DISPLAY -u WAYLAND_DISPLAY " + std::string(HEARTSIM_EXE) + " run " + quoted(phantom()) +
                            " --backend cpu --steps 1");
    EXPECT_NE(run.exit_code, 0);
    EXPECT_NE(run.output.find("--headless"), std::string::npos) << run.output;

    run = run_heartsim("run " + quoted(phantom()) + " --headless --backend vulkan");
    EXPECT_NE(run.exit_code, 0);

    run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --probe 1,2,3");
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("--probe"), std::string::npos) << run.output;
}
