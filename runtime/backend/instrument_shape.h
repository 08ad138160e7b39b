/// @file instrument_shape.h
/// @brief An instrument as the renderer draws it and a haptic run reports it: no GL.
#pragma once

#include "libmodel/sim/solver.h"

#include <Eigen/Core>

#include <cstdint>

namespace heartsim {

/// A scalpel's semi-axes when none are given (mm): a blade 20 mm long (2·az), 4 mm wide and
/// 0.6 mm thick, of the order of a No. 11 or No. 15 blade.
inline const Eigen::Vector3d default_blade_semi_axes_mm{2.0, 0.3, 10.0};

/// An instrument to draw: the ellipsoid of `semi_axes` (mm, tool frame) at `pose`; a scalpel's
/// blade, the segment from the tip along the tool's +z, 2·az long, is the flat ellipsoid around
/// it, centred half way along (drawn_centre).
struct InstrumentShape {
    InstrumentKind kind = InstrumentKind::probe;
    InstrumentPose pose;
    Eigen::Vector3d semi_axes{2.0, 2.0, 2.0};
    int hand = -1;  ///< 0 or 1 where known (the HUD's force arrows), -1 otherwise
    bool touching = false;  ///< in contact with the tissue (a force on it): drawn in the contact colour
    std::uint32_t buttons = 0;  ///< a haptic device's buttons as the last step read them (bit 0: button 1)

    /// Where the drawn ellipsoid is centred: the pose's position, or, for a scalpel, the middle
    /// of its blade.
    Eigen::Vector3d drawn_centre() const {
        if (kind != InstrumentKind::scalpel) return pose.position;
        return pose.position + semi_axes.z() * (pose.orientation.normalized() * Eigen::Vector3d::UnitZ());
    }
};

}  // namespace heartsim
