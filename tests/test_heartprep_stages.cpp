// heartprep's stage commands on scenario files, and batch conversion, run as a technician would.
#include "formats/mesh_io.h"
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/mesh.h"
#include "libmodel/phantom.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <fstream>
#include <regex>

using namespace heartsim;
using test::heartprep;
using test::quoted;
namespace fs = std::filesystem;

namespace {

/// A small heart phantom (2 mm voxels) written as NIfTI: fast to build.
fs::path small_phantom(const test::TempDir& dir, const std::string& name, double vsd = 8.0) {
    PhantomOptions options;
    options.voxel_mm = 1.5;
    options.vsd_diameter_mm = vsd;
    write_label_volume(dir / name, make_phantom(options));
    return dir / name;
}

fs::path built(const test::TempDir& dir, const std::string& name) {
    const auto input = small_phantom(dir, name + ".nii.gz");
    const auto output = dir / (name + ".h5");
    const auto run = heartprep("build " + quoted(input) + " -o " + quoted(output) + " --particles 4000 --anchor-border -q");
    EXPECT_EQ(run.exit_code, 0) << run.output;
    return output;
}

}  // namespace

TEST(HeartprepStages, BuildWritesEveryGroupOfTheContract) {
    test::TempDir dir;
    const Scenario s = read_scenario(built(dir, "heart"));  // the reader validates every group
    ASSERT_TRUE(s.packing && s.simulation_surface && s.visual && s.mapping);
    EXPECT_EQ(s.packing->neighbours.size(), s.lattice.particles.size());
    EXPECT_EQ(s.simulation_surface->normal_weight.size(), s.simulation_surface->triangles.size());
    EXPECT_EQ(s.mapping->triangle.size(), s.visual->positions.size());
}

TEST(HeartprepStages, PackRewritesTheLayoutAndKeepsTheFileValid) {
    test::TempDir dir;
    const auto file = built(dir, "heart");
    const Scenario before = read_scenario(file);
    const auto run = heartprep("pack " + quoted(file) + " --packing slices -o " + quoted(dir / "slices.h5"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario after = read_scenario(dir / "slices.h5");  // neighbours symmetric, springs consistent
    ASSERT_TRUE(after.packing);
    EXPECT_EQ(after.packing->scheme, PackingScheme::slices);
    EXPECT_EQ(after.lattice.particles.size(), before.lattice.particles.size());
    // The simulation surface followed the particles: same rest-position triangles as before.
    ASSERT_TRUE(after.simulation_surface && before.simulation_surface);
    ASSERT_EQ(after.simulation_surface->size(), before.simulation_surface->size());
    auto corners = [](const Scenario& s, std::size_t t) {
        std::array<std::array<float, 3>, 3> c;
        for (int k = 0; k < 3; ++k) c[std::size_t(k)] = s.lattice.particles.rest_position[std::size_t(s.simulation_surface->triangles[t][std::size_t(k)])];
        return c;
    };
    for (std::size_t t = 0; t < after.simulation_surface->size(); t += 97) EXPECT_EQ(corners(after, t), corners(before, t));
    // The normal weights stay with their triangles (rows are not reordered by packing).
    EXPECT_EQ(after.simulation_surface->normal_weight, before.simulation_surface->normal_weight);
    // And the mapping still reproduces the visual mesh: inspect evaluates it.
    const auto inspect = heartprep("inspect --json " + quoted(dir / "slices.h5"));
    std::smatch m;
    ASSERT_TRUE(std::regex_search(inspect.output, m, std::regex(R"("mapping_rest_error_mm": ([0-9.e+-]+))"))) << inspect.output;
    EXPECT_LT(std::stod(m[1]), 1e-4);
}

TEST(HeartprepStages, ExportedMeshesReadBackClosed) {
    test::TempDir dir;
    const auto file = built(dir, "heart");
    for (const char* what : {"simsurface", "visual"})
        for (const char* extension : {".ply", ".stl", ".glb"}) {
            const auto out = dir / (std::string(what) + extension);
            const auto run = heartprep("export " + quoted(file) + " --what " + what + " -o " + quoted(out));
            ASSERT_EQ(run.exit_code, 0) << run.output;
            EXPECT_NE(run.output.find("LPS"), std::string::npos);
            const MeshReport report = analyse_mesh(read_mesh(out));  // assimp, as MeshLab-style readers do
            EXPECT_TRUE(report.closed()) << what << extension << ": " << report.boundary_edges << " boundary edges";
        }
}

TEST(HeartprepStages, MapWithAnExternalVisualMesh) {
    test::TempDir dir;
    const auto file = built(dir, "heart");
    ASSERT_EQ(heartprep("export " + quoted(file) + " --what visual -o " + quoted(dir / "visual.stl")).exit_code, 0);
    const auto run = heartprep("map " + quoted(file) + " --visual-mesh " + quoted(dir / "visual.stl"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Scenario s = read_scenario(file);
    ASSERT_TRUE(s.mapping);
    EXPECT_EQ(s.mapping->triangle.size(), s.visual->positions.size());
}

TEST(HeartprepStages, BadVisualMeshes) {
    test::TempDir dir;
    const auto file = built(dir, "heart");
    // No triangles.
    std::ofstream(dir / "empty.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    auto run = heartprep("map " + quoted(file) + " --visual-mesh " + quoted(dir / "empty.obj"));
    EXPECT_NE(run.exit_code, 0);
    EXPECT_NE(run.output.find("empty.obj"), std::string::npos) << run.output;
    // Non-manifold: three triangles on one edge. Mapped, with a warning that says so.
    std::ofstream(dir / "fin.obj") << "v 0 0 0\nv 10 0 0\nv 5 8 0\nv 5 -8 0\nv 5 0 8\nf 1 2 3\nf 2 1 4\nf 1 2 5\n";
    run = heartprep("map " + quoted(file) + " --visual-mesh " + quoted(dir / "fin.obj") + " -o " + quoted(dir / "fin.h5"));
    EXPECT_NE(run.output.find("not a closed 2-manifold"), std::string::npos) << run.output;
    // Far from the tissue: a small triangle 500 mm away.
    std::ofstream(dir / "far.obj") << "v 500 500 500\nv 510 500 500\nv 500 510 500\nf 1 2 3\n";
    run = heartprep("map " + quoted(file) + " --visual-mesh " + quoted(dir / "far.obj") + " -o " + quoted(dir / "far.h5"));
    EXPECT_NE(run.output.find("far"), std::string::npos) << run.output;
}

TEST(HeartprepBatch, ThreeGoodOneBrokenThenResume) {
    test::TempDir dir;
    small_phantom(dir, "a.nii.gz");
    small_phantom(dir, "b.nii.gz", 0.0);
    small_phantom(dir, "c.nii.gz", 5.0);
    std::ofstream(dir / "broken.nii.gz") << "this is not a volume";
    std::ofstream(dir / "cases.csv") << "input,case_id,options\n"
                                        "a.nii.gz,case_a,\n"
                                        "b.nii.gz,case_b,--particles 3000\n"
                                        "c.nii.gz,case_c,\n"
                                        "broken.nii.gz,case_broken,\n";
    const std::string command = "batch " + quoted(dir / "cases.csv") + " -o " + quoted(dir / "out") +
                                " -j 2 --options '--particles 2000 --anchor-border'";
    auto first = heartprep(command);
    EXPECT_EQ(first.exit_code, 1) << first.output;  // a case failed (docs/user-guide.md, "Exit status")
    for (const char* id : {"case_a", "case_b", "case_c"}) {
        EXPECT_TRUE(fs::exists(dir / "out" / (std::string(id) + ".h5"))) << id;
        EXPECT_NE(first.output.find(std::string("| ") + id + " | built |"), std::string::npos) << first.output;
    }
    EXPECT_FALSE(fs::exists(dir / "out" / "case_broken.h5"));
    EXPECT_NE(first.output.find("case_broken: failed: "), std::string::npos) << first.output;
    EXPECT_NE(first.output.find("broken.nii.gz"), std::string::npos);
    EXPECT_TRUE(fs::exists(dir / "out" / "summary.csv"));
    EXPECT_TRUE(fs::exists(dir / "out" / "summary.md"));
    // Per-case options replace the batch options.
    EXPECT_LE(read_scenario(dir / "out" / "case_a.h5").lattice.particles.size(), 2000u);
    EXPECT_GT(read_scenario(dir / "out" / "case_b.h5").lattice.particles.size(), 2000u);

    auto second = heartprep(command);
    EXPECT_EQ(second.exit_code, 1);
    for (const char* id : {"case_a", "case_b", "case_c"})
        EXPECT_NE(second.output.find(std::string("| ") + id + " | skipped |"), std::string::npos) << second.output;

    // A changed input is built again.
    small_phantom(dir, "a.nii.gz", 3.0);
    auto third = heartprep(command);
    EXPECT_NE(third.output.find("| case_a | built |"), std::string::npos) << third.output;
    EXPECT_NE(third.output.find("| case_b | skipped |"), std::string::npos) << third.output;
}

TEST(HeartprepBatch, ASkippedCaseReportsTheWarningsOfTheBuildThatWroteIt) {
    test::TempDir dir;
    small_phantom(dir, "a.nii.gz");
    // --rest-state imaged warns that the heart sags when the simulation starts.
    fs::create_directory(dir / "in");
    fs::rename(dir / "a.nii.gz", dir / "in" / "a.nii.gz");
    const std::string batch = "batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") +
                              " --options '--particles 2000 --anchor-border --rest-state imaged'";
    auto summary_row = [&] {
        std::ifstream in(dir / "out" / "summary.csv");
        std::string line, row;
        while (std::getline(in, line))
            if (line.rfind("\"a\",", 0) == 0) row = line;
        return row;
    };
    const std::string warning = "--rest-state imaged: the springs are unstressed at the imaged shape";
    const auto first = heartprep(batch);
    ASSERT_EQ(first.exit_code, 0) << first.output;
    EXPECT_NE(summary_row().find(",built,"), std::string::npos) << summary_row();
    EXPECT_NE(summary_row().find(warning), std::string::npos) << summary_row();
    // The scenario keeps them, exactly the warnings its build printed (and inspect shows them).
    const Scenario built = read_scenario(dir / "out" / "a.h5");
    ASSERT_TRUE(built.build_warnings.has_value());
    std::vector<std::string> printed;
    {
        std::ifstream log(dir / "out" / "logs" / "a.log");
        for (std::string line; std::getline(log, line);)
            if (line.rfind("heartprep: warning: ", 0) == 0) printed.push_back(line.substr(20));
    }
    EXPECT_EQ(*built.build_warnings, printed);
    ASSERT_FALSE(built.build_warnings->empty());
    EXPECT_EQ(built.build_warnings->front().rfind(warning, 0), 0u) << built.build_warnings->front();
    const auto inspect = heartprep("inspect " + quoted(dir / "out" / "a.h5"));
    EXPECT_NE(inspect.output.find("warnings    " + warning), std::string::npos) << inspect.output;

    const auto second = heartprep(batch);
    ASSERT_EQ(second.exit_code, 0) << second.output;
    EXPECT_NE(summary_row().find(",skipped,"), std::string::npos) << summary_row();
    EXPECT_NE(summary_row().find(warning), std::string::npos) << "a reused case lost its warnings: " << summary_row();
    EXPECT_NE(second.output.find("| a | skipped |"), std::string::npos) << second.output;
    EXPECT_NE(second.output.find(warning), std::string::npos) << second.output;

    // A scenario from before the warnings were kept (no /build_warnings) is built again, so the
    // summary never reports "no warnings" for a case whose warnings are unknown.
    Scenario old = read_scenario(dir / "out" / "a.h5");
    old.build_warnings.reset();
    write_scenario(dir / "out" / "a.h5", old);
    EXPECT_FALSE(read_scenario(dir / "out" / "a.h5").build_warnings.has_value());
    EXPECT_NE(heartprep("inspect " + quoted(dir / "out" / "a.h5")).output.find("warnings    not stored"), std::string::npos);
    const auto third = heartprep(batch);
    ASSERT_EQ(third.exit_code, 0) << third.output;
    EXPECT_NE(summary_row().find(",built,"), std::string::npos) << summary_row();
    EXPECT_NE(summary_row().find(warning), std::string::npos) << summary_row();
}

TEST(HeartprepBatch, ManifestErrors) {
    test::TempDir dir;
    small_phantom(dir, "a.nii.gz");
    std::ofstream(dir / "duplicate.csv") << "a.nii.gz,same\na.nii.gz,same\n";
    auto run = heartprep("batch " + quoted(dir / "duplicate.csv") + " -o " + quoted(dir / "out"));
    EXPECT_EQ(run.exit_code, 1);
    EXPECT_NE(run.output.find("duplicate case id 'same' on lines 1 and 2"), std::string::npos) << run.output;
    EXPECT_FALSE(fs::exists(dir / "out"));

    std::ofstream(dir / "missing.csv") << "a.nii.gz,good\nnowhere.nii.gz,lost\n";
    run = heartprep("batch " + quoted(dir / "missing.csv") + " -o " + quoted(dir / "out2"));
    EXPECT_EQ(run.exit_code, 1);
    EXPECT_NE(run.output.find("lost: failed: "), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("nowhere.nii.gz: file not found"), std::string::npos) << run.output;
    EXPECT_TRUE(fs::exists(dir / "out2" / "good.h5"));

    run = heartprep("batch " + quoted(dir / "absent.csv") + " -o " + quoted(dir / "out3"));
    EXPECT_EQ(run.exit_code, 1);
    EXPECT_NE(run.output.find("absent.csv: file not found"), std::string::npos) << run.output;
}

TEST(HeartprepBatch, FolderOfRealCases) {
    const auto root = test::real_data_dir();
    if (root.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    test::TempDir dir;
    for (const char* name : {"hvsmr16_pat0", "hvsmr16_pat1", "hvsmr16_pat5", "hvsmr16_pat6"})
        fs::create_symlink(test::real_case(name), dir / (std::string(name) + ".nii.gz"));
    fs::create_directory(dir / "in");
    for (const auto& entry : fs::directory_iterator(dir.path()))
        if (entry.is_symlink()) fs::rename(entry.path(), dir / "in" / entry.path().filename());
    const auto run = heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") + " -j 2 --options '--cavity 2 --anchor-border'");
    EXPECT_EQ(run.exit_code, 0) << run.output;
    for (const char* name : {"hvsmr16_pat0", "hvsmr16_pat1", "hvsmr16_pat5", "hvsmr16_pat6"}) {
        const Scenario s = read_scenario(dir / "out" / (std::string(name) + ".h5"));
        EXPECT_TRUE(s.packing && s.simulation_surface && s.visual && s.mapping) << name;
    }
}
