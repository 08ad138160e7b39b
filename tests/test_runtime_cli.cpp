// `heartsim` end to end: info, a headless run on both backends with the state file, and the
// error messages a user sees.
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/state.h"
#include "formats/xdmf.h"
#include "runtime/gl/gl_context.h"

#include <gtest/gtest.h>

#include <regex>

#include <algorithm>
#include <array>
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
    // The verdict: the backend a session will use with this device, and a factor measured here.
    const bool software = run.output.find("llvmpipe") != std::string::npos || run.output.find("softpipe") != std::string::npos;
    EXPECT_NE(run.output.find(software ? "a run without --backend (a window, a haptic session, headless) simulates on the cpu backend"
                                            : "sessions simulate on the gl backend"),
              std::string::npos)
        << run.output;
    const auto at = run.output.find("real-time factor of ");
    ASSERT_NE(at, std::string::npos) << run.output;
    const double factor = std::atof(run.output.c_str() + at + std::strlen("real-time factor of "));
    EXPECT_GT(factor, 0.0) << run.output;
    EXPECT_NE(run.output.find(software ? "on the cpu backend (substep" : "on the gl backend (substep"), std::string::npos) << run.output;
    // One speed verdict with the mass scaling a session would take: a scale of the governor's
    // ladder, and a predicted factor between the measured one and S times it (mass scaling
    // lengthens the step by between √S and S: stiffness- and damping-limited).
    std::smatch m;
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex("speed: .*mass scale ([0-9]+)(, ([0-9.]+)× predicted| \\(([0-9.]+)× predicted)?"))) << run.output;
    const double scale = std::stod(m[1]);
    EXPECT_TRUE(scale == 1 || scale == 2 || scale == 4 || scale == 8 || scale == 16) << run.output;
    if (m[3].matched || m[4].matched) {
        const double predicted = std::stod(m[3].matched ? std::string(m[3]) : std::string(m[4]));
        EXPECT_GE(predicted, 0.99 * factor) << run.output;
        EXPECT_LE(predicted, 1.01 * scale * factor + 0.01) << run.output;
    }
}

// Both headless ways in reach the same GL: the EGL device platform (NVIDIA's headless way, here
// Mesa's software device) and Mesa's surfaceless platform; the run's state is the same on both.
TEST(HeartsimCli, BothHeadlessEglPlatformsGiveTheSameRun) {
    std::string reason;
    if (!have_gl(&reason)) GTEST_SKIP() << "no headless OpenGL 4.3 device: " << reason;
    test::TempDir dir;
    std::vector<std::vector<std::array<float, 3>>> positions;
    for (const char* platform : {"device", "surfaceless"}) {
        const std::string env = std::string("HEARTSIM_EGL=") + platform + " ";
        const auto info = test::run_command(env + quoted(HEARTSIM_EXE) + " info");
        if (info.exit_code == 3 && std::string(platform) == "device") GTEST_SKIP() << "this EGL has no device platform: " << info.output;
        ASSERT_EQ(info.exit_code, 0) << info.output;
        EXPECT_NE(info.output.find(std::string("EGL ") + platform), std::string::npos) << info.output;
        const fs::path state = dir.path() / (std::string(platform) + ".h5");
        const auto run = test::run_command(env + quoted(HEARTSIM_EXE) + " run " + quoted(phantom()) +
                                           " --headless --backend gl --steps 20 --gravity 0 0.02 0 --save-state " + quoted(state));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        positions.push_back(read_state(state).positions);
    }
    ASSERT_EQ(positions[0].size(), positions[1].size());
    EXPECT_TRUE(positions[0] == positions[1]) << "the same GL driver on two platforms ran differently";
    const auto bogus = test::run_command("HEARTSIM_EGL=vulkan " + std::string(quoted(HEARTSIM_EXE)) + " info");
    EXPECT_EQ(bogus.exit_code, 3) << bogus.output;
    EXPECT_NE(bogus.output.find("HEARTSIM_EGL=vulkan"), std::string::npos) << bogus.output;
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
        // /visual/positions: the deformed detailed mesh. An independent float64 reading of the
        // documented formula (docs/scenario-format.md, /mapping) at the state's particle
        // positions gives the same mesh.
        const SimulationState& state = states.back();
        ASSERT_TRUE(scenario.visual && scenario.mapping && scenario.simulation_surface);
        ASSERT_EQ(state.visual_positions.size(), scenario.visual->positions.size());
        const auto& x = state.positions;
        auto at = [&](std::int32_t i) { return Eigen::Vector3d(x[std::size_t(i)][0], x[std::size_t(i)][1], x[std::size_t(i)][2]); };
        std::vector<Eigen::Vector3d> normal(x.size(), Eigen::Vector3d::Zero());
        const auto& surface = *scenario.simulation_surface;
        for (std::size_t t = 0; t < surface.triangles.size(); ++t)
            if (surface.normal_weight[t]) {
                const auto& tri = surface.triangles[t];
                const Eigen::Vector3d area = (at(tri[1]) - at(tri[0])).cross(at(tri[2]) - at(tri[0]));
                for (std::int32_t i : tri) normal[std::size_t(i)] += area;
            }
        double error = 0.0, moved = 0.0;
        const auto& m = *scenario.mapping;
        for (std::size_t v = 0; v < state.visual_positions.size(); ++v) {
            Eigen::Vector3d p = Eigen::Vector3d::Zero(), n = Eigen::Vector3d::Zero();
            for (std::size_t k = 0; k < 8; ++k) p += double(m.weights[v][k]) * at(m.particles[v][k]);
            const auto& tri = surface.triangles[std::size_t(m.triangle[v])];
            for (std::size_t k = 0; k < 3; ++k)
                if (normal[std::size_t(tri[k])].norm() > 0) n += double(m.barycentric[v][k]) * normal[std::size_t(tri[k])].normalized();
            if (n.norm() > 0) p += double(m.offset[v]) * n.normalized();
            const auto& saved = state.visual_positions[v];
            const auto& rest_v = scenario.visual->positions[v];
            error = std::max(error, (p - Eigen::Vector3d(saved[0], saved[1], saved[2])).norm());
            moved = std::max(moved, (p - Eigen::Vector3d(rest_v[0], rest_v[1], rest_v[2])).norm());
        }
        std::printf("%s: /visual/positions against an independent float64 evaluation: max %.3g mm (the mesh moved up to %.3f mm)\n",
                    backend.c_str(), error, moved);
        EXPECT_LT(error, 1e-3);
        EXPECT_GT(moved, 0.1);
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
    EXPECT_EQ(run.exit_code, 1) << run.output;
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

TEST(HeartsimCli, OutOfMemoryIsOneLineAndExit7) {
    // Out of memory injected with address-space limits rising from 32 MiB until the run fits
    // (test_support.h): a scripted run that writes its state, and a haptic session with two
    // devices that writes its recording. Every limit below that ends with exit 7 and the one line
    // "heartsim: error: out of memory while …": not "std::bad_alloc", not oneTBB's or std::thread's
    // "Resource temporarily unavailable", and not a scenario "damaged" (exit 1) because HDF5 could
    // not allocate the buffer to read it into. The cpu backend: under such limits Mesa's llvmpipe
    // itself crashes (docs/benchmarks.md, "Fuzzing").
    if (test::under_address_sanitizer) GTEST_SKIP() << "address-space limits do not work under AddressSanitizer";
    test::TempDir dir;
    const fs::path samples = fs::path(HEARTSIM_SOURCE_DIR) / "samples";
    test::expect_clean_out_of_memory(quoted(HEARTSIM_EXE) + " run " + quoted(phantom()) +
                                         " --headless --backend cpu --steps 20 --trajectory " +
                                         quoted(samples / "probe_and_grab_phantom.csv") + " --save-state " + quoted(dir / "state.h5"),
                                     "heartsim: error: out of memory while ");
    test::expect_clean_out_of_memory(quoted(HEARTSIM_EXE) + " run " + quoted(phantom()) + " --headless --backend cpu --seconds 0.1" +
                                         " --device scripted:" + quoted(samples / "haptics/grab_phantom.csv") +
                                         " --device simulated:" + quoted(samples / "haptics/press_phantom.csv") +
                                         " --haptic-priority normal --record " + quoted(dir / "session.h5"),
                                     "heartsim: error: out of memory while ",
                                     // A session that ran out of memory while writing its recording keeps
                                     // its journal for `heartsim recover`, and the next --record to that
                                     // path refuses to replace it: each attempt starts without one.
                                     [&] { fs::remove(dir / "session.h5.journal"); });
}

TEST(HeartsimCli, AnOutputNeverReplacesAnInput) {
    // --save-state or --stats-csv naming the scenario being run (or two outputs naming one file)
    // is refused before the run, and the scenario is left as it was, byte for byte.
    test::TempDir dir;
    const fs::path scenario = dir / "case.h5";
    fs::copy_file(phantom(), scenario);
    auto bytes = [](const fs::path& path) {
        std::ifstream in(path, std::ios::binary);
        return std::string(std::istreambuf_iterator<char>(in), {});
    };
    const fs::path script = dir / "press.csv";
    fs::copy_file(fs::path(HEARTSIM_SOURCE_DIR) / "samples/haptics/press_phantom.csv", script);
    const std::string before = bytes(scenario), script_before = bytes(script);
    const std::string run = "run " + quoted(scenario) + " --headless --backend cpu --steps 1 ";
    struct Case {
        std::string arguments, mentions;
    };
    for (const Case& c : std::vector<Case>{
             {"--save-state " + quoted(scenario), "--save-state " + scenario.string() + ": that is the scenario being run"},
             {"--stats-csv " + quoted(scenario), "--stats-csv " + scenario.string() + ": that is the scenario being run"},
             {"--save-state " + quoted(dir / "s.h5") + " --stats-csv " + quoted(dir / "s.h5"), "name the same file"},
             {"--device simulated:" + quoted(script) + " --stats-csv " + quoted(script),
              "--stats-csv " + script.string() + ": that is the file of --device simulated:" + script.string()},
             // The ParaView description written beside a saved state or a recording (NAME.xmf2):
             // it replaced the scenario's own, or another output, and the run exited 0.
             {"--save-state " + quoted(dir / "case.hdf5"), "its ParaView description " + (dir / "case.xmf2").string() + " would replace the scenario's own"},
             {"--save-state " + quoted(dir / "s.h5") + " --stats-csv " + quoted(dir / "s.xmf2"), "is the file --stats-csv names"},
             {"--device simulated:" + quoted(script) + " --record " + quoted(dir / "r.h5") + " --save-state " + quoted(dir / "r.hdf5"),
              "is also --record's; give them different names"},
         }) {
        const auto result = test::run_command("(" + quoted(HEARTSIM_EXE) + " " + run + c.arguments + " 2>&1 >/dev/null)");
        EXPECT_EQ(result.exit_code, 2) << c.arguments << "\n" << result.output;
        EXPECT_NE(result.output.find(c.mentions), std::string::npos) << "'" << c.mentions << "' not in: " << result.output;
    }
    EXPECT_EQ(bytes(scenario), before) << "the scenario was changed";
    EXPECT_EQ(bytes(script), script_before) << "the device's script was changed";
    EXPECT_FALSE(fs::exists(dir / "s.h5"));
}

TEST(HeartsimCli, PathsThatCannotBeOpenedAreOneLineBeforeTheRun) {
    // Inputs that exist but cannot be read as files (a folder where a file is expected, a path
    // through a regular file; tests run as root, so permissions would stop nothing): exit 1; outputs
    // whose place cannot hold a file: exit 7 (docs/user-guide.md, "Exit status"). Each with one line
    // naming the path, before any simulation step (an output used to fail only after the whole run;
    // a folder given as a device file read as "no rows"; a folder given as the scenario was CLI11's
    // exit 105 in two lines).
    test::TempDir dir;
    std::ofstream(dir / "file.txt") << "a regular file";
    fs::create_directory(dir / "folder.h5");
    fs::create_directory(dir / "folder.csv");
    fs::create_directory(dir / "folder.xmf2");
    const std::string run = "run " + quoted(phantom()) + " --headless --backend cpu ";
    struct Case {
        std::string arguments, message;
        int exit_code;
    };
    const std::vector<Case> cases = {
        {"run " + quoted(dir / "folder.h5") + " --headless --backend cpu", "folder.h5", 1},
        {"run " + quoted(dir / "file.txt/x.h5") + " --headless --backend cpu", "file.txt/x.h5", 1},
        {run + "--trajectory " + quoted(dir / "folder.csv"), "folder.csv", 1},
        {run + "--replay " + quoted(dir / "folder.h5"), "folder.h5", 1},
        {run + "--seconds 0.1 --device scripted:" + quoted(dir / "folder.csv"), "folder.csv: is a folder; expected a CSV file", 1},
        {run + "--seconds 0.1 --device simulated:" + quoted(dir / "folder.csv"), "folder.csv: is a folder; expected a CSV file", 1},
        {run + "--seconds 0.1 --device scripted:" + quoted(dir / "folder.h5"), "folder.h5: not a regular file", 1},
        {run + "--steps 5 --save-state " + quoted(dir / "file.txt/state.h5"), "--save-state " + (dir / "file.txt/state.h5").string() + ": " + (dir / "file.txt").string() + " is a file, not a folder", 7},
        {run + "--steps 5 --save-state " + quoted(dir / "folder.h5"), "--save-state " + (dir / "folder.h5").string() + ": is a folder, expected a file name", 7},
        // The description beside it: a folder there failed after the run, leaving the state.
        {run + "--steps 5 --save-state " + quoted(dir / "folder.hdf5"), "--save-state " + (dir / "folder.xmf2").string() + ": is a folder, expected a file name (the ParaView description written beside", 7},
        {run + "--steps 5 --screenshot " + quoted(dir / "file.txt/shot.png"), "--screenshot", 7},
        {run + "--steps 5 --stats-csv " + quoted(dir / "file.txt/stats.csv"), "--stats-csv", 7},
    };
    for (const auto& [arguments, message, exit_code] : cases) {
        const auto result = test::run_command("(" + quoted(HEARTSIM_EXE) + " " + arguments + " 2>&1 >/dev/null)");
        EXPECT_EQ(result.exit_code, exit_code) << arguments << "\n" << result.output;
        EXPECT_EQ(result.output.rfind("heartsim: error: ", 0), 0u) << arguments << "\n" << result.output;
        EXPECT_EQ(std::count(result.output.begin(), result.output.end(), '\n'), 1) << arguments << "\n" << result.output;
        EXPECT_NE(result.output.find(message), std::string::npos) << "'" << message << "' not in: " << result.output;
    }
    // Refused before the run: no step was taken.
    const auto refused = run_heartsim(run + "--steps 5 --save-state " + quoted(dir / "file.txt/state.h5"));
    EXPECT_EQ(refused.output.find("ran "), std::string::npos) << refused.output;
    std::size_t entries = 0;
    for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir.path())) ++entries;
    EXPECT_EQ(entries, 4u) << "a refused run left files behind";
}

TEST(HeartsimCli, ExitStatusFollowsTheTable) {
    // docs/user-guide.md, "Exit status", the codes of the command line and of the input files (3-6
    // and 7: HapticsCli, HeartsimCli.ErrorsNameTheCause, …PathsThatCannotBeOpened…); each failure
    // one line "heartsim: error: …", CLI11's own 104-114 never.
    test::TempDir dir;
    std::ofstream(dir / "corrupt.h5") << "not a scenario";
    std::ofstream(dir / "bad.csv") << "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n0,0,probe,0,0,x,1,0,0,0,3,3,3,0\n";
    const std::string run = "run " + quoted(phantom()) + " --headless --backend cpu ";
    struct Case {
        std::string arguments;
        int exit_code;
        std::string mentions;
    };
    const std::vector<Case> cases = {
        // The trajectory's own error names its file and line, with no scenario before it
        // ("phantom.h5: bad.csv line 2 …" named the wrong file first).
        {run + "--steps 1 --trajectory " + quoted(dir / "bad.csv"), 1, "heartsim: error: " + (dir / "bad.csv").string() + " line 2 column z: 'x'"},
        {run + "--steps 1 --frobnicate", 2, "--frobnicate"},                    // unknown option
        {run + "--steps 1 --draw-share nan", 2, "--draw-share: 'nan' is not a finite number"},
        // A number whose help names its type otherwise (S) is checked as finite too: CLI11's
        // Range lets NaN through.
        {run + "--steps 1 --igtl 18944 --igtl-wait nan", 2, "--igtl-wait: 'nan' is not a finite number"},
        {run + "--steps 1 --leak-test nan", 2, "--leak-test: 'nan' is not a finite number"},
        {run + "--steps 1 --look-at 1e30,0,0 --screenshot " + quoted(dir / "far.png"), 2, "X is 1e+30 mm, outside the plausible range"},
        {run + "--steps -1", 2, "--steps: must be 0 or more, not -1"},
        {run + "--stepps 1", 2, "not expected: --stepps 1 (--stepps: did you mean --steps?) (heartsim run --help"},
        {"recover", 2, "journal is required (heartsim recover --help lists the options)"},
        {"bogus", 2, "'bogus' is neither a command (info, run, recover, plan-incision, plan-repair, plan-operation) nor a scenario file"},
        {run + "--steps 1 --save-state " + quoted(dir / "state.png"), 2, "state.png: the state is an HDF5 file"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.jpg"), 2, "shot.jpg: the screenshot is a PNG picture"},
        {"run", 2, "scenario"},                                                 // missing argument
        // An empty value (a script's unset variable) read as the option not given: the run went on
        // without its gesture, its state or its stats.
        {"run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --trajectory ''", 2,
         "--trajectory: the value is empty; give one, or leave the option out"},
        {"run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --stats-csv ''", 2, "--stats-csv: the value is empty"},
        {"run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --probe ''", 2, "--probe: the value is empty"},
        {"run '' --headless", 2, "the scenario given is an empty name; give a file"},
        // CLI11's own wording ("Could not convert: --steps = …", "At Most 3 required but received
        // 4", "Value 99 not in range 100.000000 to 10000.000000"), said in the programs' words.
        {"run " + quoted(phantom()) + " --headless --steps 99999999999999", 2, "--steps: '99999999999999' is not a whole number it takes"},
        {"run " + quoted(phantom()) + " --headless --steps 1 --gravity 1 2 3 4", 2, "--gravity takes at most 3 values, not 4"},
        {"run " + quoted(phantom()) + " --headless --steps 1 --haptic-rate 99", 2, "--haptic-rate: 99 is outside [100, 10000]"},
        {run + "--steps 1 --picking-refresh 5", 2, "--picking-refresh paces the picking buffer: it needs --contact picking"},
        {"rn " + quoted(phantom()), 2, "unknown command 'rn' (did you mean 'run'?)"},  // a typo of a command
        {run + "--steps 1 --draw-share 5", 2, "--draw-share"},                  // out of range
        {run + "--steps 1 --view sideways", 2, "--view"},                       // not one of its values
        {run + "--steps 1 --seconds 1", 2, "give --steps or --seconds"},        // contradictory
        {run + "--steps 1 --size 10x", 2, "--size"},
        {run + "--steps 1 --contact picking", 2, "--contact picking|search needs --backend gl"},
        {run + "--steps 1 --probe 1,2,3", 2, "--probe"},
        // --clip: a point and a normal, six finite numbers, the normal not zero; only where a picture is drawn.
        {run + "--steps 1 --clip centre", 2, "--clip cuts the heart open in the picture: headless it needs --screenshot OUT.png"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip 1,2,3", 2,
         "--clip '1,2,3': expected PX,PY,PZ,NX,NY,NZ (a point of the plane and its normal, mm, world LPS"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip middle", 2, "--clip 'middle': expected PX,PY,PZ,NX,NY,NZ"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip 0,0,nan,0,1,0", 2, "--clip '0,0,nan,0,1,0': 'nan' is not a finite number"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip 0,0,0,1e999,0,0", 2, "'1e999' is not a finite number"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip 0,0,0,0,0,0", 2, "--clip '0,0,0,0,0,0': the normal (0, 0, 0) is zero"},
        {run + "--steps 1 --screenshot " + quoted(dir / "shot.png") + " --clip 2e6,0,0,0,1,0", 2, "--clip '2e6,0,0,0,1,0': PX is 2e+06 mm, outside the plausible range"},
        {"run " + quoted(dir / "missing.h5") + " --headless --backend cpu --steps 1", 1, "missing.h5: file not found"},
        {"run " + quoted(dir / "corrupt.h5") + " --headless --backend cpu --steps 1", 1, "corrupt.h5: not an HDF5 file"},
        {run + "--steps 1 --trajectory " + quoted(dir / "none.csv"), 1, "none.csv: file not found"},
    };
    for (const auto& [arguments, exit_code, mentions] : cases) {
        const auto result = test::run_command("(" + quoted(HEARTSIM_EXE) + " " + arguments + " 2>&1 >/dev/null)");
        EXPECT_EQ(result.exit_code, exit_code) << arguments << "\n" << result.output;
        EXPECT_EQ(result.output.rfind("heartsim: error: ", 0), 0u) << arguments << "\n" << result.output;
        EXPECT_EQ(std::count(result.output.begin(), result.output.end(), '\n'), 1) << arguments << "\n" << result.output;
        EXPECT_NE(result.output.find(mentions), std::string::npos) << "'" << mentions << "' not in: " << result.output;
    }
    const auto help = run_heartsim("run --help");
    EXPECT_EQ(help.exit_code, 0);
    EXPECT_NE(help.output.find("Exit status: 0 success, 1 input error"), std::string::npos) << help.output;
}

// The .xmf2 beside a scenario where the scenario belongs (ParaView opens that one): one line that
// says what it is and names the .h5 beside it to give instead, or, where that .h5 is not there,
// the name it should have; exit 1 (a bad input).
TEST(HeartsimCli, AParaViewDescriptionGivenAsTheScenarioNamesTheH5BesideIt) {
    const fs::path description = xdmf_beside(phantom());
    ASSERT_TRUE(fs::exists(description));
    const auto beside = test::run_command("(" + quoted(HEARTSIM_EXE) + " run " + quoted(description) + " --headless --backend cpu --steps 1 2>&1 >/dev/null)");
    EXPECT_EQ(beside.exit_code, 1) << beside.output;
    EXPECT_EQ(std::count(beside.output.begin(), beside.output.end(), '\n'), 1) << beside.output;
    EXPECT_NE(beside.output.find(description.string() + ": not an HDF5 file: it is ParaView's description (XDMF) of " + phantom().string() +
                                 " beside it, which holds the data: give " + phantom().string()),
              std::string::npos)
        << beside.output;
    test::TempDir dir;
    fs::copy_file(description, dir / "alone.xmf2");
    const auto alone = test::run_command("(" + quoted(HEARTSIM_EXE) + " run " + quoted(dir / "alone.xmf2") + " --headless --backend cpu --steps 1 2>&1 >/dev/null)");
    EXPECT_EQ(alone.exit_code, 1) << alone.output;
    EXPECT_NE(alone.output.find("alone.xmf2: not an HDF5 file: it is ParaView's description (XDMF) of an .h5 that holds the data and should "
                                "lie beside it (" + (dir / "alone.h5").string() + ", not there): give that .h5"),
              std::string::npos)
        << alone.output;
}

// A label map where the scenario belongs (the first thing a new user tries): one line saying
// what to run first, exit 1 (a bad input), for `run` and for the plain launch alike.
TEST(HeartsimCli, ALabelMapGivenAsTheScenarioSaysToBuildItFirst) {
    const std::string sample = std::string(HEARTSIM_SOURCE_DIR) + "/samples/phantom.nii.gz";
    for (const std::string& command : {std::string(" "), std::string(" run --headless ")}) {
        const auto run = test::run_command(test::quoted(HEARTSIM_EXE) + command + test::quoted(sample));
        EXPECT_EQ(run.exit_code, 1) << run.output;
        EXPECT_NE(run.output.find("a label map, not a scenario: build one first, `heartprep build"), std::string::npos) << run.output;
    }
}

// Without --backend, a headless run on a software rasteriser simulates on the cpu backend (about
// ten times faster there) and says so in its first line; one that asks for --contact picking,
// which only the gl backend has, keeps gl. On a hardware OpenGL device both keep gl.
TEST(HeartsimCli, AHeadlessRunWithoutBackendTakesTheFasterOneAndSaysSo) {
    std::string reason;
    if (!have_gl(&reason)) GTEST_SKIP() << "no headless OpenGL 4.3 device: " << reason;
    const auto info = run_heartsim("info");
    const bool software = info.output.find("llvmpipe") != std::string::npos || info.output.find("softpipe") != std::string::npos;
    const auto plain = run_heartsim("run " + quoted(phantom()) + " --headless --steps 2");
    ASSERT_EQ(plain.exit_code, 0) << plain.output;
    EXPECT_EQ(plain.output.rfind("headless: the OpenGL device is ", 0) == 0, software) << plain.output;
    EXPECT_NE(plain.output.find(software ? "cpu backend: " : "gl backend: "), std::string::npos) << plain.output;
    const auto picking = run_heartsim("run " + quoted(phantom()) + " --headless --steps 2 --contact picking");
    ASSERT_EQ(picking.exit_code, 0) << picking.output;
    EXPECT_NE(picking.output.find("gl backend: "), std::string::npos) << picking.output;
    EXPECT_EQ(picking.output.find("software rasteriser"), std::string::npos) << picking.output;
}
