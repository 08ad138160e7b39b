/// @file openhaptics.h
/// @brief The `openhaptics` haptic device: a 3D Systems Touch / Phantom Omni (any device the
/// OpenHaptics HD API drives) behind heartsim's Device interface. libHD is loaded with dlopen at
/// run time, so heartsim builds and runs where the SDK is absent; opening then fails with
/// DeviceUnavailable. Design, errors and what was tested: docs/openhaptics.md.
///
/// Units as HD's: position mm, force N (the same as heartsim's).
///
///     auto device = open_openhaptics({.device_name = "Left Device"});  // throws DeviceUnavailable
///     session.attach(0, device.get());
///     ...
///     if (auto* touch = dynamic_cast<OpenHapticsDevice*>(device.get()); touch && !touch->fault().empty())
///         print(touch->fault());
///
/// Threading: HD runs its own servo thread (1 kHz). One asynchronous scheduler callback per
/// device reads the pose into a LatestValue (read_pose() takes the newest, never waits) and
/// renders the newest force published by send_force() through another LatestValue, after a last
/// check (finite, clamped to limits().max_force_n) and a fade to zero when no new force arrived
/// for `force_timeout_ms` (the device thread stopped). Neither side ever blocks on the other.
#pragma once

#include "runtime/haptics/haptics.h"

#include <cstdint>
#include <memory>
#include <string>

namespace heartsim::haptics {

struct OpenHapticsOptions {
    /// The device's configured name (Touch Setup), e.g. "Left Device"; "" = HD_DEFAULT_DEVICE.
    std::string device_name;
    /// The library to dlopen: a path or a bare name (the dynamic loader's search path);
    /// "" = $HEARTSIM_OPENHAPTICS_LIB when set, else "libHD.so".
    std::string library;
    /// The newest force is held this long after it arrived, then faded linearly to zero at
    /// force_timeout_ms, ms (servo clock). Covers a late device-thread tick without a dip.
    double force_hold_ms = 15.0;
    /// No new force for this long = the device thread stopped: the rendered force is zero, ms.
    /// 45 ms: zero within 50 ms of the last send_force, counting one servo frame to take the
    /// force and one to render the zero.
    double force_timeout_ms = 45.0;
    /// Physical damping b of the device plus the hand, N·ms/mm (the passivity bound's b; HD does
    /// not report it). Default: DeviceLimits' default, not measured on a Touch.
    double damping_n_ms_per_mm = DeviceLimits{}.damping_n_ms_per_mm;
    /// No new servo frame for this long, seen by read_pose(), latches a fault, ms.
    double servo_stall_ms = 100.0;
};

/// What the servo callback did (read from any thread; counts since open).
struct OpenHapticsCounters {
    std::uint64_t servo_frames = 0;    ///< servo callbacks run
    std::uint64_t forces_received = 0; ///< new forces taken from send_force()
    std::uint64_t non_finite = 0;      ///< forces replaced by zero because not finite
    std::uint64_t clamped = 0;         ///< forces clamped to max_force_n
    std::uint64_t faded = 0;           ///< frames rendered below full gain (no new force for > force_hold_ms)
    std::uint64_t bad_poses = 0;       ///< non-finite poses from the device (the previous one kept)
};

/// An open HD device. Made by open_openhaptics(); closed (force zeroed, callback unscheduled,
/// scheduler stopped with the last device, device disabled, library closed) by the destructor.
class OpenHapticsDevice final : public Device {
public:
    struct State;  // internal: shared with the servo callback
    explicit OpenHapticsDevice(std::unique_ptr<State> state);
    ~OpenHapticsDevice() override;
    OpenHapticsDevice(const OpenHapticsDevice&) = delete;
    OpenHapticsDevice& operator=(const OpenHapticsDevice&) = delete;

    /// "openhaptics" (default device) or "openhaptics:NAME".
    std::string name() const override;
    /// max_force_n from HD_NOMINAL_MAX_CONTINUOUS_FORCE (else HD_NOMINAL_MAX_FORCE, else 3.3 N);
    /// workspace from HD_USABLE_WORKSPACE_DIMENSIONS (else DeviceLimits' default);
    /// damping from OpenHapticsOptions.
    DeviceLimits limits() const override;
    /// The newest servo sample (position mm, orientation from HD_CURRENT_TRANSFORM, buttons);
    /// never waits. Latches a fault when the servo loop delivered nothing for servo_stall_ms.
    DevicePose read_pose(double time_ms) override;
    /// Publishes the force (device frame, N) for the servo loop; never waits.
    void send_force(const Eigen::Vector3d& force_n, double time_ms) override;

    /// "" while healthy; else one line: which device, the HD error code, its name and HD's
    /// description (or the stall), when it happened. Once set, the rendered force stays zero.
    std::string fault() const;
    OpenHapticsCounters counters() const;
    /// HD_DEVICE_MODEL_TYPE, e.g. "Touch" ("" when HD does not say).
    const std::string& model() const;
    /// The library actually loaded (as given to dlopen).
    const std::string& library() const;

private:
    std::unique_ptr<State> state_;
};

/// Opens the device. Throws DeviceUnavailable with one line naming the library and the device
/// (and, where HD reported one, the HD error code, name and description) when: the library
/// cannot be loaded or lacks a symbol; hdInitDevice fails (not found, in use, no permission);
/// force output cannot be enabled; the scheduler does not start; the device is not calibrated and
/// cannot calibrate itself (HD_CALIBRATION_NEEDS_MANUAL_INPUT: put the stylus in the inkwell; an
/// update is attempted for HD_CALIBRATION_NEEDS_UPDATE when the device supports auto or inkwell
/// calibration); or the servo callback cannot be scheduled.
/// The HD scheduler is process-wide: it is started with the first open device of a library and
/// stopped with the last. Opening a second device while the first runs is untested on hardware.
std::unique_ptr<Device> open_openhaptics(const OpenHapticsOptions& options);

/// The HD error code's symbolic name ("HD_COMM_ERROR"), or "HD error 0x…" when unknown.
std::string hd_error_name(unsigned code);

}  // namespace heartsim::haptics
