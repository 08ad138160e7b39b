// The AVX2 kernel: 8 lanes, FMA in the five places the portable kernel fuses.
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

template <bool Damped, bool Supported>
HEARTSIM_AVX2 bool group_avx2(const KernelData<float>& k, std::size_t group) {
    return group_avx2_body<Damped, Supported>(k, group);
}

GroupFunction<float> avx2_kernel(bool damped, bool supported) {
    return variant<float>(damped, supported, &each_group<float, &group_avx2<false, false>>, &each_group<float, &group_avx2<true, false>>,
                          &each_group<float, &group_avx2<false, true>>, &each_group<float, &group_avx2<true, true>>);
}

#endif

}  // namespace heartsim::solver_kernels
