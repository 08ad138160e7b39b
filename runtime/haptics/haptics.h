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
#pragma once

#include "libmodel/solver.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace heartsim::haptics {

// ------------------------------------------------------------------------------------------------
// Lock-free latest-value exchange

/// Single writer, single reader, wait-free: the writer publishes whole values, the reader gets the
/// newest complete one (older ones may be skipped, never torn). A triple buffer: the writer fills
/// its back slot and swaps it with the shared middle slot (an atomic index with a "fresh" bit);
/// the reader swaps its front slot with the middle one when fresh. No locks, no allocation.
template <class T>
class LatestValue {
public:
    /// Writer side only.
    void publish(const T& value) {
        slots_[back_] = value;
        back_ = middle_.exchange(back_ | fresh_bit, std::memory_order_acq_rel) & index_mask;
    }
    /// Reader side only: the newest value into `out`; true when it is newer than the last fetch.
    /// Before the first publish, `out` gets a default T and false.
    bool fetch(T& out) {
        bool fresh = false;
        if (middle_.load(std::memory_order_acquire) & fresh_bit) {
            front_ = middle_.exchange(front_, std::memory_order_acq_rel) & index_mask;
            fresh = true;
        }
        out = slots_[front_];
        return fresh;
    }

private:
    static constexpr unsigned fresh_bit = 4, index_mask = 3;
    std::array<T, 3> slots_{};
    alignas(64) std::atomic<unsigned> middle_{1};
    alignas(64) unsigned back_ = 0;   // writer's
    alignas(64) unsigned front_ = 2;  // reader's
};

/// Single producer, single consumer queue of fixed capacity, wait-free: the device thread pushes
/// one record per tick, the simulation thread drains them. A full queue drops the new record and
/// counts it (the device thread never waits and never allocates).
template <class T>
class SpscQueue {
public:
    explicit SpscQueue(std::size_t capacity = 0) { reset(capacity); }
    /// Not concurrently with push / drain.
    void reset(std::size_t capacity) {
        std::size_t c = 1;
        while (c < capacity) c <<= 1;
        slots_.assign(capacity ? c : 0, T{});
        head_.store(0), tail_.store(0), dropped_.store(0);
    }
    bool enabled() const { return !slots_.empty(); }
    /// Producer only.
    bool push(const T& value) {
        const std::size_t tail = tail_.load(std::memory_order_relaxed);
        if (slots_.empty() || tail - head_.load(std::memory_order_acquire) >= slots_.size()) {
            dropped_.fetch_add(1, std::memory_order_relaxed);
            return false;
        }
        slots_[tail & (slots_.size() - 1)] = value;
        tail_.store(tail + 1, std::memory_order_release);
        return true;
    }
    /// Consumer only: appends everything queued to `out`; returns how many.
    std::size_t drain(std::vector<T>& out) {
        const std::size_t head = head_.load(std::memory_order_relaxed), tail = tail_.load(std::memory_order_acquire);
        for (std::size_t i = head; i < tail; ++i) out.push_back(slots_[i & (slots_.size() - 1)]);
        head_.store(tail, std::memory_order_release);
        return tail - head;
    }
    std::uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

private:
    std::vector<T> slots_;
    alignas(64) std::atomic<std::size_t> head_{0};
    alignas(64) std::atomic<std::size_t> tail_{0};
    std::atomic<std::uint64_t> dropped_{0};
};

// ------------------------------------------------------------------------------------------------
// Devices

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
    DevicePose read_pose(double) override {
        pose_.fetch(current_);
        return current_;
    }
    void send_force(const Eigen::Vector3d& force_n, double) override { force_.publish(force_n); }
    /// Window thread only.
    void set_pose(const DevicePose& pose) {
        last_set_ = pose;
        pose_.publish(pose);
    }
    /// Window thread only: the pose it last set.
    const DevicePose& last_set() const { return last_set_; }
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
    DevicePose last_set_;   // window thread's
    LatestValue<Eigen::Vector3d> force_;
};

// ------------------------------------------------------------------------------------------------
// Safety

struct SafetySettings {
    double max_force_n = 0.0;          ///< 0 = the device's limit; never above it
    double max_rate_n_per_ms = 0.5;    ///< |Δf| per ms (3.3 N in 6.6 ms)
    double stall_ms = 30.0;            ///< no new simulation force for this long = stalled
    double fade_out_ms = 40.0;         ///< gain 1 → 0 (≤ 50 ms by requirement)
    double fade_in_ms = 100.0;         ///< gain 0 → 1 once healthy again
};

/// What the device thread knows about the simulation this tick.
struct SafetyInput {
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();  ///< candidate, device frame (may be NaN)
    double now_ms = 0.0;
    bool simulation_fresh = false;  ///< a new force arrived within stall_ms
    bool fault_event = false;       ///< the simulation diverged or was reset since the last tick
    bool clean_update = false;      ///< a new force arrived this tick, with no fault since the previous
};

/// The chain every force passes on the device thread before any device gets it:
///  1. non-finite → zero (and the gain fades, as for a stall);
///  2. clamp |f| to the maximum force (direction kept);
///  3. rate limit: |Δf| ≤ max_rate·Δt;
///  4. gain g ∈ [0, 1]: falls at 1/fade_out_ms while the simulation is stale, faulted or the input
///     non-finite; a divergence or reset latches the fault until g reached 0 and a clean update
///     arrived; rises at 1/fade_in_ms when healthy;
///  5. emergency stop: zero at once (this tick), latched until released; then fades in;
///  6. a last check: finite and within the maximum, else zero.
class ForceSafety {
public:
    ForceSafety(const SafetySettings& settings, double device_max_force_n);
    Eigen::Vector3d filter(const SafetyInput& input);
    void emergency_stop() { estop_ = true; }
    void release_emergency_stop() { estop_ = false; }
    bool stopped() const { return estop_; }
    double gain() const { return gain_; }
    double max_force_n() const { return max_force_; }

    struct Counters {
        std::uint64_t ticks = 0, clamped = 0, rate_limited = 0, non_finite = 0, faults = 0, stopped = 0;
    };
    const Counters& counters() const { return counters_; }

private:
    SafetySettings settings_;
    double max_force_ = 0.0;
    Eigen::Vector3d limited_ = Eigen::Vector3d::Zero();  ///< after steps 1–3
    double gain_ = 0.0;
    double last_ms_ = 0.0;
    bool started_ = false, latched_fault_ = false, estop_ = false;
    Counters counters_;
};

// ------------------------------------------------------------------------------------------------
// Coupling

enum class ForceInterpolation { hold, extrapolate };
const char* to_string(ForceInterpolation mode);

/// Spring-damper between the device (x_d) and a tool proxy (x_p, mass m_p, damping c_p to
/// ground) that the simulation sees: the proxy feels the tissue force plus K(x_d − x_p) +
/// B(v_d − v_p); the device is sent K(x_p − x_d) + B(v_p − v_d).
struct CouplingSettings {
    bool enabled = false;
    double stiffness_n_per_mm = 0.0;   ///< K
    double damping_n_ms_per_mm = 0.0;  ///< B
    double proxy_mass_g = 10.0;        ///< m_p
    double proxy_damping_n_ms_per_mm = 0.0;  ///< c_p; 0 = 2√(K·m_p) (critical on the spring)
};

/// The passivity bound of a sampled virtual spring-damper (Colgate & Schenkel 1997):
/// b > K·T/2 + B, b the device's physical damping, T the sampling period. Returns K, B with
/// B = b/4 and K = margin · 2(b − B)/T (margin < 1 keeps it strictly inside).
CouplingSettings choose_coupling(double device_damping_n_ms_per_mm, double period_ms, double margin = 0.5);
/// True when b > K·T/2 + B.
bool within_passivity_bound(const CouplingSettings& coupling, double device_damping_n_ms_per_mm, double period_ms);

/// Device frame → world (simulation) frame: x_w = offset + scale · R · x_d, q_w = R · q_d.
/// Forces go back as f_d = force_scale · Rᵀ · f_w.
struct DeviceMapping {
    Eigen::Vector3d offset_mm = Eigen::Vector3d::Zero();
    Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
    double scale = 1.0;
    double force_scale = 1.0;
};

// ------------------------------------------------------------------------------------------------
// The session: device thread ↔ simulation

/// Device thread → simulation: the tool pose of each hand (world frame), buttons, when.
struct ToolSample {
    InstrumentPose pose;
    std::uint32_t buttons = 0;
    double time_ms = 0.0;  ///< session clock
    bool valid = false;    ///< a device is attached to the hand
};
struct ToolSamples {
    std::array<ToolSample, 2> hand;
    std::uint64_t tick = 0;
};

/// Simulation → device thread: both hands' forces from one readback (world frame), when, and
/// event counters (counters, not flags, so an event is never lost when samples are skipped).
struct ForceSample {
    std::array<Eigen::Vector3d, 2> force_n{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    double time_ms = 0.0;            ///< session clock when published
    std::uint64_t sequence = 0;      ///< 1, 2, …; 0 = none yet
    std::uint64_t divergences = 0;   ///< cumulative
    std::uint64_t resets = 0;        ///< cumulative
    /// Session clock of the tool sample the step that produced these forces used (its pose is
    /// what they reflect); < 0 = unknown. The device thread measures pose → force latency by it.
    double tool_time_ms = -1.0;
};

struct HapticSettings {
    double rate_hz = 1000.0;
    ForceInterpolation interpolation = ForceInterpolation::hold;
    CouplingSettings coupling{};  ///< coupling.enabled with K = 0: choose_coupling() per device
    SafetySettings safety{};
    /// Ask the OS to run the device thread ahead of the simulation and rendering (Linux
    /// SCHED_FIFO); where that is not permitted the thread runs with normal scheduling and
    /// scheduling() says why.
    bool realtime = true;
};

/// Period statistics of the device thread, ms.
struct PeriodStats {
    std::uint64_t ticks = 0;
    double p50_ms = 0.0, p99_ms = 0.0, max_ms = 0.0, mean_ms = 0.0;
    std::uint64_t overruns = 0;  ///< ticks that started more than one period late (skipped ahead)
};

/// Durations in fixed-width bins (the last one open for everything longer) with their count, sum
/// and maximum; one writer, no allocation after construction. The device thread keeps its
/// period and pose → force latency statistics in two of these.
class DurationHistogram {
public:
    DurationHistogram(int bins_per_ms, double span_ms)
        : bins_per_ms_(bins_per_ms), counts_(std::size_t(bins_per_ms * span_ms) + 1, 0) {}
    void add(double ms) {
        ++counts_[std::size_t(std::clamp(int(ms * bins_per_ms_), 0, int(counts_.size()) - 1))];
        max_ms_ = std::max(max_ms_, ms);
        sum_ms_ += ms;
        ++count_;
    }
    std::uint64_t count() const { return count_; }
    double max_ms() const { return max_ms_; }
    double mean_ms() const { return count_ ? sum_ms_ / double(count_) : 0.0; }
    /// The q-quantile as the centre of the bin that reaches it, never above the maximum seen.
    double quantile_ms(double q) const;

private:
    int bins_per_ms_;
    std::vector<std::uint32_t> counts_;
    double max_ms_ = 0.0, sum_ms_ = 0.0;
    std::uint64_t count_ = 0;
};

/// Pose → force latency, ms: from a tool sample (device read) to the tick that first sends a force
/// computed from it (measured on the device thread when the force arrives).
struct LatencyStats {
    std::uint64_t samples = 0;
    double p50_ms = 0.0, p99_ms = 0.0, max_ms = 0.0, mean_ms = 0.0;
};

/// One device-thread tick, for recording (HapticSession::enable_tick_recording).
struct TickRecord {
    double time_ms = 0.0;
    std::uint64_t tick = 0;
    std::array<DevicePose, 2> pose{};                 ///< device frame, as read
    std::array<Eigen::Vector3d, 2> input_n{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};  ///< before safety
    std::array<Eigen::Vector3d, 2> force_n{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};  ///< sent
    std::array<float, 2> gain{};
    bool estop = false;            ///< the emergency stop was engaged this tick
    bool simulation_fresh = false; ///< a simulation force arrived within stall_ms
};

/// What one hand did on the device thread (read after stop(), or from the thread calling tick()).
struct HandTelemetry {
    Eigen::Vector3d last_force_n = Eigen::Vector3d::Zero();   ///< sent to the device (device frame)
    Eigen::Vector3d last_input_n = Eigen::Vector3d::Zero();   ///< before safety (device frame)
    std::uint64_t forces_sent = 0;
    ForceSafety::Counters safety{};
    double gain = 0.0;
};

class HapticSession {
public:
    explicit HapticSession(const HapticSettings& settings = {});
    ~HapticSession();
    HapticSession(const HapticSession&) = delete;
    HapticSession& operator=(const HapticSession&) = delete;

    /// Hand 0 or 1 (before start()); the device is not owned and must outlive the session.
    void attach(int hand, Device* device, const DeviceMapping& mapping = {});
    double period_ms() const { return 1000.0 / settings_.rate_hz; }
    const HapticSettings& settings() const { return settings_; }
    /// The coupling in use for a hand (chosen per device when settings asked for K = 0).
    const CouplingSettings& coupling(int hand) const { return hands_[hand].coupling; }

    // --- simulation side (one thread) -----------------------------------------------------------
    /// Publishes both hands' forces from one InstrumentForces (world frame). `diverged`: the step
    /// that produced them hit the watchdog; `reset`: the simulation was reset.
    /// `tool_time_ms`: ToolSample::time_ms of the poses the producing step used (latency), or < 0.
    void publish_forces(const InstrumentForces& forces, double time_ms, bool diverged = false, bool reset = false,
                        double tool_time_ms = -1.0);
    /// The newest tool poses, or nullopt before the first tick.
    std::optional<ToolSamples> latest_tools();

    // --- device side ----------------------------------------------------------------------------
    /// One device-thread period at session time `now_ms`: read poses, publish tools, take the
    /// newest forces, interpolate, couple, run ForceSafety, send. Used by the thread, and directly
    /// by tests with simulated time (then do not start()).
    void tick(double now_ms);
    /// The device thread at rate_hz on std::chrono::steady_clock; stop() joins it.
    void start();
    void stop();
    bool running() const { return thread_.joinable(); }
    /// The session clock, ms since construction (steady_clock).
    double now_ms() const;

    /// From any thread: zero every device's force at the next tick (≤ one period), latched.
    void emergency_stop() { estop_.store(true, std::memory_order_release); }
    void release_emergency_stop() { estop_.store(false, std::memory_order_release); }

    /// After stop() (or from the ticking thread).
    PeriodStats period_stats() const;
    LatencyStats latency_stats() const;
    /// How the device thread is scheduled, e.g. "SCHED_FIFO priority 80" or "normal (SCHED_FIFO
    /// refused: Operation not permitted)"; empty before start().
    std::string scheduling() const;
    HandTelemetry telemetry(int hand) const;

    /// Before start(): keep a TickRecord of every tick in a queue of `capacity` (0 = off), which
    /// the simulation thread empties with drain_ticks() well within capacity ticks.
    void enable_tick_recording(std::size_t capacity) { ticks_queue_.reset(capacity); }
    std::size_t drain_ticks(std::vector<TickRecord>& out) { return ticks_queue_.drain(out); }
    std::uint64_t dropped_ticks() const { return ticks_queue_.dropped(); }

private:
    struct Hand {
        Device* device = nullptr;
        DeviceMapping mapping;
        CouplingSettings coupling;
        std::unique_ptr<ForceSafety> safety;
        // interpolation: the two newest samples of this hand
        Eigen::Vector3d f1 = Eigen::Vector3d::Zero(), f0 = Eigen::Vector3d::Zero();
        double t1 = 0.0, t0 = 0.0;
        int samples = 0;
        // coupling
        Eigen::Vector3d proxy = Eigen::Vector3d::Zero(), proxy_v = Eigen::Vector3d::Zero();
        Eigen::Vector3d last_device = Eigen::Vector3d::Zero();
        bool primed = false;
        HandTelemetry telemetry;
    };
    void run_thread();

    HapticSettings settings_;
    std::array<Hand, 2> hands_;
    LatestValue<ToolSamples> tools_;
    LatestValue<ForceSample> forces_;
    // simulation-side counters
    std::uint64_t published_ = 0, divergences_ = 0, resets_ = 0;
    // device-side state
    ForceSample last_sample_{};
    double last_arrival_ms_ = -1e300;
    double last_tick_ms_ = 0.0;
    bool ticked_ = false;
    std::uint64_t ticks_ = 0;
    std::atomic<bool> estop_{false};
    std::atomic<bool> stop_{false};
    std::thread thread_;
    std::string scheduling_;          ///< written by start() before the thread runs its loop
    std::chrono::steady_clock::time_point epoch_;
    // Written by the device thread only: periods in 1 µs bins up to 20 ms, pose → force latency
    // in 10 µs bins up to 1 s.
    DurationHistogram periods_{1000, 20.0};
    std::uint64_t overruns_ = 0;
    DurationHistogram latencies_{100, 1000.0};
    SpscQueue<TickRecord> ticks_queue_;
};

std::string format_period_stats(const PeriodStats& stats, double rate_hz);

}  // namespace heartsim::haptics
