// heartprep end to end, as a technician runs it: the binary, real files, exit codes, messages.
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/phantom.h"
#include "libmodel/sim/solver.h"
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
    for (const char* option : {"--tissue", "--cavity", "--anchor-label", "--labels", "--anchor-border", "--min-island", "--spacing",
                               "--particles", "--occupancy", "--smoothing", "--decimate", "--youngs-modulus"})
        EXPECT_NE(build.output.find(option), std::string::npos) << option;
}

TEST(Heartprep, BuildsThePhantomIntoAScenarioWhoseReportMatchesTheFile) {
    test::TempDir dir;
    ASSERT_EQ(heartprep("phantom -o " + quoted(dir / "phantom.nii.gz")).exit_code, 0);
    const auto run = heartprep("build " + quoted(dir / "phantom.nii.gz") + " -o " + quoted(dir / "p.h5") +
                               " --cavity 2 --anchor-border --particles 5000 --verbose");
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
    // The text says how many substeps heartsim's solver takes per step of dt: the solver's own count.
    ASSERT_TRUE(s.packing.has_value());
    const Solver solver(s.lattice, s.packing->neighbours, options_from(s.solver));
    const int substeps = solver.load_report().substeps;
    const auto text = heartprep("inspect " + quoted(dir / "p.h5"));
    EXPECT_NE(text.output.find(std::to_string(substeps) + (substeps == 1 ? " substep," : " substeps,")), std::string::npos)
        << "the solver takes " << substeps << "\n" << text.output;
    EXPECT_NE(inspect.output.find("\"substeps\": " + std::to_string(substeps)), std::string::npos) << inspect.output;
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
        // The line names the frame the file holds: a .glb is in glTF's metres, +Y up (it said LPS mm).
        EXPECT_NE(run.output.find(std::string(extension) == ".glb" ? "(glTF's frame, metres, +Y superior, +Z anterior)" : "(LPS mm)"),
                  std::string::npos) << run.output;
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
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --tissue=5", {"tissue label 5 does not occur"});
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
    // The ParaView description written beside the scenario: a folder there failed after the whole
    // build and left the .h5 without it; now refused before the build, leaving nothing.
    fs::create_directory(dir / "described.xmf2");
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "described.h5"),
                   {"described.xmf2: is a folder", "(the ParaView description written beside", "described.h5)"});
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
    EXPECT_EQ(heartprep("build").exit_code, 2);
    EXPECT_EQ(heartprep("frobnicate").exit_code, 2);
    const auto bad = heartprep("build x.nii.gz -o y.h5 --occupancy 2");
    EXPECT_EQ(bad.exit_code, 2);
    EXPECT_NE(bad.output.find("--occupancy"), std::string::npos) << bad.output;
    expect_refusal(dir, "inspect " + quoted(dir / "nothing.h5"), {"nothing.h5", "file not found"});
}

namespace {

/// heartprep `arguments` with stderr alone (stdout dropped): the exit status and the error text.
test::CommandResult heartprep_stderr(const std::string& arguments) {
    return test::run_command("(" + quoted(HEARTPREP_EXE) + " " + arguments + " 2>&1 >/dev/null)");
}

/// `output` is exactly one line that begins with `prefix`.
void expect_one_line(const test::CommandResult& run, const std::string& prefix, const std::string& arguments) {
    EXPECT_EQ(run.output.rfind(prefix, 0), 0u) << arguments << "\n" << run.output;
    EXPECT_EQ(std::count(run.output.begin(), run.output.end(), '\n'), 1) << arguments << "\n" << run.output;
}

}  // namespace

TEST(HeartprepExitStatus, EachCodeOfTheTableFromARealRun) {
    // docs/user-guide.md, "Exit status": 1 input, 2 usage (CLI11's own 104-114 never leak out),
    // 7 an output that cannot be written; each with one line "heartprep: error: …".
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");
    std::ofstream(dir / "file.txt") << "a regular file";
    std::ofstream(dir / "corrupt.nii.gz") << "not a label map";
    const std::string out = " -o " + quoted(dir / "out.h5");
    struct Case {
        std::string arguments;
        int exit_code;
        std::string mentions;
    };
    const std::vector<Case> cases = {
        {"build " + quoted(input) + out + " --frobnicate", 2, "--frobnicate"},                      // unknown option
        // A mistyped option: the words as typed, the nearest option, the command's own --help.
        {"build " + quoted(input) + out + " --smothing 0.3", 2,
         "not expected: --smothing 0.3 (--smothing: did you mean --smoothing?) (heartprep build --help lists the options)"},
        {"build " + quoted(input) + out + " --particels=3000", 2, "--particels: did you mean --particles?"},
        // An output named for another format: a scenario named .stl would mislead its next reader.
        {"build " + quoted(input) + " -o " + quoted(dir / "heart.stl"), 2, "heart.stl: a scenario is an HDF5 file"},
        {"pack " + quoted(input) + " -o " + quoted(dir / "packed.ply"), 2, "packed.ply: a scenario is an HDF5 file"},
        {"frobnicate", 2, "unknown command 'frobnicate'; the commands are build, surface"},         // unknown subcommand
        {"biuld " + quoted(input) + out, 2, "unknown command 'biuld' (did you mean 'build'?)"},      // a typo of one
        {"build " + quoted(input), 2, "--output"},                                                  // missing argument
        {"build " + quoted(input) + out + " --occupancy 2", 2, "--occupancy"},                      // out of range
        {"build " + quoted(input) + out + " --rest-state sideways", 2, "--rest-state"},             // not one of its values
        {"build " + quoted(input) + out + " --packing diagonal", 2, "--packing"},
        {"build " + quoted(input) + out + " --gravity 0 nan 0", 2, "--gravity"},
        {"build " + quoted(input) + out + " --drag nan", 2, "--drag"},                              // NaN passes CLI11's ranges
        {"build " + quoted(input) + out + " --dt-safety nan", 2, "--dt-safety: 'nan' is not a finite number"},
        {"build " + quoted(input) + out + " --spacing -1", 2, "--spacing: must lie in the plausible range [0.01, 100] mm, not -1"},
        // Physical values outside plausible.h's ranges are refused at once, naming the option and
        // the range: a spacing of 1e10 mm grabbed 16.8 GB before "out of memory", and the others
        // ended in NaN residuals or messages about supports, after the work.
        {"build " + quoted(input) + out + " --spacing 1e10", 2, "--spacing: must lie in the plausible range [0.01, 100] mm, not 1e10"},
        {"build " + quoted(input) + out + " --youngs-modulus 1e300", 2, "--youngs-modulus: must lie in the plausible range [0.001, 1e+06] kPa"},
        {"build " + quoted(input) + out + " --density 1e-30", 2, "--density: must lie in the plausible range [0.01, 50] g/cm³, not 1e-30"},
        {"build " + quoted(input) + out + " --damping-ratio 1e150", 2, "--damping-ratio: must lie in the plausible range [0, 100]"},
        {"build " + quoted(input) + out + " --support-damping 1e150", 2, "--support-damping: must lie in the plausible range [0, 100]"},
        {"build " + quoted(input) + out + " --drag 1e300", 2, "--drag: must lie in the plausible range [0, 100] 1/ms"},
        {"build " + quoted(input) + out + " --gravity 1e300 0 0", 2, "--gravity: its length is 1e+300 mm/ms², outside the plausible range [0, 1]"},
        {"build " + quoted(input) + out + " --drop-free-below -1", 2, "--drop-free-below"},
        // A scenario that heartsim would refuse is not written: read back before it takes its name.
        {"build " + quoted(input) + out + " -q --support-stiffness 1e30", 1, "the scenario would not be readable (particles/support_stiffness"},
        {"build " + quoted(input) + out + " --tissue=1 --cavity 1", 2, "both as tissue and as cavity"},  // contradictory
        {"surface " + quoted(input) + " -o " + quoted(dir / "heart.vtk"), 2, "unsupported mesh format"},
        {"export " + quoted(input) + " -o " + quoted(dir / "heart.vtk"), 2, "unsupported mesh format"},
        {"phantom -o " + quoted(dir / "p.nii.gz") + " --vsd-position 3", 2, "--vsd-position"},
        // A voxel no reader accepts: the write failed with a temporary file's name and NIfTI's pixdim.
        {"phantom -o " + quoted(dir / "p.nii.gz") + " --voxel 1e300", 2, "the voxel size is 1e+300 mm, outside the plausible range [0.001, 100] mm: change --voxel"},
        {"phantom -o " + quoted(dir / "p.vtk"), 2, "p.vtk: unsupported file type '.vtk'"},
        // A radius whose voxel count overflows int used to wrap to a 1×1×1 phantom and exit 0.
        {"phantom -o " + quoted(dir / "p.nii.gz") + " --shape sphere --radius 1e12", 2, "voxels is too large (at most 2e9): raise --voxel"},         // refused before it generates
        {"batch " + quoted(dir / "cases.csv") + " --pattern '*.nii.gz' -o " + quoted(dir / "batch"), 2, "--pattern chooses files of a folder"},
        {"batch " + quoted(dir / "cases.csv") + " -o " + quoted(dir / "batch") + " -j 0", 2, "--jobs"},
        {"build " + quoted(dir / "missing.nii.gz") + out, 1, "missing.nii.gz: file not found"},     // a missing file
        {"build " + quoted(dir / "corrupt.nii.gz") + out, 1, "corrupt.nii.gz: "},                   // a corrupt one
        {"build " + quoted(input) + out + " --visual-mesh " + quoted(dir / "nowhere.stl"), 1, "nowhere.stl: cannot read the mesh"},
        {"inspect " + quoted(input), 1, "block.nii.gz: "},                                          // not a scenario
        {"build " + quoted(input) + " -o " + quoted(dir / "file.txt/out.h5"), 7, "file.txt is a file, not a folder"},
        {"surface " + quoted(input) + " -o " + quoted(dir / "nowhere/heart.stl"), 7, "does not exist"},
        // export's place: a folder read as "unsupported mesh format ''", /proc as "disk full?" after the work.
        {"export " + quoted(input) + " -o " + quoted(dir / "file.txt/heart.stl"), 7, "file.txt is a file, not a folder"},
        {"batch " + quoted(input.parent_path()) + " -o " + quoted(dir / "file.txt/batch"), 7, "cannot create the output folder"},
    };
    const auto before = listing(dir.path());
    for (const auto& [arguments, exit_code, mentions] : cases) {
        const auto run = heartprep_stderr(arguments);
        EXPECT_EQ(run.exit_code, exit_code) << arguments << "\n" << run.output;
        expect_one_line(run, "heartprep: error: ", arguments);
        EXPECT_NE(run.output.find(mentions), std::string::npos) << "'" << mentions << "' not in: " << run.output;
    }
    EXPECT_EQ(listing(dir.path()), before) << "a refused command left files behind";
}

TEST(HeartprepExitStatus, ALibmodelErrorNamesTheInputFileOnce) {
    // select_tissue (libmodel, which opens no file) says "tissue label 3 does not occur in the
    // volume (labels present: 0,1)"; the build adds the file it was given, once.
    test::TempDir dir;
    const auto input = write_block(dir, "block.nii.gz");  // labels 0 and 1
    const auto run = heartprep_stderr("build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --tissue=3 -q");
    EXPECT_EQ(run.exit_code, 1) << run.output;
    EXPECT_EQ(run.output, "heartprep: error: " + input.string() + ": tissue label 3 does not occur in the volume (labels present: 0,1)\n");
    // A message that names its file already does not get it twice.
    std::ofstream(dir / "cut.nii.gz") << "not gzip";
    const auto cut = heartprep_stderr("build " + quoted(dir / "cut.nii.gz") + " -o " + quoted(dir / "out.h5"));
    EXPECT_EQ(cut.exit_code, 1) << cut.output;
    const std::string named = (dir / "cut.nii.gz").string() + ": ";
    EXPECT_EQ(cut.output.rfind("heartprep: error: " + named, 0), 0u) << cut.output;
    EXPECT_EQ(cut.output.find(named + named), std::string::npos) << cut.output;
    EXPECT_FALSE(fs::exists(dir / "out.h5"));
}

TEST(HeartprepExitStatus, BatchExitsOneForAFailedCaseAndSaysWhenItPassedABadOption) {
    test::TempDir dir;
    write_block(dir, "block.nii.gz");
    // A case whose options the build refuses (exit 2 of the build): the case fails, the summary says
    // the options were refused, and the batch exits 1.
    std::ofstream(dir / "cases.csv") << "block.nii.gz,bad,--occupancy 7\n";
    const auto run = heartprep("batch " + quoted(dir / "cases.csv") + " -o " + quoted(dir / "out"));
    EXPECT_EQ(run.exit_code, 1) << run.output;
    EXPECT_NE(run.output.find("bad: failed: heartprep build refused the options (--occupancy 7"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("--occupancy"), std::string::npos) << run.output;
    EXPECT_FALSE(fs::exists(dir / "out" / "bad.h5"));
}

TEST(HeartprepExitStatus, HelpEndsWithTheTable) {
    for (const char* arguments : {"--help", "build --help", "batch --help"}) {
        const auto help = heartprep(arguments);
        EXPECT_EQ(help.exit_code, 0) << arguments;
        EXPECT_NE(help.output.find("Exit status: 0 success, 1 input error"), std::string::npos) << arguments << "\n" << help.output;
    }
}

// -------------------------------------------------------------------------------------------
// Real HVSMR 2016 cases, from ../shared/data/real (skipped with a message when absent).

class RealCase : public ::testing::TestWithParam<std::string> {};

TEST_P(RealCase, BuildsWithAClosedSurfaceAndParticlesInTissue) {
    const auto input = test::real_case(GetParam());
    if (input.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    test::TempDir dir;
    // The labelled myocardium alone (--walls labelled): the layout's occupancy on the label map's own tissue.
    const auto run = heartprep("build " + quoted(input) + " -o " + quoted(dir / "case.h5") + " --cavity 2 --anchor-border --verbose --walls labelled");
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
    // EFBIG as on a full disk): one clear message naming the file, exit 7, not a crash in HDF5's
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
    EXPECT_EQ(run.exit_code, 7) << run.output;  // an output that could not be written (docs/user-guide.md, "Exit status")
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
    // every limit below that ends with exit 7 and the one line "out of memory while running stage
    // '…'", whether an allocation failed, a worker thread could not start (oneTBB's
    // "pthread_create has failed") or HDF5 could not build the file in memory (it said "cannot
    // create the file in memory"); never a signal or a hang; and no output or temporary file is left.
    if (test::under_address_sanitizer) GTEST_SKIP() << "address-space limits do not work under AddressSanitizer";
    test::TempDir dir;
    test::expect_clean_out_of_memory(test::quoted(HEARTPREP_EXE) + " build " +
                                         test::quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz") + " -o " +
                                         test::quoted(dir / "out.h5") + " -q",
                                     "heartprep: error: out of memory while ");
    // The last run succeeded and wrote out.h5 and its out.xmf2; the failed ones left nothing else.
    EXPECT_EQ(listing(dir.path()), (std::set<std::string>{"out.h5", "out.xmf2"}));
}

TEST(HeartprepErrors, PathsThatCannotBeOpenedAreOneClearLine) {
    // Inputs that exist but cannot be read as files, and outputs whose place cannot hold a file
    // (tests run as root in CI, so permissions would not stop anything: a folder where a file is
    // expected, a path through a regular file, an output folder that is a file). Each: one line
    // "heartprep: error: …" naming the path and what is wrong, nothing written; exit 1 for an input,
    // 7 for an output (docs/user-guide.md, "Exit status").
    test::TempDir dir;
    std::ofstream(dir / "file.txt") << "a regular file";
    fs::create_directory(dir / "folder.nii.gz");
    fs::create_directory(dir / "folder.h5");
    fs::create_directory(dir / "folder.csv");
    const std::string phantom = quoted(fs::path(HEARTSIM_SOURCE_DIR) / "samples/phantom.nii.gz");
    struct Case {
        std::string arguments, message;
        int exit_code;
    };
    const std::vector<Case> cases = {
        {"build " + quoted(dir / "folder.nii.gz") + " -o " + quoted(dir / "a.h5") + " -q", "folder.nii.gz: is a folder", 1},
        {"build " + quoted(dir / "file.txt/x.nii.gz") + " -o " + quoted(dir / "a.h5") + " -q", "file.txt/x.nii.gz: file not found", 1},
        {"build " + phantom + " -o " + quoted(dir / "file.txt/a.h5") + " -q", "file.txt is a file, not a folder", 7},
        {"build " + phantom + " -o " + quoted(dir / "folder.h5") + " -q", "folder.h5: is a folder, expected a file name", 7},
        {"phantom --size 8 -o " + quoted(dir / "file.txt/p.nii.gz"), "file.txt is a file, not a folder", 7},
        {"phantom --size 8 -o " + quoted(dir / "folder.nii.gz"), "folder.nii.gz: is a folder, expected a file name", 7},
        {"inspect " + quoted(dir / "folder.h5"), "folder.h5: not a regular file", 1},
        {"batch " + quoted(dir / "file.txt/cases.csv") + " -o " + quoted(dir / "out"), "file.txt/cases.csv: file not found", 1},
        {"batch " + quoted(dir / "folder.csv") + " -o " + quoted(dir / "out"), "folder.csv: folder holds no label maps", 1},
    };
    const auto before = listing(dir.path());
    for (const auto& [arguments, message, exit_code] : cases) {
        const auto run = test::run_command("(" + quoted(HEARTPREP_EXE) + " " + arguments + " 2>&1 >/dev/null)");
        EXPECT_EQ(run.exit_code, exit_code) << arguments << "\n" << run.output;
        EXPECT_EQ(run.output.rfind("heartprep: error: ", 0), 0u) << arguments << "\n" << run.output;
        EXPECT_EQ(std::count(run.output.begin(), run.output.end(), '\n'), 1) << arguments << "\n" << run.output;
        EXPECT_NE(run.output.find(message), std::string::npos) << "'" << message << "' not in: " << run.output;
    }
    EXPECT_EQ(listing(dir.path()), before) << "a refused command left files behind";
}

// -------------------------------------------------------------------------------------------
// Segment names: 3D Slicer's .seg.nrrd carries them; a label table (--labels) names a NIfTI's.

namespace {

/// A label map with two disjoint blocks on 1 mm voxels: label 1 a 6×6×6 block, label 2 a
/// 10×8×6 block, both on even voxel indices so a 2 mm lattice covers them with full cells.
LabelVolume two_blocks() {
    LabelVolume v;
    v.geometry.dims = {28, 16, 16};
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = 4; k < 10; ++k)
        for (int j = 4; j < 10; ++j)
            for (int i = 2; i < 8; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    for (int k = 4; k < 10; ++k)
        for (int j = 4; j < 12; ++j)
            for (int i = 14; i < 24; ++i) v.labels[v.geometry.linear(i, j, k)] = 2;
    return v;
}

double total_mass(const Scenario& s) {
    double mass = 0.0;
    for (float m : s.lattice.particles.mass) mass += m;
    return mass;
}

/// Builds `input` with `options` into `output`; returns heartprep's output (the test fails on a
/// non-zero exit).
std::string build(const fs::path& input, const fs::path& output, const std::string& options) {
    const auto run = heartprep("build " + quoted(input) + " -o " + quoted(output) + " --spacing 2 --thin-walls keep --verbose " + options);
    EXPECT_EQ(run.exit_code, 0) << run.output;
    return run.output;
}

bool has_warning(const Scenario& s, const std::string& part) {
    if (!s.build_warnings) return false;
    return std::any_of(s.build_warnings->begin(), s.build_warnings->end(),
                       [&](const std::string& w) { return w.find(part) != std::string::npos; });
}

}  // namespace

TEST(HeartprepNames, TissueByNameBuildsThatSegmentAndNamesTheMaterial) {
    test::TempDir dir;
    const fs::path input = dir / "named.seg.nrrd";
    write_label_volume(input, two_blocks(), {{1, "blood pool"}, {2, "myocardium"}});
    const std::string by_name = build(input, dir / "by-name.h5", "--tissue MyoCardium");
    build(input, dir / "by-number.h5", "--tissue=2");
    const Scenario named = read_scenario(dir / "by-name.h5"), numbered = read_scenario(dir / "by-number.h5");
    // The same segment: the same particles, and the mass of the 10×8×6 mm³ block at 1.06 g/cm³.
    EXPECT_EQ(named.lattice.particles.rest_position, numbered.lattice.particles.rest_position);
    EXPECT_NEAR(total_mass(named), 480.0 * 1.06e-3, 1e-6);
    EXPECT_EQ(named.source.tissue_labels, std::vector<int>{2});
    ASSERT_EQ(named.lattice.materials.size(), 1u);
    EXPECT_EQ(named.lattice.materials[0].label, 2);
    EXPECT_EQ(named.lattice.materials[0].name, "myocardium");
    EXPECT_EQ(numbered.lattice.materials[0].name, "myocardium");  // a number finds the name too
    EXPECT_NE(by_name.find("tissue      label 2 'myocardium': 480 voxels"), std::string::npos) << by_name;
    EXPECT_FALSE(has_warning(named, "heart muscle")) << "myocardium is heart muscle";
    const auto inspect = heartprep("inspect " + quoted(dir / "by-name.h5"));
    EXPECT_NE(inspect.output.find("material    2 myocardium"), std::string::npos) << inspect.output;
}

TEST(HeartprepNames, BloodPoolAsTissueWarns) {
    test::TempDir dir;
    const fs::path input = dir / "named.seg.nrrd";
    write_label_volume(input, two_blocks(), {{1, "blood pool"}, {2, "myocardium"}});
    const std::string output = build(input, dir / "pool.h5", "--tissue 'blood pool'");
    const Scenario pool = read_scenario(dir / "pool.h5");
    EXPECT_NEAR(total_mass(pool), 216.0 * 1.06e-3, 1e-6);
    EXPECT_EQ(pool.lattice.materials[0].name, "blood pool");
    const std::string warning = "tissue label 1 'blood pool' is not heart muscle by its name";
    EXPECT_TRUE(has_warning(pool, warning));
    EXPECT_TRUE(has_warning(pool, "the heart muscle is segment 2 'myocardium'"));
    EXPECT_NE(output.find("heartprep: warning: " + warning), std::string::npos) << output;
}

TEST(HeartprepNames, DefaultTissuePrefersTheSegmentNamedMyocardiumOverABloodPoolLabelOne) {
    test::TempDir dir;
    const fs::path input = dir / "named.seg.nrrd";
    write_label_volume(input, two_blocks(), {{1, "blood pool"}, {2, "myocardium"}});
    build(input, dir / "default.h5", "");
    const Scenario built = read_scenario(dir / "default.h5");
    EXPECT_EQ(built.source.tissue_labels, std::vector<int>{2});
    EXPECT_NEAR(total_mass(built), 480.0 * 1.06e-3, 1e-6);
    EXPECT_TRUE(has_warning(built, "no --tissue given: label 1 'blood pool' is not heart muscle"));
    // Without names (HVSMR's files), label 1 as always, and no word about names.
    write_label_volume(dir / "unnamed.nii.gz", two_blocks());
    build(dir / "unnamed.nii.gz", dir / "unnamed.h5", "");
    const Scenario unnamed = read_scenario(dir / "unnamed.h5");
    EXPECT_EQ(unnamed.source.tissue_labels, std::vector<int>{1});
    EXPECT_EQ(unnamed.lattice.materials[0].name, "myocardium");
    EXPECT_FALSE(has_warning(unnamed, "--tissue"));
}

TEST(HeartprepNames, UnknownNameIsAnErrorListingTheSegments) {
    test::TempDir dir;
    const fs::path input = dir / "named.seg.nrrd";
    write_label_volume(input, two_blocks(), {{1, "blood pool"}, {2, "myocardium"}});
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --tissue aorta",
                   {"named.seg.nrrd", "--tissue 'aorta' names no segment", "segments: 1 'blood pool', 2 'myocardium'"});
    write_label_volume(dir / "unnamed.nii", two_blocks());
    expect_refusal(dir, "build " + quoted(dir / "unnamed.nii") + " -o " + quoted(dir / "out.h5") + " --tissue myocardium",
                   {"unnamed.nii", "names no segments", "--labels"});
}

TEST(HeartprepNames, LabelTablesNameANiftisLabels) {
    test::TempDir dir;
    const fs::path input = dir / "case.nii.gz";
    write_label_volume(input, two_blocks());
    build(input, dir / "by-number.h5", "--tissue=2");
    std::ofstream(dir / "itksnap.txt") << "# ITK-SNAP Label Description File\n"
                                          "    0     0    0    0        0  0  0    \"Clear Label\"\n"
                                          "    1   255    0    0        1  1  1    \"Blood pool\"\n"
                                          "    2     0  255    0        1  1  1    \"LV myocardium\"\n";
    std::ofstream(dir / "slicer.ctbl") << "# Color table file\n0 Background 0 0 0 0\n1 blood_pool 255 0 0 255\n2 Myocardium 0 255 0 255\n";
    std::ofstream(dir / "slicer.csv") << "LabelValue,Name,Color_R,Color_G,Color_B,Color_A\n1,blood pool,255,0,0,255\n2,myocardium,0,255,0,255\n";
    const Scenario reference = read_scenario(dir / "by-number.h5");
    for (const auto& [table, name] : std::vector<std::pair<std::string, std::string>>{
             {"itksnap.txt", "'lv myocardium'"}, {"slicer.ctbl", "myocardium"}, {"slicer.csv", "myocardium"}}) {
        build(input, dir / "named.h5", "--labels " + quoted(dir / table) + " --tissue " + name);
        const Scenario named = read_scenario(dir / "named.h5");
        EXPECT_EQ(named.lattice.particles.rest_position, reference.lattice.particles.rest_position) << table;
        EXPECT_EQ(named.lattice.materials[0].label, 2) << table;
        EXPECT_NE(named.lattice.materials[0].name.find("yocardium"), std::string::npos) << table;
    }
    // The colour table's blood_pool is "blood pool"; the cavity can be named too.
    build(input, dir / "pool.h5", "--labels " + quoted(dir / "slicer.ctbl") + " --tissue myocardium --cavity 'Blood Pool'");
    EXPECT_EQ(read_scenario(dir / "pool.h5").source.cavity_labels, std::vector<int>{1});
    std::ofstream(dir / "bad.txt") << "1 blood_pool 255 0 0 255\nnot a label line\n";
    expect_refusal(dir, "build " + quoted(input) + " -o " + quoted(dir / "out.h5") + " --labels " + quoted(dir / "bad.txt"),
                   {"bad.txt", "line 2", "expected"});
}

// -------------------------------------------------------------------------------------------
// A NIfTI whose qform and sform disagree: the build says so, on stderr and in /build_warnings.

TEST(HeartprepNifti, DisagreeingQformAndSformWarnThroughTheBuild) {
    test::TempDir dir;
    test::HandNifti nifti({16, 16, 16}, 2 /*uint8*/, 8);
    Eigen::Matrix<float, 3, 4> srow;
    srow.leftCols<3>() = Eigen::AngleAxisf(25.0f * float(M_PI) / 180.0f, Eigen::Vector3f::UnitZ()).toRotationMatrix();
    srow.col(3) = Eigen::Vector3f(20.0f, 0.0f, 0.0f);
    nifti.set_sform(srow);
    nifti.set_sform_code(2);
    nifti.set_qform(1, Eigen::Vector3f::Zero(), Eigen::Vector3f::Zero());
    std::vector<std::uint8_t> voxels(16 * 16 * 16, 0);
    for (int k = 4; k < 12; ++k)
        for (int j = 4; j < 12; ++j)
            for (int i = 4; i < 12; ++i) voxels[std::size_t((k * 16 + j) * 16 + i)] = 1;
    nifti.append_voxels(voxels);
    test::write_bytes(dir / "two-transforms.nii", nifti.bytes);
    const std::string output = build(dir / "two-transforms.nii", dir / "out.h5", "");
    const Scenario built = read_scenario(dir / "out.h5");
    EXPECT_TRUE(has_warning(built, "two-transforms.nii: the NIfTI qform (code 1, scanner anatomy) and sform (code 2, aligned anatomy) disagree"));
    EXPECT_TRUE(has_warning(built, "20.00 mm apart at the first voxel, 25.00° apart"));
    EXPECT_NE(output.find("heartprep: warning: " + dir.path().string() + "/two-transforms.nii: the NIfTI qform"), std::string::npos)
        << output;
    // -q silences the summary, not the warning.
    const std::string quiet = build(dir / "two-transforms.nii", dir / "quiet.h5", "-q");
    EXPECT_NE(quiet.find("heartprep: warning: " + dir.path().string() + "/two-transforms.nii: the NIfTI qform"), std::string::npos)
        << quiet;
    EXPECT_EQ(quiet.find("wrote "), std::string::npos) << quiet;
    // The qform is the identity: the particles lie on the block's voxels, LPS = (−x, −y, z) of RAS.
    for (const auto& p : built.lattice.particles.rest_position) {
        EXPECT_LE(p[0], -3.0f);
        EXPECT_GE(p[0], -12.0f);
    }
}

TEST(HeartprepWrongInput, AnIntensityImageWarnsOfItsValuesAndPiecesAndStrictRefusesIt) {
    // An 8-bit "image": noise of every byte value, and a ball of value 1 that builds.
    test::TempDir dir;
    LabelVolume image;
    image.geometry.dims = {90, 90, 90};
    image.geometry.spacing = Eigen::Vector3d::Constant(0.8);
    image.labels.resize(image.geometry.voxel_count());
    std::uint32_t state = 12345;
    for (auto& value : image.labels) {
        state = state * 1664525u + 1013904223u;  // a fixed linear congruential sequence
        value = std::int32_t(state >> 24);
    }
    for (int k = 0; k < 90; ++k)
        for (int j = 0; j < 90; ++j)
            for (int i = 0; i < 90; ++i)
                if ((Eigen::Vector3d(i, j, k) - Eigen::Vector3d::Constant(45)).norm() < 20) image.labels[image.geometry.linear(i, j, k)] = 1;
    const fs::path input = dir / "image.nii.gz";
    write_label_volume(input, image);
    const auto run = heartprep("build " + quoted(input) + " -o " + quoted(dir / "image.h5") + " -q --particles 2000");
    EXPECT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("holds 255 different values"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("is it an intensity image"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("separate pieces"), std::string::npos) << run.output;
    const auto strict = heartprep("build " + quoted(input) + " -o " + quoted(dir / "strict.h5") + " -q --particles 2000 --strict");
    EXPECT_EQ(strict.exit_code, 1) << strict.output;
    EXPECT_NE(strict.output.find("--strict"), std::string::npos) << strict.output;
    EXPECT_FALSE(fs::exists(dir / "strict.h5"));
}

TEST(HeartprepWrongInput, TheBloodPoolOfAnHvsmrHeartAsTissueWarnsByTheConventionsNames) {
    const fs::path input = test::real_case("hvsmr16_pat1");
    if (input.empty()) GTEST_SKIP() << "real case hvsmr16_pat1 absent";
    test::TempDir dir;
    const auto pool = heartprep("build " + quoted(input) + " --tissue=2 -q -o " + quoted(dir / "pool.h5"));
    EXPECT_EQ(pool.exit_code, 0) << pool.output;
    EXPECT_NE(pool.output.find("by HVSMR 2016's labels, which this volume's match (--labels hvsmr2016): tissue label 2 'blood pool' is "
                               "not heart muscle"),
              std::string::npos)
        << pool.output;
    // The myocardium builds without a warning, so --strict lets it through.
    const auto muscle = heartprep("build " + quoted(input) + " -q --strict -o " + quoted(dir / "muscle.h5"));
    EXPECT_EQ(muscle.exit_code, 0) << muscle.output;
    EXPECT_EQ(muscle.output.find("warning"), std::string::npos) << muscle.output;
}

// The technician's summary: what was built, from the file's own figures; fit for simulation; the
// next commands with the file's own name. One tissue volume: the summary's, inspect's and the
// file's are the label map's tissue voxels.
TEST(Heartprep, ThePlainSummarySaysWhatWasBuiltWhetherItIsFitAndWhatToRunNext) {
    test::TempDir dir;
    ASSERT_EQ(heartprep("phantom -o " + quoted(dir / "phantom.nii.gz")).exit_code, 0);
    const auto run = heartprep("build " + quoted(dir / "phantom.nii.gz") + " -o " + quoted(dir / "p.h5") + " --particles 5000");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario s = read_scenario(dir / "p.h5");
    const LabelVolume volume = read_label_volume(dir / "phantom.nii.gz");
    std::size_t tissue = 0;
    for (auto label : volume.labels) tissue += label == 1;
    // The phantom has no islands: its tissue volume is its label-1 voxels'.
    EXPECT_NEAR(s.source.tissue_volume_mm3, double(tissue) * volume.geometry.voxel_volume(), 1e-6);
    char mL[32];
    std::snprintf(mL, sizeof mL, "%.1f mL", s.source.tissue_volume_mm3 / 1000.0);
    std::smatch m;
    ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"(^built +a heart of ([0-9.]+ mL) of tissue .*: ([0-9,]+) particles)",
                                                            std::regex::multiline)))
        << run.output;
    EXPECT_EQ(m[1].str(), mL);
    std::string particles = m[2].str();
    particles.erase(std::remove(particles.begin(), particles.end(), ','), particles.end());
    EXPECT_EQ(std::stoul(particles), s.lattice.particles.size());
    EXPECT_NE(run.output.find("fit         ready to simulate"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("next        heartsim " + (dir / "p.h5").string()), std::string::npos) << run.output;
    EXPECT_EQ(run.output.find("Lanczos"), std::string::npos) << "the expert figures are --verbose's\n" << run.output;
    const auto inspect = heartprep("inspect " + quoted(dir / "p.h5"));
    EXPECT_NE(inspect.output.find(std::string("tissue      ") + mL), std::string::npos) << inspect.output;
}
