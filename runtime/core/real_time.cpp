#include "runtime/core/real_time.h"

#include "libmodel/errors.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

namespace heartsim {

RealTimeMode parse_real_time_mode(const std::string& text) {
    if (text == "auto") return RealTimeMode::automatic;
    if (text == "off") return RealTimeMode::off;
    throw OptionError("{RealTimeMode} must be auto or off, not '" + text + "'");
}

std::string mass_scale_cost(double mass_scale) {
    if (mass_scale == 1.0) return "no mass scaling: transients as physical";
    char text[128];
    std::snprintf(text, sizeof text, "transients %.2g× slower, forces at rest unchanged", std::sqrt(mass_scale));
    return text;
}

double MassScaleGovernor::assumed_factor_from_environment() {
    const char* text = std::getenv("HEARTSIM_ASSUME_REAL_TIME_FACTOR");
    if (!text || !*text) return 0.0;
    char* end = nullptr;
    const double value = std::strtod(text, &end);
    if (end == text || *end != '\0' || !(value > 0) || !std::isfinite(value))
        throw OptionError(std::string("HEARTSIM_ASSUME_REAL_TIME_FACTOR must be a positive number, not '") + text + "'");
    return value;
}

MassScaleGovernor::MassScaleGovernor(Backend& backend, double assumed_factor) : backend_(backend), assumed_factor_(assumed_factor) {}

double MassScaleGovernor::mass_scale() const { return backend_.options().mass_scale; }

double MassScaleGovernor::busy_ms() const {
    const PassTimes t = backend_.pass_times();  // gl: GPU timer queries (waits for those in flight)
    return t.step_ms + t.force_ms + t.picking_ms;
}

ScaledStep planned_step(const Backend& backend, double scale) {
    try {
        return scaled_step(backend.load_report(), backend.options(), scale);
    } catch (const InputError&) {  // a step that would need too many substeps: never a choice
        ScaledStep none;
        none.dt_ms = backend.time_step_ms();
        none.substeps = std::numeric_limits<int>::max();
        return none;
    }
}

double predicted_factor(const Backend& backend, double factor, double measured_at, double scale) {
    // The cost of a substep stays; the simulated time per substep is what S changes.
    const ScaledStep from = planned_step(backend, measured_at), to = planned_step(backend, scale);
    return factor * (to.dt_ms / double(to.substeps)) / (from.dt_ms / double(from.substeps));
}

double chosen_mass_scale(const Backend& backend, double factor, double now) {
    const auto& ladder = MassScaleGovernor::ladder;
    double best = now, best_factor = predicted_factor(backend, factor, now, now);
    for (double scale : ladder) {
        if (scale < now) continue;
        const double predicted = predicted_factor(backend, factor, now, scale);
        if (predicted >= MassScaleGovernor::margin) return scale;
        if (predicted > best_factor) best = scale, best_factor = predicted;  // none reaches it: the fastest, smallest first
    }
    return best;
}

std::string speed_verdict(const Backend& backend, double factor, double measured_at) {
    const double scale = chosen_mass_scale(backend, factor, measured_at);
    const double predicted = predicted_factor(backend, factor, measured_at, scale);
    char text[768];
    if (predicted >= 1.0) {
        if (scale == measured_at)
            std::snprintf(text, sizeof text, "keeps real time at mass scale %g (%s)", scale, mass_scale_cost(scale).c_str());
        else
            std::snprintf(text, sizeof text, "with --real-time auto (a window's and a haptic session's default) it keeps real time at mass "
                                             "scale %g, %.2f× predicted (%s)",
                          scale, predicted, mass_scale_cost(scale).c_str());
    } else {
        std::snprintf(text, sizeof text, "below real time even at mass scale %g (%.2f× predicted): %s", scale, predicted,
                      keep_up_advice(predicted, backend.size(), backend.kind(), backend.software_device()).c_str());
    }
    return text;
}

ScaledStep MassScaleGovernor::plan(double scale) const { return planned_step(backend_, scale); }

double MassScaleGovernor::predict(double factor, double measured_at, double scale) const {
    return predicted_factor(backend_, factor, measured_at, scale);
}

double MassScaleGovernor::choose(double factor) const { return chosen_mass_scale(backend_, factor, mass_scale()); }

std::optional<std::string> MassScaleGovernor::observe(double wall_ms, double simulated_ms) {
    if (!window_open_) {
        window_open_ = true;
        window_wall_ms_ = wall_ms;
        window_simulated_ms_ = simulated_ms;
        window_busy_ms_ = busy_ms();
        return std::nullopt;
    }
    const double length = first_done_ ? recheck_window_ms : first_window_ms;
    const double wall = wall_ms - window_wall_ms_;
    if (wall < length) return std::nullopt;
    const double now = mass_scale();
    const double busy_now = busy_ms();
    const double simulated = simulated_ms - window_simulated_ms_, busy = busy_now - window_busy_ms_;
    double factor = simulated / wall;
    // A run paced to the wall clock (a window, a haptic session) steps only when due: over a window
    // in which it kept up (fell behind by no more than 5 % of it) the wall clock says only "at
    // least 1", and its capacity is the simulated time over the time spent stepping. One that fell
    // behind was stepping flat out: the wall clock is the measure (drawing and all).
    if (wall - simulated <= 0.05 * wall && busy > 0) factor = std::max(factor, simulated / busy);
    if (assumed_factor_ > 0) factor = predict(assumed_factor_, 1.0, now);
    measured_ = factor;
    window_wall_ms_ = wall_ms;
    window_simulated_ms_ = simulated_ms;
    window_busy_ms_ = busy_now;
    const bool first = !first_done_;
    first_done_ = true;
    if (!first && factor >= 1.0) return std::nullopt;  // keeps up
    const double next = choose(factor);
    char line[512];
    if (next == now) {
        // Later windows say nothing unless the top of the ladder is not enough (once).
        if (!first && (now < ladder.back() || told_slow_at_top_)) return std::nullopt;
        told_slow_at_top_ = !first;
        if (factor >= 1.0)
            std::snprintf(line, sizeof line, "real time: %.2f× real time at mass scale %g: kept (%s)", factor, now, mass_scale_cost(now).c_str());
        else
            std::snprintf(line, sizeof line, "real time: %.2f× real time at mass scale %g, and a larger one would not help: %s", factor, now,
                          keep_up_advice(factor, backend_.size(), backend_.kind(), backend_.software_device()).c_str());
        return std::string(line);
    }
    backend_.set_mass_scale(next);
    const double predicted = predict(factor, now, next);
    const ScaledStep before = plan(now), after = plan(next);
    std::snprintf(line, sizeof line, "real time: %.2f× real time at mass scale %g: mass scale %g, steps of %.4g ms in %d substeps "
                                     "instead of %.4g ms in %d (%.2f× predicted; %s)%s",
                  factor, now, next, after.dt_ms, after.substeps, before.dt_ms, before.substeps, predicted, mass_scale_cost(next).c_str(),
                  predicted < 1.0 ? "; still slower than real time" : "");
    return std::string(line);
}

}  // namespace heartsim
