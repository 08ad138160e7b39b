// `heartsim run … --device …` end to end (docs/haptics.md): two hands on the phantom for real seconds with
// a recording, the recording's contents, replay reproducing the forces bit for bit (cpu), replay
// catching a tampered recording, the scripted device replaying a recording's poses, --max-force,
// and the errors a user sees. Plus the command-line vocabulary in process (device specs, the
// simulated device file, instruments, the recording file's round trip).
#include "runtime_test_support.h"
#include "scenario_damage.h"
#include "test_support.h"

#include "incision_gesture.h"

#include "formats/recording.h"
#include "formats/state.h"
#include "formats/scenario.h"
#include "libmodel/stability.h"
#include "libmodel/errors.h"
#include "runtime/haptics/haptic_run.h"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <fstream>
#include <regex>

using namespace heartsim;
using namespace heartsim::haptics;
using test::quoted;
namespace fs = std::filesystem;

namespace {

test::CommandResult run_heartsim(const std::string& arguments) { return test::run_command(std::string(quoted(HEARTSIM_EXE)) + " " + arguments); }

fs::path sample(const std::string& name) { return fs::path(HEARTSIM_SOURCE_DIR) / "samples/haptics" / name; }

/// The shipped phantom at 12,000 particles (fast enough to follow real time on a loaded 2-core
/// machine within a factor of a few), base anchored, no gravity (samples/haptics/press_phantom.csv).
const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000"); }

/// One two-handed session recorded on the cpu backend, shared by the tests that read it.
struct RecordedSession {
    test::TempDir dir;
    fs::path file;
    test::CommandResult run;
};
const RecordedSession& two_hands() {
    static RecordedSession session;
    if (session.file.empty()) {
        session.file = session.dir / "rec.h5";
        session.run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device simulated:" + quoted(sample("press_phantom.csv")) +
                                   " --device scripted:" + quoted(sample("grab_phantom.csv")) + " --seconds 2 --record " + quoted(session.file));
    }
    return session;
}

/// A grabber on the phantom's apex (scripted device) pulls 5 mm slowly from 10 ms to 40 ms, then
/// is yanked 2 m in 5 ms.
void write_yank(const fs::path& path) {
    std::ofstream out(path);
    out << "0, -1.9, -3.0, -47.0, 1,0,0,0, 1\n10, -1.9, -3.0, -47.0, 1,0,0,0, 1\n40, -1.9, -3.0, -52.0, 1,0,0,0, 1\n"
           "45, -1.9, -3.0, -2052.0, 1,0,0,0, 1\n";
}

double norm3(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

}  // namespace

// ------------------------------------------------------------------------------------------------
// End to end

TEST(HapticsCli, TwoHandsRunForTwoSecondsAndPrintTheHapticRateTable) {
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    for (const char* line : {"hand 0: simulated:", "hand 1: scripted:", "haptic period", "pose → force latency", "pose → force, steps", "wrote "})
        EXPECT_NE(s.run.output.find(line), std::string::npos) << line << "\n" << s.run.output;
    std::printf("%s\n", s.run.output.c_str());
    // A session that ends normally writes its recording and deletes the journal it kept meanwhile.
    EXPECT_FALSE(fs::exists(fs::path(s.file.string() + ".journal")));

    const Recording r = read_recording(s.file);
    ASSERT_TRUE(r.hands[0].used && r.hands[1].used);
    EXPECT_EQ(r.hands[0].instrument, "probe");
    EXPECT_EQ(r.hands[1].instrument, "grabber");
    EXPECT_EQ(r.backend, "cpu");
    // The device thread ran for the two seconds on the wall clock at about 1 kHz (not a timing
    // assertion: a tenth of the ticks is plenty to tell the thread ran the whole time).
    const std::size_t ticks = r.hands[0].tick_time_ms.size();
    EXPECT_GT(ticks, 200u);
    EXPECT_GE(r.hands[0].tick_time_ms.back() - r.hands[0].tick_time_ms.front(), 1900.0);
    ASSERT_GT(r.steps.size(), 50u);

    // The simulated hand pushed the probe into the wall: the wall pushed back (−y, against the
    // +y hand force) and the device came to rest against it, short of where a free 0.02 N push
    // at 2 N·ms/mm (10 mm/s) would have carried it in the same time.
    double max_probe = 0.0, max_grab = 0.0;
    for (std::size_t k = 0; k < r.steps.size(); ++k) {
        max_probe = std::max(max_probe, norm3(r.steps.force_n[k][0]));
        max_grab = std::max(max_grab, norm3(r.steps.force_n[k][1]));
    }
    EXPECT_GT(max_probe, 1e-3) << "the probe never touched the phantom";
    EXPECT_GT(max_grab, 1e-3) << "the grabber held nothing";
    bool pushed_back = false;
    for (const auto& f : r.hands[0].force_n) pushed_back |= f[1] < -1e-3;
    EXPECT_TRUE(pushed_back) << "the force sent to the probe's device never opposed the push";
    // Every force sent was finite and within the device's maximum; the grab and release events
    // match the script's button.
    for (int h = 0; h < 2; ++h)
        for (const auto& f : r.hands[h].force_n) {
            ASSERT_TRUE(std::isfinite(f[0] + f[1] + f[2]));
            ASSERT_LE(norm3(f), r.hands[h].max_force_n * (1 + 1e-12));
        }
    bool grabbed = false;
    for (const auto& e : r.events) grabbed |= e.what == "grab" && e.hand == 1;
    EXPECT_TRUE(grabbed);
    // Each step's forces came from that very step on the cpu backend (pose → force: 1 step), and
    // every step applied both tools (stepping starts once the device thread has given poses).
    for (std::size_t k = 0; k < r.steps.size(); ++k) {
        ASSERT_EQ(r.steps.force_step[k], std::int64_t(k));
        ASSERT_EQ(r.steps.applied[k][0] + r.steps.applied[k][1], 2) << "step " << k;
    }
}

TEST(HapticsCli, TheRecordingReplaysToTheSameForcesBitForBitOnTheCpuBackend) {
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(s.file));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
}

// A two-handed session on tissue with its own Poisson's ratio (heartprep --poisson-ratio 0.45: the
// volume term on the lattice's cells, libmodel/volume_cells.h) replays bit for bit: the cells'
// pass gives the same bits for any thread count, as the springs' does.
TEST(HapticsCli, ASessionOnANearlyIncompressibleTissueReplaysBitForBit) {
    test::TempDir dir;
    const fs::path& tissue = test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000 --poisson-ratio 0.45");
    ASSERT_NEAR(read_scenario(tissue).lattice.materials.at(0).poisson_ratio, 0.45, 1e-6);
    const auto live = run_heartsim("run " + quoted(tissue) + " --headless --backend cpu --device simulated:" + quoted(sample("press_phantom.csv")) +
                                   " --device scripted:" + quoted(sample("grab_phantom.csv")) + " --seconds 1.2 --record " + quoted(dir / "rec.h5"));
    ASSERT_EQ(live.exit_code, 0) << live.output;
    const Recording recorded = read_recording(dir / "rec.h5");
    double largest = 0;
    for (const auto& f : recorded.steps.force_n)
        for (int hand = 0; hand < 2; ++hand) largest = std::max(largest, Eigen::Vector3d(f[hand][0], f[hand][1], f[hand][2]).norm());
    EXPECT_GT(largest, 0.0) << "the hands should meet the tissue";
    const auto replay = run_heartsim("run " + quoted(tissue) + " --headless --replay " + quoted(dir / "rec.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
}

// --real-time auto changes the mass scale during a session (here from the speed injected as a
// third of real time, so it changes after the first half second whatever this machine does): every
// step records the scale it ran with, and the replay changes it at the same steps, bit for bit. A
// session at a fixed --mass-scale replays bit for bit too.
// A scalpel on a scripted device, button 1 held, drawn 16 mm through the phantom's anterior wall
// (the incision of incision_gesture.h): the session cuts springs, its state file lists them and
// names the scalpel, and its recording replays bit for bit, cutting the same springs. The hand
// feels the blade: the recording holds the tissue's resistance to the cut (well above the
// session's --max-force 0.5 N), and what the device was sent stays within the clamp and, while the
// gain is 1, within the rate limit (0.5 N/ms) from tick to tick.
TEST(HapticsCli, ACuttingSessionReplaysBitForBit) {
    test::TempDir dir;
    const Scenario scenario = read_scenario(phantom());
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 16, .retract = false});
    {
        std::ofstream csv(dir / "cut.csv");
        csv << "# time_ms, x, y, z, qw, qx, qy, qz, buttons\n";
        for (const InstrumentKeyframe& k : plan.trajectory.keyframes) {
            if (k.hand != 0) continue;
            const auto& p = k.pose.position;
            const auto& q = k.pose.orientation;
            char line[256];
            std::snprintf(line, sizeof line, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", 100 + k.time_ms, p.x(), p.y(), p.z(), q.w(), q.x(),
                          q.y(), q.z(), k.grab ? 1 : 0);
            csv << line;
        }
    }
    const auto live = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device scripted:" + quoted(dir / "cut.csv") +
                                   " --instrument scalpel --seconds 0.5 --max-force 0.5 --record " + quoted(dir / "cut.h5") + " --save-state " +
                                   quoted(dir / "state.h5"));
    ASSERT_EQ(live.exit_code, 0) << live.output;
    const SimulationState state = read_state(dir / "state.h5");
    EXPECT_EQ(state.kind[0], 3);
    std::printf("  %zu springs cut\n", state.cut_springs.size());
    EXPECT_GT(state.cut_springs.size(), 20u);
    EXPECT_EQ(read_recording(dir / "cut.h5").hands[0].instrument, "scalpel");
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "cut.h5") + " --save-state " +
                                     quoted(dir / "replayed.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
    // The replay's own saved state: the scalpel in hand 0 and the springs the session cut.
    const SimulationState replayed = read_state(dir / "replayed.h5");
    EXPECT_EQ(replayed.kind[0], 3);
    EXPECT_TRUE(replayed.cut_springs == state.cut_springs) << replayed.cut_springs.size() << " against " << state.cut_springs.size();
    // The recording replayed here on the cpu backend cuts the very springs the session's state
    // lists, and gives the scalpel's recorded forces to the bit.
    const Recording recorded = read_recording(dir / "cut.h5");
    SolverOptions options = options_from(scenario.solver);
    if (recorded.rules) static_cast<SolverRules&>(options) = *recorded.rules;
    options.mass_scale = recorded.steps.mass_scale_at(0);
    options.arithmetic = recorded.arithmetic == "fused" ? SlotArithmetic::fused : SlotArithmetic::separate;
    auto cpu = make_cpu_backend(scenario, options);
    const ReplayResult again = haptics::replay(*cpu, recorded, (dir / "cut.h5").string());
    EXPECT_TRUE(cpu->cut_springs() == state.cut_springs) << cpu->cut_springs().size() << " springs cut by the replay, " << state.cut_springs.size()
                                                         << " by the session";
    EXPECT_GT(again.compared, 100u);
    EXPECT_EQ(again.identical, again.compared);
    EXPECT_EQ(again.max_difference_n, 0.0);

    // The scalpel's force in the recording: non-zero while it cuts, and handed to the device
    // within the clamp and the rate limit.
    double largest_step = 0;
    for (const auto& f : recorded.steps.force_n) largest_step = std::max(largest_step, Eigen::Vector3d(f[0][0], f[0][1], f[0][2]).norm());
    EXPECT_GT(largest_step, 0.5) << "the blade's force should exceed --max-force 0.5 N";
    const RecordedHand& hand = recorded.hands[0];
    EXPECT_EQ(hand.max_force_n, 0.5);
    const double rate = SafetySettings{}.max_rate_n_per_ms;
    double largest_input = 0, largest_sent = 0, steepest = 0;
    std::size_t ticks_at_full_gain = 0;
    for (std::size_t k = 0; k < hand.force_n.size(); ++k) {
        const Eigen::Vector3d sent(hand.force_n[k][0], hand.force_n[k][1], hand.force_n[k][2]);
        largest_input = std::max(largest_input, Eigen::Vector3d(hand.input_n[k][0], hand.input_n[k][1], hand.input_n[k][2]).norm());
        largest_sent = std::max(largest_sent, sent.norm());
        ASSERT_LE(sent.norm(), 0.5 * (1 + 1e-12)) << "tick " << k;
        if (k == 0 || hand.gain[k] != 1.0f || hand.gain[k - 1] != 1.0f) continue;
        const Eigen::Vector3d before(hand.force_n[k - 1][0], hand.force_n[k - 1][1], hand.force_n[k - 1][2]);
        const double dt = hand.tick_time_ms[k] - hand.tick_time_ms[k - 1];
        ASSERT_LE((sent - before).norm(), rate * dt + 1e-12) << "tick " << k;
        steepest = std::max(steepest, (sent - before).norm() / dt);
        ++ticks_at_full_gain;
    }
    std::printf("  blade force: largest %.3f N computed, %.3f N into the safety chain, %.3f N sent (clamp 0.5 N), steepest %.3f N/ms "
                "at full gain (limit %.2f)\n",
                largest_step, largest_input, largest_sent, steepest, rate);
    EXPECT_GT(largest_input, 0.5);
    EXPECT_GT(largest_sent, 0.45);
    EXPECT_GT(ticks_at_full_gain, 100u);
}

TEST(HapticsCli, ASessionWhoseMassScaleChangesReplaysBitForBit) {
    test::TempDir dir;
    const std::string devices = " --headless --backend cpu --device simulated:" + quoted(sample("press_phantom.csv")) +
                                " --device scripted:" + quoted(sample("grab_phantom.csv")) + " --seconds 1.5";
    const auto live = test::run_command("HEARTSIM_ASSUME_REAL_TIME_FACTOR=0.3 " + std::string(quoted(HEARTSIM_EXE)) + " run " +
                                        quoted(phantom()) + devices + " --record " + quoted(dir / "auto.h5"));
    ASSERT_EQ(live.exit_code, 0) << live.output;
    EXPECT_NE(live.output.find("at mass scale 1: mass scale "), std::string::npos) << live.output;
    const Recording r = read_recording(dir / "auto.h5");
    ASSERT_EQ(r.steps.mass_scale.size(), r.steps.size());
    EXPECT_EQ(r.steps.mass_scale.front(), 1.0);
    EXPECT_GT(r.steps.mass_scale.back(), 1.0);
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "auto.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;

    const auto fixed = run_heartsim("run " + quoted(phantom()) + devices + " --mass-scale 4 --record " + quoted(dir / "fixed.h5"));
    ASSERT_EQ(fixed.exit_code, 0) << fixed.output;
    EXPECT_NE(fixed.output.find("mass scale 4: inertia × 4"), std::string::npos) << fixed.output;
    const Recording f = read_recording(dir / "fixed.h5");
    ASSERT_FALSE(f.steps.mass_scale.empty());
    for (double s : f.steps.mass_scale) ASSERT_EQ(s, 4.0);
    const auto again = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "fixed.h5"));
    EXPECT_EQ(again.exit_code, 0) << again.output;
    EXPECT_NE(again.output.find("match the recording bit for bit"), std::string::npos) << again.output;
    // A replay takes the recording's scale, not one of its own.
    const auto refused = run_heartsim("run " + quoted(phantom()) + " --headless --mass-scale 2 --replay " + quoted(dir / "fixed.h5"));
    EXPECT_EQ(refused.exit_code, 2) << refused.output;
    EXPECT_NE(refused.output.find("the recording's own mass scale"), std::string::npos) << refused.output;
}

// A cpu replay takes the recorded slot arithmetic (fused, or rounded apart as before heartsim
// fused it, and as sse2 does), not this CPU's fastest kernel's: the recording's attribute decides.
TEST(HapticsCli, ACpuReplayTakesTheRecordedArithmetic) {
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    const Recording recorded = read_recording(s.file);
    if (recorded.arithmetic != "fused") GTEST_SKIP() << "this CPU has no AVX2 with FMA: the session ran with separate rounding";
    // The same session with its arithmetic attribute removed, as in a recording made before the
    // fusing: it replays with sse2, whose last digits differ from the recorded fused ones.
    test::TempDir dir;
    const fs::path old_style = dir / "old-style.h5";
    fs::copy_file(s.file, old_style);
    {
        const hid_t file = H5Fopen(old_style.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        ASSERT_GE(file, 0);
        ASSERT_GE(H5Adelete(file, "arithmetic"), 0);
        H5Fclose(file);
    }
    EXPECT_EQ(read_recording(old_style).arithmetic, "separate");
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(old_style));
    EXPECT_NE(replay.output.find("replaying with the sse2 kernel"), std::string::npos) << replay.output;
    EXPECT_EQ(replay.exit_code, 5) << "fused forces replayed with separate rounding must differ somewhere\n" << replay.output;
}

TEST(HapticsCli, ReplayCatchesARecordingWhoseForcesWereChanged) {
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    Recording r = read_recording(s.file);
    // Change one recorded force by 1 µN, at a step where the probe touched.
    std::size_t touched = r.steps.size();
    for (std::size_t k = 0; k < r.steps.size() && touched == r.steps.size(); ++k)
        if (norm3(r.steps.force_n[k][0]) > 0) touched = k;
    ASSERT_LT(touched, r.steps.size());
    r.steps.force_n[touched][0][1] += 1e-6;
    test::TempDir dir;
    write_recording(dir / "tampered.h5", r);
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "tampered.h5"));
    EXPECT_EQ(replay.exit_code, 5) << replay.output;
    EXPECT_NE(replay.output.find("forces differ from the recording"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("worst at step " + std::to_string(touched)), std::string::npos) << replay.output;
}

TEST(HapticsCli, AScriptedDeviceReplaysTheDevicePosesOfARecording) {
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    test::TempDir dir;
    // No --backend: gl, unless the OpenGL device is a software rasteriser (llvmpipe here), where
    // heartsim simulates a haptic session on the faster cpu backend and says so.
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --device scripted:" + quoted(fs::path(s.file.string() + "@0")) +
                                  " --seconds 1 --record " + quoted(dir / "again.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Recording first = read_recording(s.file), again = read_recording(dir / "again.h5");
    const bool software = run.output.find("a software rasteriser: simulating with the cpu backend") != std::string::npos;
    EXPECT_EQ(again.backend, software ? "cpu" : "gl") << run.output;
    ASSERT_TRUE(again.hands[0].used);
    EXPECT_FALSE(again.hands[1].used);
    // The new ticks fall at other times; between the first recording's 1 ms ticks the scripted
    // device interpolates linearly, and the simulated device moves smoothly (≤ 10 mm/s), so the
    // poses agree to well under a micrometre.
    const std::vector<PoseKeyframe> script = recorded_pose_script(first, 0, "first");
    const ScriptedDevice reference(script);
    double worst = 0.0;
    for (std::size_t i = 0; i < again.hands[0].tick_time_ms.size(); ++i) {
        const Eigen::Vector3d expected = reference.pose_at(again.hands[0].tick_time_ms[i]).position_mm;
        const auto& p = again.hands[0].position_mm[i];
        worst = std::max(worst, (Eigen::Vector3d(p[0], p[1], p[2]) - expected).norm());
    }
    EXPECT_LT(worst, 1e-9) << "the scripted device is the same interpolation of the same keyframes";
    // And those poses are the first session's: at a shared time the positions agree.
    const double t = 500.0;
    const Eigen::Vector3d a = reference.pose_at(t).position_mm, b = ScriptedDevice(recorded_pose_script(again, 0, "again")).pose_at(t).position_mm;
    EXPECT_LT((a - b).norm(), 1e-3);
}

TEST(HapticsCli, ARecordingThatBeganLateInASessionPlaysFromItsStart) {
    // What the window's F5 writes 40 s into a session: ticks from 40,000 ms. As a scripted device
    // it starts at once, at its first pose, and moves as recorded, not after 40 s of holding still.
    Recording late;
    RecordedHand& h = late.hands[0];
    h.used = true;
    for (int i = 0; i <= 100; ++i) {
        h.tick_time_ms.push_back(40000.0 + i);
        h.position_mm.push_back({0.1 * i, -0.05 * i, 2.0});
        h.orientation.push_back({1, 0, 0, 0});
        h.buttons.push_back(i >= 50 ? 1u : 0u);
    }
    for (int i = 1; i <= 500; ++i) late.steps.time_ms.push_back(40000.0 + 0.2 * i);  // steps of 0.2 ms from 40 s
    const ScriptedDevice device(recorded_pose_script(late, 0, "late.h5"));
    EXPECT_NEAR((device.pose_at(0.0).position_mm - Eigen::Vector3d(0, 0, 2)).norm(), 0.0, 1e-9);
    EXPECT_NEAR((device.pose_at(25.5).position_mm - Eigen::Vector3d(2.55, -1.275, 2)).norm(), 0.0, 1e-9) << "between ticks 25 and 26";
    EXPECT_NEAR((device.pose_at(100.0).position_mm - Eigen::Vector3d(10, -5, 2)).norm(), 0.0, 1e-9);
    EXPECT_EQ(device.pose_at(49.5).buttons, 0u);
    EXPECT_EQ(device.pose_at(50.5).buttons, 1u);
}

TEST(HapticsCli, MaxForceClampsEveryForceSentButNotWhatTheSimulationComputed) {
    test::TempDir dir;
    // A firm 0.3 N push; the devices may render at most 0.01 N.
    {
        std::ofstream out(dir / "firm.csv");
        out << "start_mm, -24.6, -42.0, 2.7\nmass_g, 100\ndamping_n_ms_per_mm, 2\n0, 0, 0, 0\n100, 0, 0.3, 0\n";
    }
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device simulated:" + quoted(dir / "firm.csv") +
                                  " --seconds 1 --max-force 0.01 --record " + quoted(dir / "firm.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Recording r = read_recording(dir / "firm.h5");
    EXPECT_DOUBLE_EQ(r.hands[0].max_force_n, 0.01);
    double largest_input = 0.0, largest_sent = 0.0;
    for (std::size_t i = 0; i < r.hands[0].force_n.size(); ++i) {
        largest_input = std::max(largest_input, norm3(r.hands[0].input_n[i]));
        largest_sent = std::max(largest_sent, norm3(r.hands[0].force_n[i]));
    }
    EXPECT_GT(largest_input, 0.01) << "the push never made the tissue force exceed the limit; the test shows nothing";
    EXPECT_LE(largest_sent, 0.01 * (1 + 1e-12));
}

TEST(HapticsCli, TheGlBackendsForcesArriveAFewStepsLateAndReplayOnCpuWithinTolerance) {
    REQUIRE_GL();
    test::TempDir dir;
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend gl --device simulated:" + quoted(sample("press_phantom.csv")) +
                                  " --seconds 1.5 --record " + quoted(dir / "gl.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Recording r = read_recording(dir / "gl.h5");
    EXPECT_EQ(r.backend, "gl");
    // Asynchronous readback: a step's published forces come from that step or an earlier one,
    // never a later one, and the readback keeps up (at most the ring of 4 requests behind).
    std::size_t with_forces = 0;
    for (std::size_t k = 0; k < r.steps.size(); ++k) {
        ASSERT_LE(r.steps.force_step[k], std::int64_t(k));
        if (r.steps.force_step[k] >= 0) {
            ++with_forces;
            EXPECT_LE(std::int64_t(k) - r.steps.force_step[k], 4);
        }
    }
    EXPECT_GT(with_forces, r.steps.size() / 2);
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "gl.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    std::printf("%s\n", replay.output.c_str());
    // Float GPU arithmetic in another order: apart from a particle entering contact a step apart
    // (the largest difference), the forces agree closely on average.
    std::smatch m;
    ASSERT_TRUE(std::regex_search(replay.output, m, std::regex(R"(rms ([0-9.e+-]+) N \(largest recorded force ([0-9.e+-]+) N)"))) << replay.output;
    EXPECT_LT(std::stod(m[1]), 0.01 * std::stod(m[2])) << replay.output;

    // A gl session with another contact mode replays on gl with that mode (unless --contact
    // says otherwise) and agrees within the tolerance (measured on llvmpipe: bit for bit).
    const auto search = run_heartsim("run " + quoted(phantom()) + " --headless --backend gl --contact search --device simulated:" +
                                     quoted(sample("press_phantom.csv")) + " --steps 150 --record " + quoted(dir / "search.h5"));
    ASSERT_EQ(search.exit_code, 0) << search.output;
    const auto again = run_heartsim("run " + quoted(phantom()) + " --headless --backend gl --replay " + quoted(dir / "search.h5"));
    EXPECT_EQ(again.exit_code, 0) << again.output;
    EXPECT_NE(again.output.find("--contact search, as recorded"), std::string::npos) << again.output;
    std::printf("%s\n", again.output.c_str());
}

TEST(HapticsCli, AYankedGrabSlipsOutOfTheGrabberInsteadOfTearingTheTissue) {
    // A grabber on the apex pulls 5 mm slowly, then is yanked 2 m in 5 ms. The held particles slip
    // out once their springs would pass three times their rest length (SolverOptions::grab_slip_strain):
    // no divergence, no watchdog, the tissue left intact, and the replay gives the same forces.
    // On both backends, which run the same order-free slip rule. (Before the slip rule the yank
    // stretched springs twenty-fold: on cpu the watchdog restored the same failing state step
    // after step; on gl the yank tripped the watchdog, which threw the session back to t = 0.)
    test::TempDir dir;
    write_yank(dir / "yank.csv");
    for (const std::string backend : {"cpu", "gl"}) {
        SCOPED_TRACE(backend);
        const fs::path recording = dir / (backend + ".h5");
        const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend " + backend + " --device scripted:" +
                                      quoted(dir / "yank.csv") + " --instrument grabber --steps 400 --record " + quoted(recording));
        if (backend == "gl" && run.exit_code == 3) {
            std::printf("gl skipped: %s\n", run.output.c_str());
            continue;
        }
        ASSERT_EQ(run.exit_code, 0) << run.output;
        EXPECT_EQ(run.output.find("watchdog:"), std::string::npos) << run.output;
        EXPECT_NE(run.output.find("hand 0 force (0, 0, 0) N on 0 particles"), std::string::npos) << "nothing is held after the yank\n"
                                                                                                 << run.output;
        const Recording r = read_recording(recording);
        EXPECT_EQ(r.steps.size(), 400u);
        // The device plays its script on the wall clock: on llvmpipe (about 0.02 of real time, and
        // its forces a step or two late) the 30 ms pull lasts a step or two, so only the cpu run
        // is sure to publish a force from it; both must have grabbed.
        EXPECT_TRUE(std::any_of(r.steps.grab.begin(), r.steps.grab.end(), [](const auto& g) { return g[0] == 1; })) << "the grab held";
        double pulled = 0;
        for (const auto& f : r.steps.force_n) pulled = std::max(pulled, norm3(f[0]));
        if (backend == "cpu") {
            EXPECT_GT(pulled, 1e-3) << "the slow pull held tissue and felt it";
        }
        for (auto d : r.steps.diverged) ASSERT_EQ(d, 0);
        const std::smatch displacement = [&] {
            std::smatch m;
            std::regex_search(run.output, m, std::regex("displacement from rest: max ([0-9.e+-]+) mm"));
            return m;
        }();
        ASSERT_FALSE(displacement.empty()) << run.output;
        EXPECT_LT(std::stod(displacement[1]), 20.0) << "the tissue was not dragged away";
        const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --backend " + backend + " --replay " + quoted(recording));
        EXPECT_EQ(replay.exit_code, 0) << replay.output;
        if (backend == "cpu") {
            EXPECT_NE(replay.output.find("bit for bit"), std::string::npos) << replay.output;
        }
    }
}

// A recording keeps the solver's rules it ran with (how instruments pierce, grab and slip, when the
// watchdog steps in), and a replay takes them: a recording still replays as it ran after a rule
// changes. Here the yank of the test above: the replay with the recorded rules gives the same
// forces; the same file whose rules let a held particle slip at any stretch does not, since the
// grab that pulled in the recording now holds nothing: it is the recorded rule that the replay
// follows. (Not "never slips": the device plays its script on the wall clock, so on a loaded
// machine the yank may come after the 400 steps, and then no slip happened to undo.)
TEST(HapticsCli, AReplayTakesTheSolverRulesTheSessionWasRecordedWith) {
    test::TempDir dir;
    write_yank(dir / "yank.csv");
    const fs::path recording = dir / "yank.h5";
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device scripted:" + quoted(dir / "yank.csv") +
                                  " --instrument grabber --steps 400 --record " + quoted(recording));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Recording recorded = read_recording(recording);
    ASSERT_TRUE(recorded.rules.has_value());
    EXPECT_EQ(*recorded.rules, SolverRules{}) << "the phantom's scenario takes the build's rules";
    const auto same = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --replay " + quoted(recording));
    EXPECT_EQ(same.exit_code, 0) << same.output;
    EXPECT_EQ(same.output.find("the recorded solver rules"), std::string::npos) << "no rule differs\n" << same.output;

    auto edited = [&](const std::string& name, const std::function<void(Recording&)>& edit) {
        Recording r = recorded;
        edit(r);
        write_recording(dir / name, r);
        return dir / name;
    };
    double pulled = 0;
    for (const auto& f : recorded.steps.force_n) pulled = std::max(pulled, norm3(f[0]));
    ASSERT_GT(pulled, 1e-3) << "the slow pull held tissue and felt it (the test above checks the same)";
    const fs::path slips_at_once = edited("slips-at-once.h5", [](Recording& r) { r.rules->grab_slip_strain = 1e-6; });
    const auto loose = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --replay " + quoted(slips_at_once));
    EXPECT_NE(loose.output.find("the recorded solver rules: grab_slip_strain 1e-06 (this build: 2)"), std::string::npos) << loose.output;
    EXPECT_EQ(loose.exit_code, 5) << "a grab that lets go of every stretched particle feels no pull: other forces\n" << loose.output;

    // A recording from before recordings kept their rules replays with those of that time.
    const fs::path old_style = edited("old-style.h5", [](Recording& r) { r.rules.reset(); });
    EXPECT_FALSE(read_recording(old_style).rules.has_value());
    const auto old = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --replay " + quoted(old_style));
    EXPECT_NE(old.output.find("recorded before recordings kept the solver's rules"), std::string::npos) << old.output;
    EXPECT_NE(old.output.find("max_displacement_fraction 2 (this build: 4), probe_pierce_strain 0 (this build: 2), grab_reach 0 (this build: 2)"),
              std::string::npos)
        << old.output;
}

TEST(HapticsCli, ARunThatCannotRecoverStopsWithExit6AndCountsOnlyStepsThatAdvanced) {
    // The phantom with a stored critical step 1.3 times the true one (still under the proven
    // ceiling, so the file is accepted) and its damped step raised to that: the step is then about
    // 1.5 times the damped edge of stability, and a probe pressing the tissue makes every restore
    // fail again at once. After max_consecutive_restores restores without a new good state the
    // run stops, says why, keeps its recording and exits 6, where it used to roll back every
    // step and exit 0.
    test::TempDir dir;
    fs::copy_file(phantom(), dir / "unstable.h5");
    const Scenario scenario = read_scenario(phantom());
    const double ceiling = critical_step_ceiling_ms(scenario.lattice.particles, scenario.lattice.springs);
    const double critical = 1.3 * scenario.solver.critical_dt_ms;
    ASSERT_LT(critical, ceiling) << "the test needs room under the ceiling";
    for (const auto& [name, value] : {std::pair{"critical_dt_ms", critical}, std::pair{"damped_critical_dt_ms", critical},
                                      std::pair{"dt_ms", scenario.solver.safety_factor * critical}})
        test::overwrite_attribute(dir / "unstable.h5", "solver", name, std::vector<double>{value}, H5T_NATIVE_DOUBLE);
    // Undamped (no dashpots, no support dampers): the damped step then has the undamped step's
    // proven ceiling, which the reader checks, and 1.3 × critical stays under it.
    test::overwrite(dir / "unstable.h5", "materials/damping", std::vector<float>(scenario.lattice.materials.size(), 0.0f), H5T_NATIVE_FLOAT);
    test::overwrite(dir / "unstable.h5", "particles/support_damping", std::vector<float>(scenario.lattice.particles.size(), 0.0f),
                    H5T_NATIVE_FLOAT);
    {
        std::ofstream out(dir / "press.csv");
        out << "0, -1.9, -3.0, -47.0, 1,0,0,0, 0\n";
    }
    const auto run = run_heartsim("run " + quoted(dir / "unstable.h5") + " --headless --backend cpu --device scripted:" +
                                  quoted(dir / "press.csv") + " --instrument probe --steps 2000 --record " + quoted(dir / "unstable-run.h5"));
    EXPECT_EQ(run.exit_code, 6) << run.output;
    EXPECT_NE(run.output.find("could not recover"), std::string::npos) << run.output;
    const Recording r = read_recording(dir / "unstable-run.h5");
    EXPECT_LT(r.steps.size(), 2000u) << "it stopped instead of replaying the failure";
    std::smatch ran;
    ASSERT_TRUE(std::regex_search(run.output, ran, std::regex("ran ([0-9]+) steps"))) << run.output;
    EXPECT_LT(std::stoll(ran[1]), (long long)r.steps.size()) << "rolled-back steps are not counted";

    // The same with a fixed probe and no haptics, on both backends: the gl backend reads its
    // status asynchronously every step, restores its last verified state on the GPU, and gives
    // up the same way (it used to carry on silently with a diverged state).
    for (const char* backend : {"cpu", "gl"}) {
        const auto fixed = run_heartsim("run " + quoted(dir / "unstable.h5") + " --headless --backend " + backend +
                                        " --steps 2000 --probe -1.9,-3.0,-47.0,3,3,3");
        if (std::string(backend) == "gl" && fixed.exit_code == 3) {
            std::printf("gl skipped: %s\n", fixed.output.c_str());
            continue;
        }
        EXPECT_EQ(fixed.exit_code, 6) << backend << "\n" << fixed.output;
        EXPECT_NE(fixed.output.find("could not recover"), std::string::npos) << backend << "\n" << fixed.output;
        EXPECT_NE(fixed.output.find("restored the state of t = "), std::string::npos) << backend << "\n" << fixed.output;
    }
}

TEST(HapticsCli, AnOpenHapticsDeviceRunsAndAFaultMidSessionIsReportedWithExit4) {
    // Through hd_testdouble, a test double of the OpenHaptics HD library (tests/hd_testdouble).
    test::TempDir dir;
    const std::string library = std::string("HEARTSIM_OPENHAPTICS_LIB=") + quoted(fs::path(HD_TESTDOUBLE_LIB)) + " ";
    const auto healthy = test::run_command(library + "HD_TESTDOUBLE_MODE=ok " + quoted(fs::path(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                           " --headless --backend cpu --device openhaptics --seconds 0.5 --record " + quoted(dir / "oh.h5"));
    ASSERT_EQ(healthy.exit_code, 0) << healthy.output;
    EXPECT_NE(healthy.output.find("hand 0: openhaptics"), std::string::npos) << healthy.output;
    const Recording r = read_recording(dir / "oh.h5");
    // The device's frame is placed at the view's centre, turned as the camera: recorded, so a
    // scripted replay of these poses lands where the device did.
    const auto& q = r.hands[0].mapping_rotation;
    EXPECT_NEAR(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3], 1.0, 1e-9);
    EXPECT_GT(norm3(r.hands[0].mapping_offset_mm), 0.0);

    const auto faulty = test::run_command(library + "HD_TESTDOUBLE_MODE=fault_after_ms=200 " + quoted(fs::path(HEARTSIM_EXE)) + " run " +
                                          quoted(phantom()) + " --headless --backend cpu --device openhaptics --seconds 0.6 --record " +
                                          quoted(dir / "fault.h5"));
    EXPECT_EQ(faulty.exit_code, 4) << faulty.output;
    EXPECT_NE(faulty.output.find("device fault"), std::string::npos) << faulty.output;
    const Recording f = read_recording(dir / "fault.h5");  // the outputs were still written
    bool recorded = false;
    for (const auto& e : f.events) recorded |= e.what == "device_fault" && e.hand == 0;
    EXPECT_TRUE(recorded);
}

TEST(HapticsCli, TheWindowRunsTheMouseDeviceBesideASimulatedOneAndEndsCleanly) {
    if (test::run_command("command -v xvfb-run && command -v Xvfb").exit_code != 0)
        GTEST_SKIP() << "Xvfb is not installed (Debian: xvfb xauth; scripts/install-deps.sh)";
    REQUIRE_GL();
    test::TempDir dir;
    const auto run = test::run_command(test::in_xvfb_window() + quoted(HEARTSIM_EXE) + " run " +
                                       quoted(phantom()) + " --backend cpu --size 320x240 --steps 300 --device mouse --device simulated:" +
                                       quoted(sample("press_phantom.csv")) + " --instrument probe --instrument probe --record " +
                                       quoted(dir / "window.h5") + " 2>&1");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    for (const char* line : {"window: ", "haptic period", "hand 0: mouse (mouse)", "hand 1: simulated:", "ran 300 steps"})
        EXPECT_NE(run.output.find(line), std::string::npos) << line << "\n" << run.output;
    const Recording r = read_recording(dir / "window.h5");
    EXPECT_EQ(r.hands[0].device_name, "mouse");
    EXPECT_EQ(r.hands[1].instrument, "probe");
    EXPECT_EQ(r.steps.size(), 300u);
    // Nobody touched the mouse or the keyboard: the mouse device stayed where it started, in
    // front of the model, and no force was ever sent to it (it never reached the tissue).
    ASSERT_FALSE(r.hands[0].position_mm.empty());
    for (std::size_t i = 0; i < r.hands[0].position_mm.size(); ++i) {
        ASSERT_EQ(r.hands[0].position_mm[i], r.hands[0].position_mm.front());
        ASSERT_EQ(norm3(r.hands[0].force_n[i]), 0.0);
    }
}

TEST(HapticsCli, BadDevicesAndOptionsGiveClearErrors) {
    const std::string scenario = quoted(phantom());
    struct Case {
        std::string arguments;
        int exit_code;
        std::string message;
    };
    test::TempDir dir;
    {
        std::ofstream out(dir / "bad.csv");
        out << "start_mm, 0, 0\n0, 0, 0, 0\n";
    }
    const std::vector<Case> cases = {
        {"--headless --device bogus:x --seconds 1", 2, "unknown device 'bogus'"},
        {"--headless --device simulated: --seconds 1", 2, "simulated needs a file"},
        {"--headless --device simulated:/no/such.csv --seconds 1", 1, "/no/such.csv: no such file"},
        {"--headless --device mouse --seconds 1", 4, "--device mouse needs the window"},
        // Absurd but well-formed values are refused by their plausible range (libmodel/plausible.h).
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --instrument probe:1e30,1,1 --seconds 1", 2,
         "semi-axis is 1e+30 mm, outside the plausible range [0.001, 500] mm"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --max-force 1e30 --seconds 1", 2,
         "--max-force: the force is 1e+30 N, outside the plausible range [1e-06, 1000] N"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")), 2, "needs --seconds S"},
        {"--headless --device simulated:" + quoted(dir / "bad.csv") + " --seconds 1", 1, "bad.csv:1: start_mm needs 3 numbers, found 2"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --probe 0,0,0,1,1,1 --seconds 1", 2, "not both"},
        {"--headless --device scripted:a --device scripted:b --device scripted:c --seconds 1", 2, "at most two"},
        {"--headless --record x.h5 --steps 1", 2, "--record needs --device"},
        // 0 read as "no limit given" and the device's own maximum was sent; the device options
        // without a device were ignored.
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --max-force 0 --seconds 1", 2,
         "--max-force: the force is 0 N, outside the plausible range [1e-06, 1000] N"},
        {"--headless --max-force 2 --steps 1", 2, "--max-force sets how forces reach a haptic device: it needs --device"},
        {"--headless --coupling --steps 1", 2, "--coupling sets how forces reach a haptic device: it needs --device"},
        {"--headless --haptic-rate 500 --steps 1", 2, "--haptic-rate sets how forces reach a haptic device: it needs --device"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --instrument scissors --seconds 1", 2,
         "expected probe, grabber, retractor, scalpel, patch or needle"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --seconds 1 --record /no/such/folder/r.h5", 7,
         "folder /no/such/folder does not exist"},
        {"--headless --device openhaptics --seconds 1", 4, "openhaptics"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --seconds 1 --record " + quoted(phantom()), 2,
         "that is the scenario being run"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --seconds 1 --record " + quoted(dir.path()), 2, "is a folder"},
        {"--headless --device simulated:" + quoted(sample("press_phantom.csv")) + " --seconds nan", 2, "--seconds"},
        {"--headless --replay-tolerance 1 --steps 1", 2, "--replay-tolerance needs --replay"},
    };
    for (const Case& c : cases) {
        // openhaptics: no libHD here, or (where HEARTSIM_OPENHAPTICS_LIB names a test double) a
        // device that cannot be found; either way a clear message and exit 4.
        const auto run = run_heartsim("run " + scenario + " " + c.arguments);
        EXPECT_EQ(run.exit_code, c.exit_code) << c.arguments << "\n" << run.output;
        EXPECT_NE(run.output.find(c.message), std::string::npos) << c.arguments << "\n" << run.output;
    }
    // A recording made on another scenario is refused by name.
    const RecordedSession& s = two_hands();
    ASSERT_EQ(s.run.exit_code, 0) << s.run.output;
    const auto other = test::run_command(std::string(quoted(HEARTPREP_EXE)) + " build " +
                                         quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz") + " -o " + quoted(dir / "other.h5") +
                                         " --particles 3000 -q");
    ASSERT_EQ(other.exit_code, 0) << other.output;
    const auto replay = run_heartsim("run " + quoted(dir / "other.h5") + " --headless --replay " + quoted(s.file));
    EXPECT_EQ(replay.exit_code, 1) << replay.output;
    EXPECT_NE(replay.output.find("particles; this scenario has"), std::string::npos) << replay.output;
    // A file that is not a recording.
    const auto not_recording = run_heartsim("run " + scenario + " --headless --replay " + scenario);
    EXPECT_EQ(not_recording.exit_code, 1) << not_recording.output;
    EXPECT_NE(not_recording.output.find("not heartsim.recording"), std::string::npos) << not_recording.output;
}

// ------------------------------------------------------------------------------------------------
// In process

TEST(HapticsVocabulary, DeviceSpecsSimulatedDeviceFilesAndInstruments) {
    EXPECT_EQ(parse_device_spec("scripted:a.csv").kind, DeviceSpec::Kind::scripted);
    EXPECT_EQ(parse_device_spec("scripted:a.csv").argument, "a.csv");
    EXPECT_EQ(parse_device_spec("simulated:dir/b.csv").kind, DeviceSpec::Kind::simulated);
    EXPECT_EQ(parse_device_spec("mouse").kind, DeviceSpec::Kind::mouse);
    EXPECT_EQ(parse_device_spec("openhaptics").argument, "");
    EXPECT_EQ(parse_device_spec("openhaptics:Left Device").argument, "Left Device");
    EXPECT_THROW(parse_device_spec("mouse:1"), InputError);
    EXPECT_THROW(parse_device_spec("phantom"), InputError);

    const SimulatedDeviceSettings s = parse_simulated_device(
        "# comment\nstart_mm, 1, 2, 3\nmass_g, 80\ndamping_n_ms_per_mm, 0.5\nmax_force_n, 2\ntime_ms, fx, fy, fz\n0, 0, 0, 0\n100, 0, 1, 0\n", "t");
    EXPECT_EQ(s.start_mm, Eigen::Vector3d(1, 2, 3));
    EXPECT_EQ(s.mass_g, 80);
    EXPECT_EQ(s.damping_n_ms_per_mm, 0.5);
    EXPECT_EQ(s.limits.max_force_n, 2);
    EXPECT_TRUE(s.limits.workspace_mm.contains(Eigen::Vector3d(1, 2, 3)));
    EXPECT_NEAR(s.hand_force(50.0).y(), 0.5, 1e-12);  // piecewise linear
    EXPECT_NEAR(s.hand_force(1e6).y(), 1.0, 1e-12);   // held after the last row
    try {
        parse_simulated_device("mass_g, 1\n0, 0, 0\n", "f.csv");
        ADD_FAILURE() << "a 3-column force row was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("f.csv:2"), std::string::npos) << e.what();  // line numbers survive the settings rows
    }
    EXPECT_THROW(parse_simulated_device("mass_g, -1\n0, 0, 0, 0\n", "f"), InputError);
    EXPECT_THROW(parse_simulated_device("start_mm, 500, 0, 0\nworkspace_mm, -1, -1, -1, 1, 1, 1\n0, 0, 0, 0\n", "f"), InputError);

    // A first row with a typo is an error, not a header (a header has no numbers).
    EXPECT_THROW(parse_pose_script("0, 1, 2, x3, 1, 0, 0, 0\n10, 1, 2, 3, 1, 0, 0, 0\n", "typo.csv"), InputError);
    EXPECT_EQ(parse_pose_script("time_ms, x, y, z, qw, qx, qy, qz\n0, 1, 2, 3, 1, 0, 0, 0\n", "header.csv").size(), 1u);
    EXPECT_THROW(parse_simulated_device("bogus_key, 1\n0, 0, 0, 0\n", "f.csv"), InputError);  // a misspelled setting

    const Instrument probe = parse_instrument("probe", 2.5);
    EXPECT_EQ(probe.kind, InstrumentKind::probe);
    EXPECT_EQ(probe.semi_axes, Eigen::Vector3d::Constant(2.5));
    const Instrument grabber = parse_instrument("grabber:1,2,3", 2.5);
    EXPECT_EQ(grabber.kind, InstrumentKind::grabber);
    EXPECT_EQ(grabber.semi_axes, Eigen::Vector3d(1, 2, 3));
    EXPECT_THROW(parse_instrument("grabber:1,2", 1), InputError);
    EXPECT_THROW(parse_instrument("probe:1,2,-3", 1), InputError);
    // The repair's instruments: an 18 mm patch 0.5 mm thick and a needle 12 mm long, whatever the
    // lattice's spacing; semi-axes given replace them.
    const Instrument patch = parse_instrument("patch", 2.5), needle = parse_instrument("needle", 2.5);
    EXPECT_EQ(patch.kind, InstrumentKind::patch);
    EXPECT_EQ(patch.semi_axes, Eigen::Vector3d(9, 9, 0.25));
    EXPECT_EQ(needle.kind, InstrumentKind::needle);
    EXPECT_EQ(needle.semi_axes, Eigen::Vector3d(0.25, 0.25, 6));
    EXPECT_EQ(parse_instrument("patch:7,5,0.3", 2.5).semi_axes, Eigen::Vector3d(7, 5, 0.3));
    EXPECT_TRUE(takes_grab(patch.kind) && takes_grab(needle.kind));
    EXPECT_THROW(parse_instrument("none", 1), InputError);
}

TEST(HapticsRecordingFile, RoundTripsAndRejectsDamagedFiles) {
    Recording r;
    r.scenario = "x.h5";
    r.particles = 10;
    r.dt_ms = 0.25;
    r.substeps = 2;
    r.backend = "cpu";
    r.contact = "direct";
    r.interpolation = "hold";
    r.rate_hz = 1000;
    r.period_p99_ms = 1.25;
    r.rules = rules_before_recorded();
    r.rules->energy_growth_limit = 12.5;
    r.hands[1].used = true;
    r.hands[1].device = "scripted:a.csv";
    r.hands[1].device_name = "scripted";
    r.hands[1].instrument = "grabber";
    r.hands[1].semi_axes_mm = {1, 2, 3};
    r.hands[1].max_force_n = 3.3;
    for (int i = 0; i < 3; ++i) {
        r.hands[1].tick_time_ms.push_back(i);
        r.hands[1].position_mm.push_back({double(i), 0.5, -1});
        r.hands[1].orientation.push_back({1, 0, 0, 0});
        r.hands[1].buttons.push_back(std::uint32_t(i));
        r.hands[1].input_n.push_back({0, 0, 0.1 * i});
        r.hands[1].force_n.push_back({0, 0, 0.05 * i});
        r.hands[1].gain.push_back(0.5f * float(i));
    }
    for (int k = 0; k < 2; ++k) {
        r.steps.time_ms.push_back(0.25 * (k + 1));
        r.steps.wall_ms.push_back(1.0 + k);
        r.steps.tool_time_ms.push_back(0.5 + k);
        r.steps.tool_position_mm.push_back({{{0, 0, 0}, {1, 2, double(k)}}});
        r.steps.tool_orientation.push_back({{{1, 0, 0, 0}, {0, 1, 0, 0}}});
        r.steps.grab.push_back({0, std::int8_t(k)});
        r.steps.applied.push_back({0, 1});
        r.steps.force_n.push_back({{{0, 0, 0}, {0.1, 0.2, 0.3 * k}}});
        r.steps.force_step.push_back(k - 1);
        r.steps.diverged.push_back(0);
    }
    r.events.push_back({1.5, 1, "grab"});
    r.events.push_back({2.5, -1, "emergency_stop"});
    test::TempDir dir;
    write_recording(dir / "r.h5", r);
    const Recording back = read_recording(dir / "r.h5");
    EXPECT_FALSE(back.hands[0].used);
    ASSERT_TRUE(back.hands[1].used);
    EXPECT_EQ(back.hands[1].position_mm, r.hands[1].position_mm);
    EXPECT_EQ(back.hands[1].buttons, r.hands[1].buttons);
    EXPECT_EQ(back.hands[1].gain, r.hands[1].gain);
    EXPECT_EQ(back.hands[1].semi_axes_mm, r.hands[1].semi_axes_mm);
    EXPECT_EQ(back.steps.tool_position_mm, r.steps.tool_position_mm);
    EXPECT_EQ(back.steps.force_n, r.steps.force_n);
    EXPECT_EQ(back.steps.grab, r.steps.grab);
    EXPECT_EQ(back.steps.applied, r.steps.applied);
    EXPECT_EQ(back.steps.force_step, r.steps.force_step);
    ASSERT_EQ(back.events.size(), 2u);
    EXPECT_EQ(back.events[1].what, "emergency_stop");
    EXPECT_EQ(back.events[0].hand, 1);
    EXPECT_EQ(back.period_p99_ms, 1.25);
    EXPECT_EQ(back.arithmetic, "fused");
    ASSERT_TRUE(back.rules.has_value());
    EXPECT_EQ(*back.rules, *r.rules);
    {
        Recording unruled = r;
        unruled.rules.reset();
        write_recording(dir / "unruled.h5", unruled);
        EXPECT_FALSE(read_recording(dir / "unruled.h5").rules.has_value());
    }
    {
        Recording separate = r;
        separate.arithmetic = "separate";
        write_recording(dir / "separate.h5", separate);
        EXPECT_EQ(read_recording(dir / "separate.h5").arithmetic, "separate");
    }
    EXPECT_TRUE(back.steps.mass_scale.empty()) << "no column written: 1 throughout";
    EXPECT_EQ(back.steps.mass_scale_at(1), 1.0);
    {
        Recording scaled = r;
        scaled.steps.mass_scale = {1.0, 8.0};
        write_recording(dir / "scaled.h5", scaled);
        EXPECT_EQ(read_recording(dir / "scaled.h5").steps.mass_scale, scaled.steps.mass_scale);
        scaled.steps.mass_scale = {1.0, 0.5};
        write_recording(dir / "scaled.h5", scaled);
        try {
            read_recording(dir / "scaled.h5");
            ADD_FAILURE() << "accepted a mass scale below 1";
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("steps/mass_scale"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find("row 1"), std::string::npos) << e.what();
        }
    }

    // Damaged recordings are refused by file, dataset and row, never half-used.
    auto refused = [&](const Recording& damaged, const std::string& expected) {
        write_recording(dir / "damaged.h5", damaged);
        try {
            read_recording(dir / "damaged.h5");
            ADD_FAILURE() << "accepted; expected: " << expected;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
        }
    };
    EXPECT_TRUE(back.steps.instrument.empty()) << "no column written: the hand's attributes throughout";
    EXPECT_EQ(back.instrument_at(1, 1).kind, InstrumentKind::grabber);
    EXPECT_EQ(back.instrument_at(1, 1).semi_axes, Eigen::Vector3d(1, 2, 3));
    {
        // K in the window at step 1: hand 1's grabber becomes a scalpel, which grabs (its blade
        // lowered) by the step's own instrument; hand 0 holds nothing.
        Recording switched = r;
        switched.steps.instrument = {{0, instrument_code(InstrumentKind::grabber)}, {0, instrument_code(InstrumentKind::scalpel)}};
        switched.steps.semi_axes_mm = {{{{0, 0, 0}, {1, 2, 3}}}, {{{0, 0, 0}, {2, 0.3, 10}}}};
        write_recording(dir / "switched.h5", switched);
        const Recording again = read_recording(dir / "switched.h5");
        EXPECT_EQ(again.steps.instrument, switched.steps.instrument);
        EXPECT_EQ(again.steps.semi_axes_mm, switched.steps.semi_axes_mm);
        EXPECT_EQ(again.instrument_at(0, 1).kind, InstrumentKind::grabber);
        EXPECT_EQ(again.instrument_at(1, 1).kind, InstrumentKind::scalpel);
        EXPECT_EQ(again.instrument_at(1, 1).semi_axes, Eigen::Vector3d(2, 0.3, 10));
        EXPECT_EQ(again.patch_material, "pericardium");
        switched.patch_material = "dacron";
        write_recording(dir / "switched.h5", switched);
        EXPECT_EQ(read_recording(dir / "switched.h5").patch_material, "dacron");
        Recording bad = switched;
        bad.steps.instrument[1][1] = 7;  // 6 is the retractor
        refused(bad, "steps/instrument: row 1, hand 1 is 7, expected 0 (none)");
        bad = switched;
        bad.steps.instrument[1][1] = instrument_code(InstrumentKind::probe);  // a probe does not grab
        refused(bad, "dataset grab row 1, hand 1 grabs with a hand that holds no grabber");
        bad = switched;
        bad.steps.instrument[0][0] = instrument_code(InstrumentKind::probe);  // hand 0 has no device
        refused(bad, "steps/instrument: row 0, hand 0 is an instrument of a hand without a device");
        bad = switched;
        bad.steps.instrument[0][1] = instrument_code(InstrumentKind::none);  // hand 1 has a device
        refused(bad, "steps/instrument: row 0, hand 1 holds no instrument in a hand with a device");
        bad = switched;
        bad.patch_material = "cardboard";
        refused(bad, "attribute patch_material: ");
        bad = switched;
        bad.steps.semi_axes_mm[1][1][2] = -10.0;
        refused(bad, "steps/semi_axes_mm: row 1, hand 1: semi-axis");
    }

    // A force that names a later step than its own is refused by dataset name.
    Recording bad = r;
    bad.steps.force_step[0] = 1;
    write_recording(dir / "bad.h5", bad);
    try {
        read_recording(dir / "bad.h5");
        ADD_FAILURE() << "accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("force_step"), std::string::npos) << e.what();
    }
    {
        Recording damaged = r;
        damaged.rules->watchdog_interval = 0;
        refused(damaged, "/rules: watchdog_interval must be at least 1");
        damaged = r;
        damaged.rules->energy_growth_limit = 0.5;
        refused(damaged, "/rules: energy_growth_limit must be above 1");
    }
    {
        Recording unknown = r;
        unknown.arithmetic = "fast";
        refused(unknown, "attribute arithmetic must be fused or separate, not 'fast'");
    }

    // A value the writer refuses, put into a written file by hand: the reader must refuse it.
    auto refused_by_hand = [&](const std::string& dataset, const std::vector<double>& values, const std::string& expected) {
        write_recording(dir / "by-hand.h5", r);
        test::overwrite(dir / "by-hand.h5", dataset.c_str(), values, H5T_NATIVE_DOUBLE);
        try {
            read_recording(dir / "by-hand.h5");
            ADD_FAILURE() << "read; expected: " << expected;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
        }
    };
    {
        // The writer refuses a non-finite force; one put there by hand is refused by the reader.
        Recording d = r;
        d.steps.force_n[1][1][2] = std::numeric_limits<double>::quiet_NaN();
        try {
            write_recording(dir / "nan.h5", d);
            ADD_FAILURE() << "a NaN force was written";
        } catch (const OutputError& e) {
            EXPECT_NE(std::string(e.what()).find("dataset steps/force_n holds a non-finite value"), std::string::npos) << e.what();
        }
        EXPECT_FALSE(fs::exists(dir / "nan.h5"));
        std::vector<double> forces(r.steps.size() * 6);
        std::memcpy(forces.data(), r.steps.force_n.data(), forces.size() * sizeof(double));
        forces[11] = std::numeric_limits<double>::quiet_NaN();  // row 1, hand 1, z
        refused_by_hand("steps/force_n", forces, "steps/force_n: value 11 is not finite");
    }
    {
        Recording d = r;
        d.steps.grab[1][1] = 7;
        refused(d, "grab row 1, hand 1 is not 0 or 1");
    }
    {
        // So is a NaN step time (the writer refuses one too).
        std::vector<double> times = r.steps.time_ms;
        times[1] = std::numeric_limits<double>::quiet_NaN();
        refused_by_hand("steps/time_ms", times, "steps/time_ms: value 1 is not finite");
    }
    {
        Recording d = r;
        d.steps.applied[1][0] = 1;  // hand 0 has no device
        refused(d, "applied row 1, hand 0 applies a hand without a device");
    }
    {
        Recording d = r;
        d.steps.grab[0][0] = 1;  // hand 0 has no device, let alone a grabber
        refused(d, "grabs with a hand that holds no grabber, retractor, scalpel, patch or needle");
    }
    {
        Recording d = r;
        d.steps.tool_orientation[0][1] = {0, 0, 0, 0};
        refused(d, "tool_orientation row 0, hand 1 is a zero quaternion");
    }
    {
        Recording d = r;
        d.hands[1].mapping_rotation = {2, 0, 0, 0};
        refused(d, "mapping_rotation is not a unit quaternion");
    }
    // An attribute holding many values where one is expected (HDF5 would write them all into
    // one variable) and a list of strings where one format name is expected.
    write_recording(dir / "arrays.h5", r);
    {
        const hid_t file = H5Fopen((dir / "arrays.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        ASSERT_GE(file, 0);
        const hid_t hand = H5Gopen2(file, "hand1", H5P_DEFAULT);
        H5Adelete(hand, "max_force_n");
        const hsize_t many = 4096;
        const std::vector<double> values(many, 1.0);
        const hid_t space = H5Screate_simple(1, &many, nullptr);
        const hid_t attribute = H5Acreate2(hand, "max_force_n", H5T_IEEE_F64LE, space, H5P_DEFAULT, H5P_DEFAULT);
        H5Awrite(attribute, H5T_NATIVE_DOUBLE, values.data());
        H5Aclose(attribute), H5Sclose(space), H5Gclose(hand), H5Fclose(file);
    }
    try {
        read_recording(dir / "arrays.h5");
        ADD_FAILURE() << "an array attribute was read as one value";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("max_force_n must be a single value"), std::string::npos) << e.what();
    }
    {
        const hid_t file = H5Fopen((dir / "arrays.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        H5Adelete(file, "format");
        const hsize_t many = 1000;
        const hid_t type = H5Tcopy(H5T_C_S1);
        H5Tset_size(type, 32);
        const std::vector<char> text(many * 32, 'x');
        const hid_t space = H5Screate_simple(1, &many, nullptr);
        const hid_t attribute = H5Acreate2(file, "format", type, space, H5P_DEFAULT, H5P_DEFAULT);
        H5Awrite(attribute, type, text.data());
        H5Aclose(attribute), H5Sclose(space), H5Tclose(type), H5Fclose(file);
    }
    try {
        read_recording(dir / "arrays.h5");
        ADD_FAILURE() << "a list of strings was read as one";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("format must be a single string"), std::string::npos) << e.what();
    }

    // Recordings written before the event names became UTF-8 strings kept them as 24-byte
    // fixed-length strings: those still read, name for name.
    write_recording(dir / "fixed.h5", r);
    {
        const hid_t file = H5Fopen((dir / "fixed.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        ASSERT_GE(file, 0);
        H5Ldelete(file, "events/what", H5P_DEFAULT);
        const hsize_t count = r.events.size();
        const hid_t type = H5Tcopy(H5T_C_S1);
        H5Tset_size(type, 24);
        H5Tset_strpad(type, H5T_STR_NULLTERM);
        std::vector<char> text(count * 24, '\0');
        for (std::size_t i = 0; i < count; ++i) std::strncpy(&text[i * 24], r.events[i].what.c_str(), 23);
        const hid_t space = H5Screate_simple(1, &count, nullptr);
        const hid_t set = H5Dcreate2(file, "events/what", type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
        H5Dwrite(set, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, text.data());
        H5Dclose(set), H5Sclose(space), H5Tclose(type), H5Fclose(file);
    }
    {
        const Recording fixed = read_recording(dir / "fixed.h5");
        ASSERT_EQ(fixed.events.size(), r.events.size());
        for (std::size_t i = 0; i < r.events.size(); ++i) EXPECT_EQ(fixed.events[i].what, r.events[i].what);
    }

    // Nothing half-written: a failed write leaves no file behind.
    Recording uneven = r;
    uneven.steps.wall_ms.pop_back();
    EXPECT_THROW(write_recording(dir / "uneven.h5", uneven), OutputError);
    EXPECT_FALSE(fs::exists(dir / "uneven.h5"));
}
