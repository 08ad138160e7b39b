/// @file mapping_candidates.cpp
/// @brief The CGAL AABB tree behind mapping_candidates.h. Simple_cartesian<double> suffices: the
/// tree only ranks candidates; the mapping solves each candidate exactly itself.
#include "mapping_candidates.h"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <iterator>

namespace heartsim::mapping_internal {

namespace {
using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using Iterator = std::vector<Triangle>::const_iterator;
using Primitive = CGAL::AABB_triangle_primitive<Kernel, Iterator>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;
}  // namespace

struct TriangleSearch::Impl {
    std::vector<Triangle> triangles;
    Tree tree;
};

TriangleSearch::TriangleSearch(const std::vector<Eigen::Vector3d>& points,
                               const std::vector<std::array<std::int32_t, 3>>& triangles)
    : impl_(std::make_unique<Impl>()) {
    auto point = [&](std::int32_t i) {
        const Eigen::Vector3d& p = points[std::size_t(i)];
        return Point(p.x(), p.y(), p.z());
    };
    impl_->triangles.reserve(triangles.size());
    for (const auto& t : triangles) impl_->triangles.emplace_back(point(t[0]), point(t[1]), point(t[2]));
    impl_->tree.insert(impl_->triangles.cbegin(), impl_->triangles.cend());
    impl_->tree.build();
    // Built now, not lazily on the first query, so that concurrent queries only read.
    impl_->tree.accelerate_distance_queries();
}

TriangleSearch::~TriangleSearch() = default;

std::pair<std::int32_t, Eigen::Vector3d> TriangleSearch::closest(const Eigen::Vector3d& query) const {
    const auto [point, primitive] = impl_->tree.closest_point_and_primitive(Point(query.x(), query.y(), query.z()));
    return {std::int32_t(std::distance(impl_->triangles.cbegin(), primitive)), Eigen::Vector3d(point.x(), point.y(), point.z())};
}

void TriangleSearch::near(const Eigen::Vector3d& query, double radius, std::vector<std::int32_t>& out) const {
    const CGAL::Bbox_3 box(query.x() - radius, query.y() - radius, query.z() - radius, query.x() + radius,
                           query.y() + radius, query.z() + radius);
    std::vector<Iterator> hits;
    impl_->tree.all_intersected_primitives(box, std::back_inserter(hits));
    for (const auto& hit : hits) out.push_back(std::int32_t(std::distance(impl_->triangles.cbegin(), hit)));
}

}  // namespace heartsim::mapping_internal
