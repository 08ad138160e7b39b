// libFuzzer target: a label table that names the segments of a label map (formats/label_table.h
// read_label_table, what `heartprep build --labels FILE` reads), then its names looked up as
// --tissue NAME looks them up.
#include "fuzz_support.h"

#include "formats/label_table.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "labels.txt");
    heartsim::fuzz::expect_refusal_or_success([&] {
        const auto names = heartsim::read_label_table(path);
        if (names.empty()) heartsim::fuzz::broken("a label table with no entries was accepted");
        for (const auto& [label, name] : names)
            if (name.empty() || name.find('\n') != std::string::npos) heartsim::fuzz::broken("an empty or multi-line segment name");
    });
    return 0;
}
