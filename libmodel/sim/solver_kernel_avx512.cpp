// The AVX-512 kernel: two groups (16 particles) per pass in 512-bit registers, positions and motions gathered together; and the probe's 16-particle candidate test.
// The floating-point contract and the layout: solver_kernels.h.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/solver_kernels.h"
#include "libmodel/sim/solver_kernel_avx2.h"

namespace heartsim::solver_kernels {

#ifdef HEARTSIM_SOLVER_X86

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

GroupFunction<float> avx512_kernel(bool damped, bool supported) {
    return variant<float>(damped, supported, &groups_avx512<false, false>, &groups_avx512<true, false>,
                          &groups_avx512<false, true>, &groups_avx512<true, true>);
}

#endif

}  // namespace heartsim::solver_kernels
