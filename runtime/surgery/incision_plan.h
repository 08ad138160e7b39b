/// @file incision_plan.h
/// @brief A scripted incision planned on a scenario's particles (`heartsim plan-incision`,
/// docs/runtime.md "Planning an incision"): a scalpel lowered onto the heart's surface and drawn
/// `length_mm` from inferior to superior, then lifted; two grabbers used as retractors grab the
/// incision's two edges, one each side of the blade's plane, and pull them `spread_mm` apart, then
/// hold. Each approach finds its place by a geometric rule on the particles' rest positions (world
/// LPS: +x the patient's left, +y posterior, +z superior; libmodel/surgery/surgery_site.h incision_site),
/// on the approach chamber's own wall where the scenario tells it apart: the tissue whose material
/// is named for the right ventricle or the right atrium (a wall heartprep grew around that
/// chamber's blood, "right atrium wall (grown)", or one a label map labels and names so). Where no
/// material names it (HVSMR 2016's one blood pool, a build of the labels as they are), the rule
/// runs on the whole heart, as below.
///
/// * **ventriculotomy** (a right ventriculotomy through the most anterior wall): the most anterior
///   particle (smallest y) of the middle third (in z) of the model, the free wall in front rather
///   than an apex or a vessel stump at the model's ends; the blade points posterior (+y).
///   On the right ventricle's wall: its most anterior particle in the model's middle third.
/// * **atriotomy** (a right atriotomy on the right atrium's free wall): in the upper half (in z) of
///   the model, among its anterior two thirds (in y), where the right atrium sits (right, superior
///   and anterior-lateral, clear of the venae cavae behind it), the most rightward surface particle
///   (smallest x) around which the right surface holds the whole incision: along the stroke and
///   on the retractors' columns it lies within the blade's reach (so the cut stays on a continuous
///   wall, off the rim of an opening of the segmentation); the blade points medially (+x) and the
///   cut runs superior-inferior, parallel to the atrioventricular groove's right part. Where no
///   place holds it, the most rightward particle of that region. On the right atrium's wall: the
///   same rule over the middle half (in z) of that wall, front or back, clear of the venae cavae.
///   Where walls were grown but none is the right atrium's (one blood pool, HVSMR 2016), the
///   upper half is the labelled wall's (the ventricles'), not the whole model's: the grown blood
///   pool reaches up the great vessels, and the right atrium lies beside the ventricles' upper
///   half, the right heart border, with the superior vena cava above it.
///
/// The blade's plane passes a quarter lattice spacing beside the chosen particle's column (a
/// particle on the plane would be cut from its neighbours on one side or the other by the rounding
/// of the spring test).
///
///     const IncisionPlan plan = plan_incision(scenario, {.approach = IncisionApproach::atriotomy});
///     write_trajectory_csv(plan.trajectory, "incision.csv");   // for `heartsim run --trajectory`
#pragma once

#include "formats/scenario.h"
#include "libmodel/surgery/surgery_site.h"
#include "runtime/view/camera.h"
#include "runtime/core/trajectory.h"

#include <Eigen/Core>

#include <array>
#include <filesystem>
#include <string>

namespace heartsim {

/// "ventriculotomy" or "atriotomy"; OptionError naming {IncisionPlanOptions::approach} otherwise.
IncisionApproach parse_incision_approach(const std::string& name);
const char* to_string(IncisionApproach approach);

struct IncisionPlanOptions {
    IncisionApproach approach = IncisionApproach::ventriculotomy;
    double length_mm = 30.0;     ///< along z, centred on the chosen particle
    /// How far the blade reaches behind the chosen particle, mm; 0: through the wall there (the
    /// tissue's thickness along the blade, libmodel/surgery/surgery_site.h wall_thickness, and 2 mm on into the cavity).
    double depth_mm = 0.0;
    double clearance_mm = 2.0;   ///< the tip's distance in front of it
    double speed_mm_per_ms = 0.1;
    double spread_mm = 6.0;      ///< the retractors' final separation beyond their grip
    bool retract = true;         ///< false: the cut alone
};

struct IncisionPlan {
    Trajectory trajectory;
    IncisionApproach approach = IncisionApproach::ventriculotomy;
    int particle = -1;                                   ///< the chosen particle (packed index)
    Eigen::Vector3d entry = Eigen::Vector3d::Zero();     ///< its rest position
    /// The entry moved a quarter spacing along `side`: a point of the blade's plane.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d blade = Eigen::Vector3d::UnitY();    ///< where the blade points (into the heart), a world axis
    Eigen::Vector3d cut = Eigen::Vector3d::UnitZ();      ///< the direction the blade is drawn
    Eigen::Vector3d side = Eigen::Vector3d::UnitX();     ///< the blade plane's normal, cut × side = blade
    ViewDirection view = ViewDirection::anterior;        ///< the named view that faces the incision from outside
    double blade_length_mm = 0.0;
    double depth_mm = 0.0;       ///< how far the blade reaches behind the chosen particle (the option's, or through the wall)
    double wall_mm = 0.0;        ///< the tissue's thickness along the blade from the chosen particle (libmodel/surgery/surgery_site.h wall_thickness)
    double cut_end_ms = 0.0;     ///< the blade lifts here
    double end_ms = 0.0;         ///< the gesture's end (retractors held still from spread_end_ms)
    double spread_end_ms = 0.0;  ///< 0 without retractors
    double grab_ms = 0.0;        ///< the retractors close (0 without them)
    /// The retractors' grip points (hand 0 on the −side edge, hand 1 on the +side edge), and
    /// whether a particle was found there (else the point beside the centre).
    std::array<Eigen::Vector3d, 2> grips{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    std::array<bool, 2> grip_found{false, false};
    /// The atriotomy found a place whose wall holds the whole incision (else the most rightward
    /// point was taken); always true for the ventriculotomy.
    bool whole_wall = true;
    /// The material whose wall the place was chosen on ("right atrium wall (grown)"); empty when
    /// no material names the approach's chamber and the whole heart's rule chose it.
    std::string chamber_wall;
};

/// The particles of `scenario` whose tissue is labelled in the input, where the build grew walls
/// (one flag per particle); empty for a build of the labels as they are.
std::vector<std::uint8_t> labelled_where_grown(const Scenario& scenario);

/// The particles of `scenario` whose material is the wall of `approach`'s chamber (the right
/// ventricle for the ventriculotomy, the right atrium for the atriotomy): a material whose name
/// says "right ventric…" or "right atri…" (any case). One flag per particle; all 0 where none is;
/// `material_name` gets the first such material's name.
std::vector<std::uint8_t> chamber_wall_particles(const Scenario& scenario, IncisionApproach approach, std::string* material_name = nullptr);

/// The incision of `options.approach` on `scenario`. InputError when the scenario has no particles.
IncisionPlan plan_incision(const Scenario& scenario, const IncisionPlanOptions& options = {});

/// libmodel/surgery/surgery_site.h frontmost_near on `scenario`'s rest positions.
int frontmost_near(const Scenario& scenario, const Eigen::Vector3d& point, const Eigen::Vector3d& blade, double radius);

/// A camera distance (mm) at which the opened incision fills a good part of the frame: two and a
/// half incision lengths (a 30 mm cut then spans about 75 % of the frame's height).
double incision_view_distance(const IncisionPlan& plan, const IncisionPlanOptions& options);
/// `--look-at X,Y,Z,DISTANCE` for `heartsim run`: the centre of the incision, at
/// incision_view_distance, formatted to 0.1 mm.
std::string incision_look_at(const IncisionPlan& plan, const IncisionPlanOptions& options);

/// `heartsim plan-incision SCENARIO -o OUT.csv …`: reads the scenario, plans, writes the CSV (with
/// the view that shows the incision, the plan's view and incision_look_at, as its `# view:` line:
/// trajectory.h) and prints what it planned and how to play it. 0.
struct PlanIncisionArguments {
    std::string scenario, output;
    std::string approach = "ventriculotomy";
    IncisionPlanOptions options;
};
int plan_incision_command(const PlanIncisionArguments& arguments);

}  // namespace heartsim
