/// @file operation_plan.h
/// @brief The operation through an incision (`heartsim plan-operation`, docs/runtime.md "Planning
/// an operation"): one trajectory that opens the approach's chamber over a septal defect, retracts
/// the opening until the defect is seen, carries the patch and the needle in through it and sews
/// the patch over the defect (runtime/surgery/repair_plan.h), then holds. World LPS mm (+x the
/// patient's left, +y posterior, +z superior).
///
/// **Where the incision goes.** From the defect's face on the right side (its centre moved half the
/// septum's thickness along the repair's outward direction), lines of sight are followed out of the
/// heart (libmodel/surgery/sight.h): through blood for at least 4 mm, then through one free wall at
/// most 15 mm thick, then out with no tissue within 150 mm. A line belongs to the approach when the
/// wall it leaves through is the approach chamber's:
/// * **right-atrial** (a right atriotomy; the defect is reached through the tricuspid valve): the
///   right atrium's wall where a material names it ("right atrium wall (grown)"); otherwise (one
///   blood pool, HVSMR 2016) a wall at least 10 mm above the defect's face that the line leaves
///   toward the patient's right (its x component the most negative of x and y).
/// * **right-ventricular** (a right ventriculotomy): the right ventricle's free wall where a
///   material names it; otherwise a wall no higher than 10 mm above the defect's face that the line
///   leaves anteriorly (its −y component the larger of −x and −y).
///
/// The incision runs across the line of sight, parallel to the coronary course that guards the
/// approach where the landmarks give it (the right coronary artery in the right atrioventricular
/// groove for the atriotomy, the left anterior descending artery for the ventriculotomy: surgeons
/// cut parallel to the vessel they must spare), else along the body's long axis; every point of the
/// incision stays `coronary_clearance_mm` from every coronary course. Among the lines left, the
/// plan takes the one from which the most stitch sites of the repair are seen through the opening
/// (Opening: the incision's length less 6 mm each end, the retraction's width less 2 mm each
/// side: a retracted slit opens as a lens, its edges' inner faces less than the grips); on a tie the
/// thinner wall (to the millimetre), then the shorter way through blood. The retraction's width is
/// 4 mm more than the narrowest of 10, 12, … 24 mm that shows as many sites as the widest
/// (the elastic wall between the grips and the edges gives a little), at most 24 mm.
///
/// **The trajectory.** Hand 0's scalpel cuts along the incision (0.1 mm/ms), its blade from 2 mm
/// above the wall's most outward face along the incision to 2 mm below its deepest inner face (no
/// nearer the septum than 2 mm short of its face on the line of sight), and is withdrawn. Hands 0
/// and 1 then take the incision's edges with retractors (kind retractor: the retracted edges stay
/// where the hands leave them, as stay sutures hold them) and pull them apart over 500 ms; the
/// defect is exposed when they reach their width. Then hand 0 carries the patch in from outside the
/// opening along the line of sight and lays it; hand 1 brings the needle in the same way and ties
/// the stitches (plan_repair's script, on the right side always: the only side reached through the
/// right heart). Where plan-repair's automatic side leaves the right for the left (the right rim too
/// rough for a flat patch to seal, the left's smooth: RepairPlanOptions::rough_rim_mm), no
/// operation through the right heart closes the defect, and the plan refuses, saying so. The
/// trajectory records the surgeon's view (Trajectory::view, the CSV's `# view:` line): `--view
/// surgeon --eye` the eye `--look-at` the defect's face, both to 0.1 mm, where `heartsim run`
/// opens without view options.
///
///     const OperationPlan plan = plan_operation(scenario, {.approach = OperationApproach::right_atrial});
///     write_trajectory_csv(plan.trajectory, "op.csv");
#pragma once

#include "formats/scenario.h"
#include "runtime/core/trajectory.h"
#include "runtime/surgery/repair_plan.h"

#include <Eigen/Core>

#include <array>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

enum class OperationApproach { right_atrial, right_ventricular };

/// "right-atrial" or "right-ventricular"; OptionError naming {OperationPlanOptions::approach} otherwise.
OperationApproach parse_operation_approach(const std::string& name);
const char* to_string(OperationApproach approach);

struct OperationPlanOptions {
    OperationApproach approach = OperationApproach::right_ventricular;
    double length_mm = 30.0;              ///< the incision's length
    double spread_mm = 0.0;               ///< the retraction's width; 0: the narrowest that shows the most sites
    double coronary_clearance_mm = 5.0;   ///< every point of the incision at least this far from a coronary course
    double max_wall_mm = 15.0;            ///< the thickest free wall a line of sight may cut through
    double eye_distance_mm = 0.0;         ///< the surgeon's eye from the opening; 0: 2.5 incision lengths (the picture's framing)
    RepairPlanOptions repair;             ///< the repair's (its side is always the right)
};

struct OperationPlan {
    Trajectory trajectory;  ///< the gesture, its view the surgeon's (eye and target to 0.1 mm)
    OperationApproach approach = OperationApproach::right_ventricular;
    RepairPlan repair;                                       ///< the repair's plan, before its time shift
    Eigen::Vector3d target = Eigen::Vector3d::Zero();        ///< the defect's face on the right side
    Eigen::Vector3d sight = Eigen::Vector3d::UnitZ();        ///< unit, from the defect out through the opening
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();        ///< the incision's centre, mid-wall
    Eigen::Vector3d exit = Eigen::Vector3d::Zero();          ///< where the line of sight leaves the heart
    Eigen::Vector3d cut = Eigen::Vector3d::UnitZ();          ///< unit, the incision's direction
    Eigen::Vector3d side = Eigen::Vector3d::UnitX();         ///< unit, across it: sight × cut
    Eigen::Vector3d eye = Eigen::Vector3d::Zero();           ///< the surgeon's eye
    std::string chamber_wall;        ///< the material the incision opens, or how the wall was told apart
    std::string cut_parallel_to;     ///< "the right coronary artery's course", "the body's long axis", …
    double wall_mm = 0.0;            ///< the wall's thickness along the line of sight
    double blood_mm = 0.0;           ///< the line's way through blood from the defect to the wall
    double length_mm = 0.0, spread_mm = 0.0;
    double blade_mm = 0.0;           ///< the scalpel's blade: through the wall all along the incision
    double coronary_mm = -1.0;       ///< the nearest coronary course from the incision; < 0: none known
    std::string coronary_name;       ///< which
    int sites_seen = 0;              ///< stitch sites seen from the eye through the opening (rest geometry)
    int sites = 0;
    int lines_found = 0, lines_tried = 0;
    double cut_end_ms = 0.0, grab_ms = 0.0, exposed_ms = 0.0, repair_start_ms = 0.0, end_ms = 0.0;
    std::array<Eigen::Vector3d, 2> grips{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    InstrumentKind retractor = InstrumentKind::retractor;    ///< the retractors' kind
};

/// The operation of `options.approach` on `scenario`'s septal defect. InputError where the
/// scenario has no defect or detailed mesh, the defect's right rim is too rough to seal from the
/// right (above), or no incision of the approach exists (saying which
/// tests the lines of sight failed, and what would work: the other approach, a smaller clearance).
OperationPlan plan_operation(const Scenario& scenario, const OperationPlanOptions& options = {});

/// `heartsim plan-operation SCENARIO -o OUT.csv --approach A|all`: plans, writes, prints. With
/// `all`, each approach's plan goes to OUT with the approach before its extension (op.csv:
/// op.right-atrial.csv), and a table compares them; an approach that has no incision is a row
/// saying why. 0 when at least one approach was planned.
struct PlanOperationArguments {
    std::string scenario, output;
    std::string approach = "right-ventricular";
    OperationPlanOptions options;
};
int plan_operation_command(const PlanOperationArguments& arguments);

}  // namespace heartsim
