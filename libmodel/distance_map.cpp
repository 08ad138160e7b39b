// The exact Euclidean distance map of landmarks.h (distance_map): Felzenszwalb and Huttenlocher's
// separable transform, one grid axis at a time with that axis' spacing.
#include "landmarks.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace heartsim {

namespace {

/// One line of the separable transform: out[q] = min_p (s·(q − p))² + f[p] (f: squared distances,
/// +inf where none), by the lower envelope of parabolas.
void transform_line(const double* f, int n, double s, double* out, int* v, double* z) {
    int k = -1;
    for (int q = 0; q < n; ++q) {
        if (!std::isfinite(f[q])) continue;
        const double xq = q * s;
        if (k < 0) {
            k = 0, v[0] = q, z[0] = -std::numeric_limits<double>::infinity(), z[1] = std::numeric_limits<double>::infinity();
            continue;
        }
        double cross = 0.0;
        for (;;) {
            const double xv = v[k] * s;
            cross = ((f[q] + xq * xq) - (f[v[k]] + xv * xv)) / (2.0 * (xq - xv));
            if (cross <= z[k]) --k;  // z[0] is −inf: k never drops below 0
            else break;
        }
        ++k;
        v[k] = q, z[k] = cross, z[k + 1] = std::numeric_limits<double>::infinity();
    }
    if (k < 0) {
        std::fill(out, out + n, std::numeric_limits<double>::infinity());
        return;
    }
    k = 0;
    for (int q = 0; q < n; ++q) {
        const double x = q * s;
        while (z[k + 1] < x) ++k;
        const double d = x - v[k] * s;
        out[q] = d * d + f[v[k]];
    }
}

}  // namespace

std::vector<float> distance_map(const VolumeGeometry& geometry, const std::vector<std::uint8_t>& inside) {
    const auto& d = geometry.dims;
    std::vector<double> squared(geometry.voxel_count());
    for (std::size_t n = 0; n < squared.size(); ++n) squared[n] = inside[n] ? 0.0 : std::numeric_limits<double>::infinity();
    for (int axis = 0; axis < 3; ++axis) {
        const int n = d[std::size_t(axis)];
        const int other1 = (axis + 1) % 3, other2 = (axis + 2) % 3;
        const std::size_t lines = std::size_t(d[std::size_t(other1)]) * std::size_t(d[std::size_t(other2)]);
        const double s = geometry.spacing[axis];
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, lines, 256), [&](const tbb::blocked_range<std::size_t>& range) {
            std::vector<double> f(static_cast<std::size_t>(n)), out(static_cast<std::size_t>(n)), z(static_cast<std::size_t>(n) + 1);
            std::vector<int> v(static_cast<std::size_t>(n));
            for (std::size_t line = range.begin(); line != range.end(); ++line) {
                std::array<int, 3> at{};
                at[std::size_t(other1)] = int(line % std::size_t(d[std::size_t(other1)]));
                at[std::size_t(other2)] = int(line / std::size_t(d[std::size_t(other1)]));
                at[std::size_t(axis)] = 0;
                const std::size_t first = geometry.linear(at[0], at[1], at[2]);
                std::size_t stride = 1;
                for (int a = 0; a < axis; ++a) stride *= std::size_t(d[std::size_t(a)]);
                for (int q = 0; q < n; ++q) f[std::size_t(q)] = squared[first + std::size_t(q) * stride];
                transform_line(f.data(), n, s, out.data(), v.data(), z.data());
                for (int q = 0; q < n; ++q) squared[first + std::size_t(q) * stride] = out[std::size_t(q)];
            }
        });
    }
    std::vector<float> distance(squared.size());
    for (std::size_t n = 0; n < squared.size(); ++n) distance[n] = float(std::sqrt(squared[n]));
    return distance;
}

}  // namespace heartsim
