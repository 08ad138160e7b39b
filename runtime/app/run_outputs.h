/// @file run_outputs.h
/// @brief What a run of `heartsim run` draws, checks and writes around its steps and at its end
/// (run_outputs.cpp), shared by the modes (run_modes.cpp): the instruments of a script, the
/// repair drawn, the closure check, --save-state, and finish_run's summary, --stats and outputs.
/// The program's side only: main.cpp reaches them through run_modes.h.
#pragma once

#include "runtime/haptics/haptic_run.h"
#include "runtime/app/run_modes.h"

#include <chrono>
#include <vector>

namespace heartsim {

/// The instruments of the script at `time_ms`, to draw.
std::vector<InstrumentShape> shapes_at(const Trajectory& trajectory, double time_ms);

/// The renderer draws the repair's patch and stitches as they are now from the next frame on
/// (none before a patch is laid).
void draw_repair(PreparedRun& p);

/// The closure check at the end of a run on a scenario with a defect (libmodel/surgery/closure.h): the
/// detailed mesh as drawn and the patch after the leak test, one line a trainer reads. Where
/// stitches were tied, a line after it counts those whose tissue points at rest lie in the
/// defect's conduction zone ("stitches in the conduction zone: N of M", naming them; the zone
/// by scenario_conduction_zone's defaults, runtime/surgery/repair_plan.h).
void report_closure(const RunArguments& a, PreparedRun& p, const std::vector<std::array<float, 3>>& positions);

/// --save-state: the final positions, the forces, what each hand held and the springs cut.
void save_state(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const InstrumentForces& forces,
                const std::vector<std::array<float, 3>>& positions, const haptics::HapticRun* haptic);

/// After every mode but --replay: the last screenshot, the summary, --stats, --stats-csv,
/// --save-state. Returns the exit status: 4 when a haptic device faulted, else 0.
int finish_run(const RunArguments& a, PreparedRun& p, const ScriptedRunResult& run, const haptics::HapticRun* haptic,
               std::chrono::steady_clock::time_point wall_start);

}  // namespace heartsim
