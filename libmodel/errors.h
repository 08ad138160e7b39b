/// @file errors.h
/// @brief The exceptions heartsim throws. Each message names the file, the field and what was
/// expected, so the command-line tools can print it as the one-line cause of a failure.
#pragma once

#include <stdexcept>
#include <string>

namespace heartsim {

/// Bad input: a file that cannot be read, a field that is missing or out of range, an option
/// that contradicts the data. The user can fix it.
class InputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
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

}  // namespace heartsim
