/// @file repair.h
/// @brief The repair of a septal defect in a run: a Backend that holds a patch (libmodel/surgery/patch.h)
/// beside the tissue it wraps. Every run mode (scripted, replayed, haptic, the window) talks to a
/// Backend, so each gets the patch and its stitches through the hands it already drives: a hand
/// whose instrument is a `patch` lays the patch when its grab flag or button turns on; a `needle`
/// ties a stitch (libmodel/sim/solver.h InstrumentKind). Neither reaches the tissue's solver, which sees
/// no instrument in that hand.
///
/// Each step, with a patch laid: the positions of the particles the patch touches are read
/// (SurgerySupport::positions_of, runtime/backend/surgery.h), the patch steps against them held still, and
/// its stitches' and contact's equal and opposite forces go to the tissue as loads for the step
/// (SurgerySupport::set_loads).
///
/// A needle's hand feels the wall and the suture (libmodel/surgery/needle_feel.h, the measurements
/// it cites): carried (its button up), the wall's resistance along its shaft as its tip passes
/// into the tissue (a rise to the puncture, a drop, the cutting and the friction), its tip's
/// depth measured every needle_every_ms; tying a stitch (its button held), the suture's tension
/// rising as the stitch draws tight, along the shaft toward the wall. Both are the hand's
/// force (instrument_forces, latest_forces): what a device and a recording get.
///
/// Because neither touches the tissue's solver, nothing stops a patch or a needle that is carried
/// through intact tissue: the repair reports it instead (TissueIntrusion, RepairBackend::intrusions).
///
/// The repair wraps the backend (runtime/backend/backend_wrapper.h) and overrides only the calls it
/// changes; a run finds it through the backend's one extension, Backend::surgery (repair_of).
///
///     auto backend = with_repair(make_cpu_backend(scenario, options), scenario, RepairSettings{});
///     if (RepairBackend* repair = repair_of(*backend)) show(repair->patch(), repair->stitch_anchors());
#pragma once

#include "libmodel/surgery/closure.h"
#include "libmodel/surgery/needle_feel.h"
#include "libmodel/surgery/patch.h"
#include "runtime/backend/backend.h"
#include "runtime/backend/backend_wrapper.h"
#include "runtime/backend/patch_stepper.h"
#include "runtime/backend/surgery.h"

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

struct RepairSettings {
    PatchMaterial material;          ///< --patch-material
    double edge_mm = 1.6;            ///< the patch's triangles
    /// A laid patch lies this far in front of the surface (held there until its first stitch).
    double standoff_mm = 0.0;
    double tie_ms = 150.0;
    double stitch_stiffness = 5.0;   ///< N/mm
    int iterations = 4;
    /// The patch steps once every this many tissue steps (by as long: XPBD has no stability bound),
    /// its loads held in between.
    int patch_every = 3;
    /// While a hand carries a patch not yet laid or a needle between stitches, whether its working
    /// points lie in the tissue is checked once every this much simulated time (rounded to whole
    /// tissue steps, at least one), ms; 0: never (TissueIntrusion). An instrument carried at
    /// 0.2 mm/ms, a brisk hand, moves 0.4 mm between checks: less than a lattice spacing.
    double intrusion_every_ms = 2.0;
    /// What a needle's hand feels: the wall's resistance to its pass and the suture's tension.
    NeedleFeel needle;
    /// A carried needle's tip depth in the wall is measured once every this much simulated time
    /// (rounded to whole tissue steps, at least one), its force held in between, ms; 0: the needle
    /// feels no wall. The depth: from the tip back along the shaft (the tool's +z) to where it
    /// leaves the tissue (a point within 0.75 lattice spacing of a particle, where the particles
    /// are now), to 0.01 mm, at most 12 mm, less the part of it outside the drawn surface: that
    /// point lies 0.75 spacing from the particle it leaves by, the drawn surface that particle's
    /// contact skin from it (libmodel/contact_skin.h), so the depth is counted from where the
    /// trainee sees the wall as the probe's contact is; 0 with the tip outside. The particles
    /// looked at are those whose rest positions lie near the shaft: tissue that has moved more
    /// than 1 mm from rest there may be missed.
    double needle_every_ms = 0.5;
};

/// A stretch of a run in which a carried instrument passed through tissue: a patch in the hand
/// before it is laid (kind patch, grab off), or a needle between stitches (grab off). The
/// instrument's working points are the needle's tip (its pose's position) and the patch's centre
/// and 8 points round its rim (the disc of semi-axes ax, ay in the tool's x, y plane). A point lies
/// in the tissue within 0.75 lattice spacing of a particle where it is at the check
/// (libmodel/surgery/sight.h TissueOccupancy, on the current positions).
///
/// A point's depth is the shortest way out of the tissue along four lines through it, each both
/// ways: the instrument's direction of travel since the last check (standing still: the tool's z
/// axis) and the tool's x, y and z axes. Each is sampled every quarter spacing; the way out is
/// midway between the last sample inside and the first of two in a row outside (a single one may
/// fall in the small gap the 0.75-spacing rule leaves at the centre of a lattice cell), so the
/// depth is within an eighth of a spacing; at most intrusion_reach_mm. Through a wall it is about
/// the distance to the nearer face; for a rim point grazing an edge, how far it cuts into it.
///
/// A stretch runs from the first check that finds one of the hand's points in the tissue to the
/// last, through gaps shorter than intrusion_gap_ms; it ends once the checks have found none for
/// intrusion_gap_ms, or when the hand stops carrying (the patch laid, the needle's grab on,
/// another instrument). It is reported (RepairBackend::intrusions) once a point in it has been at
/// least one spacing deep: less is the surface (a needle tying a stitch there, a patch laid on it).
///
/// A needle's own bite is not a stretch through tissue it should not have met: the stretch going
/// on when the needle ties a stitch, begun within the needle's length (2·az) of where it ties, is
/// its way in to the stitch and is dropped; and after the knot, until a check first finds the tip
/// out of the tissue, the needle is drawn back out of its bite and nothing is counted.
struct TissueIntrusion {
    int hand = 0;
    InstrumentKind kind = InstrumentKind::patch;
    Eigen::Vector3d where = Eigen::Vector3d::Zero();  ///< the deepest working point at its deepest check, mm (world)
    double depth_mm = 0.0;                            ///< its depth there, mm (at most intrusion_reach_mm)
    double from_ms = 0.0, to_ms = 0.0;                ///< the simulated times of the stretch's first and last checks in the tissue
    Eigen::Vector3d entered = Eigen::Vector3d::Zero(); ///< the deepest working point at its first check, mm (world)
};

/// How far along each way a working point's depth is looked for, mm.
constexpr double intrusion_reach_mm = 40.0;
/// Checks finding no point in the tissue for less than this (simulated ms) leave a stretch going on.
constexpr double intrusion_gap_ms = 10.0;

class RepairBackend final : public BackendWrapper, public SurgerySupport {
public:
    /// `inner` must offer the surgery's support (Backend::surgery; both backends do).
    RepairBackend(std::unique_ptr<Backend> inner, const Scenario& scenario, const RepairSettings& settings);

    // The calls a repair changes: the hands that hold a patch or a needle, the step (the patch's
    // with it), the forces (what the hands feel of the patch), the tissue's reset (the patch goes).
    void set_instrument(int hand, const Instrument& instrument) override;
    void set_pose(int hand, const InstrumentPose& pose) override;
    std::size_t begin_grab(int hand) override;
    void release(int hand) override;
    void reset_tissue() override;
    StepReport step(int steps = 1) override;
    std::optional<InstrumentForces> latest_forces() override;
    InstrumentForces instrument_forces() override;

    SurgerySupport* surgery() override { return this; }
    RepairBackend* repair() override { return this; }
    void set_loads(const std::vector<ParticleLoad>& loads) override { tissue_.set_loads(loads); }
    std::vector<std::array<float, 3>> positions_of(const std::vector<std::int32_t>& particles) override {
        return tissue_.positions_of(particles);
    }
    /// The task, then this backend's step (the patch's with it).
    StepReport step_after(const std::function<void()>& task) override {
        task();
        return step(1);
    }
    // patch_stepper(): none to offer: the wrapped backend's is this repair's own (to_device).

    /// The patch, once laid; nullptr before. Where the backend's device steps it, this reads it
    /// back first (the gl backend: waits for the GPU).
    const PatchModel* patch() const {
        sync_from_device();
        return patch_ && patch_->laid() ? &*patch_ : nullptr;
    }
    /// Whether the backend's device steps the sewn patch (the gl backend's compute pass).
    bool patch_on_device() const { return device_ != nullptr; }
    /// The stitches' tissue points now (mm), in stitch order; empty without a patch.
    std::vector<Eigen::Vector3d> stitch_anchors();
    const RepairSettings& settings() const { return settings_; }
    /// Wall-clock time spent on the patch (ms), and the patch steps it took: the run's summary.
    double patch_ms() const { return patch_ms_; }
    long long patch_steps() const { return patch_steps_; }
    /// The device's own time for the patch's steps on it (GPU timer queries), ms, and how many were
    /// timed; {0, 0} where the host steps it. Waits for the steps queued.
    std::pair<double, long long> patch_device_time();
    /// The stretches in which a carried instrument passed through tissue (TissueIntrusion), in the
    /// order they began; the last of a hand may still be going on.
    const std::vector<TissueIntrusion>& intrusions() const { return intrusions_; }
    /// Whether a hand has held a patch or a needle in this run (the summary's line is for those runs).
    bool held_repair_instrument() const { return held_repair_instrument_; }
    /// Tissue steps between two of the intrusion checks (RepairSettings::intrusion_every_ms); 0: none.
    int intrusion_every() const;
    /// Wall-clock time the intrusion checks took (ms), and how many ran.
    double intrusion_ms() const { return intrusion_ms_; }
    long long intrusion_checks() const { return intrusion_checks_; }
    /// Tissue steps between two measures of a carried needle's depth (RepairSettings::needle_every_ms); 0: none.
    int needle_every() const;
    /// A carried needle's tip depth in the wall at its last measure, mm (0: out of it, or not carried).
    double needle_depth_mm(int hand) const { return passes_[std::size_t(hand & 1)].depth_mm; }

private:
    /// The steps with the patch's, as many as asked.
    StepReport step_tissue(int steps);
    /// Whether hand `hand` carries a needle whose passage through the wall it feels.
    bool feels_wall(int hand) const;
    /// Each carried needle's tip depth in the wall, measured now, and the wall's force on it.
    void feel_needles();
    /// The hand's needle out of the wall: no depth, no force.
    void end_pass(int hand) { passes_[std::size_t(hand)] = {}, wall_force_[std::size_t(hand)].setZero(); }
    /// Whether hand `hand` carries an instrument whose passage through tissue is checked.
    bool carried(int hand) const;
    /// One intrusion check of every carrying hand against the tissue as it is now.
    void check_intrusions();
    /// The hand's stretch in tissue, if one is going on, ends.
    void end_intrusion(int hand) { going_[std::size_t(hand)].reset(), shown_[std::size_t(hand)] = -1; }
    /// As `hand`'s needle ties: the stretch going on, where it began within the needle's length of
    /// the tip, is the needle's way in to its stitch (TissueIntrusion): forgotten, reported or not.
    void drop_bite(int hand);

    /// The patch's step over `every` tissue steps, the tissue as it is now; its loads onto the tissue.
    void step_patch(int every);
    void lay(int hand);
    void tie(int hand);
    /// A needle's hand feels the suture's tension while it ties (its button held), the wall's resistance
    /// to its pass while carried; a probe's hand the patch it presses on.
    void add_repair_forces(InstrumentForces& forces) const;
    /// After the patch changed on the host (a stitch tied, a recovery): the backend's device steps
    /// it from now on where it can (SurgerySupport::patch_stepper), with candidates found afresh.
    void to_device();
    /// The device's patch into patch_ when it is newer.
    void sync_from_device() const;
    /// The patch off the device (its loads off the tissue).
    void off_device();
    /// Each hand's force from the device's newest finished patch step, into patch_force_.
    void device_hand_forces(bool wait);

    SurgerySupport& tissue_;  ///< the wrapped backend's (Backend::surgery)
    const Scenario& scenario_;
    RepairSettings settings_;
    mutable std::optional<PatchModel> patch_;  ///< mutable: read back from the device when asked for
    PatchStepper* device_ = nullptr;           ///< the backend's patch pass while it steps the patch
    mutable bool device_ahead_ = false;        ///< the device's patch is newer than patch_
    std::optional<PatchPassInput> device_input_;
    long long device_steps_ = 0;               ///< patch steps on the device since it was loaded (candidates found again every candidate_refresh)
    PatchStepper* timed_device_ = nullptr;     ///< the stepper that stepped a patch in this run, for its time
    struct Hand {
        Instrument instrument;
        InstrumentPose pose;
        bool posed = false;  ///< set_pose since set_instrument
        bool grabbing = false;
        std::optional<std::size_t> stitch;  ///< the needle's stitch while its button is held
        double tied_ms = 0.0;               ///< when it was tied (its tension rises from then)
        bool laid = false;  ///< a patch: laid since set_instrument (no longer carried)
    };
    std::array<Hand, 2> hands_{};
    /// What each hand feels of the patch from its last step (held between its steps, as its loads):
    /// a probe's push, a needle's suture; N.
    std::array<Eigen::Vector3d, 2> patch_force_{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    mutable double patch_ms_ = 0.0;
    long long patch_steps_ = 0;
    long long tissue_steps_ = 0;  ///< since the patch was laid
    std::vector<TissueIntrusion> intrusions_;
    std::array<std::optional<TissueIntrusion>, 2> going_;  ///< each hand's stretch in the tissue going on, reported or not yet
    std::array<int, 2> shown_{-1, -1};  ///< its index in intrusions_ once reported, or −1
    std::array<bool, 2> withdrawing_{false, false};  ///< a needle drawn back out of the bite it tied, not yet found outside
    std::array<std::optional<Eigen::Vector3d>, 2> checked_at_;  ///< each carrying hand's position at its last check
    int since_check_ = 0;  ///< tissue steps since the last intrusion check
    // The needles' passes through the wall: each hand's, the wall's force on it at the last
    // measure (N, held in between), the particles along its shaft (from their rest positions) and
    // the tip and the shaft's direction when they were gathered.
    std::array<NeedlePass, 2> passes_{};
    std::array<Eigen::Vector3d, 2> wall_force_{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    std::array<std::vector<std::int32_t>, 2> near_tip_;
    std::array<std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>>, 2> gathered_at_;
    std::vector<float> skin_;  ///< the scenario's contact skin (scenario_contact_skin), made at the first measure
    int since_feel_ = 0;  ///< tissue steps since the last measure of the needles' depths
    bool held_repair_instrument_ = false;
    double intrusion_ms_ = 0.0;
    long long intrusion_checks_ = 0;
};

/// The detailed mesh's triangles a patch centred at `centre` and facing along `facing` can touch:
/// within `radius` of the centre across, `depth` along, facing it (rest positions); each vertex
/// carried by the particles the mapping names. Needs the scenario's detailed mesh and mapping.
ContactSurface patch_surface_near(const Scenario& scenario, const Eigen::Vector3d& centre, const Eigen::Vector3d& facing, double radius,
                                  double depth);

/// Whether `scenario` can hold a patch: a detailed mesh with its mapping and the simulation
/// surface, for the surface the patch lies on.
bool can_hold_patch(const Scenario& scenario);
/// The refusal of a run whose `what` (e.g. "--instrument patch for hand 0") lays a patch or ties a
/// stitch on a scenario that cannot hold one: said before the first step, not when the hand acts.
InputError no_patch_surface(const std::string& what);

/// The repair riding on `backend` (Backend::surgery, SurgerySupport::repair), or nullptr.
inline RepairBackend* repair_of(Backend& backend) {
    SurgerySupport* surgery = backend.surgery();
    return surgery ? surgery->repair() : nullptr;
}

/// `inner` wrapped in a RepairBackend when can_hold_patch(scenario) and `inner` offers the
/// surgery's support (Backend::surgery); else `inner` itself.
std::unique_ptr<Backend> with_repair(std::unique_ptr<Backend> inner, const Scenario& scenario, const RepairSettings& settings);

/// The defect of a scenario, where it is in the tissue's current state: its rest centre moved by
/// the displacement of the particles around it (a Gaussian of the lattice spacing's width), its
/// axis pointing to the side `patch` lies on (without one: to the heart's right and anterior, the
/// side a surgeon closes it from). nullopt when the scenario has no defect.
std::optional<DefectFrame> defect_frame_now(const Scenario& scenario, const std::vector<std::array<float, 3>>& positions,
                                            const PatchModel* patch);

}  // namespace heartsim
