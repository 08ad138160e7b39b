/// @file session.h
/// @brief HapticSession: the device thread at a fixed rate, what it exchanges with the simulation
/// (tool samples one way, force samples the other), its period and latency statistics and its
/// tick recording. Implementation: session.cpp.
#pragma once

#include "runtime/haptics/coupling.h"
#include "runtime/haptics/devices.h"
#include "runtime/haptics/exchange.h"
#include "runtime/haptics/safety.h"

#include "libmodel/sim/solver.h"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace heartsim::haptics {

/// Device thread → simulation: the tool pose of each hand (world frame), buttons, when.
struct ToolSample {
    InstrumentPose pose;
    std::uint32_t buttons = 0;
    /// Presses of button 1 (its rises) since the session began: a counter, so a press that begins
    /// and ends between two simulation steps still reaches the simulation (a 20 ms press of a
    /// patch's button while a step takes longer).
    std::uint64_t presses = 0;
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
    double max_force_n = 0.0;                                 ///< the largest |force| sent, N
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
    /// From any thread while running: the p99 of the device thread's periods so far, ms, refreshed
    /// every 500 periods (the window's HUD); < 0 before the first refresh.
    double live_period_p99_ms() const { return live_period_p99_ms_.load(std::memory_order_relaxed); }
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
        std::uint32_t buttons = 0;   ///< at the last tick
        std::uint64_t presses = 0;   ///< ToolSample::presses
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
    std::atomic<double> live_period_p99_ms_{-1.0};
    std::uint64_t overruns_ = 0;
    DurationHistogram latencies_{100, 1000.0};
    SpscQueue<TickRecord> ticks_queue_;
};

std::string format_period_stats(const PeriodStats& stats, double rate_hz);

}  // namespace heartsim::haptics
