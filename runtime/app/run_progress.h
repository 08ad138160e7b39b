/// @file run_progress.h
/// @brief How far a headless scripted run has come (docs/runtime.md "Progress of a headless run"):
/// plain lines on stderr, as heartprep's progress lines in a log, so a run of a minute is seen to
/// be going and how long it still needs.
///
///     heartsim: run: 25% (7632 of 30534 ms simulated) after 6.0 s, about 18 s left
///
/// A line every `every_s` seconds of wall time, the first after `every_s` (a run shorter than that
/// says nothing); a run of at least `quarters_from_steps` steps also says 25, 50 and 75 % as it
/// passes them, whatever the wall clock. Where any line was said, the run ends with
/// `heartsim: run: 100% (… ms simulated) in … s`. No clock inside: the caller says the wall time,
/// so the cadence is the same function of (steps, simulated time, wall time) everywhere.
#pragma once

#include <cstdio>

namespace heartsim {

struct RunProgressSettings {
    double every_s = 5.0;             ///< a line this often, seconds of wall time; none before
    int quarters_from_steps = 40000;  ///< runs of at least this many steps also say 25, 50 and 75 %
};

class RunProgress {
public:
    /// A run of `steps` steps, or (`end_ms` > 0) until `end_ms` ms of simulated time. Lines go to
    /// `out`, each flushed.
    RunProgress(int steps, double end_ms, std::FILE* out = stderr, RunProgressSettings settings = {});

    /// After a step: `steps_done` steps, `simulated_ms` since the run's start, the step now
    /// `step_ms` long (--real-time auto lengthens it), `wall_s` seconds since the run's start.
    void after_step(int steps_done, double simulated_ms, double step_ms, double wall_s);
    /// The run has ended: the closing line, where any line was said before.
    void finish(double simulated_ms, double wall_s);
    /// How many lines were said.
    int lines() const { return lines_; }

private:
    void say(double fraction, double simulated_ms, double total_ms, double wall_s);
    int steps_;
    double end_ms_;
    std::FILE* out_;
    RunProgressSettings settings_;
    double last_line_s_ = 0.0;
    int next_quarter_ = 1;  ///< the next of 25, 50, 75 % to say, in quarters; 4 once past them
    int lines_ = 0;
};

}  // namespace heartsim
