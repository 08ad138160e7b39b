// The CPU spring-mass solver: the class around the kernels (solver_kernels.h), which live in
// their own files, one per instruction set. Formulas, layout and sign conventions: docs/solver.md.
// fp-contract is off here as in the kernels (solver_kernels.h): the instrument passes must
// evaluate the same operations as the gl backend's shaders.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#pragma GCC diagnostic ignored "-Wpsabi"  // the cell pass's 8-float vectors: inlined, never passed across a call
#include "libmodel/sim/solver.h"
#include "libmodel/sim/cutting.h"
#include "libmodel/sim/solver_kernels.h"

#include "libmodel/ellipsoid.h"
#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/stability.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <limits>
#include <sstream>
#include <type_traits>
#include <utility>

namespace heartsim {

const char* to_string(SolverKernel kernel) {
    switch (kernel) {
    case SolverKernel::automatic: return "automatic";
    case SolverKernel::portable: return "portable";
    case SolverKernel::sse2: return "sse2";
    case SolverKernel::avx2: return "avx2";
    case SolverKernel::avx512: return "avx512";
    }
    return "?";
}

const char* to_string(InstrumentKind kind) {
    switch (kind) {
    case InstrumentKind::none: return "none";
    case InstrumentKind::probe: return "probe";
    case InstrumentKind::grabber: return "grabber";
    case InstrumentKind::scalpel: return "scalpel";
    case InstrumentKind::patch: return "patch";
    case InstrumentKind::needle: return "needle";
    case InstrumentKind::retractor: return "retractor";
    }
    return "none";
}

std::optional<InstrumentKind> instrument_kind_named(const std::string& word) {
    for (InstrumentKind kind : {InstrumentKind::none, InstrumentKind::probe, InstrumentKind::grabber, InstrumentKind::scalpel,
                                 InstrumentKind::patch, InstrumentKind::needle, InstrumentKind::retractor})
        if (word == to_string(kind)) return kind;
    return std::nullopt;
}

std::int8_t instrument_code(InstrumentKind kind) {
    switch (kind) {
    case InstrumentKind::none: return 0;
    case InstrumentKind::probe: return 1;
    case InstrumentKind::grabber: return 2;
    case InstrumentKind::scalpel: return 3;
    case InstrumentKind::patch: return 4;
    case InstrumentKind::needle: return 5;
    case InstrumentKind::retractor: return 6;
    }
    return 0;
}

std::optional<InstrumentKind> instrument_of_code(int code) {
    constexpr InstrumentKind kinds[] = {InstrumentKind::none,  InstrumentKind::probe,  InstrumentKind::grabber,  InstrumentKind::scalpel,
                                        InstrumentKind::patch, InstrumentKind::needle, InstrumentKind::retractor};
    if (code < 0 || code > 6) return std::nullopt;
    return kinds[code];
}

const char* to_string(WatchdogReason reason) {
    switch (reason) {
    case WatchdogReason::none: return "none";
    case WatchdogReason::non_finite: return "non-finite value";
    case WatchdogReason::speed: return "particle speed past the bound";
    case WatchdogReason::energy: return "energy growth";
    }
    return "?";
}

namespace {
using namespace solver_kernels;
}  // namespace

/// A probe during one substep, world frame, double.
template <class Real>
struct BasicSolver<Real>::ProbeFrame {
    int hand = 0;
    Eigen::Vector3d centre;
    Eigen::Matrix3d world_from_tool;
    Eigen::Vector3d previous_centre;           // the pose one substep earlier: the surface's motion
    Eigen::Matrix3d previous_world_from_tool;
    Eigen::Vector3d semi_axes;
    double bound2 = 0.0;  // squared bounding radius, with a margin
};

void check_loads(const std::vector<ParticleLoad>& loads, std::size_t particle_count) {
    for (std::size_t q = 0; q < loads.size(); ++q) {
        const ParticleLoad& load = loads[q];
        const std::string which = "load " + std::to_string(q) + " (particle " + std::to_string(load.particle) + ")";
        if (load.particle < 0 || std::size_t(load.particle) >= particle_count)
            throw InputError("solver: " + which + ": the particle index is outside [0, " + std::to_string(particle_count) + ")");
        if (!load.force_n.allFinite()) throw InputError("solver: " + which + ": the force is not finite");
        if (q > 0 && load.particle <= loads[q - 1].particle)
            throw InputError("solver: " + which + ": loads must be sorted by particle with no particle twice (load " +
                             std::to_string(q - 1) + " is on particle " + std::to_string(loads[q - 1].particle) + ")");
    }
}

template <class Real>
void BasicSolver<Real>::set_contact_skin(std::vector<float> skin) {
    if (!skin.empty() && skin.size() != n_)
        throw InputError("solver: the contact skin has " + std::to_string(skin.size()) + " values for " + std::to_string(n_) + " particles");
    const double limit = 4.0 * double(max_rest_length_);
    double largest = 0.0;
    for (std::size_t i = 0; i < skin.size(); ++i) {
        if (!(std::abs(double(skin[i])) <= limit))
            throw InputError("solver: particle " + std::to_string(i) + "'s contact skin must be finite and within " + std::to_string(limit) +
                             " mm of 0, not " + std::to_string(skin[i]));
        largest = std::max(largest, double(skin[i]));
    }
    skin_ = std::move(skin);
    max_reach_beyond_ = largest * options_.contact_skin;
}

template <class Real>
void BasicSolver<Real>::set_loads(std::vector<ParticleLoad> loads) {
    check_loads(loads, n_);
    std::vector<std::int32_t> particle(loads.size());
    std::vector<Real> force(3 * loads.size());
    for (std::size_t q = 0; q < loads.size(); ++q) {
        particle[q] = loads[q].particle;
        for (int c = 0; c < 3; ++c) force[3 * q + std::size_t(c)] = Real(loads[q].force_n[c]);
    }
    loads_ = std::move(loads);
    load_particle_ = std::move(particle);
    load_force_ = std::move(force);
}

template <class Real>
void BasicSolver<Real>::run_beside_next_step(std::function<void()> task) {
    beside_ = std::move(task);
}

template <class Real>
void BasicSolver<Real>::set_time_step(double dt_ms) {
    if (!(dt_ms > 0) || !std::isfinite(dt_ms)) throw InputError("solver: the time step must be positive and finite");
    SolverLoadReport report = load_report_;
    report.unscaled_dt_ms = dt_ms;
    const ScaledStep step = scaled_step(report, options_, options_.mass_scale);  // throws before anything changes
    load_report_.unscaled_dt_ms = dt_ms;
    apply_step(step);
}

template <class Real>
void BasicSolver<Real>::set_mass_scale(double mass_scale) {
    const ScaledStep step = scaled_step(load_report_, options_, mass_scale);  // throws before anything changes
    options_.mass_scale = mass_scale;
    apply_step(step);
    snapshot();
}

template <class Real>
void BasicSolver<Real>::apply_step(const ScaledStep& step) {
    critical_dt_ms_ = step.critical_dt_ms;
    damped_critical_dt_ms_ = step.damped_critical_dt_ms;
    load_report_.critical_dt_ms = critical_dt_ms_;
    load_report_.damped_critical_dt_ms = damped_critical_dt_ms_;
    load_report_.mass_scale = options_.mass_scale;
    const double old_h = h_;
    dt_ms_ = step.dt_ms;
    substeps_ = step.substeps;
    h_ = dt_ms_ / substeps_;
    load_report_.substeps = substeps_;
    load_report_.substep_ms = h_;
    build_step_constants();
    if (old_h > 0 && old_h != h_) {
        // Keep velocities: the Verlet state stores displacement per substep, u = v·h.
        const Real ratio = Real(h_ / old_h);
        for (std::size_t i = 0; i < n_pad_; ++i)
            for (int c = 0; c < 3; ++c) motion_[state_stride * i + std::size_t(c)] = motion_[state_stride * i + std::size_t(c)] * ratio;
        snapshot();
    }
}

template <class Real>
void BasicSolver<Real>::build_step_constants() {
    // The inertia is S·m (mass scaling); the kernel's weight term m·g stays physical.
    const double h2 = h_ * h_, s = options_.mass_scale;
    for (std::size_t i = 0; i < n_pad_; ++i) inverse_mass_h2_[i] = movable_[i] ? Real(h2 / (double(mass_[i]) * s)) : Real(0);
    support_damping_over_h_.resize(support_damping_.size());
    for (std::size_t i = 0; i < support_damping_.size(); ++i) support_damping_over_h_[i] = Real(double(support_damping_[i]) / h_);
    dashpot_over_h_.resize(dashpot_.size());
    for (std::size_t t = 0; t < dashpot_.size(); ++t) dashpot_over_h_[t] = Real(double(dashpot_[t]) / h_);
}

template <class Real>
void BasicSolver<Real>::reset() {
    time_ms_ = 0.0;
    reset_tissue();
}

template <class Real>
void BasicSolver<Real>::reset_tissue() {
    for (int hand = 0; hand < hands; ++hand) release_hand(hand, false);
    free_stayed();  // the scenario's anchoring again, before the start motion below reads it
    neighbour_ = uncut_neighbour_;
    refresh_cells();  // every cell whole again
    set_loads({});
    cut_.clear();
    strokes_.clear();
    last_cuts_ = 0;
    for (std::size_t i = 0; i < n_pad_; ++i)
        for (std::size_t c = 0; c < 4; ++c) {
            current_[state_stride * i + c] = next_[state_stride * i + c] = rest_[4 * i + c];
            motion_[state_stride * i + c] = next_motion_[state_stride * i + c] = Real(0);
        }
    // At rest the springs and supports balance the gravity the rest state was built for
    // (`balanced_gravity`; zero for an unbalanced rest state, where they exert nothing): the rest
    // acceleration is g − g_balanced, and u₀ = x₀ − x₋₁ = −½·a·h² starts the motion at second order.
    const Eigen::Vector3d rest_acceleration = (options_.gravity - options_.balanced_gravity) / options_.mass_scale;
    for (std::size_t i = 0; i < n_pad_; ++i)
        if (movable_[i])
            for (int c = 0; c < 3; ++c) motion_[state_stride * i + std::size_t(c)] = Real(-0.5 * rest_acceleration[c] * h_ * h_);
    for (auto& list : touched_) list.clear();
    good_energy_ = 0.0;
    substeps_since_check_ = 0;
    snapshot();
}

template <class Real>
void BasicSolver<Real>::set_state(const std::vector<Eigen::Vector3d>& positions, const std::vector<Eigen::Vector3d>& velocities) {
    if (positions.size() != n_ || velocities.size() != n_) throw InputError("solver: set_state needs N positions and N velocities");
    for (std::size_t i = 0; i < n_; ++i)
        if (!positions[i].allFinite() || !velocities[i].allFinite()) throw InputError("solver: set_state with a non-finite value");
    for (std::size_t i = 0; i < n_; ++i) {
        const Eigen::Vector3d v = movable_[i] ? velocities[i] : Eigen::Vector3d::Zero();
        for (int c = 0; c < 3; ++c) {
            current_[state_stride * i + std::size_t(c)] = Real(positions[i][c]);
            motion_[state_stride * i + std::size_t(c)] = Real(v[c] * h_);
        }
    }
    // Taylor start: u₀ = x₀ − x₋₁ = v·h − ½·a·h², a = (f + m·g)/m − γ·v (Verlet is then second order
    // from the first step; u₀ = v·h alone would shift time by h/2, a first-order error).
    std::vector<Eigen::Vector3d> half_step(n_, Eigen::Vector3d::Zero());
    for (std::size_t i = 0; i < n_; ++i) {
        if (!movable_[i]) continue;
        const double m = double(mass_[i]);
        const Eigen::Vector3d a = ((force_on(i) + m * options_.gravity) / m - options_.damping * velocities[i]) / options_.mass_scale;
        half_step[i] = 0.5 * h_ * h_ * a;
    }
    for (std::size_t i = 0; i < n_; ++i) {
        const Eigen::Vector3d v = movable_[i] ? velocities[i] : Eigen::Vector3d::Zero();
        for (int c = 0; c < 3; ++c) motion_[state_stride * i + std::size_t(c)] = Real(v[c] * h_ - half_step[i][c]);
    }
    for (auto& list : touched_) list.clear();
    good_energy_ = compute_energy(false).total();
    substeps_since_check_ = 0;
    snapshot();
}

template <class Real>
void BasicSolver<Real>::snapshot() {
    good_current_.resize(4 * n_pad_);
    for (std::size_t i = 0; i < n_pad_; ++i)
        for (std::size_t c = 0; c < 4; ++c) good_current_[4 * i + c] = current_[state_stride * i + c];
    good_time_ms_ = time_ms_;
    consecutive_restores_ = 0;
}

template <class Real>
void BasicSolver<Real>::restore() {
    // At rest: replaying the motion that led to the failure would lead to it again.
    for (std::size_t i = 0; i < n_pad_; ++i)
        for (std::size_t c = 0; c < 4; ++c) {
            current_[state_stride * i + c] = good_current_[4 * i + c];
            motion_[state_stride * i + c] = Real(0);
        }
    time_ms_ = good_time_ms_;
    for (auto& list : touched_) list.clear();
    substeps_since_check_ = 0;
    // Grabs end (the tissue slipped out; a retractor's does not stay) and blades lift: the runtime
    // sees no held particles and cuts nothing until it grabs again. What retractors left stayed
    // is free again: the scenario's anchoring.
    for (int hand = 0; hand < hands; ++hand)
        if (hand_[std::size_t(hand)].grabbing || hand_[std::size_t(hand)].cutting) release_hand(hand, false);
    free_stayed();
}

template <class Real>
Real BasicSolver<Real>::strain_at(std::size_t i, const Real* x, const Real* positions) const {
    Real worst = 0;
    for (int s = 0; s < slot_count; ++s) {
        const std::size_t t = entry_of(i, s);
        const std::size_t j = std::size_t(neighbour_[t]);
        if (j == i) continue;
        const Real* xj = positions + state_stride * j;
        const Real dx = x[0] - xj[0], dy = x[1] - xj[1], dz = x[2] - xj[2];
        worst = std::max(worst, std::abs(std::sqrt(dx * dx + dy * dy + dz * dz) / rest_length_[t] - Real(1)));
    }
    return worst;
}

template <class Real>
KernelData<Real> BasicSolver<Real>::kernel_data() const {
    KernelData<Real> k{};
    k.x = current_;
    k.u = motion_;
    k.xn = next_;
    k.un = next_motion_;
    k.neighbour = neighbour_.data();
    if (uniform_slots_) {
        k.rest_length = slot_rest_length_.data();
        k.stiffness = slot_stiffness_.data();
        k.per_entry_parameters = false;
    } else {
        k.rest_length = rest_length_.data();
        k.stiffness = stiffness_.data();
        k.per_entry_parameters = true;
    }
    k.dashpot = dashpot_over_h_.data();
    k.mass = mass_.data();
    k.inverse_mass_h2 = inverse_mass_h2_.data();
    k.keep = Real(1.0 - options_.damping * h_ / options_.mass_scale);  // the drag force γ·m·v on the inertia S·m
    for (int c = 0; c < 3; ++c) k.gravity[c] = Real(options_.gravity[c]);
    double max_displacement = options_.max_displacement_fraction * double(min_rest_length_);
    for (const HandState& state : hand_)
        if (state.instrument.kind != InstrumentKind::none) max_displacement = std::max(max_displacement, state.instrument.semi_axes.maxCoeff());
    k.max_displacement2 = options_.watchdog && std::isfinite(max_displacement) ? Real(max_displacement * max_displacement)
                                                                                 : std::numeric_limits<Real>::infinity();
    k.support_point = support_point_.data();
    k.support_stiffness = support_stiffness_.data();
    k.support_damping = support_damping_over_h_.data();
    return k;
}

template <class Real>
int BasicSolver<Real>::probe_frames(const InstrumentPose* previous_poses, const InstrumentPose* poses, std::array<ProbeFrame, hands>& probes) const {
    int probe_count = 0;
    for (int hand = 0; hand < hands; ++hand) {
        const HandState& state = hand_[std::size_t(hand)];
        if (state.instrument.kind != InstrumentKind::probe) continue;
        ProbeFrame& p = probes[std::size_t(probe_count++)];
        p.hand = hand;
        p.centre = poses[hand].position;
        p.world_from_tool = poses[hand].orientation.toRotationMatrix();
        p.previous_centre = previous_poses[hand].position;
        p.previous_world_from_tool = previous_poses[hand].orientation.toRotationMatrix();
        p.semi_axes = state.instrument.semi_axes;
        const double radius = (state.instrument.semi_axes.maxCoeff() + max_reach_beyond_) * (1 + 1e-3) + 1e-3;
        p.bound2 = radius * radius;
    }
    return probe_count;
}

// Projects particle i out of the probe if inside (exact test in double; the stored float position
// is re-checked so rounding cannot leave it inside). The contact is inelastic and frictionless:
// the particle keeps its own displacement u of this substep except that its normal component
// becomes at least the probe surface's, so a deep or sudden probe does not fling particles out
// at penetration/h. Only this particle's next position and motion change (nothing else reads
// them during the substep).
template <class Real>
void BasicSolver<Real>::project_out_of_probe(const ProbeFrame& p, std::size_t i, std::vector<std::int32_t>& touched, std::size_t& pierced) {
    Real* x = next_ + state_stride * i;
    const Eigen::Vector3d world(static_cast<double>(x[0]), static_cast<double>(x[1]), static_cast<double>(x[2]));
    Eigen::Vector3d local = p.world_from_tool.transpose() * (world - p.centre);
    // The probe as this particle meets it: grown by the particle's skin (set_contact_skin).
    const Eigen::Vector3d semi_axes = met_axes(p.semi_axes, reach_beyond(i));
    const double r2 = local.cwiseQuotient(semi_axes).squaredNorm();
    if (!(r2 < 1.0)) return;
    // To the nearest point of the surface (ellipsoid.h), then just outside it (1e-6 relative)
    // so that float rounding and a caller's own evaluation of the pose cannot see it inside.
    local = nearest_point_on_ellipsoid(local, semi_axes);
    double factor = 1.0 + 1e-6;
    Eigen::Vector3d stored;
    for (int attempt = 0; attempt < 60; ++attempt) {
        const Eigen::Vector3d out = p.centre + p.world_from_tool * (local * factor);
        for (int c = 0; c < 3; ++c) x[c] = Real(out[c]);
        stored = Eigen::Vector3d(static_cast<double>(x[0]), static_cast<double>(x[1]), static_cast<double>(x[2]));
        if ((p.world_from_tool.transpose() * (stored - p.centre)).cwiseQuotient(semi_axes).squaredNorm() >= 1.0 + 1e-6) break;
        factor *= 1 + 1e-6 * double(1 << std::min(attempt, 20));
    }
    // Pierced (SolverOptions::probe_pierce_strain): the surface point would stretch one of its
    // springs too far, measured against the neighbours' positions at the start of the substep
    // (the ones this pass does not write), so the particle stays inside, untouched.
    if (options_.probe_pierce_strain > 0 && double(strain_at(i, x, current_)) > options_.probe_pierce_strain) {
        for (int c = 0; c < 3; ++c) x[c] = Real(world[c]);
        ++pierced;
        return;
    }
    const Eigen::Vector3d normal = (p.world_from_tool * local.cwiseQuotient(semi_axes.cwiseProduct(semi_axes))).normalized();
    const Eigen::Vector3d surface_motion = stored - (p.previous_centre + p.previous_world_from_tool * (local * factor));
    const Real* xc = current_ + state_stride * i;
    Eigen::Vector3d u = world - Eigen::Vector3d(static_cast<double>(xc[0]), static_cast<double>(xc[1]), static_cast<double>(xc[2]));
    u += std::max(0.0, (surface_motion - u).dot(normal)) * normal;
    touched.push_back(std::int32_t(i));
    Real* motion = next_motion_ + state_stride * i;
    for (int c = 0; c < 3; ++c) motion[c] = Real(u[c]);
}

// A chunk's loads and the probes' projection, after its springs and integration (the next state
// only, its own particles).
template <class Real>
void BasicSolver<Real>::load_and_project(std::size_t chunk, const std::array<ProbeFrame, hands>& probes, int probe_count) {
    const std::size_t first = chunk * chunk_groups, last = std::min(groups_, first + chunk_groups);
    // External loads on this chunk's particles (set_loads) and the volume term's forces (cell_pass):
    // h²F/(S·m) more displacement, as F in the kernel's force sum would give, rounded apart as the
    // gl step pass does. With the volume term, F = (Σ of the particle's cells' forces, in corner
    // order) + its load, one sum as the gl backend's gather pass makes it.
    const auto load_begin = std::lower_bound(load_particle_.begin(), load_particle_.end(), std::int32_t(first * lane_count));
    const auto load_end = std::lower_bound(load_begin, load_particle_.end(), std::int32_t(last * lane_count));
    if (!cell_corner_.empty()) {
        auto load_at = load_begin;
        const std::size_t end = std::min(n_, last * lane_count);
        for (std::size_t i = first * lane_count; i < end; ++i) {
            while (load_at != load_end && std::size_t(*load_at) < i) ++load_at;
            if (!movable_[i] || held_by_[i] >= 0) continue;
            Real f[3] = {Real(0), Real(0), Real(0)};
            const Real* slot = cell_force_.data() + 24 * i;  // its 8 slots (zero where it is no cell's corner r)
            for (int r = 0; r < 8; ++r)
                for (int k = 0; k < 3; ++k) f[k] = f[k] + slot[3 * r + k];
            if (load_at != load_end && std::size_t(*load_at) == i) {
                const std::size_t q = std::size_t(load_at - load_particle_.begin());
                for (int k = 0; k < 3; ++k) f[k] = f[k] + load_force_[3 * q + std::size_t(k)];
            }
            Real* x = next_ + state_stride * i;
            Real* motion = next_motion_ + state_stride * i;
            for (int c = 0; c < 3; ++c) {
                const Real step = inverse_mass_h2_[i] * f[c];
                x[c] = x[c] + step;
                motion[c] = motion[c] + step;
            }
        }
    } else
        for (auto at = load_begin; at != load_end; ++at) {
            const std::size_t i = std::size_t(*at), q = std::size_t(at - load_particle_.begin());
            if (!movable_[i] || held_by_[i] >= 0) continue;
            Real* x = next_ + state_stride * i;
            Real* motion = next_motion_ + state_stride * i;
            for (int c = 0; c < 3; ++c) {
                const Real step = inverse_mass_h2_[i] * load_force_[3 * q + std::size_t(c)];
                x[c] = x[c] + step;
                motion[c] = motion[c] + step;
            }
        }
    for (int hand = 0; hand < hands; ++hand) touched_[chunk * hands + std::size_t(hand)].clear();
    for (int pi = 0; pi < probe_count; ++pi) {
        const ProbeFrame& p = probes[std::size_t(pi)];
        auto& touched = touched_[chunk * hands + std::size_t(p.hand)];
        const Real cx = Real(p.centre.x()), cy = Real(p.centre.y()), cz = Real(p.centre.z()), bound2 = Real(p.bound2);
        const std::size_t end = std::min(n_, last * lane_count);
        std::size_t i = first * lane_count;
#ifdef HEARTSIM_SOLVER_X86
        if constexpr (std::is_same_v<Real, float>) {
            // 16 particles per test where the avx512 kernel runs (same operations as below).
            if (load_report_.kernel == SolverKernel::avx512)
                for (; i + 16 <= last * lane_count; i += 16)
                    for (unsigned mask = near_probe16(next_ + state_stride * i, cx, cy, cz, bound2); mask != 0; mask &= mask - 1) {
                        const std::size_t q = i + std::size_t(__builtin_ctz(mask));
                        if (q < n_ && movable_[q] && held_by_[q] < 0) project_out_of_probe(p, q, touched, chunk_pierced_[chunk]);
                    }
        }
#endif
        for (; i < end; ++i) {
            const Real* x = next_ + state_stride * i;
            const Real dx = x[0] - cx, dy = x[1] - cy, dz = x[2] - cz;
            if (dx * dx + dy * dy + dz * dz < bound2 && movable_[i] && held_by_[i] < 0) project_out_of_probe(p, i, touched, chunk_pierced_[chunk]);
        }
    }
}

// Grabbed particles follow the tool rigidly, unless that would stretch one of their springs past
// the slip strain: then the particle slips out of the grabber and moves freely (it keeps the
// position the integration gave it, x + u). Order-free, in three passes as the gl backend's one
// work group runs them (solver_shaders.h `after_step`): every held particle moves to its target;
// each then measures its springs with its held neighbours at their targets and the free ones
// where the integration put them; the ones past the slip strain go back and are free. The held
// lists keep their order, so the result is deterministic.
template <class Real>
void BasicSolver<Real>::follow_grabbers(const InstrumentPose* poses) {
    std::array<Eigen::Matrix3d, hands> rotation;
    auto world_of = [&](int hand, std::size_t q) {
        return Eigen::Vector3d(poses[hand].position + rotation[std::size_t(hand)] * hand_[std::size_t(hand)].held_local[q]);
    };
    for (int hand = 0; hand < hands; ++hand) {
        const HandState& state = hand_[std::size_t(hand)];
        if (!state.grabbing) continue;
        rotation[std::size_t(hand)] = poses[hand].orientation.toRotationMatrix();
        for (std::size_t q = 0; q < state.held.size(); ++q) {
            const Eigen::Vector3d world = world_of(hand, q);
            Real* x = next_ + state_stride * std::size_t(state.held[q]);
            for (int c = 0; c < 3; ++c) x[c] = Real(world[c]);
        }
    }
    constexpr std::int8_t slipping = -2;
    if (options_.grab_slip_strain > 0)
        for (int hand = 0; hand < hands; ++hand)
            for (const std::int32_t i : hand_[std::size_t(hand)].held)
                if (double(strain_at(std::size_t(i), next_ + state_stride * std::size_t(i), next_)) > options_.grab_slip_strain)
                    held_by_[std::size_t(i)] = slipping;
    for (int hand = 0; hand < hands; ++hand) {
        HandState& state = hand_[std::size_t(hand)];
        if (!state.grabbing) continue;
        state.keep_held([&](std::size_t q) {
            const std::size_t i = std::size_t(state.held[q]);
            Real* x = next_ + state_stride * i;
            Real* motion = next_motion_ + state_stride * i;
            if (held_by_[i] == slipping) {
                for (int c = 0; c < 3; ++c) x[c] = current_[state_stride * i + std::size_t(c)] + motion[c];
                held_by_[i] = -1;
                ++slipped_;
                return false;
            }
            const Eigen::Vector3d world = world_of(hand, q);
            for (int c = 0; c < 3; ++c) motion[c] = Real(world[c] - double(current_[state_stride * i + std::size_t(c)]));
            return true;
        });
    }
}

template <class Real>
void BasicSolver<Real>::substep(const InstrumentPose* previous_poses, const InstrumentPose* poses, bool& bad,
                                const std::function<void()>* beside) {
    const KernelData<Real> k = kernel_data();
    const GroupFunction<Real> group_function = choose_group_function<Real>(load_report_.kernel, damped_, supported_);
    std::array<ProbeFrame, hands> probes;
    const int probe_count = probe_frames(previous_poses, poses, probes);

    // A chunk's springs and integration (the kernel: reads the current state, writes the next);
    // then its loads and the probes' projection (the next state only, its own particles).
    auto integrate = [&](std::size_t chunk) {
        const std::size_t first = chunk * chunk_groups, last = std::min(groups_, first + chunk_groups);
        chunk_bad_[chunk] = group_function(k, first, last);
    };
    const tbb::blocked_range<std::size_t> all_chunks(0, chunks_);
    if (!cell_corner_.empty()) cell_pass();  // reads the current state only
    if (beside && *beside) {
        // run_beside_next_step: the task beside the kernel (it may read the current state and set
        // the loads, which the kernel reads neither of), then the loads and the probes: the same
        // operations on the same values as the one pass below, to the bit.
        tbb::parallel_invoke([&] { (*beside)(); },
                             [&] {
                                 tbb::parallel_for(all_chunks, [&](const tbb::blocked_range<std::size_t>& range) {
                                     for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk) integrate(chunk);
                                 });
                             });
        tbb::parallel_for(all_chunks, [&](const tbb::blocked_range<std::size_t>& range) {
            for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk) load_and_project(chunk, probes, probe_count);
        });
    } else {
        tbb::parallel_for(all_chunks, [&](const tbb::blocked_range<std::size_t>& range) {
            for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk)
                integrate(chunk), load_and_project(chunk, probes, probe_count);
        });
    }

    bool any_grab = false;
    for (int hand = 0; hand < hands; ++hand) any_grab = any_grab || hand_[std::size_t(hand)].grabbing;
    if (any_grab) follow_grabbers(poses);

    for (std::size_t chunk = 0; chunk < chunks_; ++chunk) {
        bad = bad || chunk_bad_[chunk];
        pierced_ += chunk_pierced_[chunk];
        chunk_pierced_[chunk] = 0;
    }
    std::swap(current_, next_);
    std::swap(motion_, next_motion_);
    time_ms_ += h_;
}

template <class Real>
StepReport BasicSolver<Real>::step(int steps) {
    StepReport report;
    if (steps <= 0) return report;
    const long long total = (long long)steps * substeps_;
    const double start_ms = time_ms_;
    const std::function<void()> beside = std::exchange(beside_, nullptr);  // this call's first substep only
    std::array<InstrumentPose, hands> start, poses, previous_poses;
    for (int hand = 0; hand < hands; ++hand) start[std::size_t(hand)] = hand_[std::size_t(hand)].pose;
    // A lowered scalpel cuts what its blade sweeps from this call's start pose to its target,
    // before the substeps: the springs it crosses exert nothing from the first substep on.
    // Its force, the tissue's resistance to the cut, follows from the springs it cut
    // (cutting_force.h): the gl backend's blade pass applies the same constants to its count.
    last_cuts_ = 0;
    for (int hand = 0; hand < hands; ++hand) {
        HandState& state = hand_[std::size_t(hand)];
        state.cuts = 0;
        if (!state.cutting || !state.placed) continue;
        const double length = 2.0 * state.instrument.semi_axes.z();
        const BladeSweep sweep = blade_sweep(state.pose, state.target, length, cut_search_margin(float(max_rest_length_)));
        if (sweep.cuts_anything) strokes_.sweep(hand, state.pose, state.target, length);
        state.cuts = cut(sweep);
        last_cuts_ += state.cuts;
        const BladeStep blade = blade_step(options_.cutting_resistance, lattice_frame_, state.pose, state.target, length, double(steps) * dt_ms_);
        state.blade = next_blade_state(state.blade, blade, state.cuts);
    }

    auto fire = [&](WatchdogReason reason, const std::string& detail) {
        const double failed_at = time_ms_;
        restore();
        ++watchdog_events_;
        report.diverged = true;
        report.reason = reason;
        report.gave_up = ++consecutive_restores_ >= options_.max_consecutive_restores;
        // Only the steps of this call that survived the restore count.
        report.steps = int(std::max(0.0, std::floor((time_ms_ - start_ms) / dt_ms_ + 1e-9)));
        std::ostringstream message;
        message << "solver watchdog: " << to_string(reason) << " at t = " << failed_at << " ms (substep " << h_
                << " ms, critical " << critical_dt_ms_ << " ms)" << detail << "; restored the state of t = " << time_ms_
                << " ms at rest, grabs released";
        if (report.gave_up)
            message << "; " << consecutive_restores_ << " restores in a row without a new good state: the simulation cannot recover";
        report.message = message.str();
    };

    for (long long q = 1; q <= total; ++q) {
        const double fraction = double(q) / double(total);
        const double previous_fraction = double(q - 1) / double(total);
        for (int hand = 0; hand < hands; ++hand) {
            poses[std::size_t(hand)] = interpolate(start[std::size_t(hand)], hand_[std::size_t(hand)].target, fraction);
            previous_poses[std::size_t(hand)] = interpolate(start[std::size_t(hand)], hand_[std::size_t(hand)].target, previous_fraction);
        }
        bool bad = false;
        substep(previous_poses.data(), poses.data(), bad, q == 1 ? &beside : nullptr);
        ++report.substeps;
        if (bad && options_.watchdog) {
            bool finite = true;
            for (std::size_t i = 0; i < state_stride * n_ && finite; ++i) finite = std::isfinite(current_[i]);  // positions and motions
            fire(finite ? WatchdogReason::speed : WatchdogReason::non_finite,
                 finite ? ", a particle moved more than " + std::to_string(options_.max_displacement_fraction) +
                              " of the shortest rest length in one substep"
                        : "");
            break;
        }
        if (options_.watchdog && ++substeps_since_check_ >= options_.watchdog_interval) {
            substeps_since_check_ = 0;
            const SolverEnergy energy = compute_energy(false);
            const double e = energy.total();
            if (!std::isfinite(e)) {
                fire(WatchdogReason::non_finite, "");
                break;
            }
            const double limit = options_.energy_growth_limit * (std::max(good_energy_, 0.0) + energy_floor_);
            if (e > limit) {
                fire(WatchdogReason::energy, ", energy " + std::to_string(e) + " mJ above the limit " + std::to_string(limit) + " mJ");
                break;
            }
            // Only an intact state becomes the restore point; a torn one (a spring stretched past
            // the strain limit) is stepped on from but never returned to.
            if (options_.restore_strain_limit <= 0 || energy.max_strain <= options_.restore_strain_limit) {
                good_energy_ = e;
                snapshot();
            }
        }
        if (q % substeps_ == 0) ++report.steps;
    }
    if (!options_.watchdog) {
        // Even unguarded, nothing non-finite leaves the solver.
        bool finite = true;
        for (std::size_t i = 0; i < state_stride * n_ && finite; ++i) finite = std::isfinite(current_[i]);  // positions and motions
        if (!finite) fire(WatchdogReason::non_finite, "");
    }
    for (auto& state : hand_) state.pose = state.target;
    return report;
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::force_on(std::size_t i) const {
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    const Real* xi = current_ + state_stride * i;
    const Real* ui = motion_ + state_stride * i;
    for (int s = 0; s < slot_count; ++s) {
        const std::size_t t = entry_of(i, s);
        const std::size_t j = std::size_t(neighbour_[t]);
        if (j == i) continue;
        const Real* xj = current_ + state_stride * j;
        const Real* uj = motion_ + state_stride * j;
        const Eigen::Vector3d d(double(xj[0]) - xi[0], double(xj[1]) - xi[1], double(xj[2]) - xi[2]);
        const double length = std::max(d.norm(), 1e-15);
        double scale = double(stiffness_[t]) * (length - double(rest_length_[t])) / length;
        if (damped_) {
            const Eigen::Vector3d du(double(uj[0]) - ui[0], double(uj[1]) - ui[1], double(uj[2]) - ui[2]);
            scale += double(dashpot_over_h_[t]) * du.dot(d) / (length * length);
        }
        force += scale * d;
    }
    if (supported_ && support_stiffness_[i] != Real(0)) {
        const Real* y = support_point_.data() + 4 * i;
        force += double(support_stiffness_[i]) * Eigen::Vector3d(double(y[0]) - xi[0], double(y[1]) - xi[1], double(y[2]) - xi[2]);
        force -= double(support_damping_over_h_[i]) * Eigen::Vector3d(double(ui[0]), double(ui[1]), double(ui[2]));
    }
    if (!particle_cell_.empty()) force += volume_force_on(i);
    return force;
}

// The volume term (volume_cells.h): W = ½·Δλ/|V₀|·(V − V₀)² per whole cell, f = −Δλ/|V₀|·(V − V₀)·∂V/∂x.
template <class Real>
void BasicSolver<Real>::refresh_cells() {
    for (std::size_t c = 0; c < cell_corner_.size(); ++c) {
        bool whole = true;
        for (std::size_t q = 0; q < cell_springs.size() && whole; ++q)
            whole = neighbour_[entry_of(std::size_t(cell_corner_[c][std::size_t(cell_springs[q][0])]), cell_spring_slot_[c][q])] ==
                    cell_corner_[c][std::size_t(cell_springs[q][1])];
        cell_whole_[c] = whole ? 1 : 0;
    }
}

namespace {

/// What the float cell pass reads and writes (BasicSolver<float>::cell_pass).
struct CellLanes {
    const float* current;
    const std::array<std::int32_t, 8>* corner;
    const std::uint8_t* whole;
    const float* k12;
    const float* rest12;
    float* force;  ///< per particle, 8 slots of 3: the force of the cell it is corner r of, in slot r
    std::size_t cells;
};

/// Cells 8b … 8b+7 in the lanes of a vector of floats: lane by lane the operations of
/// cell_forces<float> (products, sums, differences; none fused), so the same bits as one cell at
/// a time. A cell that is not whole (or past the end) runs as a point of zero volume and k₁₂ 0.
__attribute__((always_inline)) inline void cell_block_body(const CellLanes& c, std::size_t b) {
    using Lanes = float __attribute__((vector_size(32)));
    Lanes p[8][3], k12{}, rest12{};
    for (int l = 0; l < 8; ++l) {
        const std::size_t cell = 8 * b + std::size_t(l);
        const bool live = cell < c.cells && c.whole[cell];
        const float* x0 = c.current + state_stride * std::size_t(live ? c.corner[cell][0] : 0);
        for (int q = 0; q < 8; ++q) {
            const float* x = live ? c.current + state_stride * std::size_t(c.corner[cell][std::size_t(q)]) : x0;
            for (int k = 0; k < 3; ++k) p[q][k][l] = x[k] - x0[k];
        }
        if (live) k12[l] = c.k12[cell], rest12[l] = c.rest12[cell];
    }
    Lanes g[8][3];
    const Lanes volume12 = cell_volume12<Lanes>(p, g);
    const Lanes pressure = -(k12 * (volume12 - rest12));
    for (int l = 0; l < 8; ++l) {
        const std::size_t cell = 8 * b + std::size_t(l);
        if (cell >= c.cells) break;
        for (int q = 0; q < 8; ++q) {
            float* out = c.force + 24 * std::size_t(c.corner[cell][std::size_t(q)]) + 3 * std::size_t(q);  // corner q's slot of its particle
            for (int k = 0; k < 3; ++k) out[k] = pressure[l] * g[q][k][l];
        }
    }
}

void cell_block(const CellLanes& c, std::size_t b) { cell_block_body(c, b); }
#ifdef HEARTSIM_SOLVER_X86
/// The same with AVX2's 8-float registers (no FMA: nothing fuses).
__attribute__((target("avx2"))) void cell_block_avx2(const CellLanes& c, std::size_t b) { cell_block_body(c, b); }
#endif

}  // namespace

template <class Real>
void BasicSolver<Real>::cell_pass() {
    if constexpr (std::is_same_v<Real, float>) {
        const std::size_t blocks = (cell_corner_.size() + 7) / 8;
        const CellLanes lanes{current_, cell_corner_.data(), cell_whole_.data(), cell_k12_.data(), cell_rest12_.data(), cell_force_.data(),
                              cell_corner_.size()};
#ifdef HEARTSIM_SOLVER_X86
        const bool avx2 = cpu_has_avx2();
#else
        const bool avx2 = false;
#endif
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 32), [&](const tbb::blocked_range<std::size_t>& range) {
            for (std::size_t b = range.begin(); b != range.end(); ++b) {
#ifdef HEARTSIM_SOLVER_X86
                if (avx2) {
                    cell_block_avx2(lanes, b);
                    continue;
                }
#endif
                cell_block(lanes, b);
            }
        });
        (void)avx2;
        return;
    }
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cell_corner_.size(), 256), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            Real out[24] = {};
            const Real* x[8];
            for (int q = 0; q < 8; ++q) x[q] = current_ + state_stride * std::size_t(cell_corner_[c][std::size_t(q)]);
            if (cell_whole_[c]) cell_forces<Real>(x, cell_k12_[c], cell_rest12_[c], out);
            for (int q = 0; q < 8; ++q)
                for (int k = 0; k < 3; ++k) cell_force_[24 * std::size_t(cell_corner_[c][std::size_t(q)]) + 3 * std::size_t(q) + std::size_t(k)] = out[3 * q + k];
        }
    });
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::volume_force_on(std::size_t i) const {
    // The cells' forces as the pass computes them (Real), summed in double as the gl force pass does.
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    for (int r = 0; r < 8; ++r) {
        const std::int32_t c = particle_cell_[i][std::size_t(r)];
        if (c < 0 || !cell_whole_[std::size_t(c)]) continue;
        const Real* x[8];
        for (int q = 0; q < 8; ++q) x[q] = current_ + state_stride * std::size_t(cell_corner_[std::size_t(c)][std::size_t(q)]);
        Real out[24];
        cell_forces<Real>(x, cell_k12_[std::size_t(c)], cell_rest12_[std::size_t(c)], out);
        force += Eigen::Vector3d(double(out[3 * r]), double(out[3 * r + 1]), double(out[3 * r + 2]));
    }
    return force;
}

template <class Real>
double BasicSolver<Real>::volume_energy() const {
    // ½·Δλ/|V₀|·(V − V₀)² = ½·k₁₂·(12V − 12V₀)², in double.
    double energy = 0.0;
    for (std::size_t c = 0; c < cell_corner_.size(); ++c) {
        if (!cell_whole_[c]) continue;
        const auto& corner = cell_corner_[c];
        const Real* x0 = current_ + state_stride * std::size_t(corner[0]);
        double p[8][3];
        for (int q = 0; q < 8; ++q) {
            const Real* x = current_ + state_stride * std::size_t(corner[std::size_t(q)]);
            for (int k = 0; k < 3; ++k) p[q][k] = double(x[k]) - double(x0[k]);
        }
        const double change = cell_volume12<double>(p, nullptr) - double(cell_rest12_[c]);
        energy += 0.5 * double(cell_k12_[c]) * change * change;
    }
    return energy;
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::particle_force(std::size_t particle) const {
    if (particle >= n_) throw InputError("solver: particle index out of range");
    return force_on(particle);
}

template <class Real>
InstrumentForces BasicSolver<Real>::instrument_forces() const {
    InstrumentForces forces;
    for (int hand = 0; hand < hands; ++hand) {
        const std::vector<std::int32_t> contact = contact_particles(hand);
        InstrumentForce& f = forces.hand[std::size_t(hand)];
        for (std::int32_t i : contact) f.force_n += force_on(std::size_t(i));
        f.particles = contact.size();
        if (hand_[std::size_t(hand)].instrument.kind == InstrumentKind::scalpel) {
            f.force_n = blade_force(hand_[std::size_t(hand)].blade, options_.cutting_resistance, 2.0 * hand_[std::size_t(hand)].instrument.semi_axes.z());
            f.springs_cut = hand_[std::size_t(hand)].cuts;
        }
        if (!f.force_n.allFinite()) f.force_n.setZero();  // unreachable with finite positions; never leak
    }
    return forces;
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::anchor_force() const {
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < n_; ++i)
        if (anchored_[i]) force += force_on(i);
    return force;
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::support_force() const {
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    if (!supported_) return force;
    for (std::size_t i = 0; i < n_; ++i) {
        const Real* x = current_ + state_stride * i;
        const Real* y = support_point_.data() + 4 * i;
        force += double(support_stiffness_[i]) * Eigen::Vector3d(double(y[0]) - x[0], double(y[1]) - x[1], double(y[2]) - x[2]);
    }
    return force;
}

template <class Real>
SolverEnergy BasicSolver<Real>::compute_energy(bool centred) const {
    std::vector<std::array<double, 4>> partial(chunks_, {0.0, 0.0, 0.0, 0.0});
    // Kinetic energy with the inertia the step integrates (S·m): what the step conserves.
    const double h = h_, s = options_.mass_scale, keep = 1.0 - options_.damping * h_ / s;
    const Eigen::Vector3d g = options_.gravity;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks_), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk) {
            double kinetic = 0, elastic = 0, gravity = 0, strain = 0;
            const std::size_t end = std::min(n_, (chunk + 1) * chunk_groups * lane_count);
            for (std::size_t i = chunk * chunk_groups * lane_count; i < end; ++i) {
                const Real* x = current_ + state_stride * i;
                for (int s = 0; s < slot_count; ++s) {
                    // Each spring once, from its end of lower index (it is in both ends' tables; an
                    // empty slot points at the particle itself).
                    const std::size_t t = entry_of(i, s);
                    if (std::size_t(neighbour_[t]) <= i) continue;
                    const Real* y = current_ + state_stride * std::size_t(neighbour_[t]);
                    const double length = std::sqrt(std::pow(double(y[0]) - x[0], 2) + std::pow(double(y[1]) - x[1], 2) +
                                                    std::pow(double(y[2]) - x[2], 2));
                    elastic += 0.5 * double(stiffness_[t]) * std::pow(length - double(rest_length_[t]), 2);
                    if (rest_length_[t] > 0) strain = std::max(strain, length / double(rest_length_[t]) - 1.0);
                }
                if (!movable_[i]) continue;
                if (supported_) {
                    const Real* y = support_point_.data() + 4 * i;
                    elastic += 0.5 * double(support_stiffness_[i]) *
                               (std::pow(double(y[0]) - x[0], 2) + std::pow(double(y[1]) - x[1], 2) + std::pow(double(y[2]) - x[2], 2));
                }
                const double m = double(mass_[i]);
                Eigen::Vector3d u(static_cast<double>(motion_[state_stride * i]), static_cast<double>(motion_[state_stride * i + 1]), static_cast<double>(motion_[state_stride * i + 2]));
                if (centred) u = 0.5 * (u + keep * u + (force_on(i) + m * g) * (h * h / (m * s)));
                kinetic += 0.5 * s * m * u.squaredNorm() / (h * h);
                const Eigen::Vector3d displacement(static_cast<double>(x[0]) - rest_[4 * i], static_cast<double>(x[1]) - rest_[4 * i + 1], static_cast<double>(x[2]) - rest_[4 * i + 2]);
                gravity -= m * g.dot(displacement);
            }
            partial[chunk] = {kinetic, elastic, gravity, strain};
        }
    });
    SolverEnergy e;
    for (const auto& p : partial) e.kinetic += p[0], e.elastic += p[1], e.gravity += p[2], e.max_strain = std::max(e.max_strain, p[3]);
    if (!cell_corner_.empty()) e.elastic += volume_energy();
    return e;
}

template <class Real>
SolverEnergy BasicSolver<Real>::energy() const {
    return compute_energy(true);
}

template <class Real>
Eigen::Vector3d BasicSolver<Real>::position(std::size_t particle) const {
    if (particle >= n_) throw InputError("solver: particle index out of range");
    const Real* x = current_ + state_stride * particle;
    return {static_cast<double>(x[0]), static_cast<double>(x[1]), static_cast<double>(x[2])};
}

template <class Real>
std::vector<std::array<float, 3>> BasicSolver<Real>::positions() const {
    std::vector<std::array<float, 3>> out(n_);
    for (std::size_t i = 0; i < n_; ++i) out[i] = {float(current_[state_stride * i]), float(current_[state_stride * i + 1]), float(current_[state_stride * i + 2])};
    return out;
}

template <class Real>
std::uint64_t BasicSolver<Real>::state_hash() const {
    std::uint64_t hash = 1469598103934665603ull;
    // Every position's 4 values in order, then every motion's: the same bytes in the same order
    // as when each had a buffer of its own, so recorded hashes still match.
    auto mix = [&](const Real* data) {
        for (std::size_t i = 0; i < n_pad_; ++i) {
            const auto* bytes = reinterpret_cast<const unsigned char*>(data + state_stride * i);
            for (std::size_t b = 0; b < 4 * sizeof(Real); ++b) hash = (hash ^ bytes[b]) * 1099511628211ull;
        }
    };
    mix(current_);
    mix(motion_);
    return hash;
}

template class BasicSolver<float>;
template class BasicSolver<double>;

}  // namespace heartsim
