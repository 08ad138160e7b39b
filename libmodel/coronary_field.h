/// @file coronary_field.h
/// @brief The coronary arteries as the renderer draws them on the detailed surface: a field on a
/// regular grid in the rest state, giving at every node the distance to the nearest coronary
/// course in units of that artery's radius and the unit direction away from it. The fragment
/// shader samples it at each fragment's rest position (runtime/gl/shaders/render_shaders.h): the
/// artery is raised (a half-cylinder's height profile) inside a ridge of epicardial fat, both as
/// a normal perturbation in the tangent frame that the deformation carries, so the detail follows
/// every deformation without more geometry (the seed's normal-mapping technique).
#pragma once

#include "libmodel/landmarks.h"

#include <Eigen/Core>
#include <string>
#include <vector>

namespace heartsim {

/// One artery's course on the detailed surface (world LPS mm, in order) and its radius (mm).
struct CoronaryCourse {
    std::string name;
    std::vector<Eigen::Vector3d> points;
    double radius_mm = 1.8;
};

/// The arteries the landmarks give (lad_course, rca_course, lcx_course), with the mean proximal
/// lumen radii of normal adult coronary arteries: anterior descending 1.85 mm, right coronary
/// 1.95 mm, circumflex 1.7 mm (Dodge et al., Circulation 86:232, 1992: proximal diameters 3.7,
/// 3.9 and 3.4 mm). Each course is smoothed along its length (its points lie on surface vertices
/// and zigzag by their spacing; its ends stay). Courses with fewer than two points are left out.
std::vector<CoronaryCourse> coronary_courses(const Landmarks& landmarks);

/// The field: nodes at origin + spacing·(i, j, k), x fastest. `reach` is the largest normalised
/// distance stored: a node farther than reach radii from every course holds reach and a zero
/// direction, as does everything outside the grid.
struct CoronaryField {
    Eigen::Vector3d origin{0, 0, 0};
    double spacing_mm = 1.0;
    int nx = 0, ny = 0, nz = 0;
    double reach = 3.0;
    /// Per node: distance to the nearest course point divided by that course's radius, clamped
    /// to reach; and the unit vector from that point to the node (zero on a course or beyond
    /// reach). size nx·ny·nz each.
    std::vector<float> distance;
    std::vector<Eigen::Vector3f> away;
    bool empty() const { return distance.empty(); }
    std::size_t index(int i, int j, int k) const {
        return (static_cast<std::size_t>(k) * static_cast<std::size_t>(ny) + static_cast<std::size_t>(j)) *
                   static_cast<std::size_t>(nx) +
               static_cast<std::size_t>(i);
    }
};

/// The field of `courses` on a grid of `spacing_mm` covering every course point widened by reach
/// radii of the widest artery and one node more. Empty when there is no course. The grid is at
/// most `max_nodes` nodes: the spacing grows until it fits. Throws InputError for a non-finite
/// point, a radius or spacing not positive, or reach below 1.
CoronaryField coronary_field(const std::vector<CoronaryCourse>& courses, double spacing_mm = 0.75,
                             double reach = 3.0, std::size_t max_nodes = 4u << 20);

}  // namespace heartsim
