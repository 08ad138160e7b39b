// The stepping core every mode drives: stepping.h, docs/runtime.md "The stepping core".
#include "runtime/core/stepping.h"

#include "runtime/haptics/haptic_run.h"
#include "runtime/core/real_time.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace heartsim {

namespace {
double ms_between(OwedClock::Clock::time_point a, OwedClock::Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
}
}  // namespace

double OwedClock::owed_ms(bool paused, Clock::time_point now) {
    if (paused != paused_) {
        if (paused) paused_at_ = now;
        else paused_total_ms_ += ms_between(paused_at_, now);
        paused_ = paused;
    }
    return ms_between(start_, paused ? paused_at_ : now) - paused_total_ms_;
}

Stepper::Stepper(Backend& backend, Settings settings) : backend_(backend), settings_(std::move(settings)) {
    if (settings_.real_time_auto) governor_ = std::make_unique<MassScaleGovernor>(backend_);
}

Stepper::~Stepper() = default;

int Stepper::steps_owed(double owed_ms, double simulated_ms) const {
    return int(std::clamp(std::floor((owed_ms - simulated_ms) / backend_.time_step_ms() + 1e-9), 0.0, 1e6));
}

bool Stepper::observe(double owed_ms, double simulated_ms) {
    if (!governor_) return false;
    const std::optional<std::string> change = governor_->observe(owed_ms, simulated_ms);
    if (!change) return false;
    std::printf("%s\n", change->c_str());
    std::fflush(stdout);  // a window's user (and its tests) read it as it happens
    if (settings_.haptic) settings_.haptic->record_event("mass_scale");
    return true;
}

void Stepper::restart_measuring() {
    if (governor_) governor_->restart();
}

StepReport Stepper::step_scripted(ScriptedHands& hands, const Trajectory& trajectory, StepClock& clock, long long step, bool keyboard_hand0,
                                  const std::optional<InstrumentPose>& hand0, std::optional<InstrumentForces>& forces) {
    const auto [t, t_next] = clock.at(step, backend_.time_step_ms());
    for (int hand = 0; hand < 2; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        if (hand == 0 && keyboard_hand0) {
            if (hand0) backend_.set_pose(0, *hand0);
            continue;
        }
        hands.apply(backend_, hand, t, t_next);
    }
    const StepReport report = backend_.step(1);
    forces.reset();
    if (trajectory.uses_hand(0) || trajectory.uses_hand(1)) {
        backend_.request_forces();
        forces = backend_.latest_forces();
    }
    return report;
}

std::function<void(int, const StepReport&)> Stepper::scripted_on_step(const Trajectory& trajectory,
                                                                      std::chrono::steady_clock::time_point wall_start,
                                                                      std::function<void(int, const StepReport&)> extra) {
    return [this, &trajectory, wall_start, extra = std::move(extra)](int step, const StepReport& report) {
        // A stroke's blade lifted: the detailed mesh opens along it from the positions of that
        // step (before anything else sees the step: a screenshot shows it opened).
        open_incisions();
        if (extra) extra(step, report);
        // --real-time auto on a scripted run: the wall clock the run has taken against the simulated time.
        if (governor_) observe(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - wall_start).count(),
                               backend_.simulated_time_ms());
        // --igtl: the state after each step to the link, when a frame is due (never waits on the network).
        if (link_due())
            offer(step + 1, link_hands(trajectory, backend_.simulated_time_ms(), backend_.latest_forces()), SlicerLink::State::running);
    };
}

int Stepper::step_to_real_time(int max_steps, double max_wall_ms) {
    haptics::HapticRun& haptic = *settings_.haptic;
    // A simulation slower than real time is always due: the wall budget returns control (to end
    // the run on time, draw a frame) and the ticks are drained after every step.
    const double until = haptic.session().now_ms() + max_wall_ms;
    int n = 0;
    while (n < max_steps && !haptic.result().gave_up && haptic.ms_until_next_step() <= 0.0) {
        haptic.step();
        ++n;
        haptic.drain();
        observe(haptic.owed_ms(), haptic.simulated_ms());  // the real time owed (pauses excluded) against the simulated time
        if (haptic.session().now_ms() >= until) break;
    }
    return n;
}

void Stepper::set_paused(bool paused) {
    if (paused == paused_) return;
    paused_ = paused;
    if (settings_.haptic) settings_.haptic->set_paused(paused);
    restart_measuring();  // a pause is no measure of speed
}

bool Stepper::open_incisions(const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    return settings_.open_incisions && settings_.open_incisions(positions, strokes);
}

void Stepper::open_or_preview_incisions(const std::vector<std::array<float, 3>>* positions, const StrokeLog* strokes) {
    if (!open_incisions(positions, strokes) && settings_.preview_incisions) settings_.preview_incisions(positions, strokes);
}

bool Stepper::link_due() const { return settings_.link && settings_.link->due(); }

void Stepper::offer(long long steps, const SlicerLinkHands& hands, SlicerLink::State state, const SlicerLink::PatchSource& patch) {
    if (!link_due()) return;
    settings_.link->offer(backend_, steps, hands, state, patch ? patch : settings_.link_patch);
}

void Stepper::offer(double time_ms, const std::vector<std::array<float, 3>>& positions, long long steps, const SlicerLinkHands& hands,
                    SlicerLink::State state, const SlicerLink::PatchSource& patch) {
    if (!link_due()) return;
    settings_.link->offer(time_ms, positions, steps, hands, state, patch ? patch : settings_.link_patch);
}

void Stepper::finish_link(long long steps, const SlicerLinkHands& hands) {
    if (settings_.link) settings_.link->finish(backend_, steps, hands, settings_.link_patch);
}

}  // namespace heartsim
