/// @file devices.h
/// @brief The Device interface the device thread drives, and three devices: `scripted` (poses
/// from a CSV), `simulated` (a damped point mass under a scripted hand force) and `mouse` (the
/// window). The OpenHaptics device is in openhaptics.h. Implementations: devices.cpp.
#pragma once

#include "runtime/haptics/exchange.h"

#include <Eigen/Core>
#include <algorithm>
#include <atomic>
#include <Eigen/Geometry>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace heartsim::haptics {

/// A haptic device that cannot be used: not found, not calibrated, its driver or scheduler
/// failed, or a device that needs a window in a headless run. heartsim exits 4 with the message.
class DeviceUnavailable : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// A device sample: position mm and orientation (device frame), buttons as bits.
struct DevicePose {
    Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();
    Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
    std::uint32_t buttons = 0;
    /// Presses of button 1 since the start, where the device knows every one (a script, even a
    /// press shorter than the ticks' spacing or over before the first tick); 0 where it does not
    /// (the session counts the presses its ticks see).
    std::uint64_t presses = 0;
};

struct DeviceLimits {
    double max_force_n = 3.3;  ///< the largest force the device may be sent (Touch / Omni: 3.3 N)
    /// Reachable positions, device frame, mm (empty box = unbounded).
    Eigen::AlignedBox3d workspace_mm{Eigen::Vector3d(-80, -60, -35), Eigen::Vector3d(80, 60, 35)};
    /// Physical damping b of the device (plus the hand holding it), N·ms/mm: the passivity
    /// bound's b (virtual stiffness K within b > K·T/2 + B).
    double damping_n_ms_per_mm = 0.02;
};

/// A haptic device seen from the device thread. Both calls are made from that thread only, once
/// per tick each, read_pose first; `time_ms` is the session clock (monotonic). Implementations
/// must not block.
class Device {
public:
    virtual ~Device() = default;
    virtual std::string name() const = 0;
    virtual DeviceLimits limits() const = 0;
    virtual DevicePose read_pose(double time_ms) = 0;
    /// Renders `force_n` (device frame) from now until the next call. Always finite and within
    /// limits() when it comes from a HapticSession (ForceSafety runs first).
    virtual void send_force(const Eigen::Vector3d& force_n, double time_ms) = 0;
};

/// `scripted`: replays poses from a CSV, interpolated (linear position, slerp orientation),
/// buttons from the keyframe at or before; holds the last keyframe after the end. Ignores forces
/// (it records the last one sent).
///     time_ms, x, y, z, qw, qx, qy, qz[, buttons]
/// Header line optional, `#` starts a comment; units mm, ms; orientation normalised on read.
struct PoseKeyframe {
    double time_ms = 0.0;
    DevicePose pose;
};
std::vector<PoseKeyframe> parse_pose_script(const std::string& text, const std::string& name);
std::vector<PoseKeyframe> read_pose_script(const std::filesystem::path& path);

class ScriptedDevice final : public Device {
public:
    explicit ScriptedDevice(std::vector<PoseKeyframe> keyframes, DeviceLimits limits = {});
    std::string name() const override { return "scripted"; }
    DeviceLimits limits() const override { return limits_; }
    DevicePose read_pose(double time_ms) override;
    void send_force(const Eigen::Vector3d& force_n, double) override { last_force_ = force_n; }
    DevicePose pose_at(double time_ms) const;
    const Eigen::Vector3d& last_force() const { return last_force_; }

private:
    std::vector<PoseKeyframe> keyframes_;
    std::vector<std::uint64_t> presses_;  ///< presses of button 1 up to and including each keyframe
    DeviceLimits limits_;
    Eigen::Vector3d last_force_ = Eigen::Vector3d::Zero();
};

/// A hand force over time, N, device frame; piecewise linear between rows of a CSV
/// `time_ms, fx, fy, fz` (header optional, `#` comments), held after the last row.
using HandForce = std::function<Eigen::Vector3d(double time_ms)>;
HandForce parse_hand_force(const std::string& text, const std::string& name);
HandForce read_hand_force(const std::filesystem::path& path);

/// `simulated`: a point mass m with viscous damping b pushed by a scripted hand force plus the
/// rendered force (held between ticks, as a real amplifier does): m ẍ = f_hand + f_render − b ẋ,
/// integrated exactly for the damping over each interval between read_pose calls. Leaving the
/// workspace stops it at the wall (velocity component zeroed). Keeps the energy account: the work
/// the rendered force did on it, mJ (N·mm).
struct SimulatedDeviceSettings {
    double mass_g = 50.0;
    double damping_n_ms_per_mm = 0.02;
    Eigen::Vector3d start_mm = Eigen::Vector3d::Zero();
    HandForce hand_force{};  ///< empty = no hand
    DeviceLimits limits{};   ///< limits.damping_n_ms_per_mm is set from damping_n_ms_per_mm
};

class SimulatedDevice final : public Device {
public:
    explicit SimulatedDevice(SimulatedDeviceSettings settings);
    std::string name() const override { return "simulated"; }
    DeviceLimits limits() const override { return settings_.limits; }
    DevicePose read_pose(double time_ms) override;
    void send_force(const Eigen::Vector3d& force_n, double time_ms) override;

    const Eigen::Vector3d& position() const { return x_; }
    const Eigen::Vector3d& velocity() const { return v_; }
    double kinetic_energy_mj() const { return 0.5 * settings_.mass_g * v_.squaredNorm(); }
    double rendered_work_mj() const { return rendered_work_mj_; }  ///< ∫ f_render · dx
    double hand_work_mj() const { return hand_work_mj_; }          ///< ∫ f_hand · dx
    const Eigen::Vector3d& rendered_force() const { return force_; }

private:
    void advance(double to_ms);
    SimulatedDeviceSettings settings_;
    Eigen::Vector3d x_, v_ = Eigen::Vector3d::Zero(), force_ = Eigen::Vector3d::Zero();
    double time_ms_ = 0.0;
    bool started_ = false;
    double rendered_work_mj_ = 0.0, hand_work_mj_ = 0.0;
};

/// `mouse`: the window's mouse and keyboard drive this device. The window (main) thread moves it
/// with set_pose(); the device thread reads the newest pose and sends forces, which the window
/// reads back with latest_force() to show them. Poses are in the world frame (mapping identity).
class WindowDevice final : public Device {
public:
    explicit WindowDevice(DeviceLimits limits = {}) : limits_(limits) { limits_.workspace_mm.setEmpty(); }
    std::string name() const override { return "mouse"; }
    DeviceLimits limits() const override { return limits_; }
    /// The pose the window set, approached at most max_speed_mm_per_ms from where the device
    /// was: a hand moves, it does not jump (a click that puts the device on the surface, a fast
    /// drag); a jump of millimetres within one simulation step would pierce the tissue.
    DevicePose read_pose(double now_ms) override {
        DevicePose target;
        pose_.fetch(target);
        const Eigen::Vector3d from = current_.position_mm;
        const double dt = started_ ? std::clamp(now_ms - last_ms_, 0.0, 100.0) : 0.0;
        const Eigen::Vector3d step = target.position_mm - from;
        const double reach = max_speed_mm_per_ms * dt;
        current_ = target;
        if (started_ && step.norm() > reach) current_.position_mm = from + step * (reach / step.norm());
        started_ = true;
        last_ms_ = now_ms;
        return current_;
    }
    static constexpr double max_speed_mm_per_ms = 0.2;  ///< 200 mm/s: a quick hand
    void send_force(const Eigen::Vector3d& force_n, double) override {
        force_.publish(force_n);
        const double f = force_n.norm();
        double peak = peak_.load(std::memory_order_relaxed);
        while (f > peak && !peak_.compare_exchange_weak(peak, f, std::memory_order_relaxed)) {}
    }
    /// Window thread only.
    void set_pose(const DevicePose& pose) {
        last_set_ = pose;
        pose_.publish(pose);
    }
    /// Window thread only: the pose it last set.
    const DevicePose& last_set() const { return last_set_; }
    /// Window thread only: the largest |force| sent since the last call, N (the device thread sends
    /// a thousand a second; a frame sees one of them).
    double peak_force_since_last() { return peak_.exchange(0.0, std::memory_order_relaxed); }
    /// Window thread only: the newest force sent (zero before the first).
    Eigen::Vector3d latest_force() {
        Eigen::Vector3d f = Eigen::Vector3d::Zero();
        force_.fetch(f);
        return f;
    }

private:
    DeviceLimits limits_;
    LatestValue<DevicePose> pose_;
    DevicePose current_;    // device thread's
    bool started_ = false;  // device thread's: a pose was read
    double last_ms_ = 0.0;  // device thread's: when
    DevicePose last_set_;   // window thread's
    LatestValue<Eigen::Vector3d> force_;
    std::atomic<double> peak_{0.0};
};

}  // namespace heartsim::haptics
