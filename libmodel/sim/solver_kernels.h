/// @file solver_kernels.h
/// @brief Private to the CPU solver (solver.cpp and the solver_kernel_*.cpp files): the packed
/// layout one substep's inner loop reads, and the kernels that run it, one translation unit per
/// instruction set (portable, sse2, avx2, avx512), as Box2D keeps one file per SIMD width.
///
/// Floating-point contract: the portable, AVX2 and AVX-512 kernels evaluate the same IEEE
/// operations in the same order, with exact sqrt and division and a fused multiply-add (one
/// rounding) in the same five places of a slot (std::fma in group_portable), so they give the
/// same bits. The SSE2 kernel, for CPUs without AVX2 and FMA, rounds those products and sums
/// apart: it differs from the others by rounding (docs/solver.md "Kernels"). Every file that
/// includes this header turns fp-contract off first, so that a compiler cannot fuse any other
/// multiply and add, in one kernel and not another.
#pragma once

#include "libmodel/sim/solver.h"

#include <cstddef>
#include <cstdint>

#if defined(__x86_64__) || defined(_M_X64)
#define HEARTSIM_SOLVER_X86 1
#include <immintrin.h>
#endif

namespace heartsim::solver_kernels {

constexpr int slot_count = 18;
constexpr int lane_count = 8;
/// Floats per particle in a state buffer: its position (x, y, z, 0), then its motion u
/// (x, y, z, 0), side by side so that one 32-byte load (one cache line) brings a neighbour's
/// position and motion together (the dashpot needs both).
constexpr std::size_t state_stride = 8;
constexpr std::size_t chunk_groups = 32;  // 256 particles per parallel task

/// The per-entry tables (neighbour, rest length, stiffness, dashpot) hold two groups of 8 side by
/// side in each slot: [pair of groups][slot][16 lanes], so that the avx512 kernel reads a slot of
/// its 16 particles with one load instead of two halves joined by a lane insert. Slot s of group g
/// begins at group_entries(g) + s·slot_stride; lane l of it is l entries on.
constexpr std::size_t slot_stride = 2 * lane_count;
constexpr std::size_t group_entries(std::size_t group) {
    return group / 2 * (slot_count * slot_stride) + group % 2 * lane_count;
}
/// The entry of particle i's slot s.
constexpr std::size_t entry_of(std::size_t i, int s) {
    return group_entries(i / lane_count) + std::size_t(s) * slot_stride + i % lane_count;
}

/// Everything one substep's inner loop reads, as raw pointers.
template <class Real>
struct KernelData {
    const Real* x;          // current positions, state_stride apart
    const Real* u;          // motion of the last substep, x_n − x_{n−1}: x + 4 (load_gather16_both reads it from x)
    Real* xn;               // next positions (written)
    Real* un;               // next motion, x_{n+1} − x_n (written): xn + 4
    const std::int32_t* neighbour;
    const Real* rest_length;
    const Real* stiffness;
    const Real* dashpot;    // c/h
    bool per_entry_parameters;  // rest length and stiffness per entry (as the neighbours), else per slot: [slot][16]
    const Real* mass;
    const Real* inverse_mass_h2;
    const Real* support_point;      // 4 per particle (x, y, z, 0), mm
    const Real* support_stiffness;  // 1 per particle, N/mm (0 where unsupported)
    const Real* support_damping;    // 1 per particle, c/h, N/mm (0 where unsupported)
    Real keep;              // 1 − γh
    Real gravity[3];        // mm/ms²
    Real max_displacement2; // mm², per substep
};

template <class Real>
constexpr Real tiny_length2() { return Real(1e-30); }

/// Where group `group`'s rest lengths and stiffnesses begin: its own entries in the per-entry
/// tables, or its lanes of the per-slot constants ([slot][16], both groups of a pair alike).
template <class Real>
std::size_t parameter_entries(const KernelData<Real>& k, std::size_t group) {
    return k.per_entry_parameters ? group_entries(group) : group % 2 * lane_count;
}

/// Runs a kernel over groups [first, last); true when a displacement is past the bound.
template <class Real>
using GroupFunction = bool (*)(const KernelData<Real>&, std::size_t, std::size_t);

template <class Real, bool (*Group)(const KernelData<Real>&, std::size_t)>
bool each_group(const KernelData<Real>& k, std::size_t first, std::size_t last) {
    bool bad = false;
    for (std::size_t g = first; g < last; ++g) bad |= Group(k, g);
    return bad;
}

/// The runner of one (damped, supported) variant among a kernel's four, given in the order
/// (damped, supported) = (no, no), (yes, no), (no, yes), (yes, yes).
template <class Real>
GroupFunction<Real> variant(bool damped, bool supported, GroupFunction<Real> plain, GroupFunction<Real> damped_only,
                            GroupFunction<Real> supported_only, GroupFunction<Real> both) {
    return supported ? (damped ? both : supported_only) : (damped ? damped_only : plain);
}

/// Each kernel's group runner for one (damped, supported) variant. The portable kernel serves
/// float and double; `fma`: compiled for a CPU with FMA (std::fma one instruction, the same bits).
template <class Real>
GroupFunction<Real> portable_kernel(bool damped, bool supported, bool fma);
#ifdef HEARTSIM_SOLVER_X86
GroupFunction<float> sse2_kernel(bool damped, bool supported);
GroupFunction<float> avx2_kernel(bool damped, bool supported);
GroupFunction<float> avx512_kernel(bool damped, bool supported);
/// Bit l set when particle l of the 16 from `x` (a state buffer) lies within √bound2 of c: the
/// probe's candidate test, (dx² + dy²) + dz² < bound2 in float as the scalar loop evaluates it.
/// Only where the avx512 kernel runs.
unsigned near_probe16(const float* x, float cx, float cy, float cz, float bound2);
bool cpu_has_fma();
#endif
bool cpu_has_avx2();
bool cpu_has_avx512();

/// The group runner of `kernel` (a resolved one: not automatic) for these variants.
template <class Real>
GroupFunction<Real> choose_group_function(SolverKernel kernel, bool damped, bool supported);

/// `automatic` is the widest kernel the CPU has: the 16-lane kernel, which gathers positions and
/// motions together, is 1.3–1.4× avx2 at 30k particles, 1.0–1.3× at 100k and 300k, and 0.9–1.1×
/// at 1M, where the step streams its tables from memory (docs/benchmarks-solver.md).
/// `arithmetic` (SlotArithmetic) overrides the kernel where a result must be reproduced: separate
/// takes sse2, fused takes portable where the choice would have been sse2. (Off x86 every kernel
/// is the fused portable one, so `separate` cannot be honoured there.)
SolverKernel resolve_kernel(SolverKernel wanted, bool is_float, std::size_t particles, SlotArithmetic arithmetic);

}  // namespace heartsim::solver_kernels
