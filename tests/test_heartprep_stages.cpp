// heartprep's stage commands on scenario files, and batch conversion, run as a technician would.
#include "formats/mesh_io.h"
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/mesh.h"
#include "libmodel/phantom.h"
#include "test_support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstring>
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
    // A place that cannot take the output's ParaView description is refused before the stage runs.
    fs::create_directory(dir / "blocked.xdmf");
    const auto blocked = heartprep("pack " + quoted(file) + " --packing slices -o " + quoted(dir / "blocked.h5"));
    EXPECT_EQ(blocked.exit_code, 7) << blocked.output;
    EXPECT_NE(blocked.output.find("blocked.xdmf: is a folder"), std::string::npos) << blocked.output;
    EXPECT_FALSE(fs::exists(dir / "blocked.h5"));
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
            // The frame the file holds: glTF's metres, +Y up, for a .glb (docs/user-guide.md).
            EXPECT_NE(run.output.find(std::string(extension) == ".glb" ? "glTF's frame, metres" : "LPS mm"), std::string::npos) << run.output;
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
    // A manifest refused before any case runs: exit 1, the reason, no output folder.
    auto refused = [&](const std::string& name, const std::string& text, const std::string& expected) {
        std::ofstream(dir / name) << text;
        const auto run = heartprep("batch " + quoted(dir / name) + " -o " + quoted(dir / "out"));
        EXPECT_EQ(run.exit_code, 1) << name;
        EXPECT_NE(run.output.find(expected), std::string::npos) << run.output;
        EXPECT_FALSE(fs::exists(dir / "out")) << name;
    };
    refused("duplicate.csv", "a.nii.gz,same\na.nii.gz,same\n", "duplicate case id 'same' on lines 1 and 2");
    // "." and ".." wrote the hidden files "..h5" and "...h5".
    refused("dots.csv", "a.nii.gz,..\n", "dots.csv: line 1: case id '..' begins with '.'");
    // Ids that differ only in case name one file on macOS and Windows.
    refused("cased.csv", "a.nii.gz,heart\na.nii.gz,Heart\n", "case ids 'heart' (line 1) and 'Heart' (line 2) differ only in case");
    // A label map given where the manifest belongs read as "line 7 has 5 fields".
    auto run = heartprep("batch " + quoted(dir / "a.nii.gz") + " -o " + quoted(dir / "out"));
    EXPECT_EQ(run.exit_code, 1);
    EXPECT_NE(run.output.find("a.nii.gz: holds binary data (a NUL byte on line"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("gzip-compressed: a .nii.gz label map?"), std::string::npos) << run.output;
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

namespace {

nlohmann::json read_json(const fs::path& path) {
    std::ifstream in(path);
    return nlohmann::json::parse(in);  // throws on text that is not JSON
}

/// A PNG's width and height, from its IHDR chunk; {0, 0} when the file is not a PNG.
std::pair<std::uint32_t, std::uint32_t> png_size(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    unsigned char header[24] = {};
    in.read(reinterpret_cast<char*>(header), sizeof header);
    if (!in || std::memcmp(header, "\x89PNG\r\n\x1a\n", 8) != 0 || std::memcmp(header + 12, "IHDR", 4) != 0) return {0, 0};
    auto big_endian = [&](int at) {
        return std::uint32_t(header[at]) << 24 | std::uint32_t(header[at + 1]) << 16 | std::uint32_t(header[at + 2]) << 8 | header[at + 3];
    };
    return {big_endian(16), big_endian(20)};
}

std::string read_file_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace

// The technician's quality check of a batch: per case the figures of its scenario, and a picture.
TEST(HeartprepBatch, TheSummaryHasTheScenariosFiguresAndAPicturePerCase) {
    test::TempDir dir;
    fs::create_directory(dir / "in");
    small_phantom(dir, "in/a-label.nii.gz", 8.0);
    small_phantom(dir, "in/b-label.nii.gz", 0.0);
    // An intensity image beside the labels (here another phantom, so that taking it would succeed
    // and show): --pattern leaves it out.
    small_phantom(dir, "in/a-image.nii.gz", 4.0);
    const auto run = heartprep("batch " + quoted(dir / "in") + " --pattern '*-label.nii.gz' -o " + quoted(dir / "out") +
                               " -j 2 --threads 1 --json --options '--particles 2000 --anchor-border'");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const auto summary = read_json(dir / "out" / "summary.json");
    ASSERT_EQ(summary["cases"].size(), 2u) << summary.dump(2);
    EXPECT_FALSE(fs::exists(dir / "out" / "a-image.h5"));
    // --json prints the same document as summary.json.
    const auto printed = nlohmann::json::parse(run.output.substr(run.output.find("{\n")));
    EXPECT_EQ(printed, summary);
    const std::string markdown = read_file_text(dir / "out" / "summary.md");
    std::vector<std::string> pictures;
    for (const auto& entry : summary["cases"]) {
        const std::string id = entry["case_id"];
        SCOPED_TRACE(id);
        EXPECT_EQ(entry["status"], "built");
        const Scenario s = read_scenario(entry["output"].get<std::string>());
        const auto& p = s.lattice.particles;
        EXPECT_EQ(entry["particles"], p.size());
        EXPECT_EQ(entry["springs"], s.lattice.springs.size());
        EXPECT_EQ(entry["anchored"], std::count(p.anchored.begin(), p.anchored.end(), 1));
        EXPECT_GT(entry["anchored"].get<std::size_t>(), 0u) << "--anchor-border anchors the phantom's cut base";
        EXPECT_EQ(entry["spacing_mm"], s.lattice.spacing);
        EXPECT_EQ(entry["dt_ms"], s.solver.dt_ms);
        // The tissue volume from the particles' masses, against the volume enclosed by the
        // scenario's own detailed surface (divergence theorem): the two discretisations agree to a
        // few per cent.
        ASSERT_TRUE(s.visual.has_value());
        double enclosed_mm3 = 0.0;
        for (const auto& t : s.visual->triangles) {
            const auto& a = s.visual->positions[std::size_t(t[0])];
            const auto& b = s.visual->positions[std::size_t(t[1])];
            const auto& c = s.visual->positions[std::size_t(t[2])];
            enclosed_mm3 += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) - double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
                             double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) / 6.0;
        }
        EXPECT_NEAR(entry["tissue_volume_ml"].get<double>(), std::abs(enclosed_mm3) / 1000.0, 0.15 * std::abs(enclosed_mm3) / 1000.0);
        // A picture at rest, linked from the markdown summary.
        ASSERT_TRUE(entry["preview"].is_string()) << entry.dump();
        const fs::path picture = dir / "out" / entry["preview"].get<std::string>();
        EXPECT_EQ(png_size(picture), std::make_pair(320u, 240u));
        EXPECT_NE(markdown.find("![" + id + "](" + entry["preview"].get<std::string>() + ")"), std::string::npos) << markdown;
        pictures.push_back(read_file_text(picture));
    }
    ASSERT_EQ(pictures.size(), 2u);
    EXPECT_NE(pictures[0], pictures[1]) << "two different hearts gave the same picture";
    // The CSV has the same columns.
    const std::string csv = read_file_text(dir / "out" / "summary.csv");
    EXPECT_EQ(csv.rfind("case_id,input,status,particles,springs,triangles,seconds,warnings,message,output,anchored,supported,"
                        "tissue_volume_ml,spacing_mm,dt_ms,preview\n", 0), 0u) << csv;

    // --pattern that matches nothing: a clear error, no output folder.
    const auto none = heartprep("batch " + quoted(dir / "in") + " --pattern '*.mha' -o " + quoted(dir / "none"));
    EXPECT_NE(none.exit_code, 0);
    EXPECT_NE(none.output.find("matches --pattern '*.mha'"), std::string::npos) << none.output;
    EXPECT_FALSE(fs::exists(dir / "none"));
    // Without a pattern, a-image and a-label are two cases, and a stem shared by two files is refused.
    std::ofstream(dir / "in" / "a-label.mha") << "x";
    const auto clash = heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "clash"));
    EXPECT_NE(clash.exit_code, 0);
    EXPECT_NE(clash.output.find("would both be case 'a-label'"), std::string::npos) << clash.output;
}

// `batch --plan` tells what a batch would do, with the content key a build stores: what the
// Snakemake workflow is built on.
TEST(HeartprepBatch, ThePlanGivesTheKeyThatTheBuildStores) {
    test::TempDir dir;
    fs::create_directory(dir / "in");
    small_phantom(dir, "in/a.nii.gz");
    const std::string batch = "batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") + " --options '--particles 2000' --no-preview";
    auto plan = nlohmann::json::parse(heartprep(batch + " --plan").output);
    ASSERT_EQ(plan["cases"].size(), 1u);
    EXPECT_EQ(plan["cases"][0]["up_to_date"], false);
    EXPECT_EQ(plan["cases"][0]["options_words"], nlohmann::json::array({"--particles", "2000"}));
    EXPECT_FALSE(fs::exists(dir / "out")) << "--plan builds nothing";
    ASSERT_EQ(heartprep(batch).exit_code, 0);
    EXPECT_EQ(read_scenario(dir / "out" / "a.h5").batch_key, plan["cases"][0]["key"]);
    EXPECT_EQ(nlohmann::json::parse(heartprep(batch + " --plan").output)["cases"][0]["up_to_date"], true);
    // Another option, another key.
    const auto other = nlohmann::json::parse(
        heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") + " --options '--particles 2500' --plan").output);
    EXPECT_NE(other["cases"][0]["key"], plan["cases"][0]["key"]);
    EXPECT_EQ(other["cases"][0]["up_to_date"], false);
}

// A build's result does not depend on how many threads made it (batch runs cases with --threads).
TEST(HeartprepBuild, TheThreadCountDoesNotChangeTheScenario) {
    test::TempDir dir;
    const auto input = small_phantom(dir, "a.nii.gz");
    for (const char* threads : {"1", "2"})
        ASSERT_EQ(heartprep("build " + quoted(input) + " -o " + quoted(dir / (std::string("t") + threads + ".h5")) +
                            " --particles 2000 --anchor-border -q --threads " + threads)
                      .exit_code,
                  0);
    const Scenario one = read_scenario(dir / "t1.h5"), two = read_scenario(dir / "t2.h5");
    EXPECT_EQ(one.lattice.particles.rest_position, two.lattice.particles.rest_position);
    EXPECT_EQ(one.lattice.particles.support_point, two.lattice.particles.support_point);
    EXPECT_EQ(one.lattice.springs.pairs, two.lattice.springs.pairs);
    ASSERT_TRUE(one.visual && two.visual);
    EXPECT_EQ(one.visual->positions, two.visual->positions);
    EXPECT_EQ(one.solver.dt_ms, two.solver.dt_ms);
    EXPECT_NE(heartprep("build " + quoted(input) + " -o " + quoted(dir / "x.h5") + " --threads -1").exit_code, 0);
}

// In a log or a pipe (a batch's case log, CI), a long stage says how far it has come.
TEST(HeartprepBuild, ALogShowsProgressBeforeAStageEnds) {
    test::TempDir dir;
    const auto input = small_phantom(dir, "a.nii.gz");
    const auto run = test::run_command("HEARTPREP_PROGRESS_SECONDS=0.000001 " + std::string(HEARTPREP_EXE) + " build " + quoted(input) +
                                       " -o " + quoted(dir / "a.h5") + " --particles 2000 2>&1 | cat");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    std::smatch m;
    EXPECT_TRUE(std::regex_search(run.output, m, std::regex(R"(heartprep: [a-z ]+: \d+% after \d+ s\n)"))) << run.output;
    // 0 turns the lines off.
    const auto off = test::run_command("HEARTPREP_PROGRESS_SECONDS=0 " + std::string(HEARTPREP_EXE) + " build " + quoted(input) +
                                       " -o " + quoted(dir / "b.h5") + " --particles 2000 2>&1 | cat");
    EXPECT_FALSE(std::regex_search(off.output, m, std::regex(R"(% after )"))) << off.output;
}

// The Snakemake workflow: one job per case, the same content key as batch, and a rerun that does
// nothing; on the phantom and (where the data is) a real case.
TEST(HeartprepWorkflow, SnakemakeBuildsTheCasesAndARerunDoesNothing) {
    if (test::run_command("command -v snakemake").exit_code != 0)
        GTEST_SKIP() << "snakemake (Debian package snakemake) is not installed; scripts/install-deps.sh installs it";
    test::TempDir dir;
    fs::create_directory(dir / "in");
    small_phantom(dir, "in/phantom.nii.gz");
    const auto root = test::real_data_dir();
    if (!root.empty()) fs::create_symlink(test::real_case("hvsmr16_pat0"), dir / "in" / "pat0.nii.gz");
    else std::fprintf(stderr, "real data not found under %s: the workflow runs on the phantom only\n", HEARTSIM_REAL_DATA);
    const std::string path = "PATH=" + quoted(fs::path(HEARTPREP_EXE).parent_path()) + ":\"$PATH\" ";
    auto snakemake = [&](const std::string& config, const std::string& extra) {
        return test::run_command("cd " + quoted(dir.path()) + " && " + path + "snakemake -s " +
                                 quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "Snakefile") + " --cores 2 --config manifest=in out=out " +
                                 config + " " + extra + " 2>&1");
    };
    const std::string options = "options='--particles 3000 --anchor-border'";
    const auto first = snakemake(options, "");
    ASSERT_EQ(first.exit_code, 0) << first.output;
    const auto summary = read_json(dir / "out" / "summary.json");
    const auto plan = nlohmann::json::parse(heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") +
                                                      " --options '--particles 3000 --anchor-border' --plan")
                                                .output);
    ASSERT_EQ(summary["cases"].size(), root.empty() ? 1u : 2u);
    for (const auto& entry : plan["cases"]) {
        const std::string id = entry["case_id"];
        const Scenario s = read_scenario(dir / "out" / (id + ".h5"));
        EXPECT_EQ(s.batch_key, entry["key"]) << id;
        EXPECT_EQ(entry["up_to_date"], true) << id;
        EXPECT_TRUE(s.packing && s.simulation_surface && s.visual && s.mapping) << id;
        EXPECT_TRUE(fs::exists(dir / "out" / "previews" / (id + ".png"))) << id;
    }
    for (const auto& entry : summary["cases"]) EXPECT_EQ(entry["status"], "skipped") << "the summary job builds nothing";
    const auto modified = fs::last_write_time(dir / "out" / "phantom.h5");

    // A rerun does nothing, also after the input was touched (same bytes, same key).
    const auto again = snakemake(options, "");
    EXPECT_EQ(again.exit_code, 0) << again.output;
    EXPECT_NE(again.output.find("Nothing to be done"), std::string::npos) << again.output;
    fs::last_write_time(dir / "in" / "phantom.nii.gz", fs::file_time_type::clock::now());
    const auto touched = snakemake(options, "-n");
    EXPECT_NE(touched.output.find("Nothing to be done"), std::string::npos) << touched.output;
    EXPECT_EQ(fs::last_write_time(dir / "out" / "phantom.h5"), modified);
    // heartprep batch finds the same cases up to date.
    const auto batch = heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") +
                                 " --options '--particles 3000 --anchor-border' --no-preview");
    EXPECT_EQ(batch.exit_code, 0) << batch.output;
    EXPECT_EQ(batch.output.find("| built |"), std::string::npos) << batch.output;

    // Other options: every case is planned again; the Slurm profile reads (a dry run submits nothing).
    const auto changed = snakemake("options='--particles 2500 --anchor-border'", "-n --profile " +
                                   quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "profiles" / "slurm"));
    EXPECT_EQ(changed.exit_code, 0) << changed.output;
    EXPECT_NE(changed.output.find("Params have changed since last execution"), std::string::npos) << changed.output;
    EXPECT_EQ(fs::last_write_time(dir / "out" / "phantom.h5"), modified);
}
