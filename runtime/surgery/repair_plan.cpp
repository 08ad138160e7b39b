#include "runtime/surgery/repair_plan.h"

#include "formats/atomic_file.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/surgery_site.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/surgery/plan_text.h"
#include "runtime/view/section_plane.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <optional>

namespace heartsim {
namespace {

/// The patient's right and anterior, LPS: the side a surgeon reaches the septum from.
const Eigen::Vector3d right_anterior = Eigen::Vector3d(-1.0, -1.0, 0.0).normalized();

/// How far beyond the wall's thickness a site may lie from the defect's centre along the axis, mm.
constexpr double window_margin_mm = 3.0;

const char* chamber_of(const std::string& defect) { return defect == "asd" ? "atrium" : "ventricle"; }

std::string defect_words(const std::string& defect) {
    return defect == "asd" ? "atrial septal defect" : defect == "vsd" ? "ventricular septal defect" : "septal defect (" + defect + ")";
}

std::string point_text(const Eigen::Vector3d& p, int decimals = 1) { return plan_text::point(p, decimals); }
std::string number_text(double value, int decimals = 1) { return plan_text::number(value, decimals); }

/// The refusal where a stitch's line meets no wall near the defect (StitchSites::missing): which
/// stitch, where, what its line met, and what to change.
InputError no_wall_at_stitch(const StitchSites& found, const StitchCircle& circle, int n) {
    const StitchSite& line = found.missing_line;
    const double stitch_radius_mm = circle.radius_of(found.missing);
    const std::string stitch = "stitch " + std::to_string(found.missing + 1) + " of " + std::to_string(n) + " (" + number_text(line.angle_deg, 0) +
                               "° round the rim): the line along the defect's axis through " + point_text(line.point) + " mm (" +
                               number_text(stitch_radius_mm) + " mm from the axis)";
    if (!found.mid_wall_found)
        return InputError(stitch + " meets no wall near the defect's centre, and none of the " + std::to_string(n) +
                          " lines crosses tissue at mid-wall: the scenario's tissue has no wall there round the opening (the "
                          "stitches' circle reaches beyond the septum: a smaller --rim; or the wall the defect was carved through "
                          "is not simulated: an atrial septum that the label map leaves unlabelled, as MM-WHS does); heartsim run "
                          "CASE --clip defect shows the section there");
    std::string what = "it crosses no tissue at all";
    if (std::isfinite(found.missing_nearest_mm))
        what = "the nearest tissue it enters begins " + number_text(found.missing_nearest_mm) + " mm from the centre's plane";
    return InputError(stitch + " meets no wall within " + number_text(found.window_mm) + " mm of the defect's centre (" + what +
                      "); a smaller --rim keeps the stitches nearer the opening, and heartsim run CASE --clip defect shows the "
                      "septum there");
}

/// The plan's conduction zone in a sentence: its arc, its band and the stitches moved out of it;
/// or why there is none.
std::string conduction_text(const RepairPlan& plan, const RepairPlanOptions& o) {
    const ConductionZone& zone = plan.zone;
    if (!zone.found) return "no zone: " + zone.reason;
    std::vector<int> moved, biting;
    for (std::size_t k = 0; k < plan.stitches.size(); ++k) {
        if (plan.stitches[k].spares_zone) moved.push_back(int(k) + 1);
        if (plan.stitches[k].would_bite_zone) biting.push_back(int(k) + 1);
    }
    auto list = [](const std::vector<int>& stitches) {
        std::string text;
        for (std::size_t i = 0; i < stitches.size(); ++i) text += (i ? ", " : "") + std::to_string(stitches[i]);
        return text;
    };
    const double from = std::remainder(plan.zone_angle_deg - zone.half_width_deg, 360.0), to = std::remainder(plan.zone_angle_deg + zone.half_width_deg, 360.0);
    std::string text = zone.reason + ". The zone: the rim's arc of " + number_text(2.0 * zone.half_width_deg, 0) + "° round " +
                       number_text(plan.zone_angle_deg, 0) + "° (" + number_text(from < 0 ? from + 360.0 : from, 0) + "° to " +
                       number_text(to < 0 ? to + 360.0 : to, 0) + "°, measured as the stitches' angles), its middle " +
                       point_text(zone.direction, 2) + " across the axis, from the axis to " + number_text(zone.outer_mm - zone.edge_mm) +
                       " mm beyond the opening's edge (" + number_text(zone.outer_mm) + " mm from the axis)";
    if (o.rim_mm >= o.zone_rim_mm)
        return text + "; every stitch lies " + number_text(o.rim_mm) + " mm beyond the edge (--rim), as far as --zone-rim " +
               number_text(o.zone_rim_mm) + " mm or farther: none moved";
    if (moved.empty()) return text + "; no stitch lies in its arc";
    return text + "; stitches " + list(moved) + " (in its arc or within " + number_text(o.zone_margin_deg, 0) + "° of it; at " +
           number_text(plan.stitch_radius_mm) + " mm stitches " + (biting.empty() ? std::string("none") : list(biting)) +
           " would bite it) moved out to " + number_text(plan.zone_radius_mm) + " mm from the axis (" + number_text(o.zone_rim_mm) +
           " mm beyond the edge), shallow: the needle's tip at the surface site on the " + (plan.on_right ? "right" : "left") +
           " side and no deeper (the model anchors every stitch at the surface; a bite's depth is not modelled)";
}

/// 221416 → "221,416".
std::string thousands(std::size_t value) {
    std::string digits = std::to_string(value), out;
    for (std::size_t i = 0; i < digits.size(); ++i) {
        if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
        out += digits[i];
    }
    return out;
}

}  // namespace

RepairSide parse_repair_side(const std::string& name) {
    if (name == "auto") return RepairSide::automatic;
    if (name == "right") return RepairSide::right;
    if (name == "left") return RepairSide::left;
    if (name == "a") return RepairSide::a;
    if (name == "b") return RepairSide::b;
    throw OptionError("{RepairPlanOptions::side} '" + name + "': expected auto, right, left, a (the axis's tail) or b (its head)");
}

ConductionZoneMode parse_conduction_zone_mode(const std::string& name) {
    if (name == "auto") return ConductionZoneMode::automatic;
    if (name == "off") return ConductionZoneMode::off;
    throw OptionError("{RepairPlanOptions::conduction_zone} '" + name + "': expected auto (mark a perimembranous defect's conduction zone "
                      "and spare it) or off");
}

const char* to_string(ConductionZoneMode mode) { return mode == ConductionZoneMode::off ? "off" : "auto"; }

ConductionZone scenario_conduction_zone(const Scenario& scenario, const ConductionZoneOptions& options) {
    const ScenarioSource& source = scenario.source;
    ConductionZone none;
    if (source.defect.empty()) {
        none.reason = "the scenario has no defect";
        return none;
    }
    if (source.defect != "vsd") {
        none.reason = "an " + defect_words(source.defect) + ": the conduction zone is a perimembranous ventricular septal defect's";
        return none;
    }
    if (!scenario.landmarks) {
        none.reason = "the scenario stores no /landmarks (no tricuspid and aortic rings): whether the defect is perimembranous "
                      "cannot be told, and no conduction zone is marked";
        return none;
    }
    return conduction_zone(source.defect_centre, source.defect_axis, source.defect_diameter_mm, *scenario.landmarks, options);
}

const char* to_string(RepairSide side) {
    switch (side) {
        case RepairSide::automatic: return "auto";
        case RepairSide::right: return "right";
        case RepairSide::left: return "left";
        case RepairSide::a: return "a";
        case RepairSide::b: return "b";
    }
    return "right";
}

namespace {
/// How many lines sample a rim's roughness for the automatic side: one every 10°.
constexpr int rough_rim_lines = 36;
/// The plan on one side (right, left, a or b).
RepairPlan plan_repair_on(const Scenario& scenario, const RepairPlanOptions& o);
}  // namespace

RepairPlan plan_repair(const Scenario& scenario, const RepairPlanOptions& o) {
    if (o.side != RepairSide::automatic) return plan_repair_on(scenario, o);
    // Each side's rim, sampled along rough_rim_lines lines round the stitches' circle whatever
    // the stitches' count (sparse stitches could straddle a recess): the right kept unless its
    // rim is rough and the left's is not.
    const double nan = std::numeric_limits<double>::quiet_NaN();
    auto roughness = [&](RepairSide side, std::string* why) {
        RepairPlanOptions probe = o;
        probe.side = side, probe.stitches = rough_rim_lines;
        try {
            return plan_repair_on(scenario, probe).fit_residual_mm;
        } catch (const InputError& e) {
            if (why) *why = e.what();
            return nan;
        }
    };
    std::string right_gap;
    const double r = roughness(RepairSide::right, &right_gap), l = roughness(RepairSide::left, nullptr);
    const bool right_fits = r <= o.rough_rim_mm, left_fits = l <= o.rough_rim_mm;
    const bool use_left = !right_fits && left_fits;
    RepairPlanOptions chosen = o;
    chosen.side = use_left ? RepairSide::left : RepairSide::right;
    RepairPlan plan = plan_repair_on(scenario, chosen);  // throws for a side with no wall round the opening
    plan.side = RepairSide::automatic;
    plan.right_residual_mm = r, plan.left_residual_mm = l;
    const char* chamber = chamber_of(plan.defect);
    const std::string lines = std::to_string(rough_rim_lines) + " lines along the axis round the stitches' circle";
    if (use_left && std::isnan(r))
        plan.side_reason = std::string("the right ") + chamber + "'s rim has gaps (of " + lines + ", one meets no wall: " + right_gap +
                           "), the left's lies within " + number_text(l, 2) + " mm of a plane: closed from the left";
    else if (use_left)
        plan.side_reason = std::string("the right ") + chamber + "'s rim is rough here (where " + lines + " enter it, up to " +
                           number_text(r, 2) + " mm off the plane through those points, more than --rough-rim " + number_text(o.rough_rim_mm, 1) +
                           " mm: recesses between stitches that a flat patch spans without sealing), the left's within " + number_text(l, 2) +
                           " mm: closed from the left, as surgeons close a muscular defect the right side's trabeculations crowd";
    else
        plan.side_reason = std::string("its rim (where ") + lines + " enter it) within " + number_text(r, 2) +
                           " mm of a plane (--rough-rim " + number_text(o.rough_rim_mm, 1) + " mm" +
                           (std::isnan(l) ? std::string() : "; the left's within " + number_text(l, 2) + " mm") + ")";
    return plan;
}

namespace {

/// The hands' keyframes of `plan` (its patch, stitches and needle placed) by `o`'s times
/// (repair_plan.h): each stitch's tie_ms, the gesture's end_ms and the trajectory, in time order.
void script_repair(RepairPlan& plan, const RepairPlanOptions& o) {
    Trajectory& script = plan.trajectory;
    const Eigen::Vector3d patch_axes(0.5 * plan.patch_diameter_mm, 0.5 * plan.patch_diameter_mm, 0.5 * o.thickness_mm);
    const Eigen::Vector3d& needle_axes = o.needle_semi_axes;
    const Eigen::Quaterniond& needle = plan.needle_orientation;
    script.add(0.0, 0, InstrumentKind::patch, plan.patch_centre, plan.patch_orientation, patch_axes, true);
    script.add(o.release_ms, 0, InstrumentKind::patch, plan.patch_centre, plan.patch_orientation, patch_axes, false);
    // The needle is held out of the way (kind none) until the patch is laid.
    script.add(0.0, 1, InstrumentKind::none, plan.stitches.front().outside, needle, needle_axes, false);
    double t = o.release_ms;
    script.add(t, 1, InstrumentKind::needle, plan.stitches.front().outside, needle, needle_axes, false);
    const int n = int(plan.stitches.size());
    for (int k = 0; k < n; ++k) {
        RepairStitch& s = plan.stitches[std::size_t(k)];
        s.tie_ms = t + o.approach_ms;
        script.add(s.tie_ms, 1, InstrumentKind::needle, s.site, needle, needle_axes, true);
        script.add(s.tie_ms + o.tie_ms, 1, InstrumentKind::needle, s.site, needle, needle_axes, false);
        t = s.tie_ms + o.tie_ms + o.withdraw_ms;
        // Straight back out along its shaft, then across to the next site: a needle drawn from one
        // site to the next outside point would cut through the rim between them.
        script.add(s.tie_ms + o.tie_ms + 0.5 * o.withdraw_ms, 1, InstrumentKind::needle, s.outside, needle, needle_axes, false);
        const Eigen::Vector3d& next = k + 1 < n ? plan.stitches[std::size_t(k + 1)].outside : s.outside;
        script.add(t, 1, InstrumentKind::needle, next, needle, needle_axes, false);
    }
    plan.end_ms = t + o.settle_ms;
    script.add(plan.end_ms, 1, InstrumentKind::needle, plan.stitches.back().outside, needle, needle_axes, false);
    script.add(plan.end_ms, 0, InstrumentKind::patch, plan.patch_centre, plan.patch_orientation, patch_axes, false);
    script.sort_by_time();
}

RepairPlan plan_repair_on(const Scenario& scenario, const RepairPlanOptions& o) {
    if (o.stitches != 0 && o.stitches < 3) throw OptionError("{RepairPlanOptions::stitches} " + std::to_string(o.stitches) + ": a patch needs at least 3 stitches");
    if (!(o.stitch_spacing_mm > 0)) throw OptionError("the stitches' spacing must be above 0 mm");
    if (!(o.rim_mm > 0)) throw OptionError("{RepairPlanOptions::rim_mm} " + number_text(o.rim_mm, 2) + ": expected a distance above 0 mm beyond the opening's edge");
    if (!(o.thickness_mm > 0)) throw OptionError("{RepairPlanOptions::thickness_mm} " + number_text(o.thickness_mm, 2) + ": expected a thickness above 0 mm");
    if (o.conduction_zone == ConductionZoneMode::automatic) {
        if (!(o.zone.band_mm > 0)) throw OptionError("{ConductionZoneOptions::band_mm} " + number_text(o.zone.band_mm, 2) + ": expected a band above 0 mm beyond the opening's edge");
        if (!(o.zone.half_width_deg > 0 && o.zone.half_width_deg <= 180))
            throw OptionError("{ConductionZoneOptions::half_width_deg} " + number_text(o.zone.half_width_deg, 1) + ": expected a half-width in (0, 180] degrees");
        if (!(o.zone.ring_reach_mm > 0)) throw OptionError("{ConductionZoneOptions::ring_reach_mm} " + number_text(o.zone.ring_reach_mm, 2) + ": expected a distance above 0 mm");
        if (!(o.zone_margin_deg >= 0)) throw OptionError("{RepairPlanOptions::zone_margin_deg} " + number_text(o.zone_margin_deg, 1) + ": expected 0 degrees or more");
        if (!(o.zone_rim_mm > o.zone.band_mm))
            throw OptionError("{RepairPlanOptions::zone_rim_mm} " + number_text(o.zone_rim_mm, 2) + " mm: the stitches moved out of the conduction zone must "
                              "lie beyond its band ({ConductionZoneOptions::band_mm} " + number_text(o.zone.band_mm, 2) + " mm)");
    }
    if (o.patch_diameter_mm < 0) throw OptionError("{RepairPlanOptions::patch_diameter_mm} " + number_text(o.patch_diameter_mm, 2) + ": expected a diameter above 0 mm");
    const ScenarioSource& source = scenario.source;
    if (source.defect.empty())
        throw InputError("the scenario has no defect (its /source carries none): build it with heartprep build LABELS -o CASE.h5 "
                         "--defect vsd (or asd; with --at X,Y,Z where the chambers are not labelled apart)");
    if (!scenario.visual || scenario.visual->triangles.empty())
        throw InputError("the scenario has no detailed mesh (/visual), on which plan-repair finds the septum's surface: build it "
                         "with heartprep build without --no-visual");
    const VisualMesh& mesh = *scenario.visual;

    RepairPlan plan;
    plan.defect = source.defect;
    plan.defect_diameter_mm = source.defect_diameter_mm;
    plan.defect_centre = source.defect_centre;
    plan.defect_axis = source.defect_axis.normalized();
    plan.side = o.side;
    const Eigen::Vector3d& centre = plan.defect_centre;
    const Eigen::Vector3d& axis = plan.defect_axis;
    plan.right_anterior_a = (-axis).dot(right_anterior);
    plan.right_anterior_b = axis.dot(right_anterior);
    const bool b_is_right = plan.right_anterior_b > plan.right_anterior_a;
    switch (o.side) {
        case RepairSide::automatic:
        case RepairSide::right: plan.on_b = b_is_right; break;
        case RepairSide::left: plan.on_b = !b_is_right; break;
        case RepairSide::a: plan.on_b = false; break;
        case RepairSide::b: plan.on_b = true; break;
    }
    plan.on_right = plan.on_b == b_is_right;
    const Eigen::Vector3d outward = plan.on_b ? axis : Eigen::Vector3d(-axis);
    plan.outward = outward;

    plan.stitch_radius_mm = 0.5 * plan.defect_diameter_mm + o.rim_mm;
    plan.patch_thickness_mm = o.thickness_mm;

    // The stitch sites on the detailed mesh, round the circle of radius D/2 + rim; those in the
    // conduction zone's arc (and its margin) on the circle of D/2 + zone_rim.
    const int n = o.stitches > 0 ? o.stitches
                                 : std::max(8, int(std::ceil(2.0 * std::numbers::pi * plan.stitch_radius_mm / o.stitch_spacing_mm - 1e-9)));
    StitchCircle circle = stitch_circle(centre, axis, plan.on_b, plan.stitch_radius_mm, n);
    plan.starts_anterior = circle.starts_anterior;
    if (o.conduction_zone == ConductionZoneMode::automatic) plan.zone = scenario_conduction_zone(scenario, o.zone);
    else plan.zone.reason = "not marked (--conduction-zone off)";
    std::vector<bool> spared(std::size_t(n), false), would_bite(std::size_t(n), false);
    // Stitches whose circle lies at zone_rim or beyond stay there: they spare the zone already.
    if (plan.zone.found && o.zone_rim_mm > o.rim_mm) {
        plan.zone_radius_mm = 0.5 * plan.defect_diameter_mm + o.zone_rim_mm;
        const double turn = std::atan2(plan.zone.direction.dot(circle.second), plan.zone.direction.dot(circle.first)) * 180.0 / std::numbers::pi;
        plan.zone_angle_deg = turn < 0 ? turn + 360.0 : turn;
        circle.radii.assign(std::size_t(n), plan.stitch_radius_mm);
        for (int k = 0; k < n; ++k) {
            const Eigen::Vector3d p = circle.point(k);
            would_bite[std::size_t(k)] = plan.zone.holds(p);
            if (plan.zone.angle_from_middle_deg(p) <= plan.zone.half_width_deg + o.zone_margin_deg) {
                spared[std::size_t(k)] = true;
                circle.radii[std::size_t(k)] = plan.zone_radius_mm;
            }
        }
    }
    const bool any_spared = std::find(spared.begin(), spared.end(), true) != spared.end();
    const double outermost_mm = any_spared ? plan.zone_radius_mm : plan.stitch_radius_mm;
    const double outermost_rim_mm = any_spared ? o.zone_rim_mm : o.rim_mm;
    plan.patch_diameter_mm = o.patch_diameter_mm > 0 ? o.patch_diameter_mm : plan.defect_diameter_mm + 2.0 * (outermost_rim_mm + 2.0);
    if (!(plan.patch_diameter_mm > 2.0 * outermost_mm))
        throw OptionError("{RepairPlanOptions::patch_diameter_mm} " + number_text(plan.patch_diameter_mm) + " mm does not reach beyond the stitches: they lie on a circle " +
                          number_text(2.0 * outermost_mm) + " mm across (the defect's " + number_text(plan.defect_diameter_mm) + " mm and " +
                          (any_spared ? "{RepairPlanOptions::zone_rim_mm}" : "{RepairPlanOptions::rim_mm}") + " " + number_text(outermost_rim_mm) +
                          " mm each side" + (any_spared ? ", where stitches spare the conduction zone" : "") + "); give a larger diameter");

    const StitchSites found = find_stitch_sites(mesh.positions, mesh.triangles, circle, window_margin_mm);
    if (found.missing >= 0) throw no_wall_at_stitch(found, circle, n);
    for (std::size_t k = 0; k < found.sites.size(); ++k) {
        const StitchSite& site = found.sites[k];
        RepairStitch stitch;
        stitch.radius_mm = circle.radius_of(int(k));
        stitch.spares_zone = spared[k];
        stitch.would_bite_zone = would_bite[k];
        stitch.height_mm = site.height_mm;
        stitch.site = site.site;
        stitch.outside = stitch.site + o.approach_mm * outward;
        stitch.angle_deg = site.angle_deg;
        stitch.wall_mm = site.wall_mm;
        plan.stitches.push_back(stitch);
    }
    plan.wall_mm = found.wall_median_mm;
    plan.wall_min_mm = found.wall_min_mm;
    plan.wall_max_mm = found.wall_max_mm;

    const PatchPlacement patch = place_patch(found.sites, circle, o.thickness_mm);
    plan.fit_residual_mm = patch.residual_mm;
    plan.patch_facing = patch.facing;
    plan.patch_tilt_deg = patch.tilt_deg;
    plan.patch_centre = patch.centre;
    plan.patch_orientation = patch.orientation;
    Eigen::Matrix3d needle_frame;
    needle_frame << circle.first, circle.second, outward;
    plan.needle_orientation = Eigen::Quaterniond(needle_frame).normalized();

    script_repair(plan, o);
    return plan;
}

}  // namespace

void write_repair_csv(const RepairPlan& plan, const std::filesystem::path& path, const std::string& scenario_name) {
    char comments[1024];
    std::snprintf(comments, sizeof comments,
                  "# heartsim plan-repair%s%s: a patch over the %s's opening on its %s side (%s), %zu stitches round the rim\n"
                  "# hand 0 lays the patch (grab 1 at 0 ms); hand 1's needle ties a stitch each time its grab turns 1; "
                  "the gesture ends at %.0f ms\n",
                  scenario_name.empty() ? "" : " ", scenario_name.c_str(), plan.defect.c_str(), plan.on_right ? "right" : "left",
                  plan.on_b ? "side b, +axis" : "side a, -axis", plan.stitches.size(), plan.end_ms);
    write_trajectory_csv(plan.trajectory, path, comments);
}

int plan_repair_command(const PlanRepairArguments& a) {
    RepairPlanOptions options = a.options;
    options.side = parse_repair_side(a.side);
    options.conduction_zone = parse_conduction_zone_mode(a.conduction_zone);
    refuse_an_input_as_output("-o " + a.output, a.output, {{a.scenario, "the scenario being planned"}});
    check_destination(a.output);  // before the planning: a folder that cannot take the file
    const Scenario scenario = read_scenario(a.scenario);
    const RepairPlan plan = plan_repair(scenario, options);
    check_planned_trajectory(plan.trajectory);
    write_repair_csv(plan, a.output, std::filesystem::path(a.scenario).filename().string());

    const char* chamber = chamber_of(plan.defect);
    const char* side_name = plan.on_right ? "right" : "left";
    const std::size_t n = plan.stitches.size();
    std::printf("plan-repair: a patch and %zu stitches closing the %s of %s (on its detailed mesh of %s triangles)\n", n,
                defect_words(plan.defect).c_str(), a.scenario.c_str(), thousands(scenario.visual->triangles.size()).c_str());
    std::printf("  defect      %s, %.1f mm across, centred at %s mm (mid-wall, world LPS), its axis %s from side a's pool to side b's\n",
                plan.defect.c_str(), plan.defect_diameter_mm, point_text(plan.defect_centre).c_str(), point_text(plan.defect_axis, 2).c_str());
    const double mine = plan.on_b ? plan.right_anterior_b : plan.right_anterior_a, other = plan.on_b ? plan.right_anterior_a : plan.right_anterior_b;
    const char* which = plan.on_b ? "side b (+axis)" : "side a (-axis)";
    const char* other_side = plan.on_b ? "side a" : "side b";
    // The right and left sides by the right-anterior rule, in one sentence for either.
    const std::string by_rule = std::string(which) + ", whose outward direction " + point_text(plan.outward, 2) + " points " +
                                (plan.on_right ? "more" : "less") + " to the patient's right and anterior (" + number_text(mine, 2) +
                                " against " + number_text(other, 2) + " for " + other_side + "): the " + side_name + " " + chamber + "'s side" +
                                (plan.on_right ? std::string(", from which a surgeon closes ") + (plan.defect == "asd" ? "an " : "a ") +
                                                     defect_words(plan.defect)
                                               : std::string());
    std::string why;
    switch (options.side) {
        case RepairSide::automatic: why = std::string(side_name) + " (auto, the default): " + by_rule + "; " + plan.side_reason; break;
        case RepairSide::right:
        case RepairSide::left: why = std::string(side_name) + " (--side=" + side_name + "): " + by_rule; break;
        case RepairSide::a:
        case RepairSide::b:
            why = std::string(to_string(options.side)) + " (--side=" + to_string(options.side) + "): " + which + ", outward " +
                  point_text(plan.outward, 2) + "; by the right-anterior rule (" + number_text(mine, 2) + " against " + number_text(other, 2) +
                  " for " + other_side + ") the " + side_name + " " + chamber + "'s side";
            break;
    }
    std::printf("  side        %s\n", why.c_str());
    std::printf("  wall        %.1f mm thick along the axis at the stitches (median; %.1f to %.1f mm): each site is where its line along "
                "the axis, coming from the %s %s, first enters the tissue within %.1f mm of the centre\n",
                plan.wall_mm, plan.wall_min_mm, plan.wall_max_mm, side_name, chamber, plan.wall_mm + window_margin_mm);
    std::printf("  patch       a disc %.1f mm across and %.2f mm thick (hand 0, laid at 0 ms), centred at %s mm, facing the tissue along %s "
                "(%.0f° from the axis): on the plane fitted to the sites (each within %.2f mm of it), lifted %.2f mm off it\n",
                plan.patch_diameter_mm, plan.patch_thickness_mm, point_text(plan.patch_centre).c_str(), point_text(plan.patch_facing, 2).c_str(),
                plan.patch_tilt_deg, plan.fit_residual_mm, 0.5 * plan.patch_thickness_mm);
    std::printf("  conduction  %s\n", conduction_text(plan, options).c_str());
    std::printf("  stitches    %zu on the circle %.1f mm from the axis (%.1f mm beyond the opening's edge), from its most %s point "
                "counter-clockwise as seen from the %s side; hand 1's needle (its shaft pointing away from the tissue) comes to each "
                "from %.0f mm outside in %.0f ms and ties it, held %.0f ms while it draws tight:\n",
                n, plan.stitch_radius_mm, options.rim_mm, plan.starts_anterior ? "anterior" : "superior",
                side_name, options.approach_mm, options.approach_ms, options.tie_ms);
    for (std::size_t k = 0; k < n; ++k) {
        const RepairStitch& s = plan.stitches[k];
        std::printf("    %2zu  %-24s mm  at %3.0f°, %+.1f mm from mid-wall, the wall %.1f mm thick there; tied at %.0f ms%s\n", k + 1,
                    point_text(s.site).c_str(), s.angle_deg, s.height_mm, s.wall_mm, s.tie_ms,
                    s.spares_zone ? ("; sparing the conduction zone: " + number_text(s.radius_mm - 0.5 * plan.defect_diameter_mm) +
                                     " mm beyond the edge, shallow")
                                        .c_str()
                                  : "");
    }
    std::printf("  gesture     %.0f ms: the patch laid at 0 ms, the stitches tied from %.0f to %.0f ms, then %.0f ms for the tissue to settle\n",
                plan.end_ms, plan.stitches.front().tie_ms, plan.stitches.back().tie_ms + options.tie_ms, options.settle_ms);
    // A tenth of a second past the gesture's end, as plan-incision.
    const double seconds = (std::floor(plan.end_ms / 100.0) + 1.0) / 10.0;
    std::printf("  wrote       %s (%zu keyframes)\n", a.output.c_str(), plan.trajectory.keyframes.size());
    std::printf("  run it      heartsim run %s --trajectory %s --seconds %.1f\n", a.scenario.c_str(), a.output.c_str(), seconds);
    // Close up on the patch and the opening: midway between the defect's centre and the patch's
    // (half a wall apart along the axis), the patch's diameter over two thirds of the picture's height.
    const Eigen::Vector3d middle = 0.5 * (plan.defect_centre + plan.patch_centre);
    const double distance = defect_view_distance(Camera{}, plan.patch_diameter_mm);
    std::printf("  see it      add --clip defect --look-at %.1f,%.1f,%.1f,%.1f (the section across the opening, the camera facing it "
                "%.0f mm away, the patch's %.1f mm over two thirds of the picture's height; headless with --screenshot repair.png): "
                "the patch on the septum's %s side, the stitches at its rim\n",
                middle.x(), middle.y(), middle.z(), distance, distance, plan.patch_diameter_mm, side_name);
    return 0;
}

}  // namespace heartsim
