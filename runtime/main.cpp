// heartsim: the simulation runtime. `heartsim info` (the GL device), `heartsim run SCENARIO.h5`.
// docs/runtime.md.
#include "backend.h"
#include "gl_context.h"
#include "trajectory.h"

#include "formats/scenario.h"
#include "formats/state.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <optional>

using namespace heartsim;

namespace {

struct RunArguments {
    std::string scenario;
    bool headless = false;
    std::string backend = "gl";
    int steps = 0;
    double seconds = 0.0;
    std::string probe, grab, trajectory, save_state;
    bool stats = false;
};

int command_info() {
    GlContext context = GlContext::create_headless();
    std::cout << describe(context.info());
    return 0;
}

int command_run(const RunArguments& a) {
    if (!a.headless)
        throw InputError("the window mode is not built yet (rendering, picking and visualisation are still to come); run with --headless");
    const BackendKind kind = parse_backend_kind(a.backend);
    if (a.steps > 0 && a.seconds > 0) throw InputError("give --steps or --seconds, not both");

    Scenario scenario = read_scenario(a.scenario);
    require_runnable(scenario, a.scenario);
    const SolverOptions options = options_from(scenario.solver);

    std::optional<GlContext> context;
    std::unique_ptr<Backend> backend;
    if (kind == BackendKind::gl) {
        context.emplace(GlContext::create_headless());
        const GlInfo info = context->info();
        const std::size_t need = estimate_gl_memory_bytes(scenario);
        std::printf("gl: %s, OpenGL %d.%d; device memory needed %.1f MiB\n", info.renderer.c_str(), info.major, info.minor,
                    double(need) / (1024.0 * 1024.0));
        if (info.max_ssbo_bytes > 0 && (long long)(scenario.lattice.particles.size() * 18 * 4 + 4096) > info.max_ssbo_bytes)
            throw InputError("the neighbour table needs more than the largest shader storage block this device offers (" +
                             std::to_string(info.max_ssbo_bytes) + " bytes); run with --backend cpu");
        backend = make_gl_backend(*context, scenario, options);
    } else {
        backend = make_cpu_backend(scenario, options);
    }
    const SolverLoadReport& load = backend->load_report();
    int steps = a.steps;
    if (a.seconds > 0) steps = int(std::ceil(a.seconds * 1000.0 / backend->time_step_ms() - 1e-9));
    if (steps <= 0) steps = 1;
    std::printf("%s backend: %zu particles, %zu springs, %zu anchored; step %.4g ms = %d substeps of %.4g ms (critical %.4g ms)\n",
                to_string(kind), load.particles, load.springs, load.anchored, backend->time_step_ms(), backend->substeps_per_step(),
                backend->substep_ms(), load.critical_dt_ms);

    Trajectory trajectory;
    if (!a.trajectory.empty()) {
        if (!a.probe.empty() || !a.grab.empty()) throw InputError("give --trajectory or --probe/--grab, not both");
        trajectory = read_trajectory(a.trajectory);
    } else {
        if (!a.probe.empty()) trajectory.keyframes.push_back(parse_fixed_instrument(a.probe, InstrumentKind::probe, 0));
        if (!a.grab.empty()) {
            // "X,Y,Z,AX,AY,AZ[,DX,DY,DZ]": grabs at the start, pulls by D over the run.
            InstrumentKeyframe start = parse_fixed_instrument(a.grab, InstrumentKind::grabber, 1);
            InstrumentKeyframe end = start;
            std::vector<double> values;
            {
                std::stringstream in(a.grab);
                std::string field;
                while (std::getline(in, field, ',')) values.push_back(std::stod(field));
            }
            if (values.size() == 9) end.pose.position += Eigen::Vector3d(values[6], values[7], values[8]);
            end.time_ms = steps * backend->time_step_ms();
            trajectory.keyframes.push_back(start);
            trajectory.keyframes.push_back(end);
        }
    }

    const auto wall_start = std::chrono::steady_clock::now();
    ScriptedRunResult run = run_scripted(*backend, trajectory, {.steps = steps, .forces_every_step = !trajectory.keyframes.empty()});
    const InstrumentForces forces = backend->instrument_forces();       // waits: the run is finished
    const auto positions = backend->positions();
    const double wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - wall_start).count();

    std::printf("ran %d steps (%lld substeps), %.4g ms simulated in %.4g ms wall: %.0f substeps/s, real-time factor %.3g\n", run.steps,
                run.substeps, backend->simulated_time_ms(), wall_ms, run.substeps / (wall_ms * 1e-3), backend->simulated_time_ms() / wall_ms);
    if (run.watchdog_events) std::printf("watchdog: %zu events; last: %s\n", run.watchdog_events, run.last_watchdog_message.c_str());
    for (int hand = 0; hand < 2; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        const auto& f = forces.hand[hand];
        std::printf("hand %d force (%.6g, %.6g, %.6g) N on %zu particles\n", hand, f.force_n.x(), f.force_n.y(), f.force_n.z(), f.particles);
    }
    if (a.stats) {
        const PassTimes t = backend->pass_times();
        std::printf("\nTable 1 (%s, %s timing)\n", to_string(kind), t.gpu_timed ? "GPU timer queries" : "wall clock");
        std::printf("%-22s %12s %12s\n", "pass", "per call ms", "calls");
        const double per_substep = t.substeps ? t.step_ms / double(t.substeps) : 0.0;
        std::printf("%-22s %12.4f %12lld   (%zu particles, 18 neighbours)\n", "simulation step", per_substep, t.substeps, load.particles);
        std::printf("%-22s %12s %12s\n", "visualisation step", "-", "not built");
        std::printf("%-22s %12s %12s\n", "picking buffer", "-", "not built (probe uses the direct test in the step)");
        std::printf("%-22s %12.4f %12lld\n", "force buffer", t.force_calls ? t.force_ms / double(t.force_calls) : 0.0, t.force_calls);
        std::printf("steps/s (substeps/s)  %.0f from the step pass, %.0f overall\n", per_substep > 0 ? 1000.0 / per_substep : 0.0,
                    run.substeps / (wall_ms * 1e-3));
    }
    if (!a.save_state.empty()) {
        SimulationState state;
        state.backend = to_string(kind);
        state.scenario = std::filesystem::path(a.scenario).filename().string();
        state.time_ms = backend->simulated_time_ms();
        state.steps = run.steps;
        state.positions = positions;
        for (int hand = 0; hand < 2; ++hand) {
            for (int c = 0; c < 3; ++c) state.force_n[hand][c] = forces.hand[hand].force_n[c];
            state.particles[hand] = std::int32_t(forces.hand[hand].particles);
            state.kind[hand] = trajectory.uses_hand(hand) ? (trajectory.at(hand, backend->simulated_time_ms()).kind == InstrumentKind::probe ? 1 : 2) : 0;
        }
        write_state(a.save_state, state);
        std::printf("wrote %s\n", a.save_state.c_str());
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"heartsim: GPU spring-mass simulation of a patient heart (scenario from heartprep)"};
    app.set_version_flag("--version", std::string("heartsim ") + HEARTSIM_VERSION);
    app.require_subcommand(1);
    auto* info = app.add_subcommand("info", "Print the OpenGL renderer, version and limits (headless EGL)");
    RunArguments a;
    auto* run = app.add_subcommand("run", "Simulate a scenario");
    run->add_option("scenario", a.scenario, "Scenario file (heartprep build)")->required()->check(CLI::ExistingFile);
    run->add_flag("--headless", a.headless, "No window: EGL surfaceless, no display needed");
    run->add_option("--backend", a.backend, "gl (OpenGL 4.3 compute) or cpu (reference)")->check(CLI::IsMember({"gl", "cpu"}));
    run->add_option("--steps", a.steps, "Solver steps (each of the scenario's dt_ms)")->check(CLI::NonNegativeNumber);
    run->add_option("--seconds", a.seconds, "Simulated seconds instead of --steps")->check(CLI::NonNegativeNumber);
    run->add_option("--probe", a.probe, "Fixed probe on hand 0: X,Y,Z,AX,AY,AZ (mm, world LPS)");
    run->add_option("--grab", a.grab, "Grabber on hand 1: X,Y,Z,AX,AY,AZ[,DX,DY,DZ] grabs at start, pulls by D over the run");
    run->add_option("--trajectory", a.trajectory, "Instrument keyframes CSV (docs/runtime.md)")->check(CLI::ExistingFile);
    run->add_option("--save-state", a.save_state, "Write final positions and forces (HDF5)");
    run->add_flag("--stats", a.stats, "Print per-pass timings (GPU timer queries) as the seed's Table 1");
    CLI11_PARSE(app, argc, argv);
    try {
        if (info->parsed()) return command_info();
        if (run->parsed()) return command_run(a);
    } catch (const GlUnavailable& e) {
        std::fprintf(stderr, "heartsim: %s\n", e.what());
        return 3;
    } catch (const InputError& e) {
        std::fprintf(stderr, "heartsim: %s\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "heartsim: %s\n", e.what());
        return 1;
    }
    return 0;
}
