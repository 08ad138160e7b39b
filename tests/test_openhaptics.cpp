// The `openhaptics` device (runtime/haptics/openhaptics.h) against hd_testdouble, a test double of the
// OpenHaptics HD library with a simulated device (tests/hd_testdouble/). Real time: the double
// runs its own 1 kHz servo thread, as HD does; assertions are on what the double's device
// received, never on wall-clock rates.
#include "runtime/haptics/openhaptics.h"

#include "hd_testdouble.h"

#include <gtest/gtest.h>

#include <dlfcn.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <limits>
#include <string>
#include <thread>
#include <vector>

using namespace heartsim;
using namespace heartsim::haptics;

namespace {

const std::string kDouble = HD_TESTDOUBLE_LIB;

/// What the double's device received (the test holds its own handle on the same library, so the
/// double's state is the one the device under test uses).
HdTestDoubleStats double_stats(const char* name = nullptr) {
    static void* library = dlopen(kDouble.c_str(), RTLD_NOW | RTLD_LOCAL);
    static auto stats = library ? reinterpret_cast<hd_testdouble_stats_function>(dlsym(library, "hd_testdouble_stats")) : nullptr;
    if (!stats) throw std::runtime_error("cannot load the test double " + kDouble);
    HdTestDoubleStats s{};
    stats(name, &s);
    return s;
}

/// HD_TESTDOUBLE_MODE for one scope.
struct DoubleMode {
    explicit DoubleMode(const char* mode) { setenv("HD_TESTDOUBLE_MODE", mode, 1); }
    ~DoubleMode() { unsetenv("HD_TESTDOUBLE_MODE"); }
};

OpenHapticsOptions on_double(const std::string& device_name = "") {
    OpenHapticsOptions options;
    options.device_name = device_name;
    options.library = kDouble;
    return options;
}

OpenHapticsDevice& as_openhaptics(Device& device) { return dynamic_cast<OpenHapticsDevice&>(device); }

/// The message open_openhaptics threw as DeviceUnavailable, or "(opened)".
std::string open_error(const OpenHapticsOptions& options) {
    try {
        open_openhaptics(options);
    } catch (const DeviceUnavailable& e) {
        return e.what();
    }
    return "(opened)";
}

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

/// Plays heartsim's device thread for `duration_ms`: read_pose then send_force(force(t)) every ms.
std::vector<DevicePose> drive(Device& device, double duration_ms,
                              const std::function<Eigen::Vector3d(double)>& force = [](double) { return Eigen::Vector3d::Zero(); }) {
    std::vector<DevicePose> poses;
    const auto t0 = Clock::now();
    auto next = t0;
    for (double t = 0.0; t < duration_ms; t = ms_since(t0)) {
        poses.push_back(device.read_pose(t));
        device.send_force(force(t), t);
        next += std::chrono::milliseconds(1);
        std::this_thread::sleep_until(next);
    }
    return poses;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST(OpenHaptics, ADeviceIsFoundItsPosesArriveAndMove) {
    auto device = open_openhaptics(on_double());
    auto& touch = as_openhaptics(*device);
    EXPECT_EQ(device->name(), "openhaptics");
    EXPECT_EQ(touch.model(), "hd_testdouble (simulated Touch)");
    EXPECT_EQ(touch.library(), kDouble);
    // Limits as the double reports them (HD_NOMINAL_MAX_CONTINUOUS_FORCE, HD_USABLE_WORKSPACE_DIMENSIONS).
    const DeviceLimits limits = device->limits();
    EXPECT_DOUBLE_EQ(limits.max_force_n, 0.88);
    EXPECT_TRUE(limits.workspace_mm.min().isApprox(Eigen::Vector3d(-100, -70, -50)));
    EXPECT_TRUE(limits.workspace_mm.max().isApprox(Eigen::Vector3d(100, 70, 50)));
    EXPECT_DOUBLE_EQ(limits.damping_n_ms_per_mm, DeviceLimits{}.damping_n_ms_per_mm);

    const auto t0 = Clock::now();  // drive's clock, within a microsecond
    const std::vector<DevicePose> poses = drive(*device, 600.0);
    const std::uint64_t frames_before = touch.counters().servo_frames;
    const HdTestDoubleStats stats = double_stats();
    const std::uint64_t frames_after = touch.counters().servo_frames;
    EXPECT_EQ(stats.open, 1);
    EXPECT_EQ(stats.scheduler_running, 1);
    EXPECT_GT(stats.frames, 100u);
    EXPECT_EQ(stats.errors_raised, 0u);
    // One servo callback per frame: the double counts at hdEndFrame, the device just after.
    EXPECT_LE(frames_before, stats.frames);
    EXPECT_LE(stats.frames, frames_after + 1);

    double travel = 0.0, largest_angle = 0.0;
    bool pressed = false, released = false;
    for (const DevicePose& pose : poses) {
        ASSERT_TRUE(pose.position_mm.allFinite());
        travel = std::max(travel, (pose.position_mm - poses.front().position_mm).norm());
        // The double turns the stylus about y: the quaternion is unit with x = z = 0.
        EXPECT_NEAR(pose.orientation.norm(), 1.0, 1e-12);
        EXPECT_NEAR(pose.orientation.x(), 0.0, 1e-12);
        EXPECT_NEAR(pose.orientation.z(), 0.0, 1e-12);
        largest_angle = std::max(largest_angle, std::abs(2.0 * std::atan2(pose.orientation.y(), pose.orientation.w())));
        pressed = pressed || pose.buttons == 1u;
        released = released || pose.buttons == 0u;
    }
    EXPECT_GT(travel, 5.0) << "the simulated hand moves ~37 mm along its circle in 600 ms";
    EXPECT_GT(largest_angle, 0.01);
    EXPECT_LE(largest_angle, 0.3 + 1e-9);
    EXPECT_TRUE(pressed && released) << "button 1 toggles every 250 ms";
    // The newest pose is the double's device position, a few servo frames old at most. The hand
    // moves ~0.06 mm per ms, so the two reads must be close in time: on a loaded machine this
    // thread can be preempted between them, and then the pair is read again. read_pose gets the
    // drive's clock: a made-up later time would look like a servo stall to the device.
    HdTestDoubleStats now{};
    DevicePose last{};
    for (int attempt = 0; attempt < 50; ++attempt) {
        const auto before = Clock::now();
        now = double_stats();
        last = device->read_pose(ms_since(t0));
        if (ms_since(before) < 2.0) break;
    }
    EXPECT_LT((last.position_mm - Eigen::Vector3d(now.position[0], now.position[1], now.position[2])).norm(), 2.0);
    EXPECT_EQ(touch.fault(), "");

    device.reset();
    const HdTestDoubleStats closed = double_stats();
    EXPECT_EQ(closed.open, 0) << "hdDisableDevice on close";
    EXPECT_EQ(closed.scheduler_running, 0) << "hdStopScheduler with the last device";
}

TEST(OpenHaptics, AForceReachesTheDeviceClampedToItsMaximumAndNonFiniteNever) {
    auto device = open_openhaptics(on_double());
    auto& touch = as_openhaptics(*device);

    const Eigen::Vector3d small(0.3, -0.2, 0.1);
    drive(*device, 150.0, [&](double) { return small; });
    HdTestDoubleStats stats = double_stats();
    EXPECT_NEAR(stats.max_force_norm, small.norm(), 1e-12) << "rendered as sent";
    const Eigen::Vector3d last(stats.last_force[0], stats.last_force[1], stats.last_force[2]);
    EXPECT_LT(last.normalized().cross(small.normalized()).norm(), 1e-12);

    drive(*device, 150.0, [](double) { return Eigen::Vector3d(10.0, 0.0, 0.0); });
    stats = double_stats();
    EXPECT_NEAR(stats.max_force_norm, 0.88, 1e-12) << "clamped to HD_NOMINAL_MAX_CONTINUOUS_FORCE";
    EXPECT_GT(touch.counters().clamped, 0u);

    const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
    drive(*device, 150.0, [&](double t) {
        const int k = static_cast<int>(t) % 3;
        return k == 0 ? Eigen::Vector3d(nan, 0.1, 0.0) : k == 1 ? Eigen::Vector3d(0.1, -inf, 0.0) : Eigen::Vector3d(0.1, 0.0, 0.0);
    });
    stats = double_stats();
    EXPECT_EQ(stats.non_finite_forces, 0u) << "a non-finite force reached hdSetDoublev";
    EXPECT_EQ(stats.over_max_forces, 0u);
    EXPECT_LE(stats.max_force_norm, 0.88 + 1e-12);
    EXPECT_GT(touch.counters().non_finite, 0u);
    EXPECT_EQ(stats.errors_raised, 0u);
    EXPECT_EQ(touch.fault(), "");
}

TEST(OpenHaptics, TheForceFadesToZeroWithin50msWhenSendForceStops) {
    auto device = open_openhaptics(on_double());
    drive(*device, 200.0, [](double) { return Eigen::Vector3d(0.0, 0.5, 0.0); });
    const double stopped_ms = double_stats().servo_ms;  // the servo clock at the last send_force
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const HdTestDoubleStats stats = double_stats();
    EXPECT_EQ(stats.last_force[0], 0.0);
    EXPECT_EQ(stats.last_force[1], 0.0);
    EXPECT_EQ(stats.last_force[2], 0.0);
    const double zero_after_ms = stats.last_nonzero_force_ms - stopped_ms;
    EXPECT_LE(zero_after_ms, 50.0) << "force_timeout_ms 45 plus a servo frame either side";
    EXPECT_GE(zero_after_ms, 5.0) << "held first (force_hold_ms 15), not cut at once";
    EXPECT_GT(as_openhaptics(*device).counters().faded, 0u);
    std::printf("[ figures  ] last non-zero force %.1f ms after send_force stopped\n", zero_after_ms);
}

TEST(OpenHaptics, ADeviceThatIsNotFoundIsReportedWithTheHdError) {
    {
        DoubleMode mode("not_found");
        const std::string message = open_error(on_double());
        EXPECT_TRUE(contains(message, "the default device")) << message;
        EXPECT_TRUE(contains(message, kDouble)) << message;
        EXPECT_TRUE(contains(message, "hdInitDevice failed")) << message;
        EXPECT_TRUE(contains(message, "HD error 0x0303 HD_COMM_CONFIG_ERROR")) << message;
        EXPECT_TRUE(contains(message, "hd_testdouble")) << message;  // HD's own description
    }
    const std::string message = open_error(on_double("No Such Device"));
    EXPECT_TRUE(contains(message, "device \"No Such Device\"")) << message;
    EXPECT_TRUE(contains(message, "HD_COMM_CONFIG_ERROR")) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << "one line";
    EXPECT_EQ(double_stats().scheduler_running, 0);
}

TEST(OpenHaptics, ACalibrationNeedingTheUserIsRefusedAnUpdateIsMade) {
    {
        DoubleMode mode("calibration");
        const std::string message = open_error(on_double("Left Device"));
        EXPECT_TRUE(contains(message, "device \"Left Device\"")) << message;
        EXPECT_TRUE(contains(message, kDouble)) << message;
        EXPECT_TRUE(contains(message, "HD_CALIBRATION_NEEDS_MANUAL_INPUT")) << message;
        EXPECT_TRUE(contains(message, "inkwell")) << message;
        const HdTestDoubleStats stats = double_stats("Left Device");
        EXPECT_EQ(stats.open, 0) << "the device is disabled again after a failed open";
        EXPECT_EQ(stats.scheduler_running, 0) << "and the scheduler it started stopped";
    }
    DoubleMode mode("calibration_update");
    auto device = open_openhaptics(on_double("Left Device"));
    EXPECT_EQ(device->name(), "openhaptics:Left Device");
    EXPECT_EQ(double_stats("Left Device").calibration_updates, 1u) << "hdUpdateCalibration(HD_CALIBRATION_AUTO)";
}

TEST(OpenHaptics, ASchedulerThatDoesNotStartIsReportedWithTheHdError) {
    DoubleMode mode("scheduler");
    const std::string message = open_error(on_double());
    EXPECT_TRUE(contains(message, "hdStartScheduler failed")) << message;
    EXPECT_TRUE(contains(message, "HD error 0x0304 HD_TIMER_ERROR")) << message;
    EXPECT_TRUE(contains(message, kDouble)) << message;
    EXPECT_EQ(double_stats().open, 0) << "the device is disabled again after a failed open";
}

TEST(OpenHaptics, AMissingLibraryOrOneWithoutTheHdApiIsReported) {
    const std::string missing = "/nonexistent/libHD.so";
    std::string message = open_error({.device_name = "Left Device", .library = missing});
    EXPECT_TRUE(contains(message, "cannot load the OpenHaptics HD library")) << message;
    EXPECT_TRUE(contains(message, missing)) << message;
    EXPECT_TRUE(contains(message, "device \"Left Device\"")) << message;
    EXPECT_TRUE(contains(message, "HEARTSIM_OPENHAPTICS_LIB")) << message;

    message = open_error({.device_name = "", .library = "libc.so.6"});
    EXPECT_TRUE(contains(message, "no symbol hdInitDevice")) << message;

    // No library option: $HEARTSIM_OPENHAPTICS_LIB.
    setenv("HEARTSIM_OPENHAPTICS_LIB", "/nonexistent/from-env.so", 1);
    message = open_error({});
    EXPECT_TRUE(contains(message, "/nonexistent/from-env.so")) << message;
    setenv("HEARTSIM_OPENHAPTICS_LIB", kDouble.c_str(), 1);
    {
        auto device = open_openhaptics({});
        EXPECT_EQ(as_openhaptics(*device).library(), kDouble);
    }
    unsetenv("HEARTSIM_OPENHAPTICS_LIB");
}

TEST(OpenHaptics, AServoFaultIsLatchedReportedAndTheForceStaysZero) {
    DoubleMode mode("fault_after_ms=150");
    auto device = open_openhaptics(on_double());
    auto& touch = as_openhaptics(*device);
    drive(*device, 400.0, [](double) { return Eigen::Vector3d(0.2, 0.0, 0.0); });
    const std::string fault = touch.fault();
    EXPECT_TRUE(contains(fault, "the default device")) << fault;
    EXPECT_TRUE(contains(fault, "HD error 0x0302 HD_COMM_ERROR")) << fault;
    EXPECT_TRUE(contains(fault, "force held at zero")) << fault;
    const HdTestDoubleStats stats = double_stats();
    EXPECT_GT(stats.max_force_norm, 0.0) << "rendered before the fault";
    EXPECT_EQ(stats.last_force[0], 0.0);
    EXPECT_LT(stats.last_nonzero_force_ms, 151.0) << "nothing after the fault";
    std::printf("[ figures  ] %s\n", fault.c_str());
}

TEST(OpenHaptics, TwoDevicesShareTheSchedulerWhichStopsWithTheLast) {
    auto left = open_openhaptics(on_double("Left Device"));
    auto right = open_openhaptics(on_double("Right Device"));
    EXPECT_TRUE(contains(open_error(on_double("Left Device")), "HD_DEVICE_ALREADY_INITIATED"));
    const auto t0 = Clock::now();
    while (ms_since(t0) < 200.0) {
        left->read_pose(ms_since(t0));
        left->send_force(Eigen::Vector3d(0.1, 0, 0), ms_since(t0));
        right->read_pose(ms_since(t0));
        right->send_force(Eigen::Vector3d(0, 0, -0.2), ms_since(t0));
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    EXPECT_NEAR(double_stats("Left Device").max_force_norm, 0.1, 1e-12);
    EXPECT_NEAR(double_stats("Right Device").max_force_norm, 0.2, 1e-12);
    left.reset();
    const unsigned long frames = double_stats("Right Device").frames;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    EXPECT_EQ(double_stats("Left Device").open, 0);
    EXPECT_GT(double_stats("Right Device").frames, frames) << "the right device's servo callback still runs";
    EXPECT_EQ(double_stats().scheduler_running, 1);
    right.reset();
    EXPECT_EQ(double_stats().scheduler_running, 0);
}

TEST(OpenHaptics, AHapticSessionDrivesTheDeviceFromItsThread) {
    auto device = open_openhaptics(on_double());
    HapticSession session;
    session.attach(0, device.get());
    session.start();
    std::vector<Eigen::Vector3d> positions;
    InstrumentForces forces;
    forces.hand[0].force_n = Eigen::Vector3d(0.0, 0.4, 0.0);
    const auto t0 = Clock::now();
    while (ms_since(t0) < 300.0) {  // the simulation's side, at 500 Hz
        if (auto tools = session.latest_tools(); tools && tools->hand[0].valid) positions.push_back(tools->hand[0].pose.position);
        session.publish_forces(forces, session.now_ms());
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    session.stop();
    const HandTelemetry telemetry = session.telemetry(0);
    EXPECT_GT(telemetry.forces_sent, 100u);
    EXPECT_TRUE(telemetry.last_force_n.isApprox(Eigen::Vector3d(0.0, 0.4, 0.0), 1e-9)) << telemetry.last_force_n.transpose();
    const HdTestDoubleStats stats = double_stats();
    EXPECT_NEAR(stats.max_force_norm, 0.4, 1e-9) << "ForceSafety fades in over 100 ms, then the full force";
    EXPECT_EQ(stats.non_finite_forces, 0u);
    ASSERT_GT(positions.size(), 10u);
    EXPECT_GT((positions.back() - positions.front()).norm(), 1.0) << "tool poses follow the moving device";
    EXPECT_EQ(as_openhaptics(*device).fault(), "");
}
