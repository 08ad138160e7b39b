/// @file incision.h
/// @brief Opening the detailed mesh along a scalpel's cut, in the rest shape: the mesh is split
/// along the surface the blade swept and each side's cut face is closed by a cap, so the mesh
/// stays a closed, consistently oriented 2-manifold (docs/architecture.md "Incision").
///
///     IncisionMesh mesh = incision_mesh(v.positions, v.normals, v.triangles);                   // the uncut detailed mesh
///     const CutSurface strip = stroke_surface(stroke, positions, rest, spacing);   // rest space
///     const IncisionResult result = open_along(mesh, strip, 0.01);
///     // result.vertices_from: the first vertex it added; mesh.cap marks the caps
///
/// The swept surface is a strip of triangles (the blade at each kept pose, consecutive poses
/// joined by two triangles). CGAL's corefinement (exact predicates) inserts the curves where it
/// meets the mesh into both; the mesh's vertices on those curves are duplicated, one copy per side,
/// except where a curve ends on the strip's border (the crack's front: the blade's end inside the
/// tissue), where both sides meet. The strip's faces inside the tissue become two caps, one per
/// side, oriented outward from their side; the copies move `gap` mm apart along the strip's normal
/// (the slit at rest), the crack front stays put.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

/// The detailed mesh as the runtime cuts it: rest positions in double (the exact geometry the cuts
/// are made in), triangles with a cap flag.
struct IncisionMesh {
    std::vector<Eigen::Vector3d> rest;                 ///< V, world mm at rest
    std::vector<std::array<std::int32_t, 3>> triangles;
    std::vector<std::uint8_t> cap;                     ///< per triangle: 1 for a cut face
    std::vector<Eigen::Vector3f> normals;              ///< V: rest normals (0 for cap-only vertices)
};

/// The surface a stroke swept, mapped into rest space: points and triangles (consistently
/// oriented; its normal, right-handed from the corner order, defines the cut's + side).
struct CutSurface {
    std::vector<Eigen::Vector3d> points;
    std::vector<std::array<std::int32_t, 3>> triangles;
};

struct IncisionResult {
    bool opened = false;              ///< the mesh changed
    std::size_t vertices_from = 0;    ///< the first vertex added (the vertices before it keep their rows)
    /// The first triangle the opening made (the ones before it are the mesh's untouched, in their
    /// order; an added vertex lies only on the ones from here on).
    std::size_t triangles_from = 0;
    std::size_t crossings = 0;        ///< edges of the curves where the strip meets the mesh
    std::size_t cap_triangles = 0;    ///< cap triangles added (both sides)
    std::size_t patch_triangles = 0;  ///< the mesh's triangles taken into the corefinement (re-meshed where the strip crosses them)
    std::vector<std::int32_t> moved;  ///< existing vertices that became a copy on one side (moved by gap)
    /// The strip's triangles inside the tissue where the blade passed (before the sides move
    /// apart): the surface no vertex may be carried across.
    std::vector<std::array<Eigen::Vector3d, 3>> cut_faces;
    std::string failure;              ///< why the mesh was left as it was (empty: opened or nothing to open)
};

/// The detailed mesh from its rest positions, normals (V or empty) and triangles, none a cap.
IncisionMesh incision_mesh(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                           const std::vector<std::array<std::int32_t, 3>>& triangles);

/// Splits `mesh` along `strip` and caps both sides (above). Leaves `mesh` as it was and says why in
/// `failure` when the geometry defeats it (CGAL refused); never throws for geometry.
IncisionResult open_along(IncisionMesh& mesh, const CutSurface& strip, double gap_mm);

/// True when every directed edge (a, b) of `triangles` occurs exactly once and (b, a) exactly once:
/// a closed, consistently oriented 2-manifold (vertex pinches aside). `why` says the first
/// offending edge (the lowest (a, b)). With `from` > 0 only the edges of triangles[from, end) are
/// checked, each against all of `triangles`: whether the faces added from `from` on close up with
/// each other and with the faces around them (open_along's check of its patch and caps).
bool closed_manifold(const std::vector<std::array<std::int32_t, 3>>& triangles, std::string* why = nullptr, std::size_t from = 0);

/// The volume a closed, outward-oriented mesh encloses (divergence theorem), mm³.
double enclosed_volume(const std::vector<Eigen::Vector3d>& positions, const std::vector<std::array<std::int32_t, 3>>& triangles);

}  // namespace heartsim
