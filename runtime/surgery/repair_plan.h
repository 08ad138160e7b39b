/// @file repair_plan.h
/// @brief A scripted closure of a septal defect (`heartsim plan-repair`, docs/runtime.md "Planning
/// a repair"): a patch (hand 0) laid over the opening on one side of the septum, then a needle
/// (hand 1) ties stitches one by one around the opening's rim, each joining the patch to the wall.
///
/// The defect is the one `heartprep build --defect` stores in /source: its centre (mid-wall), axis
/// (unit, from side a's pool to side b's) and diameter D. The geometry is found on the detailed
/// mesh at rest (/visual, a closed surface with outward normals), world LPS (+x the patient's
/// left, +y posterior, +z superior), by libmodel/surgery/surgery_site.h (the stitch circle, the sites, the
/// patch's plane); this plan chooses the side, refuses what it cannot plan and scripts the hands:
///
/// * **side**: by default the right side (the right ventricle's for a vsd, the right atrium's for
///   an asd: surgeons close both through the right heart). A scenario does not store which pool is
///   which, so the right side is the one whose outward direction (−axis for side a, +axis for side
///   b) has the larger dot product with the patient's right-anterior direction (−1, −1, 0)/√2.
///   `outward` below is that side's direction.
/// * **stitch sites**: `stitches` points (by default one every `stitch_spacing_mm`, 3 mm, along
///   that circle: under pressure a patch lifts off the rim between stitches farther apart) evenly
///   spaced on the circle of radius D/2 + `rim_mm`
///   around the axis, in the plane through the centre across it; stitch 1 at the circle's most
///   superior point (most anterior where the axis is within 25° of superior-inferior), the others
///   following counter-clockwise as seen from the chosen side (those in a conduction zone farther
///   out: below). Each site is where the line through
///   its point along the axis, followed from far outside along −outward, first enters the tissue
///   within T + 3 mm of the centre (T the wall's thickness there: below). The line crosses the
///   pool on the chosen side first, so the free wall beyond the pool (and anything farther than
///   T + 3 mm along the axis) is passed over.
/// * **wall thickness T**: on each stitch's line, the stretch inside the tissue that holds the
///   centre's plane (mid-wall) is the septum there; T is the median of those stretches' lengths.
///   Each stitch then reports the length of the stretch that begins at its site.
/// * **patch**: a disc of diameter `patch_diameter_mm` (default D + 2·(rim + 2 mm): 2 mm beyond
///   the stitches; D + 2·(zone_rim + 2 mm) where stitches moved out of a conduction zone) and thickness `thickness_mm`, facing the plane fitted to the sites by least
///   squares (its normal oriented along −outward: the way the patch faces the tissue), centred
///   on the axis, half its thickness off that plane on the chosen side (from where the axis meets
///   the plane, along the axis).
///   Its first in-plane axis (tool +x) points toward stitch 1.
/// * **conduction zone** (a vsd, `conduction_zone` automatic, the default): where the scenario's
///   tricuspid and aortic rings lie near the defect's rim, the defect is perimembranous and the
///   posteroinferior arc of its rim carries the atrioventricular conduction axis
///   (libmodel/surgery/conduction_zone.h, its rule and anatomy). Every stitch whose circle point
///   lies within that arc, or within `zone_margin_deg` beyond it, moves out along its direction to
///   D/2 + `zone_rim_mm` (4.5 mm by default: beyond the zone's band of `zone.band_mm`, 3 mm, as a
///   surgeon bites 3 to 5 mm back from the edge there), and is marked shallow. The model anchors
///   every stitch at the tissue's surface point nearest the needle's tip (libmodel/surgery/patch.h
///   PatchModel::tie): a bite's depth is not modelled, and "shallow" says only what the plan does,
///   which is what it does for every stitch: the needle's tip goes to the surface site on the
///   chosen side and no deeper. The stitches keep their count and angles; those moved lie farther
///   apart. Where rim_mm already reaches zone_rim_mm, none moves. Without the rings (HVSMR 2016's hearts), for an asd, or with `conduction_zone` off, no
///   stitch moves, and the plan says why.
///
/// The trajectory (runtime/core/trajectory.h; semi-axes and kinds as libmodel/sim/solver.h describes them):
/// hand 0 lays the patch at 0 ms (kind patch, grab 1) and lets go at `release_ms` (grab 0: a laid
/// patch stays). Hand 1, a needle whose shaft points outward (tool +z = outward), then ties the
/// stitches in order: from `approach_mm` outside a site to the site in `approach_ms`, grab 1 held
/// `tie_ms` (the stitch draws tight meanwhile), grab 0, then in `withdraw_ms` straight back out
/// to the point `approach_mm` outside the site (half of it) and across to the one outside the next
/// site (the other half; after the last: outside its own), and a final hold of `settle_ms` for the
/// tissue to settle.
///
///     const RepairPlan plan = plan_repair(scenario, {.stitches = 10});
///     write_repair_csv(plan, "repair.csv");   // for `heartsim run --trajectory`
#pragma once

#include "formats/scenario.h"
#include "libmodel/surgery/conduction_zone.h"
#include "runtime/core/trajectory.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <filesystem>
#include <string>
#include <vector>

namespace heartsim {

/// Which side of the septum the patch goes on: the right or left heart's (by the right-anterior
/// rule above), or the pool at the axis's tail (a) or head (b); automatic: the right, unless its
/// rim is too rough for a patch to lie on and the left's is not (RepairPlanOptions::rough_rim_mm).
enum class RepairSide { automatic, right, left, a, b };

/// "auto", "right", "left", "a" or "b"; OptionError naming {RepairPlanOptions::side} otherwise.
RepairSide parse_repair_side(const std::string& name);
const char* to_string(RepairSide side);

/// Whether a plan marks a perimembranous defect's conduction zone and spares it (automatic), or
/// leaves every stitch on the one circle (off).
enum class ConductionZoneMode { automatic, off };

/// "auto" or "off"; OptionError naming {RepairPlanOptions::conduction_zone} otherwise.
ConductionZoneMode parse_conduction_zone_mode(const std::string& name);
const char* to_string(ConductionZoneMode mode);

struct RepairPlanOptions {
    RepairSide side = RepairSide::automatic;
    /// The automatic side leaves the right for the left where the right's rim lies farther than
    /// this from a plane and the left's does not (each rim sampled where 36 lines along the axis,
    /// one every 10° round the stitches' circle, those in a conduction zone at its distance, enter
    /// the tissue, found as stitch sites are): a
    /// rim among the right ventricle's trabeculations, with recesses between stitches deeper than a
    /// flat patch follows (surgeons close such muscular defects from the left, whose septal face is
    /// smooth). 4 mm lies between the real hearts' right rims that a patch seals (up to 3.5 mm off a
    /// plane) and pat0's, which it does not (6.1 mm).
    double rough_rim_mm = 4.0;
    /// How many stitches around the rim, at least 3; 0: one every `stitch_spacing_mm` along the
    /// stitches' circle, at least 8 (15 round a 10 mm defect with a 2 mm rim; a surgeon's 10 to 16).
    int stitches = 0;
    double stitch_spacing_mm = 3.0;
    double rim_mm = 2.0;              ///< the stitches' distance beyond the opening's edge (radius D/2 + rim), mm
    double patch_diameter_mm = 0.0;   ///< 0: D + 2·(rim_mm + 2 mm), 2 mm beyond the stitches; else larger than D + 2·rim_mm
    double thickness_mm = 0.5;        ///< the patch's thickness, mm
    double release_ms = 20.0;         ///< hand 0 lets go of the laid patch, ms
    double approach_mm = 4.0;         ///< the needle comes to each site from this far outside it, mm
    double approach_ms = 40.0;        ///< from there to the site, ms
    double tie_ms = 150.0;            ///< grab held at the site while the stitch draws tight, ms
    double withdraw_ms = 30.0;        ///< from the site out and across to the point outside the next site, ms
    double settle_ms = 300.0;         ///< the hold after the last stitch, ms
    Eigen::Vector3d needle_semi_axes{0.25, 0.25, 6.0};  ///< the needle's ellipsoid: shaft 2·az long from the tip, mm
    ConductionZoneMode conduction_zone = ConductionZoneMode::automatic;
    ConductionZoneOptions zone;       ///< the zone's rule: the rings' reach, its band and arc
    /// The stitches in the zone lie this far beyond the opening's edge, mm; more than zone.band_mm.
    /// Where rim_mm reaches as far, no stitch moves.
    double zone_rim_mm = 4.5;
    /// A stitch this far beyond the arc moves too, degrees: a bite a little off its site still
    /// spares the zone.
    double zone_margin_deg = 10.0;
};

struct RepairStitch {
    Eigen::Vector3d site = Eigen::Vector3d::Zero();     ///< on the wall's surface, LPS mm
    Eigen::Vector3d outside = Eigen::Vector3d::Zero();  ///< approach_mm outward of the site
    double angle_deg = 0.0;   ///< around the axis from stitch 1, counter-clockwise seen from the chosen side
    double height_mm = 0.0;   ///< the site's distance from the defect's centre along outward
    double wall_mm = 0.0;     ///< the tissue's thickness along the axis from the site
    double tie_ms = 0.0;      ///< the needle's grab turns 1 here
    double radius_mm = 0.0;   ///< its line's distance from the axis: D/2 + rim, or D/2 + zone_rim when spared
    /// Moved out of the conduction zone to D/2 + zone_rim, shallow (RepairPlanOptions::zone_rim_mm).
    bool spares_zone = false;
    /// Its point at D/2 + rim would lie in the zone (ConductionZone::holds): what it would bite
    /// with the zone off.
    bool would_bite_zone = false;
};

struct RepairPlan {
    Trajectory trajectory;
    std::string defect;                                     ///< "vsd" or "asd"
    double defect_diameter_mm = 0.0;
    Eigen::Vector3d defect_centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d defect_axis = Eigen::Vector3d::UnitZ();
    RepairSide side = RepairSide::right;                    ///< as asked
    /// With the automatic side: the right rim's distance from a plane and the left's (36 lines;
    /// NaN where one meets no wall), and why the side was chosen.
    double right_residual_mm = 0.0, left_residual_mm = 0.0;
    std::string side_reason;
    bool on_b = false;                                      ///< the patch is on side b (outward = +axis), else on side a (−axis)
    bool on_right = false;                                  ///< that side is the right-anterior one
    Eigen::Vector3d outward = Eigen::Vector3d::UnitZ();     ///< unit, from the septum into the chosen side's pool
    /// Each side's outward direction dotted with (−1, −1, 0)/√2: the right side has the larger.
    double right_anterior_a = 0.0, right_anterior_b = 0.0;
    double wall_mm = 0.0;                                   ///< T, the median septal thickness along the axis at the stitches
    double wall_min_mm = 0.0, wall_max_mm = 0.0;            ///< over the stitches (RepairStitch::wall_mm)
    double stitch_radius_mm = 0.0;                          ///< D/2 + rim
    /// The conduction zone (a perimembranous vsd's; found false with the reason otherwise, and
    /// where conduction_zone is off: "--conduction-zone off").
    ConductionZone zone;
    double zone_radius_mm = 0.0;                            ///< D/2 + zone_rim: where the spared stitches lie; 0 without a zone
    /// The zone's middle round the axis, as the stitches' angles are measured (from stitch 1,
    /// counter-clockwise seen from the chosen side), degrees in [0, 360); 0 without a zone.
    double zone_angle_deg = 0.0;
    /// Stitch 1 sits at the circle's most anterior point (the axis within 25° of superior-inferior),
    /// else at its most superior.
    bool starts_anterior = false;
    std::vector<RepairStitch> stitches;
    Eigen::Vector3d patch_centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d patch_facing = Eigen::Vector3d::UnitZ();  ///< unit, tool +z: toward the tissue
    Eigen::Quaterniond patch_orientation = Eigen::Quaterniond::Identity();
    double patch_diameter_mm = 0.0, patch_thickness_mm = 0.0;
    double patch_tilt_deg = 0.0;      ///< the angle between patch_facing and −outward
    double fit_residual_mm = 0.0;     ///< the largest distance of a site from the fitted plane
    Eigen::Quaterniond needle_orientation = Eigen::Quaterniond::Identity();  ///< tool +z = outward
    double end_ms = 0.0;              ///< the gesture's end (after the settling hold)
};

/// The conduction zone of `scenario`'s defect by `options` (libmodel/surgery/conduction_zone.h):
/// found false, with the reason, for a scenario with no defect, a defect other than a vsd, or no
/// /landmarks stored.
ConductionZone scenario_conduction_zone(const Scenario& scenario, const ConductionZoneOptions& options = {});

/// The repair of `scenario`'s septal defect. Throws OptionError for stitches below 3, a rim,
/// thickness or patch diameter not above 0, a zone rim not beyond the zone's band, or
/// a patch that does not reach beyond the stitches;
/// InputError when the scenario has no defect, no detailed mesh, or a stitch's line meets no wall
/// near the defect (naming the stitch and its point).
RepairPlan plan_repair(const Scenario& scenario, const RepairPlanOptions& options = {});

/// The plan's trajectory as a CSV that `heartsim run --trajectory` reads (runtime/core/trajectory.h),
/// its first lines `#` comments saying what it is and from which scenario. OutputError when the
/// file cannot be written.
void write_repair_csv(const RepairPlan& plan, const std::filesystem::path& path, const std::string& scenario_name = "");

/// `heartsim plan-repair SCENARIO -o OUT.csv …`: reads the scenario, plans, writes the CSV and
/// prints what it planned and how to play it. 0.
struct PlanRepairArguments {
    std::string scenario, output;
    std::string side = "auto";
    std::string conduction_zone = "auto";
    RepairPlanOptions options;
};
int plan_repair_command(const PlanRepairArguments& arguments);

}  // namespace heartsim
