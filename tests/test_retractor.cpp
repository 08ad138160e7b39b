// The retractor (libmodel/sim/solver.h InstrumentKind::retractor): a grabber whose tissue stays
// where it is left. On the phantom, a retractor closes on the front wall, pulls it 4 mm out and
// lets go: what it held stays where it was, to the bit, while a grabber's tissue springs back
// under the same gesture; the gl backend does as the cpu; a probe pushed into the stayed tissue
// moves none of it and a grab there takes none of it, until reset_tissue() (or the watchdog's
// restore) frees it; a hand that takes a needle through the repair's backend leaves it too; the
// same gesture through `heartsim run --trajectory` keeps it; a haptic session with a retractor
// replays bit for bit. In a whole operation on a septal defect (a cut, retractors spreading its
// edges, the hands then taking the patch and the needle elsewhere) the retracted edges stay, on
// both backends.
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/recording.h"
#include "formats/scenario.h"
#include "formats/state.h"
#include "runtime/backend/backend.h"
#include "runtime/backend/surgery.h"
#include "runtime/core/trajectory.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/gl/gl_context.h"
#include "runtime/surgery/repair.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;

namespace {

/// The shipped phantom, base anchored, heartprep's supports and balanced gravity (it stays put at
/// rest), 6,000 particles.
const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border --particles 6000 -q"); }

test::CommandResult run_heartsim(const std::string& arguments) { return test::run_command(std::string(quoted(HEARTSIM_EXE)) + " " + arguments); }

/// The gesture's steps: hand 1 closes at step 0 on the front wall, pulls 4 mm anterior (−y) by
/// `pulled`, holds until `release` and lets go there (grab 0 from that step on).
constexpr int pulled = 100, release_step = 120, after = 200;

/// The most anterior free particle of the phantom's middle third (in z): the front wall, away from
/// the anchored base.
std::size_t front_particle(const Scenario& scenario) {
    const auto& rest = scenario.lattice.particles.rest_position;
    float low = 1e30f, high = -1e30f;
    for (const auto& r : rest) low = std::min(low, r[2]), high = std::max(high, r[2]);
    std::size_t front = rest.size();
    for (std::size_t i = 0; i < rest.size(); ++i) {
        if (scenario.lattice.particles.anchored[i]) continue;
        if (rest[i][2] < low + (high - low) / 3 || rest[i][2] > high - (high - low) / 3) continue;
        if (front == rest.size() || rest[i][1] < rest[front][1]) front = i;
    }
    return front;
}

/// The gesture as trajectory CSV text: `kind` on hand 1, a sphere of 1.5 lattice spacings centred
/// on the front particle; at the release the hand takes `then` (empty: the same kind).
std::string gesture_csv(const Scenario& scenario, const std::string& kind, const std::string& then = "") {
    const auto& r = scenario.lattice.particles.rest_position[front_particle(scenario)];
    const double dt = scenario.solver.dt_ms, a = 1.5 * scenario.lattice.spacing;
    std::ostringstream csv;
    csv.precision(17);
    csv << "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n";
    auto row = [&](double time, double pull, int grab, const std::string& held = "") {
        csv << time << ",1," << (held.empty() ? kind : held) << "," << r[0] << "," << r[1] - pull << "," << r[2] << ",1,0,0,0," << a << "," << a << "," << a << ","
            << grab << "\n";
    };
    row(0, 0, 1);
    row(pulled * dt, 4.0, 1);
    row(release_step * dt, 4.0, 0, then);
    return csv.str();
}

struct Gesture {
    std::vector<std::int32_t> held;                 ///< what hand 1 held just before it let go
    std::vector<std::array<float, 3>> at_release;   ///< positions as it let go
    std::vector<std::array<float, 3>> end;          ///< positions `after` steps later
};

/// Drives `backend` along `trajectory` step by step (ScriptedHands, as run_scripted), keeping
/// what hand 1 held and the positions as it let go.
Gesture run_gesture(Backend& backend, const Trajectory& trajectory) {
    Gesture g;
    ScriptedHands hands(trajectory);
    const double dt = backend.time_step_ms();
    for (int step = 0; step < release_step + after; ++step) {
        if (step == release_step) {
            backend.instrument_forces();  // the gl backend lists what a hand holds in its force pass
            g.held = backend.contact_particles(1);
        }
        hands.apply(backend, 1, step * dt, (step + 1) * dt);
        if (step == release_step) g.at_release = backend.positions();
        const StepReport report = backend.step(1);
        EXPECT_FALSE(report.diverged) << report.message;
    }
    g.end = backend.positions();
    return g;
}

double largest_move(const Gesture& g, const std::vector<std::int32_t>& particles) {
    double worst = 0;
    for (std::int32_t i : particles)
        for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(g.end[std::size_t(i)][c] - g.at_release[std::size_t(i)][c])));
    return worst;
}

const fs::path& vsd_phantom() { return test::built_vsd_phantom(); }

/// `heartsim plan-operation`'s operation on the VSD phantom, its retraction by retractors (a
/// grabber's rows read as retractor's): the scalpel cuts, the retractors take the edges and spread
/// them, then the hands take the patch and the needle, placed away from where the retractors hold.
struct Operation {
    fs::path csv;
    double hold_ms = 0;    ///< the retractors' last keyframe: still holding
    double switch_ms = 0;  ///< hand 0 takes the patch
};

Operation plan_operation(const fs::path& dir) {
    Operation op{.csv = dir / "op.csv"};
    const auto plan = run_heartsim("plan-operation " + quoted(vsd_phantom()) + " -o " + quoted(dir / "plan.csv"));
    if (plan.exit_code != 0) throw std::runtime_error(plan.output);
    Trajectory trajectory = read_trajectory(dir / "plan.csv");
    for (InstrumentKeyframe& k : trajectory.keyframes) {
        if (k.kind == InstrumentKind::grabber) k.kind = InstrumentKind::retractor;
        if (k.hand != 0) continue;
        if (k.kind == InstrumentKind::retractor && op.switch_ms == 0) op.hold_ms = k.time_ms;
        if (k.kind == InstrumentKind::patch && op.switch_ms == 0) op.switch_ms = k.time_ms;
    }
    write_trajectory_csv(trajectory, op.csv);
    return op;
}

/// Steps `backend` along the operation as run_scripted does, until `end_ms`: what each hand holds
/// 10 ms before the retractors' last keyframe, the positions 10 ms after the switch and at the end.
struct OperationRun {
    std::array<std::vector<std::int32_t>, 2> held;
    std::vector<std::array<float, 3>> after_switch, end;
};

OperationRun run_operation(Backend& backend, const Operation& op, double end_ms) {
    const Trajectory trajectory = read_trajectory(op.csv);
    ScriptedHands hands(trajectory);
    OperationRun r;
    const double dt = backend.time_step_ms();
    bool held = false, switched = false;
    for (long long step = 0; double(step) * dt < end_ms; ++step) {
        const double t = double(step) * dt;
        if (!held && t >= op.hold_ms - 10.0) {
            backend.instrument_forces();  // the gl backend lists what a hand holds in its force pass
            for (int hand = 0; hand < 2; ++hand) r.held[std::size_t(hand)] = backend.contact_particles(hand);
            held = true;
        }
        if (!switched && t >= op.switch_ms + 10.0) {
            r.after_switch = backend.positions();
            switched = true;
        }
        for (int hand = 0; hand < 2; ++hand) hands.apply(backend, hand, t, t + dt);
        const StepReport report = backend.step(1);
        EXPECT_FALSE(report.diverged) << report.message;
        backend.request_forces();
        backend.latest_forces();
    }
    r.end = backend.positions();
    return r;
}

double largest_move(const std::vector<std::array<float, 3>>& from, const std::vector<std::array<float, 3>>& to,
                    const std::vector<std::int32_t>& particles) {
    double worst = 0;
    for (std::int32_t i : particles)
        for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(to[std::size_t(i)][c] - from[std::size_t(i)][c])));
    return worst;
}

double distance_from_rest(const std::array<float, 3>& x, const std::array<float, 3>& rest) {
    return std::sqrt(std::pow(double(x[0]) - rest[0], 2) + std::pow(double(x[1]) - rest[1], 2) + std::pow(double(x[2]) - rest[2], 2));
}

/// The scenario on the cpu backend and, where a GL context opens here, the gl backend.
std::vector<std::unique_ptr<Backend>> cpu_and_gl(const Scenario& scenario) {
    const SolverOptions options = options_from(scenario.solver);
    std::vector<std::unique_ptr<Backend>> backends;
    backends.push_back(make_cpu_backend(scenario, options));
    if (test::shared_gl_context()) backends.push_back(make_gl_backend(*test::shared_gl_context(), scenario, options));
    return backends;
}

}  // namespace

// A retractor's tissue stays where it was let go, to within 1e-6 mm (to the bit: it is anchored at
// rest), 200 steps on; under the same gesture a grabber's springs back by more than a millimetre.
// Both were pulled 4 mm out before letting go.
TEST(Retractor, ItsTissueStaysWhereItIsLeftWhereAGrabbersSpringsBack) {
    const Scenario scenario = read_scenario(phantom());
    const auto& rest = scenario.lattice.particles.rest_position;
    for (const char* kind : {"retractor", "grabber"}) {
        SCOPED_TRACE(kind);
        const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, kind), std::string(kind) + ".csv");
        auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
        const Gesture g = run_gesture(*cpu, trajectory);
        ASSERT_GT(g.held.size(), 3u) << "the instrument should hold a piece of the front wall";
        double pulled_out = 0;
        for (std::int32_t i : g.held) pulled_out = std::max(pulled_out, distance_from_rest(g.at_release[std::size_t(i)], rest[std::size_t(i)]));
        EXPECT_NEAR(pulled_out, 4.0, 0.2) << "mm: the held tissue followed the 4 mm pull";
        const double moved = largest_move(g, g.held);
        std::printf("  %s: %zu particles held, pulled out %.3f mm, moved %.3g mm in the %d steps after letting go\n", kind, g.held.size(),
                    pulled_out, moved, after);
        if (std::string(kind) == "retractor") EXPECT_LE(moved, 1e-6);
        else EXPECT_GT(moved, 1.0) << "a grabber's tissue springs back";
    }
}

// The gl backend anchors the same particles in place (a readback of the held list and a write of
// their constants and motion): both backends end where each other does, to the cpu-vs-gl
// tolerance of test_runtime_backend (1e-4 of the model's size), and the stayed tissue does not
// move on the gl backend either, nor on either after the mass scale changes.
TEST(Retractor, GlKeepsTheRetractedTissueInPlaceAsTheCpuDoes) {
    REQUIRE_GL();
    const Scenario scenario = read_scenario(phantom());
    const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, "retractor"), "retractor.csv");
    const SolverOptions options = options_from(scenario.solver);
    auto cpu = make_cpu_backend(scenario, options);
    auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options);
    const Gesture c = run_gesture(*cpu, trajectory), g = run_gesture(*gl, trajectory);
    ASSERT_GT(c.held.size(), 3u);
    EXPECT_EQ(c.held, g.held);
    EXPECT_LE(largest_move(g, g.held), 1e-6) << "mm: the gl backend's retracted tissue moved";
    Eigen::AlignedBox3d box;
    for (const auto& r : scenario.lattice.particles.rest_position) box.extend(Eigen::Vector3d(r[0], r[1], r[2]));
    double error = 0;
    for (std::size_t i = 0; i < c.end.size(); ++i)
        for (int k = 0; k < 3; ++k) error = std::max(error, double(std::abs(c.end[i][k] - g.end[i][k])));
    std::printf("  %zu particles stayed; max |x_gl - x_cpu| %.3g mm (%.3g of the size)\n", c.held.size(), error, error / box.diagonal().norm());
    EXPECT_LE(error, 1e-4 * box.diagonal().norm());
    // A change of mass scale (--real-time auto's) rebuilds the step's constants: the stayed
    // particles stay anchored on both.
    for (Backend* backend : {cpu.get(), gl.get()}) {
        backend->set_mass_scale(4.0);
        for (int s = 0; s < 50; ++s) backend->step(1);
        const auto x = backend->positions();
        double moved = 0;
        for (std::int32_t i : c.held)
            for (int k = 0; k < 3; ++k) moved = std::max(moved, double(std::abs(x[std::size_t(i)][k] - c.end[std::size_t(i)][k])));
        EXPECT_LE(moved, 1e-6) << to_string(backend->kind()) << ": mm, after the mass scale changed";
    }
}

// Through the repair's backend (runtime/surgery/repair.h), the retractor's hand switching to a
// needle while it holds: the repair hands the tissue's solver no instrument in that hand, which
// ends the retractor's grab there, and its tissue stays as when it lets go.
TEST(Retractor, AHandThatTakesANeedleWhileRetractingLeavesTheTissueInPlace) {
    const Scenario scenario = read_scenario(phantom());
    const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, "retractor", "needle"), "retract-then-needle.csv");
    RepairBackend repair(make_cpu_backend(scenario, options_from(scenario.solver)), scenario, RepairSettings{});
    const Gesture g = run_gesture(repair, trajectory);
    ASSERT_GT(g.held.size(), 3u);
    EXPECT_EQ(repair.contact_particles(1), std::vector<std::int32_t>{}) << "the needle's hand holds no tissue";
    const double moved = largest_move(g, g.held);
    std::printf("  %zu particles stayed; moved %.3g mm in the %d steps after the switch\n", g.held.size(), moved, after);
    EXPECT_LE(moved, 1e-6);
}

// Stayed tissue is anchored: a probe pushed 2 mm into it moves none of it, and a grabber closing on
// it takes none of it. reset_tissue() brings back the scenario's anchoring: the same grab takes
// the particles again and a 2 mm pull carries them. On both backends.
TEST(Retractor, ResetTissueFreesWhatARetractorLeftInPlace) {
    const Scenario scenario = read_scenario(phantom());
    const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, "retractor"), "retractor.csv");
    const auto& r = scenario.lattice.particles.rest_position[front_particle(scenario)];
    const Eigen::Vector3d front(r[0], r[1], r[2]);
    const double a = 1.5 * scenario.lattice.spacing;
    const std::vector<std::unique_ptr<Backend>> backends = cpu_and_gl(scenario);
    for (const auto& backend : backends) {
        SCOPED_TRACE(to_string(backend->kind()));
        const Gesture g = run_gesture(*backend, trajectory);
        ASSERT_GT(g.held.size(), 3u);
        const Eigen::Vector3d out = front - Eigen::Vector3d(0, 4.0, 0);  // where the retractor left its centre
        // A probe from in front, its surface pushed 2 mm past the retractor's centre.
        backend->set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(a)});
        backend->set_pose(0, {out - Eigen::Vector3d(0, 2 * a, 0), Eigen::Quaterniond::Identity()});
        backend->step(1);
        for (int s = 1; s <= int(std::lround(10 * (a + 2))); ++s) {
            backend->set_pose(0, {out - Eigen::Vector3d(0, 2 * a - 0.1 * s, 0), Eigen::Quaterniond::Identity()});
            backend->step(1);
        }
        const auto pressed = backend->positions();
        const Eigen::Vector3d probe_at = out - Eigen::Vector3d(0, 2 * a - 0.1 * std::lround(10 * (a + 2)), 0);
        double moved = 0;
        std::size_t inside_probe = 0;  // a free particle would have been projected out of it
        for (std::int32_t i : g.held) {
            const auto& x = pressed[std::size_t(i)];
            for (int c = 0; c < 3; ++c) moved = std::max(moved, double(std::abs(x[c] - g.end[std::size_t(i)][c])));
            inside_probe += (Eigen::Vector3d(x[0], x[1], x[2]) - probe_at).norm() < a;
        }
        EXPECT_GT(inside_probe, 0u) << "the probe should reach into the stayed tissue";
        EXPECT_EQ(moved, 0.0) << "mm: a probe moved anchored tissue";
        backend->set_instrument(0, {.kind = InstrumentKind::none});
        // A grab over the stayed tissue finds nothing movable.
        backend->set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(a)});
        backend->set_pose(1, {out, Eigen::Quaterniond::Identity()});
        const std::size_t before_reset = backend->begin_grab(1);
        backend->release(1);
        // The reset: at rest where it was imaged, and free again.
        backend->reset_tissue();
        backend->set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(a)});
        backend->set_pose(1, {front, Eigen::Quaterniond::Identity()});  // placed at once: the retractor's first pose
        const std::size_t after_reset = backend->begin_grab(1);
        for (int s = 1; s <= 20; ++s) {
            backend->set_pose(1, {front - Eigen::Vector3d(0, 0.1 * s, 0), Eigen::Quaterniond::Identity()});
            backend->step(1);
        }
        const auto x = backend->positions();
        double least = 1e30;
        for (std::int32_t i : g.held) least = std::min(least, distance_from_rest(x[std::size_t(i)], scenario.lattice.particles.rest_position[std::size_t(i)]));
        std::printf("  %s: a probe reached %zu stayed particles and moved none; a grab over the stayed tissue took %zu particles, after "
                    "the reset %zu (the retractor held %zu); pulled 2 mm, each moved at least %.3f mm\n",
                    to_string(backend->kind()), inside_probe, before_reset, after_reset, g.held.size(), least);
        EXPECT_EQ(before_reset, 0u);
        EXPECT_EQ(after_reset, g.held.size());
        EXPECT_GT(least, 1.5) << "mm: after the reset the grab carries the particles the retractor had left";
    }
}

// The watchdog's restore brings back the scenario's anchoring too: after the retractor let go, a
// 10 N load on the back wall trips the watchdog (the state restored at rest, grabs released); with
// the load gone the tissue the retractor had left springs back like a grabber's. On both backends.
TEST(Retractor, TheWatchdogsRestoreFreesWhatARetractorLeftInPlace) {
    const Scenario scenario = read_scenario(phantom());
    const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, "retractor"), "retractor.csv");
    const auto& rest = scenario.lattice.particles.rest_position;
    std::int32_t back = 0;
    for (std::size_t i = 0; i < rest.size(); ++i)
        if (!scenario.lattice.particles.anchored[i] && rest[i][1] > rest[std::size_t(back)][1]) back = std::int32_t(i);
    const std::vector<std::unique_ptr<Backend>> backends = cpu_and_gl(scenario);
    for (const auto& backend : backends) {
        SCOPED_TRACE(to_string(backend->kind()));
        const Gesture g = run_gesture(*backend, trajectory);
        ASSERT_GT(g.held.size(), 3u);
        backend->surgery()->set_loads({{.particle = back, .force_n = Eigen::Vector3d(0, 10.0, 0)}});
        bool diverged = false;
        for (int s = 0; s < 50 && !diverged; ++s) diverged = backend->step(1).diverged;
        ASSERT_TRUE(diverged) << "the load should trip the watchdog";
        backend->surgery()->set_loads({});
        const auto restored = backend->positions();
        for (int s = 0; s < after; ++s) backend->step(1);
        const auto x = backend->positions();
        double moved = 0;
        for (std::int32_t i : g.held)
            for (int c = 0; c < 3; ++c) moved = std::max(moved, double(std::abs(x[std::size_t(i)][c] - restored[std::size_t(i)][c])));
        std::printf("  %s: after the restore the %zu particles the retractor had left moved %.3f mm\n", to_string(backend->kind()),
                    g.held.size(), moved);
        EXPECT_GT(moved, 1.0) << "mm: the restore should have freed them";
    }
}

// Through heartsim run --trajectory (cpu): the CSV's `retractor` kind is read, the saved state names
// it (code 6), and the tissue stays where it was let go: the state 1 step after the release and
// the one 200 steps later hold the retracted particles at the same place; with `grabber` they
// move.
TEST(Retractor, HeartsimRunKeepsTheRetractedTissueFromATrajectoryCsv) {
    const Scenario scenario = read_scenario(phantom());
    test::TempDir dir;
    const Trajectory trajectory = parse_trajectory(gesture_csv(scenario, "retractor"), "retractor.csv");
    auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
    const std::vector<std::int32_t> held = run_gesture(*cpu, trajectory).held;
    ASSERT_GT(held.size(), 3u);
    for (const char* kind : {"retractor", "grabber"}) {
        SCOPED_TRACE(kind);
        const fs::path csv = dir / (std::string(kind) + ".csv");
        std::ofstream(csv) << gesture_csv(scenario, kind);
        std::vector<SimulationState> states;
        for (int steps : {release_step + 1, release_step + after}) {
            const fs::path state = dir / (std::string(kind) + std::to_string(steps) + ".h5");
            const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --trajectory " + quoted(csv) + " --steps " +
                                          std::to_string(steps) + " --save-state " + quoted(state));
            ASSERT_EQ(run.exit_code, 0) << run.output;
            states.push_back(read_state(state));
        }
        EXPECT_EQ(states[0].kind[1], std::string(kind) == "retractor" ? 6 : 2);
        double moved = 0;
        for (std::int32_t i : held)
            for (int c = 0; c < 3; ++c)
                moved = std::max(moved, double(std::abs(states[1].positions[std::size_t(i)][c] - states[0].positions[std::size_t(i)][c])));
        std::printf("  %s: the held particles moved %.3g mm between the states\n", kind, moved);
        if (std::string(kind) == "retractor") EXPECT_LE(moved, 1e-6);
        else EXPECT_GT(moved, 1.0);
    }
}

// A haptic session (cpu) with a retractor on a scripted device: button 1 closes it on the front
// wall, it pulls 4 mm out and lets go; a probe on the second device then presses beside it. The
// recording names the retractor (code 6 each step) and replays bit for bit, and the replay's
// saved state ends where the session's did, to the bit.
TEST(Retractor, AHapticSessionWithARetractorReplaysBitForBit) {
    const Scenario scenario = read_scenario(phantom());
    test::TempDir dir;
    const auto& r = scenario.lattice.particles.rest_position[front_particle(scenario)];
    const double a = 1.5 * scenario.lattice.spacing;
    {
        std::ofstream out(dir / "retract.csv");
        out.precision(17);
        out << "# time_ms, x, y, z, qw, qx, qy, qz, buttons\n";
        out << 0 << "," << r[0] << "," << r[1] << "," << r[2] << ",1,0,0,0,0\n";
        out << 50 << "," << r[0] << "," << r[1] << "," << r[2] << ",1,0,0,0,1\n";
        out << 250 << "," << r[0] << "," << r[1] - 4.0 << "," << r[2] << ",1,0,0,0,1\n";
        out << 300 << "," << r[0] << "," << r[1] - 4.0 << "," << r[2] << ",1,0,0,0,0\n";
        std::ofstream probe(dir / "press.csv");
        probe.precision(17);
        probe << "# time_ms, x, y, z, qw, qx, qy, qz, buttons\n";
        probe << 0 << "," << r[0] + 4 * a << "," << r[1] - 2 * a << "," << r[2] << ",1,0,0,0,0\n";
        probe << 500 << "," << r[0] + 4 * a << "," << r[1] - 2 * a + 4.0 << "," << r[2] << ",1,0,0,0,0\n";
    }
    char instruments[128];
    std::snprintf(instruments, sizeof instruments, " --instrument retractor:%.6g,%.6g,%.6g --instrument probe:%.6g,%.6g,%.6g", a, a, a, a, a, a);
    const auto live = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device scripted:" + quoted(dir / "retract.csv") +
                                   " --device scripted:" + quoted(dir / "press.csv") + instruments + " --seconds 0.6 --record " +
                                   quoted(dir / "rec.h5") + " --save-state " + quoted(dir / "live.h5"));
    ASSERT_EQ(live.exit_code, 0) << live.output;
    const Recording recorded = read_recording(dir / "rec.h5");
    EXPECT_EQ(recorded.hands[0].instrument, "retractor");
    ASSERT_FALSE(recorded.steps.instrument.empty());
    bool grabbed = false, let_go = false;
    for (std::size_t k = 0; k < recorded.steps.size(); ++k) {
        EXPECT_EQ(recorded.steps.instrument[k][0], 6) << "step " << k;
        grabbed = grabbed || recorded.steps.grab[k][0];
        let_go = let_go || (grabbed && !recorded.steps.grab[k][0]);
    }
    EXPECT_TRUE(grabbed && let_go) << "the session should grab and let go";
    const auto replay = run_heartsim("run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "rec.h5") + " --save-state " +
                                     quoted(dir / "replayed.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
    const SimulationState a_state = read_state(dir / "live.h5"), b_state = read_state(dir / "replayed.h5");
    EXPECT_EQ(a_state.kind[0], 6);
    EXPECT_EQ(b_state.kind[0], 6);
    ASSERT_EQ(a_state.positions.size(), b_state.positions.size());
    EXPECT_TRUE(a_state.positions == b_state.positions) << "the replay should end where the session ended, to the bit";
    // The retracted tissue is out where the retractor left it (about 4 mm in front of rest).
    const std::size_t front = front_particle(scenario);
    std::printf("  %zu steps; the front particle ends %.3f mm from rest\n", recorded.steps.size(),
                distance_from_rest(b_state.positions[front], scenario.lattice.particles.rest_position[front]));
    EXPECT_GT(distance_from_rest(b_state.positions[front], scenario.lattice.particles.rest_position[front]), 3.0);
}

// The operation through `heartsim run --trajectory` (cpu, the repair's backend around it, the
// detailed mesh opened along the cut): the retractors hold pieces of both edges until their hands
// take the patch and the needle, placed elsewhere; the particles they held then do not move at
// all, to the bit, between the state 10 ms after the switch and the one 150 ms after it. What
// each held is taken from the same steps in this process, and the run's state before the switch
// holds as many in each hand.
TEST(Retractor, AnOperationsRetractedEdgesStayWhenTheHandsTakeThePatchAndTheNeedle) {
    test::TempDir dir;
    const Operation op = plan_operation(dir.path());
    ASSERT_GT(op.switch_ms, op.hold_ms);
    ASSERT_GT(op.hold_ms, 0);
    const Scenario scenario = read_scenario(vsd_phantom());
    RepairBackend repair(make_cpu_backend(scenario, options_from(scenario.solver)), scenario, RepairSettings{});
    const OperationRun in_process = run_operation(repair, op, op.hold_ms);
    std::vector<std::int32_t> held;
    for (int hand = 0; hand < 2; ++hand) {
        EXPECT_GT(in_process.held[std::size_t(hand)].size(), 3u) << "retractor " << hand << " should hold a piece of its edge";
        held.insert(held.end(), in_process.held[std::size_t(hand)].begin(), in_process.held[std::size_t(hand)].end());
    }
    std::vector<SimulationState> states;
    for (double ms : {op.hold_ms - 10.0, op.switch_ms + 10.0, op.switch_ms + 150.0}) {
        const fs::path state = dir / ("at" + std::to_string(int(ms)) + ".h5");
        char seconds[32];
        std::snprintf(seconds, sizeof seconds, "%.6f", ms / 1000.0);
        const auto run = run_heartsim("run " + quoted(vsd_phantom()) + " --headless --backend cpu --trajectory " + quoted(op.csv) + " --seconds " +
                                      seconds + " --save-state " + quoted(state));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        states.push_back(read_state(state));
    }
    for (int hand = 0; hand < 2; ++hand) {
        EXPECT_EQ(states[0].kind[std::size_t(hand)], 6);
        EXPECT_EQ(std::size_t(states[0].particles[std::size_t(hand)]), in_process.held[std::size_t(hand)].size()) << "hand " << hand;
    }
    EXPECT_EQ(states[1].kind[0], 4) << "hand 0 holds the patch";
    EXPECT_EQ(states[1].kind[1], 5) << "hand 1 holds the needle";
    const double moved = largest_move(states[1].positions, states[2].positions, held);
    std::printf("  the retractors held %zu + %zu particles; they moved %.3g mm from 10 to 150 ms after the switch\n",
                in_process.held[0].size(), in_process.held[1].size(), moved);
    EXPECT_EQ(moved, 0.0) << "mm: the retracted edges should stay where the retractors left them";
}

// The same operation on the gl backend (in this process, the repair's backend around it): the
// retractors hold what the cpu's do and the particles they held do not move after the switch.
TEST(Retractor, GlKeepsAnOperationsRetractedEdgesAsTheCpuDoes) {
    REQUIRE_GL();
    test::TempDir dir;
    const Operation op = plan_operation(dir.path());
    const Scenario scenario = read_scenario(vsd_phantom());
    const SolverOptions options = options_from(scenario.solver);
    RepairBackend cpu(make_cpu_backend(scenario, options), scenario, RepairSettings{});
    RepairBackend gl(make_gl_backend(*test::shared_gl_context(), scenario, options), scenario, RepairSettings{});
    const OperationRun c = run_operation(cpu, op, op.hold_ms), g = run_operation(gl, op, op.switch_ms + 150.0);
    std::vector<std::int32_t> held;
    for (int hand = 0; hand < 2; ++hand) {
        EXPECT_GT(c.held[std::size_t(hand)].size(), 3u);
        EXPECT_EQ(c.held[std::size_t(hand)], g.held[std::size_t(hand)]) << "hand " << hand;
        held.insert(held.end(), g.held[std::size_t(hand)].begin(), g.held[std::size_t(hand)].end());
    }
    ASSERT_FALSE(g.after_switch.empty());
    const double moved = largest_move(g.after_switch, g.end, held);
    std::printf("  gl: %zu particles held; they moved %.3g mm from 10 to 150 ms after the switch\n", held.size(), moved);
    EXPECT_EQ(moved, 0.0) << "mm: the gl backend's retracted edges moved";
}
