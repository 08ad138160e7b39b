#include "libmodel/surgery/conduction_zone.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <tuple>

namespace heartsim {
namespace {

/// `v` made perpendicular to the unit `axis`.
Eigen::Vector3d across(const Eigen::Vector3d& v, const Eigen::Vector3d& axis) { return v - v.dot(axis) * axis; }

std::string mm_text(double value) {
    char text[32];
    std::snprintf(text, sizeof text, "%.1f", value);
    return text;
}

/// The nearest point of `ring` to the circle of radius `radius` round the line through `centre`
/// along the unit `axis`, in the plane through the centre across it, and its distance: with h the
/// point's height along the axis and r its distance from it, √(h² + (r − radius)²).
std::pair<double, Eigen::Vector3d> nearest_to_rim(const Landmark& ring, const Eigen::Vector3d& centre, const Eigen::Vector3d& axis,
                                                  double radius) {
    double best = std::numeric_limits<double>::infinity();
    Eigen::Vector3d at = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3d& q : ring.points) {
        const Eigen::Vector3d v = q - centre;
        const double h = v.dot(axis), r = across(v, axis).norm();
        const double d = std::hypot(h, r - radius);
        if (d < best) best = d, at = q;
    }
    return {best, at};
}

/// Why `name` is not among `landmarks`' rings: its missing entry's reason, or that none was stored.
std::string why_missing(const Landmarks& landmarks, const std::string& name) {
    for (const MissingLandmark& m : landmarks.missing)
        if (m.name == name) return m.reason;
    const Landmark* found = landmarks.find(name);
    if (found && found->points.empty()) return "it has no points";
    return "the scenario's /landmarks does not hold it";
}

}  // namespace

double ConductionZone::angle_from_middle_deg(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d d = across(p - centre, axis);
    const double r = d.norm();
    if (!(r > 0) || direction.isZero()) return 0.0;
    return std::acos(std::clamp(d.dot(direction) / r, -1.0, 1.0)) * 180.0 / std::numbers::pi;
}

bool ConductionZone::in_arc(const Eigen::Vector3d& p) const { return found && angle_from_middle_deg(p) <= half_width_deg; }

bool ConductionZone::holds(const Eigen::Vector3d& p) const {
    if (!found) return false;
    const double r = across(p - centre, axis).norm();
    return r > 0 && r <= outer_mm && in_arc(p);
}

ConductionZone conduction_zone(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis_in, double diameter_mm, const Landmarks& landmarks,
                               const ConductionZoneOptions& options) {
    ConductionZone zone;
    const Eigen::Vector3d axis = axis_in.normalized();
    zone.centre = centre;
    zone.axis = axis;
    zone.half_width_deg = options.half_width_deg;
    zone.edge_mm = 0.5 * diameter_mm;
    zone.outer_mm = zone.edge_mm + options.band_mm;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    zone.tricuspid_mm = zone.aortic_mm = nan;

    const Landmark* tricuspid = landmarks.find("tricuspid_ring");
    const Landmark* aortic = landmarks.find("aortic_ring");
    if (tricuspid && tricuspid->points.empty()) tricuspid = nullptr;
    if (aortic && aortic->points.empty()) aortic = nullptr;
    if (tricuspid) std::tie(zone.tricuspid_mm, zone.tricuspid_point) = nearest_to_rim(*tricuspid, centre, axis, zone.edge_mm);
    if (aortic) std::tie(zone.aortic_mm, zone.aortic_point) = nearest_to_rim(*aortic, centre, axis, zone.edge_mm);
    if (!tricuspid || !aortic) {
        std::string reason;
        if (!tricuspid) reason = "no tricuspid ring (" + why_missing(landmarks, "tricuspid_ring") + ")";
        if (!aortic) reason += (reason.empty() ? "" : " and ") + std::string("no aortic ring (") + why_missing(landmarks, "aortic_ring") + ")";
        zone.reason = reason + ": whether the defect is perimembranous cannot be told, and no conduction zone is marked";
        return zone;
    }
    const std::string distances = "its rim comes " + mm_text(zone.tricuspid_mm) + " mm from the tricuspid ring and " +
                                  mm_text(zone.aortic_mm) + " mm from the aortic ring";
    if (!(zone.tricuspid_mm <= options.ring_reach_mm && zone.aortic_mm <= options.ring_reach_mm)) {
        zone.reason = "not perimembranous: " + distances + ", not within " + mm_text(options.ring_reach_mm) +
                      " mm of both (a muscular defect: no conduction axis along its rim)";
        return zone;
    }
    // Toward the tricuspid ring's septal part, away from the aortic root, biased posteroinferior;
    // each a unit direction across the axis (one that lies along the axis adds nothing).
    auto unit_across = [&](const Eigen::Vector3d& v) {
        const Eigen::Vector3d d = across(v, axis);
        return d.norm() > 1e-9 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d::Zero();
    };
    const Eigen::Vector3d middle = unit_across(zone.tricuspid_point - centre) - unit_across(zone.aortic_point - centre) +
                                   unit_across(Eigen::Vector3d(0.0, 1.0, -1.0).normalized());
    if (middle.norm() < 1e-9) {
        zone.reason = "perimembranous (" + distances + "), but the directions to the rings and the posteroinferior one cancel "
                      "across the axis: no arc can be told";
        return zone;
    }
    zone.direction = middle.normalized();
    zone.found = true;
    zone.reason = "perimembranous: " + distances + " (both within " + mm_text(options.ring_reach_mm) +
                  " mm); the conduction axis runs along its posteroinferior rim, toward the tricuspid ring's septal part and "
                  "away from the aortic root";
    return zone;
}

std::vector<int> points_in_zone(const ConductionZone& zone, const std::vector<Eigen::Vector3d>& points) {
    std::vector<int> in;
    for (std::size_t k = 0; k < points.size(); ++k)
        if (zone.holds(points[k])) in.push_back(int(k));
    return in;
}

}  // namespace heartsim
