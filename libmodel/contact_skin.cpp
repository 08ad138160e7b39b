#include "libmodel/contact_skin.h"

#include "libmodel/errors.h"
#include "libmodel/triangle_point.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <unordered_map>

namespace heartsim {

namespace {

using Cell = std::array<std::int64_t, 3>;

std::int64_t cell_key(const Cell& c) {
    // 21 bits per axis: a grid of over two million cells a side, far beyond any heart.
    const std::int64_t mask = (std::int64_t(1) << 21) - 1;
    return ((c[0] & mask) << 42) | ((c[1] & mask) << 21) | (c[2] & mask);
}

Eigen::Vector3d vec(const std::array<float, 3>& a) { return {double(a[0]), double(a[1]), double(a[2])}; }

}  // namespace

std::vector<float> contact_skin(const std::vector<std::array<float, 3>>& rest, const std::vector<std::array<std::int32_t, 18>>& neighbours,
                                const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                                const std::vector<std::array<std::int32_t, 3>>& triangles, double spacing) {
    if (!(spacing > 0) || !std::isfinite(spacing)) throw InputError("contact skin: the lattice spacing must be positive and finite");
    if (neighbours.size() != rest.size())
        throw InputError("contact skin: " + std::to_string(neighbours.size()) + " neighbour rows for " + std::to_string(rest.size()) +
                         " particles");
    if (normals.size() != positions.size())
        throw InputError("contact skin: " + std::to_string(normals.size()) + " normals for " + std::to_string(positions.size()) +
                         " surface vertices");
    std::vector<float> skin(rest.size(), 0.0f);
    if (triangles.empty()) return skin;
    for (std::size_t t = 0; t < triangles.size(); ++t)
        for (const std::int32_t v : triangles[t])
            if (v < 0 || std::size_t(v) >= positions.size())
                throw InputError("contact skin: triangle " + std::to_string(t) + " names vertex " + std::to_string(v) + " of " +
                                 std::to_string(positions.size()));

    // The triangles by the cells (of one spacing) their boxes meet.
    const auto cell_of = [&](const Eigen::Vector3d& p) {
        return Cell{std::int64_t(std::floor(p.x() / spacing)), std::int64_t(std::floor(p.y() / spacing)),
                    std::int64_t(std::floor(p.z() / spacing))};
    };
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells;
    for (std::size_t t = 0; t < triangles.size(); ++t) {
        Eigen::Vector3d low = vec(positions[std::size_t(triangles[t][0])]), high = low;
        for (int c = 1; c < 3; ++c) {
            const Eigen::Vector3d p = vec(positions[std::size_t(triangles[t][std::size_t(c)])]);
            low = low.cwiseMin(p);
            high = high.cwiseMax(p);
        }
        if (!low.allFinite() || !high.allFinite()) continue;
        const Cell a = cell_of(low), b = cell_of(high);
        if ((b[0] - a[0] + 1) * (b[1] - a[1] + 1) * (b[2] - a[2] + 1) > 4096) continue;  // a sliver across the model: not a surface face
        for (std::int64_t k = a[2]; k <= b[2]; ++k)
            for (std::int64_t j = a[1]; j <= b[1]; ++j)
                for (std::int64_t i = a[0]; i <= b[0]; ++i) cells[cell_key({i, j, k})].push_back(std::int32_t(t));
    }

    std::vector<std::uint32_t> seen(triangles.size(), 0);
    std::uint32_t stamp = 0;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const bool boundary = std::any_of(neighbours[i].begin(), neighbours[i].end(), [](std::int32_t j) { return j < 0; });
        if (!boundary) continue;
        const Eigen::Vector3d p = vec(rest[i]);
        ++stamp;
        double best = spacing * spacing;
        std::int32_t nearest = -1;
        Eigen::Vector3d nearest_weights = Eigen::Vector3d::Zero();
        const Cell a = cell_of(p - Eigen::Vector3d::Constant(spacing)), b = cell_of(p + Eigen::Vector3d::Constant(spacing));
        for (std::int64_t z = a[2]; z <= b[2]; ++z)
            for (std::int64_t y = a[1]; y <= b[1]; ++y)
                for (std::int64_t x = a[0]; x <= b[0]; ++x) {
                    const auto found = cells.find(cell_key({x, y, z}));
                    if (found == cells.end()) continue;
                    for (const std::int32_t t : found->second) {
                        if (seen[std::size_t(t)] == stamp) continue;
                        seen[std::size_t(t)] = stamp;
                        const auto& tri = triangles[std::size_t(t)];
                        const Eigen::Vector3d va = vec(positions[std::size_t(tri[0])]), vb = vec(positions[std::size_t(tri[1])]),
                                              vc = vec(positions[std::size_t(tri[2])]);
                        const Eigen::Vector3d w = closest_barycentric(p, va, vb, vc);
                        const double d2 = (w.x() * va + w.y() * vb + w.z() * vc - p).squaredNorm();
                        if (d2 < best) {
                            best = d2;
                            nearest = t;
                            nearest_weights = w;
                        }
                    }
                }
        if (nearest < 0) continue;
        const auto& tri = triangles[std::size_t(nearest)];
        Eigen::Vector3d point = Eigen::Vector3d::Zero(), normal = Eigen::Vector3d::Zero();
        for (int c = 0; c < 3; ++c) {
            point += nearest_weights[c] * vec(positions[std::size_t(tri[std::size_t(c)])]);
            normal += nearest_weights[c] * vec(normals[std::size_t(tri[std::size_t(c)])]);
        }
        const double side = (point - p).dot(normal);  // > 0: the particle lies inside the drawn surface
        skin[i] = side > 0 ? float(std::sqrt(best)) : side < 0 ? -float(std::sqrt(best)) : 0.0f;
    }
    return skin;
}

}  // namespace heartsim
