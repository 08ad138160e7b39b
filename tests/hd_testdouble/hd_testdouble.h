/// @file hd_testdouble.h
/// @brief The test-only entry points of hd_testdouble, a TEST DOUBLE of the OpenHaptics HD
/// library (libHD.so): a shared library exporting the same HD C functions over a simulated device,
/// so runtime/haptics/openhaptics.cpp can be tested where there is neither the SDK nor a Touch. It is not
/// 3D Systems' library and imitates only what heartsim uses. Tests reach these functions with
/// dlsym on the same library the device loaded.
///
/// Behaviour is chosen when a device is initialised, from the environment:
///   HD_TESTDOUBLE_MODE = ok (default) | not_found | calibration | calibration_update | scheduler
///                        | fault_after_ms=N
///     not_found           hdInitDevice fails with HD_COMM_CONFIG_ERROR
///     calibration         hdCheckCalibration says HD_CALIBRATION_NEEDS_MANUAL_INPUT (inkwell style)
///     calibration_update  HD_CALIBRATION_NEEDS_UPDATE until hdUpdateCalibration(HD_CALIBRATION_AUTO)
///     scheduler           hdStartScheduler fails with HD_TIMER_ERROR
///     fault_after_ms=N    every frame from N ms after the scheduler started raises HD_COMM_ERROR
///                         and renders no force (a device unplugged)
///   HD_TESTDOUBLE_DEVICES = the configured names, comma separated
///                         (default "Default Device,Left Device,Right Device"; null = the first)
#pragma once

#ifdef __cplusplus
extern "C" {
#endif

/// What the simulated device received, for assertions.
struct HdTestDoubleStats {
    int open;                         ///< initialised and not yet disabled
    int scheduler_running;            ///< the simulated servo thread runs
    unsigned long frames;             ///< hdEndFrame calls on this device
    double last_force[3];             ///< the force the last frame rendered, N
    double max_force_norm;            ///< the largest |force| rendered since hdInitDevice, N
    unsigned long non_finite_forces;  ///< non-finite forces given to hdSetDoublev (never rendered)
    unsigned long over_max_forces;    ///< forces above HD_NOMINAL_MAX_FORCE given to it (never rendered)
    double servo_ms;                  ///< the double's servo clock: ms since the scheduler started
    double last_nonzero_force_ms;     ///< servo clock of the last frame that rendered a non-zero force (-1: none)
    double position[3];               ///< the simulated device's position, mm
    unsigned long calibration_updates;  ///< hdUpdateCalibration calls that calibrated it
    unsigned long errors_raised;        ///< HD errors pushed for this device
};

/// Fills `stats` for the device initialised under `name` (null = the default device); returns 0
/// when the double never initialised that name since its state was last reset, else 1.
int hd_testdouble_stats(const char* name, struct HdTestDoubleStats* stats);
typedef int (*hd_testdouble_stats_function)(const char* name, struct HdTestDoubleStats* stats);

#ifdef __cplusplus
}
#endif
