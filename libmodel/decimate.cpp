/// @file decimate.cpp
/// @brief Edge-collapse decimation with Garland–Heckbert quadrics (CGAL Surface_mesh_simplification).
/// The only translation unit of the surface stage that includes CGAL: it compiles slowly.
// The Garland–Heckbert policies solve small systems with Eigen, which CGAL enables by this flag.
#define CGAL_EIGEN3_ENABLED

#include "libmodel/errors.h"
#include "libmodel/surface.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Bounded_normal_change_placement.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Count_ratio_stop_predicate.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/GarlandHeckbert_plane_policies.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>

#include <string>

namespace heartsim {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using CgalMesh = CGAL::Surface_mesh<Kernel::Point_3>;
namespace simplification = CGAL::Surface_mesh_simplification;

/// Stops at the edge-count ratio (for a closed triangle mesh E = 3F/2, so it is the face-count
/// ratio too), or as soon as the caller cancels; reports progress on the way.
class StopAtRatioOrCancel {
public:
    StopAtRatioOrCancel(double ratio, Progress& progress, ProgressStage& stage, bool& cancelled)
        : ratio_(ratio), progress_(progress), stage_(stage), cancelled_(cancelled) {}

    template <typename Cost, typename Profile, typename Size>
    bool operator()(const Cost& cost, const Profile& profile, Size initial_edges, Size current_edges) const {
        if (((initial_edges - current_edges) & 1023) == 0) {
            stage_.update(std::uint64_t(initial_edges - current_edges));
            if (progress_.cancelled()) {
                cancelled_ = true;
                return true;
            }
        }
        return simplification::Count_ratio_stop_predicate<CgalMesh>(ratio_)(cost, profile, initial_edges, current_edges);
    }

private:
    double ratio_;
    Progress& progress_;
    ProgressStage& stage_;
    bool& cancelled_;
};

}  // namespace

void decimate(TriangleMesh& mesh, double fraction, Progress& progress) {
    if (!(fraction >= 0.0 && fraction < 1.0))
        throw InputError("decimation: fraction must lie in [0, 1), got " + std::to_string(fraction));
    if (fraction == 0.0 || mesh.triangles.empty()) return;
    const MeshReport check = analyse_mesh(mesh);
    if (!check.closed() || !check.manifold() || check.unused_vertices != 0)
        throw InputError("decimation needs a closed 2-manifold mesh without unused vertices; this one has " +
                         std::to_string(check.boundary_edges) + " boundary edges, " +
                         std::to_string(check.nonmanifold_edges) + " non-manifold edges, " +
                         std::to_string(check.nonmanifold_vertices) + " non-manifold vertices, " +
                         std::to_string(check.misoriented_edges) + " misoriented edges, " +
                         std::to_string(check.unused_vertices) + " unused vertices");

    CgalMesh cgal_mesh;
    cgal_mesh.reserve(CgalMesh::size_type(mesh.positions.size()), CgalMesh::size_type(3 * mesh.triangles.size() / 2),
                      CgalMesh::size_type(mesh.triangles.size()));
    for (const auto& p : mesh.positions) cgal_mesh.add_vertex(Kernel::Point_3(p.x(), p.y(), p.z()));
    for (const auto& t : mesh.triangles) {
        const auto face = cgal_mesh.add_face(CgalMesh::Vertex_index(CgalMesh::size_type(t[0])),
                                             CgalMesh::Vertex_index(CgalMesh::size_type(t[1])),
                                             CgalMesh::Vertex_index(CgalMesh::size_type(t[2])));
        if (face == CgalMesh::null_face()) throw InputError("decimation: the mesh is not a 2-manifold (CGAL refused a face)");
    }

    ProgressStage stage(progress, "decimation", std::uint64_t(cgal_mesh.number_of_edges() * fraction));
    bool cancelled = false;
    using Quadrics = simplification::GarlandHeckbert_plane_policies<CgalMesh, Kernel>;
    Quadrics quadrics(cgal_mesh);
    // Rejects collapses that would flip a triangle, which the quadric placement alone allows.
    simplification::Bounded_normal_change_placement<Quadrics::Get_placement> placement(quadrics.get_placement());
    simplification::edge_collapse(cgal_mesh, StopAtRatioOrCancel(1.0 - fraction, progress, stage, cancelled),
                                  CGAL::parameters::get_cost(quadrics.get_cost()).get_placement(placement));
    if (cancelled) throw Cancelled();

    cgal_mesh.collect_garbage();
    TriangleMesh decimated;
    decimated.positions.reserve(cgal_mesh.number_of_vertices());
    for (auto v : cgal_mesh.vertices()) {
        const auto& p = cgal_mesh.point(v);
        decimated.positions.emplace_back(p.x(), p.y(), p.z());
    }
    decimated.triangles.reserve(cgal_mesh.number_of_faces());
    for (auto f : cgal_mesh.faces()) {
        std::array<std::int32_t, 3> triangle;
        int corner = 0;
        for (auto v : CGAL::vertices_around_face(cgal_mesh.halfedge(f), cgal_mesh)) triangle[std::size_t(corner++)] = std::int32_t(v.idx());
        decimated.triangles.push_back(triangle);
    }
    if (!mesh.normals.empty()) compute_vertex_normals(decimated);
    mesh = std::move(decimated);
}

}  // namespace heartsim
