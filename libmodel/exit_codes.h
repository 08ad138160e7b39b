/// @file exit_codes.h
/// @brief The exit status of heartprep and heartsim: one table for both (docs/user-guide.md, "Exit
/// status"). Each failure is one line on stderr, `PROGRAM: error: FILE: what`.
#pragma once

namespace heartsim {

enum class ExitCode : int {
    success = 0,
    input_error = 1,       ///< a file given, or a value in it, is unusable (InputError); heartprep batch: a case failed
    usage = 2,             ///< the command line is wrong (UsageError, every CLI11 parse error)
    no_opengl = 3,         ///< no usable OpenGL (GlUnavailable)
    haptic_device = 4,     ///< a haptic device that cannot be used (DeviceUnavailable, a device fault)
    replay_mismatch = 5,   ///< `heartsim run --replay`: forces beyond the tolerance
    unrecoverable = 6,     ///< the simulation could not recover (the watchdog gave up)
    internal_error = 7,    ///< an output could not be written (OutputError), out of memory, any other failure
};

/// The process exit status of `code`, for `return exit_status(…)` from main().
constexpr int exit_status(ExitCode code) { return static_cast<int>(code); }

/// The table, for the end of `--help`.
inline constexpr const char* exit_status_help =
    "Exit status: 0 success, 1 input error (a file or a value in it), 2 usage (the command line), 3 no usable OpenGL,\n"
    "4 haptic device unusable, 5 --replay forces beyond the tolerance, 6 the simulation could not recover,\n"
    "7 an output could not be written, out of memory, or an internal error (docs/user-guide.md, \"Exit status\").";

}  // namespace heartsim
