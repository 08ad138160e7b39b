/// @file recording.h
/// @brief The haptic session recording `heartsim run … --device … --record OUT.h5` writes, and
/// `heartsim run SCENARIO.h5 --replay OUT.h5` replays. HDF5, written atomically. Two time lines:
/// the device thread's ticks (what each device did and was sent) and the simulation's steps
/// (the tool poses each step used and the forces it published), plus events. Layout
/// (docs/haptics.md "Recording"):
///   root attrs  format = "heartsim.recording", format_version = 1, units = "mm g ms N", frame = "LPS",
///               scenario (file name), particles, dt_ms, substeps, backend, contact, rate_hz,
///               interpolation, arithmetic, coupling (0/1), patch_material (absent in recordings made
///               before it was kept: pericardium), period_p50_ms, period_p99_ms, period_max_ms,
///               period_mean_ms, periods, overruns, latency_p50_ms, latency_p99_ms, latency_max_ms
///   /rules      attrs: the solver's instrument and watchdog rules of the recording build
///               (libmodel/sim/solver_options.h SolverRules; absent in recordings made before heartsim kept them)
///   /hand0, /hand1 (a hand with a device)   attrs: device (the --device spec), device_name,
///               instrument ("probe" | "grabber" | "retractor" | "scalpel" | "patch" | "needle"), semi_axes_mm [3], max_force_n,
///               mapping_offset_mm [3], mapping_rotation [4] (w, x, y, z), mapping_scale, force_scale
///     tick_time_ms   float64 [T]      session clock of each device-thread tick
///     position_mm    float64 [T,3]    device pose (device frame)
///     orientation    float64 [T,4]    w, x, y, z
///     buttons        uint32  [T]
///     input_n        float64 [T,3]    force before the safety chain (device frame)
///     force_n        float64 [T,3]    force sent to the device
///     gain           float32 [T]      safety gain 0…1
///   /steps
///     time_ms        float64 [S]      simulated time at the end of the step
///     wall_ms        float64 [S]      session clock when the step's forces were published
///     tool_time_ms   float64 [S]      session clock of the tool sample the step used
///     tool_position_mm float64 [S,2,3]  tool pose per hand (world frame) used by the step
///     tool_orientation float64 [S,2,4]
///     grab           int8    [S,2]    1 while the hand's grabber held during the step (0 or 1; only a hand whose kind takes a grab)
///     applied        int8    [S,2]    1 when the step applied the hand's tool (0 before its first pose)
///     force_n        float64 [S,2,3]  forces published after the step (world frame)
///     force_step     int64   [S]      the step whose state those forces came from (−1: none yet)
///     diverged       int8    [S]      the step hit the watchdog
///     mass_scale     float64 [S]      the explicit mass scaling S the step ran with (absent in
///                                     recordings made before heartsim scaled mass: 1 throughout)
///     instrument     int8    [S,2]    the instrument each hand held during the step (libmodel/sim/solver.h instrument_code:
///                                     0 none, 1 probe, 2 grabber, 3 scalpel, 4 patch, 5 needle, 6 retractor; the
///                                     window's K, Shift + P and Shift + N change it) and
///     semi_axes_mm   float64 [S,2,3]  its semi-axes (both absent in recordings made before an instrument
///                                     could change inside one: the hand's attributes throughout)
///   /events
///     time_ms float64 [E], hand int32 [E] (−1: both), what (UTF-8 strings) [E]
#pragma once

#include "formats/atomic_file.h"

#include "libmodel/sim/solver.h"

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

struct RecordedHand {
    bool used = false;
    std::string device;       ///< the --device spec, e.g. "simulated:samples/haptics/press.csv"
    std::string device_name;  ///< what the device calls itself
    std::string instrument;   ///< "probe", "grabber", "retractor", "scalpel", "patch" or "needle"
    std::array<double, 3> semi_axes_mm{};
    double max_force_n = 0.0;
    /// Device frame → world: x_w = offset + scale·R·x_d (R from the quaternion w, x, y, z);
    /// forces back scaled by force_scale.
    std::array<double, 3> mapping_offset_mm{};
    std::array<double, 4> mapping_rotation{1.0, 0.0, 0.0, 0.0};
    double mapping_scale = 1.0, force_scale = 1.0;
    std::vector<double> tick_time_ms;
    std::vector<std::array<double, 3>> position_mm;
    std::vector<std::array<double, 4>> orientation;  ///< w, x, y, z
    std::vector<std::uint32_t> buttons;
    std::vector<std::array<double, 3>> input_n;
    std::vector<std::array<double, 3>> force_n;
    std::vector<float> gain;
};

struct RecordedSteps {
    std::vector<double> time_ms, wall_ms, tool_time_ms;
    std::vector<std::array<std::array<double, 3>, 2>> tool_position_mm;
    std::vector<std::array<std::array<double, 4>, 2>> tool_orientation;
    std::vector<std::array<std::int8_t, 2>> grab;
    std::vector<std::array<std::int8_t, 2>> applied;
    std::vector<std::array<std::array<double, 3>, 2>> force_n;
    std::vector<std::int64_t> force_step;
    std::vector<std::int8_t> diverged;
    /// The mass scale each step ran with (SolverOptions::mass_scale); empty: 1 throughout.
    std::vector<double> mass_scale;
    std::size_t size() const { return time_ms.size(); }
    /// The mass scale of step k (1 where the column is empty).
    double mass_scale_at(std::size_t k) const { return mass_scale.empty() ? 1.0 : mass_scale[k]; }
    /// The instrument each hand held during the step (instrument_code) and its semi-axes, mm;
    /// both empty: the hands' attributes throughout (Recording::instrument_at).
    std::vector<std::array<std::int8_t, 2>> instrument;
    std::vector<std::array<std::array<double, 3>, 2>> semi_axes_mm;
};


struct RecordedEvent {
    double time_ms = 0.0;
    int hand = -1;
    std::string what;
};

/// What a replay of a recording without /rules takes: the rules heartsim had before the probe's
/// pierce and the one-piece grab, with the speed bound at 2 (since the slip at 2 and the restore
/// bound at 1 of docs/benchmarks.md "Soak"). The recordings made with the pierce and the
/// one-piece grab but before /rules replay the same wherever neither acted.
SolverRules rules_before_recorded();
/// Empty when the rules are ones a solver takes, else which is wrong and what was expected.
std::string check_rules(const SolverRules& rules);

/// What is wrong with one hand's entry of a step's instrument columns: `dataset` ("instrument" or
/// "semi_axes_mm") and `what` (to follow the row's name); an empty `what` when it is one a recording
/// holds: a code 0 … 6, none exactly where the hand has no device, semi-axes in range where it
/// holds an instrument. The recording's and the journal's readers both ask it.
struct StepInstrumentFault {
    const char* dataset = "";
    std::string what;
};
StepInstrumentFault check_step_instrument(std::int8_t code, const std::array<double, 3>& semi_axes_mm, bool hand_used);

struct Recording {
    std::string scenario;
    std::int64_t particles = 0;
    double dt_ms = 0.0;  ///< the scenario's step at mass scale 1 (a step at S is longer: stability.h scaled_step_ms)
    std::int32_t substeps = 0;
    std::string backend, contact, interpolation;
    /// The spring slot's multiply-adds in the recorded run: "fused", or "separate" (the sse2
    /// kernel, and every recording made before they were fused, which has no such attribute). A
    /// cpu replay takes the same, so that it reproduces the forces to the bit (docs/haptics.md).
    std::string arithmetic = "fused";
    /// --patch-material of the session (libmodel/surgery/patch.h patch_material_named), which a replay lays.
    std::string patch_material = "pericardium";
    /// nullopt: made before recordings kept their rules (replayed with rules_before_recorded()).
    std::optional<SolverRules> rules;
    double rate_hz = 0.0;
    bool coupling = false;
    double period_p50_ms = 0, period_p99_ms = 0, period_max_ms = 0, period_mean_ms = 0;
    std::int64_t periods = 0, overruns = 0;
    double latency_p50_ms = 0, latency_p99_ms = 0, latency_max_ms = 0;
    std::array<RecordedHand, 2> hands;
    RecordedSteps steps;
    std::vector<RecordedEvent> events;
    /// The instrument `hand` held during step k: /steps/instrument and /steps/semi_axes_mm, or
    /// without them the hand's attributes.
    Instrument instrument_at(std::size_t k, int hand) const;
};

/// Whether `arithmetic` is one Recording::arithmetic takes ("fused" or "separate"); the recording's
/// and the journal's readers refuse any other.
inline bool known_arithmetic(const std::string& arithmetic) { return arithmetic == "fused" || arithmetic == "separate"; }

/// Writes atomically, then the XDMF description beside it (xdmf.h: `rec.h5` → `rec.xmf2`, a
/// time series for ParaView); throws OutputError naming the file. `check`, when given, reads the
/// complete temporary file before it takes the name (`heartsim recover` reads it back as a
/// recording), and what it throws leaves no file.
void write_recording(const std::filesystem::path& path, const Recording& recording,
                     const std::function<void(const std::filesystem::path&)>& check = {});
/// The HDF5 file (atomically, `check` as above), with `beside` (write_recording's .xmf2) or alone.
void write_recording_data(const std::filesystem::path& path, const Recording& recording,
                          const std::function<void(const std::filesystem::path&)>& check = {}, const std::vector<FileBeside>& beside = {});
/// Reads and validates (shapes agree, values finite where they must be); throws InputError
/// naming the file and the dataset.
Recording read_recording(const std::filesystem::path& path);

}  // namespace heartsim
