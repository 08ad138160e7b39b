#include "runtime/app/info_verdict.h"

#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/core/real_time.h"

#include "formats/scenario.h"
#include "libmodel/lattice.h"
#include "libmodel/packing.h"

#include <chrono>
#include <string>
#include <cstdio>

namespace heartsim {

namespace {

/// A cube of myocardium, 31 particles a side (29,791), laid out and packed as heartprep does.
Scenario block_of_myocardium() {
    Scenario scenario;
    scenario.lattice = uniform_block({31, 31, 31}, 1.5);
    scenario.packing = pack_particles(scenario.lattice);
    scenario.solver.gravity = Eigen::Vector3d::Zero();
    scenario.solver.balanced_gravity = Eigen::Vector3d::Zero();
    return scenario;
}

}  // namespace

std::string session_verdict(GlContext& context, const std::string& scenario_path, double seconds) {
    const GlInfo info = context.info();
    const bool software = is_software_rasteriser(info);
    Scenario scenario;
    if (scenario_path.empty()) {
        scenario = block_of_myocardium();
    } else {
        scenario = read_scenario(scenario_path);
        require_runnable(scenario, scenario_path);
    }
    const SolverOptions options = options_from(scenario.solver);
    std::unique_ptr<Backend> backend = software ? make_cpu_backend(scenario, options) : make_gl_backend(context, scenario, options);
    backend->step(1);  // warm up: first dispatches, page faults
    const auto start = std::chrono::steady_clock::now();
    const double simulated_start = backend->simulated_time_ms();
    double wall = 0.0;
    long long steps = 0;
    do {
        backend->step(1);
        ++steps;
        if (!software && steps % 16 == 0) backend->positions();  // a gl step is queued: wait for it now and then
        wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    } while (wall < seconds);
    if (!software) {
        backend->positions();
        wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    const double simulated_ms = backend->simulated_time_ms() - simulated_start;
    const double factor = simulated_ms / (1000.0 * wall);
    char text[1024];
    std::snprintf(text, sizeof text,
                  "verdict:\n"
                  "  %s\n"
                  "  measured here: %zu particles (%s) step at a real-time factor of %.2f on the %s backend (substep %.3f ms, %.2f ms "
                  "of wall time each)%s\n"
                  "  speed: %s\n",
                  software ? "the OpenGL device is a software rasteriser: a run without --backend (a window, a haptic session, "
                             "headless) simulates on the cpu backend and draws with OpenGL (--backend gl forces the GPU path: slower here)"
                           : "the OpenGL device is hardware: sessions simulate on the gl backend (the GPU)",
                  backend->size(), scenario_path.empty() ? "a block of myocardium 1.5 mm apart" : scenario_path.c_str(), factor,
                  to_string(backend->kind()), backend->substep_ms(), 1000.0 * wall / double(steps * backend->substeps_per_step()),
                  scenario_path.empty() ? "; a real heart of as many particles has a shorter substep (its supports and dashpots), so a "
                                          "lower factor: `heartsim info CASE.h5` measures it"
                                        : "",
                  speed_verdict(*backend, factor, backend->options().mass_scale).c_str());
    return text;
}

}  // namespace heartsim
