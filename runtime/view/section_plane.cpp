// The section view's plane: section_plane.h; docs/runtime.md "Section view".
#include "runtime/view/section_plane.h"

#include "libmodel/errors.h"
#include "formats/csv.h"
#include "libmodel/plausible.h"

#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

namespace heartsim {

SectionPlane section_facing(const Camera& camera, const Eigen::Vector3f& centre) {
    return {centre, (camera.orientation * Eigen::Vector3f::UnitZ()).normalized()};  // camera +z points back, to the eye
}

std::string describe(const SectionPlane& plane, const Eigen::Vector3f& centre) {
    double depth = plane.depth_from(centre);
    if (std::abs(depth) < 0.005) depth = 0.0;  // through the centre: "0.00", not "-0.00"
    char text[256];
    std::snprintf(text, sizeof text, "the plane %.2f mm beyond the heart's centre (through (%.2f, %.2f, %.2f) mm, normal (%.4f, %.4f, %.4f), LPS)",
                  depth, plane.point.x(), plane.point.y(), plane.point.z(), plane.normal.x(), plane.normal.y(),
                  plane.normal.z());
    return text;
}

SectionPlane section_through_defect(const Camera& camera, const Eigen::Vector3f& centre, const Eigen::Vector3f& axis) {
    const Eigen::Vector3f a = axis.normalized();
    const Eigen::Vector3f to_eye = camera.orientation * Eigen::Vector3f::UnitZ();
    Eigen::Vector3f n = to_eye - to_eye.dot(a) * a;
    if (n.norm() < 1e-3f) n = a.unitOrthogonal();
    return {centre, n.normalized()};
}

void aim_at_section(Camera& camera, const SectionPlane& plane) {
    const Eigen::Vector3f back = plane.normal.normalized();  // camera z (back) points to the eye, on the removed side
    Eigen::Vector3f up = camera.orientation * Eigen::Vector3f::UnitY();
    up -= up.dot(back) * back;
    if (up.norm() < 1e-3f) up = back.unitOrthogonal();
    up.normalize();
    Eigen::Matrix3f r;
    r.col(0) = up.cross(back);
    r.col(1) = up;
    r.col(2) = back;
    camera.orientation = Eigen::Quaternionf(r).normalized();
    camera.target = plane.point;
}

double defect_view_distance(const Camera& camera, double span_mm) {
    return camera.distance_to_span(span_mm, defect_frame_fraction);
}

SectionRequest parse_section_option(const std::string& text) {
    if (text == "centre" || text == "center") return {.facing_view = true, .plane = {}};
    if (text == "defect") return {.through_defect = true, .plane = {}};
    const std::string expected = "{SectionRequest} '" + text +
                                 "': expected PX,PY,PZ,NX,NY,NZ (a point of the plane and its normal, mm, world LPS; the side the "
                                 "normal points to is not drawn), centre (through the heart's centre, facing the camera) or defect (across the "
                                 "scenario's septal defect)";
    const std::vector<std::string> fields = csv_fields(text);
    if (fields.size() != 6) throw OptionError(expected);
    double v[6];
    for (std::size_t k = 0; k < 6; ++k) {
        std::size_t used = 0;
        bool overflow = false;
        try {
            v[k] = std::stod(fields[k], &used);
        } catch (const std::out_of_range&) {
            overflow = true;  // beyond a double: as infinite
        } catch (const std::exception&) {
            used = 0;
        }
        if (!overflow && (used == 0 || used != fields[k].size())) throw OptionError(expected);
        if (overflow || !std::isfinite(v[k])) throw OptionError("{SectionRequest} '" + text + "': '" + fields[k] + "' is not a finite number");
    }
    // The point as a trajectory's positions (plausible::coordinate_mm: a float keeps them to the µm).
    for (int a = 0; a < 3; ++a)
        if (!plausible::coordinate_mm.contains(v[a]))
            throw OptionError("{SectionRequest} '" + text + "': " + plausible::outside(std::string("P") + "XYZ"[a], v[a], plausible::coordinate_mm));
    // The normal's length does not matter, only its direction: scaled by its largest component
    // first, so no size of finite numbers overflows on the way to unit length.
    const Eigen::Vector3d given(v[3], v[4], v[5]);
    const double largest = given.cwiseAbs().maxCoeff();
    if (largest == 0.0)
        throw OptionError("{SectionRequest} '" + text + "': the normal (" + fields[3] + ", " + fields[4] + ", " + fields[5] +
                         ") is zero; give the direction of the side to remove, e.g. 0,-1,0 for the anterior half");
    const Eigen::Vector3d normal = (given / largest).normalized();
    return {.facing_view = false,
            .plane = {Eigen::Vector3d(v[0], v[1], v[2]).cast<float>(), normal.cast<float>()}};
}

}  // namespace heartsim
