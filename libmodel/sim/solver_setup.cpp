// The CPU solver's set-up: the constructor's named steps, from the packed particles and springs
// to the kernels' tables (solver_kernels.h) and the time step. The stepping is in solver.cpp.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/solver.h"
#include "libmodel/sim/solver_kernels.h"

#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/stability.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

namespace heartsim {

using namespace solver_kernels;

namespace {

/// Throws InputError for arrays of different lengths, a non-positive or non-finite mass, a
/// non-finite rest position or support, or a non-finite balanced gravity.
void check_input(const Particles& particles, const Springs& springs, const std::vector<std::array<std::int32_t, 18>>& neighbours,
                 const SolverOptions& options) {
    const std::size_t n = particles.size();
    if (n == 0) throw InputError("solver: no particles");
    if (particles.rest_position.size() != n || particles.anchored.size() != n || particles.material.size() != n)
        throw InputError("solver: particle arrays differ in length (rest_position, mass, material, anchored)");
    if (springs.pairs.size() != springs.size() || springs.stiffness.size() != springs.size())
        throw InputError("solver: spring arrays differ in length (pairs, rest_length, stiffness)");
    if (!neighbours.empty() && neighbours.size() != n)
        throw InputError("solver: the neighbour table has " + std::to_string(neighbours.size()) + " rows for " + std::to_string(n) +
                         " particles");
    if (n > std::size_t(std::numeric_limits<std::int32_t>::max() - lane_count)) throw InputError("solver: too many particles");
    for (std::size_t i = 0; i < n; ++i) {
        if (!(particles.mass[i] > 0) || !std::isfinite(particles.mass[i]))
            throw InputError("solver: particle " + std::to_string(i) + " has a non-positive or non-finite mass");
        for (float c : particles.rest_position[i])
            if (!std::isfinite(c)) throw InputError("solver: particle " + std::to_string(i) + " has a non-finite rest position");
    }
    if (particles.supported()) {
        if (particles.support_stiffness.size() != n || particles.support_point.size() != n)
            throw InputError("solver: support arrays differ in length from the particles (support_stiffness, support_point)");
        if (!particles.support_damping.empty() && particles.support_damping.size() != n)
            throw InputError("solver: support_damping differs in length from the particles");
        for (std::size_t i = 0; i < n; ++i) {
            if (!particles.support_damping.empty() && (!(particles.support_damping[i] >= 0) || !std::isfinite(particles.support_damping[i])))
                throw InputError("solver: particle " + std::to_string(i) + " has a negative or non-finite support damping");
            if (!(particles.support_stiffness[i] >= 0) || !std::isfinite(particles.support_stiffness[i]))
                throw InputError("solver: particle " + std::to_string(i) + " has a negative or non-finite support stiffness");
            for (float c : particles.support_point[i])
                if (!std::isfinite(c)) throw InputError("solver: particle " + std::to_string(i) + " has a non-finite support point");
        }
    }
    if (!options.balanced_gravity.allFinite()) throw InputError("solver: balanced_gravity must be finite");
}

/// The neighbour table (N×18), checked; `neighbours` itself, or, when it is empty, each spring in
/// the first free slot at both ends. `slot_spring` gets the spring of every slot (−1: none).
std::vector<std::array<std::int32_t, 18>> slot_table(std::size_t n, const Springs& springs,
                                                     const std::vector<std::array<std::int32_t, 18>>& neighbours,
                                                     std::vector<std::int32_t>& slot_spring) {
    std::vector<std::array<std::int32_t, 18>> table = neighbours;
    const bool assign = table.empty();
    if (assign) table.assign(n, {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1});
    for (std::size_t i = 0; i < n; ++i)
        for (int s = 0; s < slot_count; ++s)
            if (table[i][std::size_t(s)] < -1 || table[i][std::size_t(s)] >= std::int32_t(n))
                throw InputError("solver: neighbour table row " + std::to_string(i) + " slot " + std::to_string(s) + " is out of range");
    for (std::size_t q = 0; q < springs.size(); ++q) {
        const auto [a, b] = springs.pairs[q];
        if (a < 0 || b < 0 || std::size_t(a) >= n || std::size_t(b) >= n || a == b)
            throw InputError("solver: spring " + std::to_string(q) + " joins invalid particles");
        if (!(springs.stiffness[q] >= 0) || !(springs.rest_length[q] > 0) || !std::isfinite(springs.stiffness[q]) ||
            !std::isfinite(springs.rest_length[q]))
            throw InputError("solver: spring " + std::to_string(q) + " has a bad stiffness or rest length");
        if (assign) {  // no table given: each spring takes the first free slot at both ends
            auto free_slot = [&](std::int32_t p) {
                for (int s = 0; s < slot_count; ++s)
                    if (table[std::size_t(p)][std::size_t(s)] == -1) return s;
                return -1;
            };
            const int sa = free_slot(a), sb = free_slot(b);
            if (sa < 0 || sb < 0) throw InputError("solver: a particle has more than 18 springs");
            table[std::size_t(a)][std::size_t(sa)] = b;
            table[std::size_t(b)][std::size_t(sb)] = a;
        }
    }
    try {
        slot_spring = spring_of_slot(table, springs);
    } catch (const InputError& e) {
        throw InputError(std::string("solver: ") + e.what());
    }
    return table;
}

}  // namespace

template <class Real>
BasicSolver<Real>::BasicSolver(const Lattice& lattice, const std::vector<std::array<std::int32_t, 18>>& neighbours,
                               const SolverOptions& options)
    : BasicSolver(lattice.particles, lattice.springs, neighbours, [&] {
          SolverOptions o = options;
          if (o.damping_ratio.empty()) o.damping_ratio = damping_ratios(lattice.materials);
          if (o.volume_modulus.empty()) o.volume_modulus = added_lame_moduli(lattice.materials);
          return o;
      }()) {
    if (lattice.spacing > 0) lattice_frame_ = heartsim::lattice_frame(lattice);
}

template <class Real>
BasicSolver<Real>::BasicSolver(const Particles& particles, const Springs& springs,
                               const std::vector<std::array<std::int32_t, 18>>& neighbours, const SolverOptions& options)
    : options_(options) {
    check_input(particles, springs, neighbours, options_);
    n_ = particles.size();
    n_pad_ = (n_ + lane_count - 1) / lane_count * lane_count;
    groups_ = n_pad_ / lane_count;
    chunks_ = (groups_ + chunk_groups - 1) / chunk_groups;
    std::vector<std::int32_t> slot_spring;
    const std::vector<std::array<std::int32_t, 18>> table = slot_table(n_, springs, neighbours, slot_spring);
    load_particles(particles);
    load_springs(particles, springs, table, slot_spring);
    uncut_neighbour_ = neighbour_;
    const VolumeCells cells = load_cells(particles);
    load_report_.particles = n_;
    load_report_.springs = springs.size();
    load_time_steps(particles, springs, cells);
    load_report_.kernel = resolve_kernel(options_.kernel, std::is_same_v<Real, float>, n_, options_.arithmetic);

    touched_.assign(chunks_ * hands, {});
    chunk_bad_.assign(chunks_, 0);
    chunk_pierced_.assign(chunks_, 0);

    double dt = options_.dt_ms;
    if (!(dt > 0)) {
        dt = options_.safety_factor * load_report_.unscaled_damped_critical_dt_ms;  // the step at S = 1 (set_time_step scales it)
        if (!std::isfinite(dt) || !(dt > 0)) throw InputError("solver: dt_ms must be given for a network without a finite critical step");
    }
    // 64-byte aligned, so that no particle's 32 bytes straddle two cache lines.
    auto aligned = [&](std::vector<Real>& b) {
        void* start = b.data();
        std::size_t space = b.size() * sizeof(Real);
        return static_cast<Real*>(std::align(64, state_stride * n_pad_ * sizeof(Real), start, space));
    };
    current_ = aligned(state_[0]);
    next_ = aligned(state_[1]);
    motion_ = current_ + 4;
    next_motion_ = next_ + 4;
    h_ = 0.0;
    set_time_step(dt);
    // Without the lattice: its spacing is the shortest spring (a face spring), its axes the world's.
    lattice_frame_.spacing_mm = double(min_rest_length_) > 0 && std::isfinite(double(min_rest_length_)) ? double(min_rest_length_) : 1.0;
    reset();
}

/// The per-particle arrays: state buffers, rest positions, masses, anchors and supports
/// (zero-rest-length springs to fixed points; none on anchored particles).
template <class Real>
void BasicSolver<Real>::load_particles(const Particles& particles) {
    for (auto& b : state_) b.assign(state_stride * n_pad_ + 64 / sizeof(Real), Real(0));  // room to align the start
    rest_.assign(4 * n_pad_, Real(0));
    mass_.assign(n_pad_, Real(1));
    inverse_mass_h2_.assign(n_pad_, Real(0));
    movable_.assign(n_pad_, 0);
    anchored_.assign(n_pad_, 0);
    held_by_.assign(n_pad_, -1);
    for (std::size_t i = 0; i < n_; ++i) {
        for (int c = 0; c < 3; ++c) rest_[4 * i + std::size_t(c)] = Real(particles.rest_position[i][std::size_t(c)]);
        mass_[i] = Real(particles.mass[i]);
        anchored_[i] = particles.anchored[i] ? 1 : 0;
        movable_[i] = anchored_[i] ? 0 : 1;
        load_report_.anchored += anchored_[i];
    }
    // Supports: zero-rest-length springs to fixed points (none on anchored particles).
    support_point_.assign(4 * n_pad_, Real(0));
    support_stiffness_.assign(n_pad_, Real(0));
    support_damping_.assign(n_pad_, Real(0));
    supported_ = false;
    for (std::size_t i = 0; i < n_; ++i) {
        const std::array<float, 3>& y = particles.supported() ? particles.support_point[i] : particles.rest_position[i];
        for (int c = 0; c < 3; ++c) support_point_[4 * i + std::size_t(c)] = Real(y[std::size_t(c)]);
        if (particles.supported() && movable_[i] && particles.support_stiffness[i] > 0) {
            support_stiffness_[i] = Real(particles.support_stiffness[i]);
            if (!particles.support_damping.empty()) support_damping_[i] = Real(particles.support_damping[i]);
            supported_ = true;
            ++load_report_.supported;
        }
    }
}

/// The per-slot tables in [pair of groups][slot][16 lanes] order (entry_of), the per-slot
/// constants of a uniform lattice, and the watchdog's energy floor.
template <class Real>
void BasicSolver<Real>::load_springs(const Particles& particles, const Springs& springs,
                                     const std::vector<std::array<std::int32_t, 18>>& table, const std::vector<std::int32_t>& slot_spring) {
    const std::size_t entries = (groups_ + 1) / 2 * slot_count * slot_stride;
    neighbour_.assign(entries, 0);
    rest_length_.assign(entries, Real(0));
    stiffness_.assign(entries, Real(0));
    dashpot_.assign(entries, Real(0));
    min_rest_length_ = std::numeric_limits<Real>::infinity();
    damped_ = false;
    for (std::size_t i = 0; i < n_pad_; ++i) {
        for (int s = 0; s < slot_count; ++s) {
            const std::size_t t = entry_of(i, s);
            neighbour_[t] = std::int32_t(i);
            if (i >= n_) continue;
            const std::int32_t q = slot_spring[i * slot_count + std::size_t(s)];
            if (q < 0) {
                if (table[i][std::size_t(s)] >= 0) ++load_report_.table_slots_without_spring;
                continue;
            }
            const auto [a, b] = springs.pairs[std::size_t(q)];
            const std::size_t j = std::size_t(a) == i ? std::size_t(b) : std::size_t(a);
            neighbour_[t] = std::int32_t(j);
            rest_length_[t] = Real(springs.rest_length[std::size_t(q)]);
            stiffness_[t] = Real(springs.stiffness[std::size_t(q)]);
            dashpot_[t] = Real(spring_dashpot(particles, options_.damping_ratio, double(springs.stiffness[std::size_t(q)]), i, j));
            damped_ = damped_ || dashpot_[t] != Real(0);
            min_rest_length_ = std::min(min_rest_length_, rest_length_[t]);
            max_rest_length_ = std::max(max_rest_length_, rest_length_[t]);
        }
    }
    // A regular lattice of one material has one rest length and one stiffness per slot: the
    // kernel then reads 18 constants instead of two per-entry tables (less memory traffic).
    // An empty slot points at the particle itself, which gives zero force with any constants.
    {
        std::array<Real, slot_count> rest{}, stiff{};
        std::array<bool, slot_count> seen{};
        bool uniform = true;
        for (std::size_t i = 0; i < n_ && uniform; ++i)
            for (int s = 0; s < slot_count; ++s) {
                const std::size_t t = entry_of(i, s);
                if (std::size_t(neighbour_[t]) == i) continue;
                if (!seen[std::size_t(s)]) seen[std::size_t(s)] = true, rest[std::size_t(s)] = rest_length_[t], stiff[std::size_t(s)] = stiffness_[t];
                else if (rest[std::size_t(s)] != rest_length_[t] || stiff[std::size_t(s)] != stiffness_[t]) uniform = false;
            }
        uniform_slots_ = uniform && options_.compact_uniform_slots;
        slot_rest_length_.assign(std::size_t(slot_count) * slot_stride, Real(0));
        slot_stiffness_.assign(std::size_t(slot_count) * slot_stride, Real(0));
        for (int s = 0; s < slot_count; ++s)
            for (std::size_t l = 0; l < slot_stride; ++l) {  // both groups of a pair read the same 18 constants
                slot_rest_length_[std::size_t(s) * slot_stride + l] = rest[std::size_t(s)];
                slot_stiffness_[std::size_t(s) * slot_stride + l] = stiff[std::size_t(s)];
            }
        load_report_.uniform_slots = uniform_slots_;
    }
    // Each spring appears twice in the tables: ½ · ½ k (0.1 L₀)² per entry.
    for (std::size_t q = 0; q < springs.size(); ++q)
        energy_floor_ += 0.5 * double(springs.stiffness[q]) * std::pow(0.1 * double(springs.rest_length[q]), 2);
}

/// The volume term's cells (volume_cells.h) from the particles' lattice indices, each with the
/// table slots of its 24 springs; a cell one of whose springs the table lacks gets no term.
template <class Real>
VolumeCells BasicSolver<Real>::load_cells(const Particles& particles) {
    VolumeCells cells = volume_cells(particles, options_.volume_modulus);
    VolumeCells kept;
    cell_corner_.clear(), cell_k12_.clear(), cell_rest12_.clear(), cell_spring_slot_.clear();
    particle_cell_.assign(n_pad_, {-1, -1, -1, -1, -1, -1, -1, -1});
    for (std::size_t c = 0; c < cells.size(); ++c) {
        const auto& corner = cells.corner[c];
        std::array<std::int8_t, 24> slot{};
        bool complete = true;
        for (std::size_t q = 0; q < cell_springs.size() && complete; ++q) {
            const std::size_t a = std::size_t(corner[std::size_t(cell_springs[q][0])]);
            const std::int32_t b = corner[std::size_t(cell_springs[q][1])];
            slot[q] = -1;
            for (int s = 0; s < slot_count; ++s)
                if (uncut_neighbour_[entry_of(a, s)] == b) slot[q] = std::int8_t(s);
            complete = slot[q] >= 0;
        }
        if (!complete) continue;
        for (int r = 0; r < 8; ++r) particle_cell_[std::size_t(corner[std::size_t(r)])][std::size_t(r)] = std::int32_t(cell_corner_.size());
        cell_corner_.push_back(corner);
        cell_k12_.push_back(Real(cells.modulus[c] / (144.0 * std::abs(cells.rest_volume[c]))));
        // 12·V₀ from the rest positions as the step holds them (Real), by the step's own operations:
        // a cell at rest has no force to the bit.
        Real p[8][3];
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k)
                p[q][k] = rest_[4 * std::size_t(corner[std::size_t(q)]) + std::size_t(k)] - rest_[4 * std::size_t(corner[0]) + std::size_t(k)];
        cell_rest12_.push_back(cell_volume12<Real>(p, nullptr));
        cell_spring_slot_.push_back(slot);
        kept.corner.push_back(corner);
        kept.modulus.push_back(cells.modulus[c]);
        kept.rest_volume.push_back(cells.rest_volume[c]);
    }
    cell_whole_.assign(cell_corner_.size(), 1);
    cell_force_.assign(cell_corner_.empty() ? 0 : 24 * n_pad_, Real(0));
    if (cell_corner_.empty()) particle_cell_.clear();
    return kept;
}

/// The critical step (stored and checked against a proven ceiling, or estimated) and the damped
/// one, by the policy heartprep stores (stability.h time_step_limits), unscaled: set_time_step
/// scales them (scaled_step).
template <class Real>
void BasicSolver<Real>::load_time_steps(const Particles& particles, const Springs& springs, const VolumeCells& cells) {
    double critical = 0.0;
    if (options_.critical_dt_ms > 0) {
        critical = options_.critical_dt_ms;
        // A stored step is checked against a proven ceiling (one pass over the springs): one
        // flipped bit in the file must not make the step 2¹⁶ times too long.
        const double ceiling = critical_step_ceiling_ms(particles, springs, cells.empty() ? nullptr : &cells);
        if (!std::isfinite(critical) || critical > ceiling * (1.0 + 1e-6))
            throw InputError("scenario: /solver critical_dt_ms is " + std::to_string(critical) + " ms, above the proven ceiling of " +
                             std::to_string(ceiling) + " ms for these springs" + (cells.empty() ? "" : ", volume cells") +
                             " and masses: the file is damaged or not from heartprep (rebuild it)");
    } else {
        critical = estimate_critical_time_step(particles, springs, 300, 1e-6, cells.empty() ? nullptr : &cells).critical_dt_ms;
        load_report_.critical_dt_estimated = true;
    }
    // The dashpots, support dampers and drag shorten the stable step (stability.h stable_step_ms).
    const double stored = options_.damped_critical_dt_ms > 0 && std::isfinite(options_.damped_critical_dt_ms) ? options_.damped_critical_dt_ms : 0.0;
    load_report_.unscaled_critical_dt_ms = critical;
    load_report_.unscaled_damped_critical_dt_ms = time_step_limits(critical, stored, options_.safety_factor, [&] {
        return estimate_damping_eigenvalue(particles, springs, options_.damping_ratio, options_.damping);
    }).damped_critical_dt_ms;
}

ScaledStep scaled_step(const SolverLoadReport& report, const SolverOptions& options, double mass_scale) {
    if (!valid_mass_scale(mass_scale))
        throw InputError("solver: the mass scale must lie in [" + std::to_string(min_mass_scale) + ", " + std::to_string(max_mass_scale) +
                         "], not " + std::to_string(mass_scale));
    const ScaledTimeSteps limits = scale_time_steps(report.unscaled_critical_dt_ms, report.unscaled_damped_critical_dt_ms, mass_scale);
    ScaledStep step;
    step.critical_dt_ms = limits.critical_dt_ms;
    step.damped_critical_dt_ms = limits.damped_critical_dt_ms;
    step.dt_ms = scaled_step_ms(report.unscaled_dt_ms, options.safety_factor, report.unscaled_damped_critical_dt_ms, limits.damped_critical_dt_ms);
    step.substeps = substeps_for_step(step.dt_ms, options.safety_factor * step.damped_critical_dt_ms, options.subdivide, Solver::max_substeps);
    return step;
}

// The set-up's members for the two solvers (solver.cpp instantiates the rest).
#define HEARTSIM_SOLVER_SETUP(Real)                                                                                            \
    template BasicSolver<Real>::BasicSolver(const Lattice&, const std::vector<std::array<std::int32_t, 18>>&, const SolverOptions&); \
    template BasicSolver<Real>::BasicSolver(const Particles&, const Springs&, const std::vector<std::array<std::int32_t, 18>>&,     \
                                            const SolverOptions&);                                                                 \
    template void BasicSolver<Real>::load_particles(const Particles&);                                                         \
    template void BasicSolver<Real>::load_springs(const Particles&, const Springs&, const std::vector<std::array<std::int32_t, 18>>&, \
                                                  const std::vector<std::int32_t>&);                                           \
    template void BasicSolver<Real>::load_time_steps(const Particles&, const Springs&, const VolumeCells&);                     \
    template VolumeCells BasicSolver<Real>::load_cells(const Particles&);
HEARTSIM_SOLVER_SETUP(float)
HEARTSIM_SOLVER_SETUP(double)
#undef HEARTSIM_SOLVER_SETUP

}  // namespace heartsim
