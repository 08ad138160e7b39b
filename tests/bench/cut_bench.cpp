// The incision benchmark (docs/benchmarks.md "Cutting"): on one scenario, the scripted incision of
// tests/incision_gesture.h (a scalpel drawn 30 mm through the anterior wall at 0.1 mm/ms, then two
// retractors pulling the edges 6 mm apart) run on the cpu backend twice: with the blade lowered,
// and with it lifted (the same gesture, nothing cut). Per run: the step's wall time during the cut
// (p50, p99, max), the real-time factor while cutting and after, the springs cut, watchdog events,
// whether every position stayed finite, and how far the incision stands open at the end
// (incision_gesture.h incision_opening, over the springs the lowered run cut). With a detailed
// mesh, the lowered run opens it where the blade lifts (libmodel/surgery/incision_state.h, timed inside
// that step, as heartsim does): how long that takes, how far the caps lie from the blade's swept
// plane then (their drawn positions), whether the mesh is a closed 2-manifold, and how far apart
// the two sides' caps stand at the end near the incision's centre. Appends one row per run to
// OUT.csv and, given TRAJECTORY.csv, writes the gesture for `heartsim run --trajectory`.
// Usage: cut_bench SCENARIO.h5 CASE OUT.csv [TRAJECTORY.csv]
#include "incision_gesture.h"

#include "formats/scenario.h"
#include "libmodel/surgery/incision_state.h"
#include "libmodel/mapping.h"
#include "runtime/backend/backend.h"
#include "runtime/core/trajectory.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <vector>

using namespace heartsim;

namespace {

double percentile(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, std::size_t(q * double(v.size() - 1) + 0.5))];
}

struct RunFigures {
    std::vector<double> cut_phase_ms, after_ms;  // wall time of each step
    double cut_simulated_ms = 0, after_simulated_ms = 0;
    std::size_t cut = 0, watchdog = 0;
    bool finite = true;
    std::vector<std::array<std::int32_t, 2>> cut_springs;
    std::vector<std::array<float, 3>> positions;
    double open_ms = 0, cap_distance_max_mm = 0, cap_distance_mean_mm = 0, caps_apart_mm = 0;
    bool opened = false, closed = false;
};

RunFigures run(const Scenario& scenario, const test::Incision& plan, const Trajectory& trajectory) {
    auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
    ScriptedHands hands(trajectory);
    RunFigures f;
    std::optional<IncisionState> incisions;
    if (scenario.visual && scenario.mapping && scenario.simulation_surface)
        incisions.emplace(scenario.lattice, scenario.visual->positions, scenario.visual->normals, scenario.visual->triangles,
                          *scenario.mapping, *scenario.simulation_surface);
    const double dt = backend->time_step_ms();
    const int steps = int(std::ceil(plan.end_ms / dt));
    for (int step = 0; step < steps; ++step) {
        const double t = step * dt;
        for (int hand = 0; hand < 2; ++hand) hands.apply(*backend, hand, t, t + dt);
        const auto start = std::chrono::steady_clock::now();
        const StepReport report = backend->step(1);
        backend->request_forces();
        bool opened_now = false;
        if (incisions && incisions->pending(backend->strokes(), false)) {  // as heartsim: inside the step the blade lifts
            const auto open_start = std::chrono::steady_clock::now();
            opened_now = incisions->update(backend->strokes(), backend->positions(), false).opened;
            f.open_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - open_start).count();
        }
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        if (opened_now) {
            const test::CapFigures c = test::cap_figures(*incisions, apply_mapping(incisions->mapping(), backend->positions(), *scenario.simulation_surface), plan);
            f.cap_distance_max_mm = c.distance_max;
            f.cap_distance_mean_mm = c.distance_mean;
            f.opened = true;
        }
        if (report.diverged) ++f.watchdog;
        if (t < plan.cut_end_ms) f.cut_phase_ms.push_back(ms), f.cut_simulated_ms += dt;
        else f.after_ms.push_back(ms), f.after_simulated_ms += dt;
    }
    f.cut_springs = backend->cut_springs();
    f.cut = f.cut_springs.size();
    f.positions = backend->positions();
    for (const auto& p : f.positions) f.finite = f.finite && std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
    if (f.opened) {
        f.closed = closed_manifold(incisions->drawn_triangles());
        f.caps_apart_mm = test::cap_figures(*incisions, apply_mapping(incisions->mapping(), f.positions, *scenario.simulation_surface), plan).apart;
    }
    return f;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 4) {
        std::fprintf(stderr, "usage: cut_bench SCENARIO.h5 CASE OUT.csv [TRAJECTORY.csv]\n");
        return 2;
    }
    const Scenario scenario = read_scenario(argv[1]);
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 30.0, .depth_mm = 0.0});  // through the wall, as plan-incision
    if (argc > 4) test::write_trajectory_csv(plan.trajectory, argv[4]);
    Trajectory lifted = plan.trajectory;
    for (InstrumentKeyframe& k : lifted.keyframes)
        if (k.kind == InstrumentKind::scalpel) k.grab = false;
    const bool header = !std::filesystem::exists(argv[3]);
    std::ofstream out(argv[3], std::ios::app);
    if (header)
        out << "case,particles,run,springs_cut,cut_step_p50_ms,cut_step_p99_ms,cut_step_max_ms,real_time_factor_cutting,"
               "real_time_factor_after,watchdog_events,finite,opening_mean_mm,opening_max_mm,mesh_open_ms,cap_distance_max_mm,"
               "cap_distance_mean_mm,mesh_closed,caps_apart_mm\n";
    const RunFigures with_cut = run(scenario, plan, plan.trajectory), without = run(scenario, plan, lifted);
    for (const bool cutting : {false, true}) {
        const RunFigures& f = cutting ? with_cut : without;
        const test::Opening open = test::incision_opening(scenario, plan, with_cut.cut_springs, f.positions);
        double cut_wall = 0, after_wall = 0;
        for (double ms : f.cut_phase_ms) cut_wall += ms;
        for (double ms : f.after_ms) after_wall += ms;
        char line[640];
        std::snprintf(line, sizeof line, "%s,%zu,%s,%zu,%.4f,%.4f,%.4f,%.3f,%.3f,%zu,%d,%.3f,%.3f,%.1f,%.3f,%.3f,%d,%.3f\n", argv[2],
                      scenario.lattice.particles.size(), cutting ? "cut" : "uncut", f.cut, percentile(f.cut_phase_ms, 0.5),
                      percentile(f.cut_phase_ms, 0.99), percentile(f.cut_phase_ms, 1.0), f.cut_simulated_ms / cut_wall,
                      f.after_simulated_ms / after_wall, f.watchdog, f.finite ? 1 : 0, open.mean_mm, open.max_mm, f.open_ms,
                      f.cap_distance_max_mm, f.cap_distance_mean_mm, f.closed ? 1 : 0, f.caps_apart_mm);
        out << line;
        std::fputs(line, stderr);
    }
    return 0;
}
