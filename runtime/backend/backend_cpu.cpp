// The CPU backend: libmodel's Solver behind the Backend interface, timed by the wall clock.
#include "runtime/backend/backend.h"
#include "runtime/backend/surgery.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <chrono>
#include <cmath>

namespace heartsim {

BackendKind parse_backend_kind(const std::string& name) {
    if (name == "cpu") return BackendKind::cpu;
    if (name == "gl") return BackendKind::gl;
    throw InputError("backend '" + name + "': expected cpu or gl");
}

const char* to_string(BackendKind kind) { return kind == BackendKind::cpu ? "cpu" : "gl"; }

std::string keep_up_advice(double factor, std::size_t particles, BackendKind kind, bool software_gl) {
    if (kind == BackendKind::gl && software_gl)
        return "--backend cpu (faster than OpenGL on a software rasteriser), or " + keep_up_advice(factor, particles, BackendKind::cpu);
    const std::string gpu = kind == BackendKind::cpu ? "the gl backend on a GPU" : "a faster GPU";
    if (!(factor > 0) || !std::isfinite(factor) || particles == 0) return "fewer particles (heartprep build --particles) or " + gpu;
    const double keeps_up = double(particles) * std::pow(factor / 1.1, 0.75);
    if (!(keeps_up >= 100)) return gpu + " (fewer particles than 100 would not keep up here either)";
    // Two significant digits, rounded down: 16,605 → 16,000; 1,604 → 1,600.
    const double unit = std::pow(10.0, std::floor(std::log10(keeps_up)) - 1);
    const long long count = (long long)(std::floor(keeps_up / unit) * unit);
    return "heartprep build --particles " + std::to_string(count) + " would keep up here, or " + gpu;
}

void check_particle_indices(const std::vector<std::int32_t>& particles, std::size_t particle_count) {
    for (std::size_t q = 0; q < particles.size(); ++q)
        if (particles[q] < 0 || std::size_t(particles[q]) >= particle_count)
            throw InputError("positions_of: entry " + std::to_string(q) + " names particle " + std::to_string(particles[q]) +
                             ", outside [0, " + std::to_string(particle_count) + ")");
}

void require_runnable(const Scenario& scenario, const std::string& file_name) {
    if (!scenario.packing)
        throw InputError(file_name + ": group /packing is missing; the runtime needs the packed neighbour table "
                                     "(run `heartprep pack` or `heartprep build`)");
}

namespace {

using Clock = std::chrono::steady_clock;

class CpuBackend final : public Backend, public SurgerySupport {
public:
    CpuBackend(const Scenario& scenario, const SolverOptions& options)
        : solver_(scenario.lattice, scenario.packing->neighbours, options) {
        solver_.set_contact_skin(scenario_contact_skin(scenario));
    }

    BackendKind kind() const override { return BackendKind::cpu; }
    std::size_t size() const override { return solver_.size(); }
    const SolverLoadReport& load_report() const override { return solver_.load_report(); }
    const SolverOptions& options() const override { return solver_.options(); }
    double time_step_ms() const override { return solver_.time_step_ms(); }
    double substep_ms() const override { return solver_.substep_ms(); }
    int substeps_per_step() const override { return solver_.substeps_per_step(); }
    double simulated_time_ms() const override { return solver_.simulated_time_ms(); }
    void set_instrument(int hand, const Instrument& instrument) override { solver_.set_instrument(hand, instrument); }
    void set_pose(int hand, const InstrumentPose& pose) override { solver_.set_pose(hand, pose); }
    std::size_t begin_grab(int hand) override { return solver_.begin_grab(hand); }
    void release(int hand) override { solver_.release(hand); }
    void reset_tissue() override { solver_.reset_tissue(); }
    void set_mass_scale(double mass_scale) override { solver_.set_mass_scale(mass_scale); }

    StepReport step(int steps) override {
        const auto start = Clock::now();
        StepReport report = solver_.step(steps);
        times_.step_ms += std::chrono::duration<double, std::milli>(Clock::now() - start).count();
        ++times_.step_calls;
        times_.substeps += report.substeps;
        return report;
    }
    StepReport step_after(const std::function<void()>& task) override {
        solver_.run_beside_next_step(task);
        return step(1);
    }
    void request_forces() override {
        const auto start = Clock::now();
        latest_ = solver_.instrument_forces();
        latest_request_ = requests_++;
        times_.force_ms += std::chrono::duration<double, std::milli>(Clock::now() - start).count();
        ++times_.force_calls;
    }
    std::optional<InstrumentForces> latest_forces() override { return latest_; }
    std::uint64_t latest_forces_request() const override { return latest_request_; }
    InstrumentForces instrument_forces() override { return solver_.instrument_forces(); }
    std::vector<std::array<float, 3>> positions() override { return solver_.positions(); }
    void set_loads(const std::vector<ParticleLoad>& loads) override { solver_.set_loads(loads); }
    std::vector<std::array<float, 3>> positions_of(const std::vector<std::int32_t>& particles) override {
        check_particle_indices(particles, solver_.size());
        std::vector<std::array<float, 3>> out(particles.size());
        for (std::size_t q = 0; q < particles.size(); ++q) {
            const Eigen::Vector3d x = solver_.position(std::size_t(particles[q]));
            out[q] = {float(x.x()), float(x.y()), float(x.z())};
        }
        return out;
    }
    const StrokeLog& strokes() const override { return solver_.strokes(); }
    std::vector<std::array<std::int32_t, 2>> cut_springs() override {
        std::vector<std::array<std::int32_t, 2>> list = solver_.cut_springs();
        std::sort(list.begin(), list.end());
        return list;
    }
    std::vector<std::int32_t> contact_particles(int hand) override {
        std::vector<std::int32_t> list = solver_.contact_particles(hand);
        std::sort(list.begin(), list.end());
        return list;
    }
    PassTimes pass_times() override { return times_; }
    SurgerySupport* surgery() override { return this; }
    std::size_t memory_bytes() const override {
        // Three float4 position buffers, rest, per-particle constants, five per-entry tables.
        const std::size_t n = (solver_.size() + 7) / 8 * 8;
        return n * (4 * 4 * 4 + 4 * 3) + n * 18 * 4 * 5;
    }

private:
    Solver solver_;
    PassTimes times_;
    std::optional<InstrumentForces> latest_;
    std::uint64_t requests_ = 0, latest_request_ = 0;
};

}  // namespace

std::unique_ptr<Backend> make_cpu_backend(const Scenario& scenario, const SolverOptions& options) {
    require_runnable(scenario, "scenario");
    return std::make_unique<CpuBackend>(scenario, options);
}

}  // namespace heartsim
