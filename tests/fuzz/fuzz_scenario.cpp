// libFuzzer target: the scenario reader (formats/scenario.h read_scenario), the input as an .h5 file.
#include "fuzz_support.h"

#include "formats/scenario.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "input.h5");
    heartsim::fuzz::expect_refusal_or_success([&] {
        const heartsim::Scenario s = heartsim::read_scenario(path);
        // What read_scenario promises the runtime: every index it returns is in range.
        const std::size_t n = s.lattice.particles.size();
        if (n == 0 || s.lattice.particles.mass.size() != n || s.lattice.particles.material.size() != n)
            heartsim::fuzz::broken("read_scenario returned particles of different lengths");
        for (const auto& [a, b] : s.lattice.springs.pairs)
            if (a < 0 || b < 0 || std::size_t(a) >= n || std::size_t(b) >= n) heartsim::fuzz::broken("spring index out of range");
    });
    return 0;
}
