// heartprep end to end, as a technician runs it: the binary, real files, exit codes, messages.
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/phantom.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <regex>
#include <set>
#include <unistd.h>

using namespace heartsim;
using test::heartprep;
using test::quoted;
namespace fs = std::filesystem;

namespace {

/// Files in `folder` (names only).
std::set<std::string> listing(const fs::path& folder) {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(folder)) names.insert(entry.path().filename().string());
    return names;
}

/// A bad-input run: non-zero exit, one "heartprep: error:" line naming `mentions`, and the
/// folder holds exactly what it held before (no output, no temporary file).
void expect_refusal(const test::TempDir& dir, const std::string& arguments, const std::vector<std::string>& mentions) {
    const auto before = listing(dir.path());
    const auto result = heartprep(arguments);
    EXPECT_NE(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("heartprep: error: "), std::string::npos) << result.output;
    for (const auto& m : mentions) EXPECT_NE(result.output.find(m), std::string::npos) << "'" << m << "' not in: " << result.output;
    EXPECT_EQ(listing(dir.path()), before) << "bad input left files behind";
}

/// Writes a label map: a block of label 1 inside label 0.
fs::path write_block(const test::TempDir& dir, const std::string& name) {
    LabelVolume v;
    v.geometry.dims = {16, 16, 16};
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = 4; k < 12; ++k)
        for (int j = 4; j < 12; ++j)
            for (int i = 4; i < 12; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    write_label_volume(dir / name, v);
    return dir / name;
}

}  // namespace

TEST(Heartprep, HelpTeachesEveryCommand) {
    const auto help = heartprep("--help");
    EXPECT_EQ(help.exit_code, 0);
    for (const char* command : {"build", "surface", "inspect", "phantom"}) EXPECT_NE(help.output.find(command), std::string::npos);
    const auto build = heartprep("build --help");
    for (const char* option : {"--tissue", "--cavity", "--anchor-label", "--anchor-border", "--min-island", "--spacing",
                               "--particles", "--occupancy", "--smoothing", "--decimate", "--youngs-modulus"})
        EXPECT_NE(build.output.find(option), std::string::npos) << option;
}

TEST(Heartprep, BuildsThePhantomIntoAScenarioWhoseReportMatchesTheFile) {
    test::TempDir dir;
    ASSERT_EQ(heartprep("phantom -o " + quoted(dir / "phantom.nii.gz")).exit_code, 0);
    const auto run = heartprep("build " + quoted(dir / "phantom.nii.gz") + " -o " + quoted(dir / "p.h5") +
                               " --cavity 2 --anchor-border --particles 5000");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario s = read_scenario(dir / "p.h5");
    std::smatch m;
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"((\d+) particles \((\d+) anchored\), (\d+) springs)"))) << run.output;
    EXPECT_EQ(std::stoul(m[1]), s.lattice.particles.size());
    EXPECT_LE(s.lattice.particles.size(), 5000u);
    std::size_t anchored = 0;
    for (auto a : s.lattice.particles.anchored) anchored += a;
    EXPECT_EQ(std::stoul(m[2]), anchored);
    EXPECT_GT(anchored, 0u) << "the phantom's base lies on the volume border";
    EXPECT_EQ(std::stoul(m[3]), s.lattice.springs.size());
    ASSERT_TRUE(s.visual.has_value());
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"((\d+) vertices, (\d+) triangles)")));
    EXPECT_EQ(std::stoul(m[1]), s.visual->positions.size());
    EXPECT_EQ(std::stoul(m[2]), s.visual->triangles.size());
    EXPECT_LT(s.solver.dt_ms, s.solver.critical_dt_ms);
    EXPECT_LE(s.solver.dt_ms, s.solver.critical_dt_bound_ms);
    EXPECT_EQ(s.source.sha256.size(), 64u);

    const auto inspect = heartprep("inspect --json " + quoted(dir / "p.h5"));
    ASSERT_EQ(inspect.exit_code, 0) << inspect.output;
    EXPECT_NE(inspect.output.find("\"particles\": " + std::to_string(s.lattice.particles.size())), std::string::npos);
}

TEST(Heartprep, H5dumpShowsTheContractNames) {
    if (test::run_command("command -v h5dump").exit_code != 0) GTEST_SKIP() << "h5dump (Debian hdf5-tools) is not installed";
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");
    ASSERT_EQ(heartprep("build " + quoted(input) + " -o " + quoted(dir / "b.h5") + " --spacing 2 -q").exit_code, 0);
    const auto dump = test::run_command("h5dump -H " + quoted(dir / "b.h5"));
    ASSERT_EQ(dump.exit_code, 0);
    for (const char* name :
         {"ATTRIBUTE \"format\"", "ATTRIBUTE \"format_version\"", "ATTRIBUTE \"units\"", "ATTRIBUTE \"frame\"",
          "ATTRIBUTE \"generator\"", "ATTRIBUTE \"source_sha256\"", "GROUP \"source\"", "ATTRIBUTE \"voxel_to_world\"",
          "GROUP \"lattice\"", "ATTRIBUTE \"index_to_world\"", "GROUP \"materials\"", "DATASET \"label\"", "DATASET \"name\"",
          "DATASET \"density\"", "DATASET \"stiffness\"", "DATASET \"damping\"", "GROUP \"particles\"",
          "DATASET \"rest_position\"", "DATASET \"lattice_index\"", "DATASET \"mass\"", "DATASET \"material\"",
          "DATASET \"anchored\"", "GROUP \"springs\"", "DATASET \"pairs\"", "DATASET \"rest_length\"", "GROUP \"visual\"",
          "DATASET \"positions\"", "DATASET \"normals\"", "DATASET \"triangles\"", "GROUP \"solver\"", "ATTRIBUTE \"dt_ms\"",
          "ATTRIBUTE \"substeps\"", "ATTRIBUTE \"gravity\"", "ATTRIBUTE \"critical_dt_ms\""})
        EXPECT_NE(dump.output.find(name), std::string::npos) << name;
    // An 8³-voxel block at 2 mm spacing on 1 mm voxels: 4³ particles, exact shapes.
    EXPECT_NE(dump.output.find("DATASPACE  SIMPLE { ( 64, 3 ) / ( 64, 3 ) }"), std::string::npos) << dump.output;
}

TEST(Heartprep, SurfaceWritesEveryMeshFormat) {
    test::TempDir dir;
    const auto input = write_block(dir, "block.nrrd");
    for (const char* extension : {".stl", ".obj", ".ply", ".glb"}) {
        const auto out = dir / (std::string("block") + extension);
        const auto run = heartprep("surface " + quoted(input) + " -o " + quoted(out));
        EXPECT_EQ(run.exit_code, 0) << run.output;
        EXPECT_NE(run.output.find("closed 2-manifold"), std::string::npos) << run.output;
        EXPECT_GT(fs::file_size(out), 100u);
    }
}

TEST(HeartprepErrors, MissingFile) {
    test::TempDir dir;
    expect_refusal(dir, "build " + quoted(dir / "absent.nii.gz") + " -o " + quoted(dir / "out.h5"), {"absent.nii.gz", "not found"});
}

TEST(HeartprepErrors, UnsupportedFormat) {
    test::TempDir dir;
    std::ofstream(dir / "labels.txt") << "1 2 3";
    expect_refusal(dir, "build " + quoted(dir / "labels.txt") + " -o " + quoted(dir / "out.h5"), {"labels.txt", "unsupported"});
}

TEST(HeartprepErrors, FloatImage) {
    test::TempDir dir;
    test::HandNifti nifti({2, 2, 2}, 16 /*float32*/, 32);
    nifti.append_voxels(std::vector<float>{1.7f, 0, 0, 1, 1, 1, 0.5f, 0});
    test::write_bytes(dir / "float.nii", nifti.bytes);
    expect_refusal(dir, "build " + quoted(dir / "float.nii") + " -o " + quoted(dir / "out.h5"), {"float.nii", "integer label map"});
}

TEST(HeartprepErrors, LabelThatDoesNotOccur) {
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --tissue 5", {"tissue label 5 does not occur"});
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --cavity 9", {"cavity label 9 does not occur"});
}

TEST(HeartprepErrors, EmptySelection) {
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --min-island 100000", {"empty selection"});
}

TEST(HeartprepErrors, ZeroNegativeAndNanSpacing) {
    test::TempDir dir;
    for (float spacing : {0.0f, -1.0f, std::nanf("")}) {
        test::HandNifti nifti({4, 4, 4}, 2 /*uint8*/, 8);
        nifti.set_pixdim(0, spacing);
        nifti.append_voxels(std::vector<std::uint8_t>(64, 1));
        test::write_bytes(dir / "spacing.nii", nifti.bytes);
        expect_refusal(dir, "build " + quoted(dir / "spacing.nii") + " -o " + quoted(dir / "out.h5"), {"spacing.nii", "spacing"});
    }
    // And the lattice spacing option.
    const auto input = write_block(dir, "block.nii.gz");
    for (const char* bad : {"0", "-2", "nan"}) {
        const auto result = heartprep("build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --spacing " + bad);
        EXPECT_NE(result.exit_code, 0) << bad;
        EXPECT_NE(result.output.find("--spacing"), std::string::npos) << result.output;
        EXPECT_FALSE(fs::exists(dir / "out.h5"));
    }
}

TEST(HeartprepErrors, TruncatedGzip) {
    test::TempDir dir;
    const auto input = write_block(dir, "cut.nii.gz");
    fs::resize_file(input, fs::file_size(input) - 12);
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5"), {"cut.nii.gz", "truncated"});
}

TEST(HeartprepErrors, UnwritableOutput) {
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "missing" / "out.h5"), {"missing", "does not exist"});
    if (geteuid() != 0) {  // root writes anywhere; the permission case is then untestable
        fs::create_directory(dir / "locked");
        fs::permissions(dir / "locked", fs::perms::owner_read | fs::perms::owner_exec);
        expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "locked" / "out.h5"), {"not writable"});
    }
}

TEST(HeartprepErrors, VolumeTooLargeForMemory) {
    test::TempDir dir;
    // A NIfTI header declaring 30000³ uint8 voxels (27 TB) and holding none.
    test::HandNifti nifti({30000, 30000, 30000}, 2, 8);
    test::write_bytes(dir / "huge.nii", nifti.bytes);
    expect_refusal(dir, "build " + quoted(dir / "huge.nii") + " -o " + quoted(dir / "out.h5"), {"huge.nii", "too large"});
}

TEST(HeartprepErrors, UnknownOptionsAndMissingArguments) {
    test::TempDir dir;
    EXPECT_NE(heartprep("build").exit_code, 0);
    EXPECT_NE(heartprep("frobnicate").exit_code, 0);
    const auto bad = heartprep("build x.nii.gz -o y.h5 --occupancy 2");
    EXPECT_NE(bad.exit_code, 0);
    EXPECT_NE(bad.output.find("--occupancy"), std::string::npos) << bad.output;
    expect_refusal(dir, "inspect " + quoted(dir / "nothing.h5"), {"nothing.h5", "file not found"});
}

// -------------------------------------------------------------------------------------------
// Real HVSMR 2016 cases, from ../shared/data/real (skipped with a message when absent).

class RealCase : public ::testing::TestWithParam<std::string> {};

TEST_P(RealCase, BuildsWithAClosedSurfaceAndParticlesInTissue) {
    const auto input = test::real_case(GetParam());
    if (input.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    test::TempDir dir;
    const auto run = heartprep("build " + quoted(input) + " -o " + quoted(dir / "case.h5") + " --cavity 2 --anchor-border");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("closed 2-manifold"), std::string::npos) << run.output;
    const Scenario s = read_scenario(dir / "case.h5");
    std::smatch m;
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"((\d+) particles \((\d+) anchored\), (\d+) springs)")));
    EXPECT_EQ(std::stoul(m[1]), s.lattice.particles.size());
    EXPECT_EQ(std::stoul(m[3]), s.lattice.springs.size());
    EXPECT_LE(s.lattice.particles.size(), 30000u);
    EXPECT_GE(s.lattice.particles.size(), 27000u);

    // Every particle lies in tissue: its cell (a cube of side h about the particle), mapped back
    // into the label map through the file's own voxel-to-world matrix, is covered by myocardium
    // voxels (label 1, islands included) to at least --occupancy (0.5), except the thin-wall
    // particles heartprep reports. The overlap of each voxel
    // box with the cell is computed here exactly, axis by axis, in voxel units.
    const LabelVolume volume = read_label_volume(input);
    const Eigen::Matrix4d world_to_voxel = s.source.geometry.voxel_to_world().inverse();
    const Eigen::Vector3d half_cell = (0.5 * s.lattice.spacing) * s.source.geometry.spacing.cwiseInverse();
    std::size_t below_occupancy = 0, at_occupancy = 0;
    for (std::size_t p = 0; p < s.lattice.particles.size(); ++p) {
        const auto& x = s.lattice.particles.rest_position[p];
        const Eigen::Vector3d centre = (world_to_voxel * Eigen::Vector4d(x[0], x[1], x[2], 1)).head<3>();
        const Eigen::Vector3d low = centre - half_cell, high = centre + half_cell;
        auto overlap = [&](int axis, int index) {  // voxel `index` spans [index − ½, index + ½]
            return std::max(0.0, std::min(high[axis], index + 0.5) - std::max(low[axis], index - 0.5));
        };
        double covered = 0;
        for (int k = int(std::floor(low.z())); k <= int(std::ceil(high.z())); ++k)
            for (int j = int(std::floor(low.y())); j <= int(std::ceil(high.y())); ++j)
                for (int i = int(std::floor(low.x())); i <= int(std::ceil(high.x())); ++i)
                    if (volume.geometry.contains(i, j, k) && volume.labels[volume.geometry.linear(i, j, k)] == 1)
                        covered += overlap(0, i) * overlap(1, j) * overlap(2, k);
        const double fraction = covered / (8.0 * half_cell.prod());
        // Below --occupancy only on thin walls: the ridge of a wall thinner than half a cell
        // (--ridge-fraction 0.2), or a particle added beside a one-particle-thick wall
        // (--thicken-fraction 0.05).
        if (fraction < 0.5 - 1e-4) ++below_occupancy;
        else if (fraction < 0.5 + 1e-4) ++at_occupancy;  // float32 in heartprep: either side
        ASSERT_GE(fraction, 0.05 - 1e-4) << "particle " << p << " at LPS (" << x[0] << ", " << x[1] << ", " << x[2] << ")";
    }
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"(thin walls  (\d+) particles on walls thinner than half a cell, (\d+) added)")))
        << run.output;
    const std::size_t thin_wall = std::stoul(m[1]) + std::stoul(m[2]);
    EXPECT_GE(thin_wall, below_occupancy) << "every particle below --occupancy is a thin-wall particle";
    EXPECT_LE(thin_wall, below_occupancy + at_occupancy);
    EXPECT_LT(below_occupancy, s.lattice.particles.size() / 5);
}

INSTANTIATE_TEST_SUITE_P(Hvsmr2016, RealCase,
                         ::testing::Values("hvsmr16_pat0", "hvsmr16_pat1", "hvsmr16_pat5", "hvsmr16_pat6"));

TEST(HeartprepErrors, AFullDiskFailsCleanlyAndKeepsTheOldFile) {
    // A full disk injected with a file-size limit (the shell ignores SIGXFSZ, so writes fail with
    // EFBIG as on a full disk): one clear message naming the file, exit 1, not a crash in HDF5's
    // exit handler (it used to end in a segmentation fault after the message), the scenario
    // already there untouched and no temporary file left.
    test::TempDir dir;
    {
        std::ofstream old(dir / "out.h5");
        old << "the previous build";
    }
    const auto run = test::run_command("trap '' XFSZ; ulimit -f 400; " + test::quoted(HEARTPREP_EXE) + " build " +
                                       test::quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz") + " -o " +
                                       test::quoted(dir / "out.h5") + " -q");
    EXPECT_EQ(run.exit_code, 1) << run.output;
    EXPECT_NE(run.output.find("out.h5: cannot write the file (File too large; disk full?)"), std::string::npos) << run.output;
    std::ifstream kept(dir / "out.h5");
    const std::string content((std::istreambuf_iterator<char>(kept)), std::istreambuf_iterator<char>());
    EXPECT_EQ(content, "the previous build");
    std::size_t entries = 0;
    for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir.path())) ++entries;
    EXPECT_EQ(entries, 1u) << "a temporary file was left behind";
}

TEST(HeartprepErrors, OutOfMemoryIsOneLineNamingTheStageAndLeavesNoFile) {
    // Out of memory injected with address-space limits rising from 32 MiB until the build fits:
    // every limit below that ends with exit 1 and the one line "out of memory while running stage
    // '…'", whether an allocation failed, a worker thread could not start (oneTBB's
    // "pthread_create has failed") or HDF5 could not build the file in memory (it said "cannot
    // create the file in memory"); never a signal or a hang; and no output or temporary file is left.
    if (test::under_address_sanitizer) GTEST_SKIP() << "address-space limits do not work under AddressSanitizer";
    test::TempDir dir;
    test::expect_clean_out_of_memory(test::quoted(HEARTPREP_EXE) + " build " +
                                         test::quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz") + " -o " +
                                         test::quoted(dir / "out.h5") + " -q",
                                     "heartprep: error: out of memory while ");
    // The last run succeeded and wrote out.h5 and its out.xdmf; the failed ones left nothing else.
    EXPECT_EQ(listing(dir.path()), (std::set<std::string>{"out.h5", "out.xdmf"}));
}

TEST(HeartprepErrors, PathsThatCannotBeOpenedAreOneClearLine) {
    // Inputs that exist but cannot be read as files, and outputs whose place cannot hold a file
    // (tests run as root in CI, so permissions would not stop anything: a folder where a file is
    // expected, a path through a regular file, an output folder that is a file). Each: exit 1, one
    // line "heartprep: error: …" naming the path and what is wrong, nothing written.
    test::TempDir dir;
    std::ofstream(dir / "file.txt") << "a regular file";
    fs::create_directory(dir / "folder.nii.gz");
    fs::create_directory(dir / "folder.h5");
    fs::create_directory(dir / "folder.csv");
    const std::string phantom = quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz");
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"build " + quoted(dir / "folder.nii.gz") + " -o " + quoted(dir / "a.h5") + " -q", "folder.nii.gz: is a folder"},
        {"build " + quoted(dir / "file.txt/x.nii.gz") + " -o " + quoted(dir / "a.h5") + " -q", "file.txt/x.nii.gz: file not found"},
        {"build " + phantom + " -o " + quoted(dir / "file.txt/a.h5") + " -q", "file.txt is a file, not a folder"},
        {"build " + phantom + " -o " + quoted(dir / "folder.h5") + " -q", "folder.h5: is a folder, expected a file name"},
        {"phantom --size 8 -o " + quoted(dir / "file.txt/p.nii.gz"), "file.txt is a file, not a folder"},
        {"phantom --size 8 -o " + quoted(dir / "folder.nii.gz"), "folder.nii.gz: is a folder, expected a file name"},
        {"inspect " + quoted(dir / "folder.h5"), "folder.h5: not a regular file"},
        {"batch " + quoted(dir / "file.txt/cases.csv") + " -o " + quoted(dir / "out"), "file.txt/cases.csv: file not found"},
        {"batch " + quoted(dir / "folder.csv") + " -o " + quoted(dir / "out"), "folder.csv: folder holds no label maps"},
    };
    const auto before = listing(dir.path());
    for (const auto& [arguments, message] : cases) {
        const auto run = test::run_command("(" + quoted(HEARTPREP_EXE) + " " + arguments + " 2>&1 >/dev/null)");
        EXPECT_EQ(run.exit_code, 1) << arguments << "\n" << run.output;
        EXPECT_EQ(run.output.rfind("heartprep: error: ", 0), 0u) << arguments << "\n" << run.output;
        EXPECT_EQ(std::count(run.output.begin(), run.output.end(), '\n'), 1) << arguments << "\n" << run.output;
        EXPECT_NE(run.output.find(message), std::string::npos) << "'" << message << "' not in: " << run.output;
    }
    EXPECT_EQ(listing(dir.path()), before) << "a refused command left files behind";
}
