// The haptic session (session.h): the device thread and its statistics. Design: docs/haptics.md.
#include "runtime/haptics/session.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>

#include <pthread.h>
#include <sched.h>

namespace heartsim::haptics {

double DurationHistogram::quantile_ms(double q) const {
    const std::uint64_t target = std::uint64_t(std::ceil(q * double(count_)));
    std::uint64_t seen = 0;
    for (std::size_t b = 0; b < counts_.size(); ++b) {
        seen += counts_[b];
        if (seen >= target) return std::min((double(b) + 0.5) / bins_per_ms_, max_ms_);
    }
    return max_ms_;
}

HapticSession::HapticSession(const HapticSettings& settings)
    : settings_(settings), epoch_(std::chrono::steady_clock::now()) {
    if (!(settings.rate_hz >= 1.0 && settings.rate_hz <= 20000.0))
        throw InputError("haptics: the haptic rate must be between 1 and 20000 Hz");
}

HapticSession::~HapticSession() { stop(); }

void HapticSession::attach(int hand, Device* device, const DeviceMapping& mapping) {
    if (hand < 0 || hand > 1) throw InputError("haptics: hand must be 0 or 1");
    if (running()) throw InputError("haptics: attach devices before start()");
    Hand& h = hands_[hand];
    h = Hand{};
    h.device = device;
    h.mapping = mapping;
    h.mapping.rotation.normalize();
    if (!device) return;
    const DeviceLimits limits = device->limits();
    h.safety = std::make_unique<ForceSafety>(settings_.safety, limits.max_force_n);
    h.coupling = settings_.coupling;
    if (h.coupling.enabled && h.coupling.stiffness_n_per_mm <= 0.0) {
        const CouplingSettings chosen = choose_coupling(limits.damping_n_ms_per_mm, period_ms());
        h.coupling.stiffness_n_per_mm = chosen.stiffness_n_per_mm;
        h.coupling.damping_n_ms_per_mm = chosen.damping_n_ms_per_mm;
    }
    if (h.coupling.enabled) {
        if (!(h.coupling.proxy_mass_g > 0.0)) throw InputError("haptics: the coupling proxy needs a positive mass");
        if (h.coupling.proxy_damping_n_ms_per_mm <= 0.0)
            h.coupling.proxy_damping_n_ms_per_mm = 2.0 * std::sqrt(h.coupling.stiffness_n_per_mm * h.coupling.proxy_mass_g);
    }
}

void HapticSession::publish_forces(const InstrumentForces& forces, double time_ms, bool diverged, bool reset, double tool_time_ms) {
    ForceSample s;
    s.tool_time_ms = tool_time_ms;
    for (int i = 0; i < 2; ++i) s.force_n[i] = forces.hand[i].force_n;
    s.time_ms = time_ms;
    s.sequence = ++published_;
    if (diverged) ++divergences_;
    if (reset) ++resets_;
    s.divergences = divergences_;
    s.resets = resets_;
    forces_.publish(s);
}

std::optional<ToolSamples> HapticSession::latest_tools() {
    ToolSamples t;
    tools_.fetch(t);
    if (t.tick == 0) return std::nullopt;
    return t;
}

double HapticSession::now_ms() const {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - epoch_).count();
}

void HapticSession::tick(double now_ms) {
    const double dt = ticked_ ? std::max(now_ms - last_tick_ms_, 1e-6) : period_ms();
    ticked_ = true;
    last_tick_ms_ = now_ms;
    ++ticks_;

    // The newest forces.
    ForceSample sample;
    const bool fresh = forces_.fetch(sample) && sample.sequence != last_sample_.sequence && sample.sequence != 0;
    bool fault_event = false, clean_update = false, divergence = false;
    if (fresh) {
        divergence = sample.divergences != last_sample_.divergences;
        fault_event = divergence || sample.resets != last_sample_.resets;
        clean_update = !fault_event;
        last_arrival_ms_ = now_ms;
        last_sample_ = sample;
        if (sample.tool_time_ms >= 0.0 && sample.tool_time_ms <= now_ms) {
            latencies_.add(now_ms - sample.tool_time_ms);
        }
    }
    const bool simulation_fresh = last_sample_.sequence != 0 && now_ms - last_arrival_ms_ <= settings_.safety.stall_ms;
    const bool stop = estop_.load(std::memory_order_acquire);

    ToolSamples tools;
    tools.tick = ticks_;
    TickRecord record;
    record.time_ms = now_ms;
    record.tick = ticks_;
    record.estop = stop;
    record.simulation_fresh = simulation_fresh;
    for (int i = 0; i < 2; ++i) {
        Hand& h = hands_[i];
        if (!h.device) continue;
        const DevicePose pose = h.device->read_pose(now_ms);
        const Eigen::Matrix3d r = h.mapping.rotation.toRotationMatrix();
        const Eigen::Vector3d device_world = h.mapping.offset_mm + h.mapping.scale * (r * pose.position_mm);
        const Eigen::Quaterniond orientation_world = (h.mapping.rotation * pose.orientation).normalized();
        if (!h.primed) {
            h.proxy = device_world;
            h.proxy_v.setZero();
            h.last_device = device_world;
            h.primed = true;
        }
        const Eigen::Vector3d device_v = (device_world - h.last_device) / dt;
        h.last_device = device_world;

        // Interpolation: keep this hand's two newest samples.
        if (fresh) {
            if (h.samples > 0) h.f0 = h.f1, h.t0 = h.t1;
            h.f1 = sample.force_n[i];
            h.t1 = sample.time_ms;
            ++h.samples;
            if (fault_event) h.samples = 1;  // never extrapolate across a restore or reset
        }
        Eigen::Vector3d tissue = h.samples > 0 ? h.f1 : Eigen::Vector3d::Zero();
        if (settings_.interpolation == ForceInterpolation::extrapolate && h.samples > 1 && h.t1 > h.t0) {
            const double interval = h.t1 - h.t0;
            const double ahead = std::clamp(now_ms - h.t1, 0.0, interval);  // at most one interval ahead
            tissue += (h.f1 - h.f0) * (ahead / interval);
        }
        if (!tissue.allFinite()) tissue = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());

        // Coupling.
        Eigen::Vector3d world_force;
        Eigen::Vector3d tool_position = device_world;
        if (h.coupling.enabled) {
            const CouplingSettings& c = h.coupling;
            const Eigen::Vector3d env = tissue.allFinite() && simulation_fresh ? tissue : Eigen::Vector3d::Zero();
            // Semi-implicit Euler on the proxy; the spring-damper evaluated at the tick's start.
            const Eigen::Vector3d coupling_on_proxy = c.stiffness_n_per_mm * (device_world - h.proxy) + c.damping_n_ms_per_mm * (device_v - h.proxy_v);
            const Eigen::Vector3d accel = (env + coupling_on_proxy - c.proxy_damping_n_ms_per_mm * h.proxy_v) / c.proxy_mass_g;
            h.proxy_v += accel * dt;
            h.proxy += h.proxy_v * dt;
            if (!h.proxy.allFinite() || !h.proxy_v.allFinite()) h.proxy = device_world, h.proxy_v.setZero();
            world_force = c.stiffness_n_per_mm * (h.proxy - device_world) + c.damping_n_ms_per_mm * (h.proxy_v - device_v);
            if (!tissue.allFinite()) world_force = tissue;  // let the safety chain see the fault
            tool_position = h.proxy;
        } else {
            world_force = tissue;
        }
        tools.hand[i].pose.position = tool_position;
        tools.hand[i].pose.orientation = orientation_world;
        tools.hand[i].buttons = pose.buttons;
        if ((pose.buttons & 1u) && !(h.buttons & 1u)) ++h.presses;
        // A script knows every press, even one over between two ticks.
        h.presses = std::max(h.presses, pose.presses);
        h.buttons = pose.buttons;
        tools.hand[i].presses = h.presses;
        tools.hand[i].time_ms = now_ms;
        tools.hand[i].valid = true;

        const Eigen::Vector3d device_force = h.mapping.force_scale * (r.transpose() * world_force);
        if (stop) h.safety->emergency_stop();
        else if (h.safety->stopped()) h.safety->release_emergency_stop();
        const Eigen::Vector3d out = h.safety->filter({.force_n = device_force,
                                                      .now_ms = now_ms,
                                                      .simulation_fresh = simulation_fresh,
                                                      .fault_event = fault_event,
                                                      .clean_update = clean_update,
                                                      .divergence = divergence});
        h.device->send_force(out, now_ms);
        h.telemetry.last_input_n = device_force;
        h.telemetry.last_force_n = out;
        h.telemetry.max_force_n = std::max(h.telemetry.max_force_n, out.norm());
        ++h.telemetry.forces_sent;
        h.telemetry.safety = h.safety->counters();
        h.telemetry.gain = h.safety->gain();
        record.pose[i] = pose;
        record.input_n[i] = device_force;
        record.force_n[i] = out;
        record.gain[i] = float(h.safety->gain());
    }
    tools_.publish(tools);
    if (ticks_queue_.enabled()) ticks_queue_.push(record);
}

void HapticSession::start() {
    if (running()) return;
    stop_.store(false);
    thread_ = std::thread([this] { run_thread(); });
    scheduling_ = "normal";
    if (settings_.realtime) {
        // Above the simulation and llvmpipe's workers, below the kernel's own RT threads (99). The
        // thread sleeps every period, and Linux throttles RT threads that do not (95 % by default).
        sched_param parameters{};
        parameters.sched_priority = std::min(80, sched_get_priority_max(SCHED_FIFO));
        const int error = pthread_setschedparam(thread_.native_handle(), SCHED_FIFO, &parameters);
        scheduling_ = error == 0 ? "SCHED_FIFO priority " + std::to_string(parameters.sched_priority)
                                 : std::string("normal (SCHED_FIFO refused: ") + std::strerror(error) + ")";
    }
}

std::string HapticSession::scheduling() const { return scheduling_; }

void HapticSession::stop() {
    if (!running()) return;
    stop_.store(true);
    thread_.join();
}

void HapticSession::run_thread() {
    using clock = std::chrono::steady_clock;
    const auto period = std::chrono::duration_cast<clock::duration>(std::chrono::duration<double, std::milli>(period_ms()));
    auto next = clock::now();
    clock::time_point previous{};
    bool first = true;
    while (!stop_.load(std::memory_order_acquire)) {
        const auto start = clock::now();
        if (!first) {
            periods_.add(std::chrono::duration<double, std::milli>(start - previous).count());
            if (periods_.count() % 500 == 0) live_period_p99_ms_.store(periods_.quantile_ms(0.99), std::memory_order_relaxed);
        }
        first = false;
        previous = start;
        tick(std::chrono::duration<double, std::milli>(start - epoch_).count());
        next += period;
        const auto after = clock::now();
        if (after > next + period) {  // more than a period late: skip ahead, do not burst
            ++overruns_;
            next = after;
        }
        std::this_thread::sleep_until(next);
    }
}

PeriodStats HapticSession::period_stats() const {
    return {.ticks = periods_.count(),
            .p50_ms = periods_.quantile_ms(0.50),
            .p99_ms = periods_.quantile_ms(0.99),
            .max_ms = periods_.max_ms(),
            .mean_ms = periods_.mean_ms(),
            .overruns = overruns_};
}

LatencyStats HapticSession::latency_stats() const {
    return {.samples = latencies_.count(),
            .p50_ms = latencies_.quantile_ms(0.50),
            .p99_ms = latencies_.quantile_ms(0.99),
            .max_ms = latencies_.max_ms(),
            .mean_ms = latencies_.mean_ms()};
}

HandTelemetry HapticSession::telemetry(int hand) const { return hands_.at(hand).telemetry; }

std::string format_period_stats(const PeriodStats& s, double rate_hz) {
    char line[256];
    std::snprintf(line, sizeof line, "haptic rate %.0f Hz: %llu periods, mean %.3f ms, p50 %.3f ms, p99 %.3f ms, max %.3f ms, overruns %llu",
                  rate_hz, (unsigned long long)s.ticks, s.mean_ms, s.p50_ms, s.p99_ms, s.max_ms, (unsigned long long)s.overruns);
    return line;
}

}  // namespace heartsim::haptics
