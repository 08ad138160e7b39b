/// @file mesh.cpp
/// @brief Topology checks and measures of triangle meshes, from our own edge map (no CGAL), so
/// the checks can judge the CGAL-based stages independently.
#include "libmodel/mesh.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <numeric>

namespace heartsim {

namespace {

/// Disjoint sets with path halving; small and local.
class DisjointSets {
public:
    explicit DisjointSets(std::size_t count) : parent_(count) {
        std::iota(parent_.begin(), parent_.end(), std::size_t(0));
    }
    std::size_t find(std::size_t x) {
        while (parent_[x] != x) x = parent_[x] = parent_[parent_[x]];
        return x;
    }
    void unite(std::size_t a, std::size_t b) {
        a = find(a);
        b = find(b);
        if (a != b) parent_[std::max(a, b)] = std::min(a, b);
    }
private:
    std::vector<std::size_t> parent_;
};

/// One directed use of an edge by a triangle, keyed by its undirected vertex pair.
struct HalfEdge {
    std::int32_t low, high;  ///< vertex ids, low < high
    bool forward;            ///< the triangle walks low -> high
    std::int32_t face;
    bool operator<(const HalfEdge& other) const {
        if (low != other.low) return low < other.low;
        if (high != other.high) return high < other.high;
        return face < other.face;
    }
};

bool has_repeated_vertex(const std::array<std::int32_t, 3>& t) {
    return t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
}

}  // namespace

MeshReport analyse_mesh(const TriangleMesh& mesh) {
    MeshReport report;
    const std::size_t vertex_count = mesh.positions.size();
    report.faces = mesh.triangles.size();

    // Measures. The volume is taken about the bounding-box centre: the same value for a closed
    // surface, with less cancellation far from the world origin.
    const auto box = bounds(mesh);
    const Eigen::Vector3d centre = 0.5 * (box[0] + box[1]);
    std::vector<bool> used(vertex_count, false);
    for (const auto& t : mesh.triangles) {
        for (int c = 0; c < 3; ++c) used[std::size_t(t[c])] = true;
        const Eigen::Vector3d a = mesh.positions[std::size_t(t[0])] - centre;
        const Eigen::Vector3d b = mesh.positions[std::size_t(t[1])] - centre;
        const Eigen::Vector3d c = mesh.positions[std::size_t(t[2])] - centre;
        const Eigen::Vector3d twice_area_normal = (b - a).cross(c - a);
        const double twice_area = twice_area_normal.norm();
        report.area += 0.5 * twice_area;
        report.volume += a.dot(b.cross(c)) / 6.0;
        // Zero area relative to the edge lengths: exact collinearity up to rounding.
        const double scale = (b - a).norm() * (c - a).norm();
        if (has_repeated_vertex(t) || twice_area <= 1e-12 * scale) ++report.degenerate_faces;
    }
    report.vertices = std::size_t(std::count(used.begin(), used.end(), true));
    report.unused_vertices = vertex_count - report.vertices;

    // Edge map: sort the directed uses of each undirected edge together. Faces with a repeated
    // vertex have no well-defined edges and are left out of the topology.
    std::vector<HalfEdge> half_edges;
    half_edges.reserve(3 * mesh.triangles.size());
    for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
        const auto& t = mesh.triangles[f];
        if (has_repeated_vertex(t)) continue;
        for (int c = 0; c < 3; ++c) {
            const std::int32_t from = t[c], to = t[(c + 1) % 3];
            half_edges.push_back({std::min(from, to), std::max(from, to), from < to, std::int32_t(f)});
        }
    }
    std::sort(half_edges.begin(), half_edges.end());

    DisjointSets face_sets(mesh.triangles.size());
    for (std::size_t begin = 0; begin < half_edges.size();) {
        std::size_t end = begin + 1;
        while (end < half_edges.size() && half_edges[end].low == half_edges[begin].low &&
               half_edges[end].high == half_edges[begin].high)
            ++end;
        ++report.edges;
        const std::size_t uses = end - begin;
        if (uses == 1) ++report.boundary_edges;
        if (uses > 2) ++report.nonmanifold_edges;
        if (uses == 2 && half_edges[begin].forward == half_edges[begin + 1].forward) ++report.misoriented_edges;
        for (std::size_t h = begin + 1; h < end; ++h)
            face_sets.unite(std::size_t(half_edges[begin].face), std::size_t(half_edges[h].face));
        begin = end;
    }
    for (std::size_t f = 0; f < mesh.triangles.size(); ++f)
        if (!has_repeated_vertex(mesh.triangles[f]) && face_sets.find(f) == f) ++report.components;

    // Non-manifold vertices: the link of a vertex (the edges opposite it in its triangles) must be
    // one connected path or cycle; two or more pieces mean fans touching at the vertex only.
    std::vector<std::size_t> first_face(vertex_count + 1, 0);
    for (const auto& t : mesh.triangles)
        if (!has_repeated_vertex(t))
            for (int c = 0; c < 3; ++c) ++first_face[std::size_t(t[c]) + 1];
    std::partial_sum(first_face.begin(), first_face.end(), first_face.begin());
    std::vector<std::int32_t> incident_faces(first_face.back());
    {
        std::vector<std::size_t> fill(first_face.begin(), first_face.end() - 1);
        for (std::size_t f = 0; f < mesh.triangles.size(); ++f)
            if (!has_repeated_vertex(mesh.triangles[f]))
                for (int c = 0; c < 3; ++c) incident_faces[fill[std::size_t(mesh.triangles[f][c])]++] = std::int32_t(f);
    }
    std::vector<std::int32_t> link_vertices;
    std::vector<std::size_t> link_parent;
    for (std::size_t v = 0; v < vertex_count; ++v) {
        const std::size_t begin = first_face[v], end = first_face[v + 1];
        if (begin == end) continue;
        link_vertices.clear();
        auto local = [&](std::int32_t id) {
            auto found = std::find(link_vertices.begin(), link_vertices.end(), id);
            if (found != link_vertices.end()) return std::size_t(found - link_vertices.begin());
            link_vertices.push_back(id);
            link_parent.resize(link_vertices.size());
            link_parent.back() = link_vertices.size() - 1;
            return link_vertices.size() - 1;
        };
        auto root = [&](std::size_t x) {
            while (link_parent[x] != x) x = link_parent[x];
            return x;
        };
        std::size_t pieces = 0;
        for (std::size_t i = begin; i < end; ++i) {
            const auto& t = mesh.triangles[std::size_t(incident_faces[i])];
            const int corner = t[0] == std::int32_t(v) ? 0 : (t[1] == std::int32_t(v) ? 1 : 2);
            const std::size_t before = link_vertices.size();
            const std::size_t a = local(t[(corner + 1) % 3]);
            const std::size_t b = local(t[(corner + 2) % 3]);
            pieces += link_vertices.size() - before;  // each new link vertex starts a piece
            const std::size_t root_a = root(a), root_b = root(b);
            if (root_a != root_b) {
                link_parent[std::max(root_a, root_b)] = std::min(root_a, root_b);
                --pieces;
            }
        }
        if (pieces > 1) ++report.nonmanifold_vertices;
    }

    report.euler_characteristic = long(report.vertices) - long(report.edges) + long(report.faces);
    return report;
}

void compute_vertex_normals(TriangleMesh& mesh) {
    mesh.normals.assign(mesh.positions.size(), Eigen::Vector3d::Zero());
    for (const auto& t : mesh.triangles) {
        const Eigen::Vector3d& a = mesh.positions[std::size_t(t[0])];
        // The unnormalised cross product is twice the area times the unit normal: area weighting.
        const Eigen::Vector3d weighted =
            (mesh.positions[std::size_t(t[1])] - a).cross(mesh.positions[std::size_t(t[2])] - a);
        for (int c = 0; c < 3; ++c) mesh.normals[std::size_t(t[c])] += weighted;
    }
    for (auto& normal : mesh.normals) {
        const double length = normal.norm();
        normal = length > 0.0 ? Eigen::Vector3d(normal / length) : Eigen::Vector3d::Zero();
    }
}

std::array<Eigen::Vector3d, 2> bounds(const TriangleMesh& mesh) {
    if (mesh.positions.empty()) return {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    Eigen::Vector3d low = mesh.positions.front(), high = mesh.positions.front();
    for (const auto& p : mesh.positions) {
        low = low.cwiseMin(p);
        high = high.cwiseMax(p);
    }
    return {low, high};
}

}  // namespace heartsim
