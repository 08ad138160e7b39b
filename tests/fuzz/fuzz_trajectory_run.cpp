// libFuzzer target: a trajectory (runtime/core/trajectory.h read_trajectory) driving the cpu backend
// on a small block of tissue, as `heartsim run --trajectory` drives a scenario: the run loop's
// own ScriptedHands sets instruments, grabs, lowers and lifts scalpels and moves them, step by
// step, over the whole of the script (its first to its last keyframe in `steps` steps, so a script
// of any time scale is played through). After every step every position and both instruments'
// forces must be finite, and the cut list must hold springs of the block only, each once, lower
// index first; reset_tissue() must heal every cut.
#include "fuzz_support.h"

#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/select.h"
#include "libmodel/stability.h"
#include "runtime/backend/backend.h"
#include "runtime/core/trajectory.h"

#include <cmath>
#include <set>

namespace {

using namespace heartsim;

/// A 4×4×4 block of 1.5 mm voxels, one particle each, centred on the world origin, its bottom
/// layer (lattice z = 0) anchored; packed as heartprep packs a scenario.
struct Block {
    Scenario scenario;
    SolverOptions options;
    std::set<std::array<std::int32_t, 2>> springs;
};

const Block& block() {
    static const Block made = [] {
        Block b;
        LabelVolume volume;
        volume.geometry.dims = {4, 4, 4};
        volume.geometry.spacing = Eigen::Vector3d::Constant(1.5);
        volume.labels.assign(volume.geometry.voxel_count(), 1);
        const Selection selection = select_tissue(volume, {.min_island_mm3 = 0});
        b.scenario.lattice = layout_particles(selection, {1}, volume, {.spacing_mm = 1.5, .occupancy = 0.5});
        Particles& p = b.scenario.lattice.particles;
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        for (const auto& r : p.rest_position) centre += Eigen::Vector3d(r[0], r[1], r[2]) / double(p.size());
        for (auto& r : p.rest_position)
            for (int c = 0; c < 3; ++c) r[std::size_t(c)] -= float(centre[c]);
        for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][2] == 0 ? 1 : 0;
        b.scenario.packing = pack_particles(b.scenario.lattice);
        b.options.critical_dt_ms = estimate_critical_time_step(p, b.scenario.lattice.springs, 5000, 1e-12).critical_dt_ms;
        for (const auto& [i, j] : b.scenario.lattice.springs.pairs) b.springs.insert({std::min(i, j), std::max(i, j)});
        return b;
    }();
    return made;
}

void check(Backend& backend, const Block& b) {
    for (const auto& x : backend.positions())
        if (!std::isfinite(x[0]) || !std::isfinite(x[1]) || !std::isfinite(x[2])) fuzz::broken("a position is not finite");
    const InstrumentForces forces = backend.instrument_forces();
    for (const auto& hand : forces.hand)
        if (!hand.force_n.allFinite()) fuzz::broken("an instrument force is not finite");
    const auto cut = backend.cut_springs();
    if (cut.size() > b.springs.size()) fuzz::broken("more springs cut than the block has");
    for (std::size_t k = 0; k < cut.size(); ++k) {
        if (!b.springs.count(cut[k])) fuzz::broken("a cut spring that is not a spring of the block");
        if (k > 0 && !(cut[k - 1] < cut[k])) fuzz::broken("the cut list is not sorted, or lists a spring twice");
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = fuzz::write_input(data, size, "trajectory.csv");
    const Block& b = block();
    fuzz::expect_refusal_or_success([&] {
        const Trajectory trajectory = read_trajectory(path);
        const auto backend = make_cpu_backend(b.scenario, b.options);
        ScriptedHands hands(trajectory);
        const double first = trajectory.keyframes.front().time_ms, last = trajectory.keyframes.back().time_ms;
        const int steps = 40;
        // Step k covers [t_k, t_k+1]: the script from its first keyframe to its last (or one step
        // of the backend per step for a script of one instant).
        auto time_at = [&](int k) {
            const double f = double(k) / steps;
            return last > first ? first * (1 - f) + last * f : first + k * backend->time_step_ms();
        };
        for (int k = 0; k < steps; ++k) {
            for (int hand = 0; hand < 2; ++hand) hands.apply(*backend, hand, time_at(k), time_at(k + 1));
            const StepReport report = backend->step(1);
            check(*backend, b);
            if (report.gave_up) break;
        }
        backend->reset_tissue();
        if (!backend->cut_springs().empty()) fuzz::broken("reset_tissue left springs cut");
        check(*backend, b);
    });
    return 0;
}
