// The CPU spring-mass solver. Formulas, layout and sign conventions: docs/solver.md.
//
// Floating-point contract: the portable, AVX2 and AVX-512 kernels evaluate the same IEEE
// operations in the same order, with exact sqrt and division and a fused multiply-add (one
// rounding) in the same five places of a slot (std::fma in group_portable), so they give the
// same bits. The SSE2 kernel, for CPUs without AVX2 and FMA, rounds those products and sums
// apart: it differs from the others by rounding (docs/solver.md "Kernels"). fp-contract is off
// in this file so that a compiler cannot fuse any other multiply and add, in one kernel and not
// another.
//
// Why this file is long (about 1,300 lines): the four kernels are one loop spelled out four
// times, deliberately (the SIMD variants docs/architecture.md names), and they must stay side by
// side with the scalar reference they are checked against (bit for bit; SSE2 within rounding).
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "solver.h"

#include "ellipsoid.h"
#include "errors.h"
#include "packing.h"
#include "stability.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <limits>
#include <sstream>

#if defined(__x86_64__) || defined(_M_X64)
#define HEARTSIM_SOLVER_X86 1
#include <immintrin.h>
#endif

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
    }
    return "none";
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

/// One group of 8 particles: gather the 18 slots, integrate, store, check the displacement.
/// Returns true when a displacement is past the bound or not finite.
template <class Real, bool Damped, bool Supported>
__attribute__((always_inline)) inline bool group_portable_body(const KernelData<Real>& k, std::size_t group) {
    constexpr int W = lane_count;
    Real xi[W], yi[W], zi[W], uxi[W], uyi[W], uzi[W], fx[W], fy[W], fz[W];
    const std::size_t base = group * W;
    for (int l = 0; l < W; ++l) {
        const Real* p = k.x + state_stride * (base + l);
        const Real* q = k.u + state_stride * (base + l);
        xi[l] = p[0], yi[l] = p[1], zi[l] = p[2];
        uxi[l] = q[0], uyi[l] = q[1], uzi[l] = q[2];
        fx[l] = fy[l] = fz[l] = Real(0);
    }
    const std::size_t table = group_entries(group), parameters = parameter_entries(k, group);
    for (int s = 0; s < slot_count; ++s) {
        for (int l = 0; l < W; ++l) {
            const std::size_t t = table + std::size_t(s) * slot_stride + l, u = parameters + std::size_t(s) * slot_stride + l;
            const std::size_t j = std::size_t(k.neighbour[t]);
            const Real* pj = k.x + state_stride * j;
            const Real dx = pj[0] - xi[l], dy = pj[1] - yi[l], dz = pj[2] - zi[l];
            Real length2 = std::fma(dy, dy, dx * dx);
            length2 = std::fma(dz, dz, length2);
            const Real length = std::sqrt(length2 > tiny_length2<Real>() ? length2 : tiny_length2<Real>());
            const Real inverse = Real(1) / length;
            Real scale = (k.stiffness[u] * (length - k.rest_length[u])) * inverse;
            if constexpr (Damped) {
                const Real* qj = k.u + state_stride * j;
                const Real dux = qj[0] - uxi[l], duy = qj[1] - uyi[l], duz = qj[2] - uzi[l];
                Real along = std::fma(duy, dy, dux * dx);
                along = std::fma(duz, dz, along) * inverse;
                along = along * inverse;
                scale = std::fma(k.dashpot[t], along, scale);
            }
            fx[l] = std::fma(scale, dx, fx[l]);
            fy[l] = std::fma(scale, dy, fy[l]);
            fz[l] = std::fma(scale, dz, fz[l]);
        }
    }
    if constexpr (Supported) {
        // Support spring of zero rest length: f += k_s (y − x), after the 18 slots.
        for (int l = 0; l < W; ++l) {
            const Real* y = k.support_point + 4 * (base + l);
            const Real ks = k.support_stiffness[base + l], cs = k.support_damping[base + l];
            fx[l] = fx[l] + (ks * (y[0] - xi[l]) - cs * uxi[l]);
            fy[l] = fy[l] + (ks * (y[1] - yi[l]) - cs * uyi[l]);
            fz[l] = fz[l] + (ks * (y[2] - zi[l]) - cs * uzi[l]);
        }
    }
    bool bad = false;
    for (int l = 0; l < W; ++l) {
        const std::size_t i = base + l;
        const Real m = k.mass[i], w = k.inverse_mass_h2[i];
        const Real ex = k.keep * uxi[l] + (fx[l] + m * k.gravity[0]) * w;
        const Real ey = k.keep * uyi[l] + (fy[l] + m * k.gravity[1]) * w;
        const Real ez = k.keep * uzi[l] + (fz[l] + m * k.gravity[2]) * w;
        Real* out = k.xn + state_stride * i;
        out[0] = xi[l] + ex, out[1] = yi[l] + ey, out[2] = zi[l] + ez, out[3] = Real(0);
        Real* motion = k.un + state_stride * i;
        motion[0] = ex, motion[1] = ey, motion[2] = ez, motion[3] = Real(0);
        Real d2 = ex * ex + ey * ey;
        d2 = d2 + ez * ez;
        bad |= !(d2 <= k.max_displacement2);
    }
    return bad;
}

template <class Real, bool Damped, bool Supported>
bool group_portable(const KernelData<Real>& k, std::size_t group) {
    return group_portable_body<Real, Damped, Supported>(k, group);
}

#ifdef HEARTSIM_SOLVER_X86
/// group_portable compiled for a CPU with FMA, so that std::fma is one instruction instead of a
/// call into libm (about 4× faster; used for the double reference too). The same bits: std::fma rounds
/// once either way.
template <class Real, bool Damped, bool Supported>
__attribute__((target("fma"))) bool group_portable_fma(const KernelData<Real>& k, std::size_t group) {
    return group_portable_body<Real, Damped, Supported>(k, group);
}
#endif

#ifdef HEARTSIM_SOLVER_X86

inline void transpose_in(__m128 a, __m128 b, __m128 c, __m128 d, __m128& x, __m128& y, __m128& z) {
    const __m128 t0 = _mm_unpacklo_ps(a, b), t1 = _mm_unpacklo_ps(c, d);
    const __m128 t2 = _mm_unpackhi_ps(a, b), t3 = _mm_unpackhi_ps(c, d);
    x = _mm_movelh_ps(t0, t1);
    y = _mm_movehl_ps(t1, t0);
    z = _mm_movelh_ps(t2, t3);
}

/// x, y, z of the 4 particles `index` names, from a state buffer (state_stride apart).
inline void load_gather4(const float* base, const std::int32_t* index, __m128& x, __m128& y, __m128& z) {
    transpose_in(_mm_loadu_ps(base + state_stride * std::size_t(index[0])), _mm_loadu_ps(base + state_stride * std::size_t(index[1])),
                 _mm_loadu_ps(base + state_stride * std::size_t(index[2])), _mm_loadu_ps(base + state_stride * std::size_t(index[3])), x, y, z);
}

/// x, y, z of 4 consecutive particles whose float4 lie `stride` floats apart.
inline void load_own4(const float* p, std::size_t stride, __m128& x, __m128& y, __m128& z) {
    transpose_in(_mm_loadu_ps(p), _mm_loadu_ps(p + stride), _mm_loadu_ps(p + 2 * stride), _mm_loadu_ps(p + 3 * stride), x, y, z);
}

/// Stores x, y, z of 4 particles as float4 (x, y, z, 0) in a state buffer.
inline void store_own4(float* out, __m128 x, __m128 y, __m128 z) {
    const __m128 zero = _mm_setzero_ps();
    const __m128 t0 = _mm_unpacklo_ps(x, y), t1 = _mm_unpacklo_ps(z, zero);
    const __m128 t2 = _mm_unpackhi_ps(x, y), t3 = _mm_unpackhi_ps(z, zero);
    _mm_storeu_ps(out, _mm_movelh_ps(t0, t1));
    _mm_storeu_ps(out + state_stride, _mm_movehl_ps(t1, t0));
    _mm_storeu_ps(out + 2 * state_stride, _mm_movelh_ps(t2, t3));
    _mm_storeu_ps(out + 3 * state_stride, _mm_movehl_ps(t3, t2));
}

/// SSE2 has no fused multiply-add: the five a slot's other kernels fuse are rounded apart here
/// (the one kernel not bit-equal to the others; docs/solver.md "Kernels").
template <bool Damped, bool Supported>
bool group_sse2(const KernelData<float>& k, std::size_t group) {
    bool bad = false;
    const __m128 tiny = _mm_set1_ps(tiny_length2<float>()), one = _mm_set1_ps(1.0f), zero = _mm_setzero_ps();
    for (int half = 0; half < 2; ++half) {
        const std::size_t base = group * lane_count + std::size_t(half) * 4;
        __m128 xi, yi, zi, uxi, uyi, uzi;
        load_own4(k.x + state_stride * base, state_stride, xi, yi, zi);
        load_own4(k.u + state_stride * base, state_stride, uxi, uyi, uzi);
        __m128 fx = zero, fy = zero, fz = zero;
        const std::size_t table = group_entries(group) + std::size_t(half) * 4;
        const std::size_t parameters = parameter_entries(k, group) + std::size_t(half) * 4;
        for (int s = 0; s < slot_count; ++s) {
            const std::size_t t = table + std::size_t(s) * slot_stride, u = parameters + std::size_t(s) * slot_stride;
            __m128 xj, yj, zj;
            load_gather4(k.x, k.neighbour + t, xj, yj, zj);
            const __m128 dx = _mm_sub_ps(xj, xi), dy = _mm_sub_ps(yj, yi), dz = _mm_sub_ps(zj, zi);
            __m128 length2 = _mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy));
            length2 = _mm_add_ps(length2, _mm_mul_ps(dz, dz));
            const __m128 length = _mm_sqrt_ps(_mm_max_ps(length2, tiny));
            const __m128 inverse = _mm_div_ps(one, length);
            __m128 scale = _mm_mul_ps(_mm_mul_ps(_mm_loadu_ps(k.stiffness + u), _mm_sub_ps(length, _mm_loadu_ps(k.rest_length + u))), inverse);
            if constexpr (Damped) {
                __m128 uxj, uyj, uzj;
                load_gather4(k.u, k.neighbour + t, uxj, uyj, uzj);
                const __m128 dux = _mm_sub_ps(uxj, uxi), duy = _mm_sub_ps(uyj, uyi), duz = _mm_sub_ps(uzj, uzi);
                __m128 along = _mm_add_ps(_mm_mul_ps(dux, dx), _mm_mul_ps(duy, dy));
                along = _mm_mul_ps(_mm_add_ps(along, _mm_mul_ps(duz, dz)), inverse);
                along = _mm_mul_ps(along, inverse);
                scale = _mm_add_ps(scale, _mm_mul_ps(_mm_loadu_ps(k.dashpot + t), along));
            }
            fx = _mm_add_ps(fx, _mm_mul_ps(scale, dx));
            fy = _mm_add_ps(fy, _mm_mul_ps(scale, dy));
            fz = _mm_add_ps(fz, _mm_mul_ps(scale, dz));
        }
        if constexpr (Supported) {
            __m128 sx, sy, sz;
            load_own4(k.support_point + 4 * base, 4, sx, sy, sz);
            const __m128 ks = _mm_loadu_ps(k.support_stiffness + base), cs = _mm_loadu_ps(k.support_damping + base);
            fx = _mm_add_ps(fx, _mm_sub_ps(_mm_mul_ps(ks, _mm_sub_ps(sx, xi)), _mm_mul_ps(cs, uxi)));
            fy = _mm_add_ps(fy, _mm_sub_ps(_mm_mul_ps(ks, _mm_sub_ps(sy, yi)), _mm_mul_ps(cs, uyi)));
            fz = _mm_add_ps(fz, _mm_sub_ps(_mm_mul_ps(ks, _mm_sub_ps(sz, zi)), _mm_mul_ps(cs, uzi)));
        }
        const __m128 m = _mm_loadu_ps(k.mass + base), w = _mm_loadu_ps(k.inverse_mass_h2 + base), keep = _mm_set1_ps(k.keep);
        const __m128 ex = _mm_add_ps(_mm_mul_ps(keep, uxi), _mm_mul_ps(_mm_add_ps(fx, _mm_mul_ps(m, _mm_set1_ps(k.gravity[0]))), w));
        const __m128 ey = _mm_add_ps(_mm_mul_ps(keep, uyi), _mm_mul_ps(_mm_add_ps(fy, _mm_mul_ps(m, _mm_set1_ps(k.gravity[1]))), w));
        const __m128 ez = _mm_add_ps(_mm_mul_ps(keep, uzi), _mm_mul_ps(_mm_add_ps(fz, _mm_mul_ps(m, _mm_set1_ps(k.gravity[2]))), w));
        store_own4(k.xn + state_stride * base, _mm_add_ps(xi, ex), _mm_add_ps(yi, ey), _mm_add_ps(zi, ez));
        store_own4(k.un + state_stride * base, ex, ey, ez);
        __m128 d2 = _mm_add_ps(_mm_mul_ps(ex, ex), _mm_mul_ps(ey, ey));
        d2 = _mm_add_ps(d2, _mm_mul_ps(ez, ez));
        bad |= _mm_movemask_ps(_mm_cmpnle_ps(d2, _mm_set1_ps(k.max_displacement2))) != 0;
    }
    return bad;
}

#define HEARTSIM_AVX2 __attribute__((target("avx2,fma")))

HEARTSIM_AVX2 inline __m256 pair(const float* a, const float* b) {
    return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(a)), _mm_loadu_ps(b), 1);
}

HEARTSIM_AVX2 inline void transpose_in8(__m256 a, __m256 b, __m256 c, __m256 d, __m256& x, __m256& y, __m256& z) {
    const __m256 t0 = _mm256_unpacklo_ps(a, b), t1 = _mm256_unpacklo_ps(c, d);
    const __m256 t2 = _mm256_unpackhi_ps(a, b), t3 = _mm256_unpackhi_ps(c, d);
    x = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0));
    y = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2));
    z = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0));
}

HEARTSIM_AVX2 inline void load_gather8(const float* base, const std::int32_t* i, __m256& x, __m256& y, __m256& z) {
    auto at = [&](int l) { return base + state_stride * std::size_t(i[l]); };
    transpose_in8(pair(at(0), at(4)), pair(at(1), at(5)), pair(at(2), at(6)), pair(at(3), at(7)), x, y, z);
}

/// load_gather8 of positions and motions at once, each offset computed once for both loads (as
/// load_gather16_both): the same loads, so the same values.
HEARTSIM_AVX2 inline void load_gather8_both(const float* x, const float* u, const std::int32_t* i, __m256& xj, __m256& yj, __m256& zj,
                                            __m256& uxj, __m256& uyj, __m256& uzj) {
    __m256 xq[4], uq[4];
    for (int q = 0; q < 4; ++q) {
        const std::size_t o0 = state_stride * std::size_t(i[q]), o1 = state_stride * std::size_t(i[q + 4]);
        xq[q] = pair(x + o0, x + o1);
        uq[q] = pair(u + o0, u + o1);
    }
    transpose_in8(xq[0], xq[1], xq[2], xq[3], xj, yj, zj);
    transpose_in8(uq[0], uq[1], uq[2], uq[3], uxj, uyj, uzj);
}

/// x, y, z of 8 consecutive particles whose float4 lie `s` floats apart.
HEARTSIM_AVX2 inline void load_own8(const float* p, std::size_t s, __m256& x, __m256& y, __m256& z) {
    transpose_in8(pair(p, p + 4 * s), pair(p + s, p + 5 * s), pair(p + 2 * s, p + 6 * s), pair(p + 3 * s, p + 7 * s), x, y, z);
}

/// Stores x, y, z of 8 particles as float4 (x, y, z, 0) in a state buffer.
HEARTSIM_AVX2 inline void store_own8(float* out, __m256 x, __m256 y, __m256 z) {
    const __m256 zero = _mm256_setzero_ps();
    const __m256 t0 = _mm256_unpacklo_ps(x, y), t1 = _mm256_unpacklo_ps(z, zero);
    const __m256 t2 = _mm256_unpackhi_ps(x, y), t3 = _mm256_unpackhi_ps(z, zero);
    const __m256 p0 = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0));  // particles 0 | 4
    const __m256 p1 = _mm256_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2));  // 1 | 5
    const __m256 p2 = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0));  // 2 | 6
    const __m256 p3 = _mm256_shuffle_ps(t2, t3, _MM_SHUFFLE(3, 2, 3, 2));  // 3 | 7
    const __m256 particles[4] = {p0, p1, p2, p3};
    for (std::size_t q = 0; q < 4; ++q) {
        _mm_storeu_ps(out + state_stride * q, _mm256_castps256_ps128(particles[q]));
        _mm_storeu_ps(out + state_stride * (q + 4), _mm256_extractf128_ps(particles[q], 1));
    }
}

/// The 8-lane body, inlined into group_avx2 (compiled for AVX2) and into groups_avx512 for an odd
/// last group (compiled for AVX-512: EVEX-encoded, 32 vector registers). Same operations, same bits.
template <bool Damped, bool Supported>
HEARTSIM_AVX2 __attribute__((always_inline)) inline bool group_avx2_body(const KernelData<float>& k, std::size_t group) {
    const __m256 tiny = _mm256_set1_ps(tiny_length2<float>()), one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps();
    const std::size_t base = group * lane_count;
    __m256 xi, yi, zi, uxi, uyi, uzi;
    load_own8(k.x + state_stride * base, state_stride, xi, yi, zi);
    load_own8(k.u + state_stride * base, state_stride, uxi, uyi, uzi);
    __m256 fx = zero, fy = zero, fz = zero;
    const std::size_t table = group_entries(group), parameters = parameter_entries(k, group);
    for (int s = 0; s < slot_count; ++s) {
        const std::size_t t = table + std::size_t(s) * slot_stride, u = parameters + std::size_t(s) * slot_stride;
        __m256 xj, yj, zj, uxj, uyj, uzj;
        if constexpr (Damped) load_gather8_both(k.x, k.u, k.neighbour + t, xj, yj, zj, uxj, uyj, uzj);
        else load_gather8(k.x, k.neighbour + t, xj, yj, zj);
        const __m256 dx = _mm256_sub_ps(xj, xi), dy = _mm256_sub_ps(yj, yi), dz = _mm256_sub_ps(zj, zi);
        __m256 length2 = _mm256_fmadd_ps(dy, dy, _mm256_mul_ps(dx, dx));
        length2 = _mm256_fmadd_ps(dz, dz, length2);
        const __m256 length = _mm256_sqrt_ps(_mm256_max_ps(length2, tiny));
        const __m256 inverse = _mm256_div_ps(one, length);
        __m256 scale = _mm256_mul_ps(_mm256_mul_ps(_mm256_loadu_ps(k.stiffness + u), _mm256_sub_ps(length, _mm256_loadu_ps(k.rest_length + u))), inverse);
        if constexpr (Damped) {
            const __m256 dux = _mm256_sub_ps(uxj, uxi), duy = _mm256_sub_ps(uyj, uyi), duz = _mm256_sub_ps(uzj, uzi);
            __m256 along = _mm256_fmadd_ps(duy, dy, _mm256_mul_ps(dux, dx));
            along = _mm256_mul_ps(_mm256_fmadd_ps(duz, dz, along), inverse);
            along = _mm256_mul_ps(along, inverse);
            scale = _mm256_fmadd_ps(_mm256_loadu_ps(k.dashpot + t), along, scale);
        }
        fx = _mm256_fmadd_ps(scale, dx, fx);
        fy = _mm256_fmadd_ps(scale, dy, fy);
        fz = _mm256_fmadd_ps(scale, dz, fz);
    }
    if constexpr (Supported) {
        __m256 sx, sy, sz;
        load_own8(k.support_point + 4 * base, 4, sx, sy, sz);
        const __m256 ks = _mm256_loadu_ps(k.support_stiffness + base), cs = _mm256_loadu_ps(k.support_damping + base);
        fx = _mm256_add_ps(fx, _mm256_sub_ps(_mm256_mul_ps(ks, _mm256_sub_ps(sx, xi)), _mm256_mul_ps(cs, uxi)));
        fy = _mm256_add_ps(fy, _mm256_sub_ps(_mm256_mul_ps(ks, _mm256_sub_ps(sy, yi)), _mm256_mul_ps(cs, uyi)));
        fz = _mm256_add_ps(fz, _mm256_sub_ps(_mm256_mul_ps(ks, _mm256_sub_ps(sz, zi)), _mm256_mul_ps(cs, uzi)));
    }
    const __m256 m = _mm256_loadu_ps(k.mass + base), w = _mm256_loadu_ps(k.inverse_mass_h2 + base), keep = _mm256_set1_ps(k.keep);
    const __m256 ex = _mm256_add_ps(_mm256_mul_ps(keep, uxi), _mm256_mul_ps(_mm256_add_ps(fx, _mm256_mul_ps(m, _mm256_set1_ps(k.gravity[0]))), w));
    const __m256 ey = _mm256_add_ps(_mm256_mul_ps(keep, uyi), _mm256_mul_ps(_mm256_add_ps(fy, _mm256_mul_ps(m, _mm256_set1_ps(k.gravity[1]))), w));
    const __m256 ez = _mm256_add_ps(_mm256_mul_ps(keep, uzi), _mm256_mul_ps(_mm256_add_ps(fz, _mm256_mul_ps(m, _mm256_set1_ps(k.gravity[2]))), w));
    store_own8(k.xn + state_stride * base, _mm256_add_ps(xi, ex), _mm256_add_ps(yi, ey), _mm256_add_ps(zi, ez));
    store_own8(k.un + state_stride * base, ex, ey, ez);
    __m256 d2 = _mm256_add_ps(_mm256_mul_ps(ex, ex), _mm256_mul_ps(ey, ey));
    d2 = _mm256_add_ps(d2, _mm256_mul_ps(ez, ez));
    return _mm256_movemask_ps(_mm256_cmp_ps(d2, _mm256_set1_ps(k.max_displacement2), _CMP_NLE_UQ)) != 0;
}

template <bool Damped, bool Supported>
HEARTSIM_AVX2 bool group_avx2(const KernelData<float>& k, std::size_t group) {
    return group_avx2_body<Damped, Supported>(k, group);
}

#define HEARTSIM_AVX512 __attribute__((target("avx2,fma,avx512f,avx512vl,avx512dq")))

/// Four float4 (16 bytes each) into one 512-bit register, one per 128-bit lane.
HEARTSIM_AVX512 inline __m512 quad(const float* a, const float* b, const float* c, const float* d) {
    __m512 r = _mm512_castps128_ps512(_mm_loadu_ps(a));
    r = _mm512_insertf32x4(r, _mm_loadu_ps(b), 1);
    r = _mm512_insertf32x4(r, _mm_loadu_ps(c), 2);
    return _mm512_insertf32x4(r, _mm_loadu_ps(d), 3);
}

/// Registers holding particles (0,4,8,12), (1,5,9,13), (2,6,10,14), (3,7,11,15) as float4 →
/// x, y, z of particles 0..15 in order (a 4×4 transpose in each 128-bit lane, as transpose_in8).
HEARTSIM_AVX512 inline void transpose_in16(__m512 a, __m512 b, __m512 c, __m512 d, __m512& x, __m512& y, __m512& z) {
    const __m512 t0 = _mm512_unpacklo_ps(a, b), t1 = _mm512_unpacklo_ps(c, d);
    const __m512 t2 = _mm512_unpackhi_ps(a, b), t3 = _mm512_unpackhi_ps(c, d);
    x = _mm512_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0));
    y = _mm512_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2));
    z = _mm512_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0));
}

/// Gathers the float4 of 16 particles: indices 0..7 from `low`, 8..15 from `high`.
HEARTSIM_AVX512 inline void load_gather16(const float* base, const std::int32_t* low, const std::int32_t* high, __m512& x, __m512& y,
                                          __m512& z) {
    auto at = [&](int l) { return base + state_stride * std::size_t(l < 8 ? low[l] : high[l - 8]); };
    transpose_in16(quad(at(0), at(4), at(8), at(12)), quad(at(1), at(5), at(9), at(13)), quad(at(2), at(6), at(10), at(14)),
                   quad(at(3), at(7), at(11), at(15)), x, y, z);
}

/// load_gather16 of positions and motions at once, from a state buffer where a particle's motion
/// follows its position (state_stride): one 32-byte load per particle brings both, two particles
/// per register, and one lane shuffle parts positions from motions into the quads that
/// transpose_in16 takes. The same values as two load_gather16 calls.
HEARTSIM_AVX512 inline void load_gather16_both(const float* x, const std::int32_t* low, const std::int32_t* high, __m512& xj, __m512& yj,
                                               __m512& zj, __m512& uxj, __m512& uyj, __m512& uzj) {
    __m512 xq[4], uq[4];
    for (int q = 0; q < 4; ++q) {
        // Particles q, q + 4 (low table) and q + 8, q + 12 (high table): (x, u) of two in each.
        const __m512 a = _mm512_insertf32x8(_mm512_castps256_ps512(_mm256_loadu_ps(x + state_stride * std::size_t(low[q]))),
                                            _mm256_loadu_ps(x + state_stride * std::size_t(low[q + 4])), 1);
        const __m512 b = _mm512_insertf32x8(_mm512_castps256_ps512(_mm256_loadu_ps(x + state_stride * std::size_t(high[q]))),
                                            _mm256_loadu_ps(x + state_stride * std::size_t(high[q + 4])), 1);
        xq[q] = _mm512_shuffle_f32x4(a, b, _MM_SHUFFLE(2, 0, 2, 0));  // positions of q, q + 4, q + 8, q + 12
        uq[q] = _mm512_shuffle_f32x4(a, b, _MM_SHUFFLE(3, 1, 3, 1));  // their motions
    }
    transpose_in16(xq[0], xq[1], xq[2], xq[3], xj, yj, zj);
    transpose_in16(uq[0], uq[1], uq[2], uq[3], uxj, uyj, uzj);
}

/// x, y, z of 16 consecutive particles whose float4 lie `s` floats apart.
HEARTSIM_AVX512 inline void load_own16(const float* p, std::size_t s, __m512& x, __m512& y, __m512& z) {
    transpose_in16(quad(p, p + 4 * s, p + 8 * s, p + 12 * s), quad(p + s, p + 5 * s, p + 9 * s, p + 13 * s),
                   quad(p + 2 * s, p + 6 * s, p + 10 * s, p + 14 * s), quad(p + 3 * s, p + 7 * s, p + 11 * s, p + 15 * s), x, y, z);
}

/// The four float4 of `p` to particles 0, 4, 8, 12 of a state buffer from `out`.
HEARTSIM_AVX512 inline void store_quad(float* out, __m512 p) {
    _mm_storeu_ps(out, _mm512_castps512_ps128(p));
    _mm_storeu_ps(out + 4 * state_stride, _mm512_extractf32x4_ps(p, 1));
    _mm_storeu_ps(out + 8 * state_stride, _mm512_extractf32x4_ps(p, 2));
    _mm_storeu_ps(out + 12 * state_stride, _mm512_extractf32x4_ps(p, 3));
}

/// Stores x, y, z of 16 particles as float4 (x, y, z, 0) in a state buffer.
HEARTSIM_AVX512 inline void store_own16(float* out, __m512 x, __m512 y, __m512 z) {
    const __m512 zero = _mm512_setzero_ps();
    const __m512 t0 = _mm512_unpacklo_ps(x, y), t1 = _mm512_unpacklo_ps(z, zero);
    const __m512 t2 = _mm512_unpackhi_ps(x, y), t3 = _mm512_unpackhi_ps(z, zero);
    store_quad(out, _mm512_shuffle_ps(t0, t1, _MM_SHUFFLE(1, 0, 1, 0)));                     // particles 0 | 4 | 8 | 12
    store_quad(out + state_stride, _mm512_shuffle_ps(t0, t1, _MM_SHUFFLE(3, 2, 3, 2)));      // 1 | 5 | 9 | 13
    store_quad(out + 2 * state_stride, _mm512_shuffle_ps(t2, t3, _MM_SHUFFLE(1, 0, 1, 0)));  // 2 | 6 | 10 | 14
    store_quad(out + 3 * state_stride, _mm512_shuffle_ps(t2, t3, _MM_SHUFFLE(3, 2, 3, 2)));  // 3 | 7 | 11 | 15
}

/// Bit l set when particle l of the 16 from `x` (a state buffer) lies within √bound2 of c: the
/// probe's candidate test, (dx² + dy²) + dz² < bound2 in float as the scalar loop evaluates it.
HEARTSIM_AVX512 unsigned near_probe16(const float* x, float cx, float cy, float cz, float bound2) {
    __m512 px, py, pz;
    load_own16(x, state_stride, px, py, pz);
    const __m512 dx = _mm512_sub_ps(px, _mm512_set1_ps(cx)), dy = _mm512_sub_ps(py, _mm512_set1_ps(cy)), dz = _mm512_sub_ps(pz, _mm512_set1_ps(cz));
    __m512 d2 = _mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy));
    d2 = _mm512_add_ps(d2, _mm512_mul_ps(dz, dz));
    return _mm512_cmp_ps_mask(d2, _mm512_set1_ps(bound2), _CMP_LT_OQ);
}

/// Two groups (16 particles) at once in 512-bit registers: the same operations in the same order
/// per particle as group_portable, so the same bits.
template <bool Damped, bool Supported>
HEARTSIM_AVX512 bool group_pair_avx512(const KernelData<float>& k, std::size_t group) {
    const __m512 tiny = _mm512_set1_ps(tiny_length2<float>()), one = _mm512_set1_ps(1.0f), zero = _mm512_setzero_ps();
    const std::size_t base = group * lane_count;
    __m512 xi, yi, zi, uxi, uyi, uzi;
    load_own16(k.x + state_stride * base, state_stride, xi, yi, zi);
    load_own16(k.u + state_stride * base, state_stride, uxi, uyi, uzi);
    __m512 fx = zero, fy = zero, fz = zero;
    // `group` is even: it and the next share each slot's 16 entries.
    const std::size_t table = group_entries(group), parameters = parameter_entries(k, group);
    for (int s = 0; s < slot_count; ++s) {
        const std::size_t t = table + std::size_t(s) * slot_stride, t2 = t + lane_count;
        const std::size_t u = parameters + std::size_t(s) * slot_stride;
        __m512 xj, yj, zj, uxj, uyj, uzj;
        if constexpr (Damped) load_gather16_both(k.x, k.neighbour + t, k.neighbour + t2, xj, yj, zj, uxj, uyj, uzj);
        else load_gather16(k.x, k.neighbour + t, k.neighbour + t2, xj, yj, zj);
        const __m512 dx = _mm512_sub_ps(xj, xi), dy = _mm512_sub_ps(yj, yi), dz = _mm512_sub_ps(zj, zi);
        __m512 length2 = _mm512_fmadd_ps(dy, dy, _mm512_mul_ps(dx, dx));
        length2 = _mm512_fmadd_ps(dz, dz, length2);
        const __m512 length = _mm512_sqrt_ps(_mm512_max_ps(length2, tiny));
        const __m512 inverse = _mm512_div_ps(one, length);
        __m512 scale = _mm512_mul_ps(_mm512_mul_ps(_mm512_loadu_ps(k.stiffness + u), _mm512_sub_ps(length, _mm512_loadu_ps(k.rest_length + u))),
                                     inverse);
        if constexpr (Damped) {
            const __m512 dux = _mm512_sub_ps(uxj, uxi), duy = _mm512_sub_ps(uyj, uyi), duz = _mm512_sub_ps(uzj, uzi);
            __m512 along = _mm512_fmadd_ps(duy, dy, _mm512_mul_ps(dux, dx));
            along = _mm512_mul_ps(_mm512_fmadd_ps(duz, dz, along), inverse);
            along = _mm512_mul_ps(along, inverse);
            scale = _mm512_fmadd_ps(_mm512_loadu_ps(k.dashpot + t), along, scale);
        }
        fx = _mm512_fmadd_ps(scale, dx, fx);
        fy = _mm512_fmadd_ps(scale, dy, fy);
        fz = _mm512_fmadd_ps(scale, dz, fz);
    }
    if constexpr (Supported) {
        __m512 sx, sy, sz;
        load_own16(k.support_point + 4 * base, 4, sx, sy, sz);
        const __m512 ks = _mm512_loadu_ps(k.support_stiffness + base), cs = _mm512_loadu_ps(k.support_damping + base);
        fx = _mm512_add_ps(fx, _mm512_sub_ps(_mm512_mul_ps(ks, _mm512_sub_ps(sx, xi)), _mm512_mul_ps(cs, uxi)));
        fy = _mm512_add_ps(fy, _mm512_sub_ps(_mm512_mul_ps(ks, _mm512_sub_ps(sy, yi)), _mm512_mul_ps(cs, uyi)));
        fz = _mm512_add_ps(fz, _mm512_sub_ps(_mm512_mul_ps(ks, _mm512_sub_ps(sz, zi)), _mm512_mul_ps(cs, uzi)));
    }
    const __m512 m = _mm512_loadu_ps(k.mass + base), w = _mm512_loadu_ps(k.inverse_mass_h2 + base), keep = _mm512_set1_ps(k.keep);
    const __m512 ex = _mm512_add_ps(_mm512_mul_ps(keep, uxi), _mm512_mul_ps(_mm512_add_ps(fx, _mm512_mul_ps(m, _mm512_set1_ps(k.gravity[0]))), w));
    const __m512 ey = _mm512_add_ps(_mm512_mul_ps(keep, uyi), _mm512_mul_ps(_mm512_add_ps(fy, _mm512_mul_ps(m, _mm512_set1_ps(k.gravity[1]))), w));
    const __m512 ez = _mm512_add_ps(_mm512_mul_ps(keep, uzi), _mm512_mul_ps(_mm512_add_ps(fz, _mm512_mul_ps(m, _mm512_set1_ps(k.gravity[2]))), w));
    store_own16(k.xn + state_stride * base, _mm512_add_ps(xi, ex), _mm512_add_ps(yi, ey), _mm512_add_ps(zi, ez));
    store_own16(k.un + state_stride * base, ex, ey, ez);
    __m512 d2 = _mm512_add_ps(_mm512_mul_ps(ex, ex), _mm512_mul_ps(ey, ey));
    d2 = _mm512_add_ps(d2, _mm512_mul_ps(ez, ez));
    return _mm512_cmp_ps_mask(d2, _mm512_set1_ps(k.max_displacement2), _CMP_NLE_UQ) != 0;
}

/// Groups [first, last): pairs in 512-bit registers, an odd last group in 256-bit ones.
template <bool Damped, bool Supported>
HEARTSIM_AVX512 bool groups_avx512(const KernelData<float>& k, std::size_t first, std::size_t last) {
    bool bad = false;
    std::size_t g = first;
    for (; g + 1 < last; g += 2) bad |= group_pair_avx512<Damped, Supported>(k, g);
    if (g < last) bad |= group_avx2_body<Damped, Supported>(k, g);
    return bad;
}

bool cpu_has_fma() { return __builtin_cpu_supports("fma"); }
bool cpu_has_avx2() { return __builtin_cpu_supports("avx2") && cpu_has_fma(); }
bool cpu_has_avx512() {
    return cpu_has_avx2() && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512dq");
}

#else
bool cpu_has_avx2() { return false; }
bool cpu_has_avx512() { return false; }
#endif

/// Runs a kernel over groups [first, last); true when a displacement is past the bound.
template <class Real>
using GroupFunction = bool (*)(const KernelData<Real>&, std::size_t, std::size_t);

template <class Real, bool (*Group)(const KernelData<Real>&, std::size_t)>
bool each_group(const KernelData<Real>& k, std::size_t first, std::size_t last) {
    bool bad = false;
    for (std::size_t g = first; g < last; ++g) bad |= Group(k, g);
    return bad;
}

template <class Real, bool Supported>
GroupFunction<Real> choose_group_function(SolverKernel kernel, bool damped) {
    if constexpr (std::is_same_v<Real, float>) {
#ifdef HEARTSIM_SOLVER_X86
        if (kernel == SolverKernel::avx512) return damped ? &groups_avx512<true, Supported> : &groups_avx512<false, Supported>;
        if (kernel == SolverKernel::avx2)
            return damped ? &each_group<float, &group_avx2<true, Supported>> : &each_group<float, &group_avx2<false, Supported>>;
        if (kernel == SolverKernel::sse2)
            return damped ? &each_group<float, &group_sse2<true, Supported>> : &each_group<float, &group_sse2<false, Supported>>;
#endif
    }
#ifdef HEARTSIM_SOLVER_X86
    if (cpu_has_fma())
        return damped ? &each_group<Real, &group_portable_fma<Real, true, Supported>> : &each_group<Real, &group_portable_fma<Real, false, Supported>>;
#endif
    return damped ? &each_group<Real, &group_portable<Real, true, Supported>> : &each_group<Real, &group_portable<Real, false, Supported>>;
}

template <class Real>
GroupFunction<Real> choose_group_function(SolverKernel kernel, bool damped, bool supported) {
    return supported ? choose_group_function<Real, true>(kernel, damped) : choose_group_function<Real, false>(kernel, damped);
}

/// `automatic` is the widest kernel the CPU has. Measured on the development VM
/// (docs/benchmarks-solver.md), since the 16-lane kernel gathers positions and motions together
/// it is 1.3–1.4× avx2 at 30k particles, 1.0–1.3× at 100k and 300k, and even at 1M (0.9–1.1×,
/// within the VM's noise), where the step streams its tables from memory. (Before, it spilled
/// its gather offsets and was 0.7× avx2 at 300k and 1M, and `automatic` took avx2 above 50,000.)
/// `arithmetic` (SlotArithmetic) overrides the kernel where a result must be reproduced: separate
/// takes sse2, fused takes portable where the choice would have been sse2. (Off x86 every kernel
/// is the fused portable one, so `separate` cannot be honoured there.)
SolverKernel resolve_kernel(SolverKernel wanted, bool is_float, std::size_t particles, SlotArithmetic arithmetic) {
    (void)particles;
    if (!is_float) return SolverKernel::portable;
#ifdef HEARTSIM_SOLVER_X86
    if (arithmetic == SlotArithmetic::separate) return SolverKernel::sse2;
    if (wanted == SolverKernel::automatic) wanted = SolverKernel::avx512;
    if (wanted == SolverKernel::avx512 && !cpu_has_avx512()) wanted = SolverKernel::avx2;
    if (wanted == SolverKernel::avx2 && !cpu_has_avx2()) wanted = SolverKernel::sse2;
    if (arithmetic == SlotArithmetic::fused && !fuses_multiply_adds(wanted)) wanted = SolverKernel::portable;
    return wanted;
#else
    (void)wanted, (void)arithmetic;
    return SolverKernel::portable;
#endif
}

/// A probe during one substep, world frame, double.
struct ProbeFrame {
    int hand = 0;
    Eigen::Vector3d centre;
    Eigen::Matrix3d world_from_tool;
    Eigen::Vector3d previous_centre;           // the pose one substep earlier: the surface's motion
    Eigen::Matrix3d previous_world_from_tool;
    Eigen::Vector3d semi_axes;
    double bound2 = 0.0;  // squared bounding radius, with a margin
};

InstrumentPose interpolate(const InstrumentPose& a, const InstrumentPose& b, double t) {
    return {a.position + t * (b.position - a.position), a.orientation.slerp(t, b.orientation)};
}

}  // namespace

// ---------------------------------------------------------------------------------------------

template <class Real>
BasicSolver<Real>::BasicSolver(const Lattice& lattice, const std::vector<std::array<std::int32_t, 18>>& neighbours,
                               const SolverOptions& options)
    : BasicSolver(lattice.particles, lattice.springs, neighbours, [&] {
          SolverOptions o = options;
          if (o.damping_ratio.empty()) o.damping_ratio = damping_ratios(lattice.materials);
          return o;
      }()) {}

template <class Real>
BasicSolver<Real>::BasicSolver(const Particles& particles, const Springs& springs,
                               const std::vector<std::array<std::int32_t, 18>>& neighbours, const SolverOptions& options)
    : options_(options) {
    n_ = particles.size();
    if (n_ == 0) throw InputError("solver: no particles");
    if (particles.rest_position.size() != n_ || particles.anchored.size() != n_ || particles.material.size() != n_)
        throw InputError("solver: particle arrays differ in length (rest_position, mass, material, anchored)");
    if (springs.pairs.size() != springs.size() || springs.stiffness.size() != springs.size())
        throw InputError("solver: spring arrays differ in length (pairs, rest_length, stiffness)");
    if (!neighbours.empty() && neighbours.size() != n_)
        throw InputError("solver: the neighbour table has " + std::to_string(neighbours.size()) + " rows for " + std::to_string(n_) +
                         " particles");
    if (n_ > std::size_t(std::numeric_limits<std::int32_t>::max() - lane_count)) throw InputError("solver: too many particles");
    for (std::size_t i = 0; i < n_; ++i) {
        if (!(particles.mass[i] > 0) || !std::isfinite(particles.mass[i]))
            throw InputError("solver: particle " + std::to_string(i) + " has a non-positive or non-finite mass");
        for (float c : particles.rest_position[i])
            if (!std::isfinite(c)) throw InputError("solver: particle " + std::to_string(i) + " has a non-finite rest position");
    }
    if (particles.supported()) {
        if (particles.support_stiffness.size() != n_ || particles.support_point.size() != n_)
            throw InputError("solver: support arrays differ in length from the particles (support_stiffness, support_point)");
        if (!particles.support_damping.empty() && particles.support_damping.size() != n_)
            throw InputError("solver: support_damping differs in length from the particles");
        for (std::size_t i = 0; i < n_; ++i) {
            if (!particles.support_damping.empty() && (!(particles.support_damping[i] >= 0) || !std::isfinite(particles.support_damping[i])))
                throw InputError("solver: particle " + std::to_string(i) + " has a negative or non-finite support damping");
            if (!(particles.support_stiffness[i] >= 0) || !std::isfinite(particles.support_stiffness[i]))
                throw InputError("solver: particle " + std::to_string(i) + " has a negative or non-finite support stiffness");
            for (float c : particles.support_point[i])
                if (!std::isfinite(c)) throw InputError("solver: particle " + std::to_string(i) + " has a non-finite support point");
        }
    }
    if (!options_.balanced_gravity.allFinite()) throw InputError("solver: balanced_gravity must be finite");

    n_pad_ = (n_ + lane_count - 1) / lane_count * lane_count;
    groups_ = n_pad_ / lane_count;
    chunks_ = (groups_ + chunk_groups - 1) / chunk_groups;

    // Slot of every spring at both ends.
    std::vector<std::array<std::int32_t, 18>> table = neighbours;
    const bool assign = table.empty();
    if (assign) table.assign(n_, {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1});
    for (std::size_t i = 0; i < n_; ++i)
        for (int s = 0; s < slot_count; ++s)
            if (table[i][std::size_t(s)] < -1 || table[i][std::size_t(s)] >= std::int32_t(n_))
                throw InputError("solver: neighbour table row " + std::to_string(i) + " slot " + std::to_string(s) + " is out of range");
    for (std::size_t q = 0; q < springs.size(); ++q) {
        const auto [a, b] = springs.pairs[q];
        if (a < 0 || b < 0 || std::size_t(a) >= n_ || std::size_t(b) >= n_ || a == b)
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
    std::vector<std::int32_t> slot_spring;
    try {
        slot_spring = spring_of_slot(table, springs);
    } catch (const InputError& e) {
        throw InputError(std::string("solver: ") + e.what());
    }

    // Per-particle arrays.
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

    // Per-slot tables in [pair of groups][slot][16 lanes] order (entry_of).
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

    load_report_.particles = n_;
    load_report_.springs = springs.size();
    if (options_.critical_dt_ms > 0) {
        critical_dt_ms_ = options_.critical_dt_ms;
        // A stored step is checked against a proven ceiling (one pass over the springs): one
        // flipped bit in the file must not make the step 2¹⁶ times too long.
        const double ceiling = critical_step_ceiling_ms(particles, springs);
        if (!std::isfinite(critical_dt_ms_) || critical_dt_ms_ > ceiling * (1.0 + 1e-6))
            throw InputError("scenario: /solver critical_dt_ms is " + std::to_string(critical_dt_ms_) +
                             " ms, above the proven ceiling of " + std::to_string(ceiling) +
                             " ms for these springs and masses: the file is damaged or not from heartprep (rebuild it)");
    } else {
        critical_dt_ms_ = estimate_critical_time_step(particles, springs).critical_dt_ms;
        load_report_.critical_dt_estimated = true;
    }
    load_report_.critical_dt_ms = critical_dt_ms_;
    // The dashpots, support dampers and drag shorten the stable step (stability.h stable_step_ms).
    if (options_.damped_critical_dt_ms > 0 && std::isfinite(options_.damped_critical_dt_ms))
        damped_critical_dt_ms_ = std::min(options_.damped_critical_dt_ms, critical_dt_ms_);
    else
        damped_critical_dt_ms_ = stable_step_ms(4.0 / (critical_dt_ms_ * critical_dt_ms_),
                                                estimate_damping_eigenvalue(particles, springs, options_.damping_ratio, options_.damping));
    load_report_.damped_critical_dt_ms = damped_critical_dt_ms_;
    load_report_.kernel = resolve_kernel(options_.kernel, std::is_same_v<Real, float>, n_, options_.arithmetic);

    touched_.assign(chunks_ * hands, {});
    chunk_bad_.assign(chunks_, 0);
    chunk_pierced_.assign(chunks_, 0);

    double dt = options_.dt_ms;
    if (!(dt > 0)) {
        dt = options_.safety_factor * damped_critical_dt_ms();
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
    reset();
}

template <class Real>
void BasicSolver<Real>::set_time_step(double dt_ms) {
    if (!(dt_ms > 0) || !std::isfinite(dt_ms)) throw InputError("solver: the time step must be positive and finite");
    const double limit = options_.safety_factor * damped_critical_dt_ms();
    int substeps = 1;
    if (options_.subdivide && std::isfinite(limit) && limit > 0) {
        // In double first: a huge dt over a tiny limit must not overflow the int.
        const double needed = std::ceil(dt_ms / limit * (1 - 1e-12));
        if (!(needed <= double(max_substeps)))
            throw InputError("solver: the time step of " + std::to_string(dt_ms) + " ms needs " +
                             (std::isfinite(needed) ? std::to_string(std::llround(needed)) : std::string("unboundedly many")) +
                             " substeps of the stable " + std::to_string(limit) + " ms (at most " + std::to_string(max_substeps) +
                             "): use a shorter --dt or rebuild the scenario");
        substeps = std::max(1, int(needed));
    }
    const double old_h = h_;
    dt_ms_ = dt_ms;
    substeps_ = substeps;
    h_ = dt_ms / substeps;
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
    const double h2 = h_ * h_;
    for (std::size_t i = 0; i < n_pad_; ++i) inverse_mass_h2_[i] = movable_[i] ? Real(h2 / double(mass_[i])) : Real(0);
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
    for (std::size_t i = 0; i < n_pad_; ++i)
        for (std::size_t c = 0; c < 4; ++c) {
            current_[state_stride * i + c] = next_[state_stride * i + c] = rest_[4 * i + c];
            motion_[state_stride * i + c] = next_motion_[state_stride * i + c] = Real(0);
        }
    // At rest the springs and supports balance the gravity the rest state was built for
    // (`balanced_gravity`; zero for an unbalanced rest state, where they exert nothing): the rest
    // acceleration is g − g_balanced, and u₀ = x₀ − x₋₁ = −½·a·h² starts the motion at second order.
    const Eigen::Vector3d rest_acceleration = options_.gravity - options_.balanced_gravity;
    for (std::size_t i = 0; i < n_pad_; ++i)
        if (movable_[i])
            for (int c = 0; c < 3; ++c) motion_[state_stride * i + std::size_t(c)] = Real(-0.5 * rest_acceleration[c] * h_ * h_);
    for (int hand = 0; hand < hands; ++hand) release(hand);
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
        const Eigen::Vector3d a = (force_on(i) + m * options_.gravity) / m - options_.damping * velocities[i];
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
    // Grabs end (the tissue slipped out): the runtime sees no held particles until it grabs again.
    for (int hand = 0; hand < hands; ++hand)
        if (hand_[std::size_t(hand)].grabbing) release(hand);
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
void BasicSolver<Real>::set_instrument(int hand, const Instrument& instrument) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    for (int c = 0; c < 3; ++c)
        if (!(instrument.semi_axes[c] > 0) || !std::isfinite(instrument.semi_axes[c]))
            throw InputError("solver: instrument semi-axes must be positive and finite, mm");
    release(hand);
    hand_[std::size_t(hand)].instrument = instrument;
    hand_[std::size_t(hand)].placed = false;
    for (std::size_t c = 0; c < chunks_; ++c) touched_[c * hands + std::size_t(hand)].clear();
}

template <class Real>
const Instrument& BasicSolver<Real>::instrument(int hand) const {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    return hand_[std::size_t(hand)].instrument;
}

template <class Real>
void BasicSolver<Real>::set_pose(int hand, const InstrumentPose& pose) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    if (!pose.position.allFinite() || !pose.orientation.coeffs().allFinite() || pose.orientation.norm() < 1e-6)
        throw InputError("solver: an instrument pose must be finite with a non-zero quaternion");
    InstrumentPose p = pose;
    p.orientation.normalize();
    HandState& state = hand_[std::size_t(hand)];
    state.target = p;
    if (!state.placed) state.pose = p;  // the first pose of an instrument places it: no sweep from the origin
    state.placed = true;
}

std::vector<std::uint8_t> grab_piece(const std::vector<Eigen::Vector3d>& local, const std::vector<Eigen::Vector3d>& rest,
                                     const Eigen::Vector3d& semi_axes, double reach) {
    std::vector<std::uint8_t> keep(local.size(), 1);
    if (!(reach > 0) || local.empty()) return keep;
    std::size_t anchor = 0;
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t q = 0; q < local.size(); ++q) {
        const double r2 = local[q].cwiseQuotient(semi_axes).squaredNorm();
        if (r2 < nearest) {
            nearest = r2;
            anchor = q;
        }
    }
    const double limit = reach * semi_axes.maxCoeff();
    for (std::size_t q = 0; q < local.size(); ++q) keep[q] = (rest[q] - rest[anchor]).squaredNorm() <= limit * limit;
    return keep;
}

template <class Real>
std::size_t BasicSolver<Real>::begin_grab(int hand) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    HandState& state = hand_[std::size_t(hand)];
    if (state.instrument.kind != InstrumentKind::grabber) throw InputError("solver: begin_grab on a hand that holds no grabber");
    release(hand);
    state.grabbing = true;
    const Eigen::Matrix3d tool_from_world = state.pose.orientation.toRotationMatrix().transpose();
    for (std::size_t i = 0; i < n_; ++i) {
        if (!movable_[i] || held_by_[i] >= 0) continue;
        const Eigen::Vector3d x(static_cast<double>(current_[state_stride * i]), double(current_[state_stride * i + 1]), double(current_[state_stride * i + 2]));
        const Eigen::Vector3d local = tool_from_world * (x - state.pose.position);
        if (local.cwiseQuotient(state.instrument.semi_axes).squaredNorm() > 1.0) continue;
        state.held.push_back(std::int32_t(i));
        state.held_local.push_back(local);
        held_by_[i] = std::int8_t(hand);
    }
    if (options_.grab_reach > 0 && !state.held.empty()) {
        std::vector<Eigen::Vector3d> rest(state.held.size());
        for (std::size_t q = 0; q < state.held.size(); ++q)
            for (int c = 0; c < 3; ++c) rest[q][c] = double(rest_[4 * std::size_t(state.held[q]) + std::size_t(c)]);
        const std::vector<std::uint8_t> keep = grab_piece(state.held_local, rest, state.instrument.semi_axes, options_.grab_reach);
        state.keep_held([&](std::size_t q) {
            if (!keep[q]) held_by_[std::size_t(state.held[q])] = -1;
            return keep[q] != 0;
        });
    }
    return state.held.size();
}

template <class Real>
void BasicSolver<Real>::release(int hand) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    HandState& state = hand_[std::size_t(hand)];
    for (std::int32_t i : state.held) held_by_[std::size_t(i)] = -1;
    state.held.clear();
    state.held_local.clear();
    state.grabbing = false;
}

template <class Real>
std::vector<std::int32_t> BasicSolver<Real>::contact_particles(int hand) const {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    const HandState& state = hand_[std::size_t(hand)];
    if (state.instrument.kind == InstrumentKind::grabber) return state.held;
    std::vector<std::int32_t> all;
    for (std::size_t c = 0; c < chunks_; ++c) {
        const auto& list = touched_[c * hands + std::size_t(hand)];
        all.insert(all.end(), list.begin(), list.end());
    }
    return all;
}

template <class Real>
void BasicSolver<Real>::substep(const InstrumentPose* previous_poses, const InstrumentPose* poses, bool& bad) {
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
    k.keep = Real(1.0 - options_.damping * h_);
    for (int c = 0; c < 3; ++c) k.gravity[c] = Real(options_.gravity[c]);
    double max_displacement = options_.max_displacement_fraction * double(min_rest_length_);
    for (const HandState& state : hand_)
        if (state.instrument.kind != InstrumentKind::none) max_displacement = std::max(max_displacement, state.instrument.semi_axes.maxCoeff());
    k.max_displacement2 = options_.watchdog && std::isfinite(max_displacement) ? Real(max_displacement * max_displacement)
                                                                                 : std::numeric_limits<Real>::infinity();
    k.support_point = support_point_.data();
    k.support_stiffness = support_stiffness_.data();
    k.support_damping = support_damping_over_h_.data();
    const GroupFunction<Real> group_function = choose_group_function<Real>(load_report_.kernel, damped_, supported_);

    std::array<ProbeFrame, hands> probes;
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
        const double radius = state.instrument.semi_axes.maxCoeff() * (1 + 1e-3) + 1e-3;
        p.bound2 = radius * radius;
    }

    // Projects particle i out of the probe if inside (exact test in double; the stored float
    // position is re-checked so rounding cannot leave it inside). The contact is inelastic and
    // frictionless: the particle keeps its own displacement u of this substep except that its
    // normal component becomes at least the probe surface's, so a deep or sudden probe does not
    // fling particles out at penetration/h. Only this particle's next position and motion change
    // (nothing else reads them during the substep).
    auto project = [&](const ProbeFrame& p, std::size_t i, std::vector<std::int32_t>& touched, std::size_t& pierced) {
        Real* x = next_ + state_stride * i;
        const Eigen::Vector3d world(static_cast<double>(x[0]), static_cast<double>(x[1]), static_cast<double>(x[2]));
        Eigen::Vector3d local = p.world_from_tool.transpose() * (world - p.centre);
        const double r2 = local.cwiseQuotient(p.semi_axes).squaredNorm();
        if (!(r2 < 1.0)) return;
        // To the nearest point of the surface (ellipsoid.h), then just outside it (1e-6 relative)
        // so that float rounding and a caller's own evaluation of the pose cannot see it inside.
        local = nearest_point_on_ellipsoid(local, p.semi_axes);
        double factor = 1.0 + 1e-6;
        Eigen::Vector3d stored;
        for (int attempt = 0; attempt < 60; ++attempt) {
            const Eigen::Vector3d out = p.centre + p.world_from_tool * (local * factor);
            for (int c = 0; c < 3; ++c) x[c] = Real(out[c]);
            stored = Eigen::Vector3d(static_cast<double>(x[0]), static_cast<double>(x[1]), static_cast<double>(x[2]));
            if ((p.world_from_tool.transpose() * (stored - p.centre)).cwiseQuotient(p.semi_axes).squaredNorm() >= 1.0 + 1e-6) break;
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
        const Eigen::Vector3d normal = (p.world_from_tool * local.cwiseQuotient(p.semi_axes.cwiseProduct(p.semi_axes))).normalized();
        const Eigen::Vector3d surface_motion = stored - (p.previous_centre + p.previous_world_from_tool * (local * factor));
        const Real* xc = current_ + state_stride * i;
        Eigen::Vector3d u = world - Eigen::Vector3d(static_cast<double>(xc[0]), static_cast<double>(xc[1]), static_cast<double>(xc[2]));
        u += std::max(0.0, (surface_motion - u).dot(normal)) * normal;
        touched.push_back(std::int32_t(i));
        Real* motion = next_motion_ + state_stride * i;
        for (int c = 0; c < 3; ++c) motion[c] = Real(u[c]);
    };

    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks_), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk) {
            bool chunk_bad = false;
            const std::size_t first = chunk * chunk_groups, last = std::min(groups_, first + chunk_groups);
            chunk_bad |= group_function(k, first, last);
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
                                if (q < n_ && movable_[q] && held_by_[q] < 0) project(p, q, touched, chunk_pierced_[chunk]);
                            }
                }
#endif
                for (; i < end; ++i) {
                    const Real* x = next_ + state_stride * i;
                    const Real dx = x[0] - cx, dy = x[1] - cy, dz = x[2] - cz;
                    if (dx * dx + dy * dy + dz * dz < bound2 && movable_[i] && held_by_[i] < 0) project(p, i, touched, chunk_pierced_[chunk]);
                }
            }
            chunk_bad_[chunk] = chunk_bad;
        }
    });

    // Grabbed particles follow the tool rigidly, unless that would stretch one of their springs
    // past the slip strain: then the particle slips out of the grabber and moves freely (it keeps
    // the position the integration gave it, x + u). Order-free, in three passes as the gl
    // backend's one work group runs them (solver_shaders.h `after_step`): every held particle
    // moves to its target; each then measures its springs with its held neighbours at their
    // targets and the free ones where the integration put them; the ones past the slip strain go
    // back and are free. The held lists keep their order, so the result is deterministic.
    bool any_grab = false;
    for (int hand = 0; hand < hands; ++hand) any_grab = any_grab || hand_[std::size_t(hand)].grabbing;
    if (any_grab) {
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
    std::array<InstrumentPose, hands> start, poses, previous_poses;
    for (int hand = 0; hand < hands; ++hand) start[std::size_t(hand)] = hand_[std::size_t(hand)].pose;

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
        substep(previous_poses.data(), poses.data(), bad);
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
    return force;
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
    const double h = h_, keep = 1.0 - options_.damping * h_;
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
                if (centred) u = 0.5 * (u + keep * u + (force_on(i) + m * g) * (h * h / m));
                kinetic += 0.5 * m * u.squaredNorm() / (h * h);
                const Eigen::Vector3d displacement(static_cast<double>(x[0]) - rest_[4 * i], static_cast<double>(x[1]) - rest_[4 * i + 1], static_cast<double>(x[2]) - rest_[4 * i + 2]);
                gravity -= m * g.dot(displacement);
            }
            partial[chunk] = {kinetic, elastic, gravity, strain};
        }
    });
    SolverEnergy e;
    for (const auto& p : partial) e.kinetic += p[0], e.elastic += p[1], e.gravity += p[2], e.max_strain = std::max(e.max_strain, p[3]);
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
