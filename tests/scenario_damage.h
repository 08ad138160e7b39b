/// @file scenario_damage.h
/// @brief Damaging an HDF5 file (a scenario, a recording) on purpose through HDF5's C API, and
/// reading a scenario's refusal: the reader tests' helpers (programs that link HDF5,
/// tests/CMakeLists.txt).
#pragma once

#include "formats/scenario.h"
#include "libmodel/errors.h"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <filesystem>
#include <string>
#include <vector>

namespace heartsim::test {

/// Rewrites one dataset of an existing file in place.
template <class T>
void overwrite(const std::filesystem::path& file, const char* dataset, const std::vector<T>& values, hid_t type) {
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    const hid_t d = H5Dopen2(f, dataset, H5P_DEFAULT);
    ASSERT_GE(H5Dwrite(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), 0) << dataset;
    H5Dclose(d);
    H5Fclose(f);
}

/// Rewrites one attribute of group `group` in place. Through the group: HDF5 1.10's H5Awrite
/// fails on an attribute opened with H5Aopen_by_name in a 1.8-format file.
template <class T>
void overwrite_attribute(const std::filesystem::path& file, const char* group, const char* name, const std::vector<T>& values, hid_t type) {
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    const hid_t g = H5Gopen2(f, group, H5P_DEFAULT);
    const hid_t a = H5Aopen(g, name, H5P_DEFAULT);
    ASSERT_GE(a, 0) << group << " " << name;
    ASSERT_GE(H5Awrite(a, type, values.data()), 0) << group << " " << name;
    H5Aclose(a);
    H5Gclose(g);
    H5Fclose(f);
}

/// The reader's InputError message for `file`, or "" when it reads.
inline std::string refusal(const std::filesystem::path& file) {
    try {
        read_scenario(file);
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

}  // namespace heartsim::test
