// Promises the docs make about inputs and outputs (docs/reliability.md), each checked where a
// user's run broke it: a detached label map's data file in the batch key and source_sha256, the
// .xmf2 written with its .h5 or not at all, the step policy's cross-field rules, the mapping's
// offsets and the structure a scenario promises, long output names, and the --steps 0 refusal.
// And the scalpel's promises where the cpu tests (test_cutting.cpp) cannot reach: the gl backend
// under a thousand cuts in one step and every spring cut, and a saved state of a cutting run.
#include "formats/scenario.h"
#include "formats/state.h"
#include "formats/volume_io.h"
#include "defect_block_scenario.h"
#include "incision_gesture.h"
#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/stability.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/core/trajectory.h"
#include "runtime_test_support.h"
#include "scenario_damage.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <hdf5.h>
#include <sys/mount.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

using namespace heartsim;
using test::overwrite;
using test::overwrite_attribute;
using test::quoted;
using test::refusal;
namespace fs = std::filesystem;

namespace {

/// A copy of the default build of the shipped phantom (supports, a visual mesh and its mapping).
fs::path phantom_copy(const test::TempDir& dir, const std::string& name) {
    const fs::path& built = test::built_phantom("--particles 2000");
    fs::copy_file(built, dir / name);
    return dir / name;
}

template <class T>
std::vector<T> read_values(const fs::path& file, const char* dataset, hid_t type, std::size_t count) {
    std::vector<T> values(count);
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    const hid_t d = H5Dopen2(f, dataset, H5P_DEFAULT);
    EXPECT_GE(H5Dread(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), 0) << dataset;
    H5Dclose(d);
    H5Fclose(f);
    return values;
}

void expect_refused(const fs::path& file, std::initializer_list<const char*> parts) {
    const std::string message = refusal(file);
    EXPECT_FALSE(message.empty()) << file << " was read";
    for (const char* part : parts) EXPECT_NE(message.find(part), std::string::npos) << part << " in: " << message;
}

std::string file_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
}

/// A tmpfs of `bytes` mounted on a fresh folder for as long as it lives; empty() where this
/// machine does not let the test mount one (not root, no privilege).
class SmallDisk {
public:
    SmallDisk(const fs::path& folder, std::size_t bytes) : folder_(folder) {
        fs::create_directories(folder);
        resize(bytes);
    }
    ~SmallDisk() {
        if (mounted_) ::umount(folder_.c_str());
    }
    bool empty() const { return !mounted_; }
    bool resize(std::size_t bytes) {
        const std::string options = "size=" + std::to_string(bytes);
        const unsigned long flags = mounted_ ? MS_REMOUNT : 0;
        if (::mount("heartsim-test", folder_.c_str(), "tmpfs", flags, options.c_str()) != 0) return false;
        mounted_ = true;
        return true;
    }
private:
    fs::path folder_;
    bool mounted_ = false;
};

std::size_t pages(std::size_t bytes) {
    const auto page = std::size_t(::sysconf(_SC_PAGESIZE));
    return (bytes + page - 1) / page * page;
}

/// The file names in `folder`, sorted: what a failed write must not add to.
std::set<std::string> names_in(const fs::path& folder) {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(folder)) names.insert(entry.path().filename().string());
    return names;
}

test::CommandResult heartsim_command(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }

/// The two-chamber block with an 8 mm VSD (defect_block_scenario.h), built in `dir` once per
/// call: a scenario both planners take.
fs::path block_with_vsd(const test::TempDir& dir) {
    const fs::path scenario = dir / "vsd.h5";
    test::defect_block::build_block_scenario(test::defect_block::make_block(), dir / "block.nrrd", scenario, "vsd", 4000);
    return scenario;
}

}  // namespace

TEST(Reliability, TheStepPolicyIsCheckedAgainstItsCrossFieldRules) {
    test::TempDir dir;
    const fs::path good = phantom_copy(dir, "good.h5");
    ASSERT_EQ(refusal(good), "");
    const Scenario s = read_scenario(good);
    ASSERT_GT(s.solver.damped_critical_dt_ms, 0.0);

    // A safety factor of 50 ran "1 substeps of 5 ms (critical 1.018 ms)" and blew up.
    const fs::path unsafe = phantom_copy(dir, "unsafe.h5");
    overwrite_attribute<double>(unsafe, "/solver", "safety_factor", {50.0}, H5T_NATIVE_DOUBLE);
    expect_refused(unsafe, {"unsafe.h5", "/solver", "safety_factor is 50", "[0.001"});

    // A damped step above the undamped one: damping never lengthens the stable step.
    const fs::path longer = phantom_copy(dir, "longer.h5");
    overwrite_attribute<double>(longer, "/solver", "damped_critical_dt_ms", {1.5 * s.solver.critical_dt_ms}, H5T_NATIVE_DOUBLE);
    expect_refused(longer, {"longer.h5", "/solver", "exceeds critical_dt_ms"});

    // Damping raised within its plausible range, the stored step left as it was.
    const fs::path stale = phantom_copy(dir, "stale.h5");
    std::vector<float> damping(s.lattice.materials.size(), 50.0f);
    overwrite(stale, "materials/damping", damping, H5T_NATIVE_FLOAT);
    expect_refused(stale, {"stale.h5", "/solver", "damped_critical_dt_ms is", "proven ceiling", "rebuild"});

    // The ceiling is a bound, not a guess: the file's own damped step lies within it.
    const double ceiling = damped_step_ceiling_ms(s.lattice.particles, s.lattice.springs, damping_ratios(s.lattice.materials), s.solver.damping);
    EXPECT_LE(s.solver.damped_critical_dt_ms, ceiling);
    EXPECT_GT(s.solver.damped_critical_dt_ms, 0.3 * ceiling) << "a ceiling far above the step would catch nothing";
}

// A scenario that declares a Poisson's ratio above 1/4 stiffens its dilatation with the volume
// term's cells (libmodel/volume_cells.h): a step stored for its springs alone (here the step of
// the same phantom built at 1/4, which those springs would take) is above the proven ceiling that
// counts the cells, and the run refuses the file before a step is taken; the file as heartprep
// wrote it runs.
TEST(Reliability, AStepStoredWithoutTheVolumeCellsIsRefused) {
    test::TempDir dir;
    const fs::path& springs = test::built_phantom("--particles 2000");
    const fs::path& cells = test::built_phantom("--particles 2000 --poisson-ratio 0.49");
    const Scenario alone = read_scenario(springs), stiff = read_scenario(cells);
    ASSERT_NEAR(stiff.lattice.materials.at(0).poisson_ratio, 0.49, 1e-6);
    ASSERT_LT(stiff.solver.critical_dt_ms, 0.5 * alone.solver.critical_dt_ms) << "the cells shorten the step";
    const fs::path stale = dir / "stale.h5";
    fs::copy_file(cells, stale);
    for (const char* name : {"critical_dt_ms", "damped_critical_dt_ms", "dt_ms"}) {
        const double value = std::string(name) == "critical_dt_ms" ? alone.solver.critical_dt_ms
                             : std::string(name) == "dt_ms"       ? alone.solver.dt_ms
                                                                  : alone.solver.damped_critical_dt_ms;
        overwrite_attribute<double>(stale, "/solver", name, {value}, H5T_NATIVE_DOUBLE);
    }
    const auto refused = heartsim_command("run " + quoted(stale) + " --headless --backend cpu --steps 1");
    EXPECT_NE(refused.exit_code, 0) << refused.output;
    for (const char* part : {"critical_dt_ms", "proven ceiling", "volume cells", "rebuild"})
        EXPECT_NE(refused.output.find(part), std::string::npos) << part << " in: " << refused.output;
    const auto good = heartsim_command("run " + quoted(cells) + " --headless --backend cpu --steps 1");
    EXPECT_EQ(good.exit_code, 0) << good.output;
}

TEST(Reliability, MappingOffsetsAndTheScenarioStructureAreChecked) {
    test::TempDir dir;
    const Scenario s = read_scenario(phantom_copy(dir, "reference.h5"));
    ASSERT_TRUE(s.mapping && s.visual);
    const std::size_t n = s.lattice.particles.size(), v = s.visual->positions.size();

    const fs::path far = phantom_copy(dir, "far.h5");
    std::vector<float> offset(v, 0.0f);
    offset[7] = 1e30f;
    overwrite(far, "mapping/offset", offset, H5T_NATIVE_FLOAT);
    expect_refused(far, {"far.h5", "mapping/offset", "entry 7", "farther than"});

    const fs::path twice = phantom_copy(dir, "twice.h5");
    auto pairs = read_values<std::int32_t>(twice, "springs/pairs", H5T_NATIVE_INT32, 2 * s.lattice.springs.size());
    pairs[2] = pairs[0], pairs[3] = pairs[1];
    overwrite(twice, "springs/pairs", pairs, H5T_NATIVE_INT32);
    expect_refused(twice, {"twice.h5", "springs/pairs", "rows 0 and 1 join the same particles"});

    const fs::path one_node = phantom_copy(dir, "one_node.h5");
    overwrite(one_node, "particles/lattice_index", std::vector<std::int32_t>(3 * n, 0), H5T_NATIVE_INT32);
    expect_refused(one_node, {"one_node.h5", "particles/lattice_index", "rows 0 and 1 name the same lattice node (0, 0, 0)"});

    const fs::path both = phantom_copy(dir, "both.h5");
    std::size_t supported = n;
    for (std::size_t i = 0; i < n && supported == n; ++i)
        if (s.lattice.particles.support_stiffness[i] > 0) supported = i;
    ASSERT_LT(supported, n) << "the default build holds the heart on supports";
    std::vector<std::uint8_t> anchored(s.lattice.particles.anchored.begin(), s.lattice.particles.anchored.end());
    anchored[supported] = 1;
    overwrite(both, "particles/anchored", anchored, H5T_NATIVE_UINT8);
    expect_refused(both, {"both.h5", "particles/support_stiffness", ("entry " + std::to_string(supported)).c_str(), "anchored"});

    const fs::path flat = phantom_copy(dir, "flat.h5");
    overwrite_attribute(flat, "/lattice", "index_to_world", std::vector<double>(16, 0.0), H5T_NATIVE_DOUBLE);
    expect_refused(flat, {"flat.h5", "/lattice", "index_to_world"});

    const fs::path huge = phantom_copy(dir, "huge.h5");
    overwrite_attribute<std::int32_t>(huge, "/source", "dims", {1 << 30, 10, 10}, H5T_NATIVE_INT32);
    expect_refused(huge, {"huge.h5", "/source", "at most 65536 voxels along an axis"});
}

TEST(Reliability, AFullDiskAtTheXdmfLeavesNeitherNewFileAndKeepsTheOldPair) {
    test::TempDir dir;
    const fs::path input = dir / "phantom.nii.gz";
    ASSERT_EQ(test::heartprep("phantom -o " + quoted(input) + " --voxel 2").exit_code, 0);
    SmallDisk disk(dir / "disk", 64 << 20);
    if (disk.empty()) GTEST_SKIP() << "cannot mount a tmpfs here (needs root): " << std::strerror(errno);
    const fs::path out = dir / "disk" / "case.h5", xdmf = dir / "disk" / "case.xmf2";
    auto build = [&](const std::string& options) {
        return test::heartprep("build " + quoted(input) + " -o " + quoted(out) + " -q " + options);
    };
    // The sizes of the pair this build writes.
    ASSERT_EQ(build("--particles 1500").exit_code, 0);
    const std::size_t h5_bytes = fs::file_size(out), xdmf_bytes = fs::file_size(xdmf);
    fs::remove(out), fs::remove(xdmf);

    // No old file: room for the .h5 and not one page more. Nothing may be left.
    ASSERT_TRUE(disk.resize(pages(h5_bytes)));
    auto failed = build("--particles 1500");
    EXPECT_EQ(failed.exit_code, 7) << failed.output;
    EXPECT_NE(failed.output.find("XDMF"), std::string::npos) << failed.output;
    EXPECT_TRUE(fs::is_empty(dir / "disk")) << "left behind: " << (fs::exists(out) ? "case.h5 " : "") << (fs::exists(xdmf) ? "case.xmf2" : "");

    // An old pair (another build): the new .h5 fits beside it, its .xmf2 does not.
    ASSERT_TRUE(disk.resize(64 << 20));
    ASSERT_EQ(build("--particles 1200").exit_code, 0);
    const std::string old_h5 = sha256_file(out), old_xdmf = file_text(xdmf);
    ASSERT_TRUE(disk.resize(pages(fs::file_size(out)) + pages(fs::file_size(xdmf)) + pages(h5_bytes)));
    failed = build("--particles 1500");
    EXPECT_EQ(failed.exit_code, 7) << failed.output;
    EXPECT_EQ(sha256_file(out), old_h5) << "the old scenario was replaced";
    EXPECT_EQ(file_text(xdmf), old_xdmf) << "the old description was replaced";
    std::size_t files = 0;
    for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir / "disk")) ++files;
    EXPECT_EQ(files, 2u) << "a temporary was left behind";
    EXPECT_GT(xdmf_bytes, 0u);
}

TEST(Reliability, PlansAndTheStatisticsTableReplaceAnOldFileByRenameNeverWriteIntoIt) {
    // A second hard link to the old file sees what a write does to the file itself: written in
    // place (truncated and refilled), the other link would show the new bytes; renamed into place,
    // the old file lives on under the other name, as it was.
    test::TempDir dir;
    const fs::path scenario = block_with_vsd(dir);
    const std::string old_text = "an old file, kept under a second name\n";
    struct Case {
        std::string command, name;
    };
    for (const Case& c : {Case{"plan-repair " + quoted(scenario) + " -o", "repair.csv"}, Case{"plan-incision " + quoted(scenario) + " -o", "cut.csv"},
                          Case{"run " + quoted(scenario) + " --headless --backend cpu --steps 2 --stats-csv", "stats.csv"}}) {
        SCOPED_TRACE(c.name);
        const fs::path file = dir / c.name, link = dir / ("old-" + c.name);
        std::ofstream(file) << old_text;
        fs::create_hard_link(file, link);
        const auto run = heartsim_command(c.command + " " + quoted(file));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        EXPECT_EQ(file_text(link), old_text) << "the old file was rewritten where it lies";
        EXPECT_EQ(fs::hard_link_count(link), 1u);
        EXPECT_FALSE(fs::equivalent(file, link));
        // The new file is whole: a plan reads back as a trajectory, the table has its six passes.
        const std::string text = file_text(file);
        if (c.name == "stats.csv") {
            EXPECT_EQ(text.rfind("pass,calls,", 0), 0u) << text;
            EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 7) << text;
        } else {
            EXPECT_FALSE(read_trajectory(file).keyframes.empty());
        }
    }
    EXPECT_EQ(names_in(dir.path()), (std::set<std::string>{"block.nrrd", "vsd.h5", "vsd.xmf2", "repair.csv", "old-repair.csv", "cut.csv",
                                                            "old-cut.csv", "stats.csv", "old-stats.csv"}))
        << "a temporary was left behind";
}

TEST(Reliability, AFullDiskKeepsAnOldPlanMeshOrLabelMapByteForByteAndSaysTheDiskIsFull) {
    test::TempDir dir;
    const fs::path scenario = block_with_vsd(dir);
    SmallDisk disk(dir / "disk", 16 << 20);
    if (disk.empty()) GTEST_SKIP() << "cannot mount a tmpfs here (needs root): " << std::strerror(errno);
    const std::size_t page = pages(1);
    // Room for all the old files, and for all but the last page of the new ones.
    auto fill_up = [&](std::size_t new_bytes) {
        std::size_t used = 0;
        for (const auto& entry : fs::directory_iterator(dir / "disk")) used += pages(fs::file_size(entry.path()));
        return disk.resize(used + pages(new_bytes) - page);
    };
    auto expect_full_disk = [&](const test::CommandResult& failed) {
        EXPECT_EQ(failed.exit_code, 7) << failed.output;
        EXPECT_NE(failed.output.find("No space left on device"), std::string::npos) << failed.output;
        EXPECT_EQ(failed.output.find("damaged"), std::string::npos) << "the disk's fault put on the file: " << failed.output;
    };

    // A plan over an old one of fewer stitches, on a disk that holds the new plan less its last
    // page: written in place, the old plan was truncated and then cut short where the disk ended.
    const fs::path plan = dir / "disk" / "repair.csv";
    const std::string plan_command = "plan-repair " + quoted(scenario) + " -o ";
    ASSERT_EQ(heartsim_command(plan_command + quoted(dir / "new.csv")).exit_code, 0);
    const std::size_t new_plan_bytes = fs::file_size(dir / "new.csv");
    ASSERT_EQ(heartsim_command(plan_command + quoted(plan) + " --stitches=3").exit_code, 0);
    const std::string old_plan = file_text(plan);
    ASSERT_LE(pages(old_plan.size()), pages(new_plan_bytes) - page) << "the old plan must fit where the new one does not";
    ASSERT_TRUE(disk.resize(pages(new_plan_bytes) - page));
    expect_full_disk(heartsim_command(plan_command + quoted(plan)));
    EXPECT_TRUE(file_text(plan) == old_plan) << "the old plan was changed";
    EXPECT_EQ(names_in(dir / "disk"), std::set<std::string>{"repair.csv"});

    // A mesh exported for ParaView: its writer's stream only says that it failed.
    ASSERT_TRUE(disk.resize(16 << 20));
    fs::remove(plan);
    const fs::path mesh = dir / "disk" / "heart.vtp";
    const std::string export_command = "export " + quoted(scenario) + " -o " + quoted(mesh);
    ASSERT_EQ(test::heartprep(export_command).exit_code, 0);
    const std::string old_mesh = file_text(mesh);
    ASSERT_TRUE(fill_up(old_mesh.size()));
    expect_full_disk(test::heartprep(export_command));
    EXPECT_TRUE(file_text(mesh) == old_mesh) << "the old mesh was changed";
    EXPECT_EQ(names_in(dir / "disk"), std::set<std::string>{"heart.vtp"});
    ASSERT_TRUE(disk.resize(16 << 20));
    fs::remove(mesh);

    // A label map from `heartprep defect`, in one file (.nii) and as a MetaImage pair (.mhd + .raw).
    const Eigen::Vector3d at = test::defect_block::repair_site(test::defect_block::make_block());
    const std::string point = std::to_string(at.x()) + "," + std::to_string(at.y()) + "," + std::to_string(at.z());
    for (const std::string name : {"vsd.nii", "vsd.mhd"}) {
        SCOPED_TRACE(name);
        const fs::path out = dir / "disk" / name;
        const std::string defect = "defect " + quoted(dir / "block.nrrd") + " --type vsd --diameter 8 --at " + point + " -q -o " + quoted(out);
        ASSERT_EQ(test::heartprep(defect).exit_code, 0);
        const std::set<std::string> files = names_in(dir / "disk");
        std::map<std::string, std::string> old_bytes;
        std::size_t new_bytes = 0;
        for (const std::string& file : files) old_bytes[file] = file_text(dir / "disk" / file), new_bytes += old_bytes[file].size();
        ASSERT_EQ(files.size(), name == "vsd.mhd" ? 2u : 1u);
        ASSERT_TRUE(fill_up(new_bytes));
        expect_full_disk(test::heartprep(defect));
        for (const auto& [file, bytes] : old_bytes) EXPECT_TRUE(file_text(dir / "disk" / file) == bytes) << file << " was changed";
        EXPECT_EQ(names_in(dir / "disk"), files) << "a temporary was left behind";
        ASSERT_TRUE(disk.resize(16 << 20));
        for (const std::string& file : files) fs::remove(dir / "disk" / file);
    }
}

TEST(Reliability, ADetachedLabelMapsDataFileIsInTheBatchKeyTheHashAndTheSummary) {
    test::TempDir dir;
    fs::create_directories(dir / "in");
    const fs::path header = dir / "in" / "case.mhd";
    ASSERT_EQ(test::heartprep("phantom -o " + quoted(header) + " --voxel 2").exit_code, 0);
    const VolumeHeader read = read_volume_header(header);
    ASSERT_FALSE(read.data_file.empty()) << "a .mhd written by heartprep keeps its voxels in a .raw beside it";
    const fs::path raw = read.data_file;
    EXPECT_EQ(label_map_sha256(header), sha256_text(sha256_file(header) + "\n" + sha256_file(raw)));

    std::ofstream(dir / "cases.csv") << "input,case_id,options\nin/case.mhd,detached,--particles 1500\n";
    const std::string batch = "batch " + quoted(dir / "cases.csv") + " -o " + quoted(dir / "out") + " --no-preview";
    auto first = test::heartprep(batch);
    ASSERT_EQ(first.exit_code, 0) << first.output;
    const std::string first_hash = read_scenario(dir / "out" / "detached.h5").source.sha256;
    EXPECT_EQ(first_hash, label_map_sha256(header));

    // Another heart of the same size: the header's bytes stay, the voxel file changes.
    const fs::path other = dir / "other.mhd";
    ASSERT_EQ(test::heartprep("phantom -o " + quoted(other) + " --voxel 2 --vsd-diameter 14 --vsd-position 0.4").exit_code, 0);
    const VolumeHeader other_header = read_volume_header(other);
    ASSERT_EQ(other_header.geometry.dims, read.geometry.dims);
    fs::copy_file(other_header.data_file, raw, fs::copy_options::overwrite_existing);
    auto second = test::heartprep(batch);
    ASSERT_EQ(second.exit_code, 0) << second.output;
    EXPECT_NE(second.output.find("| detached | built |"), std::string::npos) << "a changed voxel file was skipped:\n" << second.output;
    const std::string second_hash = read_scenario(dir / "out" / "detached.h5").source.sha256;
    EXPECT_NE(second_hash, first_hash);
    EXPECT_EQ(second_hash, label_map_sha256(header));

    // A header whose data file lies outside its folder is read, named, and warned about.
    fs::create_directories(dir / "headers");
    std::string text = file_text(header);
    const auto at = text.find("ElementDataFile");
    ASSERT_NE(at, std::string::npos) << text;
    text = text.substr(0, at) + "ElementDataFile = ../in/" + raw.filename().string() + "\n";
    std::ofstream(dir / "headers" / "elsewhere.mhd") << text;
    auto build = test::heartprep("build " + quoted(dir / "headers" / "elsewhere.mhd") + " -o " + quoted(dir / "elsewhere.h5") +
                                 " --particles 1500");
    EXPECT_EQ(build.exit_code, 0) << build.output;
    EXPECT_NE(build.output.find("voxels      from"), std::string::npos) << build.output;
    EXPECT_NE(build.output.find("lies outside the header's folder"), std::string::npos) << build.output;

    // A data file that is not a label map (every byte value): one short line, not 256 numbers.
    std::vector<unsigned char> noise(read.geometry.voxel_count());
    for (std::size_t i = 0; i < noise.size(); ++i) noise[i] = static_cast<unsigned char>((i * 2654435761u) >> 13);
    test::write_bytes(dir / "headers" / "noise.raw", noise);
    std::string noise_header = text.substr(0, at) + "ElementDataFile = noise.raw\n";
    for (const char* type : {"MET_USHORT", "MET_SHORT", "MET_UINT", "MET_INT"})
        if (const auto t = noise_header.find(type); t != std::string::npos) noise_header.replace(t, std::strlen(type), "MET_UCHAR");
    std::ofstream(dir / "headers" / "noise.mhd") << noise_header;
    auto refused = test::heartprep("build " + quoted(dir / "headers" / "noise.mhd") + " -o " + quoted(dir / "noise.h5") + " --tissue=300");
    EXPECT_EQ(refused.exit_code, 1) << refused.output;
    EXPECT_NE(refused.output.find("different values: is this a label map?"), std::string::npos) << refused.output;
    EXPECT_LT(refused.output.size(), 1200u) << refused.output;
}

TEST(Reliability, ALegalOutputNameOf253CharactersIsWritten) {
    test::TempDir dir;
    const fs::path input = dir / "phantom.nii.gz";
    ASSERT_EQ(test::heartprep("phantom -o " + quoted(input) + " --voxel 2").exit_code, 0);
    const std::string name = std::string(250, 'h') + ".h5";  // 253 bytes; its .xmf2 255
    const auto run = test::heartprep("build " + quoted(input) + " -o " + quoted(dir / name) + " --particles 1200 -q");
    EXPECT_EQ(run.exit_code, 0) << run.output;
    EXPECT_TRUE(fs::exists(dir / name));
    EXPECT_TRUE(fs::exists(dir / (std::string(250, 'h') + ".xmf2")));
    EXPECT_EQ(refusal(dir / name), "");
    std::size_t files = 0;
    for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir.path())) ++files;
    EXPECT_EQ(files, 3u) << "a temporary was left behind";
}

TEST(Reliability, AHapticRunWithStepsZeroSaysWhatZeroMeans) {
    test::TempDir dir;
    const auto run = test::run_command(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(test::built_phantom("--particles 2000")) +
                                       " --headless --device scripted:" + quoted(dir / "poses.csv") + " --steps 0");
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("--steps 0 runs no step"), std::string::npos) << run.output;
}

// ------------------------------------------------------------------------------------------------
// Cutting

namespace {

/// A block of 10 × 14 × 14 particles 1.5 mm apart (test_support.h block_lattice) as a scenario,
/// packed, its left face (lattice x = 0) anchored, and the options of a run on it under gravity.
struct BlockRun {
    Scenario scenario;
    SolverOptions options;
    Eigen::Vector3d low = Eigen::Vector3d::Constant(1e30), high = Eigen::Vector3d::Constant(-1e30);
    Eigen::Vector3d rest(std::size_t i) const {
        const auto& r = scenario.lattice.particles.rest_position[i];
        return {r[0], r[1], r[2]};
    }
};
BlockRun block_run() {
    BlockRun b;
    b.scenario.lattice = test::block_lattice(10, 14, 14, 1.5, 0.1);
    Particles& p = b.scenario.lattice.particles;
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][0] == 0 ? 1 : 0;
    b.scenario.packing = pack_particles(b.scenario.lattice);
    b.options.critical_dt_ms = estimate_critical_time_step(p, b.scenario.lattice.springs, 5000, 1e-12).critical_dt_ms;
    b.options.gravity = {0.0, 9.81e-3, 0.0};
    for (std::size_t i = 0; i < p.size(); ++i) b.low = b.low.cwiseMin(b.rest(i)), b.high = b.high.cwiseMax(b.rest(i));
    return b;
}

/// One step in which a lowered scalpel lying in the plane through `point` with unit `normal` is
/// drawn `size` mm across it (a `size` mm blade, centred on the point); the blade lifts after it.
StepReport cut_plane(Backend& backend, const Eigen::Vector3d& point, const Eigen::Vector3d& normal, double size) {
    const Eigen::Vector3d helper = std::abs(normal.y()) < 0.9 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitX();
    const Eigen::Vector3d blade = normal.cross(helper).normalized(), across = normal.cross(blade);
    InstrumentPose from;
    from.orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), blade);
    from.position = point - 0.5 * size * (blade + across);
    InstrumentPose to = from;
    to.position += size * across;
    backend.set_instrument(0, {.kind = InstrumentKind::scalpel, .semi_axes = {1.0, 0.2, 0.5 * size}});
    backend.set_pose(0, from);
    backend.begin_grab(0);
    backend.set_pose(0, to);
    const StepReport report = backend.step(1);
    backend.release(0);
    return report;
}

bool finite(const std::vector<std::array<float, 3>>& positions) {
    for (const auto& p : positions)
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return false;
    return true;
}

double largest_difference(const std::vector<std::array<float, 3>>& a, const std::vector<std::array<float, 3>>& b) {
    double worst = 0;
    for (std::size_t i = 0; i < a.size(); ++i)
        for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(a[i][c] - b[i][c])));
    return worst;
}

}  // namespace

// The gl backend's cut pass under the load the cpu tests put on the solver (test_cutting.cpp): a
// blade drawn through a block of 1,960 particles in one step, along a plane tilted to every
// lattice axis, cuts exactly the springs with rest ends on either side of the plane (over a
// thousand, counted here by brute force) on both backends; the severed piece falls the same on
// both. Then sweeps between every two neighbouring layers cut every spring on both: the particles
// fall apart, finite, without a watchdog event, the same on both; reset_tissue heals every cut.
TEST(Reliability, TheGlBackendCutsAThousandSpringsInOneStepAndEverySpringAsTheCpuDoes) {
    REQUIRE_GL();
    const BlockRun b = block_run();
    const Eigen::Vector3d normal = Eigen::Vector3d(1.0, 0.2, 0.1).normalized();
    const Eigen::Vector3d point = 0.5 * (b.low + b.high) + Eigen::Vector3d(0.0137, 0, 0);
    std::set<std::array<std::int32_t, 2>> across, all;
    for (const auto& [i, j] : b.scenario.lattice.springs.pairs) {
        const std::array<std::int32_t, 2> key{std::min(i, j), std::max(i, j)};
        all.insert(key);
        if ((b.rest(std::size_t(i)) - point).dot(normal) * (b.rest(std::size_t(j)) - point).dot(normal) < 0) across.insert(key);
    }
    ASSERT_GE(across.size(), 1000u);
    const double size = 3.0 * (b.high - b.low).norm();

    auto cpu = make_cpu_backend(b.scenario, b.options);
    auto gl = make_gl_backend(*test::shared_gl_context(), b.scenario, b.options);
    for (Backend* backend : {cpu.get(), gl.get()}) {
        const StepReport r = cut_plane(*backend, point, normal, size);
        EXPECT_FALSE(r.diverged) << to_string(backend->kind()) << ": " << r.message;
        const auto cut = backend->cut_springs();
        EXPECT_TRUE((std::set<std::array<std::int32_t, 2>>(cut.begin(), cut.end()) == across)) << to_string(backend->kind());
        EXPECT_EQ(cut.size(), across.size()) << to_string(backend->kind());
        const StepReport fall = backend->step(int(std::ceil(3.0 / backend->time_step_ms())));
        EXPECT_FALSE(fall.diverged) << to_string(backend->kind()) << ": " << fall.message;
    }
    std::printf("  %zu springs cut in one step on each backend\n", across.size());
    auto x = cpu->positions(), y = gl->positions();
    ASSERT_TRUE(finite(x) && finite(y));
    EXPECT_LE(largest_difference(x, y), 1e-4 * (b.high - b.low).norm());

    // Every spring: a sweep between every two neighbouring layers along x, y and z.
    for (Backend* backend : {cpu.get(), gl.get()}) {
        backend->reset_tissue();
        for (int axis = 0; axis < 3; ++axis) {
            std::set<double> layers;
            for (std::size_t i = 0; i < b.scenario.lattice.particles.size(); ++i) layers.insert(b.rest(i)[axis]);
            for (auto it = layers.begin(); std::next(it) != layers.end(); ++it) {
                Eigen::Vector3d middle = 0.5 * (b.low + b.high);
                middle[axis] = 0.5 * (*it + *std::next(it));
                const StepReport r = cut_plane(*backend, middle, Eigen::Vector3d::Unit(axis), size);
                ASSERT_FALSE(r.diverged) << to_string(backend->kind()) << ": " << r.message;
            }
        }
        const auto cut = backend->cut_springs();
        EXPECT_TRUE((std::set<std::array<std::int32_t, 2>>(cut.begin(), cut.end()) == all)) << to_string(backend->kind());
        EXPECT_EQ(cut.size(), all.size()) << to_string(backend->kind());
        const StepReport fall = backend->step(int(std::ceil(3.0 / backend->time_step_ms())));
        EXPECT_FALSE(fall.diverged) << to_string(backend->kind()) << ": " << fall.message;
    }
    x = cpu->positions(), y = gl->positions();
    ASSERT_TRUE(finite(x) && finite(y));
    EXPECT_LE(largest_difference(x, y), 1e-4 * (b.high - b.low).norm());
    // Nothing joins the free particles: each fell from where it rested as the others did (the
    // anchored face stayed).
    const std::size_t free_one = std::size_t(std::find(b.scenario.lattice.particles.anchored.begin(), b.scenario.lattice.particles.anchored.end(),
                                                       std::uint8_t(0)) - b.scenario.lattice.particles.anchored.begin());
    const Eigen::Vector3d drop = Eigen::Vector3d(x[free_one][0], x[free_one][1], x[free_one][2]) - b.rest(free_one);
    EXPECT_GT(drop.y(), 0.01);
    for (std::size_t i = 0; i < x.size(); ++i) {
        const Eigen::Vector3d moved = Eigen::Vector3d(x[i][0], x[i][1], x[i][2]) - b.rest(i);
        if (b.scenario.lattice.particles.anchored[i]) ASSERT_EQ(moved, Eigen::Vector3d::Zero()) << i;
        else ASSERT_LE((moved - drop).norm(), 1e-3 * drop.norm() + 1e-5) << i;
    }
    std::printf("  every one of %zu springs cut on each backend; the free particles fell %.4f mm\n", all.size(), drop.y());
    for (Backend* backend : {cpu.get(), gl.get()}) {
        backend->reset_tissue();
        EXPECT_TRUE(backend->cut_springs().empty()) << to_string(backend->kind());
        const auto rest = backend->positions();
        for (std::size_t i = 0; i < rest.size(); ++i) ASSERT_LE((Eigen::Vector3d(rest[i][0], rest[i][1], rest[i][2]) - b.rest(i)).norm(), 1e-6);
    }
}

// `heartsim run --trajectory` with a scalpel (the incision of incision_gesture.h through the
// phantom's anterior wall), `--save-state`: the state file holds the springs the same run cut when
// driven here in process (the cpu backend, the same trajectory file read back, the same steps), to
// the spring, sorted, each once and each a spring of the scenario; its positions are that run's to
// the bit, and its hand 0 is the scalpel.
TEST(Reliability, ASavedStateOfACuttingRunHoldsTheSpringsItCut) {
    test::TempDir dir;
    const fs::path& phantom = test::built_phantom("--particles 2000");
    const Scenario scenario = read_scenario(phantom);
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 16, .retract = false});
    test::write_trajectory_csv(plan.trajectory, dir / "cut.csv");
    const Trajectory trajectory = read_trajectory(dir / "cut.csv");
    auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
    const int steps = int(std::ceil(plan.end_ms / cpu->time_step_ms()));
    const ScriptedRunResult run = run_scripted(*cpu, trajectory, {.steps = steps});
    EXPECT_EQ(run.watchdog_events, 0u) << run.last_watchdog_message;
    const auto cut = cpu->cut_springs();
    ASSERT_GT(cut.size(), 20u);

    const auto cli = test::run_command(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom) + " --headless --backend cpu --trajectory " +
                                       quoted(dir / "cut.csv") + " --steps " + std::to_string(steps) + " --save-state " + quoted(dir / "state.h5"));
    ASSERT_EQ(cli.exit_code, 0) << cli.output;
    const SimulationState state = read_state(dir / "state.h5");
    std::printf("  %zu springs cut in %d steps; the state file lists %zu\n", cut.size(), steps, state.cut_springs.size());
    EXPECT_EQ(state.steps, steps);
    EXPECT_EQ(state.kind[0], 3);
    EXPECT_TRUE(state.cut_springs == cut);
    std::set<std::array<std::int32_t, 2>> springs;
    for (const auto& [i, j] : scenario.lattice.springs.pairs) springs.insert({std::min(i, j), std::max(i, j)});
    for (std::size_t k = 0; k < state.cut_springs.size(); ++k) {
        EXPECT_TRUE(springs.count(state.cut_springs[k])) << state.cut_springs[k][0] << "–" << state.cut_springs[k][1] << " is no spring";
        if (k > 0) {
            EXPECT_LT(state.cut_springs[k - 1], state.cut_springs[k]);
        }
    }
    EXPECT_TRUE(state.positions == cpu->positions()) << "the saved positions are not the run's";

    // The reader holds the list to its promise: two rows swapped, or a row repeated, are refused
    // naming the dataset and the row.
    std::vector<std::int32_t> rows;
    for (const auto& [i, j] : state.cut_springs) rows.push_back(i), rows.push_back(j);
    std::vector<std::int32_t> swapped = rows, repeated = rows;
    std::swap(swapped[0], swapped[2]), std::swap(swapped[1], swapped[3]);
    repeated[2] = repeated[0], repeated[3] = repeated[1];
    for (const auto& [name, tampered] : {std::pair{"swapped.h5", swapped}, std::pair{"repeated.h5", repeated}}) {
        fs::copy_file(dir / "state.h5", dir / name);
        test::overwrite(dir / name, "cut_springs", tampered, H5T_NATIVE_INT32);
        try {
            read_state(dir / name);
            ADD_FAILURE() << name << " was read";
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("cut_springs: row 1"), std::string::npos) << e.what();
        }
    }
}
