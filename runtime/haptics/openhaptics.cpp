// The openhaptics device (runtime/haptics/openhaptics.h): the OpenHaptics HD C API through dlopen.
// One file because the hand-written HD declarations, the servo callback and
// the device all share OpenHapticsDevice::State, which no other file should see.
#include "runtime/haptics/openhaptics.h"

#include "libmodel/errors.h"

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <thread>
#include <vector>

namespace heartsim::haptics {

namespace {

// ------------------------------------------------------------------------------------------------
// The few HD declarations used here, written by hand (no SDK header is needed to build). Types,
// values and signatures as in OpenHaptics 3.x: HD/hdDefines.h (types, error codes, parameter
// names, calibration values), HD/hdDevice.h and HD/hdScheduler.h (functions, HDCallbackCode,
// HDSchedulerHandle), as found in public copies of those headers (e.g. github.com/hhmai/PhantomAPI
// include/HD/hdDefines.h) and the OpenHaptics API Reference. HDAPIENTRY / HDCALLBACK are empty
// on Linux (plain C calling convention).

using HHD = unsigned int;
using HDenum = unsigned int;
using HDerror = unsigned int;
using HDint = int;
using HDdouble = double;
using HDushort = unsigned short;
using HDstring = const char*;
using HDCallbackCode = unsigned int;
using HDSchedulerHandle = unsigned long;
using HDSchedulerCallback = HDCallbackCode (*)(void* user_data);

struct HDErrorInfo {
    HDerror errorCode;      // an HD_ error code
    int internalErrorCode;  // the device driver's own code
    HHD hHD;                // the current device when it happened
};

constexpr HDerror HD_SUCCESS = 0x0000;
constexpr HHD HD_INVALID_HANDLE = 0xFFFFFFFF;
constexpr HDCallbackCode HD_CALLBACK_DONE = 0, HD_CALLBACK_CONTINUE = 1;
constexpr HDushort HD_DEFAULT_SCHEDULER_PRIORITY = 0xFFFF / 2;  // (HD_MAX + HD_MIN) / 2, USHRT_MAX = max

constexpr HDenum HD_CURRENT_BUTTONS = 0x2000;               // 1 HDint, bit i = button i+1
constexpr HDenum HD_CURRENT_POSITION = 0x2050;              // 3 HDdouble, mm
constexpr HDenum HD_CURRENT_TRANSFORM = 0x2052;             // 16 HDdouble, column-major 4×4, mm
constexpr HDenum HD_DEVICE_MODEL_TYPE = 0x2501;             // string
constexpr HDenum HD_USABLE_WORKSPACE_DIMENSIONS = 0x2551;   // 6 HDdouble: min x y z, max x y z, mm
constexpr HDenum HD_CALIBRATION_STYLE = 0x2555;             // 1 HDint, HD_CALIBRATION_* bits
constexpr HDenum HD_NOMINAL_MAX_FORCE = 0x2603;             // 1 HDdouble, N (peak)
constexpr HDenum HD_NOMINAL_MAX_CONTINUOUS_FORCE = 0x2604;  // 1 HDdouble, N
constexpr HDenum HD_CURRENT_FORCE = 0x2700;                 // 3 HDdouble, N
constexpr HDenum HD_FORCE_OUTPUT = 0x4000;                  // hdEnable capability

constexpr HDenum HD_CALIBRATION_OK = 0x5000;
constexpr HDenum HD_CALIBRATION_NEEDS_UPDATE = 0x5001;
constexpr HDenum HD_CALIBRATION_NEEDS_MANUAL_INPUT = 0x5002;
constexpr HDint HD_CALIBRATION_ENCODER_RESET = 1 << 0;
constexpr HDint HD_CALIBRATION_AUTO = 1 << 1;
constexpr HDint HD_CALIBRATION_INKWELL = 1 << 2;

/// The HD entry points, resolved with dlsym. hdGetString is optional (only the model name).
struct HdApi {
    HHD (*hdInitDevice)(HDstring) = nullptr;
    void (*hdDisableDevice)(HHD) = nullptr;
    void (*hdMakeCurrentDevice)(HHD) = nullptr;
    void (*hdBeginFrame)(HHD) = nullptr;
    void (*hdEndFrame)(HHD) = nullptr;
    HDErrorInfo (*hdGetError)() = nullptr;
    HDstring (*hdGetErrorString)(HDerror) = nullptr;
    void (*hdEnable)(HDenum) = nullptr;
    void (*hdDisable)(HDenum) = nullptr;
    void (*hdGetDoublev)(HDenum, HDdouble*) = nullptr;
    void (*hdGetIntegerv)(HDenum, HDint*) = nullptr;
    void (*hdSetDoublev)(HDenum, const HDdouble*) = nullptr;
    HDstring (*hdGetString)(HDenum) = nullptr;
    HDenum (*hdCheckCalibration)() = nullptr;
    void (*hdUpdateCalibration)(HDenum) = nullptr;
    void (*hdStartScheduler)() = nullptr;
    void (*hdStopScheduler)() = nullptr;
    HDSchedulerHandle (*hdScheduleAsynchronous)(HDSchedulerCallback, void*, HDushort) = nullptr;
    void (*hdScheduleSynchronous)(HDSchedulerCallback, void*, HDushort) = nullptr;
    void (*hdUnschedule)(HDSchedulerHandle) = nullptr;
};

/// Servo thread → device thread: one pose sample (plain doubles: no alignment needs).
struct ServoSample {
    std::array<double, 3> position_mm{0.0, 0.0, 0.0};
    std::array<double, 4> rotation_wxyz{1.0, 0.0, 0.0, 0.0};
    std::uint32_t buttons = 0;
    std::uint64_t frame = 0;
};

/// Device thread → servo thread: the newest force, N, device frame.
struct ForceCommand {
    std::array<double, 3> force_n{0.0, 0.0, 0.0};
    std::uint64_t sequence = 0;
};

/// The HD scheduler is one per process (per library): started by the first open device, stopped
/// with the last. Opens and closes are serialised by this mutex.
struct SchedulerUse {
    void* library = nullptr;
    int devices = 0;
};
std::mutex& registry_mutex() {
    static std::mutex mutex;
    return mutex;
}
std::vector<SchedulerUse>& registry() {
    static std::vector<SchedulerUse> uses;
    return uses;
}
SchedulerUse* find_use(void* library) {
    for (auto& use : registry())
        if (use.library == library) return &use;
    return nullptr;
}

char hex_digit(unsigned v) { return "0123456789ABCDEF"[v & 15]; }
std::string hex4(unsigned code) {
    std::string s = "0x";
    for (int shift = 12; shift >= 0; shift -= 4) s += hex_digit(code >> shift);
    return s;
}

}  // namespace

std::string hd_error_name(unsigned code) {
    switch (code) {  // HD/hdDefines.h, "Error codes"
    case 0x0000: return "HD_SUCCESS";
    case 0x0100: return "HD_INVALID_ENUM";
    case 0x0101: return "HD_INVALID_VALUE";
    case 0x0102: return "HD_INVALID_OPERATION";
    case 0x0103: return "HD_INVALID_INPUT_TYPE";
    case 0x0104: return "HD_BAD_HANDLE";
    case 0x0200: return "HD_WARM_MOTORS";
    case 0x0201: return "HD_EXCEEDED_MAX_FORCE";
    case 0x0202: return "HD_EXCEEDED_MAX_FORCE_IMPULSE";
    case 0x0203: return "HD_EXCEEDED_MAX_VELOCITY";
    case 0x0204: return "HD_FORCE_ERROR";
    case 0x0300: return "HD_DEVICE_FAULT";
    case 0x0301: return "HD_DEVICE_ALREADY_INITIATED";
    case 0x0302: return "HD_COMM_ERROR";
    case 0x0303: return "HD_COMM_CONFIG_ERROR";
    case 0x0304: return "HD_TIMER_ERROR";
    case 0x0400: return "HD_ILLEGAL_BEGIN";
    case 0x0401: return "HD_ILLEGAL_END";
    case 0x0402: return "HD_FRAME_ERROR";
    case 0x0500: return "HD_INVALID_PRIORITY";
    case 0x0501: return "HD_SCHEDULER_FULL";
    case 0x0600: return "HD_INVALID_LICENSE";
    default: return "HD error " + hex4(code);
    }
}

// ------------------------------------------------------------------------------------------------
// State shared by the device object and its servo callback

struct OpenHapticsDevice::State {
    OpenHapticsOptions options;
    std::string library_path;
    void* library = nullptr;
    HdApi hd;
    std::string label;  ///< "the default device" or "device \"NAME\"", for messages
    std::string model;
    HHD handle = HD_INVALID_HANDLE;
    DeviceLimits limits;
    bool force_enabled = false, registered = false, scheduled = false;
    HDSchedulerHandle callback = 0;
    std::chrono::steady_clock::time_point epoch = std::chrono::steady_clock::now();

    // The exchange (each one writer, one reader).
    LatestValue<ServoSample> poses;    // servo → device thread
    LatestValue<ForceCommand> forces;  // device thread → servo

    // Servo thread only.
    ForceCommand command{};
    bool have_command = false;
    double command_ms = 0.0;  ///< servo clock when the newest command arrived
    ServoSample sample{};

    // Device thread only.
    std::uint64_t sequence = 0;
    double last_fresh_ms = 0.0;
    bool read_once = false;

    // Between threads.
    std::atomic<bool> closing{false}, released{false};
    std::atomic<bool> hd_fault{false};  ///< set by the servo thread after the fields below
    HDerror fault_code = HD_SUCCESS;
    int fault_internal = 0;
    std::uint64_t fault_frame = 0;
    double fault_ms = 0.0;
    std::atomic<bool> stall_fault{false};  ///< set by the device thread after the field below
    double stall_ms = 0.0;
    struct {
        std::atomic<std::uint64_t> servo_frames{0}, forces_received{0}, non_finite{0}, clamped{0}, faded{0}, bad_poses{0};
    } counters;

    double servo_now_ms() const {
        return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - epoch).count();
    }
    std::string prefix() const { return "openhaptics: " + label + " (library \"" + library_path + "\"): "; }
    std::string describe(const HDErrorInfo& error) const {
        const char* text = hd.hdGetErrorString ? hd.hdGetErrorString(error.errorCode) : nullptr;
        return "HD error " + hex4(error.errorCode) + " " + hd_error_name(error.errorCode) + " (\"" +
               (text ? text : "no description") + "\", internal code " + std::to_string(error.internalErrorCode) + ")";
    }
    /// The most recent error and the stack emptied (HD keeps a stack, newest first); HD_SUCCESS when none.
    HDErrorInfo take_error() const {
        HDErrorInfo first = hd.hdGetError();
        if (first.errorCode != HD_SUCCESS)
            for (int i = 0; i < 64 && hd.hdGetError().errorCode != HD_SUCCESS; ++i) {
            }
        return first;
    }
    [[noreturn]] void fail(const std::string& what) const { throw DeviceUnavailable(prefix() + what); }
    void check(const char* call) const {
        if (const HDErrorInfo error = take_error(); error.errorCode != HD_SUCCESS)
            fail(std::string(call) + " failed: " + describe(error));
    }
};

namespace {

/// One servo tick (HD's servo thread, 1 kHz): read the pose, render the newest force after the
/// last guard (finite, clamp, fade when stale), check for errors, publish the pose. No locks, no
/// allocation.
HDCallbackCode servo_callback(void* user_data) {
    auto& s = *static_cast<OpenHapticsDevice::State*>(user_data);
    const HdApi& hd = s.hd;
    const double now = s.servo_now_ms();
    const bool closing = s.closing.load(std::memory_order_acquire);

    hd.hdMakeCurrentDevice(s.handle);
    hd.hdBeginFrame(s.handle);
    HDdouble position[3] = {0, 0, 0}, transform[16] = {};
    HDint buttons = 0;
    hd.hdGetDoublev(HD_CURRENT_POSITION, position);
    hd.hdGetDoublev(HD_CURRENT_TRANSFORM, transform);
    hd.hdGetIntegerv(HD_CURRENT_BUTTONS, &buttons);

    ForceCommand fresh;
    if (s.forces.fetch(fresh)) {
        s.command = fresh;
        s.have_command = true;
        s.command_ms = now;
        s.counters.forces_received.fetch_add(1, std::memory_order_relaxed);
    }
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    const bool faulted = s.hd_fault.load(std::memory_order_relaxed) || s.stall_fault.load(std::memory_order_acquire);
    if (s.have_command && !closing && !faulted) {
        force = Eigen::Vector3d(s.command.force_n[0], s.command.force_n[1], s.command.force_n[2]);
        if (!force.allFinite()) {
            force.setZero();
            s.counters.non_finite.fetch_add(1, std::memory_order_relaxed);
        }
        const double max_n = s.limits.max_force_n, norm = force.norm();
        if (norm > max_n) {
            force *= max_n / norm;
            s.counters.clamped.fetch_add(1, std::memory_order_relaxed);
        }
        // No new force for force_hold_ms: the device thread is late or stopped. Fade linearly to
        // zero at force_timeout_ms after the last one.
        const double age = now - s.command_ms, hold = s.options.force_hold_ms, timeout = s.options.force_timeout_ms;
        if (age > hold) {
            const double gain = age >= timeout ? 0.0 : 1.0 - (age - hold) / (timeout - hold);
            force *= gain;
            s.counters.faded.fetch_add(1, std::memory_order_relaxed);
        }
        if (!force.allFinite() || force.norm() > max_n) force.setZero();  // cannot happen; never send it
    }
    hd.hdSetDoublev(HD_CURRENT_FORCE, force.data());
    hd.hdEndFrame(s.handle);

    const std::uint64_t frame = s.counters.servo_frames.fetch_add(1, std::memory_order_relaxed) + 1;
    if (const HDErrorInfo error = s.take_error(); error.errorCode != HD_SUCCESS && !s.hd_fault.load(std::memory_order_relaxed)) {
        s.fault_code = error.errorCode;
        s.fault_internal = error.internalErrorCode;
        s.fault_frame = frame;
        s.fault_ms = now;
        s.hd_fault.store(true, std::memory_order_release);
    }

    // The pose: translation from HD_CURRENT_POSITION, rotation from the upper-left 3×3 of the
    // column-major HD_CURRENT_TRANSFORM. A non-finite or degenerate reading keeps the previous one.
    const Eigen::Map<const Eigen::Matrix4d> m(transform);
    Eigen::Quaterniond q(Eigen::Matrix3d(m.topLeftCorner<3, 3>()));
    const bool finite = std::isfinite(position[0]) && std::isfinite(position[1]) && std::isfinite(position[2]) &&
                        q.coeffs().allFinite() && q.norm() > 1e-6;
    if (finite) {
        q.normalize();
        s.sample.position_mm = {position[0], position[1], position[2]};
        s.sample.rotation_wxyz = {q.w(), q.x(), q.y(), q.z()};
        s.sample.buttons = static_cast<std::uint32_t>(buttons);
    } else {
        s.counters.bad_poses.fetch_add(1, std::memory_order_relaxed);
    }
    s.sample.frame = frame;
    s.poses.publish(s.sample);

    if (closing) {
        s.released.store(true, std::memory_order_release);
        return HD_CALLBACK_DONE;  // unschedules itself after a frame with zero force
    }
    return HD_CALLBACK_CONTINUE;
}

/// Releases whatever open() got so far, in reverse; idempotent. Holds the registry mutex.
void close_locked(OpenHapticsDevice::State& s) {
    if (!s.library) return;
    if (s.scheduled) {
        // The callback renders one frame with zero force and unschedules itself; hdUnschedule only
        // when the servo loop did not come round within 200 ms.
        s.closing.store(true, std::memory_order_release);
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(200);
        while (!s.released.load(std::memory_order_acquire) && std::chrono::steady_clock::now() < deadline)
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
        if (!s.released.load(std::memory_order_acquire)) s.hd.hdUnschedule(s.callback);
        s.scheduled = false;
    }
    if (s.registered) {
        SchedulerUse* use = find_use(s.library);
        if (use && --use->devices == 0) {
            s.hd.hdStopScheduler();
            registry().erase(registry().begin() + (use - registry().data()));
        }
        s.registered = false;
    }
    if (s.handle != HD_INVALID_HANDLE) {
        s.hd.hdMakeCurrentDevice(s.handle);
        if (s.force_enabled) s.hd.hdDisable(HD_FORCE_OUTPUT);
        s.hd.hdDisableDevice(s.handle);
        s.handle = HD_INVALID_HANDLE;
    }
    if (s.hd.hdGetError) s.take_error();
    dlclose(s.library);
    s.library = nullptr;
}

template <class F>
void resolve(OpenHapticsDevice::State& s, F& function, const char* symbol, bool required = true) {
    dlerror();
    function = reinterpret_cast<F>(dlsym(s.library, symbol));
    if (!function && required)
        s.fail(std::string("the library has no symbol ") + symbol + " (not an OpenHaptics HD library?)");
}

/// Synchronous scheduler calls for the calibration (the SDK's Calibration example does the same).
struct CalibrationCall {
    const HdApi* hd;
    HHD handle;
    HDenum style;
    HDenum status;
};
HDCallbackCode calibration_status_callback(void* user_data) {
    auto& c = *static_cast<CalibrationCall*>(user_data);
    c.hd->hdMakeCurrentDevice(c.handle);
    c.hd->hdBeginFrame(c.handle);
    c.status = c.hd->hdCheckCalibration();
    c.hd->hdEndFrame(c.handle);
    return HD_CALLBACK_DONE;
}
HDCallbackCode calibration_update_callback(void* user_data) {
    auto& c = *static_cast<CalibrationCall*>(user_data);
    c.hd->hdMakeCurrentDevice(c.handle);
    if (c.hd->hdCheckCalibration() == HD_CALIBRATION_NEEDS_UPDATE) c.hd->hdUpdateCalibration(c.style);
    return HD_CALLBACK_DONE;
}

std::string calibration_name(HDenum status) {
    switch (status) {
    case HD_CALIBRATION_OK: return "HD_CALIBRATION_OK";
    case HD_CALIBRATION_NEEDS_UPDATE: return "HD_CALIBRATION_NEEDS_UPDATE";
    case HD_CALIBRATION_NEEDS_MANUAL_INPUT: return "HD_CALIBRATION_NEEDS_MANUAL_INPUT";
    default: return "calibration status " + hex4(status);
    }
}

void open_locked(OpenHapticsDevice::State& s) {
    const OpenHapticsOptions& o = s.options;
    s.label = o.device_name.empty() ? "the default device" : "device \"" + o.device_name + "\"";
    if (!o.library.empty()) {
        s.library_path = o.library;
    } else if (const char* env = std::getenv("HEARTSIM_OPENHAPTICS_LIB"); env && *env) {
        s.library_path = env;
    } else {
        s.library_path = "libHD.so";
    }
    if (!(o.force_hold_ms >= 0.0) || !(o.force_timeout_ms > o.force_hold_ms) || !std::isfinite(o.force_timeout_ms) ||
        !(o.servo_stall_ms > 0.0) || !std::isfinite(o.servo_stall_ms) || !(o.damping_n_ms_per_mm >= 0.0) ||
        !std::isfinite(o.damping_n_ms_per_mm))
        throw InputError(s.prefix() + "options need 0 <= force_hold_ms < force_timeout_ms, servo_stall_ms > 0 and "
                                      "damping >= 0, all finite");

    dlerror();
    s.library = dlopen(s.library_path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!s.library) {
        const char* why = dlerror();
        s.fail(std::string("cannot load the OpenHaptics HD library: ") + (why ? why : "dlopen failed") +
               " (install OpenHaptics, or set HEARTSIM_OPENHAPTICS_LIB to libHD.so's path)");
    }
    HdApi& hd = s.hd;
    resolve(s, hd.hdInitDevice, "hdInitDevice");
    resolve(s, hd.hdDisableDevice, "hdDisableDevice");
    resolve(s, hd.hdMakeCurrentDevice, "hdMakeCurrentDevice");
    resolve(s, hd.hdBeginFrame, "hdBeginFrame");
    resolve(s, hd.hdEndFrame, "hdEndFrame");
    resolve(s, hd.hdGetError, "hdGetError");
    resolve(s, hd.hdGetErrorString, "hdGetErrorString");
    resolve(s, hd.hdEnable, "hdEnable");
    resolve(s, hd.hdDisable, "hdDisable");
    resolve(s, hd.hdGetDoublev, "hdGetDoublev");
    resolve(s, hd.hdGetIntegerv, "hdGetIntegerv");
    resolve(s, hd.hdSetDoublev, "hdSetDoublev");
    resolve(s, hd.hdGetString, "hdGetString", false);
    resolve(s, hd.hdCheckCalibration, "hdCheckCalibration");
    resolve(s, hd.hdUpdateCalibration, "hdUpdateCalibration");
    resolve(s, hd.hdStartScheduler, "hdStartScheduler");
    resolve(s, hd.hdStopScheduler, "hdStopScheduler");
    resolve(s, hd.hdScheduleAsynchronous, "hdScheduleAsynchronous");
    resolve(s, hd.hdScheduleSynchronous, "hdScheduleSynchronous");
    resolve(s, hd.hdUnschedule, "hdUnschedule");
    s.take_error();  // stale errors of earlier users of the library

    // The device. HD_DEFAULT_DEVICE is a null name.
    const HHD handle = hd.hdInitDevice(o.device_name.empty() ? nullptr : o.device_name.c_str());
    const HDErrorInfo init_error = s.take_error();
    if (init_error.errorCode != HD_SUCCESS || handle == HD_INVALID_HANDLE) {
        if (handle != HD_INVALID_HANDLE) hd.hdDisableDevice(handle);
        s.fail("hdInitDevice failed (device not found, not configured, in use or not permitted): " +
               (init_error.errorCode != HD_SUCCESS ? s.describe(init_error) : std::string("HD_INVALID_HANDLE")));
    }
    s.handle = handle;
    hd.hdMakeCurrentDevice(handle);

    // Properties, each optional: a query HD refuses keeps heartsim's default.
    if (hd.hdGetString) {
        const char* model = hd.hdGetString(HD_DEVICE_MODEL_TYPE);
        if (s.take_error().errorCode == HD_SUCCESS && model) s.model = model;
    }
    auto query_force = [&](HDenum name) {
        HDdouble value = 0.0;
        hd.hdGetDoublev(name, &value);
        return s.take_error().errorCode == HD_SUCCESS && std::isfinite(value) && value > 0.0 ? value : 0.0;
    };
    s.limits = DeviceLimits{};
    if (const double continuous = query_force(HD_NOMINAL_MAX_CONTINUOUS_FORCE); continuous > 0.0)
        s.limits.max_force_n = continuous;
    else if (const double peak = query_force(HD_NOMINAL_MAX_FORCE); peak > 0.0)
        s.limits.max_force_n = peak;
    else
        s.limits.max_force_n = 3.3;  // Touch / Phantom Omni nominal peak force
    {
        HDdouble box[6] = {0, 0, 0, 0, 0, 0};
        hd.hdGetDoublev(HD_USABLE_WORKSPACE_DIMENSIONS, box);
        const Eigen::Vector3d lo(box[0], box[1], box[2]), hi(box[3], box[4], box[5]);
        if (s.take_error().errorCode == HD_SUCCESS && lo.allFinite() && hi.allFinite() && (hi.array() > lo.array()).all())
            s.limits.workspace_mm = Eigen::AlignedBox3d(lo, hi);
    }
    s.limits.damping_n_ms_per_mm = o.damping_n_ms_per_mm;
    HDint styles = 0;
    hd.hdGetIntegerv(HD_CALIBRATION_STYLE, &styles);
    if (s.take_error().errorCode != HD_SUCCESS) styles = 0;

    hd.hdEnable(HD_FORCE_OUTPUT);
    s.check("hdEnable(HD_FORCE_OUTPUT)");
    s.force_enabled = true;

    // The scheduler: one per process, started by the first device.
    SchedulerUse* use = find_use(s.library);
    if (!use) {
        hd.hdStartScheduler();
        s.check("hdStartScheduler");
        registry().push_back({s.library, 0});
        use = &registry().back();
    }
    ++use->devices;
    s.registered = true;

    // Calibration (needs the running scheduler). An auto or inkwell device that needs an update
    // gets one; a device that needs the user (stylus into the inkwell, arm to its reset position)
    // is refused: there is nobody to ask in the middle of a run.
    CalibrationCall call{&hd, handle, 0, 0};
    hd.hdScheduleSynchronous(calibration_status_callback, &call, HD_DEFAULT_SCHEDULER_PRIORITY);
    s.check("hdCheckCalibration");
    if (call.status == HD_CALIBRATION_NEEDS_UPDATE) {
        call.style = (styles & HD_CALIBRATION_AUTO) ? HD_CALIBRATION_AUTO : (styles & HD_CALIBRATION_INKWELL) ? HD_CALIBRATION_INKWELL : 0;
        if (call.style == 0)
            s.fail("the device needs calibrating (HD_CALIBRATION_NEEDS_UPDATE) and supports neither auto nor inkwell "
                   "calibration (HD_CALIBRATION_STYLE " + std::to_string(styles) + "): calibrate it with the vendor's "
                   "tool, then retry");
        hd.hdScheduleSynchronous(calibration_update_callback, &call, HD_DEFAULT_SCHEDULER_PRIORITY);
        s.check("hdUpdateCalibration");
        hd.hdScheduleSynchronous(calibration_status_callback, &call, HD_DEFAULT_SCHEDULER_PRIORITY);
        s.check("hdCheckCalibration");
    }
    if (call.status == HD_CALIBRATION_NEEDS_MANUAL_INPUT)
        s.fail("the device needs calibrating by hand (HD_CALIBRATION_NEEDS_MANUAL_INPUT): put the stylus into its "
               "inkwell (or the arm into its reset position), then retry");
    if (call.status != HD_CALIBRATION_OK) s.fail("the device is not calibrated: " + calibration_name(call.status));

    // The servo callback, until close.
    s.callback = hd.hdScheduleAsynchronous(servo_callback, &s, HD_DEFAULT_SCHEDULER_PRIORITY);
    s.check("hdScheduleAsynchronous");
    s.scheduled = true;
}

}  // namespace

// ------------------------------------------------------------------------------------------------

OpenHapticsDevice::OpenHapticsDevice(std::unique_ptr<State> state) : state_(std::move(state)) {}

OpenHapticsDevice::~OpenHapticsDevice() {
    std::lock_guard lock(registry_mutex());
    close_locked(*state_);
}

std::string OpenHapticsDevice::name() const {
    return state_->options.device_name.empty() ? "openhaptics" : "openhaptics:" + state_->options.device_name;
}

DeviceLimits OpenHapticsDevice::limits() const { return state_->limits; }

DevicePose OpenHapticsDevice::read_pose(double time_ms) {
    State& s = *state_;
    ServoSample sample;
    const bool fresh = s.poses.fetch(sample);
    if (fresh || !s.read_once) s.last_fresh_ms = time_ms;
    s.read_once = true;
    if (!s.stall_fault.load(std::memory_order_relaxed) && time_ms - s.last_fresh_ms > s.options.servo_stall_ms) {
        s.stall_ms = time_ms - s.last_fresh_ms;
        s.stall_fault.store(true, std::memory_order_release);
    }
    DevicePose pose;
    pose.position_mm = Eigen::Vector3d(sample.position_mm[0], sample.position_mm[1], sample.position_mm[2]);
    pose.orientation = Eigen::Quaterniond(sample.rotation_wxyz[0], sample.rotation_wxyz[1], sample.rotation_wxyz[2],
                                          sample.rotation_wxyz[3]);
    pose.buttons = sample.buttons;
    return pose;
}

void OpenHapticsDevice::send_force(const Eigen::Vector3d& force_n, double) {
    State& s = *state_;
    s.forces.publish(ForceCommand{{force_n.x(), force_n.y(), force_n.z()}, ++s.sequence});
}

std::string OpenHapticsDevice::fault() const {
    const State& s = *state_;
    std::string text;
    if (s.hd_fault.load(std::memory_order_acquire)) {
        const HDErrorInfo error{s.fault_code, s.fault_internal, s.handle};
        char when[64];
        std::snprintf(when, sizeof when, "%.1f", s.fault_ms);
        text = "openhaptics: " + s.label + ": " + s.describe(error) + " in servo frame " + std::to_string(s.fault_frame) +
               " (" + when + " ms after open); force held at zero";
    }
    if (s.stall_fault.load(std::memory_order_acquire)) {
        char stall[64];
        std::snprintf(stall, sizeof stall, "%.1f", s.stall_ms);
        text += (text.empty() ? "openhaptics: " + s.label + ": " : "; ") + std::string("no servo frame for ") + stall +
                " ms (the HD servo loop stopped); force held at zero";
    }
    return text;
}

OpenHapticsCounters OpenHapticsDevice::counters() const {
    const auto& c = state_->counters;
    return {c.servo_frames.load(), c.forces_received.load(), c.non_finite.load(),
            c.clamped.load(),      c.faded.load(),           c.bad_poses.load()};
}

const std::string& OpenHapticsDevice::model() const { return state_->model; }
const std::string& OpenHapticsDevice::library() const { return state_->library_path; }

std::unique_ptr<Device> open_openhaptics(const OpenHapticsOptions& options) {
    auto state = std::make_unique<OpenHapticsDevice::State>();
    state->options = options;
    std::lock_guard lock(registry_mutex());
    try {
        open_locked(*state);
    } catch (...) {
        close_locked(*state);
        throw;
    }
    return std::make_unique<OpenHapticsDevice>(std::move(state));
}

}  // namespace heartsim::haptics
