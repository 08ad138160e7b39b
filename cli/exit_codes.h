/// @file exit_codes.h
/// @brief The exit status of heartprep and heartsim: one numbering (docs/user-guide.md, "Exit
/// status"), and each program's part of it for its --help. Each failure is one line on stderr, `PROGRAM: error: FILE: what`.
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

/// heartprep's part of the table, for the end of its `--help` (its batch reads heartsim's
/// no_opengl from the preview it runs, but heartprep itself never exits with 3 to 6).
inline constexpr const char* heartprep_exit_status_help =
    "Exit status: 0 success, 1 input error (a file or a value in it; batch: a case failed), 2 usage (the command line),\n"
    "7 an output could not be written, out of memory, or an internal error (docs/user-guide.md, \"Exit status\").";

/// heartsim's, for the end of its `--help`.
inline constexpr const char* heartsim_exit_status_help =
    "Exit status: 0 success, 1 input error (a file or a value in it), 2 usage (the command line), 3 no usable OpenGL,\n"
    "4 haptic device unusable, 5 --replay forces beyond the tolerance, 6 the simulation could not recover,\n"
    "7 an output could not be written, out of memory, or an internal error (docs/user-guide.md, \"Exit status\").";

}  // namespace heartsim
