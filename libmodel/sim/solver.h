/// @file solver.h
/// @brief The CPU spring-mass solver: Verlet integration of M ẍ = f_spring + f_damping + f_ext
/// on the packed particle layout, driven by the 18-slot neighbour table; two instruments (probe
/// and grabber) with haptic forces; a watchdog that never lets a non-finite value out.
/// The reference every backend is checked against and the fallback where there is no GPU.
/// Formulas, sign conventions and the memory layout: docs/solver.md.
///
/// Units: mm, g, ms; force N (g·mm/ms²), stiffness N/mm, energy mJ (N·mm). World frame LPS.
///
///     Solver solver(lattice, packing.neighbours, {.dt_ms = scenario.solver.dt_ms});
///     solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = {2, 2, 6}});
///     solver.set_pose(0, {.position = tip, .orientation = q});
///     StepReport report = solver.step(10);
///     InstrumentForces forces = solver.instrument_forces();   // both hands, one call
#pragma once

#include "libmodel/sim/cutting.h"
#include "libmodel/sim/cutting_force.h"
#include "libmodel/instrument_pose.h"
#include "libmodel/lattice.h"
#include "libmodel/sim/solver_options.h"
#include "libmodel/stability.h"
#include "libmodel/volume_cells.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <functional>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {


enum class InstrumentKind {
    none,
    probe,    ///< particles inside the ellipsoid are projected to its boundary after every substep
    grabber,  ///< begin_grab() captures the particles inside; they follow the pose rigidly
    /// A blade from the pose's position (the tip) along the tool's +z axis, 2·az long (ax, ay: its
    /// half-width and half-thickness, for drawing). From begin_grab() until release() each step
    /// cuts, for good, every spring that crosses the surface the blade swept during the step
    /// (cutting.h); lifted, it touches nothing. It neither pushes nor holds tissue; its force is the
    /// tissue's resistance to the cut (cutting_force.h), zero once lifted.
    scalpel,
    /// The repair's hands (runtime/surgery/repair.h): the solver never holds them (a backend passes them on
    /// as none). A patch is laid over the tissue where begin_grab() finds it: its pose's position is
    /// the patch's centre, the tool's +z the way it faces the tissue, ax and ay its half-diameters,
    /// az half its thickness.
    patch,
    /// From begin_grab() a needle ties a stitch between the patch point and the tissue point
    /// nearest its tip (the pose's position); the stitch draws tight over its tying time.
    needle,
    /// A grabber whose tissue stays where it is left (stay sutures tying a retracted edge to the
    /// drape): from begin_grab() until release() exactly a grabber (the same capture, follow and
    /// force). Its release(), or set_instrument() on its hand while it holds, does not free the
    /// particles it holds: they become anchored where they are, at rest, until reset(),
    /// reset_tissue() or the watchdog's restore brings back the scenario's own anchoring.
    retractor,
};

/// "none", "probe", "grabber", "scalpel", "patch", "needle" or "retractor": the word of
/// trajectories, recordings and the window's HUD.
const char* to_string(InstrumentKind kind);
/// The kind to_string() calls `word`; empty for any other word.
std::optional<InstrumentKind> instrument_kind_named(const std::string& word);
/// The kind's code in files (a state's /instrument_kind, a recording's /steps/instrument): 0 none,
/// 1 probe, 2 grabber, 3 scalpel, 4 patch, 5 needle, 6 retractor.
std::int8_t instrument_code(InstrumentKind kind);
/// The kind of a code; nullopt for a code outside 0 … 6.
std::optional<InstrumentKind> instrument_of_code(int code);
/// Whether the kind acts on a grab flag or button 1: a grabber or a retractor holds, a scalpel's
/// blade is lowered, a patch is laid, a needle ties a stitch.
inline bool takes_grab(InstrumentKind kind) { return kind != InstrumentKind::none && kind != InstrumentKind::probe; }
/// Whether begin_grab() captures tissue that then follows the tool: a grabber or a retractor.
inline bool holds_tissue(InstrumentKind kind) { return kind == InstrumentKind::grabber || kind == InstrumentKind::retractor; }
/// The repair's kinds (patch, needle), which the solver never sees.
inline bool repair_kind(InstrumentKind kind) { return kind == InstrumentKind::patch || kind == InstrumentKind::needle; }

/// An instrument's volume: an ellipsoid with semi-axes along the tool frame's x, y, z, mm.
struct Instrument {
    InstrumentKind kind = InstrumentKind::none;
    Eigen::Vector3d semi_axes{2.0, 2.0, 2.0};
    bool operator==(const Instrument& other) const { return kind == other.kind && semi_axes == other.semi_axes; }
};

/// A force on one particle, N, world frame (an external load: a stitch's pull, a patch's contact).
struct ParticleLoad {
    std::int32_t particle = 0;   ///< packed index
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();
};

/// Throws InputError, naming the first offending entry, unless `loads` is sorted by particle with
/// no particle twice, every index in [0, particle_count) and every force finite: the rule of
/// BasicSolver::set_loads and of every backend's.
void check_loads(const std::vector<ParticleLoad>& loads, std::size_t particle_count);

/// The force the tissue exerts on one instrument, N, world frame: the sum of the spring and
/// dashpot forces acting on the particles it holds (grabber) or touched in the last substep
/// (probe). A probe pressed into tissue is pushed back out: the force points from the tissue
/// towards the probe. A scalpel's is the tissue's resistance to the cut, against the blade's
/// motion (cutting_force.h), smoothed over the steps; zero while the blade is lifted. A haptic
/// device renders it as is.
struct InstrumentForce {
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();
    std::size_t particles = 0;  ///< particles held or touched
    std::size_t springs_cut = 0;  ///< a scalpel: springs its blade cut in the last step
};

struct InstrumentForces {
    std::array<InstrumentForce, 2> hand;
};

enum class WatchdogReason { none, non_finite, speed, energy };
const char* to_string(WatchdogReason reason);

/// What step() did.
struct StepReport {
    int steps = 0;                ///< steps completed (each of dt_ms)
    long long substeps = 0;       ///< substeps completed
    bool diverged = false;        ///< the watchdog fired: the state is the last good one, grabs released, at rest
    /// The watchdog fired max_consecutive_restores times in a row without reaching a new restore
    /// point: stepping on would replay the same failure.
    bool gave_up = false;
    WatchdogReason reason = WatchdogReason::none;
    std::string message;          ///< one line: what, when, how large
};

/// Energies, mJ (N·mm), relative to the rest state (elastic 0, gravity potential 0 at rest).
struct SolverEnergy {
    double kinetic = 0.0;
    double elastic = 0.0;         ///< springs and supports (not 0 at rest when pre-stressed)
    double gravity = 0.0;         ///< −Σ m g·(x − x_rest)
    double max_strain = 0.0;      ///< the largest spring strain L/L₀ − 1 (stretch; from the same pass)
    double total() const { return kinetic + elastic + gravity; }
};

struct SolverLoadReport {
    std::size_t particles = 0;
    std::size_t springs = 0;
    std::size_t anchored = 0;
    std::size_t supported = 0;                   ///< free particles with a support spring
    std::size_t table_slots_without_spring = 0;  ///< neighbour-table entries no spring joins (ignored)
    double critical_dt_ms = 0.0;
    double damped_critical_dt_ms = 0.0;          ///< with dashpots and drag (BasicSolver::damped_critical_dt_ms)
    bool critical_dt_estimated = false;          ///< estimated here rather than given
    int substeps = 1;                            ///< per step
    double substep_ms = 0.0;
    SolverKernel kernel = SolverKernel::portable;///< the one chosen
    bool uniform_slots = false;                  ///< rest length and stiffness read as 18 per-slot constants
    /// Explicit mass scaling S (SolverOptions::mass_scale); the critical steps above include it.
    double mass_scale = 1.0;
    double unscaled_critical_dt_ms = 0.0;         ///< the critical steps at S = 1
    double unscaled_damped_critical_dt_ms = 0.0;
    double unscaled_dt_ms = 0.0;                  ///< the step at S = 1 (stability.h scaled_step_ms)
};

/// The step at mass scale `mass_scale` of the network `report` describes (its unscaled critical,
/// damped and step figures) under `options` (safety factor, subdivide): the scaled limits
/// (stability.h scale_time_steps), the step (scaled_step_ms) and its substeps (substeps_for_step).
/// One rule for both backends and for --real-time auto's predictions. Throws InputError for a
/// scale outside [1, 1024] or a step of more than BasicSolver::max_substeps substeps.
struct ScaledStep {
    double critical_dt_ms = 0.0;
    double damped_critical_dt_ms = 0.0;
    double dt_ms = 0.0;
    int substeps = 1;
};
ScaledStep scaled_step(const SolverLoadReport& report, const SolverOptions& options, double mass_scale);

/// begin_grab()'s piece of tissue (SolverOptions::grab_reach), shared by the cpu and gl
/// backends: of the particles captured inside a grabber with `semi_axes` (their tool-frame
/// positions `local` and rest positions `rest`, in ascending particle order), which it keeps:
/// those whose rest position lies within reach × the largest semi-axis of the rest position of
/// the one nearest the centre (in the ellipsoid's scaled metric; the first of equals). reach ≤ 0:
/// all. Where a scalpel cut springs between captured particles, `joined` lists the pairs (rows of
/// `local`) still joined by a spring, and only those reached from that nearest one through them
/// are kept: a grabber over an incision, used as a retractor, takes the side of the particle
/// nearest its centre.
/// Empty `joined`: no spring among them was cut, and the reach alone decides.
std::vector<std::uint8_t> grab_piece(const std::vector<Eigen::Vector3d>& local, const std::vector<Eigen::Vector3d>& rest,
                                     const Eigen::Vector3d& semi_axes, double reach,
                                     const std::vector<std::array<std::int32_t, 2>>& joined = {});

/// For grab_piece: of the captured particles `held` (ascending), the pairs of rows joined by a
/// spring that is not cut, by a neighbour table read as `neighbour(i, slot)` (the particle itself
/// where the slot is empty or cut) and the table as loaded `uncut(i, slot)`; empty when no spring
/// between two captured particles is cut.
template <class Current, class Uncut>
std::vector<std::array<std::int32_t, 2>> joined_captured(const std::vector<std::int32_t>& held, int slots, Current&& neighbour, Uncut&& uncut) {
    std::vector<std::array<std::int32_t, 2>> joined;
    bool any_cut = false;
    for (std::size_t q = 0; q < held.size(); ++q)
        for (int s = 0; s < slots; ++s) {
            const std::int32_t j = uncut(std::size_t(held[q]), s);
            if (j <= held[q]) continue;
            const auto at = std::lower_bound(held.begin(), held.end(), j);
            if (at == held.end() || *at != j) continue;
            if (neighbour(std::size_t(held[q]), s) == j) joined.push_back({std::int32_t(q), std::int32_t(at - held.begin())});
            else any_cut = true;
        }
    if (!any_cut) joined.clear();
    return joined;
}

namespace solver_kernels {
template <class Real>
struct KernelData;
}  // namespace solver_kernels

/// The solver, in float (`Solver`, the hot path, GPU parity) or double (`ReferenceSolver`,
/// the converged reference for convergence tests). Not thread-safe: one caller drives it;
/// step() itself runs on TBB's workers and gives the same bits for any thread count.
template <class Real>
class BasicSolver {
public:
    using Scalar = Real;  ///< float for Solver, double for ReferenceSolver
    static constexpr int hands = 2;
    static constexpr int slots = 18;
    static constexpr int lanes = 8;  ///< particles per group in the slot tables (docs/solver.md)
    /// The most substeps one step may take; a longer dt is refused (InputError) rather than run
    /// for minutes per frame.
    static constexpr int max_substeps = 10000;

    /// Builds the solver from the packed particles and springs. `neighbours` is /packing/neighbours
    /// (N×18, lattice.h slot order, −1 = none); empty = slots assigned from the springs in order.
    /// Throws InputError for mismatched sizes, a spring not in the table, a non-positive mass,
    /// a particle with more than 18 springs, or a non-positive or non-finite time step.
    BasicSolver(const Particles& particles, const Springs& springs,
                const std::vector<std::array<std::int32_t, 18>>& neighbours, const SolverOptions& options = {});
    /// Same, with damping ratios from `lattice.materials` unless options give them.
    BasicSolver(const Lattice& lattice, const std::vector<std::array<std::int32_t, 18>>& neighbours,
                const SolverOptions& options = {});

    const SolverLoadReport& load_report() const { return load_report_; }
    /// The options it was made with.
    const SolverOptions& options() const { return options_; }
    std::size_t size() const { return n_; }

    /// Sets the time of one step at mass scale 1, ms (under mass scaling a step of one substep
    /// grows with the stable step: stability.h scaled_step_ms); recomputes the substeps and the
    /// per-substep constants, keeping velocities.
    void set_time_step(double dt_ms);
    double time_step_ms() const { return dt_ms_; }
    double substep_ms() const { return h_; }
    int substeps_per_step() const { return substeps_; }
    double simulated_time_ms() const { return time_ms_; }
    /// The critical step with damping: dashpots, support dampers and drag shorten it. The
    /// damped central-difference scheme is stable while h²λ_K + 2hλ_C < 4 (stability.h
    /// stable_step_ms), λ_K = 4/critical², λ_C the largest eigenvalue of M^(−1/2) C M^(−1/2)
    /// estimated at load. Equals the critical step undamped.
    double damped_critical_dt_ms() const { return damped_critical_dt_ms_; }
    /// Changes the explicit mass scaling S (SolverOptions::mass_scale, in [1, 1024]) during a run:
    /// the critical steps, the step (stability.h scaled_step_ms), the substeps and the per-substep
    /// constants follow; positions and velocities are kept. Throws InputError outside the range
    /// (nothing changed then).
    void set_mass_scale(double mass_scale);
    double mass_scale() const { return options_.mass_scale; }

    /// Instruments: hand 0 or 1. Changing an instrument releases what it held (release(): a
    /// retractor's tissue stays).
    void set_instrument(int hand, const Instrument& instrument);
    const Instrument& instrument(int hand) const;
    /// The pose reached at the end of the next step() call; the pose moves linearly (position)
    /// and by slerp (orientation) across that call's substeps, so fast tools do not teleport.
    /// The first pose after set_instrument() places the instrument there at once.
    void set_pose(int hand, const InstrumentPose& pose);
    /// Starts a grab gesture: captures the free particles inside the grabber or retractor at its
    /// current pose (one piece of tissue: SolverOptions::grab_reach); they then follow it rigidly,
    /// in ascending index order. Returns how many. On a scalpel it lowers the blade: the steps from
    /// now on cut (returns 0). Throws if the hand holds none of these.
    std::size_t begin_grab(int hand);
    /// Ends a grab, or lifts a scalpel's blade. A grabber's particles go free. A retractor's stay:
    /// each becomes anchored where it is now (not movable, zero inverse mass, no support spring,
    /// zero motion: it never moves again), listed in stayed_particles(), until reset(),
    /// reset_tissue() or the watchdog's restore frees them (the scenario's anchoring again).
    void release(int hand);
    /// The particles retractors left anchored in place (release()), in the order they stayed (each
    /// release's in its held order); empty after reset(), reset_tissue() and the watchdog's restore.
    const std::vector<std::int32_t>& stayed_particles() const { return stayed_; }
    /// The springs cut so far, each as its two packed particle indices (lower first), in the
    /// order they were cut (particle order within a step). reset() and reset_tissue() heal them.
    const std::vector<std::array<std::int32_t, 2>>& cut_springs() const { return cut_; }
    /// Springs the last step() call cut.
    std::size_t last_cut_count() const { return last_cuts_; }
    /// The lattice the springs were laid out on (the scalpel's area per spring, cutting_force.h):
    /// the Lattice's spacing and axes, or, built from bare particles, the shortest rest length and
    /// the world's axes.
    const LatticeFrame& lattice_frame() const { return lattice_frame_; }
    /// The scalpel strokes so far, pose for pose as they were swept (cutting.h StrokeLog).
    const StrokeLog& strokes() const { return strokes_; }
    /// Particles held by a grabber, or touched by a probe in the last substep (packed indices).
    std::vector<std::int32_t> contact_particles(int hand) const;

    /// External loads from the next substep on, until replaced (an empty list removes them): in every
    /// substep a load F on a movable particle that no grabber holds adds h²F/(S·m) to its next position
    /// and to its motion, as F added to its spring force would in the Verlet step (applied after the
    /// integration, before the probes' projection). Sorted by particle, no repeats, indices in range,
    /// finite: else InputError, nothing changed. reset() and reset_tissue() remove them; the
    /// watchdog's restore keeps them. The watchdog's energy check counts the energy a load puts in
    /// as any other: a load that adds more than energy_growth_limit times the energy between two
    /// checks trips it.
    void set_loads(std::vector<ParticleLoad> loads);
    const std::vector<ParticleLoad>& loads() const { return loads_; }
    /// Each particle's skin, mm, in packed order (libmodel/contact_skin.h: how far the drawn surface
    /// lies beyond it at rest; negative where the particle lies outside it). From the next substep a
    /// probe, and from the next begin_grab() a grabber or retractor, meets particle i grown by
    /// skin[i] × SolverOptions::contact_skin on each semi-axis (shrunk where negative, to half its
    /// own at most: met_axes), so that it meets the tissue where it is drawn. Empty (as
    /// constructed): no skin. Throws InputError, nothing changed, unless there are size() values,
    /// each finite and within 4 × the lattice's longest rest length of 0.
    void set_contact_skin(std::vector<float> skin);
    const std::vector<float>& contact_skin() const { return skin_; }
    /// How far an instrument reaches beyond particle i: skin × SolverOptions::contact_skin, mm.
    double reach_beyond(std::size_t i) const { return skin_.empty() ? 0.0 : double(skin_[i]) * options_.contact_skin; }
    /// The semi-axes with which an instrument of `semi_axes` meets a particle it reaches `reach`
    /// beyond: semi_axes + reach on each, and at least half of each (a negative reach shrinks it).
    static Eigen::Vector3d met_axes(const Eigen::Vector3d& semi_axes, double reach) {
        return (semi_axes + Eigen::Vector3d::Constant(reach)).cwiseMax(0.5 * semi_axes);
    }
    /// `task` runs during the next step() (its first substep), beside the kernel's spring pass and
    /// before the loads are applied, on one of the step's threads: it may read positions
    /// (position()) and set_loads(), which that substep applies, and must touch nothing else of
    /// the solver. The step comes out the same to the bit as `task` run before it (the spring pass
    /// reads neither the loads nor writes what the task reads); on two cores the task's time hides
    /// in the spring pass's. What it throws, step() throws. One step only.
    void run_beside_next_step(std::function<void()> task);

    /// Advances `steps` steps of dt_ms. Stops early when the watchdog fires (see StepReport).
    StepReport step(int steps = 1);
    /// Back to rest: rest positions, zero velocity, grabs released, cut springs restored, loads
    /// removed, time 0. Instruments kept.
    void reset();
    /// The tissue back to its rest state as reset() (uncut, unloaded), but the simulated time goes
    /// on (a window's "reset the tissue" key during a session).
    void reset_tissue();
    /// Sets every particle's position (mm) and velocity (mm/ms), N each, packed order. The
    /// motion of the last substep is v·h − ½·a·h² (a from the forces at x), so the start is
    /// second order. Anchored particles take the given position and zero velocity. Time is unchanged.
    void set_state(const std::vector<Eigen::Vector3d>& positions, const std::vector<Eigen::Vector3d>& velocities);

    /// Both instruments' forces from the current state, in one call (N, world frame).
    InstrumentForces instrument_forces() const;
    /// The force the tissue exerts on its anchors (Σ spring + dashpot forces on anchored
    /// particles), N. Minus it is the anchors' reaction on the tissue.
    Eigen::Vector3d anchor_force() const;
    /// The force the supports exert on the tissue, Σ k_s·(support point − x), N. With the anchors'
    /// reaction (−anchor_force()), the weight and the instruments' it sums to the tissue's
    /// momentum change: zero at static equilibrium.
    Eigen::Vector3d support_force() const;
    /// Σ spring + dashpot + support force on one particle, N.
    Eigen::Vector3d particle_force(std::size_t particle) const;

    /// Energies with the centred velocity (x_{n+1} − x_{n−1})/2h (O(h²), for tests without
    /// instruments). The watchdog uses the cheaper backward-difference kinetic energy.
    SolverEnergy energy() const;

    /// Current position of a particle (packed order), mm.
    Eigen::Vector3d position(std::size_t particle) const;
    /// Current positions, N×3 float32 in packed order, mm.
    std::vector<std::array<float, 3>> positions() const;
    /// FNV-1a over the bits of the current positions and motions: equal states, equal hashes.
    std::uint64_t state_hash() const;

    /// The cells with a volume term (libmodel/volume_cells.h), whole or cut.
    std::size_t volume_cell_count() const { return cell_corner_.size(); }
    /// The cells' corners and constants as the step uses them (the gl backend uploads the same):
    /// k₁₂ = Δλ/(144·|V₀|) and 12·V₀ (volume_cells.h cell_forces).
    const std::vector<std::array<std::int32_t, 8>>& volume_cell_corners() const { return cell_corner_; }
    const std::vector<Real>& volume_cell_k12() const { return cell_k12_; }
    const std::vector<Real>& volume_cell_rest12() const { return cell_rest12_; }
    /// The neighbour-table slot (lattice.h order) of each of a cell's 24 springs (volume_cells.h
    /// cell_springs), at its first corner: the cell is whole while the slot holds its second.
    const std::vector<std::array<std::int8_t, 24>>& volume_cell_spring_slots() const { return cell_spring_slot_; }

    std::size_t watchdog_events() const { return watchdog_events_; }
    /// Particles that slipped out of a grabber so far (grab_slip_strain).
    std::size_t slipped_particles() const { return slipped_; }
    /// Times a probe pierced the tissue instead of pushing a particle, so far (probe_pierce_strain).
    std::size_t pierced_particles() const { return pierced_; }

    BasicSolver(const BasicSolver&) = delete;
    BasicSolver& operator=(const BasicSolver&) = delete;
    BasicSolver(BasicSolver&&) = default;
    BasicSolver& operator=(BasicSolver&&) = default;
    ~BasicSolver() = default;

private:
    struct HandState {
        Instrument instrument;
        InstrumentPose pose;        ///< where the tool is now
        InstrumentPose target;      ///< where it will be after the next step()
        bool grabbing = false;
        bool cutting = false;       ///< a scalpel between begin_grab and release
        bool placed = false;        ///< a pose was set since set_instrument
        BladeState blade;           ///< a scalpel's blade state (cutting_force.h; zero lifted)
        std::size_t cuts = 0;       ///< springs its blade cut in the last step() call
        std::vector<std::int32_t> held;            ///< packed indices
        std::vector<Eigen::Vector3d> held_local;   ///< tool-frame positions at capture

        /// Keeps, in order, the held particles for which keep(q) is true (q their place in the
        /// list before; keep is called once each, in order, and may read held_local[q]).
        template <class Keep> void keep_held(Keep&& keep) {
            std::size_t kept = 0;
            for (std::size_t q = 0; q < held.size(); ++q) {
                if (!keep(q)) continue;
                held[kept] = held[q];
                held_local[kept] = held_local[q];
                ++kept;
            }
            held.resize(kept);
            held_local.resize(kept);
        }
    };

    void build_step_constants();
    /// release() with `stay`: a retractor's held particles anchored in place (false: freed, as
    /// the tissue's reset and the watchdog's restore release).
    void release_hand(int hand, bool stay);
    /// The stayed particles movable again, with their support springs (the scenario's anchoring).
    void free_stayed();
    // The constructor's steps (solver_setup.cpp).
    void load_particles(const Particles& particles);
    void load_springs(const Particles& particles, const Springs& springs, const std::vector<std::array<std::int32_t, 18>>& table,
                      const std::vector<std::int32_t>& slot_spring);
    void load_time_steps(const Particles& particles, const Springs& springs, const VolumeCells& cells);
    /// The volume term's cells (returned, for the time step), their springs' table entries and
    /// each particle's cells.
    VolumeCells load_cells(const Particles& particles);
    /// Which cells are whole, from the neighbour table: after every change to it (a cut, a reset).
    void refresh_cells();
    /// Each whole cell's forces on its corners at the current positions, into cell_force_.
    void cell_pass();
    /// The volume term's force on particle i at the current positions, in double.
    Eigen::Vector3d volume_force_on(std::size_t i) const;
    /// Σ ½·Δλ/|V₀|·(V − V₀)² over the whole cells at the current positions, mJ (in double).
    double volume_energy() const;
    /// Takes `step` (scaled_step): the limits, the step, its substeps and the per-substep
    /// constants; keeps velocities.
    void apply_step(const ScaledStep& step);
    void substep(const InstrumentPose* previous_poses, const InstrumentPose* poses, bool& bad, const std::function<void()>* beside = nullptr);
    // substep()'s parts (solver.cpp).
    struct ProbeFrame;
    /// The kernel's pointers and per-substep constants.
    solver_kernels::KernelData<Real> kernel_data() const;
    /// The probes' frames at `poses` and the substep before; returns how many (the first entries).
    int probe_frames(const InstrumentPose* previous_poses, const InstrumentPose* poses, std::array<ProbeFrame, hands>& probes) const;
    void project_out_of_probe(const ProbeFrame& probe, std::size_t particle, std::vector<std::int32_t>& touched, std::size_t& pierced);
    void load_and_project(std::size_t chunk, const std::array<ProbeFrame, hands>& probes, int probe_count);
    void follow_grabbers(const InstrumentPose* poses);
    SolverEnergy compute_energy(bool centred) const;
    /// The largest strain of particle i's springs if it stood at `x` (its neighbours in `positions`).
    Real strain_at(std::size_t i, const Real* x, const Real* positions) const;
    void snapshot();
    void restore();
    /// Cuts the springs that cross `sweep` at the current positions; returns how many.
    std::size_t cut(const BladeSweep& sweep);
    Eigen::Vector3d force_on(std::size_t particle) const;

    SolverOptions options_;
    SolverLoadReport load_report_;
    std::size_t n_ = 0, n_pad_ = 0, groups_ = 0, chunks_ = 0;
    double dt_ms_ = 0.0, h_ = 0.0, critical_dt_ms_ = 0.0, time_ms_ = 0.0;
    int substeps_ = 1;
    Real min_rest_length_ = 0;
    Real max_rest_length_ = 0;  ///< the longest spring at rest: cut()'s search margin (cutting.h)
    double energy_floor_ = 0.0;
    double damped_critical_dt_ms_ = 0.0;  ///< given, or from λ_max of M^(−1/2) C M^(−1/2) (stability.h)
    bool damped_ = false;

    // Per particle (n_pad_): the position (x, y, z, 0) and, beside it, the motion of the last
    // substep (u = x_n − x_{n−1} = v·h, x, y, z, 0), 8 values at a 64-byte aligned start, in two
    // buffers that swap after a substep; current_ and next_ point at the positions, motion_ and
    // next_motion_ four values on (the same stride). Keeping u apart from x keeps the velocity
    // exact to float rounding of u itself, not of the absolute coordinates (docs/solver.md
    // "Precision").
    std::vector<Real> state_[2];
    Real* current_ = nullptr;
    Real* next_ = nullptr;
    Real* motion_ = nullptr;
    Real* next_motion_ = nullptr;
    std::vector<Real> rest_;            ///< 4 per particle
    std::vector<Real> mass_;            ///< g (1 for padding)
    std::vector<Real> inverse_mass_h2_; ///< h²/m, 0 for anchored and padding
    std::vector<std::uint8_t> movable_; ///< 1 = free particle (not anchored, not padding)
    std::vector<std::uint8_t> anchored_;
    std::vector<std::int8_t> held_by_;  ///< −1 or the hand holding it
    std::vector<std::int32_t> stayed_;  ///< stayed_particles()
    std::vector<Real> stayed_support_stiffness_;  ///< each stayed particle's support stiffness as loaded, N/mm
    std::vector<Real> support_point_;   ///< 4 per particle, mm (the rest position where unsupported)
    std::vector<Real> support_stiffness_; ///< N/mm, 0 for unsupported, anchored and padding
    std::vector<Real> support_damping_;   ///< c, N·ms/mm
    std::vector<Real> support_damping_over_h_; ///< c/h, N/mm
    bool supported_ = false;

    // Per group of `lanes` particles, per slot, per lane: [group][slot][lane].
    std::vector<std::int32_t> neighbour_;  ///< the particle itself where the slot is empty or its spring cut
    std::vector<std::int32_t> uncut_neighbour_;  ///< neighbour_ as loaded (reset_tissue heals cuts)
    std::vector<std::array<std::int32_t, 2>> cut_;  ///< cut springs, lower index first
    std::size_t last_cuts_ = 0;
    LatticeFrame lattice_frame_;
    StrokeLog strokes_;
    std::vector<Real> rest_length_;        ///< mm (0 where empty)
    std::vector<Real> stiffness_;          ///< N/mm (0 where empty)
    std::vector<Real> dashpot_;            ///< c, N·ms/mm (0 where empty)
    std::vector<Real> dashpot_over_h_;     ///< c/h, N/mm
    bool uniform_slots_ = false;
    std::vector<Real> slot_rest_length_;   ///< [slot][lane] constants when uniform_slots_
    std::vector<Real> slot_stiffness_;

    // The volume term (volume_cells.h): per cell its corners, k₁₂ = Δλ/(144·|V₀|) and 12·V₀ (cell_forces), the
    // table slots of its 24 springs at their first corners (neighbour_ holds the second while it is whole),
    // whether it is whole; per particle (n_pad_) the force (3 each, N) of the cell it is corner r
    // of, in its slot r (0 where it is no cell's corner r; the cell pass writes each cell's eight
    // into its corners' slots, so a particle's eight lie together), and that cell (−1: none).
    std::vector<std::array<std::int32_t, 8>> cell_corner_;
    std::vector<Real> cell_k12_;
    std::vector<Real> cell_rest12_;
    std::vector<std::array<std::int8_t, 24>> cell_spring_slot_;
    std::vector<std::uint8_t> cell_whole_;
    std::vector<Real> cell_force_;
    std::vector<std::array<std::int32_t, 8>> particle_cell_;

    std::array<HandState, hands> hand_;
    std::vector<ParticleLoad> loads_;          ///< set_loads(), sorted by particle
    std::vector<float> skin_;                  ///< set_contact_skin(), N or empty
    double max_reach_beyond_ = 0.0;            ///< the largest reach_beyond()
    std::function<void()> beside_;             ///< run_beside_next_step()
    std::vector<std::int32_t> load_particle_;  ///< loads_'s particles, for the chunks' lower_bound
    std::vector<Real> load_force_;             ///< loads_'s forces rounded to Real, 3 per load, N
    std::vector<std::vector<std::int32_t>> touched_;  ///< [chunk × hands + hand]
    std::vector<std::uint8_t> chunk_bad_;

    // Watchdog.
    std::vector<Real> good_current_;  ///< the restore point (restored at rest: no motion kept)
    double good_time_ms_ = 0.0;
    double good_energy_ = 0.0;
    long long substeps_since_check_ = 0;
    std::size_t watchdog_events_ = 0;
    int consecutive_restores_ = 0;
    std::size_t slipped_ = 0;
    std::size_t pierced_ = 0;
    std::vector<std::size_t> chunk_pierced_;  ///< this substep's pierces per chunk (summed in order)
};

using Solver = BasicSolver<float>;
using ReferenceSolver = BasicSolver<double>;

extern template class BasicSolver<float>;
extern template class BasicSolver<double>;

}  // namespace heartsim
