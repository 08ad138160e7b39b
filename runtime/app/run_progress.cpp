// A headless run's progress lines: run_progress.h; docs/runtime.md "Progress of a headless run".
#include "runtime/app/run_progress.h"

#include <algorithm>
#include <cmath>

namespace heartsim {
namespace {

/// "6.0 s" below ten seconds, "18 s" above.
void print_seconds(std::FILE* out, double s) { std::fprintf(out, s < 10.0 ? "%.1f s" : "%.0f s", s); }

}  // namespace

RunProgress::RunProgress(int steps, double end_ms, std::FILE* out, RunProgressSettings settings)
    : steps_(steps), end_ms_(end_ms), out_(out), settings_(settings) {
    if (steps_ < settings_.quarters_from_steps) next_quarter_ = 4;
}

void RunProgress::after_step(int steps_done, double simulated_ms, double step_ms, double wall_s) {
    // How far: by the simulated time where the run ends at a time, else by the steps (a step that
    // lengthened on the way makes the rest longer in simulated time, not in steps).
    double fraction = 0.0, total_ms = 0.0;
    if (end_ms_ > 0.0) {
        fraction = simulated_ms / end_ms_;
        total_ms = end_ms_;
    } else if (steps_ > 0) {
        fraction = double(steps_done) / double(steps_);
        total_ms = simulated_ms + double(std::max(steps_ - steps_done, 0)) * step_ms;
    }
    fraction = std::clamp(fraction, 0.0, 1.0);
    if (fraction >= 1.0) return;  // the closing line says the end
    bool due = settings_.every_s > 0.0 && wall_s - last_line_s_ >= settings_.every_s;
    if (next_quarter_ < 4 && fraction >= 0.25 * next_quarter_) {
        due = true;
        while (next_quarter_ < 4 && fraction >= 0.25 * next_quarter_) ++next_quarter_;
    }
    if (due) say(fraction, simulated_ms, total_ms, wall_s);
}

void RunProgress::finish(double simulated_ms, double wall_s) {
    if (lines_ == 0) return;
    std::fprintf(out_, "heartsim: run: 100%% (%.0f ms simulated) in ", simulated_ms);
    print_seconds(out_, wall_s);
    std::fprintf(out_, "\n");
    std::fflush(out_);
    ++lines_;
}

void RunProgress::say(double fraction, double simulated_ms, double total_ms, double wall_s) {
    // The percent rounded down, so a line said on passing 25 % says 25%.
    std::fprintf(out_, "heartsim: run: %d%% (%.0f of %.0f ms simulated) after ", int(std::floor(100.0 * fraction)), simulated_ms, total_ms);
    print_seconds(out_, wall_s);
    // The rest at the pace so far.
    if (fraction > 0.0) {
        std::fprintf(out_, ", about ");
        print_seconds(out_, wall_s * (1.0 - fraction) / fraction);
        std::fprintf(out_, " left");
    }
    std::fprintf(out_, "\n");
    std::fflush(out_);
    last_line_s_ = wall_s;
    ++lines_;
}

}  // namespace heartsim
