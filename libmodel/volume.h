/// @file volume.h
/// @brief Voxel volumes on a regular grid placed in the world (LPS, mm), as ITK describes them.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace heartsim {

/// Where a voxel grid sits in the world. A voxel index (i,j,k) maps to the world point
///   x = origin + direction · diag(spacing) · (i,j,k)ᵀ      (LPS, mm)
/// which is the centre of that voxel (ITK's convention). `direction` has unit columns: the world
/// direction of +i, +j and +k.
struct VolumeGeometry {
    std::array<int, 3> dims{0, 0, 0};              ///< voxel counts along i, j, k
    Eigen::Vector3d spacing{1.0, 1.0, 1.0};        ///< voxel size along i, j, k, mm (> 0)
    Eigen::Vector3d origin{0.0, 0.0, 0.0};         ///< world position of voxel (0,0,0)'s centre, LPS mm
    Eigen::Matrix3d direction = Eigen::Matrix3d::Identity();  ///< columns: world axes of i, j, k

    std::size_t voxel_count() const {
        return std::size_t(dims[0]) * std::size_t(dims[1]) * std::size_t(dims[2]);
    }
    /// Linear index of voxel (i,j,k); i runs fastest.
    std::size_t linear(int i, int j, int k) const {
        return (std::size_t(k) * std::size_t(dims[1]) + std::size_t(j)) * std::size_t(dims[0]) + std::size_t(i);
    }
    bool contains(int i, int j, int k) const {
        return i >= 0 && j >= 0 && k >= 0 && i < dims[0] && j < dims[1] && k < dims[2];
    }
    /// 4×4 homogeneous matrix taking continuous voxel indices to world LPS mm.
    Eigen::Matrix4d voxel_to_world() const {
        Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
        m.topLeftCorner<3, 3>() = direction * spacing.asDiagonal();
        m.topRightCorner<3, 1>() = origin;
        return m;
    }
    /// World position of continuous voxel index `ijk`.
    Eigen::Vector3d to_world(const Eigen::Vector3d& ijk) const {
        return origin + direction * spacing.cwiseProduct(ijk);
    }
    /// Voxel volume, mm³.
    double voxel_volume() const { return spacing.prod(); }
};

/// An integer label map (segmentation): one label per voxel, i fastest.
struct LabelVolume {
    VolumeGeometry geometry;
    std::vector<std::int32_t> labels;  ///< geometry.voxel_count() values
};

/// A binary mask on a volume grid: 1 = selected, 0 = not, i fastest.
struct Mask {
    VolumeGeometry geometry;
    std::vector<std::uint8_t> values;  ///< geometry.voxel_count() values, each 0 or 1

    bool at(int i, int j, int k) const {
        return geometry.contains(i, j, k) && values[geometry.linear(i, j, k)] != 0;
    }
    std::size_t count() const;
};

}  // namespace heartsim
