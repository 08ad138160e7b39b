#include "runtime/surgery/operation_plan.h"

#include "formats/atomic_file.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/sight.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/surgery/plan_text.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>

namespace heartsim {
namespace {

/// "x, y, z" (the parentheses, where wanted, are the sentence's).
std::string point_text(const Eigen::Vector3d& p, int decimals = 1) { return plan_text::coordinates(p, decimals); }
std::string number_text(double value, int decimals = 1) { return plan_text::number(value, decimals); }

/// The coronary courses the landmarks give, each a polyline.
struct Course {
    std::string name, words;
    std::vector<Eigen::Vector3d> points;
};

std::vector<Course> coronary_courses(const Scenario& scenario) {
    std::vector<Course> courses;
    if (!scenario.landmarks) return courses;
    const std::pair<const char*, const char*> named[] = {{"rca_course", "the right coronary artery's course"},
                                                         {"lad_course", "the left anterior descending artery's course"},
                                                         {"lcx_course", "the circumflex artery's course"}};
    for (const auto& [name, words] : named)
        if (const Landmark* l = scenario.landmarks->find(name); l && l->points.size() >= 2) courses.push_back({name, words, l->points});
    return courses;
}

double segment_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double t = ab.squaredNorm() > 0 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
    return (p - (a + t * ab)).norm();
}

/// The nearest distance from the segment a–b (sampled every 0.5 mm) to the course.
double distance_to_course(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Course& course) {
    double best = std::numeric_limits<double>::infinity();
    const int n = std::max(1, int(std::ceil((b - a).norm() / 0.5)));
    for (int s = 0; s <= n; ++s) {
        const Eigen::Vector3d p = a + (double(s) / n) * (b - a);
        for (std::size_t k = 0; k + 1 < course.points.size(); ++k) best = std::min(best, segment_distance(p, course.points[k], course.points[k + 1]));
    }
    return best;
}

/// The direction of `course` nearest `point`.
Eigen::Vector3d course_direction_near(const Course& course, const Eigen::Vector3d& point) {
    std::size_t best = 0;
    double best_d = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k + 1 < course.points.size(); ++k)
        if (const double d = segment_distance(point, course.points[k], course.points[k + 1]); d < best_d) best_d = d, best = k;
    return (course.points[best + 1] - course.points[best]).normalized();
}

/// `v` with its component along `n` (unit) removed, unit; zero where nothing is left.
Eigen::Vector3d across(const Eigen::Vector3d& v, const Eigen::Vector3d& n) {
    const Eigen::Vector3d w = v - v.dot(n) * n;
    return w.norm() > 0.3 * v.norm() ? Eigen::Vector3d(w.normalized()) : Eigen::Vector3d::Zero();
}

/// One candidate incision on a line of sight.
struct Candidate {
    SightLine line;
    Eigen::Vector3d cut, side;
    std::string parallel_to;
    double coronary_mm = -1.0;
    std::string coronary_name;
    int seen = 0;
};

Opening opening_of(const Eigen::Vector3d& centre, const Candidate& c, double length_mm, double spread_mm) {
    Opening o;
    o.centre = centre;
    o.cut = c.cut, o.side = c.side, o.sight = c.line.direction;
    // A retracted slit opens as a lens: its ends hardly, its edges' inner faces less than the grips.
    o.half_length = std::max(0.0, 0.5 * length_mm - 6.0);
    o.half_width = std::max(0.0, 0.5 * spread_mm - 2.0);
    o.half_depth = 0.5 * c.line.wall_mm() + 1.0;
    return o;
}

int count_seen(const TissueOccupancy& tissue, const std::vector<RepairStitch>& stitches, const Eigen::Vector3d& eye, const Opening& opening) {
    int seen = 0;
    for (const RepairStitch& s : stitches) seen += seen_through(tissue, eye, s.site, opening, tissue.spacing()) ? 1 : 0;
    return seen;
}

const char* approach_words(OperationApproach a) {
    return a == OperationApproach::right_atrial ? "right atriotomy" : "right ventriculotomy";
}

}  // namespace

OperationApproach parse_operation_approach(const std::string& name) {
    if (name == "right-atrial") return OperationApproach::right_atrial;
    if (name == "right-ventricular") return OperationApproach::right_ventricular;
    throw OptionError("{OperationPlanOptions::approach} '" + name + "': expected right-atrial, right-ventricular or all");
}

const char* to_string(OperationApproach approach) {
    return approach == OperationApproach::right_atrial ? "right-atrial" : "right-ventricular";
}

OperationPlan plan_operation(const Scenario& scenario, const OperationPlanOptions& o) {
    if (!(o.length_mm > 6.0 && o.length_mm <= 120.0))
        throw OptionError("{OperationPlanOptions::length_mm} " + number_text(o.length_mm) + ": expected an incision above 6 mm and at most 120 mm long");
    if (o.spread_mm < 0.0 || o.spread_mm > 60.0)
        throw OptionError("{OperationPlanOptions::spread_mm} " + number_text(o.spread_mm) + ": expected a width of 0 (chosen) to 60 mm");
    if (!(o.coronary_clearance_mm >= 0.0 && o.coronary_clearance_mm <= 50.0))
        throw OptionError("{OperationPlanOptions::coronary_clearance_mm} " + number_text(o.coronary_clearance_mm) + ": expected 0 to 50 mm");
    if (!(o.max_wall_mm > 0.0 && o.max_wall_mm <= 60.0))
        throw OptionError("{OperationPlanOptions::max_wall_mm} " + number_text(o.max_wall_mm) + ": expected above 0 and at most 60 mm");
    if (!(o.eye_distance_mm >= 0.0 && o.eye_distance_mm <= 2000.0))
        throw OptionError("{OperationPlanOptions::eye_distance_mm} " + number_text(o.eye_distance_mm) + ": expected 0 (2.5 incision lengths) to 2000 mm");
    OperationPlan plan;
    plan.approach = o.approach;
    // The repair through the right heart: its side the right, unless plan-repair's automatic side
    // finds the right rim too rough for a flat patch to seal and the left's smooth.
    RepairPlanOptions repair_options = o.repair;
    repair_options.side = RepairSide::automatic;
    plan.repair = plan_repair(scenario, repair_options);
    if (!plan.repair.on_right)
        throw InputError("no operation through the right heart closes this defect: " + plan.repair.side_reason +
                         "; no right-heart incision reaches the left side (heartsim plan-repair CASE -o repair.csv closes it there); "
                         "--rough-rim " + number_text(std::ceil(plan.repair.right_residual_mm + 0.5), 0) +
                         " plans the operation through the right heart anyway, its patch on the rough rim");
    const RepairPlan& repair = plan.repair;
    const auto& rest = scenario.lattice.particles.rest_position;
    const double spacing = scenario.lattice.spacing;
    plan.target = repair.defect_centre + (0.5 * repair.wall_mm) * repair.outward;
    const TissueOccupancy tissue(rest, spacing);

    const bool atrial = o.approach == OperationApproach::right_atrial;
    std::string wall_name;
    const std::vector<std::uint8_t> wall =
        chamber_wall_particles(scenario, atrial ? IncisionApproach::atriotomy : IncisionApproach::ventriculotomy, &wall_name);
    const bool named = std::any_of(wall.begin(), wall.end(), [](std::uint8_t f) { return f != 0; });
    plan.chamber_wall = named ? "'" + wall_name + "'"
                              : atrial ? std::string("no tissue is named for the right atrium: a wall 10 mm or more above the defect, facing the patient's right")
                                       : std::string("no tissue is named for the right ventricle: a wall below 10 mm above the defect, facing anterior");
    const Eigen::Vector3d target = plan.target;
    SightOptions sight;
    sight.target = target, sight.outward = repair.outward, sight.max_wall_mm = o.max_wall_mm;
    sight.accepts = [&](int particle, const SightLine& line) {
        if (named) return particle >= 0 && wall[std::size_t(particle)] != 0;
        const Eigen::Vector3d exit = line.exit(target), d = line.direction;
        const double above = exit.z() - target.z();
        if (atrial) return above >= 10.0 && -d.x() >= -d.y() && d.x() < 0.0;
        return above < 10.0 && -d.y() >= -d.x() && d.y() < 0.0;
    };
    const SightLines lines = sight_lines(tissue, sight);
    plan.lines_found = int(lines.lines.size());
    plan.lines_tried = lines.tried;
    const std::string other = atrial ? "right-ventricular" : "right-atrial";
    if (lines.lines.empty())
        throw InputError("no incision for a " + std::string(approach_words(o.approach)) + " over the defect: of the " + std::to_string(lines.tried) +
                         " lines of sight from its face at (" + point_text(target) + ") mm within 80° of the right side's outward direction (" +
                         point_text(repair.outward, 2) + "), " + std::to_string(lines.no_blood) + " met tissue within 4 mm, " +
                         std::to_string(lines.thick_wall) + " crossed a wall thicker than " + number_text(o.max_wall_mm) + " mm, " +
                         std::to_string(lines.more_tissue) + " met tissue again beyond the first wall, " + std::to_string(lines.never_out) +
                         " met no wall, and " + std::to_string(lines.not_accepted) + " left through a wall that is not the approach's (" +
                         plan.chamber_wall + "); try --approach " + other + (o.max_wall_mm < 30.0 ? " or a larger --max-wall" : ""));

    // Each line's incision: its direction, its distance from the coronary courses, the sites seen.
    const std::vector<Course> courses = coronary_courses(scenario);
    const Course* guard = nullptr;
    for (const Course& c : courses)
        if (c.name == (atrial ? "rca_course" : "lad_course")) guard = &c;
    const double eye_distance = o.eye_distance_mm > 0 ? o.eye_distance_mm : 2.5 * o.length_mm;
    std::vector<Candidate> candidates;
    double nearest_refused = std::numeric_limits<double>::infinity();
    std::string nearest_refused_name;
    for (const SightLine& line : lines.lines) {
        Candidate c;
        c.line = line;
        const Eigen::Vector3d exit = line.exit(target), blade = -line.direction;
        c.cut = guard ? across(course_direction_near(*guard, exit), line.direction) : Eigen::Vector3d::Zero();
        c.parallel_to = guard ? guard->words : "";
        if (c.cut.isZero()) {
            c.cut = across(Eigen::Vector3d::UnitZ(), line.direction);
            c.parallel_to = "the body's long axis";
            if (c.cut.isZero()) c.cut = across(Eigen::Vector3d::UnitX(), line.direction), c.parallel_to = "the body's left-right axis";
        }
        if (c.cut.z() < 0.0) c.cut = -c.cut;  // drawn upward, as plan-incision's
        c.side = blade.cross(c.cut).normalized();
        const Eigen::Vector3d a = exit - (0.5 * o.length_mm) * c.cut, b = exit + (0.5 * o.length_mm) * c.cut;
        double nearest = std::numeric_limits<double>::infinity();
        for (const Course& course : courses)
            if (const double d = distance_to_course(a, b, course); d < nearest) nearest = d, c.coronary_name = course.words;
        c.coronary_mm = courses.empty() ? -1.0 : nearest;
        if (!courses.empty() && nearest < o.coronary_clearance_mm) {
            if (nearest < nearest_refused || nearest_refused_name.empty()) nearest_refused = nearest, nearest_refused_name = c.coronary_name;
            continue;
        }
        c.seen = count_seen(tissue, repair.stitches, exit + eye_distance * line.direction,
                            opening_of(line.wall_middle(target), c, o.length_mm, o.spread_mm > 0 ? o.spread_mm : 24.0));
        candidates.push_back(c);
    }
    if (candidates.empty())
        throw InputError("no incision for a " + std::string(approach_words(o.approach)) + " over the defect keeps " +
                         number_text(o.coronary_clearance_mm) + " mm from the coronary courses: each of the " + std::to_string(lines.lines.size()) +
                         " lines of sight through the approach's wall would put the " + number_text(o.length_mm, 0) +
                         " mm incision within that of one (" + nearest_refused_name + "); a shorter --length, a smaller --coronary-clearance, or "
                         "--approach " + other);
    const Candidate& best = *std::max_element(candidates.begin(), candidates.end(), [](const Candidate& x, const Candidate& y) {
        if (x.seen != y.seen) return x.seen < y.seen;
        // On a tie, the thinner wall (to the millimetre: less tissue cut), then the shorter way through blood.
        if (std::round(x.line.wall_mm()) != std::round(y.line.wall_mm())) return std::round(x.line.wall_mm()) > std::round(y.line.wall_mm());
        return x.line.wall_in_mm > y.line.wall_in_mm;
    });
    plan.sight = best.line.direction;
    plan.exit = best.line.exit(target);
    plan.centre = best.line.wall_middle(target);
    plan.cut = best.cut, plan.side = best.side;
    plan.cut_parallel_to = best.parallel_to;
    plan.wall_mm = best.line.wall_mm();
    plan.blood_mm = best.line.wall_in_mm;
    plan.coronary_mm = best.coronary_mm;
    plan.coronary_name = best.coronary_name;
    plan.length_mm = o.length_mm;
    plan.eye = plan.exit + eye_distance * plan.sight;
    plan.sites = int(repair.stitches.size());
    if (o.spread_mm > 0) {
        plan.spread_mm = o.spread_mm;
        plan.sites_seen = best.seen;
    } else {
        // The narrowest width that shows as many sites as the widest (from 10 mm: a narrower retraction
        // of a wall some millimetres thick leaves a slit).
        const int most = count_seen(tissue, repair.stitches, plan.eye, opening_of(plan.centre, best, o.length_mm, 24.0));
        for (double w = 10.0; w <= 24.0; w += 2.0)
            if (const int seen = count_seen(tissue, repair.stitches, plan.eye, opening_of(plan.centre, best, o.length_mm, w)); seen >= most) {
                // 4 mm more: the elastic wall between the grips and the edges gives a little.
                plan.spread_mm = std::min(24.0, w + 4.0);
                plan.sites_seen = count_seen(tissue, repair.stitches, plan.eye, opening_of(plan.centre, best, o.length_mm, plan.spread_mm));
                break;
            }
    }

    // The trajectory.
    Trajectory& script = plan.trajectory;
    const Eigen::Vector3d blade = -plan.sight;
    Eigen::Matrix3d frame;
    frame.col(0) = plan.cut, frame.col(1) = plan.side, frame.col(2) = blade;
    const Eigen::Quaterniond orientation = Eigen::Quaterniond(frame).normalized();
    // The blade reaches through the wall all along the incision: from 2 mm above its most outward
    // face to 2 mm below its deepest inner face (the wall curves away from the line of sight's
    // plane), but no nearer the septum than 2 mm short of its face on the line.
    double outer = 0.0, inner = plan.wall_mm;
    for (double t = -0.5 * o.length_mm; t <= 0.5 * o.length_mm + 1e-9; t += 1.0) {
        const Eigen::Vector3d q = plan.exit + t * plan.cut + 10.0 * plan.sight;
        const std::vector<SightSpan> spans = tissue_along(tissue, q, q - (10.0 + plan.wall_mm + plan.blood_mm) * plan.sight);
        if (spans.empty()) continue;
        outer = std::max(outer, 10.0 - spans.front().from);
        inner = std::max(inner, spans.front().to - 10.0 + 0.25 * spacing);
    }
    inner = std::min(inner, plan.wall_mm + plan.blood_mm - 2.0);
    const double clearance = 2.0, speed = 0.1;
    const double blade_length = outer + clearance + inner + 2.0;
    plan.blade_mm = blade_length;
    const Eigen::Vector3d blade_axes(2.0, 0.3, 0.5 * blade_length);
    const Eigen::Vector3d tip = plan.exit + (outer + clearance) * plan.sight, half = (0.5 * o.length_mm) * plan.cut;
    plan.cut_end_ms = o.length_mm / speed;
    script.add(0.0, 0, InstrumentKind::scalpel, tip - half, orientation, blade_axes, true);
    script.add(plan.cut_end_ms, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, true);
    script.add(plan.cut_end_ms + 1e-3, 0, InstrumentKind::scalpel, tip + half, orientation, blade_axes, false);
    script.add(plan.cut_end_ms + 25.0, 0, InstrumentKind::scalpel, tip + half + 10.0 * plan.sight, orientation, blade_axes, false);

    // Retractors: each an ellipsoid along the edge (a quarter of the incision long), 1.2 spacings
    // across, through the wall's depth, its inner side a quarter spacing from the blade's plane;
    // pulled apart and 2 mm out toward the surgeon.
    plan.retractor = InstrumentKind::retractor;
    const double across_mm = 1.2 * spacing, offset = across_mm + 0.25 * spacing;
    const Eigen::Vector3d retractor_axes(0.25 * o.length_mm, across_mm, 0.5 * plan.wall_mm + 0.5 * spacing);
    plan.grab_ms = plan.cut_end_ms + 50.0;
    plan.exposed_ms = plan.grab_ms + 500.0;
    plan.repair_start_ms = plan.exposed_ms + 200.0;
    for (int hand = 0; hand < 2; ++hand) {
        const double s = hand == 0 ? -1.0 : 1.0;
        const Eigen::Vector3d grip = plan.centre + (s * offset) * plan.side;
        plan.grips[std::size_t(hand)] = grip;
        const Eigen::Vector3d pulled = grip + (s * 0.5 * plan.spread_mm) * plan.side + 2.0 * plan.sight;
        if (hand == 1) script.add(0.0, 1, InstrumentKind::none, plan.eye, orientation, retractor_axes, false);
        script.add(plan.grab_ms, hand, plan.retractor, grip, orientation, retractor_axes, true);
        script.add(plan.exposed_ms, hand, plan.retractor, pulled, orientation, retractor_axes, true);
        script.add(plan.repair_start_ms, hand, plan.retractor, pulled, orientation, retractor_axes, true);
    }

    // The repair, carried in through the opening: the patch and the needle from outside it along
    // the line of sight, then plan_repair's script from the patch's laying on.
    const double carry_ms = 400.0;
    const double lay_ms = plan.repair_start_ms + carry_ms + 1.0;
    const Eigen::Vector3d outside = plan.exit + 20.0 * plan.sight;
    const Eigen::Vector3d patch_axes(0.5 * repair.patch_diameter_mm, 0.5 * repair.patch_diameter_mm, 0.5 * repair.patch_thickness_mm);
    script.add(plan.repair_start_ms + 1.0, 0, InstrumentKind::patch, outside, repair.patch_orientation, patch_axes, false);
    script.add(plan.repair_start_ms + 1.0, 1, InstrumentKind::needle, outside, repair.needle_orientation, o.repair.needle_semi_axes, false);
    for (InstrumentKeyframe k : repair.trajectory.keyframes) {
        if (k.hand == 1 && k.kind == InstrumentKind::none) continue;  // the needle waits outside the opening instead
        k.time_ms += lay_ms;
        plan.trajectory.keyframes.push_back(k);
    }
    plan.end_ms = lay_ms + repair.end_ms;
    script.sort_by_time();
    // The view the run starts from (the CSV's `# view:` line): the surgeon's, from the eye into the
    // opening, as the points print (0.1 mm), so that the printed options and the file agree.
    script.view = parse_view_options("--view surgeon --eye " + plan_text::option_point(plan.eye) + " --look-at " +
                                     plan_text::option_point(plan.target));
    return plan;
}

namespace {

/// OUT.csv → OUT.APPROACH.csv.
std::string output_for(const std::string& output, OperationApproach approach) {
    const std::filesystem::path p(output);
    return (p.parent_path() / (p.stem().string() + "." + to_string(approach) + p.extension().string())).string();
}

void print_plan(const OperationPlan& plan, const std::string& scenario, const std::string& output, const OperationPlanOptions& o) {
    std::printf("plan-operation: a %s (--approach %s) to close the %s on %s\n", approach_words(plan.approach), to_string(plan.approach),
                plan.repair.defect.c_str(), scenario.c_str());
    std::printf("  defect      %.1f mm across; its right face at (%s) mm, the septum %.1f mm thick there\n", plan.repair.defect_diameter_mm,
                point_text(plan.target).c_str(), plan.repair.wall_mm);
    std::printf("  sight       %d of %d lines of sight from that face leave the heart through the approach's wall (%s); the chosen one "
                "goes %.1f mm through blood along (%s), then through the %.1f mm wall, out at (%s) mm\n",
                plan.lines_found, plan.lines_tried, plan.chamber_wall.c_str(), plan.blood_mm, point_text(plan.sight, 2).c_str(), plan.wall_mm,
                point_text(plan.exit).c_str());
    std::printf("  incision    %.0f mm along (%s), parallel to %s, centred at (%s) mm; the scalpel (hand 0), its blade "
                "%.1f mm long (through the wall all along the incision and 2 mm on), cuts from 0 to %.0f ms, then is withdrawn\n",
                plan.length_mm, point_text(plan.cut, 2).c_str(), plan.cut_parallel_to.c_str(), point_text(plan.exit).c_str(), plan.blade_mm,
                plan.cut_end_ms);
    if (plan.coronary_mm >= 0)
        std::printf("  coronaries  the nearest course, %s, is %.1f mm from the incision (at least %.1f mm asked)\n", plan.coronary_name.c_str(),
                    plan.coronary_mm, o.coronary_clearance_mm);
    else
        std::printf("  coronaries  not known: the scenario's landmarks give no coronary course (its label map does not tell the chambers apart)\n");
    std::printf("  retraction  two retractors (hands 0 and 1) take the edges at %.0f ms and pull them %.0f mm apart by %.0f ms, then hold; "
                "when the hands take the patch and the needle at %.0f ms, the edges stay where they were left (stay sutures)\n",
                plan.grab_ms, plan.spread_mm, plan.exposed_ms, plan.repair_start_ms);
    std::printf("  surgeon's eye: %s mm\n", point_text(plan.eye).c_str());
    std::printf("  defect exposed at: %.2f s\n", plan.exposed_ms / 1000.0);
    std::printf("  rim seen    %d of %d stitch sites seen from the eye through the %.0f mm wide opening (at rest, the opening's wall taken away)\n",
                plan.sites_seen, plan.sites, plan.spread_mm);
    std::printf("  repair      from %.0f ms: the patch (hand 0) and the needle (hand 1) carried in from 20 mm outside the opening; the patch "
                "laid at %.0f ms on the septum's right side, %zu stitches; the gesture ends at %.0f ms\n",
                plan.repair_start_ms, plan.repair_start_ms + 401.0, plan.repair.stitches.size(), plan.end_ms);
    const double seconds = (std::floor(plan.end_ms / 100.0) + 1.0) / 10.0;
    std::printf("  wrote       %s (%zu keyframes)\n", output.c_str(), plan.trajectory.keyframes.size());
    std::printf("  run it      heartsim run %s --trajectory %s --seconds %.1f\n", scenario.c_str(), output.c_str(), seconds);
    std::printf("  see it      the run's window and screenshots open from the surgeon's eye into the opening, the view the file "
                "records (%s; --view, --eye or --look-at choose another); the exposure alone: --seconds %.2f\n",
                view_options(*plan.trajectory.view).c_str(), plan.exposed_ms / 1000.0);
}

}  // namespace

int plan_operation_command(const PlanOperationArguments& a) {
    const bool all = a.approach == "all";
    std::vector<OperationApproach> approaches;
    if (all) approaches = {OperationApproach::right_atrial, OperationApproach::right_ventricular};
    else approaches = {parse_operation_approach(a.approach)};
    for (OperationApproach approach : approaches) {
        const std::string out = all ? output_for(a.output, approach) : a.output;
        refuse_an_input_as_output("-o " + out, out, {{a.scenario, "the scenario being planned"}});
        check_destination(out);
    }
    const Scenario scenario = read_scenario(a.scenario);
    struct Row {
        OperationApproach approach;
        std::optional<OperationPlan> plan;
        std::string refusal;
    };
    std::vector<Row> rows;
    for (OperationApproach approach : approaches) {
        OperationPlanOptions options = a.options;
        options.approach = approach;
        const std::string out = all ? output_for(a.output, approach) : a.output;
        Row row{approach, std::nullopt, ""};
        try {
            row.plan = plan_operation(scenario, options);
        } catch (const OptionError&) {
            throw;
        } catch (const InputError& e) {
            if (!all) throw;
            row.refusal = e.what();
        }
        if (row.plan) {
            check_planned_trajectory(row.plan->trajectory);
            write_trajectory_csv(row.plan->trajectory, out,
                                 "# heartsim plan-operation " + std::filesystem::path(a.scenario).filename().string() + ": a " +
                                     approach_words(approach) + ", the defect exposed, a patch sewn over it through the opening\n");
            print_plan(*row.plan, a.scenario, out, options);
        } else {
            std::printf("plan-operation: no %s (--approach %s) on %s: %s\n", approach_words(approach), to_string(approach), a.scenario.c_str(),
                        row.refusal.c_str());
        }
        rows.push_back(std::move(row));
    }
    if (!all) return 0;
    std::printf("\n| approach | incision, mm | wall cut, mm (area, mm²) | nearest coronary course, mm | way through blood, mm | stitch sites seen | opening, mm |\n");
    std::printf("|---|---|---|---|---|---|---|\n");
    for (const Row& row : rows) {
        if (!row.plan) {
            std::printf("| %s | no incision: %s | | | | | |\n", to_string(row.approach), row.refusal.c_str());
            continue;
        }
        const OperationPlan& p = *row.plan;
        std::printf("| %s | %.0f | %.1f (%.0f) | %s | %.1f | %d of %d | %.0f |\n", to_string(p.approach), p.length_mm, p.wall_mm, p.length_mm * p.wall_mm,
                    p.coronary_mm >= 0 ? number_text(p.coronary_mm).c_str() : "not known", p.blood_mm, p.sites_seen, p.sites, p.spread_mm);
    }
    const bool any = std::any_of(rows.begin(), rows.end(), [](const Row& r) { return r.plan.has_value(); });
    if (!any) throw InputError("no approach has an incision over the defect (each row above says why)");
    return 0;
}

}  // namespace heartsim
