// libFuzzer target: the simulated haptic device file (runtime/haptics/haptic_run.h
// read_simulated_device: settings rows and the hand force CSV), then the device stepped for a few
// ticks as the device thread steps it.
#include "fuzz_support.h"

#include "runtime/haptics/haptic_run.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "simulated.csv");
    heartsim::fuzz::expect_refusal_or_success([&] {
        heartsim::haptics::SimulatedDevice device(heartsim::haptics::read_simulated_device(path));
        for (int tick = 0; tick < 4; ++tick) {
            device.read_pose(tick * 1.0);
            device.send_force(Eigen::Vector3d(0.1, 0.0, -0.1), tick * 1.0);
        }
    });
    return 0;
}
