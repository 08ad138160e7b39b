/// @file patch.h
/// @brief A patch sewn over a septal defect: a thin sheet simulated by extended position-based
/// dynamics (XPBD) beside the tissue's mass-spring lattice, stitches that tie patch points to
/// tissue points, and one-sided contact with the tissue's surface (docs/architecture.md "The
/// patch").
///
/// The tissue steps explicitly at a step its own springs bound; a patch of pericardium or PTFE is
/// three orders of magnitude stiffer and would bind it a hundredfold tighter. XPBD projects the
/// patch's constraints within each tissue step instead, with compliances from the material's
/// Young's modulus, so the patch is as stiff as it is without shortening the heart's step. The two
/// meet through the tissue's particles: the model reads the current positions of the particles
/// that carry its stitch anchors and contact surface (`particles()`), steps the patch with them
/// held still, and returns the equal and opposite forces as loads on those particles for the
/// tissue's next step (Backend::set_loads).
///
///     PatchModel patch(spec, lattice.particles.rest_position, surface);
///     patch.lay(pose, surface_positions_of(patch.particles()));
///     patch.tie(tip, time_ms, positions_of(patch.particles()));
///     patch.step(positions_of(patch.particles()), dt_ms, time_ms);  // then backend.set_loads(patch.loads())
#pragma once

#include "libmodel/instrument_pose.h"
#include "libmodel/sim/solver.h"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// 1 mmHg in N/mm² (133.322 Pa).
inline constexpr double mmhg_in_n_per_mm2 = 1.33322e-4;

/// A patch material in physical terms.
struct PatchMaterial {
    std::string name = "pericardium";
    double youngs_modulus_mpa = 30.0;  ///< in-plane, N/mm²
    double poisson_ratio = 0.45;
    double density = 1.1e-3;           ///< g/mm³
};

/// The materials heartsim knows: "pericardium" (glutaraldehyde-fixed bovine pericardium, about
/// 30 MPa in its working range), "ptfe" (expanded PTFE, about 40 MPa), "dacron" (woven polyester,
/// about 200 MPa). Throws InputError naming the three otherwise.
PatchMaterial patch_material_named(const std::string& name);

/// A point carried by tissue particles: its rest position and its carriers (packed indices) with
/// weights summing to 1; it moves with their displacement, x = rest + Σ w_k (x_k − X_k).
struct CarriedPoint {
    Eigen::Vector3d rest = Eigen::Vector3d::Zero();
    std::vector<std::pair<std::int32_t, double>> carriers;
};

/// The tissue surface a patch can touch: triangles of the detailed mesh (counter-clockwise seen
/// from outside), each vertex carried by particles (the detailed mesh's mapping).
struct ContactSurface {
    std::vector<CarriedPoint> vertices;
    std::vector<std::array<std::int32_t, 3>> triangles;
};

struct PatchSpec {
    PatchMaterial material;
    double thickness_mm = 0.5;
    double radius_x_mm = 9.0, radius_y_mm = 9.0;  ///< the oval's half-diameters (the pose's tool x and y)
    double edge_mm = 1.6;                         ///< the triangles' size
    double standoff_mm = 0.0;                     ///< laid this far in front of the surface it drapes onto
    double tie_ms = 150.0;                        ///< how long a stitch takes to draw tight
    double stitch_stiffness = 5.0;                ///< N/mm: the suture and its pledget
    double damping_per_ms = 0.5;                  ///< the patch's motion relaxes at this rate (the blood's drag)
    int iterations = 4;                           ///< constraint projections per step
    Eigen::Vector3d gravity = Eigen::Vector3d::Zero();  ///< mm/ms²; the patch floats in blood, so it sinks by (1 − ρ_blood/ρ) of it
    double blood_density = 1.06e-3;               ///< g/mm³
    double friction = 0.3;                        ///< Coulomb's coefficient between patch and tissue
};

struct Stitch {
    int vertex = 0;              ///< the patch's vertex
    CarriedPoint anchor;         ///< the tissue's point
    double tied_ms = 0.0;        ///< when the needle tied it
    double start_length = 0.0;   ///< patch point to tissue point then, mm
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();  ///< the stitch's pull on the patch in the last step, N (minus that on the tissue)
};

/// The positions of particles(), in that order (mm).
using ParticlePositions = std::vector<std::array<float, 3>>;

/// An instrument the patch cannot pass through: a probe's ellipsoid (semi-axes along the pose's
/// tool x, y, z), moved by the hand and not by the patch.
struct PatchObstacle {
    InstrumentPose pose;
    Eigen::Vector3d semi_axes = Eigen::Vector3d::Ones();
};

/// What PatchModel::step keeps between steps, as a pass carries it: per vertex the triangle under
/// it (−1: none) and where and when it last looked (searched_travel NaN: it must look again); the
/// tissue's accumulated shift and deformation; the slots' positions at the last look at the
/// surface, when its grid was built, and when the patch last stepped awake (each empty: none).
struct PatchKeptState {
    std::vector<std::int32_t> under;
    std::vector<Eigen::Vector3d> searched_at, searched_shift;
    std::vector<double> searched_travel;
    Eigen::Vector3d tissue_shift = Eigen::Vector3d::Zero();
    double tissue_travel = 0.0;
    std::vector<Eigen::Vector3d> slot_x, grid_slot_x, asleep_slot_x;
};

/// A sewn patch flattened for a pass that steps it where the tissue is stepped (the gl backend's
/// compute pass, runtime/gl/patch_pass.h), so the tissue is never read back to step it: what
/// PatchModel::step reads, as arrays. Ranges are (first, one past the last) lists: `x_first[k]`
/// to `x_first[k + 1]`. The pass keeps what the host's step keeps between steps (`kept`), so the
/// two step alike; only where the host looks for the triangle under a vertex in its grid does the
/// pass look among that vertex's candidates.
struct PatchPassInput {
    // The patch: positions and velocities (mm, mm/ms), inverse masses (g⁻¹), its distance
    // constraints (vertices; rest length mm, compliance mm/N) in colour order, and where each
    // colour starts.
    std::vector<Eigen::Vector3d> x, v;
    std::vector<double> inverse_mass;
    std::vector<std::array<std::int32_t, 2>> distance_vertices;
    std::vector<std::array<double, 2>> distance_rest_compliance;
    std::vector<std::int32_t> colour_first;
    // The tissue: the particles read (PatchModel::particles(), the "slots"), their positions at
    // the last step (empty: none yet, no friction carried), and the contact surface: each vertex
    // base + Σ w·x over its (slot, weight) entries, its inverse mass at mass scale 1, triangles.
    std::vector<std::int32_t> particles;
    std::vector<Eigen::Vector3d> stepped_slot_x;
    std::vector<Eigen::Vector3d> surface_base;
    std::vector<std::int32_t> surface_first, surface_slot;
    std::vector<double> surface_weight, surface_inverse_mass;
    std::vector<std::array<std::int32_t, 3>> triangles;
    // The stitches: patch vertex, when tied (ms), length then (mm), the anchor as base + Σ w·x,
    // its inverse mass at mass scale 1.
    std::vector<std::int32_t> stitch_vertex;
    std::vector<double> stitch_tied_ms, stitch_start_length, stitch_inverse_mass;
    std::vector<Eigen::Vector3d> stitch_base;
    std::vector<std::int32_t> stitch_first, stitch_slot;
    std::vector<double> stitch_weight;
    /// The stitches in colour order (greedy in their order: no two of a colour tie the same
    /// vertex), and where each colour starts.
    std::vector<std::int32_t> stitch_order, stitch_colour_first;
    // Per patch vertex: the facing surface triangles it can lie over until the next refresh
    // (PatchModel::pass_candidates). Per surface vertex: the patch vertices whose candidates touch
    // it, ascending (the contact's loads gathered). Per slot: its surface vertices and stitches
    // with their weights (the loads gathered onto the particles).
    std::vector<std::int32_t> candidate_first, candidate;
    std::vector<std::int32_t> over_first, over;
    std::vector<std::int32_t> slot_vertex_first, slot_vertex;
    std::vector<double> slot_vertex_weight;
    std::vector<std::int32_t> slot_stitch_first, slot_stitch;
    std::vector<double> slot_stitch_weight;
    PatchKeptState kept;
    double largest_weight_sum = 1.0;  ///< the largest Σ |w_k| of a surface vertex
    // The spec, as step() takes it.
    Eigen::Vector3d facing = Eigen::Vector3d::UnitZ();
    Eigen::Vector3d acceleration = Eigen::Vector3d::Zero();  ///< afloat in blood, mm/ms²
    double thickness_mm = 0.5, friction = 0.3, damping_per_ms = 0.5, tie_ms = 150.0, stitch_stiffness = 5.0, edge_mm = 1.6;
    double search_again_mm = 0.2, grid_margin_mm = 0.75;
    int iterations = 4;
};

/// What a pass's steps left: the patch's positions and velocities, each stitch's pull on the patch
/// and the contact's, N, the tissue's positions as the last step read them, and what it keeps.
struct PatchPassState {
    std::vector<Eigen::Vector3d> x, v, stitch_force, stepped_slot_x;
    Eigen::Vector3d contact_force = Eigen::Vector3d::Zero();
    PatchKeptState kept;
};

class PatchModel {
public:
    /// `rest` are the particles' rest positions (packed order); `surface` the tissue the patch can
    /// lie on; `tissue_inverse_mass` the particles' 1/m (g⁻¹, 0 where anchored; empty: a rigid
    /// tissue), by which the tissue yields to the stitches and the contact. Throws InputError for a
    /// thickness, radius, edge or material out of range.
    PatchModel(const PatchSpec& spec, const std::vector<std::array<float, 3>>& rest, ContactSurface surface,
               std::vector<double> tissue_inverse_mass = {});
    /// The tissue's explicit mass scaling S (its particles weigh S·m in the step).
    void set_mass_scale(double mass_scale) { mass_scale_ = mass_scale > 0 ? mass_scale : 1.0; }

    /// The particles whose current positions step(), lay() and tie() take, sorted (the contact
    /// surface's carriers and every stitch anchor's).
    const std::vector<std::int32_t>& particles() const { return particles_; }

    /// Lays the patch: an oval in the plane of the pose (tool x, y), centred at its position,
    /// facing the tissue along the tool's +z; each vertex draped onto the surface it meets along
    /// +z within 6 mm of that plane (then standoff_mm in front of it plus half the thickness);
    /// vertices over no surface, or meeting it more than 1.5 mm deeper than their neighbours (the
    /// opening), follow their neighbours'. Its rest shape is the laid shape: trimmed to fit, it starts
    /// unstressed. Until its first stitch it stays where it was laid (held in front of the
    /// defect); sewn, it moves. Laying again replaces the patch and its stitches.
    void lay(const InstrumentPose& pose, const ParticlePositions& positions);
    bool laid() const { return !x_.empty(); }

    /// Ties a stitch from the tissue surface point nearest `tip` (within `reach_mm`) to the patch
    /// vertex that lay nearest it when the patch was laid (seen along the way it faced): the stitch
    /// draws its two points together, from their distance now to none, over tie_ms (a smoothstep,
    /// so its pull starts and ends without a jump); the contact keeps the patch half its thickness
    /// off the tissue, so a tied stitch presses it on. Returns the stitch's index, or nullopt (and why in `why`) when no patch is laid or
    /// no surface is within reach.
    std::optional<std::size_t> tie(const Eigen::Vector3d& tip, double time_ms, const ParticlePositions& positions,
                                   std::string* why = nullptr, double reach_mm = 5.0);

    /// After the tissue's watchdog restored an earlier state: the patch stops, drops its loads, and
    /// each stitch draws tight again over tie_ms from its length now.
    void recover(const ParticlePositions& positions, double time_ms);

    /// One tissue step of dt_ms ending at time_ms + dt_ms: the tissue held at `positions`.
    void step(const ParticlePositions& positions, double dt_ms, double time_ms);

    /// The instruments the next step()s keep a sewn patch out of: each vertex inside one, grown by
    /// half the patch's thickness, goes to the nearest point of its surface, as a probe pushes the
    /// tissue's particles (a laid patch not yet sewn is the hand's and is not pushed).
    void set_obstacles(std::vector<PatchObstacle> obstacles);
    /// The patch's push on each obstacle in the last step(), in set_obstacles' order, N (minus the
    /// obstacle's push on the patch, m·Δx/dt² summed over the vertices it moved).
    const std::vector<Eigen::Vector3d>& obstacle_forces() const { return obstacle_force_; }

    /// The loads the last step() leaves on the tissue (minus the stitches' and the contact's
    /// forces on the patch, at their tissue points), sorted by particle, summed per particle.
    std::vector<ParticleLoad> loads() const;

    /// The leak test: a copy of the patch, let go of (a laid patch is held only until sewn), with
    /// the tissue held at `positions`, after `duration_ms` under `pressure_n_mm2` pushing it off
    /// the wall over the opening (where no tissue lies under it), its stitches drawn tight. A
    /// patch sewn all round bulges a little; one held by too few stitches lifts off the rim.
    PatchModel under_pressure(const ParticlePositions& positions, double pressure_n_mm2, double duration_ms = 400.0,
                              double dt_ms = 0.25) const;

    /// The patch flattened for a pass (PatchPassInput), its candidates found within `reach_mm`
    /// across of each vertex at the tissue's `positions`. Throws when no patch is laid.
    PatchPassInput pass_input(const ParticlePositions& positions, double reach_mm);
    /// Only the candidates and the lists that follow them, found afresh with the tissue at
    /// `positions` (of particles()) and the patch where it is.
    void pass_candidates(PatchPassInput& input, const ParticlePositions& positions, double reach_mm) const;
    /// The same from a pass's snapshot: the patch's positions `x` and the slots' `slot_x`.
    void pass_candidates(PatchPassInput& input, const std::vector<Eigen::Vector3d>& x, const std::vector<Eigen::Vector3d>& slot_x,
                         double reach_mm) const;
    /// Takes what a pass's steps left (its sizes those of pass_input's); the obstacles' forces as
    /// the pass gave them, in set_obstacles' order.
    void take_pass_state(const PatchPassState& state, const std::vector<Eigen::Vector3d>& obstacle_forces);
    /// Laid and not yet sewn: held where it lies, step() moves nothing.
    bool held() const { return held_; }

    const std::vector<Eigen::Vector3d>& positions() const { return x_; }
    const std::vector<std::array<std::int32_t, 3>>& triangles() const { return triangles_; }
    const std::vector<Stitch>& stitches() const { return stitches_; }
    const PatchSpec& spec() const { return spec_; }
    std::size_t surface_triangles() const { return surface_.triangles.size(); }
    /// Where a carried point is now, given positions of particles().
    Eigen::Vector3d where(const CarriedPoint& point, const ParticlePositions& positions) const;
    /// The sum of the contact's forces on the patch in the last step, N.
    const Eigen::Vector3d& contact_force() const { return contact_force_; }
    double mass_g() const;

private:
    void build_mesh();
    // step()'s parts, in the order it takes them (patch_step.cpp).
    struct StitchPull;
    struct StepContact;
    /// Gravity afloat in blood, the pressure over the opening and the damping, for one step.
    void drift(double dt_ms);
    /// The stitches' anchors and lengths for the step ending at time_ms + dt_ms.
    StitchPull stitch_pull(const ParticlePositions& positions, double dt_ms, double time_ms) const;
    /// α/dt² and 1/(w_a + w_b + α/dt²) per distance, recomputed where the step length changed.
    void update_compliance(double dt_ms, double dt2);
    /// The surface under each vertex for the step (under_), the tissue's inverse mass there and how
    /// far it moved since the last step.
    StepContact step_contact();
    void project_stitches(StitchPull& pull, double dt2);
    void project_distances(std::vector<double>& lambda);
    /// One-sided contact with friction: a vertex over a surface triangle stays half the thickness
    /// in front of it (the tissue held still within the step, yielding as predicted).
    void project_contact(StepContact& contact, const std::vector<Eigen::Vector3d>& previous);
    void project_obstacles(double dt2);
    /// The stitches' and the contact's forces, and their opposites as loads on the tissue.
    void load_tissue(const StitchPull& pull, const StepContact& contact, double dt2);
    /// The grid over a surface at `surface_x` (per triangle its unit `normals`): build_surface_grid
    /// for the step, pass_candidates for a pass.
    struct SurfaceGrid {
        Eigen::Vector3d origin = Eigen::Vector3d::Zero();
        Eigen::Vector3i dims = Eigen::Vector3i::Zero();
        std::vector<std::vector<std::int32_t>> cells;
        std::vector<std::array<float, 6>> box;  ///< per triangle: where a point it holds can be (u, v min; u, v max; along +z, min, max)
    };
    SurfaceGrid grid_over(const std::vector<Eigen::Vector3d>& surface_x, const std::vector<Eigen::Vector3d>& normals) const;
    /// The grid over the surface where the slots are at `slot_x`.
    SurfaceGrid grid_at(const std::vector<Eigen::Vector3d>& slot_x) const;
    /// Surface vertex `v` with the slots at `slot_x`: base + Σ w·x over its carriers.
    Eigen::Vector3d surface_point(std::size_t v, const std::vector<Eigen::Vector3d>& slot_x) const;
    /// The unit normal of triangle (a, b, c), zero where it has no area.
    static Eigen::Vector3d unit_normal(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c);
    /// Whether the patch and the tissue it touches are at rest (step() then changes nothing).
    bool at_rest(const ParticlePositions& positions, double time_ms) const;
    void refresh_particles();
    /// The surface at `positions`: begin_surface() and then sx() and sn() compute each vertex and
    /// normal as first read; deform_surface() computes them all.
    void begin_surface(const ParticlePositions& positions);
    void deform_surface(const ParticlePositions& positions);
    const Eigen::Vector3d& sx(std::size_t vertex);  ///< a surface vertex now
    const Eigen::Vector3d& sn(std::size_t triangle);  ///< a surface triangle's unit normal now
    /// Nearest point of the deformed surface to p: triangle and barycentric weights; false if none
    /// within `reach`.
    bool nearest_on_surface(const Eigen::Vector3d& p, double reach, int& triangle, Eigen::Vector3d& bary) const;
    void build_surface_grid();
    /// Whether a surface vertex may have moved by more than half grid_margin since the grid was
    /// built (bounded through its carriers).
    bool surface_moved() const;
    /// A carried point's generalised inverse mass Σ w_k²/(S·m_k): how far the tissue there yields
    /// to an impulse.
    double inverse_mass_of(const CarriedPoint& point) const;
    double vertex_inverse_mass(std::size_t surface_vertex) const;
    /// The facing surface triangle under p (its projection inside, p within [−2, 3 + thickness] mm
    /// in front of it), the nearest such; −1 when none. `bary`: where, `depth`: how far in front.
    int triangle_under(const Eigen::Vector3d& p, Eigen::Vector3d& bary, double& depth);
    CarriedPoint carried_at(int triangle, const Eigen::Vector3d& bary) const;
    void add_load(const CarriedPoint& point, const Eigen::Vector3d& force);
    void add_load(std::size_t slot, const Eigen::Vector3d& force);
    void clear_loads();
    std::size_t slot_of(std::int32_t particle) const;  ///< its index in particles_

    PatchSpec spec_;
    const std::vector<std::array<float, 3>>& rest_;
    std::vector<double> tissue_inverse_mass_;
    double mass_scale_ = 1.0;
    mutable std::vector<double> surface_inverse_mass_;  ///< per surface vertex, at S = 1
    ContactSurface surface_;
    std::vector<std::int32_t> particles_;
    std::vector<int> slot_of_surface_;     ///< per (vertex, carrier) flattened: the slot in particles_
    std::vector<double> surface_weight_;   ///< per (vertex, carrier) flattened: its weight
    std::vector<std::size_t> vertex_first_;  ///< per surface vertex (and one past the last): its first entry in those
    std::vector<Eigen::Vector3d> surface_base_;  ///< per surface vertex: rest − Σ w_k X_k
    double largest_weight_sum_ = 1.0;            ///< the largest Σ |w_k| of a surface vertex
    // The patch: positions, previous positions, velocities, inverse masses; material coordinates.
    std::vector<Eigen::Vector3d> x_, v_, laid_;
    std::vector<double> inverse_mass_, area_;
    double pressure_ = 0.0;  ///< N/mm², over the opening (under_pressure)
    std::vector<Eigen::Vector2d> material_;
    std::vector<std::array<std::int32_t, 3>> triangles_;
    struct Distance { int a, b; double rest, compliance; };
    std::vector<Distance> distances_;  ///< edges (stretch) and the pairs across each inner edge (bending), by colour
    std::vector<std::int32_t> colour_first_;  ///< per colour and one past the last: its first entry in distances_
    std::vector<double> alpha_, denominator_;  ///< per distance: α/dt² and 1/(w_a + w_b + α/dt²) for steps of alpha_dt_
    double alpha_dt_ = -1.0;
    std::vector<Eigen::Vector3d> vertex_force_;   ///< per surface vertex: the contact's force on it in step(), zero between
    std::vector<std::int32_t> loaded_vertices_;  ///< the surface vertices vertex_force_ held a force for in the last step()
    std::vector<Stitch> stitches_;
    bool held_ = true;                 ///< laid and not yet sewn
    // The deformed surface, per step.
    std::vector<Eigen::Vector3d> slot_x_;          ///< the positions of particles_, in double
    std::vector<Eigen::Vector3d> stepped_slot_x_;  ///< those the last step() held the tissue at
    std::vector<Eigen::Vector3d> surface_x_;
    std::vector<Eigen::Vector3d> surface_normal_;  ///< per triangle, unit
    std::vector<std::uint64_t> x_stamp_, normal_stamp_;  ///< the surface each was computed for
    std::uint64_t stamp_ = 0;
    static constexpr double grid_margin = 0.75;     ///< mm
    std::vector<Eigen::Vector3d> grid_slot_x_;     ///< the particles when the grid was built
    // Whether a patch vertex must look for the surface under it again (search_again()): the
    // tissue's motion split into a shift (its particles' mean displacement, summed over the calls
    // to begin_surface) and a deformation (the largest departure of a particle's displacement from
    // that mean, summed).
    /// How far a vertex moves on the tissue before it looks again: 0.4 of the patch's thickness,
    /// less than the half thickness the contact keeps it off the surface, so a surface it reaches
    /// unseen is found before the vertex passes it.
    double search_again() const { return 0.4 * spec_.thickness_mm; }
    Eigen::Vector3d tissue_shift_ = Eigen::Vector3d::Zero();
    double tissue_travel_ = 0.0;
    std::vector<Eigen::Vector3d> searched_at_;      ///< per patch vertex: where it last looked for the surface under it
    std::vector<Eigen::Vector3d> searched_shift_;   ///< tissue_shift_ then
    std::vector<double> searched_travel_;           ///< tissue_travel_ then (NaN: it must look again)
    double grid_cell_ = 1.0;
    SurfaceGrid grid_;  ///< the step's, over the surface where grid_slot_x_ put it
    Eigen::Vector3d facing_ = Eigen::Vector3d::UnitZ();  ///< the laid patch's +z (toward the tissue)
    Eigen::Matrix3d frame_ = Eigen::Matrix3d::Identity(); ///< the laid patch's tool frame
    Eigen::Vector3d contact_force_ = Eigen::Vector3d::Zero();
    std::vector<PatchObstacle> obstacles_;
    std::vector<Eigen::Vector3d> obstacle_force_;
    /// Whether an obstacle reaches a vertex's neighbourhood (the patch must not sleep then).
    bool obstacle_near() const;
    std::vector<Eigen::Vector3d> slot_force_;    ///< the loads, per slot of particles_
    std::vector<char> slot_loaded_;
    std::vector<std::int32_t> loaded_slots_;
    std::vector<int> under_;  ///< per vertex: the surface triangle under it in the last step, or −1
    ParticlePositions asleep_positions_;  ///< the tissue as the patch last stepped
};

}  // namespace heartsim
