// heartsim: the simulation runtime. `heartsim info` (the GL device), `heartsim run SCENARIO.h5`.
// docs/runtime.md.
#include "runtime/gl/gl_context.h"
#include "runtime/haptics/haptics.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/app/info_verdict.h"
#include "runtime/surgery/operation_plan.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/app/run_modes.h"
#include "runtime/view/window_keys.h"

#include "cli/cli_messages.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "cli/exit_codes.h"
#include "cli/option_flags.h"
#include "libmodel/text.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>
#include <vector>

using namespace heartsim;

namespace {

int command_info(const std::string& scenario) {
    GlContext context = GlContext::create_headless();
    std::cout << describe(context.info()) << std::flush;
    std::cout << session_verdict(context, scenario);
    return 0;
}

/// What the command is doing, for the one line an out-of-memory failure prints.
const char* activity = "starting";

/// One run mode per call (run_modes.h); the arguments decide which.
int command_run(const RunArguments& a) {
    activity = "loading the scenario and preparing the run";
    PreparedRun run(a);
    activity = "running the simulation and writing its outputs";
    if (!a.replay.empty()) return replay_mode(a, run);
    if (!a.headless) return window_mode(a, run);
    if (!a.devices.empty()) return headless_haptic_mode(a, run);
    return headless_scripted_mode(a, run);
}

/// `heartsim run`'s options, into `a`.
CLI::App* add_run_command(CLI::App& app, RunArguments& a) {
    auto* run = app.add_subcommand("run", "Simulate a scenario");
    run->footer("\n" + window_keys_text());  // the window's keys, from the table the on-screen help shows
    run->add_option("scenario", a.scenario, "Scenario file (heartprep build)")->required();
    run->add_flag("--headless", a.headless, "No window: EGL surfaceless, no display needed. A run past 5 s of wall time (or of "
                                            "40,000 steps) says its progress on stderr");
    run->add_option("--backend", a.backend, "gl (OpenGL 4.3 compute) or cpu (reference). Default gl; cpu for --replay, and where "
                                            "OpenGL is software (llvmpipe), unless a headless run asks for --contact picking or search")
        ->check(CLI::IsMember({"gl", "cpu"}));
    run->add_option("--steps", a.steps, "Solver steps (each of the scenario's dt_ms). Default: 1 headless, no limit in a window")->check(cli_messages::non_negative());
    run->add_option("--seconds", a.seconds, "Simulated seconds instead of --steps")->check(cli_messages::non_negative());
    run->add_option("--probe", a.probe, "Fixed probe on hand 0: X,Y,Z,AX,AY,AZ (mm, world LPS)");
    run->add_option("--grab", a.grab, "Grabber on hand 1: X,Y,Z,AX,AY,AZ[,DX,DY,DZ] grabs at start, pulls by D over the run");
    run->add_option("--trajectory", a.trajectory,
                    "Instrument keyframes CSV (docs/runtime.md \"Trajectory CSV\"): per hand a probe, grabber, retractor (a grabber "
                    "whose tissue stays anchored where it is let go, until the tissue is reset), scalpel, patch, needle or none");
    run->add_option("--patch-material", a.patch_material,
                    "A patch's material, laid by a hand whose instrument is a patch (docs/runtime.md \"Closing a defect\"): pericardium "
                    "(fixed bovine pericardium, 30 MPa), ptfe (expanded PTFE, 40 MPa) or dacron (woven polyester, 200 MPa)")
        ->check(CLI::IsMember({"pericardium", "ptfe", "dacron"}))
        ->capture_default_str();
    run->add_option("--leak-test", a.leak_test_mmhg,
                    "MMHG: the pressure across the septum the closure check holds the patch to at the end of a run on a scenario with a "
                    "defect: it pushes the patch off the wall over the opening, as the left ventricle does in systole once the defect "
                    "is closed; a patch its stitches do not hold lifts off the rim. Default 75: a child's left ventricle at about 100 "
                    "mmHg against a right ventricle at 25, the systolic difference a patch over a VSD carries (10: the left "
                    "ventricle's filling pressure as the heart fills again; 0: the patch as it lies)")
        ->check(CLI::Range(0.0, 300.0))
        ->capture_default_str();
    run->add_option("--save-state", a.save_state, "Write final positions and forces (HDF5), and OUT.xmf2 beside it for ParaView (the deformed heart)")
        ->check(cli_messages::output_extension({".h5", ".hdf5"}, "the state is an HDF5 file"));
    run->add_option("--gravity", a.gravity,
                    "Gravity vector in LPS, mm/ms², instead of the scenario's (0 0 0: none; 0 0.00981 0: supine patient)")
        ->expected(3);
    run->add_option("--mass-scale", a.mass_scale,
                    "Explicit mass scaling S (1 to 1024): inertia × S in the step, so a simulated second takes √S to S times fewer "
                    "substeps; weight, "
                    "dashpots and stiffness unchanged: the tissue rests and feels the same, fast transients run √S slower "
                    "(docs/solver.md \"Mass scaling\"). Fixes S: --real-time off");
    run->add_option("--real-time", a.real_time,
                    "auto: measure the speed over the first half second and take the smallest S of 1, 2, 4, 8, 16 that keeps "
                    "the simulation at or above real time (raised again if the machine slows; said on the terminal and the HUD). "
                    "off: S stays 1 (or --mass-scale). Default: auto in a window and in haptic sessions, off for scripted "
                    "--headless runs and replays")
        ->check(CLI::IsMember({"auto", "off"}));
    run->add_option("--contact", a.contact, "Probe contacts for the force pass: direct (the step's test, as the cpu solver), "
                                            "picking (Sørensen & Mosegaard's picking buffer) or search (every surface particle)")
        ->check(CLI::IsMember({"direct", "picking", "search"}))
        ->default_str(RunArguments::default_contact);
    run->add_option("--picking-refresh", a.picking_refresh, "With --contact picking: render the picking buffer every K force requests (stale in between)")
        ->check(CLI::Range(1, 1 << 20))
        ->default_str(std::to_string(RunArguments::default_picking_refresh));
    run->add_flag("--stats", a.stats, "Print per-pass timings (GPU timer queries) as Sørensen & Mosegaard's Table 1");
    run->add_option("--stats-csv", a.stats_csv, "Write the --stats timings as CSV, one row per pass (tests/bench/run_runtime_bench.sh)");
    run->add_option("--screenshot", a.screenshot, "Write the last frame as a PNG (headless: offscreen rendering)")
        ->check(cli_messages::output_extension({".png"}, "the screenshot is a PNG picture"));
    run->add_option("--screenshot-every", a.screenshot_every, "Also write OUT-000123.png after every N steps (numbered by step; 0: only the last frame)")
        ->check(cli_messages::non_negative());
    run->add_option("--draw-share", a.draw_share,
                    "Window with the cpu backend: drawing takes at most this fraction of the wall clock, the simulation the rest "
                    "(a software renderer then draws fewer frames)")
        ->check(CLI::Range(0.01, 1.0))
        ->capture_default_str();
    run->add_option("--size", a.size, "Window or screenshot size WxH pixels (default 1280x800 window, 1024x768 headless)");
    run->add_option("--view", a.view, "Initial view: anterior (default), posterior, left, right, superior, inferior, surgeon (the "
                                      "patient supine, seen from the surgeon's place on the patient's right), or section "
                                      "(with --clip: straight at the section plane, from the removed side). Without --view, --eye "
                                      "and --look-at: the view a --trajectory records (its '# view:' line; plan-operation's surgeon's eye)")
        ->check(CLI::IsMember({"anterior", "posterior", "left", "right", "superior", "inferior", "surgeon", "section"}));
    run->add_option("--clip", a.clip,
                    "Section view: PX,PY,PZ,NX,NY,NZ, a point and a normal (mm, world LPS); the side the normal points to is not "
                    "drawn and the cut wall is shaded. centre: through the heart's centre facing the camera (the nearer half "
                    "removed). defect: across the scenario's septal defect (heartprep build --defect), the camera turned to look "
                    "at it, close enough that the opening and 4 mm round it span two thirds of the picture's height. Headless with --screenshot; in a window C, [ and ] do the same")
        ->type_name("PLANE");
    run->add_option("--surface-detail", a.surface_detail,
                    "The coronary arteries along the courses heartprep found, raised in their fat, and the ventricles' fibres, "
                    "drawn on the detailed mesh as it deforms: on (default) or off (the plain surface)")
        ->check(CLI::IsMember({"on", "off"}));
    run->add_option("--look-at", a.look_at,
                    "Centre the view on a point: X,Y,Z[,DISTANCE] (mm, world LPS), the camera looking from the --view direction (or "
                    "at the --clip section) from DISTANCE mm away (default: the fitted view's distance). Headless with --screenshot; "
                    "heartsim plan-incision and plan-repair print the one that frames their incision or patch")
        ->type_name("X,Y,Z[,D]");
    run->add_option("--eye", a.eye,
                    "With --look-at: where the camera stands, X,Y,Z (mm, world LPS), looking at the --look-at point; the --view's "
                    "up kept as nearly as the line of sight allows (--view surgeon: the patient's left up, across the table). "
                    "heartsim plan-operation prints the surgeon's eye and records it in its CSV, where a run without view options starts")
        ->type_name("X,Y,Z");
    run->add_option("--device", a.devices,
                    "Haptic device for hand 0, then hand 1 (give once or twice): scripted:FILE (pose CSV, or a --record file "
                    ".h5[@HAND]), simulated:FILE (a virtual device pushed by a scripted hand force), mouse (the window), "
                    "openhaptics[:NAME] (3D Systems Touch / Phantom Omni through libHD)")
        ->type_name("SPEC")
        ->allow_extra_args(false);
    run->add_option("--instrument", a.instruments, "Instrument per --device, in order: probe, grabber, retractor, scalpel, patch or needle[:AX,AY,AZ] "
                                                    "semi-axes mm (default: hand 0 probe, hand 1 grabber, 1.5 lattice spacings; a grabber "
                                                    "holds and a scalpel cuts while button 1 is pressed; a retractor holds as a grabber and, "
                                                    "let go, leaves the tissue anchored where it is until the tissue is reset; a scalpel's blade runs from the tip "
                                                    "along the tool's +z, 2*AZ long, default 2,0.3,10; button 1 lays a patch, centred at the "
                                                    "tip and facing the tissue along +z, AX and AY its half-diameters, AZ half its thickness, "
                                                    "default 9,9,0.25, and ties a stitch with a needle, default 0.25,0.25,6, whose hand feels "
                                                    "the wall as its tip passes into it and the suture's tension while the button is held)")
        ->type_name("KIND")
        ->allow_extra_args(false);
    run->add_option("--haptic-rate", a.haptic_rate, "Device thread rate, Hz")->check(CLI::Range(100.0, 10000.0))->capture_default_str();
    run->add_option("--max-force", a.max_force, "Largest force sent to any device, N (default: each device's own maximum; never above it)")
        ->check(cli_messages::non_negative());
    run->add_option("--interpolation", a.interpolation, "Force between simulation updates: hold (zero order) or extrapolate (first order)")
        ->check(CLI::IsMember({"hold", "extrapolate"}))->capture_default_str();
    run->add_option("--haptic-priority", a.haptic_priority,
                    "Device thread scheduling: realtime (SCHED_FIFO where permitted, else normal, as the table says) or normal")
        ->check(CLI::IsMember({"realtime", "normal"}))
        ->capture_default_str();
    run->add_flag("--coupling", a.coupling, "Virtual coupling (spring-damper within the passivity bound b > KT/2 + B) between device and tool");
    run->add_option("--record", a.record, "Record device poses, forces and events of the haptic session (HDF5, written at the end; meanwhile "
                                         "OUT.h5.journal keeps all but the last second of a session that is killed: `heartsim recover`), and OUT.xmf2 "
                                         "beside it for ParaView (the tools over time)")
        ->check(cli_messages::output_extension({".h5", ".hdf5"}, "the recording is an HDF5 file"));
    run->add_option("--replay", a.replay, "Replay a --record file's tool poses and grabs (cpu backend unless --backend) and compare the forces");
    run->add_option("--replay-tolerance", a.replay_tolerance,
                    "Largest |Δf| accepted by --replay, N (default: 0 for a cpu recording on cpu, else 10 % of the largest force)")
        ->check(cli_messages::non_negative());
    run->add_option("--igtl", a.igtl,
                    "Live link to 3D Slicer over OpenIGTLink (a window or a headless run): PORT listens there for Slicer's OpenIGTLinkIF "
                    "(client; Slicer's default port is 18944) on 127.0.0.1 unless --igtl-bind, HOST:PORT connects to a Slicer server; "
                    "streams the instruments' poses (TRANSFORM), the mesh as drawn and a repair's patch and stitches (POLYDATA), forces "
                    "and state (STRING), RAS mm unless --igtl-frame lps; the simulation never waits for it (docs/runtime.md \"Live link "
                    "to 3D Slicer\")")
        ->type_name("PORT|HOST:PORT");
    run->add_option("--igtl-bind", a.igtl_bind, "With --igtl PORT: the IPv4 address heartsim listens on: 127.0.0.1 (this machine only, "
                                                "the default), 0.0.0.0 (every interface: Slicer on another machine) or one interface's")
        ->type_name("ADDRESS");
    run->add_option("--igtl-frame", a.igtl_frame, "With --igtl: the coordinates sent, ras (Slicer's scene, the default: heartsim's LPS "
                                                  "with x and y negated) or lps (heartsim's world, the scenario's)")
        ->check(CLI::IsMember({"ras", "lps"}))->type_name("ras|lps");
    run->add_option("--igtl-wait", a.igtl_wait, "With --igtl: before the first step, wait up to S seconds for Slicer to connect "
                                                "(default 0: start at once, stream to whoever connects)")
        ->check(CLI::Range(0.0, 600.0))->type_name("S");
    run->add_option("--igtl-mesh-rate", a.igtl_mesh_rate, "With --igtl: the most mesh (POLYDATA) messages a second, sent only when the "
                                                          "mesh moved (default 20; poses, forces and state: up to 60)")
        ->check(CLI::Range(0.1, 1000.0))->type_name("HZ");
    return run;
}

/// `heartsim recover JOURNAL [-o OUT.h5]`.
CLI::App* add_recover_command(CLI::App& app, std::string& journal, std::string& recovered) {
    auto* recover = app.add_subcommand("recover", "Write the recording of a --record session that was killed, from the journal it "
                                                  "kept beside the recording (OUT.h5.journal: all but its last second); then delete the journal");
    recover->add_option("journal", journal, "The journal, OUT.h5.journal")->required();
    recover->add_option("-o,--output", recovered, "Recording to write (default: the journal's name without .journal, the --record file)")
        ->check(cli_messages::output_extension({".h5", ".hdf5"}, "the recording is an HDF5 file"));
    return recover;
}

/// `heartsim plan-incision`'s options, into `plan`.
CLI::App* add_plan_incision_command(CLI::App& app, PlanIncisionArguments& plan) {
    auto* plan_command = app.add_subcommand(
        "plan-incision",
        "Plan a scripted incision on a scenario and write it as a --trajectory CSV: a scalpel (hand 0) lowered onto the heart's "
        "surface and drawn from inferior to superior, lifted, then two grabbers (hands 0 and 1) used as retractors grab the "
        "incision's edges and pull them apart, then hold. Prints where it cuts, which way the blade points, how long a run must "
        "last (--seconds) and the --view and --look-at that show the incision, which the CSV records: heartsim run opens there "
        "without view options (docs/runtime.md \"Planning an incision\")");
    plan_command->add_option("scenario", plan.scenario, "Scenario file (heartprep build)")->required();
    plan_command->add_option("-o,--output", plan.output, "Trajectory CSV to write, for heartsim run --trajectory")
        ->required()
        ->check(cli_messages::output_extension({".csv"}, "the trajectory is a CSV file"));
    plan_command->add_option("--approach", plan.approach,
                             "ventriculotomy: a right ventriculotomy through the most anterior wall of the heart's middle third (the "
                             "blade pointing posterior); atriotomy: a right atriotomy on the right atrium's free wall, the most rightward "
                             "wall of the heart's upper half that holds the whole incision (the blade pointing medially, +x); a scenario "
                             "stores no chamber "
                             "labels: each place is found by that rule on its particles")
        ->check(CLI::IsMember({"ventriculotomy", "atriotomy"}))
        ->capture_default_str();
    plan_command->add_option("--length", plan.options.length_mm, "The incision's length, mm (drawn from inferior to superior)")
        ->check(cli_messages::within(plausible::incision_length_mm))
        ->capture_default_str();
    plan_command->add_option("--spread", plan.options.spread_mm,
                             "How far the retractors pull the edges apart, mm (half each way, across the incision); 0: no retractors, "
                             "the cut alone")
        ->check(cli_messages::within(plausible::retraction_mm))
        ->capture_default_str();
    plan_command->add_option("--depth", plan.options.depth_mm, "How deep the blade reaches behind the surface point, mm (its tip starts "
                                                                "2 mm in front of it). Default: through the wall there, 2 mm into the "
                                                                "cavity (the plan says how thick the wall is)")
        ->check(cli_messages::within(plausible::blade_depth_mm));
    plan_command->add_option("--speed", plan.options.speed_mm_per_ms, "How fast the blade is drawn, mm/ms (0.1 mm/ms = 10 cm/s)")
        ->type_name("MM_PER_MS")
        ->check(cli_messages::within(plausible::blade_speed_mm_per_ms))
        ->capture_default_str();
    plan_command->footer("\nExample:\n"
                         "  heartsim plan-incision case.h5 -o cut.csv --approach atriotomy --length 25\n"
                         "  heartsim run case.h5 --trajectory cut.csv --seconds 1.2           # as it printed\n"
                         "  heartsim run case.h5 --headless --trajectory cut.csv --seconds 1.2 \\\n"
                         "      --screenshot cut.png                       # from the --view and --look-at the CSV records\n");
    return plan_command;
}

/// `heartsim plan-repair`'s options, into `repair`.
CLI::App* add_plan_repair_command(CLI::App& app, PlanRepairArguments& repair) {
    auto* repair_command = app.add_subcommand(
        "plan-repair",
        "Plan the closure of a scenario's septal defect (heartprep build --defect vsd|asd) and write it as a --trajectory CSV: "
        "a patch (hand 0) laid over the opening on the septum's right side (its left where the right's rim is too rough to "
        "seal: --side), then a needle (hand 1) tying stitches one by one round the opening's rim, a stitch every 3 mm, each "
        "joining the patch to the wall. The septum's surface is found on the detailed mesh, along "
        "lines parallel to the defect's axis. A perimembranous VSD's conduction zone (its posteroinferior rim, along which "
        "the bundle of His runs) is spared: --conduction-zone. Prints the side and why, the wall's thickness, the patch, the "
        "conduction zone, each stitch's site, how "
        "long a run must last (--seconds) and how to see it (--clip defect) (docs/runtime.md \"Planning a repair\")");
    repair_command->add_option("scenario", repair.scenario, "Scenario file with a septal defect (heartprep build ... --defect vsd)")->required();
    repair_command->add_option("-o,--output", repair.output, "Trajectory CSV to write, for heartsim run --trajectory")
        ->required()
        ->check(cli_messages::output_extension({".csv"}, "the trajectory is a CSV file"));
    repair_command->add_option("--side", repair.side,
                               "Which side of the septum the patch goes on: right (the right ventricle's for a vsd, the right "
                               "atrium's for an asd, as a surgeon closes them through the right heart), left, a / b (the pool at "
                               "the tail / head of the stored defect axis), or auto: the right, unless its rim is rough (where 36 "
                               "lines along the axis round the stitches' circle enter it, farther than --rough-rim off a plane: "
                               "recesses among the trabeculations that a flat patch spans without sealing) and the left's is not. A scenario does not say which pool is which: "
                               "the right side is the one whose outward direction points more to the patient's right and anterior")
        ->check(CLI::IsMember({"auto", "right", "left", "a", "b"}))
        ->capture_default_str();
    repair_command->add_option("--rough-rim", repair.options.rough_rim_mm,
                               "With --side auto: how far off a plane the right side's rim may lie before the patch goes on the "
                               "left, mm (the real hearts' right rims that a patch seals lie within 3.5 mm, one it does not 6.1 mm)")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::rim_roughness_mm))
        ->capture_default_str();
    repair_command->add_option("--stitches", repair.options.stitches,
                               "How many stitches, evenly spaced round the rim (at least 3; surgeons place 10 to 16 round a VSD's patch). "
                               "Default: one every 3 mm along the stitches' circle, at least 8 (15 round a 10 mm defect with the 2 mm "
                               "rim): under pressure a patch lifts off the rim between stitches farther apart")
        ->type_name("N")
        ->check(CLI::Range(3, 360));
    repair_command->add_option("--rim", repair.options.rim_mm,
                               "How far beyond the opening's edge the stitches bite, mm: they lie on the circle of radius D/2 + rim "
                               "round the defect's axis (D its diameter)")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::stitch_rim_mm))
        ->capture_default_str();
    repair_command->add_option("--patch-diameter", repair.options.patch_diameter_mm,
                               "The patch's diameter, mm; more than the stitches' circle, D + 2 * rim. Default: D + 2 * (rim + 2 mm), "
                               "2 mm beyond the stitches")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::patch_diameter_mm));
    repair_command->add_option("--thickness", repair.options.thickness_mm, "The patch's thickness, mm")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::patch_thickness_mm))
        ->capture_default_str();
    repair_command->add_option("--conduction-zone", repair.conduction_zone,
                               "auto: where the scenario's tricuspid and aortic rings lie within --zone-reach of a vsd's rim "
                               "(perimembranous), mark the posteroinferior arc of the rim along which the atrioventricular conduction "
                               "axis (the bundle of His) runs, and move the stitches there out to --zone-rim beyond the edge; off: "
                               "every stitch at --rim. Scenarios without the rings (HVSMR 2016's) get no zone, and the plan says why")
        ->check(CLI::IsMember({"auto", "off"}))
        ->capture_default_str();
    repair_command->add_option("--zone-rim", repair.options.zone_rim_mm,
                               "How far beyond the opening's edge the stitches in the conduction zone bite, mm: more than --zone-band "
                               "(surgeons bite 3 to 5 mm back from the edge there); where --rim reaches as far, none moves")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::stitch_rim_mm))
        ->capture_default_str();
    repair_command->add_option("--zone-band", repair.options.zone.band_mm,
                               "How far beyond the opening's edge the conduction zone reaches, mm: a stitch nearer the edge within its "
                               "arc bites the conduction axis's course")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::stitch_rim_mm))
        ->capture_default_str();
    repair_command->add_option("--zone-half-width", repair.options.zone.half_width_deg,
                               "The conduction zone's arc round the defect's axis: this many degrees either side of its middle")
        ->type_name("DEG")
        ->check(cli_messages::within(plausible::zone_half_width_deg))
        ->capture_default_str();
    repair_command->add_option("--zone-margin", repair.options.zone_margin_deg,
                               "Stitches this many degrees beyond the conduction zone's arc move out too, so a bite a little off its "
                               "site still spares the zone")
        ->type_name("DEG")
        ->check(cli_messages::within(plausible::zone_margin_deg))
        ->capture_default_str();
    repair_command->add_option("--zone-reach", repair.options.zone.ring_reach_mm,
                               "The defect is perimembranous (has a conduction zone) where its rim comes within this of both the "
                               "tricuspid and the aortic ring, mm")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::stitch_rim_mm))
        ->capture_default_str();
    repair_command->footer("\nExample:\n"
                           "  heartprep build case-label.nii.gz -o vsd.h5 --defect vsd --at=40.7,-14.4,-10.4   # a 10 mm VSD there\n"
                           "  heartsim plan-repair vsd.h5 -o repair.csv --stitches=10 --rim=2.5\n"
                           "  heartsim run vsd.h5 --trajectory repair.csv --seconds 2.6 --clip defect --look-at X,Y,Z,D   # as it printed\n");
    return repair_command;
}

/// `heartsim plan-operation`'s options, into `operation`.
CLI::App* add_plan_operation_command(CLI::App& app, PlanOperationArguments& operation) {
    auto* command = app.add_subcommand(
        "plan-operation",
        "Plan the operation on a scenario's septal defect (heartprep build --defect vsd) through an incision, and write it as a "
        "--trajectory CSV: a scalpel (hand 0) opens the approach's chamber where a line of sight from the defect leaves the heart "
        "through its free wall, clear of the coronary courses; two retractors (hands 0 and 1) pull the incision's edges apart until "
        "the defect is seen; then the patch (hand 0) and the needle (hand 1) come in through the opening and the patch is sewn over "
        "the defect's right side (plan-repair's stitches). Prints the incision, the retraction, the surgeon's eye (the CSV records "
        "the surgeon's view: heartsim run opens there without view options), when the defect "
        "is exposed, how many stitch sites are seen from the eye, and how to run and see it; with --approach all, both approaches "
        "and a table comparing them (docs/runtime.md \"Planning an operation\")");
    command->add_option("scenario", operation.scenario, "Scenario file with a septal defect (heartprep build ... --defect vsd)")->required();
    command->add_option("-o,--output", operation.output,
                        "Trajectory CSV to write, for heartsim run --trajectory; with --approach all, one per approach, named with the "
                        "approach before the extension (op.csv: op.right-atrial.csv, op.right-ventricular.csv)")
        ->required()
        ->check(cli_messages::output_extension({".csv"}, "the trajectory is a CSV file"));
    command->add_option("--approach", operation.approach,
                        "right-atrial (a right atriotomy: the defect seen through the tricuspid valve), right-ventricular (a right "
                        "ventriculotomy over the defect), or all (both, and a table comparing them)")
        ->check(CLI::IsMember({"right-atrial", "right-ventricular", "all"}))
        ->capture_default_str();
    command->add_option("--length", operation.options.length_mm, "The incision's length, mm")
        ->type_name("MM")
        ->check(CLI::Range(6.0, 120.0))
        ->capture_default_str();
    command->add_option("--spread", operation.options.spread_mm,
                        "How far apart the retractors pull the incision's edges, mm. Default: 4 mm more than the narrowest of 10, 12, ... 24 mm "
                        "that shows as many stitch sites from the surgeon's eye as 24 mm (at most 24)")
        ->type_name("MM")
        ->check(CLI::Range(2.0, 60.0));
    command->add_option("--coronary-clearance", operation.options.coronary_clearance_mm,
                        "The least distance from any point of the incision to a coronary course (the scenario's landmarks), mm")
        ->type_name("MM")
        ->check(CLI::Range(0.0, 50.0))
        ->capture_default_str();
    command->add_option("--max-wall", operation.options.max_wall_mm, "The thickest free wall the incision may cut through, mm")
        ->type_name("MM")
        ->check(CLI::Range(1.0, 60.0))
        ->capture_default_str();
    command->add_option("--eye-distance", operation.options.eye_distance_mm,
                        "The surgeon's eye's distance from the opening along the line of sight, mm. Default: 2.5 incision lengths (the "
                        "opening then fills a good part of the picture)")
        ->type_name("MM")
        ->check(CLI::Range(1.0, 2000.0));
    command->add_option("--rough-rim", operation.options.repair.rough_rim_mm,
                        "How far off a plane the defect's right-side rim may lie, mm, before the plan refuses: a rougher rim (among "
                        "the right ventricle's trabeculations) a flat patch laid through the right heart does not seal, and surgeons "
                        "close such a defect from the left (plan-repair's --rough-rim)")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::rim_roughness_mm))
        ->capture_default_str();
    command->add_option("--stitches", operation.options.repair.stitches, "How many stitches round the rim (plan-repair's --stitches)")
        ->type_name("N")
        ->check(CLI::Range(3, 360));
    command->add_option("--rim", operation.options.repair.rim_mm, "How far beyond the opening's edge the stitches bite, mm (plan-repair's --rim)")
        ->type_name("MM")
        ->check(cli_messages::within(plausible::stitch_rim_mm))
        ->capture_default_str();
    command->footer("\nExample:\n"
                    "  heartprep build ct-label.nii.gz --labels mmwhs --defect vsd -o vsd.h5\n"
                    "  heartsim plan-operation vsd.h5 -o op.csv --approach all           # both approaches, compared\n"
                    "  heartsim run vsd.h5 --trajectory op.right-atrial.csv --seconds 7   # from the surgeon's eye the CSV records\n");
    return command;
}

/// Training staff launch a session as `heartsim scenario.h5` (or `heartsim --device mouse
/// scenario.h5`): a first argument other than a subcommand, --help or --version means `run`;
/// `arguments` gets the word. A mistyped command is refused: the exit status, else nullopt.
std::optional<int> insert_run_word(const CLI::App& app, int argc, char** argv, std::vector<char*>& arguments) {
    static char run_word[] = "run";
    const std::string first = argc >= 2 ? argv[1] : "";
    std::vector<std::string> commands;
    for (const CLI::App* command : app.get_subcommands({})) commands.push_back(command->get_name());
    const bool is_command = std::find(commands.begin(), commands.end(), first) != commands.end();
    if (argc >= 2 && !is_command && first != "-h" && first != "--help" && first != "--version") {
        // A mistyped command ("heartsim rn case.h5") is no scenario: say so rather than "file not found".
        if (first[0] != '-' && first.find('.') == std::string::npos && !std::filesystem::exists(first)) {
            const std::string nearest = text::nearest_word(first, commands);
            if (!nearest.empty())
                std::fprintf(stderr, "heartsim: error: unknown command '%s' (did you mean '%s'?); the commands are %s (heartsim --help)\n",
                             first.c_str(), nearest.c_str(), text::join(commands).c_str());
            else
                std::fprintf(stderr, "heartsim: error: '%s' is neither a command (%s) nor a scenario file (heartsim --help)\n", first.c_str(),
                             text::join(commands).c_str());
            return exit_status(ExitCode::usage);
        }
        arguments.insert(arguments.begin() + 1, run_word);
    }
    return std::nullopt;
}

}  // namespace

int main(int argc, char** argv) {
    // Lines on stdout reach a file or a pipe as they are printed (a log, a test follow them).
    std::setvbuf(stdout, nullptr, _IOLBF, 0);
    CLI::App app{"heartsim: GPU spring-mass simulation of a patient heart (scenario from heartprep)\n\n"
                 "  heartsim scenario.h5                      open a window and simulate (same as `heartsim run`)\n"
                 "  heartsim run scenario.h5 --headless --steps 500 --screenshot out.png --stats\n"
                 "  heartsim info                             the OpenGL device, version and limits\n"
                 "  heartsim recover rec.h5.journal           the recording of a --record session that was killed\n"
                 "  heartsim plan-incision scenario.h5 -o incision.csv   a scripted incision with retractors, for run --trajectory\n"
                 "  heartsim plan-repair scenario.h5 -o repair.csv       a patch stitched over a septal defect, for run --trajectory\n"
                 "  heartsim plan-operation scenario.h5 -o op.csv --approach all   the operation through an incision, both approaches\n",
                 "heartsim"};
    app.set_version_flag("--version", std::string("heartsim ") + HEARTSIM_VERSION);
    app.require_subcommand(1);
    auto* info = app.add_subcommand("info", "Print the OpenGL renderer, version and limits (headless EGL), and a verdict: which backend "
                                            "a session will use here and the real-time factor measured on SCENARIO (or, without one, on "
                                            "a block of 30,000 particles)");
    std::string info_scenario;
    info->add_option("scenario", info_scenario, "A scenario to measure the verdict on (heartprep build); default: a uniform block");
    RunArguments a;
    CLI::App* run = add_run_command(app, a);
    std::string journal, recovered;
    CLI::App* recover = add_recover_command(app, journal, recovered);
    PlanIncisionArguments plan;
    CLI::App* plan_command = add_plan_incision_command(app, plan);
    PlanRepairArguments repair;
    CLI::App* repair_command = add_plan_repair_command(app, repair);
    PlanOperationArguments operation;
    CLI::App* operation_command = add_plan_operation_command(app, operation);
    std::vector<char*> arguments(argv, argv + argc);
    if (const std::optional<int> refused = insert_run_word(app, argc, argv, arguments)) return *refused;
    for (CLI::App* command : app.get_subcommands({})) command->footer(command->get_footer() + "\n" + heartsim_exit_status_help);
    cli_messages::require_finite_numbers(app);
    app.footer(heartsim_exit_status_help);
    // Every failure is one line `heartsim: error: FILE: what` and an exit status of the table in
    // cli/exit_codes.h (docs/user-guide.md, "Exit status"); an option the runtime's parts name by
    // its meaning is spelled as heartsim's flag (cli/option_flags.h).
    auto fail = [](ExitCode code, const std::string& message) {
        std::fprintf(stderr, "heartsim: error: %s\n", one_line(cli::spell_options(message, cli::heartsim_flags)).c_str());
        return exit_status(code);
    };
    try {
        app.parse(int(arguments.size()), arguments.data());
    } catch (const CLI::ParseError& e) {
        if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
        // Not CLI11's two lines and its own exit codes (104-114).
        return fail(ExitCode::usage, cli_messages::parse_error_message(app, e, int(arguments.size()), arguments.data()));
    }
    for (const CLI::App* command : {static_cast<const CLI::App*>(run), static_cast<const CLI::App*>(recover),
                                    static_cast<const CLI::App*>(plan_command), static_cast<const CLI::App*>(repair_command),
                                    static_cast<const CLI::App*>(operation_command)})
        if (const std::string empty = cli_messages::empty_value_given(*command); command->parsed() && !empty.empty())
            return fail(ExitCode::usage, empty);
    for (const char* option : {"--max-force", "--haptic-rate", "--interpolation", "--haptic-priority", "--coupling"})
        if (run->count(option) > 0) a.device_options_given.push_back(option);
    // The file an error that names none comes from: the scenario run, or the journal recovered.
    const std::string file = run->parsed() ? a.scenario : recover->parsed() ? journal : plan_command->parsed() ? plan.scenario
                           : repair_command->parsed() ? repair.scenario : operation_command->parsed() ? operation.scenario : "";
    try {
        if (info->parsed()) return command_info(info_scenario);
        if (recover->parsed()) return recover_recording(journal, recovered);
        if (run->parsed()) return command_run(a);
        if (plan_command->parsed()) return plan_incision_command(plan);
        if (repair_command->parsed()) return plan_repair_command(repair);
        if (operation_command->parsed()) return plan_operation_command(operation);
    } catch (const GlUnavailable& e) {
        return fail(ExitCode::no_opengl, e.what());
    } catch (const haptics::DeviceUnavailable& e) {
        return fail(ExitCode::haptic_device, e.what());
    } catch (const OptionError& e) {
        return fail(ExitCode::usage, e.what());
    } catch (const InputError& e) {
        return fail(ExitCode::input_error, with_file(file, e).what());
    } catch (const OutputError& e) {
        return fail(ExitCode::internal_error, e.what());
    } catch (const std::exception& e) {
        // Out of memory (an allocation, a thread that could not start, HDF5's own allocations):
        // one line saying so, whatever the library's words were.
        if (is_out_of_memory(e)) return fail(ExitCode::internal_error, std::string("out of memory while ") + activity);
        return fail(ExitCode::internal_error, e.what());
    }
    return exit_status(ExitCode::success);
}
