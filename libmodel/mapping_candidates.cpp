/// @file mapping_candidates.cpp
/// @brief The CGAL AABB tree behind mapping_candidates.h. Simple_cartesian<double> suffices: the
/// tree only ranks candidates; the mapping solves each candidate exactly itself.
#include "libmodel/mapping_candidates.h"

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
    std::vector<std::int32_t> rows;
    std::vector<CGAL::Bbox_3> boxes;  ///< of each triangle
    Tree tree;
};

TriangleSearch::TriangleSearch(const std::vector<Eigen::Vector3d>& points,
                               const std::vector<std::array<std::int32_t, 3>>& triangles, std::vector<std::int32_t> rows)
    : impl_(std::make_unique<Impl>()) {
    impl_->rows = std::move(rows);
    auto point = [&](std::int32_t i) {
        const Eigen::Vector3d& p = points[std::size_t(i)];
        return Point(p.x(), p.y(), p.z());
    };
    impl_->triangles.reserve(triangles.size());
    for (const auto& t : triangles) impl_->triangles.emplace_back(point(t[0]), point(t[1]), point(t[2]));
    impl_->boxes.reserve(impl_->triangles.size());
    for (const auto& t : impl_->triangles) impl_->boxes.push_back(t.bbox());
    impl_->tree.insert(impl_->triangles.cbegin(), impl_->triangles.cend());
    impl_->tree.build();
    // Built now, not lazily on the first query, so that concurrent queries only read.
    impl_->tree.accelerate_distance_queries();
}

TriangleSearch::~TriangleSearch() = default;

std::pair<std::int32_t, Eigen::Vector3d> TriangleSearch::closest(const Eigen::Vector3d& query) const {
    // (Starting from the previous vertex's answer as a hint was tried: twice slower than the
    // k-d tree start that accelerate_distance_queries builds.)
    const auto [point, primitive] = impl_->tree.closest_point_and_primitive(Point(query.x(), query.y(), query.z()));
    return {impl_->rows[std::size_t(std::distance(impl_->triangles.cbegin(), primitive))], Eigen::Vector3d(point.x(), point.y(), point.z())};
}

namespace {
/// CGAL traversal traits listing the primitives whose bounding box meets a box: the tree's own
/// node test, and a box-box test on the primitives instead of CGAL's exact triangle-box test (the
/// caller measures each candidate's distance itself, so a superset is fine and much cheaper).
struct BoxListing {
    const std::vector<CGAL::Bbox_3>* boxes;
    const std::vector<Triangle>* triangles;
    const std::vector<std::int32_t>* rows;
    std::vector<std::int32_t>* out;
    bool go_further() const { return true; }
    void intersection(const CGAL::Bbox_3& query, const Primitive& primitive) {
        const std::size_t k = std::size_t(std::distance(triangles->cbegin(), primitive.id()));
        if (CGAL::do_overlap(query, (*boxes)[k])) out->push_back((*rows)[k]);
    }
    template <class Node> bool do_intersect(const CGAL::Bbox_3& query, const Node& node) const {
        return CGAL::do_overlap(query, node.bbox());
    }
};
}  // namespace

void TriangleSearch::near(const Eigen::Vector3d& query, double radius, std::vector<std::int32_t>& out) const {
    const CGAL::Bbox_3 box(query.x() - radius, query.y() - radius, query.z() - radius, query.x() + radius,
                           query.y() + radius, query.z() + radius);
    BoxListing listing{&impl_->boxes, &impl_->triangles, &impl_->rows, &out};
    impl_->tree.traversal(box, listing);
}

}  // namespace heartsim::mapping_internal
