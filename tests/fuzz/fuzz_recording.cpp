// libFuzzer target: the haptic session recording reader (formats/recording.h read_recording) and,
// as `heartsim run --device scripted:FILE.h5@HAND` does, the pose script taken from each hand
// (runtime/haptics/haptic_run.h recorded_pose_script); the input as an .h5 file.
#include "fuzz_support.h"

#include "formats/recording.h"
#include "runtime/haptics/haptic_run.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "input.h5");
    heartsim::fuzz::expect_refusal_or_success([&] {
        const heartsim::Recording recording = heartsim::read_recording(path);
        for (int hand = 0; hand < 2; ++hand)
            heartsim::fuzz::expect_refusal_or_success([&] {
                const auto keyframes = heartsim::haptics::recorded_pose_script(recording, hand, path.string());
                heartsim::haptics::ScriptedDevice device(keyframes);
                device.read_pose(keyframes.front().time_ms + 0.5);
            });
    });
    return 0;
}
