// The portable kernel (the scalar reference, float and double; std::fma where the other kernels fuse), the CPU feature checks and the choice among the kernels.
// The floating-point contract and the layout: solver_kernels.h.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/solver_kernels.h"

#include <algorithm>
#include <cmath>
#include <type_traits>

namespace heartsim::solver_kernels {

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

namespace {

template <class Real, bool Supported>
GroupFunction<Real> portable_variant(bool damped, bool fma) {
#ifdef HEARTSIM_SOLVER_X86
    if (fma)
        return damped ? &each_group<Real, &group_portable_fma<Real, true, Supported>> : &each_group<Real, &group_portable_fma<Real, false, Supported>>;
#else
    (void)fma;
#endif
    return damped ? &each_group<Real, &group_portable<Real, true, Supported>> : &each_group<Real, &group_portable<Real, false, Supported>>;
}

}  // namespace

template <class Real>
GroupFunction<Real> portable_kernel(bool damped, bool supported, bool fma) {
    return supported ? portable_variant<Real, true>(damped, fma) : portable_variant<Real, false>(damped, fma);
}
template GroupFunction<float> portable_kernel<float>(bool, bool, bool);
template GroupFunction<double> portable_kernel<double>(bool, bool, bool);

#ifdef HEARTSIM_SOLVER_X86
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

template <class Real>
GroupFunction<Real> choose_group_function(SolverKernel kernel, bool damped, bool supported) {
    if constexpr (std::is_same_v<Real, float>) {
#ifdef HEARTSIM_SOLVER_X86
        if (kernel == SolverKernel::avx512) return avx512_kernel(damped, supported);
        if (kernel == SolverKernel::avx2) return avx2_kernel(damped, supported);
        if (kernel == SolverKernel::sse2) return sse2_kernel(damped, supported);
#endif
    }
#ifdef HEARTSIM_SOLVER_X86
    return portable_kernel<Real>(damped, supported, cpu_has_fma());
#else
    (void)kernel;
    return portable_kernel<Real>(damped, supported, false);
#endif
}
template GroupFunction<float> choose_group_function<float>(SolverKernel, bool, bool);
template GroupFunction<double> choose_group_function<double>(SolverKernel, bool, bool);

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

}  // namespace heartsim::solver_kernels
