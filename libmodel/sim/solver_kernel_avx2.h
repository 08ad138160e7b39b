/// @file solver_kernel_avx2.h
/// @brief Private to the solver's avx2 and avx512 kernels: the 8-lane loads, stores and group
/// body, which the avx512 kernel inlines for an odd last group (compiled there for AVX-512:
/// EVEX-encoded, 32 vector registers; the same operations, the same bits).
#pragma once

#include "libmodel/sim/solver_kernels.h"

#ifdef HEARTSIM_SOLVER_X86

namespace heartsim::solver_kernels {

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

}  // namespace heartsim::solver_kernels

#endif
