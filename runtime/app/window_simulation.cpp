// The window's simulation thread: docs/runtime.md "The window".
#include "runtime/app/window_simulation.h"

#include <algorithm>
#include <chrono>

namespace heartsim {

using Clock = std::chrono::steady_clock;

WindowSimulation::WindowSimulation(Stepper& stepper, const Trajectory& trajectory, const WindowSimulationOptions& options)
    : stepper_(stepper), backend_(stepper.backend()), repair_(repair_of(backend_)), hands_(std::in_place, trajectory),
      trajectory_(&trajectory), options_(options), start_mass_scale_(backend_.options().mass_scale) {
    thread_ = std::thread([this] { run(); });
}

WindowSimulation::WindowSimulation(Stepper& stepper, const WindowSimulationOptions& options)
    : stepper_(stepper), backend_(stepper.backend()), repair_(repair_of(backend_)), haptic_(stepper.haptic()),
      options_(options), start_mass_scale_(backend_.options().mass_scale) {
    status_.shapes = haptic_->shapes();
    thread_ = std::thread([this] { run_haptic(); });
}

bool WindowSimulation::finish_at_limit() {
    const bool at_end = options_.end_ms > 0 && backend_.options().mass_scale != start_mass_scale_ &&
                        status_.simulated_ms >= options_.end_ms * (1 - 1e-12);
    if (!status_.run.gave_up && !at_end && (options_.steps < 0 || status_.attempted < options_.steps)) return false;
    status_.finished = true;
    positions_ = backend_.positions();  // the final state, for the last frame
    copy_strokes();
    fresh_ = true;
    published_.notify_all();
    return true;
}

void WindowSimulation::copy_strokes() {
    const StrokeLog& log = backend_.strokes();
    if (log.version() != strokes_.version() || log.clears() != strokes_.clears()) strokes_ = log;
    const PatchModel* patch = repair_ ? repair_->patch() : nullptr;
    if (patch) patch_ = drawn_patch(*patch, repair_->stitch_anchors());
    else if (!patch_.triangles.empty()) patch_ = {};
}

StrokeLog WindowSimulation::strokes() const {
    std::lock_guard lock(mutex_);
    return published_strokes_;
}

DrawnPatch WindowSimulation::patch() const {
    std::lock_guard lock(mutex_);
    return published_patch_;
}

void WindowSimulation::publish_start() {
    {
        std::lock_guard lock(mutex_);
        positions_ = backend_.positions();  // something to draw before the first step
        copy_strokes();
        fresh_ = true;
    }
    published_.notify_all();
}

void WindowSimulation::publish_if_wanted() {
    if (!want_positions_) return;
    positions_ = backend_.positions();
    copy_strokes();
    fresh_ = true, want_positions_ = false;
    published_.notify_all();
}

WindowSimulation::~WindowSimulation() {
    {
        std::lock_guard lock(mutex_);
        stop_ = true;
    }
    published_.notify_all();
    if (thread_.joinable()) thread_.join();
}

void WindowSimulation::set_keyboard_pose(const InstrumentPose& pose) {
    std::lock_guard lock(mutex_);
    keyboard_pose_ = pose;
    keyboard_set_ = true;
}

void WindowSimulation::set_paused(bool paused) {
    std::lock_guard lock(mutex_);
    paused_ = paused;
}

void WindowSimulation::request_reset_tissue() {
    std::lock_guard lock(mutex_);
    reset_ = true;
}

void WindowSimulation::run_between_steps(std::function<void()> action) {
    {
        std::lock_guard lock(mutex_);
        actions_.push_back(std::move(action));
    }
    published_.notify_all();
}

void WindowSimulation::request_single_step() {
    {
        std::lock_guard lock(mutex_);
        if (haptic_) return;
        ++single_steps_;
    }
    published_.notify_all();
}

bool WindowSimulation::latest(std::vector<std::array<float, 3>>& positions) {
    std::unique_lock lock(mutex_);
    if (!status_.finished && !stop_ && !paused_) {
        want_positions_ = true;
        published_.wait(lock, [&] { return fresh_ || status_.finished || stop_ || paused_; });
    }
    if (!fresh_ && positions_.empty()) return false;
    positions = positions_;
    published_strokes_ = strokes_;
    published_patch_ = patch_;
    fresh_ = false;
    return true;
}

WindowSimulation::Status WindowSimulation::status() const {
    std::lock_guard lock(mutex_);
    return status_;
}

void WindowSimulation::run() {
    StepClock step_clock(backend_.time_step_ms());
    const double start_ms = backend_.simulated_time_ms();
    OwedClock clock;
    bool was_paused = false;
    publish_start();
    for (;;) {
        InstrumentPose keyboard;
        bool keyboard_set = false, reset = false, paused = false, step_once = false;
        {
            std::unique_lock lock(mutex_);
            if (stop_) break;
            keyboard = keyboard_pose_, keyboard_set = keyboard_set_, reset = reset_, paused = paused_;
            reset_ = false;
            step_once = paused && single_steps_ > 0;
            if (step_once) --single_steps_;
            if (!paused) single_steps_ = 0;
        }
        if (reset) {
            backend_.reset_tissue();
            std::lock_guard lock(mutex_);
            ++status_.resets;
        }
        const double owed_ms = clock.owed_ms(paused, Clock::now());
        const double simulated_ms = backend_.simulated_time_ms() - start_ms;
        const double dt = backend_.time_step_ms();  // changes with the mass scale
        if (paused != was_paused) stepper_.restart_measuring();  // a pause is no measure of speed
        was_paused = paused;
        if ((paused && !step_once) || (!paused && simulated_ms + dt > owed_ms)) {
            // Ahead of the wall clock (or paused): wait for the next step's time, or for a request.
            std::unique_lock lock(mutex_);
            status_.owed_ms = owed_ms;
            status_.paused = paused;
            publish_if_wanted();
            const double wait_ms = paused ? 5.0 : std::min(5.0, simulated_ms + dt - owed_ms);
            published_.wait_for(lock, std::chrono::duration<double, std::milli>(wait_ms),
                                [&] { return stop_ || want_positions_ || reset_ || single_steps_ > 0 || paused_ != paused; });
            continue;
        }
        // One step, the hands posed as run_scripted poses them.
        std::optional<InstrumentForces> forces;
        const StepReport report = stepper_.step_scripted(*hands_, *trajectory_, step_clock, status_.attempted, options_.keyboard_hand0,
                                                         keyboard_set ? std::optional(keyboard) : std::nullopt, forces);
        if (!paused) stepper_.observe(owed_ms, backend_.simulated_time_ms() - start_ms);
        const bool received = forces.has_value();
        std::lock_guard lock(mutex_);
        if (forces) {
            status_.has_forces = true;
            for (int hand = 0; hand < 2; ++hand) status_.forces[hand] = forces->hand[hand].force_n;
        }
        status_.paused = paused;
        ++status_.attempted;
        status_.run.add(report);
        status_.simulated_ms = backend_.simulated_time_ms() - start_ms;
        status_.owed_ms = owed_ms;
        status_.mass_scale = backend_.options().mass_scale;
        status_.run.forces_received += received;
        if (options_.keyboard_hand0 && keyboard_set) status_.keyboard_position_mm = keyboard.position;
        publish_if_wanted();
        if (finish_at_limit()) break;
    }
}

void WindowSimulation::run_haptic() {
    // The session's own clock paces the steps (Stepper::step_to_real_time); pauses stop it.
    const double start_ms = backend_.simulated_time_ms();
    OwedClock clock;
    publish_start();
    for (;;) {
        bool reset = false, paused = false;
        std::vector<std::function<void()>> actions;
        {
            std::lock_guard lock(mutex_);
            if (stop_) break;
            reset = reset_, paused = paused_;
            reset_ = false;
            actions.swap(actions_);
        }
        for (auto& action : actions) action();
        stepper_.set_paused(paused);  // no-op unless it changed
        const double owed_ms = clock.owed_ms(paused, Clock::now());
        if (reset) {
            backend_.reset_tissue();
            std::lock_guard lock(mutex_);
            ++status_.resets;
        }
        int stepped = 0;
        if (paused) {
            haptic_->drain();
        } else {
            const long long left = options_.steps >= 0 ? options_.steps - (long long)haptic_->rows() : 100000;
            stepped = stepper_.step_to_real_time(int(std::clamp(left, 0LL, 100000LL)), 2.0);
        }
        std::unique_lock lock(mutex_);
        status_.paused = paused;
        status_.haptic_period_p99_ms = haptic_->session().live_period_p99_ms();
        status_.has_forces = true;
        for (int hand = 0; hand < 2; ++hand) status_.forces[hand] = haptic_->latest_published_forces().hand[hand].force_n;
        status_.attempted = (long long)haptic_->rows();
        status_.run = haptic_->result();
        status_.simulated_ms = backend_.simulated_time_ms() - start_ms;
        status_.owed_ms = owed_ms;
        status_.mass_scale = backend_.options().mass_scale;
        status_.shapes = haptic_->shapes();
        publish_if_wanted();
        if (finish_at_limit()) break;
        if (stepped == 0) {
            const double wait_ms = paused ? 5.0 : std::clamp(haptic_->ms_until_next_step(), 0.05, 1.0);
            published_.wait_for(lock, std::chrono::duration<double, std::milli>(wait_ms),
                                [&] { return stop_ || want_positions_ || reset_ || !actions_.empty() || paused_ != paused; });
        }
    }
}

}  // namespace heartsim
