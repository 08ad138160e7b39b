/// @file backend_gl_impl.h
/// @brief The gl backend's class (runtime/gl/backend_gl.h), shared by the three files that define
/// it and included by nothing else: backend_gl.cpp (the hands, the forces, loads and positions,
/// contact), backend_gl_build.cpp (its buffers and programs from the scenario, the constants of
/// the step) and backend_gl_step.cpp (the step, the scalpel's cut, the watchdog). Every pass reads
/// and writes the same buffers and hand state, kept here. Shaders and the arithmetic contract:
/// shaders/solver_shaders.h; design and deviations: docs/runtime.md.
#pragma once

#include "runtime/gl/backend_gl.h"
#include "runtime/gl/gl_object.h"
#include "runtime/gl/gl_program.h"
#include "runtime/gl/picking.h"
#include "runtime/gl/shaders/bindings.h"
#include "runtime/gl/shaders/solver_shaders.h"
#include "runtime/backend/patch_stepper.h"
#include "runtime/backend/surgery.h"

#include "libmodel/sim/cutting.h"
#include "libmodel/sim/cutting_force.h"

#include <epoxy/gl.h>

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim::gl_backend {

namespace sh = gl_shaders;
constexpr int slot_count = 18, lane_count = 8, hands = 2;
constexpr int ring_slots = 4;              // force readbacks in flight
constexpr GLsizeiptr ring_stride = 256;    // ≥ GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT everywhere we know
constexpr int status_slots = 8;            // watchdog status readbacks in flight (one per step)
constexpr long long snapshot_substeps = 64;  // substeps between restore-point candidates, as the cpu watchdog_interval

using gl::Buffer;
/// A compute program and its uniform lookup.
struct Program {
    gl::Program id;
    GLint at(const char* name) const { return glGetUniformLocation(id, name); }
};

using gl::storage;

/// The entry of particle i's slot s in the gl per-entry tables ([group of 8][slot][lane]).
constexpr std::size_t table_entry(std::size_t i, int s) { return (i / lane_count * slot_count + std::size_t(s)) * lane_count + i % lane_count; }

struct ForceSlot {
    double force[2][4];     ///< each hand's force in x, y, z, N; w is 0 (the count has its own word)
    std::uint32_t status;
    std::uint32_t sequence;
    std::uint32_t cuts[2];  ///< springs each hand's blade cut in the step the forces are from
    std::uint32_t counts[2];  ///< particles each hand's force sums (held or touched)
    double blade[2][6];     ///< each hand's BladeState: energy, travel, velocity x, y, z, speed
};
static_assert(sizeof(ForceSlot) == 184 && sizeof(ForceSlot) <= std::size_t(ring_stride));  // std430 ForceBuffer

/// One entry of set_loads's scatter list (std430 `LoadEntry`, shaders/solver_shaders.h load_scatter).
struct LoadEntry {
    std::int32_t particle;
    float force[3];  ///< N; zero for a particle the new list drops
};
static_assert(sizeof(LoadEntry) == 16);

class GlBackend final : public Backend, public SurgerySupport {
public:
    bool software_device() const override { return software_; }
    void set_software(bool software) { software_ = software; }
    GlBackend(const Scenario& scenario, const SolverOptions& options);
    ~GlBackend() override;

    BackendKind kind() const override { return BackendKind::gl; }
    std::size_t size() const override { return n_; }
    const SolverLoadReport& load_report() const override { return load_report_; }
    const SolverOptions& options() const override { return options_; }
    double time_step_ms() const override { return dt_ms_; }
    double substep_ms() const override { return h_; }
    int substeps_per_step() const override { return substeps_; }
    double simulated_time_ms() const override { return time_ms_; }
    std::size_t memory_bytes() const override { return memory_bytes_; }
    unsigned position_buffer() const { return position_[current_].id(); }

    void set_instrument(int hand, const Instrument& instrument) override;
    void set_pose(int hand, const InstrumentPose& pose) override;
    std::size_t begin_grab(int hand) override;

    /// The captured list (in the atomics' order) in ascending particle order, as the cpu solver
    /// holds it, and only the piece of tissue the cpu solver keeps (SolverOptions::grab_reach,
    /// libmodel grab_piece, on host copies of the rest positions): the others are freed by the
    /// release pass run over just them. Returns the count kept.
    GLuint keep_one_piece(int hand, GLuint count);
    void release(int hand) override;
    /// release() with `stay`: a retractor's held particles anchored in place (anchor_held) before
    /// the release pass frees the list; false: freed, as place_tissue releases.
    void release_hand(int hand, bool stay);
    /// Solver::release_hand's stay on the device: reads the hand's held list back (one small
    /// readback) and writes each particle's constants (not movable, h²/m 0, no support spring)
    /// and zero motion into both motion buffers; the host copies follow (stayed_).
    void anchor_held(int hand);
    /// The stayed particles' constants as loaded again, uploaded (upload_step_constants).
    void free_stayed();

    /// 1 − γh/S, as Solver's kernel constants (the drag force γ·m·v on the inertia S·m).
    float keep() const { return float(1.0 - options_.damping * h_ / options_.mass_scale); }

    void set_mass_scale(double mass_scale) override;

    /// The constants that depend on h and the mass scale (Solver::build_step_constants, and the
    /// start motion of reset()): h²/(S·m), the support and spring dashpots c/h, u₀ = −½·a·h².
    void upload_step_constants();
    void reset_tissue() override;
    StepReport step(int steps) override;

    /// Neither hand holds anything the tissue feels (a repair's patch and needle hands): the forces
    /// are zero, and a request needs no pass.
    bool no_instruments() const {
        return hand_[0].instrument.kind == InstrumentKind::none && hand_[1].instrument.kind == InstrumentKind::none;
    }

    void request_forces() override;

    std::uint64_t latest_forces_request() const override { return latest_sequence_; }

    std::optional<InstrumentForces> latest_forces() override;
    InstrumentForces instrument_forces() override;

    /// Solver::cut on the gpu: the cut pass over the current positions, queued; the springs cut
    /// are counted into the hand's counter word (cleared by the caller).
    void cut(const BladeSweep& sweep, int hand);

    /// The scalpel's state after its cut (Solver::step: next_blade_state with `r`), queued: one
    /// invocation reads the hand's cut counter and updates its state in the counter words.
    void blade(int hand, const BladeStep& r);

    /// The hand's cut counter and blade state to zero (a lifted blade, a new instrument, a reset).
    void clear_blade(int hand);

    const StrokeLog& strokes() const override { return strokes_; }

    std::vector<std::array<std::int32_t, 2>> cut_springs() override;
    std::vector<std::array<float, 3>> positions() override;
    void set_loads(const std::vector<ParticleLoad>& loads) override;
    std::vector<std::array<float, 3>> positions_of(const std::vector<std::int32_t>& particles) override;
    void set_contact(const ContactSettings& settings) override;
    std::vector<std::int32_t> contact_particles(int hand) override;
    PassTimes pass_times() override;

    SurgerySupport* surgery() override { return this; }
    /// The task, then the step: the patch pass it queues runs on the GPU before the tissue's.
    StepReport step_after(const std::function<void()>& task) override;
    PatchStepper* patch_stepper() override;

private:
    bool software_ = false;  ///< the context's device is a software rasteriser (keep_up_advice)
    struct HandState {
        Instrument instrument;
        InstrumentPose pose, target;
        bool grabbing = false, placed = false;
        bool cutting = false;  ///< a scalpel between begin_grab and release
    };
    struct Pending {
        std::array<gl::Query, 2> queries;
        bool is_force = false;
        bool is_picking = false;
        long long substeps = 0;
    };

    /// No loads: the load buffer back to zero, the step pass no longer reads it.
    void clear_loads();

    /// The force pass reads the picking / search list (not the step's touched list) for probes.
    bool listed_contacts() const { return contact_.mode != ContactMode::direct && picking_; }

    /// picking or search: each probe's contact list for the force pass, timed as one call.
    void run_contact_search();

    static void check_hand(int hand) {
        if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    }

    static void check(const char* what) { check_gl_error("gl backend", what); }

    void set_indexed_1f(GLuint program, const std::string& name, int index, float value) {
        glProgramUniform1f(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), value);
    }
    void set_indexed_3dv(GLuint program, const std::string& name, int index, const double* value) {
        glProgramUniform3dv(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), 1, value);
    }
    void set_indexed_matrix(GLuint program, const std::string& name, int index, const double* column_major);
    InstrumentForces read_slot(int slot);

    /// After a step: copies the sticky status word into the next status slot behind a fence, and
    /// every snapshot_substeps substeps takes the state as a restore-point candidate, with its
    /// largest spring stretch (strain_pass) beside the status. The candidate becomes the restore
    /// point once that slot comes back clean and its stretch within restore_strain_limit, as the
    /// cpu solver's rule: a torn state is stepped on from but never returned to. A full ring
    /// skips a step.
    void queue_status();

    /// Reads the finished status slots in order without waiting; true at the first that shows a
    /// divergence. The candidate's slot drops it when its stretch is past the limit; a clean slot
    /// at or after the candidate's makes it the restore point.
    bool poll_status();

    /// Drops every status slot and candidate in flight (they belong to a state that is gone).
    void forget_status();

    /// The last verified state, at rest, grabs released, the status cleared; as Solver::restore.
    /// Grabs released (a retractor's tissue freed, not stayed), what retractors left anchored free
    /// again, the tissue at `positions` (both buffers) with `motion` (null: at rest), the
    /// touched lists and the watchdog status cleared, nothing of the old state in flight. The
    /// one way reset_tissue() and restore() put the tissue somewhere.
    void place_tissue(const Buffer& positions, const Buffer* motion);
    void restore(StepReport& report);
    void harvest_queries(bool wait);
    void bind_common();

    /// The tables of libmodel/sim/solver.cpp's constructor, built the same way (same slot search,
    /// same rounding of the dashpot and h²/m from double).
    void build_buffers(const Scenario& scenario);
    SolverOptions options_;
    SolverLoadReport load_report_;
    std::size_t n_ = 0, n_pad_ = 0, memory_bytes_ = 0;
    double dt_ms_ = 0, h_ = 0, time_ms_ = 0;
    int substeps_ = 1;
    float min_rest_length_ = 0;
    float max_rest_length_ = 0;
    bool damped_ = false;
    bool supported_ = false;
    std::array<HandState, hands> hand_{};

    /// Positions and the motion of the last substep (u = x_n − x_{n−1}), two buffers each: index
    /// current_ is read by a substep, next_ written; they swap after it.
    Buffer position_[2], motion_[2], rest_current_, rest_motion_;
    int current_ = 0, next_ = 1;
    Buffer neighbour_, rest_length_, stiffness_, dashpot_, particle_, held_by_, counters_, touched_, held_, held_local_, ring_;
    /// External loads: `load_` per padded particle (N, zero where none); set_loads's scatter list;
    /// positions_of's indices and positions. The two lists grow on demand.
    Buffer load_, load_list_, gather_index_, gathered_;
    /// Per padded particle, double: how far an instrument reaches beyond it (Solver::reach_beyond,
    /// from the scenario's contact skin); the largest, for the probes' bounding spheres.
    Buffer skin_;
    std::vector<double> reach_beyond_;
    double max_reach_beyond_ = 0.0;
    std::size_t load_list_bytes_ = 0, gather_capacity_ = 0;
    std::vector<std::int32_t> load_particles_;  ///< the particles of the loads in force, ascending
    std::unique_ptr<PatchStepper> patch_pass_;  ///< a sewn patch's pass, made on first use (patch_pass.h)
    bool patch_pass_refused_ = false;           ///< the driver could not build it
    bool patch_loads_ = false;                  ///< the patch's pass has loads on the tissue
    std::vector<float> rest_position_;  ///< 3 per particle, host copy for begin_grab
    /// Host copies of what upload_step_constants() derives the h- and S-dependent constants from.
    struct ParticleConstants { float mass, inverse_mass_h2; std::int32_t movable; float support_stiffness; float support_point[4]; };
    static_assert(sizeof(ParticleConstants) == 32);  // std430 `Particle` in shaders/solver_shaders.h
    std::vector<ParticleConstants> particle_host_;
    std::vector<std::int32_t> stayed_;                ///< particles a retractor left anchored in place (anchor_held)
    std::vector<ParticleConstants> stayed_constants_; ///< their host constants as loaded, to free them
    std::vector<double> support_damping_host_;  ///< c_s per particle, N·ms/mm (0 where unsupported)
    std::vector<std::int32_t> uncut_neighbour_;  ///< the neighbour table as loaded (reset_tissue heals cuts)
    StrokeLog strokes_;  ///< what the scalpels swept (Backend::strokes)
    bool blade_swept_ = false;  ///< a cut pass ran since the tissue was last whole (a grab then reads the table)
    std::vector<float> dashpot_host_;           ///< c per table entry, N·ms/mm, rounded to float as the table's
    Program step_program_, after_program_, capture_program_, release_program_, force_program_, strain_program_, cut_program_,
        blade_program_, scatter_program_, gather_program_, cell_program_;
    /// The volume term (libmodel/volume_cells.h), as the reference solver holds it: per cell its
    /// corners, k12 and 12·V0 and its springs' table entries; per padded particle the 8 slots of
    /// its cells' forces, which the step pass adds to its load.
    Buffer cell_corner_, cell_constants_, cell_spring_, cell_force_;
    std::size_t cell_count_ = 0;
    std::vector<std::array<std::int32_t, 8>> cell_corner_host_;
    std::vector<float> cell_constants_host_;  ///< k12, 12·V0 per cell
    std::vector<std::array<std::int8_t, 24>> cell_spring_slot_host_;  ///< each cell's springs' table slots (Solver::volume_cell_spring_slots)
    /// The cells' forces at the current positions (the bound position buffer) into cell_force_.
    void run_cell_pass();
    /// The step pass's `loaded`: the volume term, a load or the patch's loads.
    void update_loaded();
    LatticeFrame lattice_frame_;  ///< the reference solver's (Solver::lattice_frame)
    void* ring_map_ = nullptr;
    std::array<gl::Fence, ring_slots> fences_;
    std::array<std::uint64_t, ring_slots> sequence_of_{};
    std::uint64_t next_sequence_ = 0, latest_sequence_ = 0;
    std::optional<InstrumentForces> latest_;
    // Watchdog (queue_status, poll_status, restore).
    Buffer good_position_, candidate_position_, status_ring_;
    void* status_map_ = nullptr;
    std::array<gl::Fence, status_slots> status_fences_;
    std::uint64_t status_sequence_ = 0, polled_sequence_ = 0, candidate_slot_sequence_ = 0;
    double good_time_ms_ = 0.0, candidate_time_ms_ = 0.0;
    bool candidate_pending_ = false;
    long long substeps_since_snapshot_ = 0;
    int consecutive_restores_ = 0;
    std::deque<Pending> pending_;
    PassTimes times_;
    std::optional<SimulationSurface> surface_;
    double lattice_spacing_ = 1.0;
    ContactSettings contact_;
    std::unique_ptr<PickingPass> picking_;
};

}  // namespace heartsim::gl_backend
