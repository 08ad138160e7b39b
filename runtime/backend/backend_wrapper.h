/// @file backend_wrapper.h
/// @brief A Backend that owns another and passes every call to it: a wrapper that adds to the
/// tissue's hands (runtime/surgery/repair.h) overrides the calls it changes and inherits the rest.
#pragma once

#include "runtime/backend/backend.h"

#include <memory>
#include <utility>

namespace heartsim {

class BackendWrapper : public Backend {
public:
    explicit BackendWrapper(std::unique_ptr<Backend> inner) : inner_(std::move(inner)) {}

    BackendKind kind() const override { return inner_->kind(); }
    std::size_t size() const override { return inner_->size(); }
    const SolverLoadReport& load_report() const override { return inner_->load_report(); }
    const SolverOptions& options() const override { return inner_->options(); }
    double time_step_ms() const override { return inner_->time_step_ms(); }
    double substep_ms() const override { return inner_->substep_ms(); }
    int substeps_per_step() const override { return inner_->substeps_per_step(); }
    double simulated_time_ms() const override { return inner_->simulated_time_ms(); }
    void set_instrument(int hand, const Instrument& instrument) override { inner_->set_instrument(hand, instrument); }
    void set_pose(int hand, const InstrumentPose& pose) override { inner_->set_pose(hand, pose); }
    std::size_t begin_grab(int hand) override { return inner_->begin_grab(hand); }
    void release(int hand) override { inner_->release(hand); }
    void reset_tissue() override { inner_->reset_tissue(); }
    void set_mass_scale(double mass_scale) override { inner_->set_mass_scale(mass_scale); }
    StepReport step(int steps = 1) override { return inner_->step(steps); }
    void request_forces() override { inner_->request_forces(); }
    std::optional<InstrumentForces> latest_forces() override { return inner_->latest_forces(); }
    std::uint64_t latest_forces_request() const override { return inner_->latest_forces_request(); }
    InstrumentForces instrument_forces() override { return inner_->instrument_forces(); }
    std::vector<std::array<std::int32_t, 2>> cut_springs() override { return inner_->cut_springs(); }
    const StrokeLog& strokes() const override { return inner_->strokes(); }
    std::vector<std::array<float, 3>> positions() override { return inner_->positions(); }
    PassTimes pass_times() override { return inner_->pass_times(); }
    std::size_t memory_bytes() const override { return inner_->memory_bytes(); }
    bool software_device() const override { return inner_->software_device(); }
    void set_contact(const ContactSettings& settings) override { inner_->set_contact(settings); }
    std::vector<std::int32_t> contact_particles(int hand) override { return inner_->contact_particles(hand); }
    const Backend& simulating() const override { return inner_->simulating(); }
    SurgerySupport* surgery() override { return inner_->surgery(); }

protected:
    Backend& inner() { return *inner_; }
    const Backend& inner() const { return *inner_; }

private:
    std::unique_ptr<Backend> inner_;
};

}  // namespace heartsim
