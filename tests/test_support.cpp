#include "test_support.h"

#include "libmodel/select.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <sys/wait.h>

namespace heartsim::test {

TempDir::TempDir() {
    std::random_device device;
    auto base = std::filesystem::temp_directory_path();
    for (;;) {
        path_ = base / ("heartsim-test-" + std::to_string(device()));
        if (std::filesystem::create_directory(path_)) break;
    }
}

TempDir::~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
}

std::filesystem::path real_data_dir() {
    std::filesystem::path dir = HEARTSIM_REAL_DATA;
    return std::filesystem::is_directory(dir) ? dir : std::filesystem::path();
}

std::vector<RealCase> real_cases() {
    namespace fs = std::filesystem;
    std::vector<RealCase> cases;
    const fs::path data = real_data_dir();
    if (data.empty() || !fs::is_directory(data)) return cases;
    for (const auto& folder : fs::directory_iterator(data)) {
        if (!folder.is_directory()) continue;
        for (const auto& file : fs::directory_iterator(folder.path()))
            if (file.path().filename().string().find("label.nii.gz") != std::string::npos) {
                const std::string name = folder.path().filename().string();
                cases.push_back({name, file.path(),
                                 name == "mmwhs_ct1002" ? " --labels mmwhs" : name == "mmwhs_wh" ? " --labels mmwhs-ordinal" : ""});
                break;
            }
    }
    std::sort(cases.begin(), cases.end(), [](const RealCase& a, const RealCase& b) { return a.name < b.name; });
    return cases;
}

std::string vsd_options(const RealCase& c) {
    static const std::map<std::string, std::string> septum_points = {{"hvsmr16_pat0", "40.7,-14.4,-10.4"},
                                                                     {"hvsmr16_pat1", "11.4,-25.6,5.2"},
                                                                     {"hvsmr16_pat5", "26.8,-17.3,-4.9"},
                                                                     {"hvsmr16_pat6", "26.9,-12.1,-20.0"}};
    if (!c.label_options.empty()) return " --defect vsd";
    const auto point = septum_points.find(c.name);
    return point == septum_points.end() ? "" : " --defect vsd --at=" + point->second;
}

std::filesystem::path real_case(const std::string& name) {
    auto dir = real_data_dir();
    if (dir.empty()) return {};
    auto file = dir / name / ("training_axial_crop_" + name.substr(name.rfind('_') + 1) + "-label.nii.gz");
    return std::filesystem::exists(file) ? file : std::filesystem::path();
}

Lattice block_lattice(int nx, int ny, int nz, double spacing, double damping_ratio) {
    Material material;
    material.damping_ratio = damping_ratio;
    return uniform_block({nx, ny, nz}, spacing, material);
}

Mask make_mask(int n, double spacing, const std::function<bool(const Eigen::Vector3d&)>& inside) {
    Mask mask;
    mask.geometry.dims = {n, n, n};
    mask.geometry.spacing = Eigen::Vector3d::Constant(spacing);
    mask.geometry.origin = Eigen::Vector3d::Constant(-0.5 * (n - 1) * spacing);
    mask.values.assign(mask.geometry.voxel_count(), 0);
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i)
                mask.values[mask.geometry.linear(i, j, k)] =
                    inside(mask.geometry.to_world(Eigen::Vector3d(i, j, k))) ? 1 : 0;
    return mask;
}

void write_bytes(const std::filesystem::path& path, const std::vector<unsigned char>& bytes) {
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

CommandResult run_command(const std::string& command) {
    CommandResult result;
    FILE* pipe = popen((command + " 2>&1").c_str(), "r");
    if (!pipe) return result;
    std::array<char, 4096> buffer;
    size_t n;
    while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0) result.output.append(buffer.data(), n);
    int status = pclose(pipe);
    result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return result;
}

void expect_clean_out_of_memory(const std::string& command, const std::string& out_of_memory_prefix,
                                const std::function<void()>& before_each) {
    std::vector<LimitedRun> runs;
    for (std::size_t limit = 32; limit <= 4096; limit += 8) {
        if (before_each) before_each();
        // stderr to the pipe, stdout away: the error must be one line of its own.
        const CommandResult result =
            run_command("(ulimit -v " + std::to_string(limit * 1024) + "; timeout 120 " + command + " 2>&1 >/dev/null)");
        runs.push_back({limit, result});
        if (result.exit_code == 0) break;
    }
    std::string log;
    for (const auto& run : runs)
        log += std::to_string(run.limit_mib) + " MiB: exit " + std::to_string(run.result.exit_code) + ": " + run.result.output;
    ASSERT_EQ(runs.back().result.exit_code, 0) << "never succeeded up to 4 GiB:\n" << log;
    std::size_t out_of_memory = 0;
    for (const auto& run : runs) {
        // Warnings ("PROGRAM: warning: …", e.g. a session slower than real time) may come first;
        // the error itself is one line of its own.
        std::string output;
        std::istringstream lines(run.result.output);
        for (std::string line; std::getline(lines, line);)
            if (line.rfind("heartsim: warning: ", 0) != 0 && line.rfind("heartprep: warning: ", 0) != 0) output += line + "\n";
        if (run.result.exit_code == 0) continue;
        if (run.result.exit_code == 127 && output.find("error while loading shared libraries") != std::string::npos) continue;
        const bool one_line = !output.empty() && output.find('\n') == output.size() - 1;
        const bool clean = run.result.exit_code == 7 && one_line && output.rfind(out_of_memory_prefix, 0) == 0;
        EXPECT_TRUE(clean) << "under " << run.limit_mib << " MiB: exit " << run.result.exit_code << ", expected 7 and one line \""
                           << out_of_memory_prefix << "…\":\n" << output;
        out_of_memory += clean;
    }
    EXPECT_GT(out_of_memory, 0u) << "no limit made the program run out of memory in our code:\n" << log;
}

std::string quoted(const std::filesystem::path& path) { return "'" + path.string() + "'"; }

CommandResult heartprep(const std::string& arguments) { return run_command(quoted(HEARTPREP_EXE) + " " + arguments); }

std::string in_xvfb_window() {
    return "ASAN_OPTIONS=\"${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0\" timeout 600 xvfb-run -a -s '-screen 0 640x480x24' ";
}

const std::filesystem::path& built_phantom(const std::string& build_options) {
    static TempDir dir;
    static std::map<std::string, std::filesystem::path> built;
    auto& path = built[build_options];
    if (path.empty()) {
        const auto output = dir / ("phantom-" + std::to_string(built.size()) + ".h5");
        const auto run = heartprep("build " + quoted(std::filesystem::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz") + " -o " +
                                   quoted(output) + " " + build_options + " -q");
        if (run.exit_code != 0) throw std::runtime_error("heartprep build failed: " + run.output);
        path = output;
    }
    return path;
}

const std::filesystem::path& built_vsd_phantom() {
    static TempDir dir;
    static std::filesystem::path built;
    if (built.empty()) {
        const auto labels = dir / "phantom.nii.gz", scenario = dir / "vsd.h5";
        const auto phantom = heartprep("phantom -o " + quoted(labels) + " --vsd-diameter 0");
        if (phantom.exit_code != 0) throw std::runtime_error("heartprep phantom failed: " + phantom.output);
        const auto build = heartprep("build " + quoted(labels) + " --defect vsd --at=-21.1,-1.1,-1.5 --diameter 8 --particles 8000 -q -o " +
                                     quoted(scenario));
        if (build.exit_code != 0) throw std::runtime_error("heartprep build failed: " + build.output);
        built = scenario;
    }
    return built;
}

}  // namespace heartsim::test
