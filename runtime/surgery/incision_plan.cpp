#include "runtime/surgery/incision_plan.h"

#include "formats/atomic_file.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/surgery_site.h"
#include "libmodel/text.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

namespace heartsim {
namespace {

/// "posterior (+y)" and the like: where a world axis points, in the patient's words.
std::string direction_words(const Eigen::Vector3d& v) {
    const auto [axis, sign] = axis_of(v);
    static const char* const words[3][2] = {{"toward the patient's right (-x)", "toward the patient's left (+x)"}, {"anterior (-y)", "posterior (+y)"}, {"inferior (-z)", "superior (+z)"}};
    return words[axis][sign > 0 ? 1 : 0];
}

}  // namespace

IncisionApproach parse_incision_approach(const std::string& name) {
    if (name == "ventriculotomy") return IncisionApproach::ventriculotomy;
    if (name == "atriotomy") return IncisionApproach::atriotomy;
    throw OptionError("{IncisionPlanOptions::approach} '" + name + "': expected ventriculotomy or atriotomy");
}

const char* to_string(IncisionApproach approach) {
    return approach == IncisionApproach::atriotomy ? "atriotomy" : "ventriculotomy";
}

namespace {

/// One flag per particle of `scenario`: its material's row's flag in `rows` (0 for a row beyond it).
std::vector<std::uint8_t> particles_of_rows(const Scenario& scenario, const std::vector<std::uint8_t>& rows) {
    const auto& material = scenario.lattice.particles.material;
    std::vector<std::uint8_t> flags(scenario.lattice.particles.rest_position.size(), 0);
    for (std::size_t i = 0; i < flags.size() && i < material.size(); ++i)
        flags[i] = material[i] >= 0 && std::size_t(material[i]) < rows.size() && rows[std::size_t(material[i])];
    return flags;
}

}  // namespace

std::vector<std::uint8_t> chamber_wall_particles(const Scenario& scenario, IncisionApproach approach, std::string* material_name) {
    const auto& materials = scenario.lattice.materials;
    const char* const chamber = approach == IncisionApproach::atriotomy ? "right atri" : "right ventric";
    std::vector<std::uint8_t> rows(materials.size(), 0);
    for (std::size_t m = 0; m < materials.size(); ++m) {
        rows[m] = text::lowercase(materials[m].name).find(chamber) != std::string::npos;
        if (rows[m] && material_name && material_name->empty()) *material_name = materials[m].name;
    }
    return particles_of_rows(scenario, rows);
}

std::vector<std::uint8_t> labelled_where_grown(const Scenario& scenario) {
    const auto& origin = scenario.tissue_origin;
    if (std::none_of(origin.begin(), origin.end(), [](const TissueOrigin& o) { return o.grown; })) return {};
    std::vector<std::uint8_t> rows(origin.size());
    for (std::size_t m = 0; m < origin.size(); ++m) rows[m] = !origin[m].grown;
    return particles_of_rows(scenario, rows);
}

int frontmost_near(const Scenario& scenario, const Eigen::Vector3d& point, const Eigen::Vector3d& blade, double radius) {
    return frontmost_near(scenario.lattice.particles.rest_position, point, blade, radius);
}

IncisionPlan plan_incision(const Scenario& scenario, const IncisionPlanOptions& o) {
    const auto& rest = scenario.lattice.particles.rest_position;
    if (rest.empty()) throw InputError("the scenario has no particles: there is no tissue to cut");
    IncisionPlan plan;
    plan.approach = o.approach;
    const double spacing = scenario.lattice.spacing;
    std::string wall_name;
    std::vector<std::uint8_t> wall = chamber_wall_particles(scenario, o.approach, &wall_name);
    const IncisionSite site = incision_site(rest, spacing,
                                            {.approach = o.approach,
                                             .length_mm = o.length_mm,
                                             .depth_mm = o.depth_mm,
                                             .clearance_mm = o.clearance_mm,
                                             .chamber_wall = std::move(wall),
                                             .height_from = labelled_where_grown(scenario)});
    if (site.on_chamber_wall) plan.chamber_wall = wall_name;
    plan.particle = int(site.particle);
    plan.whole_wall = site.whole_wall;
    plan.entry = site.entry;
    plan.centre = site.centre;
    plan.blade = site.blade, plan.cut = site.cut, plan.side = site.side;
    plan.wall_mm = site.wall_mm;
    plan.view = o.approach == IncisionApproach::ventriculotomy ? ViewDirection::anterior : ViewDirection::right;
    Eigen::Matrix3d tool_to_world;
    tool_to_world.col(0) = plan.cut;
    tool_to_world.col(1) = plan.side;
    tool_to_world.col(2) = plan.blade;
    const Eigen::Quaterniond orientation(tool_to_world);
    plan.depth_mm = o.depth_mm > 0 ? o.depth_mm : std::min(plan.wall_mm + 2.0, 40.0);
    plan.blade_length_mm = o.clearance_mm + plan.depth_mm;
    const Eigen::Vector3d blade_axes(2.0, 0.3, 0.5 * plan.blade_length_mm);
    Trajectory& script = plan.trajectory;
    const Eigen::Vector3d tip = plan.centre - o.clearance_mm * plan.blade;
    const Eigen::Vector3d half = (0.5 * o.length_mm) * plan.cut;
    plan.cut_end_ms = o.length_mm / o.speed_mm_per_ms;
    script.add(0.0, 0, InstrumentKind::scalpel, tip - half, orientation, blade_axes, true);
    script.add(plan.cut_end_ms, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, true);
    // Lifted and withdrawn 10 mm back out.
    script.add(plan.cut_end_ms + 1e-3, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, false);
    plan.end_ms = plan.cut_end_ms + 25.0;
    script.add(plan.end_ms, 0, InstrumentKind::scalpel, tip + half - 10.0 * plan.blade, orientation, blade_axes, false);
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
        const int at = frontmost_near(rest, beside, plan.blade, spacing);
        const Eigen::Vector3d grip = at >= 0 ? Eigen::Vector3d(rest[std::size_t(at)][0], rest[std::size_t(at)][1], rest[std::size_t(at)][2])
                                             : beside;
        plan.grips[std::size_t(hand)] = grip, plan.grip_found[std::size_t(hand)] = at >= 0;
        const double pull = side * 0.5 * o.spread_mm;
        const Eigen::Vector3d pulled = grip + pull * plan.side;
        const Eigen::Quaterniond none = Eigen::Quaterniond::Identity();
        if (hand == 1) script.add(0.0, 1, InstrumentKind::none, grip, none, grabber_axes, false);
        script.add(plan.grab_ms, hand, InstrumentKind::grabber, grip, none, grabber_axes, true);
        script.add(plan.spread_end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
        script.add(plan.end_ms, hand, InstrumentKind::grabber, pulled, none, grabber_axes, true);
    }
    script.sort_by_time();
    return plan;
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
    // The view that shows the incision, recorded for heartsim run (the CSV's `# view:` line).
    Trajectory planned = plan.trajectory;
    planned.view = parse_view_options(std::string("--view ") + to_string(plan.view) + " --look-at " + incision_look_at(plan, options));
    write_trajectory_csv(planned, a.output);

    const bool atriotomy = options.approach == IncisionApproach::atriotomy;
    const auto [side_axis, side_sign] = axis_of(plan.side);
    const char axis_name = "xyz"[side_axis];
    std::printf("plan-incision: a right %s on %s (%zu particles, lattice spacing %.2f mm)\n", to_string(options.approach), a.scenario.c_str(),
                scenario.lattice.particles.rest_position.size(), scenario.lattice.spacing);
    std::string where;
    if (!plan.chamber_wall.empty())
        where = atriotomy ? "on the right atrium's own wall ('" + plan.chamber_wall +
                                "'), the most rightward place of its middle half where the wall holds the whole incision"
                          : "on the right ventricle's own wall ('" + plan.chamber_wall + "'), its most anterior point in the heart's middle third";
    else
        where = atriotomy ? (scenario.tissue_origin.empty() ? std::string("no tissue is named for the right atrium, so on the whole heart: the most rightward place of its upper half, "
                                                                         "among its anterior two thirds, where the right wall holds the whole incision")
                                                             : std::string("no tissue is named for the right atrium, so beside the labelled wall's upper half: the most "
                                                                           "rightward place at that height, among the heart's anterior two thirds, where the right wall "
                                                                           "holds the whole incision"))
                          : "no tissue is named for the right ventricle, so on the whole heart: the most anterior point of its middle "
                            "third (the free wall in front)";
    std::printf("  where       %s: particle %d at (%.1f, %.1f, %.1f) mm, world LPS\n", where.c_str(), plan.particle, plan.entry.x(),
                plan.entry.y(), plan.entry.z());
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
        std::printf("  note        no place on the right wall holds the whole incision within the blade's reach: "
                    "the most rightward point taken; the cut may run off the wall\n");
    if (!scenario.visual || !scenario.mapping)
        std::printf("  note        the scenario has no detailed mesh (/visual with /mapping): the run cuts the tissue, but the surface it "
                    "draws does not open\n");
    // A tenth of a second past the gesture's end: the tissue settles under the held retractors.
    const double seconds = (std::floor(plan.end_ms / 100.0) + 1.0) / 10.0;
    std::printf("  wrote       %s (%zu keyframes; the gesture lasts %.0f ms)\n", a.output.c_str(), plan.trajectory.keyframes.size(), plan.end_ms);
    std::printf("  run it      heartsim run %s --trajectory %s --seconds %.1f\n", a.scenario.c_str(), a.output.c_str(), seconds);
    std::printf("  see it      the run's window and screenshots open on the incision, the camera from outside on its centre, %.0f mm "
                "away: the view the file records (%s; --view, --eye or --look-at choose another)\n",
                incision_view_distance(plan, options), view_options(*planned.view).c_str());
    return 0;
}

}  // namespace heartsim
