// libFuzzer target: the scripted haptic device's pose CSV (runtime/haptics/devices.h
// read_pose_script), then the device sampled as the device thread samples it.
#include "fuzz_support.h"

#include "runtime/haptics/devices.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "poses.csv");
    heartsim::fuzz::expect_refusal_or_success([&] {
        auto keyframes = heartsim::haptics::read_pose_script(path);
        const double first = keyframes.front().time_ms, last = keyframes.back().time_ms;
        heartsim::haptics::ScriptedDevice device(std::move(keyframes));
        for (double t : {first - 1.0, first, 0.5 * first + 0.5 * last, last, last + 1.0}) device.read_pose(t);
    });
    return 0;
}
