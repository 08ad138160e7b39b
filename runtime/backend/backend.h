/// @file backend.h
/// @brief The simulation behind one interface: `cpu` (libmodel's Solver, the reference) and
/// `gl` (compute shaders on the same packed layout; runtime/gl/backend_gl.h). This interface is
/// the tissue's and knows no GL, no device and no surgery: the gl part (heartsim_gl) builds on it,
/// and a surgery's needs come through its one extension, surgery() (runtime/backend/surgery.h). Both do
/// the same step with the same formulas, instrument semantics and force sign (docs/solver.md,
/// docs/runtime.md "The backend interface").
///
///     auto backend = make_gl_backend(gl, scenario, options_from(scenario.solver));  // runtime/gl/backend_gl.h
///     backend->set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = {2, 2, 6}});
///     backend->set_pose(0, pose);
///     backend->step(1);                                 // one step of dt_ms (its substeps inside)
///     backend->request_forces();                       // asynchronous, both hands
///     if (auto f = backend->latest_forces()) use(*f);  // never waits
#pragma once

#include "formats/scenario.h"
#include "libmodel/sim/solver.h"
#include "runtime/backend/contact.h"

#include "libmodel/errors.h"

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

class SurgerySupport;  // runtime/backend/surgery.h

enum class BackendKind { cpu, gl };
/// "cpu" or "gl"; throws InputError otherwise.
BackendKind parse_backend_kind(const std::string& name);
const char* to_string(BackendKind kind);

/// For the messages that say a run is slower than real time: the particle count that would keep
/// up here, from the measured real-time factor `factor` with `particles` particles, and, on the
/// cpu backend, a GPU. A simulated second costs about particles^(4/3) (particles per substep, and
/// the stable substep shrinks with the lattice spacing, particles^(−1/3)); the count is rounded
/// down to two significant digits and leaves 10 % of margin. One clause: "heartprep build
/// --particles 19000 would keep up here, or the gl backend on a GPU". On the gl backend over a
/// software rasteriser (`software_gl`) the backend comes first: "--backend cpu (faster than
/// OpenGL on a software rasteriser), or heartprep build --particles …".
std::string keep_up_advice(double factor, std::size_t particles, BackendKind kind, bool software_gl = false);

/// Time spent per pass, ms, summed over the run (GPU timer queries for gl, wall clock for cpu).
struct PassTimes {
    double step_ms = 0.0;          ///< simulation substeps: springs, integration, probe projection, grab follow
    double force_ms = 0.0;         ///< force buffer: both instruments' forces
    long long step_calls = 0;      ///< step() calls measured
    long long substeps = 0;        ///< substeps measured
    long long force_calls = 0;     ///< force passes measured
    double picking_ms = 0.0;       ///< probe contact search (picking buffer render + collect, or the direct search pass)
    long long picking_calls = 0;   ///< contact passes measured (both probes of one force request: one call)
    long long picking_renders = 0; ///< picking-buffer renders (one per probe every K force requests)
    bool gpu_timed = false;        ///< true when the figures come from GPU timer queries
};

class Backend {
public:
    virtual ~Backend() = default;
    virtual BackendKind kind() const = 0;
    virtual std::size_t size() const = 0;                  ///< particles
    virtual const SolverLoadReport& load_report() const = 0;
    virtual const SolverOptions& options() const = 0;        ///< the options it was made with
    virtual double time_step_ms() const = 0;               ///< one step()
    virtual double substep_ms() const = 0;
    virtual int substeps_per_step() const = 0;
    virtual double simulated_time_ms() const = 0;

    /// Hand 0 or 1; as Solver::set_instrument / set_pose / begin_grab / release.
    virtual void set_instrument(int hand, const Instrument& instrument) = 0;
    virtual void set_pose(int hand, const InstrumentPose& pose) = 0;
    /// Captures the free particles inside the grabber or retractor; returns how many (gl: one
    /// small readback).
    virtual std::size_t begin_grab(int hand) = 0;
    /// Ends a grab or lifts a blade. A retractor's particles stay anchored where they are, at
    /// rest, until reset_tissue() or the watchdog's restore (Solver::release; gl: one small
    /// readback of the held list); set_instrument() on a retractor that holds does the same.
    virtual void release(int hand) = 0;

    /// The tissue back to its rest state (rest positions, at rest, grabs released, loads removed,
    /// what retractors left in place free again: the scenario's anchoring); the simulated time and
    /// the instruments are kept.
    virtual void reset_tissue() = 0;
    /// Explicit mass scaling S in [1, 1024] from the next step on (Solver::set_mass_scale): the
    /// substeps, the load report's critical steps and options().mass_scale follow; positions and
    /// velocities are kept. Throws InputError outside the range (nothing changed then).
    virtual void set_mass_scale(double mass_scale) = 0;
    /// Advances `steps` steps of time_step_ms(). gl: queued on the GPU, returns at once.
    virtual StepReport step(int steps = 1) = 0;

    /// Queues the force pass for both hands on the current state (gl: into a persistent mapped
    /// ring, fenced); latest_forces() returns the newest finished one without waiting.
    virtual void request_forces() = 0;
    virtual std::optional<InstrumentForces> latest_forces() = 0;
    /// The request number (0, 1, … in request_forces() order) of what latest_forces() returned
    /// last; meaningful once it returned a value.
    virtual std::uint64_t latest_forces_request() const = 0;
    /// Both hands' forces on the current state, N, world frame (the force the tissue exerts on
    /// the instrument, docs/solver.md). Waits for the GPU.
    virtual InstrumentForces instrument_forces() = 0;
    /// The springs a scalpel cut so far (Solver::cut_springs), each as its two packed particle
    /// indices, lower first, sorted. Waits for the GPU.
    virtual std::vector<std::array<std::int32_t, 2>> cut_springs() = 0;
    /// The scalpel strokes so far, pose for pose as the cut pass swept them (the detailed mesh's
    /// incision is built from them, libmodel/surgery/incision_state.h). Never waits.
    virtual const StrokeLog& strokes() const = 0;
    /// Current positions, N×3 mm, packed order. Waits for the GPU.
    virtual std::vector<std::array<float, 3>> positions() = 0;
    /// Pass timings so far (waits for outstanding timer queries).
    virtual PassTimes pass_times() = 0;
    /// Bytes of device memory the backend allocated (gl), or of its own arrays (cpu).
    virtual std::size_t memory_bytes() const = 0;
    /// Whether it simulates on a software rasteriser (the gl backend over Mesa's llvmpipe).
    virtual bool software_device() const { return false; }
    /// How the force pass finds a probe's contact particles (runtime/backend/contact.h): gl only; the cpu
    /// backend always uses its solver's touched list (`direct`) and rejects the others.
    virtual void set_contact(const ContactSettings& settings) {
        if (settings.mode != ContactMode::direct) throw InputError("--contact picking|search needs --backend gl");
    }
    /// The particles the last force pass summed for `hand`, sorted (gl: waits for the GPU).
    virtual std::vector<std::int32_t> contact_particles(int hand) { (void)hand; return {}; }
    /// The backend that simulates: itself, or the one a wrapper (runtime/backend/backend_wrapper.h) passes
    /// its calls to; the renderer reads the gl backend's position buffer through it
    /// (gl_position_buffer takes the backend returned here whose kind() is gl for the gl backend,
    /// so a wrapper, which says its inner backend's kind, must pass this on too).
    virtual const Backend& simulating() const { return *this; }
    /// The one extension for a surgery on the tissue (runtime/backend/surgery.h: a few particles' positions,
    /// loads on them, a task beside a step, the device's patch pass, the repair riding on the hands),
    /// or nullptr where the backend offers none.
    virtual SurgerySupport* surgery() { return nullptr; }
};

/// The CPU backend: libmodel's Solver on the scenario's packed particles. Throws InputError if
/// the scenario has no /packing.
std::unique_ptr<Backend> make_cpu_backend(const Scenario& scenario, const SolverOptions& options);

/// Throws InputError naming the entry and the index unless every one of `particles` is in
/// [0, particle_count): SurgerySupport::positions_of's check, on both backends.
void check_particle_indices(const std::vector<std::int32_t>& particles, std::size_t particle_count);

/// Throws InputError naming the group when the scenario lacks what a run needs (/packing).
void require_runnable(const Scenario& scenario, const std::string& file_name);

}  // namespace heartsim
