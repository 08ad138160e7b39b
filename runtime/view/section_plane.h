/// @file section_plane.h
/// @brief The section view (docs/runtime.md "Section view"): a plane that cuts the drawn heart
/// open so that a trainer sees inside it (a septal defect, a valve). What lies on the side the
/// plane's normal points to is not drawn; the renderer shades the cut wall (renderer.h). No GL:
/// `--clip` and the window's keys make and move the plane, the renderer draws with it.
///
///     SectionPlane plane = section_facing(renderer.camera(), renderer.model_centre());
///     renderer.set_section(plane.moved(-5.0f));   // 5 mm deeper: more of the heart removed
#pragma once

#include "runtime/view/camera.h"

#include <Eigen/Core>

#include <optional>
#include <string>

namespace heartsim {

/// A plane in the world frame (LPS, mm) and the half-space it removes.
struct SectionPlane {
    Eigen::Vector3f point = Eigen::Vector3f::Zero();   ///< a point of the plane, world LPS mm
    Eigen::Vector3f normal = Eigen::Vector3f::UnitZ(); ///< unit; the half-space it points into is not drawn

    /// Signed distance of `x` from the plane, mm: > 0 on the removed side.
    float distance(const Eigen::Vector3f& x) const { return normal.dot(x - point); }
    /// The same plane moved by `mm` along its normal (< 0: deeper, more removed).
    SectionPlane moved(float mm) const { return {point + mm * normal, normal}; }
    /// How far the plane lies beyond `centre`, mm, measured against the normal: 0 through it,
    /// > 0 when more than the half on the normal's side is removed.
    float depth_from(const Eigen::Vector3f& centre) const { return distance(centre); }
};

/// The plane through `centre` perpendicular to `camera`'s view direction, its normal towards the
/// eye: it removes the half of the model nearer to the camera.
SectionPlane section_facing(const Camera& camera, const Eigen::Vector3f& centre);

/// "the plane D mm beyond the heart's centre (through (x, y, z) mm, normal (nx, ny, nz), LPS)":
/// where `plane` lies, for the terminal (D: depth_from(centre)).
std::string describe(const SectionPlane& plane, const Eigen::Vector3f& centre);

/// What `--clip` asked for: a plane given by point and normal, or one through the model's centre
/// facing the camera (made once the camera is fitted).
struct SectionRequest {
    bool facing_view = false;  ///< "centre": section_facing(fitted camera, model centre)
    /// "defect": through the scenario's septal defect (its /source defect_centre), the plane
    /// holding the defect's axis and facing the camera as nearly as that allows
    /// (section_through_defect); the camera then looks at the defect across the plane.
    bool through_defect = false;
    bool aim_camera = false;   ///< --view section: the camera looks straight at the plane (aim_at_section)
    SectionPlane plane;        ///< otherwise: the plane given, its normal made unit
};

/// The plane through `centre` that holds `axis` (a septal defect's centre and axis) and faces the
/// camera as nearly as that allows: its normal is the camera's direction to the eye made
/// perpendicular to the axis (or, when the camera looks along the axis, any perpendicular).
/// Cutting there shows the wall across the opening: the defect as a gap in the septum's band.
SectionPlane section_through_defect(const Camera& camera, const Eigen::Vector3f& centre, const Eigen::Vector3f& axis);

/// Turns `camera` to look at `plane.point` straight against `plane.normal` (from the removed
/// side), keeping its distance and as much of its up direction as it can.
void aim_at_section(Camera& camera, const SectionPlane& plane);

/// How `--clip defect` frames the defect: the default patch of `heartsim plan-repair` (the
/// defect's diameter D plus 2 · (2 mm rim + 2 mm): D + 8 mm, runtime/surgery/repair_plan.h) across two
/// thirds of the picture's height, so a 10 mm opening spans 37 % of it.
constexpr double defect_frame_margin_mm = 8.0;
constexpr double defect_frame_fraction = 2.0 / 3.0;

/// The camera distance (mm) at which `span_mm` (a patch's diameter, or D + defect_frame_margin_mm)
/// spans defect_frame_fraction of the picture's height through `camera`'s field of view.
double defect_view_distance(const Camera& camera, double span_mm);

/// Reads `--clip`'s value: "PX,PY,PZ,NX,NY,NZ" (a point and a normal, world LPS mm; the side the
/// normal points to is removed), "centre" ("center" too) or "defect". Throws OptionError naming {SectionRequest} when
/// it is neither, a number is not finite, a coordinate is beyond 10^6 mm, or the normal is zero.
SectionRequest parse_section_option(const std::string& text);

}  // namespace heartsim
