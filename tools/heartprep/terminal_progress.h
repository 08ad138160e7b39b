/// @file terminal_progress.h
/// @brief heartsim::Progress on stderr: a progress bar on a terminal (shown once a stage has run
/// for a second); when stderr is a file or a pipe (logs, CI, batch runs), plain lines: how far a
/// long stage has come every progress_interval_seconds(), and each stage's time when it ends.
#pragma once

#include "libmodel/progress.h"

#include <atomic>
#include <chrono>
#include <mutex>
#include <string>

namespace heartsim::cli {

/// Where stderr is not a terminal (a log, a pipe, a batch's case), a long stage and a batch print a
/// plain line this often, in seconds: HEARTPREP_PROGRESS_SECONDS, default 10; 0 = never.
double progress_interval_seconds();

class TerminalProgress final : public Progress {
public:
    /// `quiet` suppresses everything.
    explicit TerminalProgress(bool quiet = false);
    void begin(std::string_view stage, std::uint64_t total) override;
    void update(std::uint64_t done) override;
    void end() override;

    /// The stage most recently begun by any TerminalProgress of the process ("" before the
    /// first), kept after it ends: main() names it when the work runs out of memory.
    static std::string last_stage();

private:
    using Clock = std::chrono::steady_clock;
    void draw(bool final);
    bool quiet_;
    bool terminal_;
    std::mutex mutex_;
    std::string stage_;
    std::uint64_t total_ = 0;
    std::atomic<std::uint64_t> done_{0};
    Clock::time_point start_;
    Clock::time_point last_draw_;  ///< the bar drawn, or a plain line printed
    double interval_;              ///< progress_interval_seconds()
    bool shown_ = false;
    int depth_ = 0;  ///< nested stages: only the outermost prints
};

}  // namespace heartsim::cli
