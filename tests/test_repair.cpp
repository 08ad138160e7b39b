// The repair of a septal defect at run time (runtime/surgery/repair.h): a patch and its stitches riding on
// the real backends. A haptic session on two scripted devices (a patch, a needle) closing the VSD
// of the synthetic two-chamber block, replayed bit for bit; a patch sewn onto a slab of tissue that
// is then stretched, followed by its stitches, with Newton's third law between patch and tissue at
// every step; and the same scripted repair on the cpu and gl backends.
#include "defect_block_scenario.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/recording.h"
#include "formats/scenario.h"
#include "formats/state.h"
#include "formats/volume_io.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/surgery/repair.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/core/trajectory.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <numbers>
#include <regex>

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;

namespace {

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

Eigen::Vector3d vec(const std::array<float, 3>& p) { return {double(p[0]), double(p[1]), double(p[2])}; }

/// The diagonal of the box of the rest positions, mm (the cpu = gl tolerance is 1e-4 of it, as in
/// test_runtime_backend.cpp).
double model_size(const Scenario& scenario) {
    Eigen::AlignedBox3d box;
    for (const auto& p : scenario.lattice.particles.rest_position) box.extend(vec(p));
    return box.diagonal().norm();
}

/// The two-chamber block (septum 6 mm thick) with an 8 mm VSD at local (0.5, −4, 6) mm, built by
/// heartprep at 3,000 particles, and `heartsim plan-repair`'s 4-stitch closure of it: hand 0 lays
/// the patch at 0 ms, hand 1's needle ties stitches at 60, 280, 500 and 720 ms, the gesture ends at
/// 1,200 ms. Each hand's rows are also written as a device's pose script (time, pose, button 1 =
/// the plan's grab), for `--device scripted:FILE`. And plan-repair's closure with 8 stitches,
/// ending at 2,080 ms.
struct BlockRepair {
    test::TempDir dir;
    fs::path scenario = dir / "vsd.h5", plan = dir / "repair.csv", closure = dir / "closure.csv";
    std::array<fs::path, 2> script{dir / "patch_hand.csv", dir / "needle_hand.csv"};
    double end_ms = 0.0;
    BlockRepair() {
        test::defect_block::build_block_scenario(test::defect_block::make_block(), dir / "block.nrrd", scenario, "vsd", 3000);
        const auto planned = heartsim_command("plan-repair " + quoted(scenario) + " -o " + quoted(plan) + " --stitches=4");
        if (planned.exit_code != 0) throw std::runtime_error("plan-repair failed: " + planned.output);
        const auto whole = heartsim_command("plan-repair " + quoted(scenario) + " -o " + quoted(closure) + " --stitches=8");
        if (whole.exit_code != 0) throw std::runtime_error("plan-repair failed: " + whole.output);
        const Trajectory trajectory = read_trajectory(plan);
        for (int hand = 0; hand < 2; ++hand) {
            std::ofstream out(script[std::size_t(hand)]);
            out << "# time_ms, x, y, z, qw, qx, qy, qz, buttons: hand " << hand << " of " << plan.filename().string() << "\n";
            for (const InstrumentKeyframe& k : trajectory.keyframes) {
                end_ms = std::max(end_ms, k.time_ms);
                if (k.hand != hand) continue;
                const auto& p = k.pose.position;
                const auto& q = k.pose.orientation;
                char line[256];
                std::snprintf(line, sizeof line, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", k.time_ms, p.x(), p.y(), p.z(), q.w(),
                              q.x(), q.y(), q.z(), k.grab ? 1 : 0);
                out << line;
            }
        }
    }
};

const BlockRepair& block_repair() {
    static const BlockRepair built;
    return built;
}

/// The closure verdict a run prints: "yes" or "no", and the largest rim gap, mm.
struct Verdict {
    std::string closed;
    double gap_mm = -1.0;
};
Verdict verdict_of(const std::string& output) {
    std::smatch m;
    if (!std::regex_search(output, m, std::regex("defect closed: (yes|no), largest rim gap ([0-9.]+) mm"))) return {};
    return {m[1], std::stod(m[2])};
}

double end_of(const Trajectory& trajectory) {
    double end = 0.0;
    for (const InstrumentKeyframe& k : trajectory.keyframes) end = std::max(end, k.time_ms);
    return end;
}

double largest_difference(const std::vector<std::array<float, 3>>& a, const std::vector<std::array<float, 3>>& b) {
    double d = 0.0;
    for (std::size_t i = 0; i < a.size() && i < b.size(); ++i)
        for (int c = 0; c < 3; ++c) d = std::max(d, double(std::abs(a[i][c] - b[i][c])));
    return d;
}

}  // namespace

// Two scripted devices close the block's VSD in a haptic session on the cpu backend: hand 0 holds
// a patch (--instrument patch: the default 18 mm disc, 0.5 mm thick) and lays it with button 1,
// hand 1 a needle whose button ties each stitch, their pose scripts the plan's rows. The recording
// names both instruments with their semi-axes; the needle's hand is sent a force only while its
// button is held. `--replay` reproduces every recorded force bit for bit, and the replay's saved
// state holds the patch exactly where the session's did, sewn by the same stitches.
TEST(Repair, AHapticRepairSessionReplaysBitForBit) {
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    const double seconds = 1e-3 * b.end_ms + 0.1;
    char length[32];
    std::snprintf(length, sizeof length, "%.3f", seconds);
    const auto live = heartsim_command("run " + quoted(b.scenario) + " --headless --backend cpu --device scripted:" + quoted(b.script[0]) +
                                       " --device scripted:" + quoted(b.script[1]) + " --instrument patch --instrument needle --patch-material ptfe --seconds " +
                                       length + " --record " + quoted(dir / "repair.h5") + " --save-state " + quoted(dir / "live.h5"));
    ASSERT_EQ(live.exit_code, 0) << live.output;
    std::printf("%s\n", live.output.c_str());
    for (const char* line : {"hand 0: scripted:", "→ patch 9×9×0.25 mm", "hand 1: scripted:", "→ needle 0.25×0.25×6 mm", "ptfe patch laid at",
                             "stitch 1 tied", "stitch 4 tied", "defect closed: "})
        EXPECT_NE(live.output.find(line), std::string::npos) << line;
    EXPECT_EQ(live.output.find("stitch 5 tied"), std::string::npos) << "one stitch per press of the needle's button";

    const Recording recorded = read_recording(dir / "repair.h5");
    ASSERT_TRUE(recorded.hands[0].used && recorded.hands[1].used);
    EXPECT_EQ(recorded.hands[0].instrument, "patch");
    EXPECT_EQ(recorded.hands[1].instrument, "needle");
    EXPECT_EQ(recorded.hands[0].semi_axes_mm, (std::array<double, 3>{9, 9, 0.25}));
    EXPECT_EQ(recorded.hands[1].semi_axes_mm, (std::array<double, 3>{0.25, 0.25, 6}));
    EXPECT_EQ(recorded.patch_material, "ptfe");
    std::array<int, 2> presses{0, 0};
    for (const auto& e : recorded.events)
        if (e.what == "grab" && e.hand >= 0) ++presses[std::size_t(e.hand)];
    EXPECT_EQ(presses[0], 1) << "the patch is laid once";
    EXPECT_EQ(presses[1], 4) << "a press per stitch";
    // The patch's hand feels nothing; the needle's hand the suture's tension while the button is
    // held and, carried, at most the wall's push at the puncture (libmodel/surgery/needle_feel.h).
    double needle_held = 0.0;
    std::size_t held_steps = 0;
    const RecordedSteps& s = recorded.steps;
    for (std::size_t k = 0; k < s.size(); ++k) {
        const Eigen::Vector3d patch_hand(s.force_n[k][0][0], s.force_n[k][0][1], s.force_n[k][0][2]);
        const Eigen::Vector3d needle_hand(s.force_n[k][1][0], s.force_n[k][1][1], s.force_n[k][1][2]);
        ASSERT_EQ(patch_hand.norm(), 0.0) << "step " << k;
        if (s.force_step[k] < 0) continue;
        if (!s.grab[std::size_t(s.force_step[k])][1]) ASSERT_LE(needle_hand.norm(), NeedleFeel{}.puncture_n) << "step " << k;
        else needle_held = std::max(needle_held, needle_hand.norm()), ++held_steps;
    }
    std::printf("  %zu steps recorded; the needle's hand felt up to %.4g N over %zu steps with its button held\n", s.size(), needle_held,
                held_steps);
    EXPECT_GT(held_steps, 100u);
    EXPECT_GT(needle_held, 0.0) << "the stitches' tension should reach the needle's hand";

    const auto replay = heartsim_command("run " + quoted(b.scenario) + " --headless --replay " + quoted(dir / "repair.h5") + " --save-state " +
                                         quoted(dir / "replayed.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("stitch 4 tied"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("ptfe patch laid at"), std::string::npos) << "the replay lays the recorded material\n" << replay.output;
    // A replay ends with the closure check every run on a defect ends with, and reaches the session's verdict.
    const Verdict live_verdict = verdict_of(live.output), replay_verdict = verdict_of(replay.output);
    ASSERT_FALSE(live_verdict.closed.empty()) << live.output;
    EXPECT_EQ(replay_verdict.closed, live_verdict.closed) << replay.output;
    EXPECT_EQ(replay_verdict.gap_mm, live_verdict.gap_mm) << replay.output;

    const SimulationState session = read_state(dir / "live.h5"), again = read_state(dir / "replayed.h5");
    EXPECT_EQ(session.kind[0], 4);
    EXPECT_EQ(session.kind[1], 5);
    EXPECT_EQ(again.kind, session.kind);
    ASSERT_TRUE(session.patch.has_value());
    ASSERT_TRUE(again.patch.has_value());
    EXPECT_EQ(session.patch->stitch_vertex.size(), 4u);
    EXPECT_EQ(again.patch->stitch_vertex, session.patch->stitch_vertex);
    EXPECT_EQ(again.patch->stitch_tied_ms, session.patch->stitch_tied_ms);
    ASSERT_EQ(again.patch->positions.size(), session.patch->positions.size());
    EXPECT_TRUE(again.patch->positions == session.patch->positions)
        << "largest difference " << largest_difference(again.patch->positions, session.patch->positions) << " mm";
    EXPECT_TRUE(again.positions == session.positions) << "largest difference " << largest_difference(again.positions, session.positions) << " mm";
    EXPECT_EQ(again.patch->closed, session.patch->closed);
    EXPECT_EQ(again.patch->largest_rim_gap_mm, session.patch->largest_rim_gap_mm);
}

namespace {

/// The slab's half-extents (x, y, z), mm: 60 × 24 × 9 mm, its top face at z = 4.5 mm. At 3,000
/// particles its lattice spacing is about 1.7 mm, as a heart's at its default budget (pat6: 1.5 mm).
const Eigen::Vector3d slab_half(30.0, 12.0, 4.5);

/// The slab, clamped at its x = −half_x end (tissue touching label 2 is anchored), without
/// gravity or supports, built by heartprep at 3,000 particles.
const fs::path& slab() {
    static test::TempDir dir;
    static const fs::path built = [] {
        LabelVolume v;
        auto& g = v.geometry;
        g.spacing = Eigen::Vector3d::Constant(0.5);
        const Eigen::Vector3d box = slab_half + Eigen::Vector3d(4.0, 2.0, 2.0);  // the clamp, and a margin of background
        for (int a = 0; a < 3; ++a) g.dims[std::size_t(a)] = 2 * int(std::ceil(box[a] / 0.5)) + 1;
        g.origin = -0.25 * Eigen::Vector3d(g.dims[0] - 1, g.dims[1] - 1, g.dims[2] - 1);  // centred on the origin
        v.labels.assign(g.voxel_count(), 0);
        for (int k = 0; k < g.dims[2]; ++k)
            for (int j = 0; j < g.dims[1]; ++j)
                for (int i = 0; i < g.dims[0]; ++i) {
                    const Eigen::Vector3d p = g.origin + 0.5 * Eigen::Vector3d(i, j, k);
                    if (std::abs(p.y()) >= slab_half.y() || std::abs(p.z()) >= slab_half.z() || p.x() <= -slab_half.x() - 2.0 ||
                        p.x() >= slab_half.x())
                        continue;
                    v.labels[g.linear(i, j, k)] = p.x() < -slab_half.x() ? 2 : 1;
                }
        write_label_volume(dir / "slab.nrrd", v);
        const fs::path out = dir / "slab.h5";
        const auto r = test::heartprep("build " + quoted(dir / "slab.nrrd") + " -o " + quoted(out) +
                                       " --anchor-label 2 --support none --gravity 0 0 0 --embedding-stiffness 0 --particles 3000 -q");
        if (r.exit_code != 0) throw std::runtime_error("heartprep build failed: " + r.output);
        return out;
    }();
    return built;
}

/// The tool pointing down (tool +z = world −z): a patch laid on the slab's top face faces it.
const Eigen::Quaterniond facing_down(0.0, 1.0, 0.0, 0.0);

}  // namespace

// A 12 mm patch laid on the slab's top face and sewn by 4 stitches 4 mm from its centre
// (RepairBackend on the cpu backend, with the settings every run mode gives it); then a grabber
// takes the free end and pulls it 3 mm along the slab. At every step of the pull and after it, each
// stitch holds its patch vertex within half the patch's thickness + 0.1 mm of its tissue point, and
// the patch's centroid moves as the mean of those points, within the same 0.1 mm. While the
// needle's button is held its hand feels exactly the suture's tension (libmodel/surgery/needle_feel.h:
// NeedleFeel::suture_tension_n times the smoothstep of the time since the tie over tie_ms) along
// the shaft toward the slab, and once let go at most the wall's push at a puncture. At every step the loads the patch leaves on the tissue add up to minus the forces on the
// patch (its stitches' and the contact's): Newton's third law, to the rounding of the carriers'
// weights (the mapping's, float: each point's sum to 1 within about 1e-7).
TEST(Repair, APatchSewnOnASlabFollowsItWhenItIsStretched) {
    const Scenario scenario = read_scenario(slab());
    auto made = with_repair(make_cpu_backend(scenario, options_from(scenario.solver)), scenario, RepairSettings{});
    RepairBackend* repair = repair_of(*made);
    ASSERT_NE(repair, nullptr) << "a scenario with a detailed mesh takes a patch";
    Backend& backend = *repair;
    const double dt = backend.time_step_ms();
    const int per_ms = int(std::ceil(1.0 / dt));

    double newton_residual = 0.0, newton_scale = 0.0, largest_stitch = 0.0, largest_contact = 0.0;
    auto step = [&](int steps) {
        for (int s = 0; s < steps; ++s) {
            const StepReport r = backend.step(1);
            ASSERT_FALSE(r.diverged) << r.message;
            const PatchModel* patch = repair->patch();
            if (!patch) continue;
            Eigen::Vector3d on_patch = patch->contact_force(), on_tissue = Eigen::Vector3d::Zero();
            double scale = patch->contact_force().norm();
            for (const Stitch& stitch : patch->stitches()) {
                on_patch += stitch.force_n;
                scale += stitch.force_n.norm();
                largest_stitch = std::max(largest_stitch, stitch.force_n.norm());
            }
            largest_contact = std::max(largest_contact, patch->contact_force().norm());
            for (const ParticleLoad& load : patch->loads()) on_tissue += load.force_n;
            newton_residual = std::max(newton_residual, (on_tissue + on_patch).norm());
            newton_scale = std::max(newton_scale, scale);
        }
    };

    // The patch: 12 mm across, 0.5 mm thick, centred over the slab's middle (laid from 1 mm above
    // the face, it drapes onto it).
    const double half_thickness = 0.25;
    backend.set_instrument(0, {.kind = InstrumentKind::patch, .semi_axes = {6.0, 6.0, half_thickness}});
    backend.set_pose(0, {.position = {0, 0, slab_half.z() + 1.0}, .orientation = facing_down});
    backend.begin_grab(0);
    ASSERT_NE(repair->patch(), nullptr);
    backend.release(0);
    step(5 * per_ms);
    // Four stitches, 4 mm from the centre along ±x and ±y, each pressed for 30 ms.
    backend.set_instrument(1, {.kind = InstrumentKind::needle, .semi_axes = {0.25, 0.25, 6.0}});
    double felt = 0.0, felt_after = 0.0, mismatch = 0.0;
    const double top = slab_half.z();
    for (const Eigen::Vector3d& site :
         {Eigen::Vector3d(4, 0, top), Eigen::Vector3d(0, 4, top), Eigen::Vector3d(-4, 0, top), Eigen::Vector3d(0, -4, top)}) {
        backend.set_pose(1, {.position = site, .orientation = facing_down});
        const std::size_t stitch = repair->patch()->stitches().size();
        backend.begin_grab(1);
        ASSERT_EQ(repair->patch()->stitches().size(), stitch + 1) << "no stitch tied at (" << site.transpose() << ")";
        const double tied_ms = backend.simulated_time_ms();
        const Eigen::Vector3d shaft = facing_down * Eigen::Vector3d::UnitZ();
        for (int s = 0; s < 30 * per_ms; ++s) {
            step(1);
            const Eigen::Vector3d hand = backend.instrument_forces().hand[1].force_n;
            const double tension = suture_tension_n(NeedleFeel{}, backend.simulated_time_ms() - tied_ms, RepairSettings{}.tie_ms);
            mismatch = std::max(mismatch, (hand + tension * shaft).norm());
            felt = std::max(felt, hand.norm());
        }
        backend.release(1);
        step(1);
        felt_after = std::max(felt_after, backend.instrument_forces().hand[1].force_n.norm());
        step(10 * per_ms);
    }
    ASSERT_EQ(repair->patch()->stitches().size(), 4u);
    std::printf("  the needle's hand felt up to %.4g N while tying (the suture's tension, to %.3g N), %.3g N once let go\n", felt, mismatch,
                felt_after);
    EXPECT_GT(felt, 0.0);
    EXPECT_LE(mismatch, 1e-12);
    EXPECT_LE(felt_after, NeedleFeel{}.puncture_n);
    step(250 * per_ms);  // the last stitch draws tight (150 ms) and the patch settles

    const PatchModel& patch = *repair->patch();
    auto gaps = [&] {
        const auto anchors = repair->stitch_anchors();
        double largest = 0.0;
        for (std::size_t k = 0; k < anchors.size(); ++k)
            largest = std::max(largest, (patch.positions()[std::size_t(patch.stitches()[k].vertex)] - anchors[k]).norm());
        return largest;
    };
    auto centroid = [&] {
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        for (const auto& x : patch.positions()) c += x;
        return Eigen::Vector3d(c / double(patch.positions().size()));
    };
    auto mean_anchor = [&] {
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        for (const auto& a : repair->stitch_anchors()) c += a;
        return Eigen::Vector3d(c / 4.0);
    };
    // How far apart the ±x stitches' tissue points stand: the tissue stretches under the pull, the
    // patch (a thousand times stiffer) does not, so each of those stitches gives by half the change.
    auto anchor_span = [&] {
        const auto anchors = repair->stitch_anchors();
        return (anchors[0] - anchors[2]).norm();
    };
    const double sewn_gap = gaps(), span_before = anchor_span();
    const Eigen::Vector3d centroid_before = centroid(), anchors_before = mean_anchor();

    // The grabber (hand 0, the patch laid) takes the last 2.5 mm of the free end and pulls it 3 mm
    // along +x over 300 ms, then holds it 300 ms.
    const Eigen::Vector3d grip(slab_half.x() - 0.5, 0, 0);
    backend.set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = {2.0, slab_half.y() + 1.0, slab_half.z() + 1.0}});
    backend.set_pose(0, {.position = grip});
    ASSERT_GT(backend.begin_grab(0), 20u) << "the grabber should hold the slab's end";
    double pulled_gap = 0.0, spread = 0.0;
    const int pull = 300 * per_ms;
    for (int s = 1; s <= 2 * pull; ++s) {
        backend.set_pose(0, {.position = grip + Eigen::Vector3d(3.0 * std::min(1.0, double(s) / pull), 0, 0)});
        step(1);
        pulled_gap = std::max(pulled_gap, gaps());
        spread = std::max(spread, anchor_span() - span_before);
    }
    const Eigen::Vector3d moved = centroid() - centroid_before, anchors_moved = mean_anchor() - anchors_before;
    std::printf("  stitch gaps (patch vertex to tissue point): %.3f mm sewn, at most %.3f mm during and after the pull (bound %.2f mm: "
                "the tissue under the ±x stitches spread %.3f mm)\n",
                sewn_gap, pulled_gap, half_thickness + 0.5 * spread + 0.1, spread);
    std::printf("  the patch's centroid moved (%.4f, %.4f, %.4f) mm, its stitches' tissue points (%.4f, %.4f, %.4f) mm on average\n",
                moved.x(), moved.y(), moved.z(), anchors_moved.x(), anchors_moved.y(), anchors_moved.z());
    std::printf("  Newton: |Σ loads on the tissue + Σ forces on the patch| at most %.3g N (forces up to %.3g N; stitch %.3g N, contact %.3g N)\n",
                newton_residual, newton_scale, largest_stitch, largest_contact);
    EXPECT_LE(sewn_gap, half_thickness + 0.1);
    EXPECT_LE(pulled_gap, half_thickness + 0.5 * spread + 0.1);
    // The patch itself keeps its shape: the distance between the ±x stitches' patch points.
    const double patch_span = (patch.positions()[std::size_t(patch.stitches()[0].vertex)] - patch.positions()[std::size_t(patch.stitches()[2].vertex)]).norm();
    EXPECT_NEAR(patch_span, span_before, 0.02 * span_before);
    EXPECT_GT(anchors_moved.x(), 1.0) << "the tissue under the patch should move with the pull";
    EXPECT_LE((moved - anchors_moved).norm(), 0.1);
    EXPECT_GT(largest_stitch, 0.0);
    EXPECT_GT(largest_contact, 0.0);
    EXPECT_LE(newton_residual, 1e-6 * newton_scale);
}

// plan-repair's 8-stitch closure of the block's VSD played by `heartsim run --trajectory` on the cpu
// and gl backends (llvmpipe where there is no GPU; the gl backend steps the patch in its compute
// pass, twice to the same bit): the patch ends where it ends on the other
// backend within 1e-4 of the model's size (the backends' agreement elsewhere,
// test_runtime_backend.cpp), sewn by the same stitches, and both print the same closure verdict:
// closed, the patch checked as it lies (--leak-test 0), sewn all round over the opening.
TEST(Repair, TheCpuAndGlBackendsSewThePatchAlike) {
    REQUIRE_GL();
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    char length[32];
    std::snprintf(length, sizeof length, "%.3f", 1e-3 * end_of(read_trajectory(b.closure)));
    std::map<std::string, test::CommandResult> runs;
    std::map<std::string, SimulationState> states;
    for (const std::string backend : {"cpu", "gl"}) {
        const fs::path state = dir / (backend + ".h5");
        runs[backend] = heartsim_command("run " + quoted(b.scenario) + " --headless --backend " + backend + " --trajectory " + quoted(b.closure) +
                                         " --seconds " + length + " --leak-test 0 --save-state " + quoted(state));
        ASSERT_EQ(runs[backend].exit_code, 0) << runs[backend].output;
        states[backend] = read_state(state);
        ASSERT_TRUE(states[backend].patch.has_value()) << runs[backend].output;
    }
    // The gl backend's patch pass gathers rather than scatters: a second run is the same to the bit.
    {
        const fs::path again = dir / "gl-again.h5";
        const auto run = heartsim_command("run " + quoted(b.scenario) + " --headless --backend gl --trajectory " + quoted(b.closure) +
                                          " --seconds " + length + " --leak-test 0 --save-state " + quoted(again));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        const SimulationState second = read_state(again);
        ASSERT_TRUE(second.patch.has_value());
        EXPECT_EQ(second.patch->positions, states["gl"].patch->positions);
        EXPECT_EQ(second.positions, states["gl"].positions);
        EXPECT_NE(runs["gl"].output.find("ran on the GPU"), std::string::npos) << runs["gl"].output;
        EXPECT_TRUE(std::regex_search(runs["gl"].output, std::regex("the GPU spent [0-9.e+-]+ ms on each of the patch's [1-9][0-9]* steps")))
            << runs["gl"].output;
    }
    const PatchState &cpu = *states["cpu"].patch, &gl = *states["gl"].patch;
    const double size = model_size(read_scenario(b.scenario)), tolerance = 1e-4 * size;
    ASSERT_EQ(cpu.positions.size(), gl.positions.size());
    EXPECT_EQ(cpu.stitch_vertex.size(), 8u);
    EXPECT_EQ(gl.stitch_vertex, cpu.stitch_vertex);
    const double patch_error = largest_difference(cpu.positions, gl.positions);
    const double anchor_error = largest_difference(cpu.stitch_anchor, gl.stitch_anchor);
    const double tissue_error = largest_difference(states["cpu"].positions, states["gl"].positions);
    const Verdict on_cpu = verdict_of(runs["cpu"].output), on_gl = verdict_of(runs["gl"].output);
    std::printf("  max |x_gl - x_cpu|: patch %.3g mm, stitches' tissue points %.3g mm, tissue %.3g mm (tolerance %.3g mm, 1e-4 of %.1f mm)\n"
                "  closure: cpu %s (largest rim gap %.2f mm), gl %s (%.2f mm)\n",
                patch_error, anchor_error, tissue_error, tolerance, size, on_cpu.closed.c_str(), on_cpu.gap_mm, on_gl.closed.c_str(), on_gl.gap_mm);
    EXPECT_LE(patch_error, tolerance);
    EXPECT_LE(anchor_error, tolerance);
    EXPECT_LE(tissue_error, tolerance);
    EXPECT_EQ(on_cpu.closed, "yes") << runs["cpu"].output;
    EXPECT_EQ(on_gl.closed, on_cpu.closed) << runs["gl"].output;
    // The gap is a distance between the two meshes, each within the tolerance, printed to 0.01 mm.
    EXPECT_LE(std::abs(on_gl.gap_mm - on_cpu.gap_mm), 2 * tolerance + 0.01);
}

// After plan-repair's eight stitches, hand 0 takes a 2 mm probe and presses it 1 mm into the middle
// of the sewn patch, over the opening: the probe pushes the patch (no patch vertex inside it, grown
// by half the patch's thickness), the hand is pushed back towards the side it came from, and the
// defect stays closed (the patch as it lies: --leak-test 0, as the run without the probe).
TEST(Repair, AProbePressedOnTheSewnPatchIsPushedBackAndTheDefectStaysClosed) {
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    const Trajectory plan = read_trajectory(b.closure);
    const double end = end_of(plan);
    char length[32];
    std::snprintf(length, sizeof length, "%.3f", 1e-3 * end);
    const auto sewn = heartsim_command("run " + quoted(b.scenario) + " --headless --trajectory " + quoted(b.closure) + " --seconds " + length +
                                       " --leak-test 0 --save-state " + quoted(dir / "sewn.h5"));
    ASSERT_EQ(sewn.exit_code, 0) << sewn.output;
    ASSERT_EQ(verdict_of(sewn.output).closed, "yes") << sewn.output;
    const SimulationState before = read_state(dir / "sewn.h5");
    ASSERT_TRUE(before.patch.has_value());
    // The patch's middle as sewn, and the way it faces the tissue (the laying pose's tool +z).
    Eigen::Vector3d middle = Eigen::Vector3d::Zero();
    for (const auto& x : before.patch->positions) middle += vec(x);
    middle /= double(before.patch->positions.size());
    Eigen::Vector3d facing = Eigen::Vector3d::UnitZ();
    for (const InstrumentKeyframe& k : plan.keyframes)
        if (k.kind == InstrumentKind::patch) facing = k.pose.orientation * Eigen::Vector3d::UnitZ();
    double nearest = 1e9;  // the patch vertex nearest its middle: where the probe presses
    Eigen::Vector3d pressed = middle;
    for (const auto& x : before.patch->positions)
        if ((vec(x) - middle).norm() < nearest) nearest = (vec(x) - middle).norm(), pressed = vec(x);
    const double radius = 2.0, half = 0.25;
    const Eigen::Vector3d away = pressed - facing * (radius + half + 6.0), in = pressed - facing * (radius + half - 1.0);
    fs::copy_file(b.closure, dir / "press.csv");
    {
        std::ofstream out(dir / "press.csv", std::ios::app);
        auto row = [&](double t, const Eigen::Vector3d& p) {
            char line[256];
            std::snprintf(line, sizeof line, "%.3f, 0, probe, %.6f, %.6f, %.6f, 1, 0, 0, 0, %g, %g, %g, 0\n", t, p.x(), p.y(), p.z(), radius, radius, radius);
            out << line;
        };
        row(end + 20, away);
        row(end + 320, in);
        row(end + 620, in);
    }
    std::snprintf(length, sizeof length, "%.3f", 1e-3 * (end + 620));
    const auto pressing = heartsim_command("run " + quoted(b.scenario) + " --headless --trajectory " + quoted(dir / "press.csv") + " --seconds " +
                                           length + " --leak-test 0 --save-state " + quoted(dir / "pressed.h5"));
    ASSERT_EQ(pressing.exit_code, 0) << pressing.output;
    const SimulationState after = read_state(dir / "pressed.h5");
    ASSERT_TRUE(after.patch.has_value());
    EXPECT_EQ(after.kind[0], 1) << "hand 0 holds the probe";
    const Eigen::Vector3d force(after.force_n[0][0], after.force_n[0][1], after.force_n[0][2]);
    double closest = 1e9;
    for (const auto& x : after.patch->positions) closest = std::min(closest, (vec(x) - in).norm());
    const double moved = (after.patch->positions.empty() ? 0.0 : largest_difference(after.patch->positions, before.patch->positions));
    std::printf("  the probe 1 mm into the patch's middle: pushed back with %.4g N (%.2f of it against the way it came); nearest patch vertex %.3f mm "
                "from its centre; the patch moved up to %.2f mm\n",
                force.norm(), force.norm() > 0 ? -force.dot(facing) / force.norm() : 0.0, closest, moved);
    EXPECT_GE(closest, radius + half - 1e-6) << "no patch vertex inside the probe";
    EXPECT_GT(-force.dot(facing), 0.0) << "the patch pushes the probe back out of it";
    EXPECT_GT(-force.dot(facing), 0.9 * force.norm()) << "mostly straight back";
    EXPECT_GT(moved, 0.5) << "the patch gave way under the probe";
    EXPECT_EQ(verdict_of(pressing.output).closed, "yes") << pressing.output;
}

// plan-repair's closure with only 3 stitches is open: the run says so, says where the leak passes
// the rim (at the rim's radius from the defect's axis, where the stitches bite) and between which
// two of the three, and the saved state keeps that point (/patch attribute leak_mm) as printed.
// The 8-stitch repair, closed as it lies (--leak-test 0), keeps none.
TEST(Repair, AnOpenRepairSaysWhereItLeaksAndTheStateKeepsIt) {
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    const auto planned = heartsim_command("plan-repair " + quoted(b.scenario) + " -o " + quoted(dir / "three.csv") + " --stitches=3");
    ASSERT_EQ(planned.exit_code, 0) << planned.output;
    char length[32];
    std::snprintf(length, sizeof length, "%.3f", 1e-3 * end_of(read_trajectory(dir / "three.csv")));
    const auto run = heartsim_command("run " + quoted(b.scenario) + " --headless --trajectory " + quoted(dir / "three.csv") + " --seconds " +
                                      length + " --save-state " + quoted(dir / "open.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    ASSERT_EQ(verdict_of(run.output).closed, "no") << run.output;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(run.output, m,
                                  std::regex(R"(the leak: its way out of the opening passes the rim widest at \(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)\) mm, between stitches ([0-9]+) and ([0-9]+))")))
        << run.output;
    const Eigen::Vector3d printed(std::stod(m[1]), std::stod(m[2]), std::stod(m[3]));
    const int first = std::stoi(m[4]), second = std::stoi(m[5]);
    EXPECT_TRUE(first >= 1 && first < second && second <= 3) << first << ", " << second;
    const SimulationState state = read_state(dir / "open.h5");
    ASSERT_TRUE(state.patch.has_value() && state.patch->has_defect);
    const PatchState& patch = *state.patch;
    ASSERT_TRUE(patch.leak_mm.has_value()) << "the state keeps where it leaks";
    const Eigen::Vector3d leak((*patch.leak_mm)[0], (*patch.leak_mm)[1], (*patch.leak_mm)[2]);
    EXPECT_LE((leak - printed).cwiseAbs().maxCoeff(), 0.05 + 1e-9) << "printed to 0.1 mm";
    const Eigen::Vector3d centre(patch.defect_centre[0], patch.defect_centre[1], patch.defect_centre[2]);
    const Eigen::Vector3d axis(patch.defect_axis[0], patch.defect_axis[1], patch.defect_axis[2]);
    const Eigen::Vector3d d = leak - centre;
    const double rho = (d - d.dot(axis) * axis).norm(), rim = 0.5 * patch.defect_diameter_mm + patch.rim_offset_mm;
    std::printf("  3 stitches: open (largest rim gap %.2f mm); the leak passes the rim %.3f mm from the axis (the rim %.3f), %.2f mm along it, "
                "between stitches %d and %d\n",
                patch.largest_rim_gap_mm, rho, rim, d.dot(axis), first, second);
    EXPECT_NEAR(rho, rim, 1e-6 * std::max(1.0, rim));
    // The stitches named are those either side of it round the axis, from the state's anchors.
    const Eigen::Vector3d x_axis = (d - d.dot(axis) * axis).normalized(), y_axis = axis.cross(x_axis);
    double back = 1e9, ahead = 1e9;
    int clockwise = -1, counter = -1;
    for (std::size_t s = 0; s < patch.stitch_anchor.size(); ++s) {
        const Eigen::Vector3d a = vec(patch.stitch_anchor[s]) - centre;
        const double turn = std::atan2(a.dot(y_axis), a.dot(x_axis));  // from the leak, counter-clockwise seen from the patch's side
        const double b = turn <= 0 ? -turn : 2.0 * std::numbers::pi - turn, f = turn > 0 ? turn : 2.0 * std::numbers::pi + turn;
        if (b < back) back = b, clockwise = int(s) + 1;
        if (f < ahead) ahead = f, counter = int(s) + 1;
    }
    EXPECT_EQ(std::min(clockwise, counter), first);
    EXPECT_EQ(std::max(clockwise, counter), second);
    // A repair the check calls closed keeps no leak.
    const auto sewn = heartsim_command("run " + quoted(b.scenario) + " --headless --trajectory " + quoted(b.closure) + " --seconds " +
                                       [&] {
                                           char s[32];
                                           std::snprintf(s, sizeof s, "%.3f", 1e-3 * end_of(read_trajectory(b.closure)));
                                           return std::string(s);
                                       }() +
                                       " --leak-test 0 --save-state " + quoted(dir / "sewn.h5"));
    ASSERT_EQ(sewn.exit_code, 0) << sewn.output;
    ASSERT_EQ(verdict_of(sewn.output).closed, "yes") << sewn.output;
    EXPECT_EQ(sewn.output.find("the leak:"), std::string::npos);
    const SimulationState closed = read_state(dir / "sewn.h5");
    ASSERT_TRUE(closed.patch.has_value());
    EXPECT_FALSE(closed.patch->leak_mm.has_value());
}

// A patch laid away from the opening: the plan's patch moved along the defect's axis, out past the
// block's outer wall (local |x| 19 to 22 mm, the septum at x = 0), and let go with no stitch. The
// outer wall caps the check's cylinder, so the fill finds no way out of the opening; the patch does
// not cover it, so the run says no and why, the saved state keeps /patch closed = 0, and
// check-closure.py says no on that state by its own geometry.
TEST(Repair, APatchLaidAwayFromTheOpeningDoesNotCloseIt) {
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    const Scenario scenario = read_scenario(b.scenario);
    const Eigen::Vector3d centre = scenario.source.defect_centre, axis = scenario.source.defect_axis.normalized();
    Trajectory away;
    for (InstrumentKeyframe k : read_trajectory(b.plan).keyframes) {
        if (k.hand != 0 || k.kind != InstrumentKind::patch) continue;
        const double along = (k.pose.position - centre).dot(axis);
        k.pose.position += (along < 0 ? -30.0 - along : 30.0 - along) * axis;  // 30 mm from mid-wall, on the patch's side
        away.keyframes.push_back(k);
    }
    ASSERT_FALSE(away.keyframes.empty());
    {
        std::ofstream out(dir / "away.csv");
        out << "time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab\n";
        for (const InstrumentKeyframe& k : away.keyframes) {
            const auto& p = k.pose.position;
            const auto& q = k.pose.orientation;
            char line[512];
            std::snprintf(line, sizeof line, "%.17g,0,patch,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", k.time_ms, p.x(),
                          p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), k.semi_axes.x(), k.semi_axes.y(), k.semi_axes.z(), k.grab ? 1 : 0);
            out << line;
        }
    }
    char length[32];
    std::snprintf(length, sizeof length, "%.3f", 1e-3 * (end_of(away) + 100.0));
    const auto run = heartsim_command("run " + quoted(b.scenario) + " --headless --backend cpu --trajectory " + quoted(dir / "away.csv") +
                                      " --seconds " + length + " --save-state " + quoted(dir / "away.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    ASSERT_NE(run.output.find("patch laid at"), std::string::npos) << run.output;
    EXPECT_EQ(verdict_of(run.output).closed, "no") << run.output;
    EXPECT_NE(run.output.find("the patch does not cover the opening"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("the fill found no way out"), std::string::npos) << "the fill alone would have called it closed:\n" << run.output;
    const SimulationState state = read_state(dir / "away.h5");
    ASSERT_TRUE(state.patch.has_value() && state.patch->has_defect);
    EXPECT_FALSE(state.patch->closed);
    const auto script = test::run_command("python3 " + quoted(fs::path(HEARTSIM_SOURCE_DIR) / "scripts" / "check-closure.py") + " " +
                                          quoted(dir / "away.h5") + " --scenario " + quoted(b.scenario));
    EXPECT_EQ(script.exit_code, 1) << script.output;
    EXPECT_NE(script.output.find("defect closed: no (the patch does not cover the opening"), std::string::npos) << script.output;
}

// The gl backend steps a sewn patch in a compute pass (runtime/gl/patch_pass.h) from the same
// flattened patch the host steps (PatchModel::pass_input). With the tissue held where it was imaged,
// plan-repair's patch on the block, its eight stitches tied at once, steps 200 times on each: the
// pass's positions, stitch pulls and contact force match the host's step to rounding, as the two
// run the same arithmetic in double and keep the same things between steps.
TEST(Repair, TheGlPatchPassStepsThePatchAsTheHostDoes) {
    REQUIRE_GL();
    const BlockRepair& b = block_repair();
    const Scenario scenario = read_scenario(b.scenario);
    const SolverOptions options = options_from(scenario.solver);
    auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options);
    ASSERT_NE(gl->surgery(), nullptr);
    SurgerySupport& surgery = *gl->surgery();
    EXPECT_EQ(surgery.repair(), nullptr);  // the bare backend holds no repair
    PatchStepper* pass = surgery.patch_stepper();
    ASSERT_NE(pass, nullptr);
    const Trajectory plan = read_trajectory(b.closure);
    std::optional<InstrumentKeyframe> laid;
    std::vector<Eigen::Vector3d> ties;
    std::array<bool, 2> held{false, false};
    for (const InstrumentKeyframe& k : plan.keyframes) {
        const bool press = k.grab && !held[std::size_t(k.hand)];
        held[std::size_t(k.hand)] = k.grab;
        if (press && k.kind == InstrumentKind::patch && !laid) laid = k;
        if (press && k.kind == InstrumentKind::needle) ties.push_back(k.pose.position);
    }
    ASSERT_TRUE(laid.has_value());
    ASSERT_EQ(ties.size(), 8u);
    PatchSpec spec;
    spec.radius_x_mm = laid->semi_axes.x();
    spec.radius_y_mm = laid->semi_axes.y();
    spec.thickness_mm = 2.0 * laid->semi_axes.z();
    spec.gravity = options.gravity;
    const Particles& particles = scenario.lattice.particles;
    std::vector<double> inverse_mass(particles.size(), 0.0);
    for (std::size_t i = 0; i < particles.size(); ++i)
        inverse_mass[i] = particles.anchored[i] || !(particles.mass[i] > 0) ? 0.0 : 1.0 / double(particles.mass[i]);
    const Eigen::Vector3d facing = laid->pose.orientation.normalized() * Eigen::Vector3d::UnitZ();
    PatchModel host(spec, particles.rest_position,
                    patch_surface_near(scenario, laid->pose.position, facing, std::max(spec.radius_x_mm, spec.radius_y_mm) + 3.0, 8.0),
                    inverse_mass);
    const ParticlePositions positions = surgery.positions_of(host.particles());
    host.lay(laid->pose, positions);
    for (const Eigen::Vector3d& tip : ties) ASSERT_TRUE(host.tie(tip, 0.0, positions).has_value());
    pass->load(host.pass_input(positions, 3.0));
    const double dt = 3 * gl->time_step_ms();
    double worst = 0.0, worst_force = 0.0, largest_force = 0.0;
    for (int step = 0; step < 200; ++step) {
        host.step(positions, dt, step * dt);
        pass->step({.dt_ms = dt, .time_ms = step * dt, .mass_scale = 1.0, .obstacles = {}, .hand_output = {-1, -1}});
        if (step % 50 != 49) continue;
        const PatchPassState state = pass->state(nullptr);
        ASSERT_EQ(state.x.size(), host.positions().size());
        for (std::size_t i = 0; i < state.x.size(); ++i) worst = std::max(worst, (state.x[i] - host.positions()[i]).norm());
        for (std::size_t s = 0; s < state.stitch_force.size(); ++s) {
            worst_force = std::max(worst_force, (state.stitch_force[s] - host.stitches()[s].force_n).norm());
            largest_force = std::max(largest_force, host.stitches()[s].force_n.norm());
        }
        worst_force = std::max(worst_force, (state.contact_force - host.contact_force()).norm());
        largest_force = std::max(largest_force, host.contact_force().norm());
    }
    std::printf("  after 200 steps of %.3g ms: max |x_pass - x_host| %.3g mm; forces within %.3g N of the host's (largest %.3g N)\n", dt,
                worst, worst_force, largest_force);
    EXPECT_LT(worst, 1e-9);
    EXPECT_GT(largest_force, 0.0);
    EXPECT_LT(worst_force, 1e-9 * std::max(1.0, largest_force));
}

// A patch lies on the detailed mesh. On a scenario built without one, a run whose script or
// device lays a patch is refused before its first step, saying which hand, when, and what the
// scenario lacks, not stopped mid-run in the solver's words ("begin_grab on a hand that holds no
// grabber").
TEST(Repair, APatchOnAScenarioWithoutADetailedMeshIsRefusedBeforeTheFirstStep) {
    const BlockRepair& b = block_repair();
    test::TempDir dir;
    Scenario bare = read_scenario(b.scenario);
    bare.visual.reset();
    bare.mapping.reset();
    write_scenario(dir / "bare.h5", bare);
    const auto scripted = heartsim_command("run " + quoted(dir / "bare.h5") + " --headless --backend cpu --trajectory " + quoted(b.plan) +
                                           " --seconds 0.2 --save-state " + quoted(dir / "state.h5"));
    EXPECT_EQ(scripted.exit_code, 1) << scripted.output;
    EXPECT_NE(scripted.output.find("the --trajectory's patch of hand 0 at 0 ms lays a patch or ties a stitch, and the scenario has no "
                                   "detailed mesh (/visual with /mapping)"),
              std::string::npos)
        << scripted.output;
    EXPECT_EQ(scripted.output.find("begin_grab"), std::string::npos) << scripted.output;
    EXPECT_FALSE(fs::exists(dir / "state.h5"));
    const auto device = heartsim_command("run " + quoted(dir / "bare.h5") + " --headless --backend cpu --device scripted:" +
                                         quoted(b.script[0]) + " --instrument patch --seconds 0.2");
    EXPECT_EQ(device.exit_code, 1) << device.output;
    EXPECT_NE(device.output.find("--instrument patch for hand 0 lays a patch"), std::string::npos) << device.output;
    // The same scenario still runs what needs no patch: the run itself is not refused.
    const auto probe = heartsim_command("run " + quoted(dir / "bare.h5") + " --headless --backend cpu --steps 2");
    EXPECT_EQ(probe.exit_code, 0) << probe.output;
}

namespace {

/// What the needle's hand felt in one scripted pass and stitch (NeedlePassAndStitch).
struct NeedleFelt {
    double peak_n = 0.0;             ///< the largest force on the way in, N
    double peak_depth_mm = 0.0;      ///< the tip's depth in the wall there
    double after_n = 0.0;            ///< the force at the next step's measure, N
    double after_depth_mm = 0.0;     ///< the tip's depth there
    double through_n = 0.0;          ///< the force at the bite, the tip through the surface, N
    double bite_depth_mm = 0.0;      ///< the tip's depth there
    double largest_out_of_shaft = 0.0;  ///< the largest part of a felt force across the shaft, N
    double tension_n = 0.0;          ///< the force as the stitch has drawn tight, N
    double tension_along_shaft = 0.0;   ///< its component along the shaft (negative: toward the wall)
    double largest_n = 0.0;          ///< the largest force felt anywhere in the pass, N
    bool finite = true;
    std::size_t stitches = 0;
};

/// On the VSD phantom, the repair's backend around `inner`: hand 0 lays plan-repair's patch; hand 1's
/// needle (its shaft outward, as the plan holds it) comes from 4 mm outside stitch 1's site to
/// `bite_mm` past it into the wall at 0.05 mm/ms, posed every step, the force it feels read after
/// every step; there its button ties the stitch and is held for the tie and 30 ms more, then let
/// go, and the needle is drawn back out the way it came.
NeedleFelt needle_pass_and_stitch(std::unique_ptr<Backend> inner, const Scenario& scenario, const RepairPlan& plan, double bite_mm) {
    RepairBackend repair(std::move(inner), scenario, RepairSettings{});
    const double dt = repair.time_step_ms();
    NeedleFelt felt;
    const double radius = 0.5 * plan.patch_diameter_mm;
    repair.set_instrument(0, Instrument{InstrumentKind::patch, Eigen::Vector3d(radius, radius, 0.5 * plan.patch_thickness_mm)});
    repair.set_pose(0, InstrumentPose{plan.patch_centre, plan.patch_orientation});
    repair.step(1);
    repair.begin_grab(0);
    repair.step(1);
    repair.release(0);
    repair.set_instrument(1, Instrument{InstrumentKind::needle, Eigen::Vector3d(0.25, 0.25, 6.0)});
    const Eigen::Vector3d site = plan.stitches.front().site, out = plan.needle_orientation * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d start = site + 4.0 * out, end = site - bite_mm * out;
    const int steps_in = int(std::ceil((4.0 + bite_mm) / 0.05 / dt));
    auto feel = [&](bool carried) {
        const Eigen::Vector3d f = repair.instrument_forces().hand[1].force_n;
        felt.finite = felt.finite && f.allFinite();
        felt.largest_n = std::max(felt.largest_n, f.norm());
        if (carried) felt.largest_out_of_shaft = std::max(felt.largest_out_of_shaft, (f - f.dot(out) * out).norm());
        return f;
    };
    bool after_peak = false;
    for (int k = 0; k <= steps_in; ++k) {
        const double s = double(k) / steps_in;
        repair.set_pose(1, InstrumentPose{start + s * (end - start), plan.needle_orientation});
        repair.step(1);
        const Eigen::Vector3d f = feel(true);
        const double depth = repair.needle_depth_mm(1);
        if (f.norm() > felt.peak_n) felt.peak_n = f.norm(), felt.peak_depth_mm = depth, after_peak = true;
        else if (after_peak && depth > felt.peak_depth_mm) felt.after_n = f.norm(), felt.after_depth_mm = depth, after_peak = false;
        felt.through_n = f.norm(), felt.bite_depth_mm = repair.needle_depth_mm(1);
    }
    repair.begin_grab(1);
    const int hold = int(std::ceil((RepairSettings{}.tie_ms + 30.0) / dt));
    Eigen::Vector3d tension = Eigen::Vector3d::Zero();
    for (int k = 0; k < hold; ++k) {
        repair.step(1);
        tension = feel(false);
    }
    felt.tension_n = tension.norm();
    felt.tension_along_shaft = tension.dot(out);
    if (const PatchModel* patch = repair.patch()) felt.stitches = patch->stitches().size();
    repair.release(1);
    for (int k = steps_in; k >= 0; --k) {
        const double s = double(k) / steps_in;
        repair.set_pose(1, InstrumentPose{start + s * (end - start), plan.needle_orientation});
        repair.step(1);
        feel(true);
    }
    return felt;
}

}  // namespace

// What the needle's hand feels on the VSD phantom, on the cpu and gl backends (llvmpipe where there
// is no GPU): a needle driven into the wall at plan-repair's first stitch site, 2.5 mm past it,
// ties the stitch there and is drawn out again. On the way in the hand feels the wall push back
// along the shaft, at most within the measured peak forces of suture needles puncturing tissue
// (Maloney et al. 2025, Ann. Plast. Surg. 95(4):423: 0.61 to 0.90 N on average), then, once the
// tip is through the surface, less than half of it, and no more than it as the needle goes on; with the stitch drawn tight, the suture's tension along the shaft
// toward the wall within what surgeons were measured to pull with when tying (Laufer et al. 2016,
// Stud. Health Technol. Inform. 220:199–204: 1.6 N superficial, 3.79 N deep knots). Every force
// is finite and none exceeds the tension.
TEST(Repair, TheNeedlesHandFeelsThePunctureAndTheSutureWithinMeasuredRanges) {
    const Scenario scenario = read_scenario(test::built_vsd_phantom());
    const RepairPlan plan = plan_repair(scenario);
    ASSERT_FALSE(plan.stitches.empty());
    const double bite = 2.5;
    ASSERT_GT(plan.stitches.front().wall_mm, bite + 1.0) << "the wall at stitch 1 must be thicker than the bite";
    const SolverOptions options = options_from(scenario.solver);
    std::map<std::string, NeedleFelt> felt;
    felt["cpu"] = needle_pass_and_stitch(make_cpu_backend(scenario, options), scenario, plan, bite);
    if (test::shared_gl_context()) felt["gl"] = needle_pass_and_stitch(make_gl_backend(*test::shared_gl_context(), scenario, options), scenario, plan, bite);
    for (const auto& [backend, f] : felt) {
        std::printf("  %s: puncture %.3f N at %.2f mm deep; %.3f N just through, %.2f mm deep; %.3f N at the bite, %.2f mm deep; "
                    "suture %.3f N (along the shaft %.3f N); largest %.3f N, %.2g N across the shaft; %zu stitch\n",
                    backend.c_str(), f.peak_n, f.peak_depth_mm, f.after_n, f.after_depth_mm, f.through_n, f.bite_depth_mm, f.tension_n,
                    f.tension_along_shaft, f.largest_n, f.largest_out_of_shaft, f.stitches);
        EXPECT_TRUE(f.finite) << backend;
        EXPECT_EQ(f.stitches, 1u) << backend;
        EXPECT_GE(f.peak_n, 0.61) << backend << ": the puncture should be felt as suture needles were measured to puncture tissue";
        EXPECT_LE(f.peak_n, 0.90) << backend;
        EXPECT_GT(f.bite_depth_mm, f.peak_depth_mm) << backend << ": the needle should go on past the puncture";
        EXPECT_GT(f.after_depth_mm, f.peak_depth_mm) << backend;
        EXPECT_LT(f.after_n, 0.5 * f.peak_n) << backend << ": the force should drop once the tip is through the surface";
        EXPECT_LE(f.through_n, f.peak_n) << backend;
        EXPECT_LE(f.largest_out_of_shaft, 1e-9) << backend << ": the wall pushes along the shaft";
        EXPECT_GE(f.tension_n, 1.6) << backend << ": the suture's tension should be what surgeons pull with";
        EXPECT_LE(f.tension_n, 3.79) << backend;
        EXPECT_NEAR(f.tension_along_shaft, -f.tension_n, 1e-9) << backend << ": the suture pulls the hand toward the wall";
        EXPECT_LE(f.largest_n, f.tension_n + 1e-12) << backend;
    }
}
