// The watchdog soak (docs/benchmarks.md "Soak"): a scenario as heartprep built it, stepped with
// the shipped solver options for many steps of the gesture that used to freeze the simulation
// for good: a 3 mm grabber grabs beside an anchor or a strong support, pulls 20 mm in a random
// direction over 200 ms, lets go and waits 100 ms, then travels (at 2 mm/ms, holding nothing)
// to the next site. At the end the hand leaves and the tissue settles. It reports the steps that
// advanced against those asked, the watchdog's events and how often it gave up (heartsim would
// stop there with exit 6), slipped particles, the largest instrument force, finite positions,
// and how far the settled tissue is from its rest state.
//   soak_bench SCENARIO.h5 [--steps N] [--seed S] [--settle SECONDS] [--slip STRAIN] [--restore-strain STRAIN] [--events]
#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/sim/solver.h"
#include "tests/soak_gesture.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <random>
#include <string>
#include <vector>

using namespace heartsim;

int main(int argc, char** argv) {
    if (argc < 2 || std::string(argv[1]) == "--help") {
        std::fprintf(stderr, "usage: soak_bench SCENARIO.h5 [--steps N] [--seed S] [--settle SECONDS] [--slip STRAIN] [--restore-strain STRAIN] [--events]\n");
        return argc < 2 ? 2 : 0;
    }
    long long steps = 100000;
    unsigned seed = 1;
    double settle_s = 1.0, slip = -1.0, restore_strain = -1.0;
    bool events = false;
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--steps" && a + 1 < argc) steps = std::stoll(argv[++a]);
        else if (arg == "--seed" && a + 1 < argc) seed = unsigned(std::stoul(argv[++a]));
        else if (arg == "--settle" && a + 1 < argc) settle_s = std::stod(argv[++a]);
        else if (arg == "--slip" && a + 1 < argc) slip = std::stod(argv[++a]);
        else if (arg == "--restore-strain" && a + 1 < argc) restore_strain = std::stod(argv[++a]);
        else if (arg == "--events") events = true;
        else {
            std::fprintf(stderr, "soak_bench: unknown argument %s\n", arg.c_str());
            return 2;
        }
    }
    try {
        const Scenario scenario = read_scenario(argv[1]);
        if (!scenario.packing) throw InputError(std::string(argv[1]) + ": no /packing");
        SolverOptions options = options_from(scenario.solver);
        if (slip >= 0) options.grab_slip_strain = slip;
        if (restore_strain >= 0) options.restore_strain_limit = restore_strain;
        Solver solver(scenario.lattice, scenario.packing->neighbours, options);
        const auto& rest = scenario.lattice.particles.rest_position;
        const std::vector<std::size_t> sites = test::held_hardest(scenario);
        if (sites.empty()) throw InputError(std::string(argv[1]) + ": nothing anchored or supported to grab beside");
        std::printf("soak: %s, %zu particles, dt %.4g ms (%d substeps), %zu grab sites (%s), %lld steps of 20 mm pulls over 200 ms, "
                    "100 ms let go, travel at 2 mm/ms\n",
                    argv[1], solver.size(), solver.time_step_ms(), solver.substeps_per_step(), sites.size(),
                    std::any_of(scenario.lattice.particles.anchored.begin(), scenario.lattice.particles.anchored.end(), [](auto a) { return a != 0; })
                        ? "beside anchors"
                        : "stiffest supports",
                    steps);

        test::SoakGesture gesture(solver, scenario, sites, seed);
        long long advanced = 0, gave_up = 0;
        double largest_force = 0;
        std::string last_message;
        const auto t0 = std::chrono::steady_clock::now();
        for (long long s = 0; s < steps; ++s) {
            gesture.before_step(solver);
            const StepReport report = solver.step();
            advanced += report.steps;
            if (report.diverged) last_message = report.message;
            if (report.diverged && events)
                std::printf("soak: event at step %lld, %s step %lld; %zu slipped so far: %s\n", s,
                            gesture.phase() == test::SoakGesture::Phase::travel ? "travel"
                            : gesture.phase() == test::SoakGesture::Phase::pull ? "pull"
                                                                                 : "let-go",
                            gesture.phase_step(), solver.slipped_particles(),
                            report.message.c_str());
            if (report.gave_up) ++gave_up;
            const InstrumentForces forces = solver.instrument_forces();
            largest_force = std::max(largest_force, forces.hand[1].force_n.norm());
        }
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        // The hand leaves; the tissue settles.
        solver.set_instrument(1, {.kind = InstrumentKind::none});
        solver.step(int(std::lround(settle_s * 1000.0 / solver.time_step_ms())));
        bool finite = true;
        double settled = 0;
        std::size_t displaced = 0;  // particles left more than 1 mm from rest: a lattice folded on itself
        for (std::size_t i = 0; i < solver.size(); ++i) {
            const Eigen::Vector3d x = solver.position(i);
            finite = finite && x.allFinite();
            const double d = (x - Eigen::Vector3d(rest[i][0], rest[i][1], rest[i][2])).norm();
            settled = std::max(settled, d);
            displaced += d > 1.0;
        }
        std::printf("soak: %lld of %lld steps advanced in %.1f s (%.0f steps/s); watchdog events %zu, gave up %lld times; %lld grabs held "
                    "%.1f particles on average, %zu slipped; largest grabber force %.3g N; positions %s; %.3g s after the hand left, the "
                    "largest distance from rest %.3g mm, %zu particles more than 1 mm from it\n",
                    advanced, steps, seconds, double(steps) / seconds, solver.watchdog_events(), gave_up, gesture.grabs(),
                    gesture.grabs() ? double(gesture.held_total()) / double(gesture.grabs()) : 0.0, solver.slipped_particles(), largest_force,
                    finite ? "finite" : "NOT FINITE", settle_s, settled, displaced);
        if (!last_message.empty()) std::printf("soak: last watchdog message: %s\n", last_message.c_str());
        return finite && gave_up == 0 ? 0 : 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "soak_bench: %s\n", e.what());
        return 2;
    }
}
