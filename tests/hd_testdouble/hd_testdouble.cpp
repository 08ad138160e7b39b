// hd_testdouble: a TEST DOUBLE of the OpenHaptics HD C API (libHD.so), built as a shared library
// for tests/test_openhaptics.cpp. It is not 3D Systems' library: it exports the HD functions
// heartsim's `openhaptics` device loads (same names, signatures and HD_ constant values as
// OpenHaptics 3.x HD/hdDefines.h, hdDevice.h, hdScheduler.h, declared here by hand) over a
// simulated device, with failure modes chosen by environment (hd_testdouble.h). What it imitates:
//  * a scheduler thread at 1 kHz (steady clock) running the synchronous and asynchronous
//    callbacks; hdUnschedule / hdStopScheduler wait for a running callback to return;
//  * frames: hdBeginFrame / hdEndFrame per device, hdSetDoublev(HD_CURRENT_FORCE) taking effect
//    at hdEndFrame when HD_FORCE_OUTPUT is enabled; errors on a per-thread stack, newest first;
//  * a device that moves: a 50 g point mass on a spring (0.02 N/mm) to a hand moving on a 20 mm
//    circle every 2 s, pushed by the rendered force, orientation turning with it, button 1
//    toggling every 250 ms;
//  * properties: HD_NOMINAL_MAX_CONTINUOUS_FORCE 0.88 N and HD_NOMINAL_MAX_FORCE 3.3 N (the
//    Touch's published figures), a usable workspace invented for the double (±100, ±70, ±50 mm,
//    unlike heartsim's default so a test can tell it was read).
// Whatever the real driver does beyond this (its exact error codes for a missing device, what it
// allows while the scheduler runs) is not claimed here.
#include "hd_testdouble.h"

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <numbers>
#include <string>
#include <thread>
#include <vector>

namespace {

using HHD = unsigned int;
using HDenum = unsigned int;
using HDerror = unsigned int;
using HDint = int;
using HDdouble = double;
using HDushort = unsigned short;
using HDboolean = unsigned char;
using HDstring = const char*;
using HDCallbackCode = unsigned int;
using HDSchedulerHandle = unsigned long;
using HDSchedulerCallback = HDCallbackCode (*)(void*);

}  // namespace

extern "C" {
struct HDErrorInfo {
    HDerror errorCode;
    int internalErrorCode;
    HHD hHD;
};
}

namespace {

constexpr HDerror HD_SUCCESS = 0x0000, HD_INVALID_ENUM = 0x0100, HD_INVALID_VALUE = 0x0101,
                  HD_INVALID_OPERATION = 0x0102, HD_BAD_HANDLE = 0x0104, HD_EXCEEDED_MAX_FORCE = 0x0201,
                  HD_DEVICE_ALREADY_INITIATED = 0x0301, HD_COMM_ERROR = 0x0302, HD_COMM_CONFIG_ERROR = 0x0303,
                  HD_TIMER_ERROR = 0x0304, HD_ILLEGAL_BEGIN = 0x0400, HD_ILLEGAL_END = 0x0401;
constexpr HHD HD_INVALID_HANDLE = 0xFFFFFFFF;
constexpr HDCallbackCode HD_CALLBACK_DONE = 0;
constexpr HDenum HD_CURRENT_BUTTONS = 0x2000, HD_CURRENT_POSITION = 0x2050, HD_CURRENT_TRANSFORM = 0x2052,
                 HD_DEVICE_MODEL_TYPE = 0x2501, HD_USABLE_WORKSPACE_DIMENSIONS = 0x2551, HD_CALIBRATION_STYLE = 0x2555,
                 HD_NOMINAL_MAX_FORCE = 0x2603, HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604, HD_CURRENT_FORCE = 0x2700,
                 HD_FORCE_OUTPUT = 0x4000;
constexpr HDenum HD_CALIBRATION_OK = 0x5000, HD_CALIBRATION_NEEDS_UPDATE = 0x5001,
                 HD_CALIBRATION_NEEDS_MANUAL_INPUT = 0x5002;
constexpr HDint HD_CALIBRATION_AUTO = 1 << 1, HD_CALIBRATION_INKWELL = 1 << 2;

constexpr double kMaxContinuousForceN = 0.88, kMaxForceN = 3.3;  // Touch data sheet figures
constexpr double kMassG = 50.0, kSpringNPerMm = 0.02, kDampingNMsPerMm = 0.002;
constexpr double kCircleRadiusMm = 20.0, kCirclePeriodMs = 2000.0;

enum class Mode { ok, not_found, calibration, calibration_update, scheduler, fault_after, unknown };

struct SimDevice {
    std::string name;
    bool open = false, in_frame = false, force_output = false;
    HDenum calibration = HD_CALIBRATION_OK;
    HDint calibration_style = HD_CALIBRATION_INKWELL;
    std::array<double, 3> x{0, 0, 0}, v{0, 0, 0};
    double angle = 0.0;  // rad, about the vertical (y) axis
    std::uint32_t buttons = 0;
    std::array<double, 3> pending{0, 0, 0}, rendered{0, 0, 0};
    HdTestDoubleStats stats{};
};

struct SyncJob {
    HDSchedulerCallback callback;
    void* data;
    bool done = false;
};
struct AsyncOp {
    HDSchedulerHandle id;
    HDSchedulerCallback callback;
    void* data;
    bool active = true;
};

struct Double {
    std::recursive_mutex mutex;  // held by the servo thread while it steps and runs callbacks
    std::condition_variable_any sync_done;
    Mode mode = Mode::ok;
    double fault_after_ms = 0.0;
    std::vector<SimDevice> devices;  // handle = index
    std::vector<AsyncOp> async;
    std::deque<SyncJob*> sync;
    HDSchedulerHandle next_id = 1;
    std::thread servo;
    std::atomic<bool> running{false};
    std::chrono::steady_clock::time_point start;
    double servo_ms = 0.0;
};
Double& the() {
    static Double d;
    return d;
}

thread_local std::vector<HDErrorInfo> error_stack;
thread_local HHD current = HD_INVALID_HANDLE;
thread_local bool on_servo_thread = false;

void raise(HDerror code, int internal = 0) {
    error_stack.push_back({code, internal, current});
    Double& d = the();
    std::lock_guard lock(d.mutex);
    if (current < d.devices.size()) ++d.devices[current].stats.errors_raised;
}

SimDevice* device(HHD handle) {
    Double& d = the();
    return handle < d.devices.size() && d.devices[handle].open ? &d.devices[handle] : nullptr;
}

std::vector<std::string> configured_names() {
    const char* env = std::getenv("HD_TESTDOUBLE_DEVICES");
    const std::string list = env && *env ? env : "Default Device,Left Device,Right Device";
    std::vector<std::string> names;
    std::size_t begin = 0;
    while (begin <= list.size()) {
        const std::size_t end = std::min(list.find(',', begin), list.size());
        if (end > begin) names.push_back(list.substr(begin, end - begin));
        begin = end + 1;
    }
    return names;
}

Mode read_mode(double& fault_after_ms) {
    const char* env = std::getenv("HD_TESTDOUBLE_MODE");
    const std::string mode = env ? env : "ok";
    if (mode.empty() || mode == "ok") return Mode::ok;
    if (mode == "not_found") return Mode::not_found;
    if (mode == "calibration") return Mode::calibration;
    if (mode == "calibration_update") return Mode::calibration_update;
    if (mode == "scheduler") return Mode::scheduler;
    if (mode.rfind("fault_after_ms=", 0) == 0) {
        fault_after_ms = std::atof(mode.c_str() + std::strlen("fault_after_ms="));
        return Mode::fault_after;
    }
    return Mode::unknown;
}

/// The hand on its circle at servo time t, and the device's response (semi-implicit Euler).
void step_device(SimDevice& dev, double t_ms, double dt_ms) {
    const double phase = 2.0 * std::numbers::pi * t_ms / kCirclePeriodMs;
    const std::array<double, 3> hand{kCircleRadiusMm * std::cos(phase), kCircleRadiusMm * std::sin(phase), 0.0};
    for (int i = 0; i < 3; ++i) {
        const double f = kSpringNPerMm * (hand[i] - dev.x[i]) - kDampingNMsPerMm * dev.v[i] + dev.rendered[i];
        dev.v[i] += dt_ms * f / kMassG;
        dev.x[i] += dt_ms * dev.v[i];
    }
    dev.angle = 0.3 * std::sin(phase);
    dev.buttons = (static_cast<long>(t_ms / 250.0) % 2) ? 1u : 0u;
    for (int i = 0; i < 3; ++i) dev.stats.position[i] = dev.x[i];
    dev.stats.servo_ms = t_ms;
}

void servo_loop() {
    on_servo_thread = true;
    Double& d = the();
    auto next = std::chrono::steady_clock::now();
    double last_ms = 0.0;
    while (d.running.load()) {
        next += std::chrono::milliseconds(1);
        const auto now = std::chrono::steady_clock::now();
        if (now - next > std::chrono::milliseconds(20)) next = now;  // far behind: skip ahead, no burst
        std::this_thread::sleep_until(next);
        std::unique_lock lock(d.mutex);
        d.servo_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - d.start).count();
        const double dt = std::min(5.0, d.servo_ms - last_ms);
        last_ms = d.servo_ms;
        for (auto& dev : d.devices)
            if (dev.open) step_device(dev, d.servo_ms, dt);
        while (!d.sync.empty()) {
            SyncJob* job = d.sync.front();
            d.sync.pop_front();
            while (job->callback(job->data) != HD_CALLBACK_DONE) {
            }
            job->done = true;
        }
        d.sync_done.notify_all();
        for (std::size_t i = 0; i < d.async.size(); ++i) {  // callbacks may schedule more: index loop
            if (!d.async[i].active) continue;
            if (d.async[i].callback(d.async[i].data) == HD_CALLBACK_DONE) d.async[i].active = false;
        }
        std::erase_if(d.async, [](const AsyncOp& op) { return !op.active; });
    }
}

const char* describe(HDerror code) {
    switch (code) {
    case HD_SUCCESS: return "no error [hd_testdouble]";
    case HD_INVALID_ENUM: return "invalid enumeration [hd_testdouble]";
    case HD_INVALID_VALUE: return "invalid value [hd_testdouble]";
    case HD_INVALID_OPERATION: return "invalid operation [hd_testdouble]";
    case HD_BAD_HANDLE: return "bad device handle [hd_testdouble]";
    case HD_EXCEEDED_MAX_FORCE: return "exceeded the maximum force [hd_testdouble]";
    case HD_DEVICE_ALREADY_INITIATED: return "device already initiated [hd_testdouble]";
    case HD_COMM_ERROR: return "communication error: the simulated device stopped answering [hd_testdouble]";
    case HD_COMM_CONFIG_ERROR: return "communication configuration error: no such device [hd_testdouble]";
    case HD_TIMER_ERROR: return "timer error: the simulated scheduler could not start [hd_testdouble]";
    case HD_ILLEGAL_BEGIN: return "illegal begin frame [hd_testdouble]";
    case HD_ILLEGAL_END: return "illegal end frame [hd_testdouble]";
    default: return "error [hd_testdouble]";
    }
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// The HD API, as much of it as heartsim's openhaptics device calls.

extern "C" {

HHD hdInitDevice(HDstring name) {
    Double& d = the();
    std::lock_guard lock(d.mutex);
    bool any_open = false;
    for (const auto& dev : d.devices) any_open = any_open || dev.open;
    if (!any_open && !d.running.load()) d.devices.clear();  // a fresh start for each test
    d.mode = read_mode(d.fault_after_ms);
    if (d.mode == Mode::unknown) {
        raise(HD_INVALID_VALUE, -2);
        return HD_INVALID_HANDLE;
    }
    const std::vector<std::string> names = configured_names();
    const std::string wanted = name ? name : (names.empty() ? "" : names.front());
    bool known = false;
    for (const auto& n : names) known = known || n == wanted;
    if (d.mode == Mode::not_found || !known) {
        raise(HD_COMM_CONFIG_ERROR, -1);
        return HD_INVALID_HANDLE;
    }
    for (const auto& dev : d.devices)
        if (dev.open && dev.name == wanted) {
            raise(HD_DEVICE_ALREADY_INITIATED);
            return HD_INVALID_HANDLE;
        }
    SimDevice dev;
    dev.name = wanted;
    dev.open = true;
    dev.stats.open = 1;
    dev.stats.last_nonzero_force_ms = -1.0;
    if (d.mode == Mode::calibration) {
        dev.calibration = HD_CALIBRATION_NEEDS_MANUAL_INPUT;
        dev.calibration_style = HD_CALIBRATION_INKWELL;
    } else if (d.mode == Mode::calibration_update) {
        dev.calibration = HD_CALIBRATION_NEEDS_UPDATE;
        dev.calibration_style = HD_CALIBRATION_AUTO;
    }
    step_device(dev, d.servo_ms, 0.0);
    d.devices.push_back(dev);
    current = static_cast<HHD>(d.devices.size() - 1);
    return current;
}

void hdDisableDevice(HHD handle) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(handle);
    if (!dev) return raise(HD_BAD_HANDLE);
    dev->open = false;
    dev->stats.open = 0;
    dev->rendered = {0, 0, 0};
    if (current == handle) current = HD_INVALID_HANDLE;
}

void hdMakeCurrentDevice(HHD handle) {
    std::lock_guard lock(the().mutex);
    if (!device(handle)) return raise(HD_BAD_HANDLE);
    current = handle;
}

HHD hdGetCurrentDevice() { return current; }

void hdBeginFrame(HHD handle) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(handle);
    if (!dev) return raise(HD_BAD_HANDLE);
    current = handle;
    if (dev->in_frame) return raise(HD_ILLEGAL_BEGIN);
    dev->in_frame = true;
    dev->pending = {0, 0, 0};
}

void hdEndFrame(HHD handle) {
    Double& d = the();
    std::lock_guard lock(d.mutex);
    SimDevice* dev = device(handle);
    if (!dev) return raise(HD_BAD_HANDLE);
    if (!dev->in_frame) return raise(HD_ILLEGAL_END);
    dev->in_frame = false;
    ++dev->stats.frames;
    std::array<double, 3> force = dev->force_output ? dev->pending : std::array<double, 3>{0, 0, 0};
    const double norm = std::sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2]);
    if (norm > kMaxForceN) {  // HD's own guard: refuse and report
        force = {0, 0, 0};
        raise(HD_EXCEEDED_MAX_FORCE);
    }
    if (d.mode == Mode::fault_after && d.running.load() && d.servo_ms >= d.fault_after_ms) {
        force = {0, 0, 0};  // unplugged: nothing reaches the motors
        raise(HD_COMM_ERROR, 7);
    }
    dev->rendered = force;
    for (int i = 0; i < 3; ++i) dev->stats.last_force[i] = force[i];
    const double rendered = std::sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2]);
    dev->stats.max_force_norm = std::max(dev->stats.max_force_norm, rendered);
    if (rendered > 0.0) dev->stats.last_nonzero_force_ms = d.servo_ms;
}

HDErrorInfo hdGetError() {
    if (error_stack.empty()) return {HD_SUCCESS, 0, current};
    const HDErrorInfo newest = error_stack.back();
    error_stack.pop_back();
    return newest;
}

HDstring hdGetErrorString(HDerror code) { return describe(code); }

void hdEnable(HDenum capability) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    if (capability != HD_FORCE_OUTPUT) return raise(HD_INVALID_ENUM);
    dev->force_output = true;
}

void hdDisable(HDenum capability) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    if (capability != HD_FORCE_OUTPUT) return raise(HD_INVALID_ENUM);
    dev->force_output = false;
}

void hdGetDoublev(HDenum name, HDdouble* values) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    switch (name) {
    case HD_CURRENT_POSITION:
        for (int i = 0; i < 3; ++i) values[i] = dev->x[i];
        return;
    case HD_CURRENT_TRANSFORM: {  // column-major: rotation about y by angle, then translation
        const double c = std::cos(dev->angle), s = std::sin(dev->angle);
        const double m[16] = {c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, dev->x[0], dev->x[1], dev->x[2], 1};
        std::memcpy(values, m, sizeof m);
        return;
    }
    case HD_NOMINAL_MAX_CONTINUOUS_FORCE: values[0] = kMaxContinuousForceN; return;
    case HD_NOMINAL_MAX_FORCE: values[0] = kMaxForceN; return;
    case HD_USABLE_WORKSPACE_DIMENSIONS: {
        const double box[6] = {-100, -70, -50, 100, 70, 50};
        std::memcpy(values, box, sizeof box);
        return;
    }
    default: return raise(HD_INVALID_ENUM);
    }
}

void hdGetIntegerv(HDenum name, HDint* values) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    switch (name) {
    case HD_CURRENT_BUTTONS: values[0] = static_cast<HDint>(dev->buttons); return;
    case HD_CALIBRATION_STYLE: values[0] = dev->calibration_style; return;
    default: return raise(HD_INVALID_ENUM);
    }
}

void hdSetDoublev(HDenum name, const HDdouble* values) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    if (name != HD_CURRENT_FORCE) return raise(HD_INVALID_ENUM);
    if (!dev->in_frame) return raise(HD_INVALID_OPERATION);
    if (!std::isfinite(values[0]) || !std::isfinite(values[1]) || !std::isfinite(values[2])) {
        ++dev->stats.non_finite_forces;
        dev->pending = {0, 0, 0};
        return raise(HD_INVALID_VALUE);
    }
    if (std::sqrt(values[0] * values[0] + values[1] * values[1] + values[2] * values[2]) > kMaxForceN)
        ++dev->stats.over_max_forces;
    dev->pending = {values[0], values[1], values[2]};
}

HDstring hdGetString(HDenum name) {
    if (name == HD_DEVICE_MODEL_TYPE) return "hd_testdouble (simulated Touch)";
    raise(HD_INVALID_ENUM);
    return nullptr;
}

HDenum hdCheckCalibration() {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) {
        raise(HD_BAD_HANDLE);
        return HD_CALIBRATION_NEEDS_MANUAL_INPUT;
    }
    return dev->calibration;
}

void hdUpdateCalibration(HDenum style) {
    std::lock_guard lock(the().mutex);
    SimDevice* dev = device(current);
    if (!dev) return raise(HD_BAD_HANDLE);
    if (!(static_cast<HDint>(style) & dev->calibration_style)) return raise(HD_INVALID_VALUE);
    if (dev->calibration == HD_CALIBRATION_NEEDS_UPDATE) {
        dev->calibration = HD_CALIBRATION_OK;
        ++dev->stats.calibration_updates;
    }
}

void hdStartScheduler() {
    Double& d = the();
    std::lock_guard lock(d.mutex);
    if (d.mode == Mode::scheduler) return raise(HD_TIMER_ERROR, -3);
    if (d.running.load()) return raise(HD_INVALID_OPERATION);
    d.start = std::chrono::steady_clock::now();
    d.servo_ms = 0.0;
    d.running.store(true);
    d.servo = std::thread(servo_loop);
}

void hdStopScheduler() {
    Double& d = the();
    std::thread servo;
    {
        std::lock_guard lock(d.mutex);
        if (!d.running.load()) return raise(HD_INVALID_OPERATION);
        d.running.store(false);
        servo = std::move(d.servo);
    }
    servo.join();
    std::lock_guard lock(d.mutex);
    d.async.clear();  // the scheduler's operations end with it
    for (SyncJob* job : d.sync) job->done = true;
    d.sync.clear();
    d.sync_done.notify_all();
}

HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback callback, void* data, HDushort) {
    Double& d = the();
    std::lock_guard lock(d.mutex);
    d.async.push_back({d.next_id, callback, data});
    return d.next_id++;
}

void hdScheduleSynchronous(HDSchedulerCallback callback, void* data, HDushort) {
    Double& d = the();
    if (on_servo_thread) {
        while (callback(data) != HD_CALLBACK_DONE) {
        }
        return;
    }
    std::unique_lock lock(d.mutex);
    if (!d.running.load()) return raise(HD_INVALID_OPERATION);  // nothing would ever run it
    SyncJob job{callback, data};
    d.sync.push_back(&job);
    d.sync_done.wait(lock, [&] { return job.done; });
}

void hdUnschedule(HDSchedulerHandle id) {
    Double& d = the();
    std::lock_guard lock(d.mutex);  // waits for a running callback to return
    for (auto& op : d.async)
        if (op.id == id && op.active) {
            op.active = false;
            return;
        }
    raise(HD_INVALID_OPERATION);
}

// ------------------------------------------------------------------------------------------------
// Test-only

int hd_testdouble_stats(const char* name, HdTestDoubleStats* stats) {
    Double& d = the();
    std::lock_guard lock(d.mutex);
    const std::vector<std::string> names = configured_names();
    const std::string wanted = name ? name : (names.empty() ? "" : names.front());
    for (auto it = d.devices.rbegin(); it != d.devices.rend(); ++it)
        if (it->name == wanted) {
            *stats = it->stats;
            stats->scheduler_running = d.running.load() ? 1 : 0;
            return 1;
        }
    *stats = HdTestDoubleStats{};
    stats->scheduler_running = d.running.load() ? 1 : 0;
    return 0;
}

}  // extern "C"
