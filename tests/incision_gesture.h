/// @file incision_gesture.h
/// @brief The scripted incision of the cutting tests and the cutting benchmark: on a scenario's
/// most anterior point, a scalpel with its blade pointing posterior (+y, LPS) is lowered and drawn
/// `length_mm` from inferior to superior (−z to +z) at 0.1 mm/ms; lifted, it becomes a retractor
/// (hand 0) beside a second one (hand 1): they grab the two edges of the incision, one each side
/// of the blade's plane x = x_c, and pull them `spread_mm` apart along ±x, then hold.
///
///     const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 30});
///     run_scripted(*backend, plan.trajectory, {.steps = int(plan.end_ms / dt)});
///     write_trajectory_csv(plan.trajectory, "incision.csv");   // for `heartsim run --trajectory`
#pragma once

#include "formats/scenario.h"
#include "runtime/trajectory.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
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
    double cut_end_ms = 0.0;     ///< the blade lifts here
    double end_ms = 0.0;         ///< the gesture's end (retractors held still from spread_end_ms)
    double spread_end_ms = 0.0;
};

/// The particle most anterior (smallest y) among those within `radius` of the line through
/// (x, ·, z) along y; −1 if none.
inline int most_anterior_near(const Scenario& scenario, double x, double z, double radius) {
    const auto& rest = scenario.lattice.particles.rest_position;
    int best = -1;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        if (std::hypot(rest[i][0] - x, rest[i][2] - z) > radius) continue;
        if (best < 0 || rest[i][1] < rest[std::size_t(best)][1]) best = int(i);
    }
    return best;
}

inline Incision anterior_incision(const Scenario& scenario, const IncisionOptions& o = {}) {
    const auto& rest = scenario.lattice.particles.rest_position;
    if (rest.empty()) throw std::runtime_error("anterior_incision: the scenario has no particles");
    // The most anterior point of the middle third (in z) of the model: the free wall, not an
    // apex or a vessel stump at the model's ends.
    double z_low = std::numeric_limits<double>::infinity(), z_high = -z_low;
    for (const auto& p : rest) z_low = std::min(z_low, double(p[2])), z_high = std::max(z_high, double(p[2]));
    std::size_t front = 0;
    bool found = false;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const double z = rest[i][2];
        if (z < z_low + (z_high - z_low) / 3 || z > z_high - (z_high - z_low) / 3) continue;
        if (!found || rest[i][1] < rest[front][1]) front = i, found = true;
    }
    Incision plan;
    const double spacing = scenario.lattice.spacing;
    // The blade's plane a quarter spacing beside the particle's column: a particle on the plane
    // would be cut from its neighbours on one side or the other by the rounding of the spring test.
    plan.centre = Eigen::Vector3d(rest[front][0] + 0.25 * spacing, rest[front][1], rest[front][2]);
    // The blade points posterior (the tool's +z onto the world's +y) with its width along the cut
    // (the tool's x onto the world's +z, the direction it moves), its flat faces facing ±x.
    Eigen::Matrix3d tool_to_world;
    tool_to_world.col(0) = Eigen::Vector3d::UnitZ();
    tool_to_world.col(1) = Eigen::Vector3d::UnitX();
    tool_to_world.col(2) = Eigen::Vector3d::UnitY();
    const Eigen::Quaterniond posterior(tool_to_world);
    const double blade_length = o.clearance_mm + o.depth_mm;
    const Eigen::Vector3d blade_axes(2.0, 0.3, 0.5 * blade_length);
    auto key = [&](double t, int hand, InstrumentKind kind, const Eigen::Vector3d& p, const Eigen::Quaterniond& q,
                   const Eigen::Vector3d& axes, bool grab) {
        InstrumentKeyframe k;
        k.time_ms = t, k.hand = hand, k.kind = kind, k.semi_axes = axes, k.grab = grab;
        k.pose.position = p, k.pose.orientation = q;
        plan.trajectory.keyframes.push_back(k);
    };
    const Eigen::Vector3d tip = plan.centre - Eigen::Vector3d(0, o.clearance_mm, 0);
    const Eigen::Vector3d half = Eigen::Vector3d(0, 0, 0.5 * o.length_mm);
    plan.cut_end_ms = o.length_mm / o.speed_mm_per_ms;
    key(0.0, 0, InstrumentKind::scalpel, tip - half, posterior, blade_axes, true);
    key(plan.cut_end_ms, 0, InstrumentKind::scalpel, tip + half, posterior, blade_axes, true);
    // Lifted and withdrawn 10 mm anterior.
    key(plan.cut_end_ms + 1e-3, 0, InstrumentKind::scalpel, tip + half, posterior, blade_axes, false);
    plan.end_ms = plan.cut_end_ms + 25.0;
    key(plan.end_ms, 0, InstrumentKind::scalpel, tip + half - Eigen::Vector3d(0, 10, 0), posterior, blade_axes, false);
    if (!o.retract) return plan;

    // Retractors: a grabber of radius 1.2 spacings each side of the blade's plane, its centre on
    // the most anterior particle 0.5 spacing beyond its reach from the plane, so it holds one
    // edge only; grab 50 ms after the cut, pull over 500 ms, hold 250 ms.
    const double radius = 1.2 * spacing, offset = radius + 0.5 * spacing;
    const double grab_ms = plan.cut_end_ms + 50.0;
    plan.spread_end_ms = grab_ms + 500.0;
    plan.end_ms = plan.spread_end_ms + 250.0;
    const Eigen::Vector3d grabber_axes = Eigen::Vector3d::Constant(radius);
    for (int hand = 0; hand < 2; ++hand) {
        const double side = hand == 0 ? -1.0 : 1.0;
        const int at = most_anterior_near(scenario, plan.centre.x() + side * offset, plan.centre.z(), spacing);
        const Eigen::Vector3d grip = at >= 0 ? Eigen::Vector3d(rest[std::size_t(at)][0], rest[std::size_t(at)][1], rest[std::size_t(at)][2])
                                             : Eigen::Vector3d(plan.centre + Eigen::Vector3d(side * offset, 0, 0));
        const Eigen::Vector3d pulled = grip + Eigen::Vector3d(side * 0.5 * o.spread_mm, 0, 0);
        const Eigen::Quaterniond none = Eigen::Quaterniond::Identity();
        if (hand == 1) key(0.0, 1, InstrumentKind::none, grip, none, grabber_axes, false);
        key(grab_ms, hand, InstrumentKind::grabber, grip, none, grabber_axes, true);
        key(plan.spread_end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
        key(plan.end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
    }
    std::stable_sort(plan.trajectory.keyframes.begin(), plan.trajectory.keyframes.end(),
                     [](const auto& a, const auto& b) { return a.time_ms < b.time_ms; });
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

/// The trajectory as a CSV that `heartsim run --trajectory` reads (runtime/trajectory.h).
inline void write_trajectory_csv(const Trajectory& t, const std::filesystem::path& path) {
    std::FILE* f = std::fopen(path.c_str(), "w");
    if (!f) throw std::runtime_error("cannot write " + path.string());
    std::fprintf(f, "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n");
    for (const InstrumentKeyframe& k : t.keyframes) {
        const auto& p = k.pose.position;
        const auto& q = k.pose.orientation;
        std::fprintf(f, "%.17g,%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", k.time_ms, k.hand, to_string(k.kind), p.x(),
                     p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), k.semi_axes.x(), k.semi_axes.y(), k.semi_axes.z(), k.grab ? 1 : 0);
    }
    if (std::fclose(f) != 0) throw std::runtime_error("cannot write " + path.string());
}

}  // namespace heartsim::test
