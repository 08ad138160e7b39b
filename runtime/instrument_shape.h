/// @file instrument_shape.h
/// @brief An instrument as the renderer draws it and a haptic run reports it: no GL.
#pragma once

#include "libmodel/solver.h"

#include <Eigen/Core>

namespace heartsim {

/// An instrument to draw: the ellipsoid of `semi_axes` (mm, tool frame) at `pose`.
struct InstrumentShape {
    InstrumentKind kind = InstrumentKind::probe;
    InstrumentPose pose;
    Eigen::Vector3d semi_axes{2.0, 2.0, 2.0};
    int hand = -1;  ///< 0 or 1 where known (the HUD's force arrows), -1 otherwise
};

}  // namespace heartsim
