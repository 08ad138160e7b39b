// Run time against error with the mass scale S as the knob (docs/benchmarks.md "Mass scaling: run
// time against error"), driven by tests/bench/run_mass_scale_bench.sh:
//   mass_scale_bench SCENARIO TRAJECTORY.csv SECONDS RAMP_MS CASE OUT.csv [--scales 1,2,4,8,16]
// runs the scripted gesture on the cpu backend at each S for SECONDS simulated, reading both
// instruments' forces after every step, and appends one row per S to OUT.csv (with a header when
// it is new): the step and its substeps, the real-time factor (simulated over wall time of the
// stepping, force readback included as a run includes it), watchdog events, and the tool force's
// deviation from the S = 1 run at the same simulated time (linear interpolation of the S = 1
// series), as a fraction of the largest S = 1 force of that hand: the largest during the gesture
// and its first RAMP_MS, and the mean over the last second (settled). Hands that hold nothing are
// left out. Not a test: it asserts nothing.
#include "formats/scenario.h"
#include "runtime/backend/backend.h"
#include "runtime/core/trajectory.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

struct Series {
    std::vector<double> time_ms;
    std::vector<std::array<Eigen::Vector3d, 2>> force;
    double wall_ms = 0.0, dt_ms = 0.0;
    int substeps = 0;
    std::size_t watchdog_events = 0;
};

Series run(const Scenario& scenario, const Trajectory& trajectory, double seconds, double scale) {
    SolverOptions options = options_from(scenario.solver);
    options.mass_scale = scale;
    const auto backend = make_cpu_backend(scenario, options);
    Series s;
    s.dt_ms = backend->time_step_ms();
    s.substeps = backend->substeps_per_step();
    const int steps = int(std::ceil(seconds * 1000.0 / s.dt_ms - 1e-9));
    s.time_ms.reserve(std::size_t(steps));
    s.force.reserve(std::size_t(steps));
    ScriptedRunOptions o{.steps = steps, .forces_every_step = true};
    o.on_step = [&](int, const StepReport&) {
        const auto forces = backend->latest_forces();  // the cpu backend computed them with the request
        s.time_ms.push_back(backend->simulated_time_ms());
        s.force.push_back({forces ? forces->hand[0].force_n : Eigen::Vector3d::Zero(), forces ? forces->hand[1].force_n : Eigen::Vector3d::Zero()});
    };
    const ScriptedRunResult r = run_scripted(*backend, trajectory, o);
    s.wall_ms = r.wall_ms;
    s.watchdog_events = r.watchdog_events;
    return s;
}

Eigen::Vector3d at(const Series& s, int hand, double t) {
    const auto it = std::lower_bound(s.time_ms.begin(), s.time_ms.end(), t);
    if (it == s.time_ms.begin()) return s.force.front()[hand];
    if (it == s.time_ms.end()) return s.force.back()[hand];
    const std::size_t k = std::size_t(it - s.time_ms.begin());
    const double a = (t - s.time_ms[k - 1]) / (s.time_ms[k] - s.time_ms[k - 1]);
    return (1 - a) * s.force[k - 1][hand] + a * s.force[k][hand];
}

}  // namespace

int main(int argc, char** argv) try {
    if (argc < 7)
        throw std::runtime_error("usage: mass_scale_bench SCENARIO TRAJECTORY.csv SECONDS RAMP_MS CASE OUT.csv [--scales 1,2,4,8,16]");
    const Scenario scenario = read_scenario(argv[1]);
    const Trajectory trajectory = read_trajectory(argv[2]);
    const double seconds = std::stod(argv[3]), ramp_ms = std::stod(argv[4]);
    const std::string name = argv[5], out_path = argv[6];
    std::vector<double> scales{1, 2, 4, 8, 16};
    for (int i = 7; i + 1 < argc; ++i)
        if (std::string(argv[i]) == "--scales") {
            scales.clear();
            std::stringstream in(argv[i + 1]);
            for (std::string v; std::getline(in, v, ',');) scales.push_back(std::stod(v));
        }
    if (scales.empty() || scales.front() != 1.0) throw std::runtime_error("--scales must start with 1 (the reference)");
    const bool fresh = !std::filesystem::exists(out_path);
    std::ofstream out(out_path, std::ios::app);
    if (fresh)
        out << "case,particles,mass_scale,dt_ms,substeps,substeps_per_simulated_ms,real_time_factor,watchdog_events,"
               "ramp_error,settled_error,settled_force_n\n";
    Series reference;
    for (double scale : scales) {
        const Series s = run(scenario, trajectory, seconds, scale);
        if (scale == 1.0) reference = s;
        double ramp_error = 0.0, settled_error = 0.0, settled_force = 0.0;
        for (int hand = 0; hand < 2; ++hand) {
            double largest = 0.0;
            for (const auto& f : reference.force) largest = std::max(largest, f[hand].norm());
            if (largest < 1e-6) continue;  // this hand held or touched nothing
            double ramp = 0.0, settled = 0.0;
            std::size_t settled_samples = 0;
            for (std::size_t k = 0; k < s.time_ms.size(); ++k) {
                const double t = s.time_ms[k];
                const double d = (s.force[k][hand] - at(reference, hand, t)).norm() / largest;
                if (t <= ramp_ms) ramp = std::max(ramp, d);
                if (t >= seconds * 1000.0 - 1000.0) settled += d, ++settled_samples;
            }
            ramp_error = std::max(ramp_error, ramp);
            settled_error = std::max(settled_error, settled_samples ? settled / double(settled_samples) : 0.0);
            settled_force = std::max(settled_force, s.force.back()[hand].norm());
        }
        const double simulated = s.time_ms.empty() ? 0.0 : s.time_ms.back();
        char row[512];
        std::snprintf(row, sizeof row, "%s,%zu,%g,%.6g,%d,%.6g,%.4g,%zu,%.4g,%.4g,%.5g\n", name.c_str(), scenario.lattice.particles.size(), scale,
                      s.dt_ms, s.substeps, double(s.substeps) / s.dt_ms, simulated / s.wall_ms, s.watchdog_events, ramp_error, settled_error,
                      settled_force);
        out << row;
        out.flush();
        std::printf("%s", row);
        std::fflush(stdout);
    }
    return 0;
} catch (const std::exception& e) {
    std::fprintf(stderr, "mass_scale_bench: %s\n", e.what());
    return 1;
}
