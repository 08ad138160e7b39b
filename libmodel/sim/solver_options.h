/// @file solver_options.h
/// @brief The CPU and GL solvers' options, each with one owner: the step settings a scenario's
/// /solver stores (StepSettings), the rules heartsim applies to instruments and the watchdog,
/// which a recording stores (SolverRules), and how this run computes, never stored
/// (KernelOptions). SolverOptions is the three together. A new option goes into the struct
/// that owns it, and into the code that uses it; nothing mirrors it.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace heartsim {

/// Which inner loop runs the step. portable, avx2 and avx512 give the same bits for float: they
/// evaluate the same IEEE operations in the same order (exact sqrt and division, a fused
/// multiply-add in the same five places of a slot, no other contraction). sse2 has no fused
/// multiply-add: it rounds those products apart, a few ulps from the others (docs/solver.md).
enum class SolverKernel {
    automatic,  ///< the widest the CPU has: avx512, else avx2, else sse2 (docs/solver.md "Kernels")
    portable,   ///< plain C++, what the compiler makes of it (the only kernel for double)
    sse2,       ///< x86-64 baseline intrinsics, 4 lanes
    avx2,       ///< 8 lanes; falls back to sse2 on a CPU without AVX2 and FMA
    /// 16 lanes (two groups per 512-bit register; AVX-512F/VL/DQ); falls back to avx2.
    avx512,
};
const char* to_string(SolverKernel kernel);
/// Whether a kernel fuses the spring slot's five multiply-adds: every one but sse2.
inline bool fuses_multiply_adds(SolverKernel kernel) { return kernel != SolverKernel::sse2; }

/// The spring slot's multiply-adds, when a result must be reproduced to the bit (replaying a
/// recording): `fused` takes a fusing kernel even where the CPU lacks AVX2 and FMA (portable,
/// through libm: slow, the same bits); `separate` takes the sse2 kernel (x86), which rounds them
/// apart as every kernel did before they were fused. `as_kernel`: whatever the kernel does.
enum class SlotArithmetic { as_kernel, fused, separate };

/// What a scenario's /solver attributes store (formats/scenario.h `SolverSettings` adds the
/// file-only fields): the step and what it is derived from, drag and gravity.
struct StepSettings {
    /// Time of one step() unit, ms. 0 = safety_factor × the damped critical step.
    double dt_ms = 0.0;
    /// Critical step 2/ω_max, ms. 0 = estimated here (stability.h: Lanczos iteration).
    double critical_dt_ms = 0.0;
    /// The stable step with dashpots, support dampers and drag (stability.h stable_step_ms), ms.
    /// 0 = estimated here from critical_dt_ms and the damping (a Lanczos estimate of its own).
    double damped_critical_dt_ms = 0.0;
    /// Each step is split into the fewest equal substeps with substep ≤ safety_factor × the
    /// damped critical step (damped_critical_dt_ms); dt_ms = 0 takes one such substep. The margin
    /// covers the estimate (a Lanczos Ritz value approaches the largest eigenvalue from below)
    /// and deformation: docs/solver.md "Step policy".
    double safety_factor = 0.8;
    /// Global drag γ, 1/ms: f = −γ·m·v on every free particle (scenario /solver damping).
    double damping = 0.0;
    /// Gravity, mm/ms² (9.81e-3 is 1 g), world frame.
    Eigen::Vector3d gravity{0.0, 9.81e-3, 0.0};
    /// The gravity the rest state is a static equilibrium for (supports.h balance_rest_state;
    /// scenario /solver balanced_gravity), mm/ms²; zero when the springs are unstressed at rest.
    /// Only the start of motion depends on it: reset() starts from rest with acceleration
    /// gravity − balanced_gravity.
    Eigen::Vector3d balanced_gravity = Eigen::Vector3d::Zero();
};

/// The solver's rules that come from heartsim, not from the scenario: how instruments pierce,
/// grab and slip, and when the watchdog steps in. They change between versions; a recording
/// keeps the ones it ran with (its /rules) and a replay takes them (docs/haptics.md).
struct SolverRules {
    /// Largest displacement of a free particle in one substep, as a fraction of the shortest
    /// rest length (and at least the largest semi-axis of an instrument in use): the speed
    /// bound. An unstable mode grows geometrically past any bound within a few dozen substeps;
    /// what a stable step can still do is snap a light surface particle through a neighbour in
    /// a folded lattice, which moved it up to 3.2 × the shortest rest length in one substep (and
    /// less in the next) in 4 × 10⁵ steps of 20 mm pulls on the real hearts. At 2 those snaps
    /// tripped the watchdog 17–24 times per 10⁵ steps, each a restore at rest with the grab
    /// released (docs/benchmarks.md "Soak").
    double max_displacement_fraction = 4.0;
    /// Energy check: the total energy may grow at most this factor between two checks, over a
    /// floor of ½·Σk(0.1·L₀)² (every spring strained 10%), so instrument work from rest passes.
    double energy_growth_limit = 100.0;
    /// A held particle slips out of the grabber when one of its springs would be stretched beyond
    /// (1 + this) × its rest length, as tissue slips out of forceps: a grab cannot stretch the
    /// tissue without limit. 2 (three times the rest length): the 10 mm pulls of the real-time
    /// benchmark hold on the real hearts (one edge particle slips on two of them; at 1 every
    /// grab let go), while 20 mm pulls beside the stiffest supports slip instead of stretching
    /// springs four-fold, which made the soak's lattice unstable and folded it (docs/benchmarks.md
    /// "Soak"). ≤ 0: never slips.
    double grab_slip_strain = 2.0;
    /// A free particle that a probe would push to where one of its springs is stretched beyond
    /// (1 + this) × its rest length (measured against its neighbours where they were at the start
    /// of the substep) is not pushed: the probe pierces the tissue there, as a needle does, and the
    /// particle stays where the integration put it. Without it a probe driven through the tissue
    /// drags what it meets tens of millimetres along its surface, and the springs, stretched
    /// five-fold, fling it out when the probe turns (docs/solver.md "Instruments"). 2, as the
    /// grab's slip: a press of the real-time benchmark stretches no spring half as far. ≤ 0: never
    /// pierces.
    double probe_pierce_strain = 2.0;
    /// begin_grab() takes one piece of tissue: of the particles inside the grabber, only those
    /// whose rest position lies within (this × the grabber's largest semi-axis) of the rest
    /// position of the one nearest its centre. 2 is the grabber's diameter, so a grab of tissue
    /// at rest (or stretched) takes everything inside; a grab of tissue that a probe crumpled
    /// together from far apart takes the piece under the jaws instead of a rigid clump of
    /// thousands of particles. ≤ 0: everything inside.
    double grab_reach = 2.0;
    /// How far a probe, a grabber or a retractor reaches beyond a particle, as a fraction of the
    /// particle's skin (libmodel/contact_skin.h: how far the drawn surface lies beyond it at rest,
    /// BasicSolver::set_contact_skin): the instrument is grown by skin × this for that particle, so
    /// at 1 it meets the tissue where the trainee sees it drawn, not half a spacing inside. 0: at
    /// the particles themselves (what recordings made before this rule replay with). In [0, 1].
    double contact_skin = 1.0;
    /// A state becomes the watchdog's restore point only while no spring is longer than
    /// (1 + this) × its rest length: a state stretched further, released at rest, diverges again
    /// at once (geometric stiffening shortens the stable step), and restoring to it froze the
    /// soak on two real hearts at 4. Below the slip strain on purpose: while a grab holds springs
    /// between the two, the restore point stays the last state before that stretch. ≤ 0: no bound.
    double restore_strain_limit = 1.0;
    std::int32_t watchdog_interval = 64;       ///< substeps between energy checks and good-state snapshots
    /// After this many restores in a row without a new restore point the simulation cannot
    /// recover: step() reports gave_up and the runtime stops (exit 6).
    std::int32_t max_consecutive_restores = 10;
    bool operator==(const SolverRules&) const = default;
};

/// Calls f(name, field of each of `rules`…) for each rule, in the order the recording and the
/// journal keep them: the one list of SolverRules' fields, for the file and for comparisons.
template <class F, class... Rules> void for_each_rule(F&& f, Rules&... rules) {
    f("max_displacement_fraction", rules.max_displacement_fraction...);
    f("energy_growth_limit", rules.energy_growth_limit...);
    f("grab_slip_strain", rules.grab_slip_strain...);
    f("probe_pierce_strain", rules.probe_pierce_strain...);
    f("grab_reach", rules.grab_reach...);
    f("restore_strain_limit", rules.restore_strain_limit...);
    f("watchdog_interval", rules.watchdog_interval...);
    f("max_consecutive_restores", rules.max_consecutive_restores...);
    f("contact_skin", rules.contact_skin...);
}

/// How this run computes the step: the run's choice, never in a scenario (mass_scale alone is
/// kept by recordings and saved states, so that a replay steps the same).
struct KernelOptions {
    /// Explicit mass scaling S ≥ 1 (docs/solver.md "Mass scaling"): the inertia in the step is
    /// S × each particle's mass, so the critical step grows by √S and a simulated second takes √S
    /// (stiffness-limited) to S (damping-limited) times fewer substeps, while the weight (m·g), the
    /// dashpots and the drag force stay physical: the
    /// tissue rests where it rested and feels as stiff; only fast transients slow by √S.
    /// 1: no scaling (the same bits as a solver without it). heartsim run --mass-scale, --real-time.
    double mass_scale = 1.0;

    bool watchdog = true;             ///< divergence detection and restore (off only for tests)
    /// false: never subdivide (one substep per step even above critical; the watchdog guards it).
    bool subdivide = true;
    SolverKernel kernel = SolverKernel::automatic;
    SlotArithmetic arithmetic = SlotArithmetic::as_kernel;
    /// Read one rest length and stiffness per slot instead of per-entry tables when every
    /// spring in a slot has the same (a one-material regular lattice): same results, less traffic.
    bool compact_uniform_slots = true;
};

/// The scalpel's cutting resistance (libmodel/sim/cutting_force.h, docs/haptics.md "The scalpel's
/// force"): the energy to cut tissue is G_c × the area cut, and the hand feels it as a force
/// against the blade's motion, the energy over the distance of the blade's last λ of travel. Not
/// kept by recordings: a replay renders the blade with this build's values.
struct CuttingResistance {
    /// G_c, the energy to cut a unit area, N/mm (= mJ/mm²; 0.3 N/mm = 300 J/m²): an order of
    /// magnitude from blade-cutting measurements of soft tissue, not a measurement of myocardium.
    /// 0: the blade cuts with no force.
    double toughness_n_per_mm = 0.3;
    /// λ, in lattice spacings: the energy of the cut is averaged over the blade's last λ of travel
    /// (an exponential window in distance, cutting_force.h), across the layers of springs a blade
    /// meets one at a time; 0 = each step's own.
    double smoothing_spacings = 2.0;
    /// τ, ms (simulated time): the exponential filter of the blade's velocity and speed, which
    /// give the force's direction and let go of a blade that stops; 0 = each step's own.
    double smoothing_ms = 4.0;
    /// v_min, mm/ms: below this smoothed speed of the blade the force fades as (speed / v_min)², so
    /// that a blade brought to a stop in the tissue lets go of the hand. 0.002 mm/ms = 2 mm/s.
    double min_speed_mm_per_ms = 0.002;
    bool operator==(const CuttingResistance&) const = default;
};

/// Everything a solver takes. Every field has a default and a unit.
struct SolverOptions : StepSettings, SolverRules, KernelOptions {
    /// Spring damping ratio ζ per material row (dimensionless); a spring's dashpot is
    /// c = 2ζ√(kμ), μ the pair's reduced mass, ζ the mean of its two particles' materials.
    /// Empty: taken from the lattice's materials, or 0 when built from bare particles.
    std::vector<double> damping_ratio;
    /// Δλ per material row, N/mm²: the Lamé modulus the volume term adds to the springs' λ = μ
    /// (libmodel/volume_cells.h; 0: the springs alone, ν = 1/4). Empty: taken from the lattice's
    /// materials' Poisson's ratios, or none when built from bare particles.
    std::vector<double> volume_modulus;
    CuttingResistance cutting_resistance;  ///< the scalpel's force (not a rule a recording keeps)
};

}  // namespace heartsim
