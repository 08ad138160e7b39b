/// @file needle_feel.h
/// @brief What the hand that holds a suture needle feels: the wall's resistance as the needle
/// passes through it, and the suture's tension as a stitch is drawn tight. Both are set from
/// published measurements (the defaults below, and docs/haptics.md "The patch and the needle"):
///
/// * Puncture. A needle pressed into soft tissue first deforms it, the force rising with the
///   tip's travel, until the tissue fails at the tip; the force then drops, and the rest of the
///   pass is the tip cutting and the shaft's friction (Okamura, Simone and O'Leary 2004, IEEE
///   Trans. Biomed. Eng. 51(10); Jiang et al. 2014, J. Biomech. 47:3344–3353: deformation,
///   insertion and extraction phases). Frick et al. 2001 (J. Biomech. 34(10):1335–1340) saw the
///   same peak at a suture needle's entry into skin. The peak: taper-point and reverse-cutting
///   suture needles on 4-0 and 5-0 sutures (TF, C-1, RB-1, P-3, PS-2) puncture tissue with
///   0.61 to 0.90 N on average (Maloney et al. 2025, Ann. Plast. Surg. 95(4):423, rabbit
///   cartilage). The depth of the rise and the force after the drop are chosen, not measured:
///   a millimetre of give, then about a third of the peak (Barnett, Lee and Moore 2015, J. Manuf. Sci.
///   Eng.: friction is about a fifth of the insertion force, the tip's cutting the rest).
/// * Suture tension. Surgeons tying square knots pull with 1.6 N on average in a superficial
///   knot and 3.79 N in a deep one (Laufer et al. 2016, Stud. Health Technol. Inform.
///   220:199–204); knots of 4-0 polypropylene tied with 3 ± 0.5 N survive cyclic loading best of
///   1 to 5 N (Lee, Wong and Tay 2019, Biomed. J. Sci. Tech. Res. 17(2):12716–12721). A pledgeted
///   suture cuts into a porcine aortic annulus from 9.3 ± 6.0 N (Hartrumpf et al. 2022, Medicina
///   58(8):1055): the tension stays well below that.
///
///     NeedlePass pass;
///     for (double depth : depths) felt = wall_force_n(NeedleFeel{}, pass, depth);  // N, along the shaft, out of the wall
///     const double tension = suture_tension_n(NeedleFeel{}, now_ms - tied_ms, tie_ms);
#pragma once

#include <algorithm>
#include <cmath>

namespace heartsim {

/// The needle's feel, N and mm.
struct NeedleFeel {
    double puncture_n = 0.75;          ///< the wall's push at the moment the tip cuts in, N (Maloney 2025: 0.61–0.90 N)
    double puncture_depth_mm = 1.0;    ///< how far the wall gives under the tip before it does, mm (chosen)
    double cutting_n = 0.2;            ///< the tip's cutting once through the surface, N (chosen: with the friction, a third of the peak)
    double friction_n_per_mm = 0.05;   ///< the shaft's friction per mm of it in the wall, N/mm (chosen)
    double suture_tension_n = 3.0;     ///< the stitch drawn tight, N (Lee 2019: 3 ± 0.5 N; Laufer 2016: 1.6–3.79 N)
};

/// Where a needle's pass through the wall is: whether its tip has cut in, and its depth at the
/// last measure (mm).
struct NeedlePass {
    bool punctured = false;
    double depth_mm = 0.0;
};

/// The wall's force on the needle along its shaft for the tip `depth_mm` into the wall (≤ 0: out
/// of it), N: positive pushes the needle back out, negative pulls it in (the friction against a
/// needle drawn out). Until the tip has cut in, the wall gives: puncture_n·(d/puncture_depth)²,
/// the tip cutting in at puncture_depth_mm (punctured from then on); after, cutting_n +
/// friction_n_per_mm·d while the needle goes on in or stays, −friction_n_per_mm·d while it is
/// drawn out (its depth less than at the last measure). Out of the wall the pass starts afresh.
/// Bounded by puncture_n either way; 0 for a NaN depth or a feel with a depth not above 0.
inline double wall_force_n(const NeedleFeel& feel, NeedlePass& pass, double depth_mm) {
    if (!(depth_mm > 0) || !(feel.puncture_depth_mm > 0)) {
        pass = {};
        return 0.0;
    }
    const double peak = std::max(0.0, feel.puncture_n);
    if (!pass.punctured && depth_mm >= feel.puncture_depth_mm) pass.punctured = true;
    double force;
    if (!pass.punctured) {
        const double s = depth_mm / feel.puncture_depth_mm;
        force = peak * s * s;
    } else if (depth_mm < pass.depth_mm) {
        force = -feel.friction_n_per_mm * depth_mm;
    } else {
        force = feel.cutting_n + feel.friction_n_per_mm * depth_mm;
    }
    pass.depth_mm = depth_mm;
    return std::isfinite(force) ? std::clamp(force, -peak, peak) : 0.0;
}

/// The suture's tension `since_tied_ms` after its stitch was tied, drawn tight over `tie_ms`, N:
/// suture_tension_n times the smoothstep of since/tie_ms (as the stitch itself draws tight,
/// libmodel/surgery/patch.h PatchModel::tie), then held. 0 before the tie and for a NaN time.
inline double suture_tension_n(const NeedleFeel& feel, double since_tied_ms, double tie_ms) {
    if (!(since_tied_ms >= 0)) return 0.0;
    const double s = tie_ms > 0 ? std::min(1.0, since_tied_ms / tie_ms) : 1.0;
    const double tension = std::max(0.0, feel.suture_tension_n) * s * s * (3.0 - 2.0 * s);
    return std::isfinite(tension) ? tension : 0.0;
}

}  // namespace heartsim
