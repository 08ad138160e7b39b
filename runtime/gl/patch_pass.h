/// @file patch_pass.h
/// @brief A sewn patch stepped by a compute pass before the tissue's step, on the tissue's own
/// position and load buffers (shaders/patch_shaders.h): the gl backend's PatchStepper
/// (runtime/backend/patch_stepper.h). Nothing is read back to step it; the hands' forces come back through a
/// small fenced ring, as the instruments' do.
#pragma once

#include "runtime/backend/patch_stepper.h"

#include <functional>
#include <memory>

namespace heartsim {

/// `positions()`: the name of the buffer holding the tissue's current positions (it rotates with
/// each substep); `loads`: the tissue's load buffer; `loaded(on)`: the step pass reads the load
/// buffer while some patch or set_loads loads lie there. `n_particles`: the tissue's particle count.
std::unique_ptr<PatchStepper> make_gl_patch_pass(std::function<unsigned()> positions, unsigned loads, std::function<void(bool)> loaded,
                                                 std::size_t n_particles);

}  // namespace heartsim
