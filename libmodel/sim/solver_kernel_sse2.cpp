// The SSE2 kernel: 4 lanes, for x86 CPUs without AVX2 and FMA; it rounds the slot's products and sums apart.
// The floating-point contract and the layout: solver_kernels.h.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/solver_kernels.h"

#include <cmath>

namespace heartsim::solver_kernels {

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
GroupFunction<float> sse2_kernel(bool damped, bool supported) {
    return variant<float>(damped, supported, &each_group<float, &group_sse2<false, false>>, &each_group<float, &group_sse2<true, false>>,
                          &each_group<float, &group_sse2<false, true>>, &each_group<float, &group_sse2<true, true>>);
}

#endif

}  // namespace heartsim::solver_kernels
