// libFuzzer target: `heartprep batch`'s CSV manifest (tools/heartprep/manifest.h read_manifest),
// read as the batch reads it before building anything.
#include "fuzz_support.h"

#include "tools/heartprep/manifest.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "cases.csv");
    heartsim::fuzz::expect_refusal_or_success([&] {
        for (const auto& c : heartsim::cli::read_manifest(path, "--cavity 2"))
            if (c.id.empty() || c.input.empty()) heartsim::fuzz::broken("a case without an id or an input");
    });
    return 0;
}
