/// @file mapping_candidates.h
/// @brief Internal to the mapping: candidate simulation-surface triangles near a point, through a
/// CGAL AABB tree kept inside mapping_candidates.cpp (the one CGAL translation unit of the
/// mapping, so the rest compiles fast). Not part of the public interface.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace heartsim::mapping_internal {

/// An AABB tree over triangles (`triangles` index `points`); queries answer `rows[k]` for
/// triangles[k] (the triangle's row in the caller's list). Built once; queries are const and
/// safe to run from many threads at once.
class TriangleSearch {
public:
    TriangleSearch(const std::vector<Eigen::Vector3d>& points, const std::vector<std::array<std::int32_t, 3>>& triangles,
                   std::vector<std::int32_t> rows);
    ~TriangleSearch();
    TriangleSearch(const TriangleSearch&) = delete;
    TriangleSearch& operator=(const TriangleSearch&) = delete;

    /// The triangle closest to `query` (its row) and the closest point on it.
    std::pair<std::int32_t, Eigen::Vector3d> closest(const Eigen::Vector3d& query) const;

    /// Appends to `out` every triangle meeting the axis-aligned cube of half-size `radius` (mm)
    /// around `query`.
    void near(const Eigen::Vector3d& query, double radius, std::vector<std::int32_t>& out) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace heartsim::mapping_internal
