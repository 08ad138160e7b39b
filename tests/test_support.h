/// @file test_support.h
/// @brief Shared helpers for the tests: temporary folders, real-data paths, shape masks.
#pragma once

#include "libmodel/volume.h"

#include <filesystem>
#include <functional>
#include <string>

namespace heartsim::test {

/// A fresh empty folder under the system temp dir, removed when the object dies.
class TempDir {
public:
    TempDir();
    ~TempDir();
    const std::filesystem::path& path() const { return path_; }
    std::filesystem::path operator/(const std::string& name) const { return path_ / name; }
private:
    std::filesystem::path path_;
};

/// Folder holding the real HVSMR cases, or empty when absent.
std::filesystem::path real_data_dir();

/// The label-map file of real case `name` (e.g. "hvsmr16_pat1"), or empty when absent.
std::filesystem::path real_case(const std::string& name);

/// A mask on an isotropic grid of `n` voxels per side with `spacing` mm, centred on the world
/// origin (identity direction), selected where inside(x) is true at the voxel centre (world mm).
Mask make_mask(int n, double spacing, const std::function<bool(const Eigen::Vector3d&)>& inside);

/// Result of running a command: exit status and what it printed (stdout + stderr).
struct CommandResult {
    int exit_code = -1;
    std::string output;
};

/// Runs `command` through the shell, capturing stdout and stderr together.
CommandResult run_command(const std::string& command);

}  // namespace heartsim::test
