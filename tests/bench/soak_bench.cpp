// The watchdog soak (docs/benchmarks.md "Soak"): a scenario as heartprep built it, stepped with
// the shipped solver options for many steps of a hostile two-handed gesture: a 3 mm grabber
// grabs beside an anchor or a strong support, pulls 20 mm in a random direction over 200 ms and
// lets go (the gesture that used to freeze the simulation for good), while a probe presses
// where the grab was. At the end both hands leave and the tissue settles. It reports the steps
// that advanced against those asked, the watchdog's events and whether it gave up, slipped
// particles, the largest instrument force, finite positions, and how far the settled tissue is
// from its rest state.
//   soak_bench SCENARIO.h5 [--steps N] [--seed S]
#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/solver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <random>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

/// Free particles beside an anchor (a spring to one), or, where nothing is anchored, the 2 % with
/// the stiffest support springs: where a pull is held hardest.
std::vector<std::size_t> held_hardest(const Scenario& scenario) {
    const Particles& p = scenario.lattice.particles;
    const auto& neighbours = scenario.packing->neighbours;
    std::vector<std::size_t> sites;
    for (std::size_t i = 0; i < p.size(); ++i) {
        if (p.anchored[i]) continue;
        for (std::int32_t j : neighbours[i])
            if (j >= 0 && p.anchored[std::size_t(j)]) {
                sites.push_back(i);
                break;
            }
    }
    if (!sites.empty() || !p.supported()) return sites;
    std::vector<std::size_t> order(p.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    const std::size_t keep = std::max<std::size_t>(1, order.size() / 50);
    std::partial_sort(order.begin(), order.begin() + std::ptrdiff_t(keep), order.end(),
                      [&](std::size_t a, std::size_t b) { return p.support_stiffness[a] > p.support_stiffness[b]; });
    order.resize(keep);
    return order;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2 || std::string(argv[1]) == "--help") {
        std::fprintf(stderr, "usage: soak_bench SCENARIO.h5 [--steps N] [--seed S]\n");
        return argc < 2 ? 2 : 0;
    }
    long long steps = 100000;
    unsigned seed = 1;
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--steps" && a + 1 < argc) steps = std::stoll(argv[++a]);
        else if (arg == "--seed" && a + 1 < argc) seed = unsigned(std::stoul(argv[++a]));
        else {
            std::fprintf(stderr, "soak_bench: unknown argument %s\n", arg.c_str());
            return 2;
        }
    }
    try {
        const Scenario scenario = read_scenario(argv[1]);
        if (!scenario.packing) throw InputError(std::string(argv[1]) + ": no /packing");
        Solver solver(scenario.lattice, scenario.packing->neighbours, options_from(scenario.solver));
        const auto& rest = scenario.lattice.particles.rest_position;
        const std::vector<std::size_t> sites = held_hardest(scenario);
        if (sites.empty()) throw InputError(std::string(argv[1]) + ": nothing anchored or supported to grab beside");
        const double dt = solver.time_step_ms();
        const long long pull_steps = std::max(1LL, (long long)std::lround(200.0 / dt)), rest_steps = std::max(1LL, (long long)std::lround(100.0 / dt));
        const long long cycle = pull_steps + rest_steps;
        std::printf("soak: %s, %zu particles, dt %.4g ms (%d substeps), %zu grab sites (%s), %lld steps: %lld cycles of a 20 mm pull over "
                    "200 ms and 100 ms let go\n",
                    argv[1], solver.size(), dt, solver.substeps_per_step(), sites.size(),
                    std::any_of(scenario.lattice.particles.anchored.begin(), scenario.lattice.particles.anchored.end(), [](auto a) { return a != 0; })
                        ? "beside anchors"
                        : "stiffest supports",
                    steps, (steps + cycle - 1) / cycle);

        solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(2, 2, 5)});
        solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(3.0)});
        std::mt19937 random(seed);
        std::uniform_int_distribution<std::size_t> pick(0, sites.size() - 1);
        std::normal_distribution<double> gauss(0, 1);
        Eigen::Vector3d site = Eigen::Vector3d::Zero(), direction = Eigen::Vector3d::UnitX();
        long long advanced = 0, gave_up = 0, grabs = 0, held_total = 0;
        double largest_force = 0;
        std::string last_message;
        const auto t0 = std::chrono::steady_clock::now();
        for (long long s = 0; s < steps; ++s) {
            const long long phase = s % cycle;
            if (phase == 0) {
                const std::size_t i = sites[pick(random)];
                site = Eigen::Vector3d(rest[i][0], rest[i][1], rest[i][2]);
                direction = Eigen::Vector3d(gauss(random), gauss(random), gauss(random)).normalized();
                solver.set_pose(1, {site, Eigen::Quaterniond::Identity()});
                solver.set_pose(0, {site + 6.0 * direction.unitOrthogonal(), Eigen::Quaterniond::Identity()});
            } else if (phase == 1) {
                held_total += long(solver.begin_grab(1));
                ++grabs;
            } else if (phase < pull_steps) {
                const double f = double(phase) / double(pull_steps);
                solver.set_pose(1, {site + 20.0 * f * direction, Eigen::Quaterniond::Identity()});
                solver.set_pose(0, {site + (6.0 - 4.0 * f) * direction.unitOrthogonal(), Eigen::Quaterniond::Identity()});
            } else if (phase == pull_steps) {
                solver.release(1);
                solver.set_pose(0, {site + 30.0 * direction.unitOrthogonal(), Eigen::Quaterniond::Identity()});
            }
            const StepReport report = solver.step();
            advanced += report.steps;
            if (report.diverged) last_message = report.message;
            if (report.gave_up) ++gave_up;
            const InstrumentForces forces = solver.instrument_forces();
            largest_force = std::max({largest_force, forces.hand[0].force_n.norm(), forces.hand[1].force_n.norm()});
        }
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        // Both hands leave; the tissue settles for a second of simulated time.
        solver.set_instrument(0, {.kind = InstrumentKind::none});
        solver.set_instrument(1, {.kind = InstrumentKind::none});
        solver.step(int(std::lround(1000.0 / dt)));
        bool finite = true;
        double settled = 0;
        for (std::size_t i = 0; i < solver.size(); ++i) {
            const Eigen::Vector3d x = solver.position(i);
            finite = finite && x.allFinite();
            settled = std::max(settled, (x - Eigen::Vector3d(rest[i][0], rest[i][1], rest[i][2])).norm());
        }
        std::printf("soak: %lld of %lld steps advanced in %.1f s (%.0f steps/s); watchdog events %zu, gave up %lld times; %lld grabs held "
                    "%.1f particles on average, %zu slipped; largest instrument force %.3g N; positions %s; 1 s after the hands left, the "
                    "largest distance from rest %.3g mm\n",
                    advanced, steps, seconds, double(steps) / seconds, solver.watchdog_events(), gave_up, grabs,
                    grabs ? double(held_total) / double(grabs) : 0.0, solver.slipped_particles(), largest_force,
                    finite ? "finite" : "NOT FINITE", settled);
        if (!last_message.empty()) std::printf("soak: last watchdog message: %s\n", last_message.c_str());
        return finite && gave_up == 0 ? 0 : 1;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "soak_bench: %s\n", e.what());
        return 2;
    }
}
