// The scalpel's swept surface and the spring-crossing test (cutting.h). The float arithmetic is
// written out operation by operation, mirrored by the gl backend's cut pass; fp-contract is off
// so that no multiply and add here fuse where the shader's `precise` keeps them apart.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/cutting.h"

#include "libmodel/sim/solver.h"

#include <algorithm>

namespace heartsim {

namespace {

/// (b − a) · ((c − a) × (d − a)): six times the signed volume of the tetrahedron abcd.
float orient(const float* a, const float* b, const float* c, const float* d) {
    const float bx = b[0] - a[0], by = b[1] - a[1], bz = b[2] - a[2];
    const float cx = c[0] - a[0], cy = c[1] - a[1], cz = c[2] - a[2];
    const float dx = d[0] - a[0], dy = d[1] - a[1], dz = d[2] - a[2];
    const float nx = cy * dz - cz * dy;
    const float ny = cz * dx - cx * dz;
    const float nz = cx * dy - cy * dx;
    float v = bx * nx + by * ny;
    v = v + bz * nz;
    return v;
}

bool crosses_triangle(const float* t0, const float* t1, const float* t2, const float* p, const float* q) {
    // A point on the plane counts as on its positive side: a spring with an end on the blade's
    // plane is cut once, on the side where the other end lies below, never twice or never.
    const float sp = orient(t0, t1, t2, p), sq = orient(t0, t1, t2, q);
    if ((sp >= 0.0f) == (sq >= 0.0f)) return false;
    const float e0 = orient(p, q, t0, t1), e1 = orient(p, q, t1, t2), e2 = orient(p, q, t2, t0);
    return (e0 >= 0.0f && e1 >= 0.0f && e2 >= 0.0f) || (e0 <= 0.0f && e1 <= 0.0f && e2 <= 0.0f);
}

}  // namespace

std::array<Eigen::Vector3d, 2> blade_segment(const InstrumentPose& pose, double length) {
    const Eigen::Vector3d axis = pose.orientation.normalized() * Eigen::Vector3d::UnitZ();
    return {pose.position, pose.position + length * axis};
}

BladeSweep blade_sweep(const InstrumentPose& from, const InstrumentPose& to, double length, float margin) {
    BladeSweep sweep;
    const auto a = blade_segment(from, length), b = blade_segment(to, length);
    const Eigen::Vector3d corners[4] = {a[0], a[1], b[1], b[0]};
    for (int c = 0; c < 4; ++c)
        for (int d = 0; d < 3; ++d) sweep.corner[std::size_t(c)][std::size_t(d)] = float(corners[c][d]);
    for (int d = 0; d < 3; ++d) {
        sweep.low[std::size_t(d)] = sweep.high[std::size_t(d)] = sweep.corner[0][std::size_t(d)];
        for (int c = 1; c < 4; ++c) {
            sweep.low[std::size_t(d)] = std::min(sweep.low[std::size_t(d)], sweep.corner[std::size_t(c)][std::size_t(d)]);
            sweep.high[std::size_t(d)] = std::max(sweep.high[std::size_t(d)], sweep.corner[std::size_t(c)][std::size_t(d)]);
        }
        sweep.near_low[std::size_t(d)] = sweep.low[std::size_t(d)] - margin;
        sweep.near_high[std::size_t(d)] = sweep.high[std::size_t(d)] + margin;
    }
    // Twice the quad's area, from its two triangles: zero when the blade stood still or moved
    // along itself.
    const double area = ((a[1] - a[0]).cross(b[1] - a[0])).norm() + ((b[1] - a[0]).cross(b[0] - a[0])).norm();
    sweep.cuts_anything = length > 0 && area > 1e-12 * std::max(1.0, length * length);
    return sweep;
}

bool spring_crosses(const BladeSweep& sweep, const float* p, const float* q) {
    if (!sweep.cuts_anything) return false;
    for (int d = 0; d < 3; ++d)
        if (std::max(p[d], q[d]) < sweep.low[std::size_t(d)] || std::min(p[d], q[d]) > sweep.high[std::size_t(d)]) return false;
    const auto& c = sweep.corner;
    return crosses_triangle(c[0].data(), c[1].data(), c[2].data(), p, q) || crosses_triangle(c[0].data(), c[2].data(), c[3].data(), p, q);
}


void StrokeLog::sweep(int hand, const InstrumentPose& from, const InstrumentPose& to, double length) {
    if (hand < 0 || hand > 1) return;
    int& row = open_[std::size_t(hand)];
    if (row < 0) {
        row = int(strokes_.size());
        strokes_.push_back({hand, length, {from}, false});
    }
    strokes_[std::size_t(row)].poses.push_back(to);
    ++version_;
}

void StrokeLog::lift(int hand) {
    if (hand < 0 || hand > 1 || open_[std::size_t(hand)] < 0) return;
    strokes_[std::size_t(open_[std::size_t(hand)])].lifted = true;
    open_[std::size_t(hand)] = -1;
    ++version_;
}

void StrokeLog::clear() {
    strokes_.clear();
    open_ = {-1, -1};
    ++version_;
    ++clears_;
}

}  // namespace heartsim
