/// @file defect_block.h
/// @brief A synthetic two-chamber block with a septum of known thickness, for the septal defect
/// tests (test_defect.cpp: the library; test_defect_cli.cpp: heartprep).
#pragma once

#include "libmodel/defect.h"
#include "libmodel/volume.h"

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <deque>
#include <vector>

namespace heartsim::test::defect_block {

constexpr int wall = 1, left = 3, right = 5, aorta = 6;

/// A closed box (myocardium walls 3 mm thick) holding two pools, left (x below the septum) and
/// right, parted by a septum `septum_mm` thick across x at x = 0, `height_mm` tall (z) and 40 mm
/// deep (y); an anisotropic grid turned by a rotation, so nothing lines up with the voxel axes by
/// chance. With `with_aorta`, a pool of aorta blood sits above the septum's top end (z high),
/// walled off from both pools.
struct Block {
    LabelVolume volume;
    Eigen::Matrix3d rotation;
    double septum_mm, height_mm;
    /// Local block coordinates (x across the septum) of a voxel centre.
    Eigen::Vector3d local(int i, int j, int k) const {
        const Eigen::Vector3d world = volume.geometry.to_world(Eigen::Vector3d(i, j, k));
        return rotation.transpose() * world;
    }
    Eigen::Vector3d world(const Eigen::Vector3d& local) const { return rotation * local; }
};

inline Block make_block(double septum_mm = 6.0, double height_mm = 40.0, bool with_aorta = false) {
    Block b;
    b.septum_mm = septum_mm;
    b.height_mm = height_mm;
    b.rotation = (Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.25, Eigen::Vector3d::UnitY())).toRotationMatrix();
    auto& g = b.volume.geometry;
    g.spacing = Eigen::Vector3d(0.5, 0.6, 0.7);
    g.direction = b.rotation;
    const double half_x = 25.0, half_y = 23.0, half_z = 0.5 * height_mm + 3.0 + (with_aorta ? 14.0 : 0.0) + 3.0;
    const Eigen::Vector3d extent(2 * half_x, 2 * half_y, 2 * half_z);
    for (int a = 0; a < 3; ++a) g.dims[std::size_t(a)] = int(std::ceil(extent[a] / g.spacing[a])) + 1;
    // Centre the grid on the local origin.
    g.origin = b.rotation * (-0.5 * Eigen::Vector3d(g.dims[0] - 1, g.dims[1] - 1, g.dims[2] - 1).cwiseProduct(g.spacing));
    b.volume.labels.assign(g.voxel_count(), 0);
    const double top = 0.5 * height_mm;
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                const Eigen::Vector3d p = b.local(i, j, k);
                int label = 0;
                const bool in_box = std::abs(p.x()) < 22.0 && std::abs(p.y()) < 20.0 && p.z() > -top - 3.0 && p.z() < top + 3.0;
                if (in_box) {
                    const bool cavity = std::abs(p.y()) < 17.0 && std::abs(p.z()) < top && std::abs(p.x()) < 19.0;
                    label = !cavity ? wall : std::abs(p.x()) <= 0.5 * septum_mm ? wall : p.x() < 0 ? left : right;
                }
                if (with_aorta && p.z() >= top + 3.0 && p.z() < top + 17.0 && std::abs(p.x()) < 10.0 && std::abs(p.y()) < 10.0)
                    label = p.z() < top + 6.0 || std::abs(p.x()) > 7.0 || std::abs(p.y()) > 7.0 ? wall : aorta;
                b.volume.labels[g.linear(i, j, k)] = label;
            }
    return b;
}

inline DefectOptions block_options(bool sided) {
    DefectOptions o;
    o.wall_labels = {wall};
    o.blood_labels = {left, right, aorta};
    if (sided) {
        o.side_a = left;
        o.side_b = right;
        o.aorta = aorta;
    }
    return o;
}

/// Whether any voxel of label `from` reaches one of label `to` through voxels of either label
/// (6-connected), over the whole volume.
inline bool pools_connect(const LabelVolume& v, int from, int to) {
    const auto& g = v.geometry;
    std::vector<std::uint8_t> seen(v.labels.size());
    std::deque<std::array<int, 3>> queue;
    for (int k = 0; k < g.dims[2] && queue.empty(); ++k)
        for (int j = 0; j < g.dims[1] && queue.empty(); ++j)
            for (int i = 0; i < g.dims[0] && queue.empty(); ++i)
                if (v.labels[g.linear(i, j, k)] == from) queue.push_back({i, j, k}), seen[g.linear(i, j, k)] = 1;
    while (!queue.empty()) {
        const auto p = queue.front();
        queue.pop_front();
        if (v.labels[g.linear(p[0], p[1], p[2])] == to) return true;
        for (const auto& d : std::array<std::array<int, 3>, 6>{{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}}}) {
            const int i = p[0] + d[0], j = p[1] + d[1], k = p[2] + d[2];
            if (!g.contains(i, j, k) || seen[g.linear(i, j, k)]) continue;
            const int l = v.labels[g.linear(i, j, k)];
            if (l != from && l != to) continue;
            seen[g.linear(i, j, k)] = 1;
            queue.push_back({i, j, k});
        }
    }
    return false;
}


}  // namespace heartsim::test::defect_block
