/// @file surgery.h
/// @brief The one extension of the Backend interface (runtime/backend/backend.h) for a surgery on the
/// tissue, reached through Backend::surgery(): what a repair (runtime/surgery/repair.h) needs of a backend
/// beyond stepping it (a few particles' positions, loads on them, a task beside a step, the
/// device's own patch pass) and, where a repair rides on the backend's hands, the repair itself.
/// Both backends offer it; a backend without it returns nullptr.
///
///     if (SurgerySupport* surgery = backend.surgery()) surgery->set_loads(loads);
///     if (RepairBackend* repair = repair_of(backend)) draw(repair->patch());  // runtime/surgery/repair.h
#pragma once

#include "runtime/backend/backend.h"

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace heartsim {

class PatchStepper;   // runtime/backend/patch_stepper.h
class RepairBackend;  // runtime/surgery/repair.h

class SurgerySupport {
public:
    virtual ~SurgerySupport() = default;
    /// External loads on particles from the next step on, until replaced (Solver::set_loads; the
    /// same checks). gl: uploaded at once (one small scatter), applied in the step pass.
    virtual void set_loads(const std::vector<ParticleLoad>& loads) = 0;
    /// The current positions of `particles` (packed indices, any order, repeats allowed), mm. gl:
    /// one gather pass and one small readback (waits for the GPU). Index out of range: InputError.
    virtual std::vector<std::array<float, 3>> positions_of(const std::vector<std::int32_t>& particles) = 0;
    /// One step with `task` run first: `task` may read positions_of() and set_loads(), which the
    /// step then applies. The cpu backend runs it beside the step's spring pass
    /// (Solver::run_beside_next_step: the same result to the bit, its time hidden on two cores);
    /// the gl backend runs it before the step.
    virtual StepReport step_after(const std::function<void()>& task) = 0;
    /// The device's own stepper for a sewn patch (the gl backend's compute pass), or nullptr: the
    /// host steps a patch then (runtime/surgery/repair.h).
    virtual PatchStepper* patch_stepper() { return nullptr; }
    /// The repair riding on the backend's hands (runtime/surgery/repair.h), or nullptr.
    virtual RepairBackend* repair() { return nullptr; }
};

}  // namespace heartsim
