/// @file patch_stepper.h
/// @brief A sewn patch stepped on a backend's device, where the device steps the tissue (the gl
/// backend's compute pass, runtime/gl/patch_pass.h), so the tissue is not read back to step it.
/// A repair (runtime/surgery/repair.h) finds it through SurgerySupport::patch_stepper (runtime/backend/surgery.h)
/// and steps the patch on the host where there is none.
#pragma once

#include "libmodel/surgery/patch.h"

#include <array>
#include <optional>
#include <utility>
#include <vector>

namespace heartsim {

/// One step of a sewn patch on the device: as PatchModel::step over dt_ms from time_ms, with the
/// probes it is kept out of and the mass scale of the tissue it is sewn to. `hand_output`: what
/// each hand feels of it (−1 nothing, 0 or 1 that obstacle's push, 2 + s stitch s's pull).
struct PatchPassStep {
    double dt_ms = 0.0, time_ms = 0.0, mass_scale = 1.0;
    std::vector<PatchObstacle> obstacles;
    std::array<int, 2> hand_output{-1, -1};
};

/// A backend's stepper of a sewn patch where it steps the tissue (the gl backend: a compute pass
/// before the tissue's step, runtime/gl/patch_pass.h), so the tissue is not read back to step it.
/// The pass writes the patch's loads on the tissue itself; they stay until its next step or unload().
class PatchStepper {
public:
    virtual ~PatchStepper() = default;
    /// Whether it can step `patch` (its size fits the pass).
    virtual bool takes(const PatchModel& patch) const = 0;
    /// The patch's whole state and constants, from now on (replaces a patch loaded before).
    virtual void load(const PatchPassInput& input) = 0;
    /// Only the candidates and the lists that follow them (PatchModel::pass_candidates).
    virtual void load_candidates(const PatchPassInput& input) = 0;
    /// Queues one step, before the tissue's next.
    virtual void step(const PatchPassStep& step) = 0;
    /// What its steps left, and the obstacles' forces of the last (waits for the device).
    virtual PatchPassState state(std::vector<Eigen::Vector3d>* obstacle_forces) = 0;
    /// Each hand's force from the newest finished step (PatchPassStep::hand_output), without
    /// waiting; nullopt while none has finished. `wait`: the last step's, waiting for it.
    virtual std::optional<std::array<Eigen::Vector3d, 2>> hand_forces(bool wait) = 0;
    /// Queues a copy of the patch's positions and of the tissue's particles as its last step read
    /// them, for snapshot(); nothing waits.
    virtual void request_snapshot() = 0;
    /// That copy (waiting for it only if it is not done yet): the patch's positions and the slots'
    /// (empty before the pass has stepped).
    virtual std::pair<std::vector<Eigen::Vector3d>, std::vector<Eigen::Vector3d>> snapshot() = 0;
    /// The patch's loads off the tissue; nothing is stepped until load().
    virtual void unload() = 0;
    /// The device's own time for the steps timed so far (GPU timer queries around each pass), ms,
    /// and how many were timed; `wait`: every step queued is timed first.
    virtual std::pair<double, long long> device_time(bool wait) = 0;
};

}  // namespace heartsim
