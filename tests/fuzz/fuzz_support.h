/// @file fuzz_support.h
/// @brief What the libFuzzer targets share. heartsim's readers take paths, so each input is
/// written to a file of its own process under /dev/shm (memory, no disk wear) and the real reader
/// is called on it. A documented refusal (InputError, libmodel/errors.h) is an expected outcome;
/// anything else (a crash, a sanitizer report, another exception type escaping, a leak, a
/// timeout, an allocation over libFuzzer's -malloc_limit_mb) is a finding. tests/fuzz/README.md.
#pragma once

#include "libmodel/errors.h"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

namespace heartsim::fuzz {

/// Writes `size` bytes to `name` inside this process's folder /dev/shm/heartsim-fuzz-<pid>
/// (created on first use, removed at exit) and returns the file's path. The same name is
/// rewritten for every input.
std::filesystem::path write_input(const std::uint8_t* data, std::size_t size, const std::string& name);

/// Runs `read`; an InputError is the reader refusing bad input as documented, and is swallowed.
/// Every other exception escapes to libFuzzer, which reports it as a crash.
template <class Read>
void expect_refusal_or_success(Read&& read) {
    try {
        read();
    } catch (const InputError&) {
    }
}

/// A broken promise of a reader that returned normally: prints `what` and aborts (a finding).
[[noreturn]] void broken(const std::string& what);

}  // namespace heartsim::fuzz
