/// @file defect_block_scenario.h
/// @brief The two-chamber block of defect_block.h built into a scenario by heartprep, with an
/// 8 mm septal defect where the repair tests carve it (local (0.5, −4, 6) mm: in the septum, off
/// its middle), for the repair's tests (test_repair.cpp, test_repair_plan.cpp,
/// test_runtime_render.cpp).
#pragma once

#include "defect_block.h"
#include "formats/volume_io.h"
#include "test_support.h"

#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>

namespace heartsim::test::defect_block {

/// Where the repair tests carve their defect, in world coordinates.
inline Eigen::Vector3d repair_site(const Block& block) { return block.world({0.5, -4.0, 6.0}); }

/// Writes `block` to `input` (a label map, once) and builds `output` from it with heartprep at
/// `particles` particles: with an 8 mm `defect` ("vsd" or "asd") at repair_site, or intact for
/// "". Throws with heartprep's output when it fails.
inline void build_block_scenario(const Block& block, const std::filesystem::path& input, const std::filesystem::path& output,
                                 const std::string& defect, int particles) {
    if (!std::filesystem::exists(input)) write_label_volume(input, block.volume);
    std::string options;
    if (!defect.empty()) {
        const Eigen::Vector3d at = repair_site(block);
        char point[96];
        std::snprintf(point, sizeof point, "%.4f,%.4f,%.4f", at.x(), at.y(), at.z());
        options = " --defect " + defect + " --diameter 8 --at=" + point;
    }
    const auto built = heartprep("build " + quoted(input) + options + " --particles " + std::to_string(particles) + " -q -o " + quoted(output));
    if (built.exit_code != 0) throw std::runtime_error("heartprep build failed: " + built.output);
}

}  // namespace heartsim::test::defect_block
