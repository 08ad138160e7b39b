/// @file box_mesh.h
/// @brief A closed box's surface mesh, for the incision's tests and its fuzz target: a shape whose
/// volume, faces and cuts are known in closed form.
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <vector>

namespace heartsim::test {

/// A closed box [low, high], each face a grid of squares about `step` mm split into two
/// triangles, counter-clockwise seen from outside, its vertices shared along edges and corners.
struct BoxMesh {
    std::vector<std::array<float, 3>> positions;
    std::vector<std::array<std::int32_t, 3>> triangles;
};
inline BoxMesh box_mesh(const Eigen::Vector3d& low, const Eigen::Vector3d& high, double step) {
    BoxMesh mesh;
    std::array<int, 3> n{};
    for (int a = 0; a < 3; ++a) n[std::size_t(a)] = std::max(1, int(std::lround((high[a] - low[a]) / step)));
    std::map<std::array<int, 3>, std::int32_t> index;
    auto vertex = [&](std::array<int, 3> g) {
        auto [it, added] = index.try_emplace(g, std::int32_t(mesh.positions.size()));
        if (added) {
            std::array<float, 3> p{};
            for (int a = 0; a < 3; ++a) p[std::size_t(a)] = float(low[a] + (high[a] - low[a]) * g[std::size_t(a)] / n[std::size_t(a)]);
            mesh.positions.push_back(p);
        }
        return it->second;
    };
    for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
            const int u = (axis + 1) % 3, v = (axis + 2) % 3;
            for (int i = 0; i < n[std::size_t(u)]; ++i)
                for (int j = 0; j < n[std::size_t(v)]; ++j) {
                    std::array<std::array<int, 3>, 4> c{};
                    for (int k = 0; k < 4; ++k) {
                        c[std::size_t(k)][std::size_t(axis)] = side ? n[std::size_t(axis)] : 0;
                        c[std::size_t(k)][std::size_t(u)] = i + (k == 1 || k == 2);
                        c[std::size_t(k)][std::size_t(v)] = j + (k >= 2);
                    }
                    // (u, v, axis) is right-handed: u→v counter-clockwise seen from +axis.
                    const std::int32_t a = vertex(c[0]), b = vertex(c[1]), d = vertex(c[2]), e = vertex(c[3]);
                    if (side) {
                        mesh.triangles.push_back({a, b, d});
                        mesh.triangles.push_back({a, d, e});
                    } else {
                        mesh.triangles.push_back({a, d, b});
                        mesh.triangles.push_back({a, e, d});
                    }
                }
        }
    return mesh;
}

}  // namespace heartsim::test
