#include "terminal_progress.h"

#include <cstdio>
#include <cstdlib>
#include <unistd.h>

namespace heartsim::cli {

namespace {
constexpr double show_after_seconds = 1.0;

std::mutex last_stage_mutex;
std::string last_stage_name;
}  // namespace

double progress_interval_seconds() {
    if (const char* text = std::getenv("HEARTPREP_PROGRESS_SECONDS")) {
        char* end = nullptr;
        const double value = std::strtod(text, &end);
        if (end != text && *end == '\0' && value >= 0.0 && value < 1e9) return value;
    }
    return 10.0;
}

std::string TerminalProgress::last_stage() {
    std::lock_guard lock(last_stage_mutex);
    return last_stage_name;
}

TerminalProgress::TerminalProgress(bool quiet)
    : quiet_(quiet), terminal_(isatty(fileno(stderr)) != 0), interval_(progress_interval_seconds()) {}

void TerminalProgress::begin(std::string_view stage, std::uint64_t total) {
    {
        std::lock_guard lock(last_stage_mutex);
        last_stage_name = stage;
    }
    std::lock_guard lock(mutex_);
    if (depth_++ > 0) return;
    stage_ = stage;
    total_ = total;
    done_ = 0;
    start_ = last_draw_ = Clock::now();
    shown_ = false;
}

void TerminalProgress::update(std::uint64_t done) {
    done_ = done;
    if (quiet_) return;
    std::unique_lock lock(mutex_, std::try_to_lock);  // workers never wait for the drawing
    if (!lock.owns_lock() || depth_ != 1) return;
    const auto now = Clock::now();
    if (!terminal_) {
        // A log or a pipe: a line now and then, so a long stage is seen to be going.
        if (interval_ <= 0.0 || std::chrono::duration<double>(now - last_draw_).count() < interval_) return;
        last_draw_ = now;
        const double seconds = std::chrono::duration<double>(now - start_).count();
        if (total_)
            std::fprintf(stderr, "heartprep: %s: %d%% after %.0f s\n", stage_.c_str(),
                         int(100.0 * std::min(1.0, double(done_) / double(total_))), seconds);
        else
            std::fprintf(stderr, "heartprep: %s: running for %.0f s\n", stage_.c_str(), seconds);
        std::fflush(stderr);
        return;
    }
    if (std::chrono::duration<double>(now - start_).count() < show_after_seconds) return;
    if (shown_ && std::chrono::duration<double>(now - last_draw_).count() < 0.1) return;
    last_draw_ = now;
    draw(false);
}

void TerminalProgress::end() {
    std::lock_guard lock(mutex_);
    if (--depth_ > 0) return;
    if (quiet_) return;
    const double seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    if (terminal_) {
        if (shown_ || seconds >= show_after_seconds) {
            done_ = total_;
            draw(true);
        }
    } else if (seconds >= show_after_seconds) {
        std::fprintf(stderr, "heartprep: %s: %.1f s\n", stage_.c_str(), seconds);
    }
}

void TerminalProgress::draw(bool final) {
    const double seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    constexpr int width = 30;
    const double fraction = total_ ? std::min(1.0, double(done_) / double(total_)) : (final ? 1.0 : 0.0);
    std::string bar(width, ' ');
    if (total_ || final)
        for (int i = 0; i < int(fraction * width + 0.5); ++i) bar[std::size_t(i)] = '#';
    else
        bar[std::size_t(int(seconds * 8) % width)] = '#';  // unknown total: a moving mark
    std::fprintf(stderr, "\r%-22s [%s] %3d%%  %5.1f s%s", stage_.c_str(), bar.c_str(), int(fraction * 100 + 0.5), seconds,
                 final ? "\n" : "");
    std::fflush(stderr);
    shown_ = true;
}

}  // namespace heartsim::cli
