// What a run draws, checks and writes around its steps and at its end: run_outputs.h. What each
// prints, in the order it prints it, is the command's output that tests/test_runtime_cli.cpp and
// tests/test_haptics_cli.cpp check.
#include "runtime/app/run_outputs.h"

#include "runtime/surgery/repair_plan.h"

#include "runtime/gl/backend_gl.h"
#include "runtime/gl/picking.h"

#include "runtime/haptics/haptic_run.h"
#include "runtime/view/png.h"
#include "runtime/view/section_plane.h"
#include "runtime/core/stepping.h"
#include "runtime/app/window_run.h"

#include "formats/atomic_file.h"
#include "formats/recording.h"
#include "formats/recording_journal.h"
#include "formats/state.h"
#include "formats/xdmf.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "cli/exit_codes.h"
#include "libmodel/mapping.h"
#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <sstream>
#include <thread>
#include <tuple>
#include <utility>

namespace heartsim {

using Clock = std::chrono::steady_clock;

/// The instruments of the script at `time_ms`, to draw.
std::vector<InstrumentShape> shapes_at(const Trajectory& trajectory, double time_ms) {
    std::vector<InstrumentShape> shapes;
    for (int hand = 0; hand < 2; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        const InstrumentKeyframe k = trajectory.at(hand, time_ms);
        if (k.kind != InstrumentKind::none) shapes.push_back({k.kind, k.pose, k.semi_axes});
    }
    return shapes;
}

/// The renderer draws the repair's patch and stitches as they are now from the next frame on
/// (none before a patch is laid).
void draw_repair(PreparedRun& p) {
    if (!p.renderer) return;
    if (const PatchModel* patch = p.repair ? p.repair->patch() : nullptr) p.renderer->set_patch(drawn_patch(*patch, p.repair->stitch_anchors()));
    else p.renderer->clear_patch();
}

namespace {

/// --stats: Sørensen & Mosegaard's Table 1, per pass.
void print_stats(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, double wall_ms) {
    const PassTimes t = p.backend->pass_times();
    std::printf("\nTable 1 (%s, %s timing)\n", to_string(p.kind), t.gpu_timed ? "GPU timer queries" : "wall clock");
    std::printf("%-22s %12s %12s\n", "pass", "per call ms", "calls");
    const double per_substep = t.substeps ? t.step_ms / double(t.substeps) : 0.0;
    std::printf("%-22s %12.4f %12lld   (%zu particles, 18 neighbours)\n", "simulation step", per_substep, t.substeps,
                p.backend->load_report().particles);
    if (p.renderer) {
        Renderer& renderer = *p.renderer;
        const RenderTimes r = renderer.times(true);
        if (r.normals_calls)
            std::printf("%-22s %12.4f %12lld   (compute, one invocation per surface particle)\n", "particle normals",
                        r.normals_ms / double(r.normals_calls), r.normals_calls);
        std::printf("%-22s %12.4f %12lld   (%s: %zu vertices, %zu faces; %dx%d)\n", "visualisation step",
                    r.frames ? r.draw_ms / double(r.frames) : 0.0, r.frames, renderer.draws_visual_mesh() ? "mapped visual mesh" : "simulation surface",
                    renderer.vertex_count(), renderer.triangle_count(), renderer.width(), renderer.height());
        if (r.uploads)
            std::printf("%-22s %12.4f %12lld   (cpu backend: positions to the GPU, wall clock)\n", "position upload", r.upload_ms / double(r.uploads),
                        r.uploads);
    } else {
        std::printf("%-22s %12s %12s\n", "visualisation step", "-", "skipped (headless, no --screenshot)");
    }
    if (t.picking_calls)
        std::printf("%-22s %12.4f %12lld   (%s; %lld buffer renders)\n", "picking buffer", t.picking_ms / double(t.picking_calls),
                    t.picking_calls, a.contact_mode().c_str(), t.picking_renders);
    else
        std::printf("%-22s %12s %12s\n", "picking buffer", "-", "none (--contact direct: the step's own probe test)");
    std::printf("%-22s %12.4f %12lld\n", "force buffer", t.force_calls ? t.force_ms / double(t.force_calls) : 0.0, t.force_calls);
    std::printf("steps/s (substeps/s)  %.0f from the step pass, %.0f overall\n", per_substep > 0 ? 1000.0 / per_substep : 0.0,
                run.substeps / (wall_ms * 1e-3));
}

/// --stats-csv: the --stats figures, one row per pass, with the run's columns repeated on every
/// row (tests/bench/run_runtime_bench.sh reads it). A pass that did not run: calls 0.
void write_stats_csv(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, double wall_ms) {
    const PassTimes t = p.backend->pass_times();
    const RenderTimes r = p.renderer ? p.renderer->times(true) : RenderTimes{};
    const std::string device = p.context ? p.context->info().renderer : std::string("none (cpu backend, headless, no GL context)");
    auto quote = [](const std::string& text) {
        std::string q = "\"";
        for (char c : text) q += c == '"' ? std::string("\"\"") : std::string(1, c);
        return q + "\"";
    };
    const double seconds = std::max(wall_ms * 1e-3, 1e-9);
    const double per_substep = t.substeps ? t.step_ms / double(t.substeps) : 0.0;
    char run_columns[512];
    std::snprintf(run_columns, sizeof run_columns, "%s,%s,%d,%s,%zu,%d,%lld,%.6f,%.6g,%.6g,%.6g,%lld,%.6g", to_string(p.kind),
                  a.contact_mode().c_str(), a.picking_refresh_every(), quote(device).c_str(), p.backend->load_report().particles, run.steps,
                  run.substeps, wall_ms, run.steps / seconds, run.substeps / seconds, per_substep > 0 ? 1000.0 / per_substep : 0.0, r.frames,
                  p.backend->options().mass_scale);
    std::ostringstream out;
    out << "pass,calls,total_ms,mean_ms,per,timing,backend,contact,picking_refresh,renderer,particles,steps,substeps,wall_ms,"
           "steps_per_s,substeps_per_s,step_pass_substeps_per_s,frames,mass_scale\n";
    const char* timing = t.gpu_timed ? "gpu" : "wall";
    auto row = [&](const char* pass, long long calls, double total_ms, const char* per, const char* how) {
        char line[256];
        std::snprintf(line, sizeof line, "%s,%lld,%.6f,%.6f,%s,%s,", pass, calls, total_ms, calls ? total_ms / double(calls) : 0.0, per, how);
        out << line << run_columns << '\n';
    };
    row("simulation step", t.substeps, t.step_ms, "substep", timing);
    row("particle normals", r.normals_calls, r.normals_ms, "frame", "gpu");
    row("visualisation step", r.frames, r.draw_ms, "frame", "gpu");
    row("position upload", r.uploads, r.upload_ms, "frame", "wall");
    row("picking buffer", t.picking_calls, t.picking_ms, "force request", timing);
    row("force buffer", t.force_calls, t.force_ms, "force request", timing);
    const std::string text = out.str();
    write_bytes_atomically(a.stats_csv, text.data(), text.size(), "the --stats-csv table");
    std::printf("wrote %s\n", a.stats_csv.c_str());
}

/// The run's incision state, made at the first stroke; null without a mapped visual mesh or
/// before any stroke.
IncisionState* incision_state(PreparedRun& p, const StrokeLog& log) {
    const Scenario& scenario = p.scenario;
    if (!scenario.visual || !scenario.mapping || !scenario.simulation_surface || scenario.visual->positions.empty()) return nullptr;
    if (!p.incisions && !log.strokes().empty())
        p.incisions = std::make_unique<IncisionState>(scenario.lattice, scenario.visual->positions, scenario.visual->normals,
                                                      scenario.visual->triangles, *scenario.mapping, *scenario.simulation_surface);
    return p.incisions.get();
}

/// `positions`, or the backend's read into `read`.
const std::vector<std::array<float, 3>>& positions_or_read(PreparedRun& p, const std::vector<std::array<float, 3>>* positions,
                                                            std::vector<std::array<float, 3>>& read) {
    if (positions) return *positions;
    read = p.backend->positions();
    return read;
}

/// The renderer draws the incision state's mesh from the next frame on.
void draw_incisions(PreparedRun& p) {
    const IncisionState& cut = *p.incisions;
    if (p.link) p.link->set_drawn_mesh(cut.drawn_triangles(), cut.mapping());  // and Slicer from its next mesh on
    if (!p.renderer || !p.renderer->draws_visual_mesh()) return;
    p.renderer->set_visual(cut.rest_positions(), cut.rest_normals(), cut.drawn_triangles(), cut.mapping(), cut.cap_first());
}

}  // namespace

bool open_incisions(PreparedRun& p, bool finish, const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    const StrokeLog& log = strokes ? *strokes : p.backend->strokes();
    IncisionState* incisions = incision_state(p, log);
    if (!incisions || !incisions->pending(log, finish)) return false;
    std::vector<std::array<float, 3>> read;
    const IncisionUpdate update = incisions->update(log, positions_or_read(p, positions, read), finish);
    for (const std::string& failure : update.failures)
        std::printf("incision: the detailed mesh does not open along one stroke: %s (the tissue is cut; the mesh stays closed)\n", failure.c_str());
    if (!update.opened) return false;
    const IncisionState& cut = *incisions;
    if (cut.cut())
        std::printf("incision: the detailed mesh opened along %zu stroke(s): %zu vertices, %zu triangles of which %zu cut faces; %zu vertices "
                    "embedded on their own side (%.0f ms)\n",
                    update.strokes, cut.mesh().rest.size(), cut.drawn_triangles().size(), cut.drawn_triangles().size() - cut.cap_first(),
                    update.reembedded, 1e3 * update.seconds);
    std::fflush(stdout);  // a window's user (and its tests) read it as it happens
    draw_incisions(p);
    return true;
}

bool preview_incisions(PreparedRun& p, const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    if (!p.renderer || !p.renderer->draws_visual_mesh()) return false;
    const StrokeLog& log = strokes ? *strokes : p.backend->strokes();
    if (log.strokes().empty() || log.version() == p.previewed_strokes) return false;
    if (std::chrono::steady_clock::now() - p.previewed < std::chrono::milliseconds(250)) return false;
    IncisionState* incisions = incision_state(p, log);
    if (!incisions) return false;
    std::vector<std::array<float, 3>> read;
    p.previewed_strokes = log.version();
    const IncisionUpdate update = incisions->preview(log, positions_or_read(p, positions, read));
    p.previewed = std::chrono::steady_clock::now();  // the next one a quarter second after this one ends
    if (!update.opened) return false;
    draw_incisions(p);
    return true;
}


/// --save-state: the final positions, the forces, what each hand held and the springs cut.
/// The detailed mesh as drawn at `positions`: the mapping evaluated there (libmodel apply_mapping,
/// the vertex shader's formula and float order); once cut, the incision's mesh and mapping. Needs
/// the scenario's visual mesh, mapping and simulation surface.
std::vector<std::array<float, 3>> drawn_detailed_mesh(const PreparedRun& p, const std::vector<std::array<float, 3>>& positions) {
    const bool opened = p.incisions && p.incisions->cut();
    const auto visual = apply_mapping(opened ? p.incisions->mapping() : *p.scenario.mapping, positions, *p.scenario.simulation_surface);
    std::vector<std::array<float, 3>> out;
    out.reserve(visual.size());
    for (const auto& v : visual) out.push_back({v.x(), v.y(), v.z()});
    return out;
}

void save_state(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const InstrumentForces& forces,
                const std::vector<std::array<float, 3>>& positions, const haptics::HapticRun* haptic) {
    const Recording* replayed = p.replayed ? &*p.replayed : nullptr;
    SimulationState state;
    state.backend = to_string(p.kind);
    state.scenario = std::filesystem::path(a.scenario).filename().string();
    state.time_ms = p.backend->simulated_time_ms();
    state.steps = run.steps;
    state.mass_scale = p.backend->options().mass_scale;
    state.positions = positions;
    for (int hand = 0; hand < 2; ++hand) {
        for (int c = 0; c < 3; ++c) state.force_n[hand][c] = forces.hand[hand].force_n[c];
        state.particles[hand] = std::int32_t(forces.hand[hand].particles);
        if (haptic) {
            state.kind[hand] = !haptic->uses_hand(hand) ? 0 : std::int32_t(instrument_code(haptic->instrument(hand)));
        } else if (replayed) {  // a replay: the instruments the recording's hands held at its last step
            state.kind[hand] = std::int32_t(instrument_code(replayed->instrument_at(replayed->steps.size() ? replayed->steps.size() - 1 : 0, hand).kind));
        } else {
            state.kind[hand] = p.trajectory.uses_hand(hand) ? std::int32_t(instrument_code(p.trajectory.at(hand, p.backend->simulated_time_ms()).kind)) : 0;
        }
    }
    state.cut_springs = p.backend->cut_springs();
    if (const PatchModel* patch = p.repair ? p.repair->patch() : nullptr) {
        PatchState out;
        out.material = patch->spec().material.name;
        out.thickness_mm = patch->spec().thickness_mm;
        out.youngs_modulus_mpa = patch->spec().material.youngs_modulus_mpa;
        for (const auto& x : patch->positions()) out.positions.push_back({float(x.x()), float(x.y()), float(x.z())});
        out.triangles = patch->triangles();
        const auto anchors = p.repair->stitch_anchors();
        for (std::size_t k = 0; k < patch->stitches().size(); ++k) {
            const Stitch& stitch = patch->stitches()[k];
            out.stitch_vertex.push_back(stitch.vertex);
            out.stitch_anchor.push_back({float(anchors[k].x()), float(anchors[k].y()), float(anchors[k].z())});
            out.stitch_force.push_back({stitch.force_n.x(), stitch.force_n.y(), stitch.force_n.z()});
            out.stitch_tied_ms.push_back(stitch.tied_ms);
        }
        if (p.closure) {
            out.has_defect = true;
            for (int c = 0; c < 3; ++c) out.defect_centre[c] = p.closure->frame.centre[c], out.defect_axis[c] = p.closure->frame.axis[c];
            out.defect_diameter_mm = p.closure->frame.diameter_mm;
            out.closed = p.closure->result.closed;
            out.largest_rim_gap_mm = p.closure->result.largest_rim_gap_mm;
            if (const auto& leak = p.closure->result.leak_mm) out.leak_mm = std::array<double, 3>{leak->x(), leak->y(), leak->z()};
            out.leak_test_mmhg = a.leak_test_mmhg;
            out.leak_test_positions = p.closure->tested_patch;
            out.rim_offset_mm = p.closure->rim_offset_mm;
            out.margin_mm = p.closure->margin_mm;
        }
        state.patch = std::move(out);
    }
    if (p.scenario.visual && p.scenario.mapping && p.scenario.simulation_surface) {
        state.visual_positions = drawn_detailed_mesh(p, positions);
        if (p.incisions && p.incisions->cut()) {
            state.visual_triangles = p.incisions->drawn_triangles();
            state.visual_cap_first = p.incisions->cap_first();
        }
    }
    state.scenario_path = a.scenario;
    if (p.scenario.simulation_surface) state.scenario_simsurface_triangles = p.scenario.simulation_surface->size();
    if (p.scenario.visual) state.scenario_visual_triangles = p.scenario.visual->triangles.size();
    write_state(a.save_state, state);
    std::printf("wrote %s\n", a.save_state.c_str());
}

namespace {

/// The stitches tied in the run that bite inside the defect's conduction zone, one line after the
/// closure's: each stitch's tissue point at rest (where the needle tied it, on the detailed mesh's
/// rest surface: CarriedPoint::rest) against the zone the scenario gives by default
/// (scenario_conduction_zone, runtime/surgery/repair_plan.h), not against a plan's flags. Nothing
/// without a tied stitch.
void report_conduction_zone(PreparedRun& p) {
    const PatchModel* patch = p.repair ? p.repair->patch() : nullptr;
    if (!patch || patch->stitches().empty()) return;
    const ConductionZone zone = scenario_conduction_zone(p.scenario);
    const std::size_t m = patch->stitches().size();
    if (!zone.found) {
        std::printf("stitches in the conduction zone: cannot tell, %zu stitches tied (no zone: %s)\n", m, zone.reason.c_str());
        return;
    }
    std::vector<Eigen::Vector3d> tissue;
    for (const Stitch& s : patch->stitches()) tissue.push_back(s.anchor.rest);
    const std::vector<int> in = points_in_zone(zone, tissue);
    std::string which;
    for (std::size_t i = 0; i < in.size(); ++i) {
        const Eigen::Vector3d& x = tissue[std::size_t(in[i])];
        const Eigen::Vector3d off = x - zone.centre - (x - zone.centre).dot(zone.axis) * zone.axis;
        char one[160];
        std::snprintf(one, sizeof one, "%sstitch %d at (%.1f, %.1f, %.1f) mm, %.1f mm beyond the edge, %.0f° from the arc's middle", i ? "; " : "",
                      in[i] + 1, x.x(), x.y(), x.z(), off.norm() - zone.edge_mm, zone.angle_from_middle_deg(x));
        which += one;
    }
    std::printf("stitches in the conduction zone: %zu of %zu%s%s%s\n", in.size(), m, in.empty() ? "" : " (", which.c_str(), in.empty() ? "" : ")");
    std::printf("  conduction zone: the defect's posteroinferior rim, the arc of %.0f° round (%.2f, %.2f, %.2f) across its axis, from the "
                "axis to %.1f mm beyond the opening's edge; %s; each stitch's tissue point at rest\n",
                2.0 * zone.half_width_deg, zone.direction.x(), zone.direction.y(), zone.direction.z(), zone.outer_mm - zone.edge_mm,
                zone.reason.c_str());
}

}  // namespace

/// The closure check at the end of a run on a scenario with a defect (libmodel/surgery/closure.h): the
/// detailed mesh as drawn and the patch after the leak test, one line a trainer reads.
void report_closure(const RunArguments& a, PreparedRun& p, const std::vector<std::array<float, 3>>& positions) {
    const PatchModel* patch = p.repair ? p.repair->patch() : nullptr;
    const auto frame = defect_frame_now(p.scenario, positions, patch);
    p.closure.reset();
    if (!frame || !p.scenario.visual || !p.scenario.mapping || !p.scenario.simulation_surface) return;
    const auto tissue = drawn_detailed_mesh(p, positions);
    const bool opened = p.incisions && p.incisions->cut();
    const auto& triangles = opened ? p.incisions->drawn_triangles() : p.scenario.visual->triangles;
    std::vector<std::array<float, 3>> patch_positions;
    std::vector<std::array<std::int32_t, 3>> patch_triangles;
    double thickness = 0;
    if (patch) {
        const PatchModel tested = patch->under_pressure(p.repair->positions_of(patch->particles()), a.leak_test_mmhg * mmhg_in_n_per_mm2);
        for (const auto& x : tested.positions()) patch_positions.push_back({float(x.x()), float(x.y()), float(x.z())});
        patch_triangles = tested.triangles();
        thickness = tested.spec().thickness_mm;
    }
    try {
        // The patch's reach: its half-diameters, as laid.
        const ClosureOptions options =
            patch ? repair_closure_options(*frame, std::max(patch->spec().radius_x_mm, patch->spec().radius_y_mm), p.repair->stitch_anchors())
                  : ClosureOptions{};
        const ClosureResult r = check_closure(tissue, triangles, patch_positions, patch_triangles, thickness, *frame, options);
        p.closure = PreparedRun::ClosureReport{r, *frame, patch_positions, options.rim_offset_mm, options.margin_mm};
        if (r.cannot_tell) std::printf("defect closed: %s\n", r.why.c_str());  // "cannot tell: …"
        else if (r.closed) std::printf("defect closed: yes, largest rim gap %.2f mm\n", r.largest_rim_gap_mm);
        else std::printf("defect closed: no, largest rim gap %.2f mm (%s)\n", r.largest_rim_gap_mm, r.why.c_str());
        std::printf("  closure check: %s, %zu stitches, the patch held to %.3g mmHg across the septum; a flood fill of %zu voxels of "
                    "%.2f mm reached %zu from the far side; wall %.1f mm thick; %d rim points (%.2f s)\n",
                    patch ? "a patch" : "no patch", patch ? patch->stitches().size() : std::size_t(0), a.leak_test_mmhg, r.voxels,
                    ClosureOptions{}.voxel_mm, r.reached, r.wall_thickness_mm, r.rim_points, r.seconds);
        if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::rim)
            std::printf("  the leak: its way out of the opening passes the rim widest at (%.1f, %.1f, %.1f) mm, %s\n", r.leak_mm->x(),
                        r.leak_mm->y(), r.leak_mm->z(), leak_place(r).c_str());
        else if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::through_patch)
            std::printf("  the leak: its way out of the opening does not pass the rim but goes through the patch, out at (%.1f, %.1f, %.1f) mm\n",
                        r.leak_mm->x(), r.leak_mm->y(), r.leak_mm->z());
        else if (r.leak_mm && r.leak_way == ClosureResult::LeakWay::uncovered)
            std::printf("  the leak: the fill found no way out, but the patch leaves the opening uncovered around (%.1f, %.1f, %.1f) mm\n",
                        r.leak_mm->x(), r.leak_mm->y(), r.leak_mm->z());
    } catch (const InputError& e) {
        std::printf("defect closed: cannot tell (%s)\n", e.what());
    }
    report_conduction_zone(p);
}

namespace {

/// Where a carried patch or needle passed through tissue (RepairBackend::intrusions), after the
/// closure's lines: "none", or one line for each of the first few stretches and a count of the rest.
/// Nothing in a run whose hands held neither, or with the check off (RepairSettings::intrusion_every_ms).
void report_intrusions(PreparedRun& p) {
    if (!p.repair || !p.repair->held_repair_instrument() || p.repair->intrusion_every() == 0) return;
    const auto& found = p.repair->intrusions();
    if (found.empty()) {
        std::printf("instruments through tissue: none\n");
        return;
    }
    constexpr std::size_t shown = 5;
    for (std::size_t i = 0; i < found.size() && i < shown; ++i) {
        const TissueIntrusion& t = found[i];
        std::printf("instruments through tissue: the %s (hand %d) passed through tissue at (%.1f, %.1f, %.1f) mm, %.1f mm deep, from %.0f "
                    "to %.0f ms\n",
                    std::string(to_string(t.kind)).c_str(), t.hand, t.where.x(), t.where.y(), t.where.z(), t.depth_mm, t.from_ms, t.to_ms);
    }
    if (found.size() > shown) std::printf("instruments through tissue: %zu more, %zu in all\n", found.size() - shown, found.size());
}

}  // namespace

/// After every mode but --replay: the last screenshot, the summary, --stats, --stats-csv,
/// --save-state. Returns the exit status: 4 when a haptic device faulted, else 0.
int finish_run(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const haptics::HapticRun* haptic,
               Clock::time_point wall_start) {
    Backend& backend = *p.backend;
    auto uses_hand = [&](int hand) { return haptic ? haptic->uses_hand(hand) : p.trajectory.uses_hand(hand); };
    open_incisions(p, true);  // a stroke still under way counts as finished
    if (p.renderer && !a.screenshot.empty()) {
        draw_repair(p);
        p.renderer->render(backend, haptic ? haptic->shapes() : shapes_at(p.trajectory, backend.simulated_time_ms()));
        write_png(a.screenshot, p.renderer->read_pixels());
        std::printf("wrote %s (%dx%d)\n", a.screenshot.c_str(), p.renderer->width(), p.renderer->height());
    }
    const InstrumentForces forces = backend.instrument_forces();       // waits: the run is finished
    const auto positions = backend.positions();
    const double wall_ms = std::chrono::duration<double, std::milli>(Clock::now() - wall_start).count();

    // Steps the watchdog rolled back are not counted: the simulated time says how far the run got.
    const long long advanced = run.watchdog_events ? std::llround(backend.simulated_time_ms() / backend.time_step_ms()) : run.steps;
    std::printf("ran %lld steps (%lld substeps), %.4g ms simulated in %.4g ms wall: %.0f substeps/s, real-time factor %.3g\n", advanced,
                run.substeps, backend.simulated_time_ms(), wall_ms, run.substeps / (wall_ms * 1e-3), backend.simulated_time_ms() / wall_ms);
    if (run.watchdog_events) std::printf("watchdog: %zu events; last: %s\n", run.watchdog_events, run.last_watchdog_message.c_str());
    if (p.repair && p.repair->patch_steps() > 0) {
        if (const auto [device_ms, timed] = p.repair->patch_device_time(); timed > 0)
            std::printf("repair: the GPU spent %.3g ms on each of the patch's %lld steps it ran (%.1f %% of the wall time)\n",
                        device_ms / double(timed), timed, 100.0 * device_ms / wall_ms);
        std::printf(p.repair->patch_on_device()
                        ? "repair: the patch's %lld steps (one every %d of the tissue's) ran on the GPU before the tissue's; the host "
                          "took %.3g ms each (queueing them, finding the surface near the patch again every 64, reading it back): "
                          "%.1f %% of the wall time\n"
                        : "repair: the patch's %lld steps (one every %d of the tissue's) took %.3g ms each (reading the tissue, stepping "
                          "the patch, loading the tissue): %.1f %% of the wall time\n",
                    p.repair->patch_steps(), p.repair->settings().patch_every, p.repair->patch_ms() / double(p.repair->patch_steps()),
                    100.0 * p.repair->patch_ms() / wall_ms);
    }
    {
        // How far the tissue is from where it was imaged: a heart that is held stays in place.
        const auto& rest = p.scenario.lattice.particles.rest_position;
        double largest = 0.0, sum = 0.0;
        std::size_t worst = 0;
        for (std::size_t i = 0; i < positions.size() && i < rest.size(); ++i) {
            const double d = std::sqrt(std::pow(double(positions[i][0]) - rest[i][0], 2) + std::pow(double(positions[i][1]) - rest[i][1], 2) +
                                       std::pow(double(positions[i][2]) - rest[i][2], 2));
            sum += d;
            if (d > largest) largest = d, worst = i;
        }
        std::printf("displacement from rest: max %.4g mm (particle %zu), mean %.4g mm\n", largest, worst,
                    positions.empty() ? 0.0 : sum / double(positions.size()));
    }
    for (int hand = 0; hand < 2; ++hand) {
        if (!uses_hand(hand)) continue;
        const auto& f = forces.hand[hand];
        std::printf("hand %d force (%.6g, %.6g, %.6g) N on %zu particles\n", hand, f.force_n.x(), f.force_n.y(), f.force_n.z(), f.particles);
    }
    if (p.repair || !p.scenario.source.defect.empty()) report_closure(a, p, positions);
    report_intrusions(p);
    if (a.stats) print_stats(a, p, run, wall_ms);
    if (!a.stats_csv.empty()) write_stats_csv(a, p, run, wall_ms);
    if (!a.save_state.empty()) save_state(a, p, run, forces, positions, haptic);
    if (run.gave_up) {
        std::fprintf(stderr, "heartsim: error: the simulation could not recover and stopped: %s\n", one_line(run.last_watchdog_message).c_str());
        return exit_status(ExitCode::unrecoverable);
    }
    if (haptic && haptic->device_faulted()) {
        std::fprintf(stderr, "heartsim: error: a haptic device faulted during the session (above); the run's outputs were written\n");
        return exit_status(ExitCode::haptic_device);
    }
    return 0;
}


}  // namespace heartsim
