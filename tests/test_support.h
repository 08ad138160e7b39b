/// @file test_support.h
/// @brief Shared helpers for the tests: temporary folders, real-data paths, shape masks.
#pragma once

#include "libmodel/lattice.h"
#include "libmodel/volume.h"

#include <array>
#include <cstring>
#include <filesystem>
#include <vector>
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

/// A real case: its folder's name, its label map, and the heartprep options its labels need
/// (" --labels mmwhs" for MM-WHS CT 1002, " --labels mmwhs-ordinal" for the MM-WHS whole-heart
/// MR; empty for the HVSMR cases, whose myocardium is label 1).
struct RealCase {
    std::string name;
    std::filesystem::path label_map;
    std::string label_options;
};
/// Every real case in real_data_dir() with a *label.nii.gz, by name; none when the data are absent.
std::vector<RealCase> real_cases();
/// heartprep build's options for a 10 mm ventricular septal defect in real case `c` (" --defect
/// vsd", with " --at=X,Y,Z" a point of the septum for the HVSMR cases, whose one blood pool does
/// not tell the ventricles apart: the points of scripts/real-cases.sh); empty for an HVSMR case
/// with no point known.
std::string vsd_options(const RealCase& c);

/// A mask on an isotropic grid of `n` voxels per side with `spacing` mm, centred on the world
/// origin (identity direction), selected where inside(x) is true at the voxel centre (world mm).
Mask make_mask(int n, double spacing, const std::function<bool(const Eigen::Vector3d&)>& inside);

/// An nx × ny × nz block of tissue voxels of `spacing` mm laid out at the same spacing (one
/// particle per voxel, in lattice order, not packed), its material's springs damped at
/// `damping_ratio`.
Lattice block_lattice(int nx, int ny, int nz, double spacing = 1.5, double damping_ratio = Material{}.damping_ratio);

/// Result of running a command: exit status and what it printed (stdout + stderr).
struct CommandResult {
    int exit_code = -1;
    std::string output;
};

/// Runs `command` through the shell, capturing stdout and stderr together.
CommandResult run_command(const std::string& command);

/// True in a build with AddressSanitizer. It reserves terabytes of address space for its shadow
/// memory, so an address-space limit (ulimit -v) stops any program at its start: the tests that
/// inject an out-of-memory that way skip.
#if defined(__SANITIZE_ADDRESS__)
inline constexpr bool under_address_sanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
inline constexpr bool under_address_sanitizer = true;
#else
inline constexpr bool under_address_sanitizer = false;
#endif
#else
inline constexpr bool under_address_sanitizer = false;
#endif

/// One run of a command under an address-space limit: stderr only (stdout is discarded).
struct LimitedRun {
    std::size_t limit_mib = 0;
    CommandResult result;
};

/// Out of memory, injected: runs `command` (a shell command line) under address-space limits
/// (ulimit -v) rising from 32 MiB in 8 MiB steps, each with a 120 s timeout, until a run exits 0
/// or the limit passes 4 GiB; returns every run. Then checks them: each run either could not
/// start (the dynamic loader's "error while loading shared libraries", before any of our code),
/// or exited 7 (docs/user-guide.md, "Exit status") with exactly one line on stderr that begins with `out_of_memory_prefix` (e.g.
/// "heartsim: error: out of memory while "), or was the last and succeeded; and at least one ran out of
/// memory in our code. Failures are reported through GoogleTest with each run's output.
/// `before_each`, when given, runs (in the test, unlimited) before every attempt: e.g. removing
/// what a run that failed on purpose keeps for the user (a --record journal).
void expect_clean_out_of_memory(const std::string& command, const std::string& out_of_memory_prefix,
                                const std::function<void()>& before_each = {});

/// `path` in single quotes, for a shell command line.
std::string quoted(const std::filesystem::path& path);

/// Runs the heartprep binary of this build with `arguments` (already quoted where needed).
CommandResult heartprep(const std::string& arguments);

/// The shipped phantom (samples/phantom.nii.gz) built by heartprep with `build_options` (e.g.
/// "--cavity 2 --anchor-border"), once per test program and set of options, into a folder that
/// lives as long as the program. Throws with heartprep's output when the build fails.
const std::filesystem::path& built_phantom(const std::string& build_options);
/// The phantom's two ventricles (heartprep phantom --vsd-diameter 0) built with an 8 mm VSD carved
/// through its septum at (-21.1, -1.1, -1.5) mm, 8,000 particles and the detailed mesh: the
/// operation's and the repair's small heart. Built once per test program; throws where it fails.
const std::filesystem::path& built_vsd_phantom();

/// The start of a shell command that runs a program in a window under Xvfb (640×480), with a
/// 10-minute limit. Under AddressSanitizer leak detection is off for that program only: Mesa's
/// driver leaves 112 bytes at exit when it has rasterised, in a module it has already unloaded,
/// which LeakSanitizer cannot attribute or suppress (tests/CMakeLists.txt does the same for the
/// picking and render test programs); heartsim's headless runs in the other tests keep it.
std::string in_xvfb_window();

/// Writes `bytes` to `path` (replacing it).
void write_bytes(const std::filesystem::path& path, const std::vector<unsigned char>& bytes);

/// A NIfTI-1 single-file image written byte by byte from the standard's field offsets (nifti1.h).
struct HandNifti {
    std::vector<unsigned char> bytes = std::vector<unsigned char>(352, 0);

    template <class T>
    void put(std::size_t offset, T value) { std::memcpy(&bytes[offset], &value, sizeof(T)); }

    HandNifti(std::array<short, 3> dims, short datatype, short bitpix) {
        put<int>(0, 348);                        // sizeof_hdr
        put<short>(40, 3);                       // dim[0]
        for (int d = 0; d < 3; ++d) put<short>(42 + 2 * d, dims[d]);
        for (int d = 3; d < 7; ++d) put<short>(42 + 2 * d, 1);
        put<short>(70, datatype);
        put<short>(72, bitpix);
        put<float>(76, 1.0f);                    // pixdim[0] = qfac
        for (int d = 0; d < 3; ++d) put<float>(80 + 4 * d, 1.0f);
        put<float>(108, 352.0f);                 // vox_offset
        put<float>(112, 1.0f);                   // scl_slope
        bytes[123] = 2;                          // xyzt_units: mm
        std::memcpy(&bytes[344], "n+1\0", 4);
    }
    void set_pixdim(int axis, float value) { put<float>(80 + 4 * axis, value); }
    /// sform_code 1 with rows srow_x, srow_y, srow_z (RAS mm); qform_code 0.
    void set_sform(const Eigen::Matrix<float, 3, 4>& rows) {
        put<short>(252, 0);
        put<short>(254, 1);
        for (int row = 0; row < 3; ++row)
            for (int column = 0; column < 4; ++column) put<float>(280 + 16 * row + 4 * column, rows(row, column));
    }
    /// qform_code `code`: the rotation of quaternion (a, b, c, d) with a = √(1 − b² − c² − d²) ≥ 0,
    /// qfac pixdim[0], offsets qoffset_x, y, z (RAS mm). Leaves the sform as it is.
    void set_qform(short code, const Eigen::Vector3f& bcd, const Eigen::Vector3f& offset, float qfac = 1.0f) {
        put<short>(252, code);
        put<float>(76, qfac);
        for (int i = 0; i < 3; ++i) {
            put<float>(256 + 4 * i, bcd[i]);
            put<float>(268 + 4 * i, offset[i]);
        }
    }
    void set_sform_code(short code) { put<short>(254, code); }
    template <class T>
    void append_voxels(const std::vector<T>& values) {
        const auto* raw = reinterpret_cast<const unsigned char*>(values.data());
        bytes.insert(bytes.end(), raw, raw + values.size() * sizeof(T));
    }
};

}  // namespace heartsim::test
