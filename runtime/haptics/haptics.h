/// @file haptics.h
/// @brief The haptic core: the Device interface, the lock-free exchange between the device thread
/// and the simulation, force hold / first-order extrapolation, optional virtual coupling within
/// the passivity bound, the ForceSafety filter, the device thread with period statistics, and
/// two devices (`scripted`, `simulated`). Design and bounds: docs/haptics.md.
///
/// Units: mm, g, ms; force N (= g·mm/ms²); stiffness N/mm; damping N·ms/mm (= N·s/m).
/// Forces are "the force the tissue exerts on the instrument" (docs/solver.md): rendered as is.
///
///     SimulatedDevice device({...});
///     HapticSession session({.rate_hz = 1000});
///     session.attach(0, &device);
///     session.start();                                        // device thread, steady clock
///     // simulation thread:
///     if (auto tools = session.latest_tools()) backend->set_pose(0, tools->hand[0].pose);
///     backend->step();
///     session.publish_forces(backend->instrument_forces(), session.now_ms());
///     session.stop();  print(session.period_stats());
///
/// One header per part, all in runtime/haptics/: exchange.h, devices.h, safety.h, coupling.h,
/// session.h; this one includes them all.
#pragma once

#include "runtime/haptics/coupling.h"
#include "runtime/haptics/devices.h"
#include "runtime/haptics/exchange.h"
#include "runtime/haptics/safety.h"
#include "runtime/haptics/session.h"
