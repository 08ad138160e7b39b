/// @file incision_gesture.h
/// @brief The scripted incision of the cutting tests and the cutting benchmark: on a scenario's
/// most anterior point, a scalpel with its blade pointing posterior (+y, LPS) is lowered and drawn
/// `length_mm` from inferior to superior (−z to +z) at 0.1 mm/ms; lifted, it becomes a retractor
/// (hand 0) beside a second one (hand 1): they grab the two edges of the incision, one each side
/// of the blade's plane x = x_c, and pull them `spread_mm` apart along ±x, then hold. The gesture
/// itself is the runtime's (runtime/surgery/incision_plan.h, the ventriculotomy of `heartsim
/// plan-incision`); this header keeps the tests' names for it.
///
///     const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 30});
///     run_scripted(*backend, plan.trajectory, {.steps = int(plan.end_ms / dt)});
///     write_trajectory_csv(plan.trajectory, "incision.csv");   // for `heartsim run --trajectory`
#pragma once

#include "formats/scenario.h"
#include "libmodel/surgery/incision_state.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/core/trajectory.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace heartsim::test {

struct IncisionOptions {
    double length_mm = 30.0;     ///< along z, centred on the most anterior particle
    double depth_mm = 6.0;       ///< how far the blade reaches behind the most anterior point
    double clearance_mm = 2.0;   ///< the tip's distance in front of it
    double speed_mm_per_ms = 0.1;
    double spread_mm = 6.0;      ///< the retractors' final separation beyond their grip
    bool retract = true;         ///< false: the cut alone
};

struct Incision {
    Trajectory trajectory;
    /// The most anterior particle's rest position moved a quarter spacing along +x: a point of the
    /// blade's plane x = centre.x.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double depth_mm = 0.0;       ///< how far the blade reaches behind the most anterior particle (the plan's)
    double cut_end_ms = 0.0;     ///< the blade lifts here
    double end_ms = 0.0;         ///< the gesture's end (retractors held still from spread_end_ms)
    double spread_end_ms = 0.0;
};

/// The particle most anterior (smallest y) among those within `radius` of the line through
/// (x, ·, z) along y; −1 if none.
inline int most_anterior_near(const Scenario& scenario, double x, double z, double radius) {
    return frontmost_near(scenario, Eigen::Vector3d(x, 0.0, z), Eigen::Vector3d::UnitY(), radius);
}

/// The ventriculotomy of runtime/surgery/incision_plan.h. std::runtime_error (InputError) when the
/// scenario has no particles.
inline Incision anterior_incision(const Scenario& scenario, const IncisionOptions& o = {}) {
    const IncisionPlan p = plan_incision(scenario, {.approach = IncisionApproach::ventriculotomy,
                                                    .length_mm = o.length_mm,
                                                    .depth_mm = o.depth_mm,
                                                    .clearance_mm = o.clearance_mm,
                                                    .speed_mm_per_ms = o.speed_mm_per_ms,
                                                    .spread_mm = o.spread_mm,
                                                    .retract = o.retract});
    Incision plan;
    plan.trajectory = p.trajectory;
    plan.centre = p.centre;
    plan.depth_mm = p.depth_mm;
    plan.cut_end_ms = p.cut_end_ms;
    plan.end_ms = p.end_ms;
    plan.spread_end_ms = p.spread_end_ms;
    return plan;
}

/// How far an incision stands open: over `springs` (those a run cut) whose rest midpoint lies
/// within `radius_mm` of the incision's centre, the mean and the largest of (the distance between
/// their ends at `positions` − their rest length).
struct Opening {
    double mean_mm = 0, max_mm = 0;
    int springs = 0;
};
inline Opening incision_opening(const Scenario& scenario, const Incision& plan, const std::vector<std::array<std::int32_t, 2>>& springs,
                                const std::vector<std::array<float, 3>>& positions, double radius_mm = 5.0) {
    const auto& rest = scenario.lattice.particles.rest_position;
    auto point = [](const std::array<float, 3>& p) { return Eigen::Vector3d(p[0], p[1], p[2]); };
    Opening o;
    double sum = 0;
    for (const auto& [a, b] : springs) {
        const Eigen::Vector3d ra = point(rest[std::size_t(a)]), rb = point(rest[std::size_t(b)]);
        if ((0.5 * (ra + rb) - plan.centre).norm() > radius_mm) continue;
        const double open = (point(positions[std::size_t(a)]) - point(positions[std::size_t(b)])).norm() - (ra - rb).norm();
        sum += open, o.max_mm = o.springs ? std::max(o.max_mm, open) : open, ++o.springs;
    }
    if (o.springs) o.mean_mm = sum / o.springs;
    return o;
}

/// The caps' drawn vertices: the largest and mean distance from the plane x = x_c (the blade's),
/// and the mean x of each side's cap vertices within 5 mm (in z) of the centre, the crack's front
/// (on both) left out: the caps facing −x close the + side, those facing +x the − side.
struct CapFigures {
    double distance_max = 0, distance_mean = 0, apart = 0;
    std::array<int, 2> side_vertices{0, 0};  ///< the − and + sides' cap vertices near the centre, the front left out
};
inline CapFigures cap_figures(const IncisionState& incisions, const std::vector<Eigen::Vector3f>& drawn, const Incision& plan) {
    CapFigures c;
    const IncisionMesh& mesh = incisions.mesh();
    std::vector<int> faces(mesh.rest.size(), 0);
    for (std::size_t t = incisions.cap_first(); t < incisions.drawn_triangles().size(); ++t) {
        const auto& tri = incisions.drawn_triangles()[t];
        const Eigen::Vector3d n = (mesh.rest[std::size_t(tri[1])] - mesh.rest[std::size_t(tri[0])])
                                      .cross(mesh.rest[std::size_t(tri[2])] - mesh.rest[std::size_t(tri[0])]);
        for (std::int32_t v : tri) faces[std::size_t(v)] |= n.x() < 0 ? 2 : 1;
    }
    double sum = 0, side_sum[2] = {0, 0};
    int count = 0;
    auto& side_count = c.side_vertices;
    for (std::size_t v = 0; v < mesh.rest.size(); ++v) {
        if (!faces[v]) continue;
        const double d = std::abs(double(drawn[v].x()) - plan.centre.x());
        c.distance_max = std::max(c.distance_max, d);
        sum += d, ++count;
        if ((faces[v] == 1 || faces[v] == 2) && std::abs(mesh.rest[v].z() - plan.centre.z()) < 5.0) {
            side_sum[std::size_t(faces[v] - 1)] += drawn[v].x();
            ++side_count[std::size_t(faces[v] - 1)];
        }
    }
    c.distance_mean = count ? sum / count : 0;
    if (side_count[0] && side_count[1]) c.apart = side_sum[1] / side_count[1] - side_sum[0] / side_count[0];
    return c;
}

/// The trajectory as a CSV that `heartsim run --trajectory` reads (runtime/core/trajectory.h).
inline void write_trajectory_csv(const Trajectory& t, const std::filesystem::path& path) { heartsim::write_trajectory_csv(t, path); }

}  // namespace heartsim::test
