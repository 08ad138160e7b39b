/// @file backend_gl.h
/// @brief The gl backend (runtime/backend/backend.h): the step, the instruments and the force buffer as
/// compute shaders on the scenario's packed layout, in the current OpenGL 4.3+ context.
#pragma once

#include "runtime/backend/backend.h"

#include <memory>

namespace heartsim {

class GlContext;

/// Device memory the GL backend will allocate for `scenario`, bytes (printed before allocating).
std::size_t estimate_gl_memory_bytes(const Scenario& scenario);

/// The GL backend on the current context of `context`. Throws InputError if the scenario has no
/// /packing, GlUnavailable if the context cannot run it (or a shader fails to build).
std::unique_ptr<Backend> make_gl_backend(GlContext& context, const Scenario& scenario, const SolverOptions& options);

/// The GL name of the shader storage buffer holding `backend`'s current positions (float4 per
/// particle, packed order, w unused) when it is the gl backend, for the passes that read them in
/// place (visualisation); valid until its next step(), which rotates the buffers. 0 for any other
/// backend (its positions must be uploaded).
unsigned gl_position_buffer(const Backend& backend);

}  // namespace heartsim
