/// @file errors.h
/// @brief The exceptions heartsim throws. Each message names the file, the field and what was
/// expected, so the command-line tools can print it as the one-line cause of a failure.
#pragma once

#include <cstring>
#include <new>
#include <stdexcept>
#include <string>
#include <system_error>

namespace heartsim {

/// Bad input: a file that cannot be read, a field that is missing or out of range, an option
/// that contradicts the data. The user can fix it.
class InputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Options that are wrong in themselves or contradict each other, whatever the data: an option
/// value outside its set, labels given both as tissue and as cavity. The caller's request is at
/// fault, not a file. libmodel names an option by its meaning, in braces: `{LayoutOptions::occupancy}`,
/// `{SelectionOptions::tissue_labels}`; heartprep spells it as its flag (cli/option_flags.h),
/// in this message and in a report's warnings alike.
class OptionError : public InputError {
public:
    using InputError::InputError;
};

/// An output that could not be written (permissions, disk full). Nothing half-written remains.
class OutputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// Long work stopped because the caller's Progress asked to cancel.
class Cancelled : public std::runtime_error {
public:
    Cancelled() : std::runtime_error("cancelled") {}
};

/// Whether `error` means the process ran out of memory (or of address space): std::bad_alloc, or a
/// thread that could not be started (std::thread's std::system_error with EAGAIN or ENOMEM, or
/// oneTBB's std::runtime_error "pthread_create has failed: …"). The command-line tools report
/// these as one line "out of memory while …" rather than their library's own words.
inline bool is_out_of_memory(const std::exception& error) {
    if (dynamic_cast<const std::bad_alloc*>(&error)) return true;
    if (const auto* system = dynamic_cast<const std::system_error*>(&error))
        return system->code() == std::errc::resource_unavailable_try_again || system->code() == std::errc::not_enough_memory;
    return std::strncmp(error.what(), "pthread_create has failed", 25) == 0;
}

}  // namespace heartsim
