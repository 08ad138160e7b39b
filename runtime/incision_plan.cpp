#include "runtime/incision_plan.h"

#include "formats/atomic_file.h"
#include "libmodel/errors.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

namespace heartsim {
namespace {

/// The world axis `v` lies along (0, 1 or 2) and its sign; `v` is a signed unit axis.
std::pair<int, double> axis_of(const Eigen::Vector3d& v) {
    int axis = 0;
    v.cwiseAbs().maxCoeff(&axis);
    return {axis, v[axis] < 0 ? -1.0 : 1.0};
}

/// "posterior (+y)" and the like: where a world axis points, in the patient's words.
std::string direction_words(const Eigen::Vector3d& v) {
    const auto [axis, sign] = axis_of(v);
    static const char* const words[3][2] = {{"toward the patient's right (-x)", "toward the patient's left (+x)"}, {"anterior (-y)", "posterior (+y)"}, {"inferior (-z)", "superior (+z)"}};
    return words[axis][sign > 0 ? 1 : 0];
}

const char* view_name(ViewDirection view) {
    switch (view) {
        case ViewDirection::anterior: return "anterior";
        case ViewDirection::posterior: return "posterior";
        case ViewDirection::left: return "left";
        case ViewDirection::right: return "right";
        case ViewDirection::superior: return "superior";
        case ViewDirection::inferior: return "inferior";
    }
    return "anterior";
}

/// The chosen particle of each approach (incision_plan.h); `whole` tells whether the atriotomy's
/// place holds the whole incision.
std::size_t entry_particle(const Scenario& scenario, const IncisionPlanOptions& o, bool& whole) {
    const auto& rest = scenario.lattice.particles.rest_position;
    double z_low = std::numeric_limits<double>::infinity(), z_high = -z_low;
    for (const auto& p : rest) z_low = std::min(z_low, double(p[2])), z_high = std::max(z_high, double(p[2]));
    std::size_t front = 0;
    bool found = false;
    whole = true;
    if (o.approach == IncisionApproach::ventriculotomy) {
        // The most anterior point of the middle third (in z) of the model: the free wall, not an
        // apex or a vessel stump at the model's ends.
        for (std::size_t i = 0; i < rest.size(); ++i) {
            const double z = rest[i][2];
            if (z < z_low + (z_high - z_low) / 3 || z > z_high - (z_high - z_low) / 3) continue;
            if (!found || rest[i][1] < rest[front][1]) front = i, found = true;
        }
        return front;
    }
    // The atriotomy: the right surface seen from the patient's right, as the most rightward
    // particle (smallest x) of each (y, z) column one spacing wide. Of the columns in the upper
    // half (in z) and the anterior two thirds (in y), the most rightward whose neighbourhood holds
    // the whole incision: along the stroke (± length / 2 in z) and on the retractors' columns
    // (± 2 columns in y) the surface lies within the blade's reach (from its tip, `clearance` in
    // front, to `depth` behind). That keeps the cut on a continuous wall, off the rim of an opening
    // of the segmentation (a valve ring, a vessel's mouth) where the next column's surface lies deep
    // inside the heart.
    double y_low = std::numeric_limits<double>::infinity(), y_high = -y_low;
    for (const auto& p : rest) y_low = std::min(y_low, double(p[1])), y_high = std::max(y_high, double(p[1]));
    const double z_mid = z_low + 0.5 * (z_high - z_low), y_limit = y_low + 2.0 * (y_high - y_low) / 3.0;
    const double h = scenario.lattice.spacing;
    const int ny = int(std::lround((y_high - y_low) / h)) + 1, nz = int(std::lround((z_high - z_low) / h)) + 1;
    std::vector<int> surface(std::size_t(ny) * std::size_t(nz), -1);
    auto column = [&](int by, int bz) -> int& { return surface[std::size_t(bz) * std::size_t(ny) + std::size_t(by)]; };
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const int by = std::clamp(int(std::lround((rest[i][1] - y_low) / h)), 0, ny - 1);
        const int bz = std::clamp(int(std::lround((rest[i][2] - z_low) / h)), 0, nz - 1);
        int& f = column(by, bz);
        if (f < 0 || rest[i][0] < rest[std::size_t(f)][0]) f = int(i);
    }
    const int half = std::max(1, int(std::lround(0.5 * o.length_mm / h))), wide = 2;
    const double reach = o.depth_mm > 0 ? o.depth_mm : 6.0;  // "through the wall": a wall 6 mm deep around the place
    for (int bz = 0; bz < nz; ++bz)
        for (int by = 0; by < ny; ++by) {
            const int c = column(by, bz);
            if (c < 0 || rest[std::size_t(c)][2] < z_mid || rest[std::size_t(c)][1] > y_limit) continue;
            const double x0 = rest[std::size_t(c)][0];
            if (found && x0 >= rest[front][0]) continue;
            bool holds = bz - half >= 0 && bz + half < nz && by - wide >= 0 && by + wide < ny;
            for (int dz = -half; holds && dz <= half; ++dz)
                for (int dy = -wide; holds && dy <= wide; ++dy) {
                    const int f = column(by + dy, bz + dz);
                    holds = f >= 0 && rest[std::size_t(f)][0] >= x0 - o.clearance_mm && rest[std::size_t(f)][0] <= x0 + reach;
                }
            if (holds) front = std::size_t(c), found = true;
        }
    if (found) return front;
    // No such place (a heart smaller than the incision): the most rightward particle of the upper
    // half among the anterior two thirds.
    whole = false;
    for (int pass = 0; pass < 2 && !found; ++pass)  // the second pass without the y limit: never empty
        for (std::size_t i = 0; i < rest.size(); ++i) {
            if (rest[i][2] < z_mid || (pass == 0 && rest[i][1] > y_limit)) continue;
            if (!found || rest[i][0] < rest[front][0]) front = i, found = true;
        }
    return front;
}

}  // namespace

double wall_thickness(const Scenario& scenario, std::size_t from, const Eigen::Vector3d& direction) {
    const auto& rest = scenario.lattice.particles.rest_position;
    const double h = scenario.lattice.spacing;
    const Eigen::Vector3d start(rest[from][0], rest[from][1], rest[from][2]);
    // The particles near the line, once.
    std::vector<Eigen::Vector3d> near;
    for (const auto& r : rest) {
        const Eigen::Vector3d p(r[0], r[1], r[2]);
        const Eigen::Vector3d d = p - start;
        if (d.dot(direction) > -h && (d - d.dot(direction) * direction).norm() <= 0.75 * h) near.push_back(p);
    }
    double inside = 0.0;
    for (double t = 0.25 * h; t < 200.0; t += 0.25 * h) {
        const Eigen::Vector3d q = start + t * direction;
        bool covered = false;
        for (const auto& p : near)
            if ((p - q).squaredNorm() <= 0.5625 * h * h) {
                covered = true;
                break;
            }
        if (!covered) break;
        inside = t;
    }
    return inside + 0.5 * h;
}

IncisionApproach parse_incision_approach(const std::string& name) {
    if (name == "ventriculotomy") return IncisionApproach::ventriculotomy;
    if (name == "atriotomy") return IncisionApproach::atriotomy;
    throw OptionError("{IncisionPlanOptions::approach} '" + name + "': expected ventriculotomy or atriotomy");
}

const char* to_string(IncisionApproach approach) {
    return approach == IncisionApproach::atriotomy ? "atriotomy" : "ventriculotomy";
}

int frontmost_near(const Scenario& scenario, const Eigen::Vector3d& point, const Eigen::Vector3d& blade, double radius) {
    const auto& rest = scenario.lattice.particles.rest_position;
    const auto [axis, sign] = axis_of(blade);
    const int u = axis == 0 ? 1 : 0, v = axis == 2 ? 1 : 2;  // the two other axes, in order
    int best = -1;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        if (std::hypot(rest[i][u] - point[u], rest[i][v] - point[v]) > radius) continue;
        const std::size_t b = std::size_t(best);
        if (best < 0 || (sign > 0 ? rest[i][axis] < rest[b][axis] : rest[i][axis] > rest[b][axis])) best = int(i);
    }
    return best;
}

IncisionPlan plan_incision(const Scenario& scenario, const IncisionPlanOptions& o) {
    const auto& rest = scenario.lattice.particles.rest_position;
    if (rest.empty()) throw InputError("the scenario has no particles: there is no tissue to cut");
    IncisionPlan plan;
    plan.approach = o.approach;
    const std::size_t front = entry_particle(scenario, o, plan.whole_wall);
    plan.particle = int(front);
    plan.entry = Eigen::Vector3d(rest[front][0], rest[front][1], rest[front][2]);
    if (o.approach == IncisionApproach::ventriculotomy) {
        // The blade points posterior (the tool's +z onto the world's +y) with its width along the
        // cut (the tool's x onto the world's +z, the direction it moves), its flat faces facing ±x.
        plan.blade = Eigen::Vector3d::UnitY(), plan.cut = Eigen::Vector3d::UnitZ(), plan.side = Eigen::Vector3d::UnitX();
        plan.view = ViewDirection::anterior;
    } else {
        // The blade points medially (+x), drawn superior; its flat faces facing ±y (cut × side = blade).
        plan.blade = Eigen::Vector3d::UnitX(), plan.cut = Eigen::Vector3d::UnitZ(), plan.side = -Eigen::Vector3d::UnitY();
        plan.view = ViewDirection::right;
    }
    const double spacing = scenario.lattice.spacing;
    // The blade's plane a quarter spacing beside the particle's column: a particle on the plane
    // would be cut from its neighbours on one side or the other by the rounding of the spring test.
    const auto [side_axis, side_sign] = axis_of(plan.side);
    plan.centre = plan.entry;
    plan.centre[side_axis] = double(rest[front][std::size_t(side_axis)]) + side_sign * 0.25 * spacing;
    Eigen::Matrix3d tool_to_world;
    tool_to_world.col(0) = plan.cut;
    tool_to_world.col(1) = plan.side;
    tool_to_world.col(2) = plan.blade;
    const Eigen::Quaterniond orientation(tool_to_world);
    plan.wall_mm = wall_thickness(scenario, front, plan.blade);
    plan.depth_mm = o.depth_mm > 0 ? o.depth_mm : std::min(plan.wall_mm + 2.0, 40.0);
    plan.blade_length_mm = o.clearance_mm + plan.depth_mm;
    const Eigen::Vector3d blade_axes(2.0, 0.3, 0.5 * plan.blade_length_mm);
    auto key = [&](double t, int hand, InstrumentKind kind, const Eigen::Vector3d& p, const Eigen::Quaterniond& q,
                   const Eigen::Vector3d& axes, bool grab) {
        InstrumentKeyframe k;
        k.time_ms = t, k.hand = hand, k.kind = kind, k.semi_axes = axes, k.grab = grab;
        k.pose.position = p, k.pose.orientation = q;
        plan.trajectory.keyframes.push_back(k);
    };
    const Eigen::Vector3d tip = plan.centre - o.clearance_mm * plan.blade;
    const Eigen::Vector3d half = (0.5 * o.length_mm) * plan.cut;
    plan.cut_end_ms = o.length_mm / o.speed_mm_per_ms;
    key(0.0, 0, InstrumentKind::scalpel, tip - half, orientation, blade_axes, true);
    key(plan.cut_end_ms, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, true);
    // Lifted and withdrawn 10 mm back out.
    key(plan.cut_end_ms + 1e-3, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, false);
    plan.end_ms = plan.cut_end_ms + 25.0;
    key(plan.end_ms, 0, InstrumentKind::scalpel, tip + half - 10.0 * plan.blade, orientation, blade_axes, false);
    if (!o.retract) return plan;

    // Retractors: a grabber of radius 1.2 spacings each side of the blade's plane, its centre on
    // the frontmost particle 0.5 spacing beyond its reach from the plane, so it holds one edge
    // only; grab 50 ms after the cut, pull over 500 ms, hold 250 ms.
    const double radius = 1.2 * spacing, offset = radius + 0.5 * spacing;
    plan.grab_ms = plan.cut_end_ms + 50.0;
    plan.spread_end_ms = plan.grab_ms + 500.0;
    plan.end_ms = plan.spread_end_ms + 250.0;
    const Eigen::Vector3d grabber_axes = Eigen::Vector3d::Constant(radius);
    for (int hand = 0; hand < 2; ++hand) {
        const double side = hand == 0 ? -1.0 : 1.0;
        const Eigen::Vector3d beside = plan.centre + (side * offset) * plan.side;
        const int at = frontmost_near(scenario, beside, plan.blade, spacing);
        const Eigen::Vector3d grip = at >= 0 ? Eigen::Vector3d(rest[std::size_t(at)][0], rest[std::size_t(at)][1], rest[std::size_t(at)][2])
                                             : beside;
        plan.grips[std::size_t(hand)] = grip, plan.grip_found[std::size_t(hand)] = at >= 0;
        const double pull = side * 0.5 * o.spread_mm;
        const Eigen::Vector3d pulled = grip + pull * plan.side;
        const Eigen::Quaterniond none = Eigen::Quaterniond::Identity();
        if (hand == 1) key(0.0, 1, InstrumentKind::none, grip, none, grabber_axes, false);
        key(plan.grab_ms, hand, InstrumentKind::grabber, grip, none, grabber_axes, true);
        key(plan.spread_end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
        key(plan.end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
    }
    std::stable_sort(plan.trajectory.keyframes.begin(), plan.trajectory.keyframes.end(),
                     [](const auto& a, const auto& b) { return a.time_ms < b.time_ms; });
    return plan;
}

void write_trajectory_csv(const Trajectory& t, const std::filesystem::path& path, const std::string& comments) {
    std::string text = comments + "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n";
    for (const InstrumentKeyframe& k : t.keyframes) {
        const auto& p = k.pose.position;
        const auto& q = k.pose.orientation;
        char row[512];
        std::snprintf(row, sizeof row, "%.17g,%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", k.time_ms, k.hand,
                      to_string(k.kind), p.x(), p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), k.semi_axes.x(), k.semi_axes.y(), k.semi_axes.z(),
                      k.grab ? 1 : 0);
        text += row;
    }
    write_bytes_atomically(path, text.data(), text.size(), "the trajectory");
}

double incision_view_distance(const IncisionPlan&, const IncisionPlanOptions& options) { return 2.5 * options.length_mm; }

std::string incision_look_at(const IncisionPlan& plan, const IncisionPlanOptions& options) {
    char text[160];
    std::snprintf(text, sizeof text, "%.1f,%.1f,%.1f,%.1f", plan.centre.x(), plan.centre.y(), plan.centre.z(),
                  incision_view_distance(plan, options));
    return text;
}

int plan_incision_command(const PlanIncisionArguments& a) {
    IncisionPlanOptions options = a.options;
    options.approach = parse_incision_approach(a.approach);
    options.retract = options.spread_mm > 0.0;
    refuse_an_input_as_output("-o " + a.output, a.output, {{a.scenario, "the scenario being planned"}});
    check_destination(a.output);  // before the planning: a folder that cannot take the file
    const Scenario scenario = read_scenario(a.scenario);
    const IncisionPlan plan = plan_incision(scenario, options);
    check_planned_trajectory(plan.trajectory);
    write_trajectory_csv(plan.trajectory, a.output);

    const bool atriotomy = options.approach == IncisionApproach::atriotomy;
    const auto [side_axis, side_sign] = axis_of(plan.side);
    const char axis_name = "xyz"[side_axis];
    std::printf("plan-incision: a right %s on %s (%zu particles, lattice spacing %.2f mm)\n", to_string(options.approach), a.scenario.c_str(),
                scenario.lattice.particles.rest_position.size(), scenario.lattice.spacing);
    std::printf("  where       %s: particle %d at (%.1f, %.1f, %.1f) mm, world LPS\n",
                atriotomy ? "the most rightward place of the heart's upper half, among its anterior two thirds, where the right wall "
                            "holds the whole incision (the right atrium's free wall where the tissue has one)"
                          : "the most anterior point of the heart's middle third (the free wall in front)",
                plan.particle, plan.entry.x(), plan.entry.y(), plan.entry.z());
    char through[64] = "";
    if (!(options.depth_mm > 0)) std::snprintf(through, sizeof through, ": through the %.1f mm wall and 2 mm on", plan.wall_mm);
    std::printf("  blade       %.1f mm long (its tip %.1f mm in front of that point, %.1f mm deep behind it%s), pointing %s%s; its plane "
                "%c = %.2f mm passes a quarter spacing beside the particle\n",
                plan.blade_length_mm, options.clearance_mm, plan.depth_mm,
                through,
                atriotomy ? "medially, " : "", direction_words(plan.blade).c_str(), axis_name, plan.centre[side_axis]);
    std::printf("  stroke      %.1f mm from inferior to superior (z %.1f to %.1f mm) at %g mm/ms: lowered at 0 ms, lifted at %.0f ms, "
                "then withdrawn\n",
                options.length_mm, plan.centre.z() - 0.5 * options.length_mm, plan.centre.z() + 0.5 * options.length_mm, options.speed_mm_per_ms,
                plan.cut_end_ms);
    if (options.retract) {
        std::printf("  retractors  two grabbers (hands 0 and 1) grab the incision's edges at %.0f ms, one each side of the plane, and pull "
                    "them %.1f mm apart along %c (%.1f mm each) by %.0f ms, then hold until %.0f ms\n",
                    plan.grab_ms, options.spread_mm, axis_name, 0.5 * options.spread_mm, plan.spread_end_ms, plan.end_ms);
        for (int hand = 0; hand < 2; ++hand)
            if (!plan.grip_found[std::size_t(hand)])
                std::printf("  note        no tissue beside the incision for hand %d's retractor: it closes on the empty point (%.1f, %.1f, "
                            "%.1f) mm and holds nothing\n",
                            hand, plan.grips[std::size_t(hand)].x(), plan.grips[std::size_t(hand)].y(), plan.grips[std::size_t(hand)].z());
    } else {
        std::printf("  retractors  none (--spread 0): the cut alone, ending at %.0f ms\n", plan.end_ms);
    }
    if (!plan.whole_wall)
        std::printf("  note        no place on the right wall of the upper half holds the whole incision within the blade's reach: "
                    "the most rightward point taken; the cut may run off the wall\n");
    if (!scenario.visual || !scenario.mapping)
        std::printf("  note        the scenario has no detailed mesh (/visual with /mapping): the run cuts the tissue, but the surface it "
                    "draws does not open\n");
    // A tenth of a second past the gesture's end: the tissue settles under the held retractors.
    const double seconds = (std::floor(plan.end_ms / 100.0) + 1.0) / 10.0;
    std::printf("  wrote       %s (%zu keyframes; the gesture lasts %.0f ms)\n", a.output.c_str(), plan.trajectory.keyframes.size(), plan.end_ms);
    std::printf("  run it      heartsim run %s --trajectory %s --seconds %.1f\n", a.scenario.c_str(), a.output.c_str(), seconds);
    std::printf("  see it      add --view %s --look-at %s (the camera from outside, on the incision's centre, %.0f mm away)\n",
                view_name(plan.view), incision_look_at(plan, options).c_str(), incision_view_distance(plan, options));
    return 0;
}

}  // namespace heartsim
