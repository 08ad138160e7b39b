/// @file camera.h
/// @brief The camera the window, the screenshots and the haptic devices' view frame share: named
/// views and an orbiting perspective camera (mm, world frame LPS). No GL: the renderer draws with
/// it, a haptic run maps a device's axes through it.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <optional>
#include <string>

namespace heartsim {

/// The default views, named by where the camera stands (world frame LPS: +x left, +y posterior,
/// +z superior). anterior (the default): the camera in front of the patient looking posterior,
/// superior up, the patient's left on the image's right (as facing the patient). surgeon: as the
/// surgeon stands at an open chest, the patient supine and the surgeon on the patient's right:
/// looking down on the heart's front from 23 degrees to the patient's right, the patient's left
/// (the far side of the table) up, the head on the image's left.
enum class ViewDirection { anterior, posterior, left, right, superior, inferior, surgeon };
/// "anterior", "posterior", "left", "right", "superior", "inferior" or "surgeon"; throws InputError
/// otherwise.
ViewDirection parse_view_direction(const std::string& name);
/// The name parse_view_direction reads: "anterior", …, "surgeon".
const char* to_string(ViewDirection view);

/// An orbiting perspective camera (mm, world frame).
struct Camera {
    Eigen::Vector3f target = Eigen::Vector3f::Zero();            ///< orbit centre
    float distance = 100.0f;                                     ///< eye to target
    Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();  ///< camera → world (x right, y up, z back)
    Eigen::Vector3f turntable_axis = Eigen::Vector3f::UnitZ();  ///< horizontal drags turn about this world axis
    float fov_y_degrees = 30.0f;
    float radius = 50.0f;                                        ///< the model's bounding-sphere radius (near/far, zoom limits)

    Eigen::Vector3f eye() const;
    Eigen::Matrix4f view() const;
    Eigen::Matrix4f projection(float aspect) const;
    /// Turns about the turntable axis by `yaw` and about the camera's right axis by `pitch` (radians).
    void orbit(float yaw, float pitch);
    /// Moves the target in the view plane by a drag of (dx, dy) pixels in a viewport `height` pixels high.
    void pan(float dx, float dy, int height);
    /// The size of one pixel at the target's depth, mm, in a viewport `height` pixels high.
    double mm_per_pixel(int height) const;
    /// The distance (mm) at which a span of `span_mm` at the target, across the view, covers
    /// `fraction` (0–1] of the picture's height: span / (fraction · 2 tan(fov_y / 2)).
    double distance_to_span(double span_mm, double fraction) const;
    /// Multiplies the distance by `factor` (clamped to 0.05–20 model radii).
    void zoom(float factor);
};

/// The camera that shows the whole box from `view`: the nearest distance at which all eight
/// corners lie inside the frustum at `aspect` (width / height), plus 5 %.
Camera fit_camera(const Eigen::AlignedBox3f& box, ViewDirection view, float aspect);

/// `heartsim run --look-at X,Y,Z[,DISTANCE]`: a point to centre the view on (mm, world LPS) and,
/// optionally, the camera's distance from it (mm).
struct LookAt {
    Eigen::Vector3f point = Eigen::Vector3f::Zero();
    std::optional<float> distance;
    /// `heartsim run --eye X,Y,Z`: where the camera stands (mm, world LPS), looking at the point;
    /// its distance is then the eye's from the point.
    std::optional<Eigen::Vector3f> eye;
};
/// Parses "X,Y,Z" or "X,Y,Z,DISTANCE": finite numbers, DISTANCE > 0. OptionError naming {LookAt}
/// (heartsim's --look-at) otherwise.
LookAt parse_look_at(const std::string& text);
/// Parses `--eye` "X,Y,Z" (mm, world LPS) into look.eye: finite coordinates within reach, not on
/// the point itself. OptionError naming {LookAt::eye} (heartsim's --eye) otherwise.
void parse_eye(const std::string& text, LookAt& look);
/// Centres `camera` on the point, looking from where it looks (its orientation, the --view's,
/// kept), from the distance given or its own. With an eye: the camera stands there looking at the
/// point, the --view's up turned as little as it takes to lie across the line of sight (so the
/// surgeon's view keeps the patient's left up). The near plane follows the distance (projection).
void aim_camera_at(Camera& camera, const LookAt& look);

/// The view a plan shows its trajectory from (heartsim plan-operation's surgeon's eye,
/// plan-incision's camera on the incision): `heartsim run --trajectory` starts from it when given
/// none of --view, --eye and --look-at (docs/runtime.md "Planning an operation"). The options that
/// say it, as heartsim run takes them: a named view and, optionally, a point looked at and an eye.
struct PlannedView {
    ViewDirection direction = ViewDirection::anterior;  ///< --view
    std::optional<LookAt> look;                         ///< --look-at, and --eye in look->eye
};
bool operator==(const LookAt& a, const LookAt& b);
bool operator==(const PlannedView& a, const PlannedView& b);
/// The view as heartsim run's options: "--view surgeon --eye X,Y,Z --look-at X,Y,Z[,DISTANCE]"
/// (the --eye and --look-at only where given; each number in the fewest digits that read back to
/// the same float, so parse_view_options(view_options(v)) == v).
std::string view_options(const PlannedView& view);
/// Reads view_options' text: "--view NAME", then in any order "--look-at X,Y,Z[,DISTANCE]" and
/// "--eye X,Y,Z" (the eye only with a point), separated by spaces; each value checked as the
/// command line's option is (parse_view_direction, parse_look_at, parse_eye; "section" is refused:
/// it needs --clip). OptionError naming the option, or saying what was expected, otherwise.
PlannedView parse_view_options(const std::string& text);

}  // namespace heartsim
