/// @file info_verdict.h
/// @brief `heartsim info`'s verdict: which backend a window or haptic session will simulate on
/// with this machine's OpenGL device, and the real-time factor measured here on a lattice of
/// 30,000 particles.
#pragma once

#include "runtime/gl/gl_context.h"

#include <string>

namespace heartsim {

/// Measures, for about `seconds` of wall time, the backend a session would use (the cpu backend
/// on a software rasteriser, else gl on `context`) stepping the scenario at `scenario_path`, or
/// without one a 31 × 31 × 31 block of myocardium particles 1.5 mm apart (no supports, no gravity,
/// unstressed: its substep is longer than a real heart's of as many particles, whose supports and
/// dashpots shorten it), and returns the verdict's lines. Throws InputError for a scenario it cannot read.
std::string session_verdict(GlContext& context, const std::string& scenario_path = {}, double seconds = 1.0);

}  // namespace heartsim
