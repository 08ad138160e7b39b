/// @file incision.cpp
/// @brief incision.h: CGAL's corefinement of the detailed mesh's faces near the cut with the swept
/// strip, then the split, the caps and the slit in plain arrays. The only translation unit of the
/// incision that includes CGAL (it compiles slowly).
#include "libmodel/surgery/incision.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/corefinement.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <map>
#include <optional>
#include <set>
#include <unordered_map>

namespace heartsim {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using VertexIndex = Mesh::Vertex_index;
using FaceIndex = Mesh::Face_index;
namespace pmp = CGAL::Polygon_mesh_processing;

/// Carries a face's cap flag to the faces corefinement splits it into.
struct CapVisitor : pmp::Corefinement::Default_visitor<Mesh> {
    Mesh* patch = nullptr;
    Mesh::Property_map<FaceIndex, std::uint8_t>* cap = nullptr;
    FaceIndex* splitting = nullptr;
    void before_subface_creations(FaceIndex f, Mesh& tm) {
        if (&tm == patch) *splitting = f;
    }
    void after_subface_created(FaceIndex f, Mesh& tm) {
        if (&tm == patch && *splitting != Mesh::null_face()) (*cap)[f] = (*cap)[*splitting];
    }
};

Point point(const Eigen::Vector3d& p) { return {p.x(), p.y(), p.z()}; }
Eigen::Vector3d vector(const Point& p) { return {p.x(), p.y(), p.z()}; }

struct PointKey {
    double x, y, z;
    bool operator<(const PointKey& o) const { return std::tie(x, y, z) < std::tie(o.x, o.y, o.z); }
};
PointKey key(const Point& p) { return {p.x(), p.y(), p.z()}; }

/// Per point, the sides of the box `low`–`high` it lies beyond: bit 2k below it along axis k, bit
/// 2k + 1 above it. A triangle's box misses the box exactly where its corners share such a bit.
std::vector<std::uint8_t> sides_beyond(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& low, const Eigen::Vector3d& high) {
    std::vector<std::uint8_t> sides(points.size());
    for (std::size_t v = 0; v < points.size(); ++v) {
        unsigned bits = 0;
        for (int k = 0; k < 3; ++k) bits |= (points[v][k] < low[k] ? 1u : 0u) << (2 * k) | (points[v][k] > high[k] ? 2u : 0u) << (2 * k);
        sides[v] = std::uint8_t(bits);
    }
    return sides;
}

/// Whether each of `points` lies inside the closed mesh: the parity of the crossings of three
/// rays from it, each nearly along one axis (tilted by about a thousandth, so that a ray rarely
/// meets an edge or a vertex of a mesh whose features follow the voxel axes), the majority. Each
/// ray's exact test runs only on the triangles whose boxes its narrow column meets, looked for
/// among those whose boxes meet the columns of all the points' rays along that axis: one pass over
/// the mesh per axis, whatever the number of points. `box` bounds `rest`.
std::vector<std::uint8_t> inside(const std::vector<Point>& points, const std::vector<Eigen::Vector3d>& rest,
                                 const std::vector<std::array<std::int32_t, 3>>& triangles, const Eigen::AlignedBox3d& box) {
    static const double tilt[3][2] = {{1.31e-3, 0.73e-3}, {0.89e-3, -1.17e-3}, {-0.61e-3, 1.07e-3}};
    auto apart = [&](const std::array<std::int32_t, 3>& t, const Eigen::Vector3d& low, const Eigen::Vector3d& high) {
        const Eigen::Vector3d& a = rest[std::size_t(t[0])];
        const Eigen::Vector3d& b = rest[std::size_t(t[1])];
        const Eigen::Vector3d& c = rest[std::size_t(t[2])];
        for (int k = 0; k < 3; ++k)
            if (std::max({a[k], b[k], c[k]}) < low[k] || std::min({a[k], b[k], c[k]}) > high[k]) return true;
        return false;
    };
    // Per axis: its direction, each ray's column (none for a point beyond the mesh along this
    // axis: no crossing, outside) and the box of all of them.
    std::array<Eigen::Vector3d, 3> direction;
    std::array<std::vector<std::optional<Eigen::AlignedBox3d>>, 3> column;
    std::array<Eigen::AlignedBox3d, 3> all;
    for (int axis = 0; axis < 3; ++axis) {
        Eigen::Vector3d& d = direction[std::size_t(axis)];
        d = Eigen::Vector3d::Zero();
        d[axis] = 1.0;
        d[(axis + 1) % 3] = tilt[axis][0];
        d[(axis + 2) % 3] = tilt[axis][1];
        column[std::size_t(axis)].resize(points.size());
        all[std::size_t(axis)].setEmpty();
        for (std::size_t i = 0; i < points.size(); ++i) {
            const Eigen::Vector3d from(points[i].x(), points[i].y(), points[i].z());
            const double reach = box.max()[axis] - from[axis] + 1.0;
            if (reach <= 0) continue;
            const Eigen::Vector3d to = from + reach * d;
            column[std::size_t(axis)][i] = Eigen::AlignedBox3d(from.cwiseMin(to), from.cwiseMax(to));
            all[std::size_t(axis)].extend(*column[std::size_t(axis)][i]);
        }
    }
    // The triangles whose boxes meet each axis's box of columns, in one pass over the mesh: per
    // vertex the sides of the three boxes it lies beyond (sides_beyond's bits, 6 per axis).
    std::array<std::vector<std::size_t>, 3> near;
    {
        std::vector<std::uint32_t> beyond(rest.size(), 0);
        for (std::size_t v = 0; v < rest.size(); ++v) {
            std::uint32_t bits = 0;
            for (int axis = 0; axis < 3; ++axis) {
                const Eigen::AlignedBox3d& b = all[std::size_t(axis)];
                for (int k = 0; k < 3; ++k)
                    bits |= ((rest[v][k] < b.min()[k] ? 1u : 0u) << (2 * k) | (rest[v][k] > b.max()[k] ? 2u : 0u) << (2 * k)) << (6 * axis);
            }
            beyond[v] = bits;
        }
        for (std::size_t t = 0; t < triangles.size(); ++t) {
            const std::uint32_t shared =
                beyond[std::size_t(triangles[t][0])] & beyond[std::size_t(triangles[t][1])] & beyond[std::size_t(triangles[t][2])];
            for (int axis = 0; axis < 3; ++axis)
                if (!all[std::size_t(axis)].isEmpty() && !((shared >> (6 * axis)) & 63u)) near[std::size_t(axis)].push_back(t);
        }
    }
    std::vector<int> votes(points.size(), 0);
    for (int axis = 0; axis < 3; ++axis) {
        if (all[std::size_t(axis)].isEmpty()) continue;
        const Eigen::Vector3d& d = direction[std::size_t(axis)];
        for (std::size_t i = 0; i < points.size(); ++i) {
            const auto& col = column[std::size_t(axis)][i];
            if (!col) continue;
            const Kernel::Ray_3 ray(points[i], Kernel::Vector_3(d.x(), d.y(), d.z()));
            int crossings = 0;
            for (std::size_t t : near[std::size_t(axis)]) {
                if (apart(triangles[t], col->min(), col->max())) continue;
                const auto& tri = triangles[t];
                const Kernel::Triangle_3 face(point(rest[std::size_t(tri[0])]), point(rest[std::size_t(tri[1])]), point(rest[std::size_t(tri[2])]));
                if (!face.is_degenerate() && CGAL::do_intersect(ray, face)) ++crossings;
            }
            votes[i] += crossings % 2;
        }
    }
    std::vector<std::uint8_t> result(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) result[i] = votes[i] >= 2 ? 1 : 0;
    return result;
}

}  // namespace

IncisionMesh incision_mesh(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                           const std::vector<std::array<std::int32_t, 3>>& triangles) {
    IncisionMesh mesh;
    mesh.rest.reserve(positions.size());
    for (const auto& p : positions) mesh.rest.emplace_back(p[0], p[1], p[2]);
    mesh.normals.assign(positions.size(), Eigen::Vector3f::Zero());
    if (normals.size() == positions.size())
        for (std::size_t v = 0; v < normals.size(); ++v) mesh.normals[v] = {normals[v][0], normals[v][1], normals[v][2]};
    mesh.triangles = triangles;
    mesh.cap.assign(triangles.size(), 0);
    return mesh;
}

namespace {

/// The strip as a surface mesh, its degenerate triangles left out (a blade that barely moved);
/// false with `failure` set where corefinement cannot take it, false with `failure` empty where no
/// triangle is left.
bool strip_mesh(const CutSurface& strip, Mesh& swept, std::string& failure) {
    std::vector<VertexIndex> strip_vertex;
    for (const auto& p : strip.points) strip_vertex.push_back(swept.add_vertex(point(p)));
    for (const auto& t : strip.triangles) {
        const Point a = point(strip.points[std::size_t(t[0])]), b = point(strip.points[std::size_t(t[1])]), c = point(strip.points[std::size_t(t[2])]);
        if (CGAL::collinear(a, b, c)) continue;
        if (swept.add_face(strip_vertex[std::size_t(t[0])], strip_vertex[std::size_t(t[1])], strip_vertex[std::size_t(t[2])]) == Mesh::null_face()) {
            failure = "the swept surface folds onto itself";
            return false;
        }
    }
    if (swept.number_of_faces() == 0) return false;
    // A blade whose path crosses its own swept surface (a loop, a sawing stroke the thinning did
    // not split): corefinement needs surfaces that do not cross themselves.
    if (pmp::does_self_intersect(swept)) {
        failure = "the swept surface crosses itself (a looping or sawing stroke)";
        return false;
    }
    for (VertexIndex v : swept.vertices())
        if (swept.is_isolated(v)) swept.remove_vertex(v);
    swept.collect_garbage();
    return true;
}

/// The mesh's faces near the strip, as corefinement takes them: each vertex knows the mesh's
/// vertex it is, each face its cap flag.
struct Patch {
    Mesh mesh;
    Mesh::Property_map<VertexIndex, std::int32_t> original;
    Mesh::Property_map<FaceIndex, std::uint8_t> cap;
    std::vector<std::uint8_t> taken;  ///< per triangle of the mesh: in the patch
};

/// The patch: the mesh's faces whose boxes meet `box` (every face the strip crosses, and so every
/// face sharing an edge it crosses), in the mesh's order. A face's box misses `box` where all its
/// corners lie beyond the same side of it. False with `failure` set where a face cannot be taken.
bool take_patch(const IncisionMesh& mesh, const CGAL::Bbox_3& box, Patch& patch, std::string& failure) {
    patch.original = patch.mesh.add_property_map<VertexIndex, std::int32_t>("v:original", -1).first;
    patch.cap = patch.mesh.add_property_map<FaceIndex, std::uint8_t>("f:cap", 0).first;
    patch.taken.assign(mesh.triangles.size(), 0);
    const std::vector<std::uint8_t> beyond =
        sides_beyond(mesh.rest, Eigen::Vector3d(box.xmin(), box.ymin(), box.zmin()), Eigen::Vector3d(box.xmax(), box.ymax(), box.zmax()));
    std::unordered_map<std::int32_t, VertexIndex> patch_vertex;
    auto vertex_of = [&](std::int32_t id) {
        auto [it, added] = patch_vertex.try_emplace(id);
        if (added) {
            it->second = patch.mesh.add_vertex(point(mesh.rest[std::size_t(id)]));
            patch.original[it->second] = id;
        }
        return it->second;
    };
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const auto& tri = mesh.triangles[t];
        if (beyond[std::size_t(tri[0])] & beyond[std::size_t(tri[1])] & beyond[std::size_t(tri[2])]) continue;
        patch.taken[t] = 1;
        FaceIndex f = patch.mesh.add_face(vertex_of(tri[0]), vertex_of(tri[1]), vertex_of(tri[2]));
        if (f == Mesh::null_face()) {  // a pinch within the patch: this face on vertices of its own
            std::array<VertexIndex, 3> own;
            for (int k = 0; k < 3; ++k) {
                own[std::size_t(k)] = patch.mesh.add_vertex(point(mesh.rest[std::size_t(tri[std::size_t(k)])]));
                patch.original[own[std::size_t(k)]] = tri[std::size_t(k)];
            }
            f = patch.mesh.add_face(own[0], own[1], own[2]);
            if (f == Mesh::null_face()) {
                failure = "the detailed mesh has a degenerate face where the blade passed";
                return false;
            }
        }
        patch.cap[f] = mesh.cap[t];
    }
    return true;
}

/// Whether two of the patch's faces around one vertex lie in one plane and one of them has a
/// corner inside the other: a triangle folded onto its neighbour (an earlier slit may move a
/// vertex a little across a mesh edge close beside the cut). Corefinement cannot take such a
/// surface (it crosses itself).
bool folded(const Mesh& patch) {
    auto strictly_inside = [](const Point& p, const Point& a, const Point& b, const Point& c) {
        return CGAL::coplanar_orientation(a, b, c, p) == CGAL::POSITIVE && CGAL::coplanar_orientation(b, c, a, p) == CGAL::POSITIVE &&
               CGAL::coplanar_orientation(c, a, b, p) == CGAL::POSITIVE;
    };
    // Faces whose normals (in double) are not parallel within a millionth of a radian do not lie in
    // one plane: only the others take the exact tests.
    std::vector<Eigen::Vector3d> normal(patch.num_faces());
    for (FaceIndex f : patch.faces()) {
        const auto h = patch.halfedge(f);
        const Eigen::Vector3d a = vector(patch.point(patch.source(h))), b = vector(patch.point(patch.target(h))),
                              c = vector(patch.point(patch.target(patch.next(h))));
        normal[f] = (b - a).cross(c - a);
    }
    std::vector<FaceIndex> around;
    for (VertexIndex v : patch.vertices()) {
        around.clear();
        for (FaceIndex f : CGAL::faces_around_target(patch.halfedge(v), patch))
            if (f != Mesh::null_face()) around.push_back(f);
        for (std::size_t i = 0; i < around.size(); ++i)
            for (std::size_t j = i + 1; j < around.size(); ++j) {
                const Eigen::Vector3d& m = normal[around[i]];
                const Eigen::Vector3d& n = normal[around[j]];
                if (m.cross(n).squaredNorm() > 1e-12 * m.squaredNorm() * n.squaredNorm()) continue;
                std::array<Point, 3> a, b;
                int k = 0;
                for (VertexIndex w : CGAL::vertices_around_face(patch.halfedge(around[i]), patch)) a[std::size_t(k++)] = patch.point(w);
                k = 0;
                for (VertexIndex w : CGAL::vertices_around_face(patch.halfedge(around[j]), patch)) b[std::size_t(k++)] = patch.point(w);
                if (CGAL::orientation(a[0], a[1], a[2], b[0]) != CGAL::COPLANAR || CGAL::orientation(a[0], a[1], a[2], b[1]) != CGAL::COPLANAR ||
                    CGAL::orientation(a[0], a[1], a[2], b[2]) != CGAL::COPLANAR || CGAL::collinear(a[0], a[1], a[2]) || CGAL::collinear(b[0], b[1], b[2]))
                    continue;
                for (const Point& p : b)
                    if (strictly_inside(p, a[0], a[1], a[2])) return true;
                for (const Point& p : a)
                    if (strictly_inside(p, b[0], b[1], b[2])) return true;
            }
    }
    return false;
}

/// The mesh being opened: its arrays with the patch's faces refined (after the faces away from
/// the cut, as they were), the cut's edges, and each vertex on the cut split into its fans.
struct Opening {
    std::vector<Eigen::Vector3d> rest;
    std::vector<std::array<std::int32_t, 3>> triangles;
    std::vector<std::uint8_t> cap;
    std::set<std::pair<std::int32_t, std::int32_t>> cut_edges;
    /// Per vertex on the cut: its copies (the first the vertex itself) and the faces of each one's fan.
    std::map<std::int32_t, std::vector<std::pair<std::int32_t, std::vector<std::size_t>>>> copies;
};

/// The mesh's arrays with the corefined patch in place of the faces it took; the first patch face
/// goes to `result.triangles_from`.
void refine(const IncisionMesh& mesh, const Patch& patch, const Mesh::Property_map<Mesh::Edge_index, bool>& constrained, Opening& out,
            IncisionResult& result) {
    out.rest = mesh.rest;
    std::vector<std::int32_t> global(patch.mesh.num_vertices(), -1);
    for (VertexIndex v : patch.mesh.vertices()) {
        if (patch.original[v] >= 0) {
            global[v] = patch.original[v];
        } else {
            global[v] = std::int32_t(out.rest.size());
            out.rest.push_back(vector(patch.mesh.point(v)));
        }
    }
    out.triangles.reserve(mesh.triangles.size() + 4 * patch.mesh.number_of_faces());
    out.cap.reserve(out.triangles.capacity());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        if (!patch.taken[t]) {
            out.triangles.push_back(mesh.triangles[t]);
            out.cap.push_back(mesh.cap[t]);
        }
    result.triangles_from = out.triangles.size();
    for (FaceIndex f : patch.mesh.faces()) {
        std::array<std::int32_t, 3> tri{};
        int k = 0;
        for (VertexIndex v : CGAL::vertices_around_face(patch.mesh.halfedge(f), patch.mesh)) tri[std::size_t(k++)] = global[v];
        out.triangles.push_back(tri);
        out.cap.push_back(patch.cap[f]);
    }
    for (auto e : patch.mesh.edges())
        if (constrained[e]) {
            const std::int32_t a = global[patch.mesh.vertex(e, 0)], b = global[patch.mesh.vertex(e, 1)];
            out.cut_edges.insert({std::min(a, b), std::max(a, b)});
        }
}

/// A cut edge from one point of the strip's border to another that is not itself on the border:
/// where the blade's edge grazes the surface, the curve crosses the strip in one edge. Neither end
/// is parted (each is the crack's front), so the mesh's faces on its two sides would keep the edge
/// while both caps reach it: four faces on one edge. Each such edge is split at its middle, in the
/// strip and in the mesh's faces (from `triangles_from`) alike: the middle is a point of the curve
/// inside the strip, which split_into_fans then parts, one copy per side.
void split_cut_chords(Mesh& swept, Mesh::Property_map<Mesh::Edge_index, bool>& constrained, Opening& out, std::size_t triangles_from) {
    std::vector<Mesh::Edge_index> chords;
    for (auto e : swept.edges())
        if (constrained[e] && !swept.is_border(e) && swept.is_border(swept.vertex(e, 0)) && swept.is_border(swept.vertex(e, 1)))
            chords.push_back(e);
    if (chords.empty()) return;
    std::map<PointKey, std::int32_t> on_cut;  // the cut edges' ends, by their exact coordinates
    for (const auto& [a, b] : out.cut_edges) {
        on_cut[key(point(out.rest[std::size_t(a)]))] = a;
        on_cut[key(point(out.rest[std::size_t(b)]))] = b;
    }
    for (auto e : chords) {
        const auto h = swept.halfedge(e);
        const auto ia = on_cut.find(key(swept.point(swept.source(h)))), ib = on_cut.find(key(swept.point(swept.target(h))));
        if (ia == on_cut.end() || ib == on_cut.end()) continue;
        const std::int32_t a = ia->second, b = ib->second;
        const Point middle = CGAL::midpoint(swept.point(swept.source(h)), swept.point(swept.target(h)));
        // The strip: both halves stay on the curve, the two faces each split through the middle.
        const auto split = CGAL::Euler::split_edge(h, swept);
        swept.point(swept.target(split)) = middle;
        constrained[swept.edge(split)] = true;
        constrained[swept.edge(h)] = true;
        if (!swept.is_border(split)) CGAL::Euler::split_face(split, swept.next(swept.next(split)), swept);
        const auto across = swept.opposite(split);
        if (!swept.is_border(across)) CGAL::Euler::split_face(swept.prev(across), swept.next(across), swept);
        // The mesh: the middle a vertex of its own, each face on the edge in two through it.
        const std::int32_t m = std::int32_t(out.rest.size());
        out.rest.push_back(vector(middle));
        const std::size_t faces = out.triangles.size();
        for (std::size_t t = triangles_from; t < faces; ++t)
            for (std::size_t k = 0; k < 3; ++k) {
                const std::int32_t x = out.triangles[t][k], y = out.triangles[t][(k + 1) % 3], z = out.triangles[t][(k + 2) % 3];
                if (!((x == a && y == b) || (x == b && y == a))) continue;
                out.triangles[t] = {x, m, z};
                out.triangles.push_back({m, y, z});
                out.cap.push_back(out.cap[t]);
                break;
            }
        out.cut_edges.erase({std::min(a, b), std::max(a, b)});
        out.cut_edges.insert({std::min(a, m), std::max(a, m)});
        out.cut_edges.insert({std::min(m, b), std::max(m, b)});
    }
}

/// Splits each vertex on the cut into its fans: the faces around it joined across edges that are
/// not cut. The first fan keeps the vertex; each other fan gets a copy.
void split_into_fans(Opening& out, std::size_t triangles_from) {
    std::map<std::int32_t, std::vector<std::size_t>> around;
    for (const auto& [a, b] : out.cut_edges) {
        around.try_emplace(a);
        around.try_emplace(b);
    }
    // A vertex on a cut edge lies on the strip, so every face around it meets the strip's box: the
    // patch's faces are all of them.
    for (std::size_t t = triangles_from; t < out.triangles.size(); ++t)
        for (std::int32_t v : out.triangles[t])
            if (auto it = around.find(v); it != around.end()) it->second.push_back(t);
    for (auto& [v, faces] : around) {
        std::vector<int> fan(faces.size(), -1);
        int fans = 0;
        for (std::size_t seed = 0; seed < faces.size(); ++seed) {
            if (fan[seed] >= 0) continue;
            fan[seed] = fans;
            std::vector<std::size_t> stack{seed};
            while (!stack.empty()) {
                const std::size_t i = stack.back();
                stack.pop_back();
                for (std::size_t j = 0; j < faces.size(); ++j) {
                    if (fan[j] >= 0) continue;
                    // faces i and j share an edge (v, w) that is not cut
                    for (std::int32_t w : out.triangles[faces[i]]) {
                        if (w == v) continue;
                        const auto& tj = out.triangles[faces[j]];
                        if (std::find(tj.begin(), tj.end(), w) == tj.end()) continue;
                        if (out.cut_edges.count({std::min(v, w), std::max(v, w)})) continue;
                        fan[j] = fans;
                        stack.push_back(j);
                        break;
                    }
                }
            }
            ++fans;
        }
        auto& list = out.copies[v];
        for (int k = 0; k < fans; ++k) {
            std::int32_t id = v;
            if (k > 0) {
                id = std::int32_t(out.rest.size());
                out.rest.push_back(out.rest[std::size_t(v)]);
            }
            std::vector<std::size_t> members;
            for (std::size_t i = 0; i < faces.size(); ++i)
                if (fan[i] == k) {
                    members.push_back(faces[i]);
                    for (auto& corner : out.triangles[faces[i]])
                        if (corner == v) corner = id;
                }
            list.push_back({id, std::move(members)});
        }
    }
}

/// Both caps share the strip's border (the crack's front); an edge through the strip's inside
/// between two border vertices would then be shared by both caps twice over. Such an edge is split
/// at its middle (and its two faces with it): the middle is the strip's inside, one copy per side.
void split_chords(Mesh& swept, const Mesh::Property_map<Mesh::Edge_index, bool>& constrained) {
    std::vector<Mesh::Edge_index> chords;
    for (auto e : swept.edges())
        if (!swept.is_border(e) && !constrained[e] && swept.is_border(swept.vertex(e, 0)) && swept.is_border(swept.vertex(e, 1)))
            chords.push_back(e);
    for (auto e : chords) {
        const auto h = swept.halfedge(e);
        const Point middle = CGAL::midpoint(swept.point(swept.source(h)), swept.point(swept.target(h)));
        const auto split = CGAL::Euler::split_edge(h, swept);  // split → the new vertex
        swept.point(swept.target(split)) = middle;
        // Each of the two faces, now four-sided, in two triangles through the new vertex.
        CGAL::Euler::split_face(split, swept.next(swept.next(split)), swept);
        const auto across = swept.opposite(split);
        CGAL::Euler::split_face(swept.prev(across), swept.next(across), swept);
    }
}

/// Whether each of the strip's faces lies inside the tissue: the strip in regions between the cut
/// curves, each region inside where the centroid of its first face is (inside).
std::vector<std::uint8_t> faces_inside(const Mesh& swept, const Mesh::Property_map<Mesh::Edge_index, bool>& constrained, const IncisionMesh& mesh) {
    Eigen::AlignedBox3d mesh_box;
    for (const auto& x : mesh.rest) mesh_box.extend(x);
    std::vector<int> region(swept.num_faces(), -1);
    int regions = 0;
    std::vector<Point> centres;  // per region: the centroid of its first face, tested for inside the tissue
    for (FaceIndex seed : swept.faces()) {
        if (region[seed] >= 0) continue;
        region[seed] = regions;
        std::vector<FaceIndex> stack{seed};
        while (!stack.empty()) {
            const FaceIndex f = stack.back();
            stack.pop_back();
            for (auto h : CGAL::halfedges_around_face(swept.halfedge(f), swept)) {
                if (constrained[swept.edge(h)]) continue;
                const FaceIndex g = swept.face(swept.opposite(h));
                if (g == Mesh::null_face() || region[g] >= 0) continue;
                region[g] = regions;
                stack.push_back(g);
            }
        }
        const auto h = swept.halfedge(seed);
        centres.push_back(CGAL::centroid(swept.point(swept.source(h)), swept.point(swept.target(h)), swept.point(swept.target(swept.next(h)))));
        ++regions;
    }
    const std::vector<std::uint8_t> region_inside = inside(centres, mesh.rest, mesh.triangles, mesh_box);
    std::vector<std::uint8_t> face_inside(swept.num_faces(), 0);
    for (FaceIndex f : swept.faces()) face_inside[f] = region_inside[std::size_t(region[f])];
    return face_inside;
}

/// The caps of one opening, and the copies of the vertices on their rims that move apart.
struct Caps {
    std::vector<std::array<std::int32_t, 3>> faces;
    std::map<std::int32_t, Eigen::Vector3d> slit_normal;  ///< vertex → summed normals of its cap faces
    std::map<std::int32_t, int> slit_side;
};

/// The caps: the strip's faces inside the tissue, side + (the strip's normal side) with the faces
/// reversed, side − as they are, each on the copies of its own side; the strip's faces they came
/// from go to `result.cut_faces`.
Caps make_caps(const Mesh& swept, const std::vector<std::uint8_t>& face_inside, Opening& out, IncisionResult& result) {
    Caps caps;
    std::map<PointKey, std::int32_t> on_curve;  // points of the cut curves → their vertex (before the split)
    for (const auto& [v, list] : out.copies) on_curve[key(point(out.rest[std::size_t(v)]))] = v;
    std::map<std::pair<std::size_t, int>, std::int32_t> strip_copy;  // (strip vertex, side) → vertex
    auto cap_vertex = [&](VertexIndex s, int side, const Eigen::Vector3d& normal) -> std::int32_t {
        const Point& p = swept.point(s);
        if (auto it = on_curve.find(key(p)); it != on_curve.end()) {
            const auto& list = out.copies[it->second];
            if (list.size() == 1) return list.front().first;  // the crack's front: shared
            // the copy whose fan lies on `side` of the cap face
            double best = 0.0;
            std::int32_t chosen = list.front().first;
            for (const auto& [id, fan] : list) {
                double lean = 0.0;
                for (std::size_t t : fan)
                    for (std::int32_t w : out.triangles[t]) lean += (out.rest[std::size_t(w)] - vector(p)).dot(normal);
                if (side * lean > best) {
                    best = side * lean;
                    chosen = id;
                }
            }
            caps.slit_normal.try_emplace(chosen, Eigen::Vector3d::Zero()).first->second += normal;
            caps.slit_side[chosen] = side;
            return chosen;
        }
        const bool front = swept.is_border(s);
        auto [it, added] = strip_copy.try_emplace({std::size_t(s), front ? 0 : side});
        if (added) {
            it->second = std::int32_t(out.rest.size());
            out.rest.push_back(vector(p));
        }
        if (!front) {
            caps.slit_normal.try_emplace(it->second, Eigen::Vector3d::Zero()).first->second += normal;
            caps.slit_side[it->second] = side;
        }
        return it->second;
    };
    for (FaceIndex f : swept.faces()) {
        if (!face_inside[f]) continue;
        std::array<VertexIndex, 3> s{};
        int k = 0;
        for (VertexIndex v : CGAL::vertices_around_face(swept.halfedge(f), swept)) s[std::size_t(k++)] = v;
        const Eigen::Vector3d a = vector(swept.point(s[0])), b = vector(swept.point(s[1])), c = vector(swept.point(s[2]));
        const Eigen::Vector3d normal = (b - a).cross(c - a).normalized();
        if (!normal.allFinite()) continue;
        const std::array<std::int32_t, 3> plus{cap_vertex(s[0], +1, normal), cap_vertex(s[2], +1, normal), cap_vertex(s[1], +1, normal)};
        const std::array<std::int32_t, 3> minus{cap_vertex(s[0], -1, normal), cap_vertex(s[1], -1, normal), cap_vertex(s[2], -1, normal)};
        caps.faces.push_back(plus);
        caps.faces.push_back(minus);
        result.cut_faces.push_back({a, b, c});
    }
    return caps;
}

/// The slit at rest (each side's copies `gap`/2 into their own side), the normals of the added
/// vertices, and the caps appended to the faces.
void part_and_shade(const IncisionMesh& mesh, const Caps& caps, double gap_mm, Opening& out, std::vector<Eigen::Vector3f>& normals,
                    IncisionResult& result) {
    for (const auto& [id, normal] : caps.slit_normal) {
        const Eigen::Vector3d n = normal.normalized();
        if (!n.allFinite()) continue;
        out.rest[std::size_t(id)] += 0.5 * gap_mm * caps.slit_side.at(id) * n;
        if (std::size_t(id) < result.vertices_from) result.moved.push_back(id);
    }
    // Normals: an added vertex on the surface takes its faces' area-weighted normal; a vertex of
    // the caps only, none (the caps are shaded flat).
    normals = mesh.normals;
    normals.resize(out.rest.size(), Eigen::Vector3f::Zero());
    std::vector<Eigen::Vector3d> summed(out.rest.size() - result.vertices_from, Eigen::Vector3d::Zero());
    for (std::size_t f = result.triangles_from; f < out.triangles.size(); ++f) {  // an added vertex lies on the patch's faces only
        const auto& t = out.triangles[f];
        const Eigen::Vector3d n =
            (out.rest[std::size_t(t[1])] - out.rest[std::size_t(t[0])]).cross(out.rest[std::size_t(t[2])] - out.rest[std::size_t(t[0])]);
        for (std::int32_t v : t)
            if (std::size_t(v) >= result.vertices_from) summed[std::size_t(v) - result.vertices_from] += n;
    }
    for (std::size_t k = 0; k < summed.size(); ++k)
        if (summed[k].squaredNorm() > 0) normals[result.vertices_from + k] = summed[k].normalized().cast<float>();
    for (const auto& c : caps.faces) {
        out.triangles.push_back(c);
        out.cap.push_back(1);
    }
    result.cap_triangles = caps.faces.size();
}

}  // namespace

IncisionResult open_along(IncisionMesh& mesh, const CutSurface& strip, double gap_mm) {
    IncisionResult result;
    result.vertices_from = mesh.rest.size();
    Mesh swept;
    if (!strip_mesh(strip, swept, result.failure)) return result;
    Patch patch;
    if (!take_patch(mesh, pmp::bbox(swept), patch, result.failure)) return result;
    result.patch_triangles = patch.mesh.number_of_faces();
    if (patch.mesh.number_of_faces() == 0) return result;

    if (folded(patch.mesh)) {
        result.failure = "the detailed mesh folds onto itself where the blade passed (an earlier slit moved a vertex across a mesh edge beside it)";
        return result;
    }
    auto patch_constrained = patch.mesh.add_property_map<Mesh::Edge_index, bool>("e:constrained", false).first;
    auto strip_constrained = swept.add_property_map<Mesh::Edge_index, bool>("e:constrained", false).first;
    FaceIndex splitting = Mesh::null_face();
    CapVisitor visitor;
    visitor.patch = &patch.mesh;
    visitor.cap = &patch.cap;
    visitor.splitting = &splitting;
    try {
        pmp::corefine(patch.mesh, swept, CGAL::parameters::edge_is_constrained_map(patch_constrained).visitor(visitor),
                      CGAL::parameters::edge_is_constrained_map(strip_constrained));
    } catch (const std::exception& e) {
        result.failure = std::string("the cut could not be traced through the detailed mesh (") + e.what() + ")";
        return result;
    }
    for (auto e : patch.mesh.edges()) result.crossings += patch_constrained[e] ? 1 : 0;
    if (result.crossings == 0) return result;  // the blade stayed outside (or wholly inside) the surface

    Opening out;
    refine(mesh, patch, patch_constrained, out, result);
    split_cut_chords(swept, strip_constrained, out, result.triangles_from);
    split_into_fans(out, result.triangles_from);
    split_chords(swept, strip_constrained);
    const Caps caps = make_caps(swept, faces_inside(swept, strip_constrained, mesh), out, result);
    if (caps.faces.empty()) {
        result.failure = "the cut meets the surface but no part of the swept surface lies inside the tissue";
        return result;
    }
    std::vector<Eigen::Vector3f> normals;
    part_and_shade(mesh, caps, gap_mm, out, normals, result);
    // Where the geometry defeated the split, the mesh stays as it was.
    if (!closed_manifold(out.triangles, nullptr, result.triangles_from)) {
        IncisionResult failed;
        failed.vertices_from = result.vertices_from;
        failed.patch_triangles = result.patch_triangles;
        failed.failure = "the split along the cut did not close up (the swept surface meets the mesh too intricately there)";
        return failed;
    }
    mesh.rest = std::move(out.rest);
    mesh.normals = std::move(normals);
    mesh.triangles = std::move(out.triangles);
    mesh.cap = std::move(out.cap);
    result.opened = true;
    return result;
}

namespace {

std::string edge_count_message(std::int32_t a, std::int32_t b, int forward, int reverse) {
    return "edge (" + std::to_string(a) + ", " + std::to_string(b) + ") occurs " + std::to_string(forward) + " time(s), its reverse " +
           std::to_string(reverse);
}

/// closed_manifold's check of the faces from `from` on: their directed edges and the reverses in
/// an open-addressing table, each counted over all the faces whose two ends are both corners of
/// the checked faces (a pass over the faces with no sorting: the patch and caps are a small part
/// of the mesh).
bool faces_close_up(const std::vector<std::array<std::int32_t, 3>>& triangles, std::string* why, std::size_t from) {
    std::vector<std::uint8_t> touched;
    for (std::size_t t = from; t < triangles.size(); ++t)
        for (std::int32_t v : triangles[t]) {
            if (v < 0) continue;
            if (std::size_t(v) >= touched.size()) touched.resize(std::size_t(v) + 1, 0);
            touched[std::size_t(v)] = 1;
        }
    auto code = [](std::int32_t a, std::int32_t b) { return std::uint64_t(std::uint32_t(a)) << 32 | std::uint32_t(b); };
    constexpr std::uint64_t empty = ~std::uint64_t(0);  // (−1, −1): no edge of ours (negative corners are left out)
    int bits = 4;
    while ((std::size_t(1) << bits) < 2 * 6 * (triangles.size() - from)) ++bits;
    const std::size_t mask = (std::size_t(1) << bits) - 1;
    std::vector<std::uint64_t> keys(mask + 1, empty);
    std::vector<std::uint32_t> counts(mask + 1, 0);
    auto slot = [&](std::uint64_t key) {
        std::size_t s = std::size_t((key * 0x9E3779B97F4A7C15ull) >> (64 - bits));
        while (keys[s] != key && keys[s] != empty) s = (s + 1) & mask;
        return s;
    };
    for (std::size_t t = from; t < triangles.size(); ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            const std::int32_t a = triangles[t][k], b = triangles[t][(k + 1) % 3];
            if (a < 0 || b < 0) continue;
            keys[slot(code(a, b))] = code(a, b);
            keys[slot(code(b, a))] = code(b, a);
        }
    auto ours = [&](std::int32_t v) { return v >= 0 && std::size_t(v) < touched.size() && touched[std::size_t(v)]; };
    for (const auto& t : triangles) {
        if (!ours(t[0]) && !ours(t[1])) continue;  // no edge with both ends ours
        for (std::size_t k = 0; k < 3; ++k) {
            const std::int32_t a = t[k], b = t[(k + 1) % 3];
            if (!ours(a) || !ours(b)) continue;
            const std::size_t s = slot(code(a, b));
            if (keys[s] != empty) ++counts[s];
        }
    }
    auto count = [&](std::int32_t a, std::int32_t b) { return a < 0 || b < 0 ? 0 : int(counts[slot(code(a, b))]); };
    // The first offending edge is the lowest (a, b).
    bool closed = true;
    std::pair<std::int32_t, std::int32_t> worst;
    for (std::size_t t = from; t < triangles.size(); ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            const std::int32_t a = triangles[t][k], b = triangles[t][(k + 1) % 3];
            if (count(a, b) == 1 && count(b, a) == 1) continue;
            if (!why) return false;
            if (closed || std::make_pair(a, b) < worst) worst = {a, b};
            closed = false;
        }
    if (!closed) *why = edge_count_message(worst.first, worst.second, count(worst.first, worst.second), count(worst.second, worst.first));
    return closed;
}

}  // namespace

bool closed_manifold(const std::vector<std::array<std::int32_t, 3>>& triangles, std::string* why, std::size_t from) {
    if (from > 0) return faces_close_up(triangles, why, from);
    using Edge = std::pair<std::int32_t, std::int32_t>;
    std::vector<Edge> directed;
    for (const auto& t : triangles)
        for (int k = 0; k < 3; ++k) directed.push_back({t[std::size_t(k)], t[std::size_t((k + 1) % 3)]});
    std::sort(directed.begin(), directed.end());
    auto count = [&](const Edge& e) {
        const auto [first, last] = std::equal_range(directed.begin(), directed.end(), e);
        return int(last - first);
    };
    // The edges in order: the first offending one is the lowest (a, b).
    for (std::size_t n = 0; n < directed.size(); ++n) {
        const Edge& edge = directed[n];
        if (n > 0 && directed[n - 1] == edge) continue;
        const int forward = count(edge), reverse = count({edge.second, edge.first});
        if (forward != 1 || reverse != 1) {
            if (why) *why = edge_count_message(edge.first, edge.second, forward, reverse);
            return false;
        }
    }
    return true;
}

double enclosed_volume(const std::vector<Eigen::Vector3d>& positions, const std::vector<std::array<std::int32_t, 3>>& triangles) {
    double six = 0.0;
    for (const auto& t : triangles)
        six += positions[std::size_t(t[0])].dot(positions[std::size_t(t[1])].cross(positions[std::size_t(t[2])]));
    return six / 6.0;
}

}  // namespace heartsim
