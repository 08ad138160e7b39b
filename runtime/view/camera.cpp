#include "runtime/view/camera.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <vector>

namespace heartsim {
namespace {

/// Camera basis (right, up, back) for each named view, world LPS.
Eigen::Matrix3f view_basis(ViewDirection view) {
    Eigen::Vector3f back = {0, -1, 0}, up = {0, 0, 1};  // set again below; initialised for the compiler
    switch (view) {
        case ViewDirection::anterior: back = {0, -1, 0}, up = {0, 0, 1}; break;
        case ViewDirection::posterior: back = {0, 1, 0}, up = {0, 0, 1}; break;
        case ViewDirection::left: back = {1, 0, 0}, up = {0, 0, 1}; break;
        case ViewDirection::right: back = {-1, 0, 0}, up = {0, 0, 1}; break;
        case ViewDirection::superior: back = {0, 0, 1}, up = {0, -1, 0}; break;
        case ViewDirection::inferior: back = {0, 0, -1}, up = {0, -1, 0}; break;
        case ViewDirection::surgeon:
            // The eye above the chest (anterior, -y) and out over the patient's right (-x); up
            // is away from the surgeon, across the table to the patient's left (+x).
            back = Eigen::Vector3f(-0.42f, -1.0f, 0.0f).normalized();
            up = Eigen::Vector3f(1.0f, -0.42f, 0.0f).normalized();
            break;
    }
    Eigen::Matrix3f basis;
    basis.col(0) = up.cross(back);
    basis.col(1) = up;
    basis.col(2) = back;
    return basis;
}

}  // namespace

ViewDirection parse_view_direction(const std::string& name) {
    if (name == "anterior") return ViewDirection::anterior;
    if (name == "posterior") return ViewDirection::posterior;
    if (name == "left") return ViewDirection::left;
    if (name == "right") return ViewDirection::right;
    if (name == "superior") return ViewDirection::superior;
    if (name == "inferior") return ViewDirection::inferior;
    if (name == "surgeon") return ViewDirection::surgeon;
    throw InputError("{ViewDirection} '" + name + "': expected anterior, posterior, left, right, superior, inferior or surgeon");
}

const char* to_string(ViewDirection view) {
    switch (view) {
        case ViewDirection::anterior: return "anterior";
        case ViewDirection::posterior: return "posterior";
        case ViewDirection::left: return "left";
        case ViewDirection::right: return "right";
        case ViewDirection::superior: return "superior";
        case ViewDirection::inferior: return "inferior";
        case ViewDirection::surgeon: return "surgeon";
    }
    return "anterior";
}

Eigen::Vector3f Camera::eye() const { return target + orientation * Eigen::Vector3f(0, 0, distance); }

Eigen::Matrix4f Camera::view() const {
    const Eigen::Matrix3f r = orientation.toRotationMatrix().transpose();
    Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
    m.topLeftCorner<3, 3>() = r;
    m.topRightCorner<3, 1>() = -(r * eye());
    return m;
}

Eigen::Matrix4f Camera::projection(float aspect) const {
    const float f = 1.0f / std::tan(0.5f * fov_y_degrees * float(M_PI) / 180.0f);
    const float near_plane = std::max(distance - 2.0f * radius, 0.01f * radius), far_plane = distance + 2.0f * radius;
    Eigen::Matrix4f m = Eigen::Matrix4f::Zero();
    m(0, 0) = f / aspect;
    m(1, 1) = f;
    m(2, 2) = (far_plane + near_plane) / (near_plane - far_plane);
    m(2, 3) = 2.0f * far_plane * near_plane / (near_plane - far_plane);
    m(3, 2) = -1.0f;
    return m;
}

void Camera::orbit(float yaw, float pitch) {
    const Eigen::Vector3f right = orientation * Eigen::Vector3f::UnitX();
    orientation = Eigen::AngleAxisf(yaw, turntable_axis.normalized()) * Eigen::AngleAxisf(pitch, right) * orientation;
    orientation.normalize();
}

double Camera::mm_per_pixel(int height) const {
    return 2.0 * double(distance) * std::tan(double(fov_y_degrees) * M_PI / 360.0) / double(std::max(height, 1));
}

double Camera::distance_to_span(double span_mm, double fraction) const {
    return span_mm / (fraction * 2.0 * std::tan(double(fov_y_degrees) * M_PI / 360.0));
}

void Camera::pan(float dx, float dy, int height) {
    const float size = float(mm_per_pixel(height));
    target += orientation * Eigen::Vector3f(-dx * size, dy * size, 0.0f);
}

void Camera::zoom(float factor) { distance = std::clamp(distance * factor, 0.05f * radius, 20.0f * radius); }

Camera fit_camera(const Eigen::AlignedBox3f& box, ViewDirection view, float aspect) {
    Camera camera;
    camera.target = box.center();
    camera.radius = std::max(0.5f * box.diagonal().norm(), 1e-3f);
    const Eigen::Matrix3f basis = view_basis(view);
    camera.orientation = Eigen::Quaternionf(basis);
    camera.turntable_axis = basis.col(1);
    // The nearest distance at which every corner of the box lies inside the frustum, plus 5 %.
    const float tan_y = std::tan(0.5f * camera.fov_y_degrees * float(M_PI) / 180.0f), tan_x = tan_y * aspect;
    float distance = 0.0f;
    for (int corner = 0; corner < 8; ++corner) {
        const Eigen::Vector3f c = basis.transpose() * (box.corner(Eigen::AlignedBox3f::CornerType(corner)) - camera.target);
        distance = std::max({distance, c.z() + std::abs(c.x()) / tan_x, c.z() + std::abs(c.y()) / tan_y});
    }
    camera.distance = 1.05f * distance;
    return camera;
}

LookAt parse_look_at(const std::string& text) {
    const std::string expected = "{LookAt} '" + text + "': expected X,Y,Z or X,Y,Z,DISTANCE: the point to centre the view on and the "
                                 "camera's distance from it (mm, world LPS; DISTANCE above 0)";
    std::vector<double> values;
    std::size_t start = 0;
    while (true) {
        const std::size_t comma = text.find(',', start);
        const std::string word = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
        char* end = nullptr;
        const double value = std::strtod(word.c_str(), &end);
        if (word.empty() || end == word.c_str() || *end != '\0' || !std::isfinite(value)) throw OptionError(expected);
        values.push_back(value);
        if (comma == std::string::npos) break;
        start = comma + 1;
    }
    if (values.size() != 3 && values.size() != 4) throw OptionError(expected);
    // The point as --clip's and a trajectory's (a float keeps them to the µm); the distance as far.
    for (int a = 0; a < 3; ++a)
        if (!plausible::coordinate_mm.contains(values[std::size_t(a)]))
            throw OptionError("{LookAt} '" + text + "': " + plausible::outside(std::string(1, "XYZ"[a]), values[std::size_t(a)], plausible::coordinate_mm));
    if (values.size() == 4 && values[3] > plausible::coordinate_mm.high)
        throw OptionError("{LookAt} '" + text + "': " + plausible::outside("DISTANCE", values[3], {0.0, plausible::coordinate_mm.high, "mm"}));
    LookAt look;
    look.point = Eigen::Vector3f(float(values[0]), float(values[1]), float(values[2]));
    if (values.size() == 4) {
        if (!(values[3] > 0.0)) throw OptionError(expected);
        look.distance = float(values[3]);
    }
    return look;
}

void parse_eye(const std::string& text, LookAt& look) {
    LookAt eye;
    try {
        eye = parse_look_at(text);
    } catch (const OptionError&) {
        throw OptionError("{LookAt::eye} '" + text + "': expected X,Y,Z: where the camera stands (mm, world LPS, each within a million mm), looking at the --look-at point");
    }
    if (eye.distance) throw OptionError("{LookAt::eye} '" + text + "': expected X,Y,Z (three numbers): the camera's distance is the eye's from the --look-at point");
    if ((eye.point - look.point).norm() < 1e-3f) throw OptionError("{LookAt::eye} '" + text + "': the eye is on the --look-at point: it must look at it from somewhere");
    look.eye = eye.point;
}

void aim_camera_at(Camera& camera, const LookAt& look) {
    camera.target = look.point;
    if (look.distance) camera.distance = *look.distance;
    if (!look.eye) return;
    const Eigen::Vector3f back = (*look.eye - look.point).normalized();
    const Eigen::Vector3f view_up = camera.orientation * Eigen::Vector3f::UnitY(), view_right = camera.orientation * Eigen::Vector3f::UnitX();
    Eigen::Vector3f up = view_up - view_up.dot(back) * back;
    if (up.norm() < 0.2f) up = back.cross(view_right);  // looking along the view's up: its right keeps the picture's sides
    up.normalize();
    Eigen::Matrix3f basis;
    basis.col(0) = up.cross(back);
    basis.col(1) = up;
    basis.col(2) = back;
    camera.orientation = Eigen::Quaternionf(basis).normalized();
    camera.turntable_axis = up;
    camera.distance = (*look.eye - look.point).norm();
}

bool operator==(const LookAt& a, const LookAt& b) {
    return a.point == b.point && a.distance == b.distance && a.eye.has_value() == b.eye.has_value() && (!a.eye || *a.eye == *b.eye);
}

bool operator==(const PlannedView& a, const PlannedView& b) { return a.direction == b.direction && a.look == b.look; }

namespace {

/// `value` in the fewest significant digits (up to 9, which always do) that read back as the same
/// float, without an exponent where the digits allow (30, not 3e+01).
std::string float_text(float value) {
    char text[32];
    for (int digits = 1; digits <= 9; ++digits) {
        std::snprintf(text, sizeof text, "%.*g", digits, double(value));
        if (std::strtof(text, nullptr) == value && (digits == 9 || !std::strchr(text, 'e'))) break;
    }
    return text;
}

std::string point_text(const Eigen::Vector3f& p) { return float_text(p.x()) + "," + float_text(p.y()) + "," + float_text(p.z()); }

}  // namespace

std::string view_options(const PlannedView& view) {
    // Appended piece by piece (GCC 12 warns, wrongly, of overlapping copies in "literal" + string).
    std::string text = "--view ";
    text += to_string(view.direction);
    if (!view.look) return text;
    if (view.look->eye) text.append(" --eye ").append(point_text(*view.look->eye));
    text.append(" --look-at ").append(point_text(view.look->point));
    if (view.look->distance) text.append(",").append(float_text(*view.look->distance));
    return text;
}

PlannedView parse_view_options(const std::string& text) {
    const std::string expected = "'" + text + "': expected --view NAME, then optionally --look-at X,Y,Z[,DISTANCE] and --eye X,Y,Z";
    std::istringstream in(text);
    std::optional<std::string> view, look_at, eye;
    std::string option;
    while (in >> option) {
        std::optional<std::string>* value = option == "--view" ? &view : option == "--look-at" ? &look_at : option == "--eye" ? &eye : nullptr;
        if (!value) throw OptionError(expected + " ('" + option + "' is none of these)");
        if (value->has_value()) throw OptionError(expected + " (" + option + " given twice)");
        std::string word;
        if (!(in >> word)) throw OptionError(expected + " (" + option + " without its value)");
        *value = word;
    }
    if (!view) throw OptionError(expected + " (no --view)");
    if (*view == "section") throw OptionError("{ViewDirection} 'section': a planned view is a named one (section needs --clip)");
    PlannedView planned;
    try {
        planned.direction = parse_view_direction(*view);
    } catch (const InputError& e) {
        throw OptionError(e.what());
    }
    if (eye && !look_at) throw OptionError(expected + " (--eye looks at the --look-at point: give it)");
    if (look_at) planned.look = parse_look_at(*look_at);
    if (eye) parse_eye(*eye, *planned.look);
    return planned;
}

}  // namespace heartsim
