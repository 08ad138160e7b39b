// libFuzzer target: the scripted-instrument trajectory CSV (runtime/core/trajectory.h read_trajectory),
// then the trajectory sampled as the run loop samples it (Trajectory::at), and its planned view
// (the `# view:` line) read back equal from the options it writes.
#include "fuzz_support.h"

#include "runtime/core/trajectory.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "trajectory.csv");
    heartsim::fuzz::expect_refusal_or_success([&] {
        const heartsim::Trajectory trajectory = heartsim::read_trajectory(path);
        if (trajectory.view && !(heartsim::parse_view_options(heartsim::view_options(*trajectory.view)) == *trajectory.view))
            heartsim::fuzz::broken("a planned view that does not read back as written: " + heartsim::view_options(*trajectory.view));
        const double first = trajectory.keyframes.front().time_ms, last = trajectory.keyframes.back().time_ms;
        for (int hand = 0; hand < 2; ++hand) {
            if (!trajectory.uses_hand(hand)) continue;
            for (double t : {first - 1.0, first, 0.5 * first + 0.5 * last, last, last + 1.0}) {
                const heartsim::InstrumentKeyframe k = trajectory.at(hand, t);
                if (!(k.semi_axes.minCoeff() > 0)) heartsim::fuzz::broken("a keyframe with a non-positive semi-axis");
            }
        }
    });
    return 0;
}
