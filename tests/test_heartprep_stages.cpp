// heartprep's stage commands on scenario files, and batch conversion, run as a technician would.
#include "formats/csv.h"
#include "formats/mesh_io.h"
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/mesh.h"
#include "libmodel/phantom.h"
#include "test_support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include <unistd.h>

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
    fs::create_directory(dir / "blocked.xmf2");
    const auto blocked = heartprep("pack " + quoted(file) + " --packing slices -o " + quoted(dir / "blocked.h5"));
    EXPECT_EQ(blocked.exit_code, 7) << blocked.output;
    EXPECT_NE(blocked.output.find("blocked.xmf2: is a folder"), std::string::npos) << blocked.output;
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
        EXPECT_NE(second.output.find(std::string("| ") + id + " | reused |"), std::string::npos) << second.output;

    // A changed input is built again.
    small_phantom(dir, "a.nii.gz", 3.0);
    auto third = heartprep(command);
    EXPECT_NE(third.output.find("| case_a | built |"), std::string::npos) << third.output;
    EXPECT_NE(third.output.find("| case_b | reused |"), std::string::npos) << third.output;
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
    EXPECT_NE(summary_row().find(",reused,"), std::string::npos) << summary_row();
    EXPECT_NE(summary_row().find(warning), std::string::npos) << "a reused case lost its warnings: " << summary_row();
    EXPECT_NE(second.output.find("| a | reused |"), std::string::npos) << second.output;
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
        // The tissue volume: the build's own (the label map's tissue voxels, as the build summary
        // and inspect give it), and against the volume enclosed by the scenario's detailed surface
        // (divergence theorem): the two discretisations agree to a few per cent.
        ASSERT_GT(s.source.tissue_volume_mm3, 0.0);
        EXPECT_NEAR(entry["tissue_volume_ml"].get<double>(), s.source.tissue_volume_mm3 / 1000.0, 1e-9);
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
                        "tissue_volume_ml,spacing_mm,dt_ms,preview,built_by,built_at\n", 0), 0u) << csv;

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

// One case, one set of figures: every figure of a batch's summary.csv is the one `heartprep inspect
// --json` gives for the same scenario (the supported particles those on surface supports, the
// tissue the label map's), and the build's own summary in the case's log says the same; a case that
// failed measured nothing, so its figures are blank, in the CSV and the markdown alike.
TEST(HeartprepBatch, EverySummaryFigureIsInspectsAndAFailedCaseHasBlanks) {
    test::TempDir dir;
    fs::create_directory(dir / "in");
    small_phantom(dir, "in/a.nii.gz", 8.0);
    small_phantom(dir, "in/b.nii.gz", 0.0);
    std::ofstream(dir / "in" / "broken.nii.gz") << "this is not a volume";
    const auto run = heartprep("batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") +
                               " -j 2 --threads 1 --no-preview --options '--particles 2000 --anchor-border'");
    ASSERT_EQ(run.exit_code, 1) << run.output;  // one case failed
    std::istringstream csv(read_file_text(dir / "out" / "summary.csv"));
    std::string line;
    ASSERT_TRUE(std::getline(csv, line));
    std::map<std::string, std::size_t> column;
    for (const auto& name : csv_fields(line)) column.emplace(name, column.size());
    const std::vector<std::string> figures{"particles", "springs", "triangles", "anchored", "supported", "tissue_volume_ml", "spacing_mm", "dt_ms"};
    for (const auto& name : figures) ASSERT_TRUE(column.count(name)) << name;
    const std::string markdown = read_file_text(dir / "out" / "summary.md");
    std::size_t built = 0, failed = 0;
    while (std::getline(csv, line)) {
        const auto row = csv_fields(line);
        ASSERT_EQ(row.size(), column.size()) << line;
        const std::string id = row[column.at("case_id")];
        SCOPED_TRACE(id);
        auto cell = [&](const std::string& name) { return row[column.at(name)]; };
        if (id == "broken") {
            ++failed;
            EXPECT_EQ(cell("status"), "failed");
            for (const auto& name : figures) EXPECT_EQ(cell(name), "") << name << " of a case that built nothing";
            // The markdown row: case, status, then six blank figures.
            EXPECT_NE(markdown.find("| broken | failed |  |  |  |  |  |  | "), std::string::npos) << markdown;
            continue;
        }
        ++built;
        ASSERT_EQ(cell("status"), "built");
        const auto inspect = heartprep("inspect --json " + quoted(fs::path(cell("output"))));
        ASSERT_EQ(inspect.exit_code, 0) << inspect.output;
        const auto j = nlohmann::json::parse(inspect.output);
        EXPECT_EQ(std::stoull(cell("particles")), j["particles"].get<std::size_t>());
        EXPECT_EQ(std::stoull(cell("springs")), j["springs"].get<std::size_t>());
        EXPECT_EQ(std::stoull(cell("triangles")), j["visual"]["triangles"].get<std::size_t>());
        EXPECT_EQ(std::stoull(cell("anchored")), j["anchored"].get<std::size_t>());
        EXPECT_EQ(std::stoull(cell("supported")), j["holding"]["surface_supported_particles"].get<std::size_t>());
        // Written with 3, 4 and 5 decimals.
        EXPECT_NEAR(std::stod(cell("tissue_volume_ml")), j["tissue_volume_ml"].get<double>(), 0.5e-3);
        EXPECT_NEAR(std::stod(cell("spacing_mm")), j["lattice"]["spacing"].get<double>(), 0.5e-4);
        EXPECT_NEAR(std::stod(cell("dt_ms")), j["solver"]["dt_ms"].get<double>(), 0.5e-5);
        // The posterior supports are the heart's back, not every free particle (the elastic
        // foundation under all of them is not a surface support).
        const std::size_t particles = j["particles"], anchored = j["anchored"], supported = j["holding"]["surface_supported_particles"];
        EXPECT_GT(supported, 0u);
        EXPECT_LT(supported, (particles - anchored) / 2);
        EXPECT_EQ(j["holding"]["supported_particles"].get<std::size_t>(), particles - anchored) << "the foundation holds every free particle";
        // The build's summary, in the case's log, gives the same particles, supports and tissue.
        const std::string log = read_file_text(dir / "out" / "logs" / (id + ".log"));
        std::smatch m;
        ASSERT_TRUE(std::regex_search(log, m, std::regex("a heart of ([0-9.]+) mL of tissue .*: ([0-9,]+) particles"))) << log;
        EXPECT_NEAR(std::stod(m[1]), j["tissue_volume_ml"].get<double>(), 0.05);
        EXPECT_EQ(std::regex_replace(m[2].str(), std::regex(","), ""), cell("particles"));
        ASSERT_TRUE(std::regex_search(log, m, std::regex("\\(([0-9,]+) particles on supports\\)"))) << log;
        EXPECT_EQ(std::regex_replace(m[1].str(), std::regex(","), ""), cell("supported"));
    }
    EXPECT_EQ(built, 2u);
    EXPECT_EQ(failed, 1u);
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
    for (const auto& entry : summary["cases"]) EXPECT_EQ(entry["status"], "built by the workflow") << entry.dump();
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
    EXPECT_NE(batch.output.find("| phantom | reused |"), std::string::npos) << batch.output;

    // Other options: every case is planned again; the Slurm profile reads (a dry run submits nothing).
    const auto changed = snakemake("options='--particles 2500 --anchor-border'", "-n --profile " +
                                   quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "profiles" / "slurm"));
    EXPECT_EQ(changed.exit_code, 0) << changed.output;
    EXPECT_NE(changed.output.find("Params have changed since last execution"), std::string::npos) << changed.output;
    EXPECT_EQ(fs::last_write_time(dir / "out" / "phantom.h5"), modified);
}

namespace {

bool snakemake_installed() { return test::run_command("command -v snakemake").exit_code == 0; }

/// Snakemake's major version (7 in Debian 12), 0 when it cannot be told.
int snakemake_major() {
    const auto run = test::run_command("snakemake --version 2>/dev/null");
    return run.exit_code == 0 ? std::atoi(run.output.c_str()) : 0;
}

/// Writes an executable script.
void write_script(const fs::path& path, const std::string& text) {
    std::ofstream(path) << text;
    fs::permissions(path, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec | fs::perms::others_read |
                              fs::perms::others_exec);
}

/// A case's entry in summary.json.
nlohmann::json summary_entry(const nlohmann::json& summary, const std::string& id) {
    for (const auto& entry : summary["cases"])
        if (entry["case_id"] == id) return entry;
    ADD_FAILURE() << "no case " << id << " in " << summary.dump(2);
    return {};
}

/// The count line under the markdown table ("3 cases: …").
std::string count_line(const fs::path& markdown) {
    std::ifstream in(markdown);
    for (std::string line; std::getline(in, line);)
        if (line.find(" cases: ") != std::string::npos) return line;
    return {};
}

}  // namespace

// The complaint: after Snakemake built the cases, the summary said "0 built, 3 skipped" with the
// time of the summary's own check as each build time. The summary says how each case was built,
// with the time of the build that made its scenario, after the workflow as after batch.
TEST(HeartprepWorkflow, TheSummarySaysHowEachCaseWasBuilt) {
    if (!snakemake_installed()) GTEST_SKIP() << "snakemake (Debian package snakemake) is not installed; scripts/install-deps.sh installs it";
    test::TempDir dir;
    fs::create_directory(dir / "in");
    const std::map<std::string, std::string> cases{{"a", "8"}, {"b", "0"}, {"c", "5"}};  // case: VSD diameter, mm
    for (const auto& [id, vsd] : cases)
        ASSERT_EQ(heartprep("phantom --size 24 --vsd-diameter " + vsd + " -o " + quoted(dir / "in" / (id + ".nii.gz"))).exit_code, 0);
    const std::string path = "PATH=" + quoted(fs::path(HEARTPREP_EXE).parent_path()) + ":\"$PATH\" ";
    const std::string snakefile = quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "Snakefile");
    auto snakemake = [&](const std::string& extra) {
        return test::run_command("cd " + quoted(dir.path()) + " && " + path + "snakemake -s " + snakefile +
                                 " --cores 2 --config manifest=in out=out preview=0 options='--particles 2000 --anchor-border' " + extra +
                                 " 2>&1");
    };
    const std::string batch = "batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") + " --options '--particles 2000 --anchor-border' --no-preview";
    auto record = [&](const std::string& id) { return read_json(dir / "out" / "logs" / (id + ".build.json")); };

    // 1. The workflow builds the three cases: `built by the workflow`, each with its own build's time.
    const auto start = std::chrono::steady_clock::now();
    const auto built = snakemake("");
    const double run_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    ASSERT_EQ(built.exit_code, 0) << built.output;
    auto summary = read_json(dir / "out" / "summary.json");
    const std::string run = read_file_text(dir / "out" / "logs" / "workflow-run");
    ASSERT_FALSE(run.empty());
    std::map<std::string, double> workflow_seconds;
    for (const auto& [id, vsd] : cases) {
        SCOPED_TRACE(id);
        const auto entry = summary_entry(summary, id);
        EXPECT_EQ(entry["status"], "built by the workflow");
        EXPECT_EQ(entry["built_by"], "workflow");
        ASSERT_TRUE(entry["seconds"].is_number()) << entry.dump();
        const double seconds = entry["seconds"];
        // The build's own time: the one its job recorded, more than nothing, less than the whole run.
        EXPECT_GT(seconds, 0.0);
        EXPECT_LT(seconds, run_seconds);
        const auto written = record(id);
        EXPECT_EQ(written["run"].get<std::string>() + "\n", run);
        EXPECT_EQ(written["status"], "built");
        EXPECT_NEAR(seconds, written["seconds"].get<double>(), 1e-9);
        EXPECT_EQ(entry["built_at"], written["finished"]);
        workflow_seconds[id] = seconds;
    }
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("3 cases: 3 built by the workflow, 0 reused, 0 failed.", 0), 0u)
        << read_file_text(dir / "out" / "summary.md");
    EXPECT_NE(read_file_text(dir / "out" / "summary.md").find("| a | built by the workflow |"), std::string::npos);

    // 2. heartprep batch over the same folder reuses them, with the workflow builds' times.
    const auto reused = heartprep(batch);
    ASSERT_EQ(reused.exit_code, 0) << reused.output;
    summary = read_json(dir / "out" / "summary.json");
    for (const auto& [id, seconds] : workflow_seconds) {
        const auto entry = summary_entry(summary, id);
        EXPECT_EQ(entry["status"], "reused") << id;
        EXPECT_EQ(entry["built_by"], "workflow") << id;
        EXPECT_NEAR(entry["seconds"].get<double>(), seconds, 0.005) << id << ": not the time of the build that made the file";
    }
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("3 cases: 0 built, 3 reused, 0 failed.", 0), 0u) << reused.output;

    // 3. Forced, batch builds them again: `built`, with its own builds' times, which the records keep.
    const auto forced = heartprep(batch + " --force");
    ASSERT_EQ(forced.exit_code, 0) << forced.output;
    summary = read_json(dir / "out" / "summary.json");
    for (const auto& [id, vsd] : cases) {
        const auto entry = summary_entry(summary, id);
        EXPECT_EQ(entry["status"], "built") << id;
        EXPECT_EQ(entry["built_by"], "batch") << id;
        EXPECT_GT(entry["seconds"].get<double>(), 0.0) << id;
        EXPECT_NEAR(record(id)["seconds"].get<double>(), entry["seconds"].get<double>(), 1e-6) << id;
        EXPECT_EQ(record(id)["built_by"], "batch") << id;
    }
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("3 cases: 3 built, 0 reused, 0 failed.", 0), 0u) << forced.output;
    // Snakemake finds them up to date (the same keys), and batch again reuses them.
    EXPECT_NE(snakemake("").output.find("Nothing to be done"), std::string::npos);
    const auto reused_again = heartprep(batch);
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("3 cases: 0 built, 3 reused, 0 failed.", 0), 0u) << reused_again.output;

    // 4. Cases that fail in the workflow: a file that is no label map, and a build the system
    // kills (the out-of-memory killer's SIGKILL, played by a heartprep wrapper: a test double for
    // a machine that runs out of memory). The run writes the summary anyway (onerror): `failed`
    // with the reason and the time until the failure; the new good case `built by the workflow`,
    // the others `reused`.
    std::ofstream(dir / "in" / "broken.nii.gz") << "this is not a volume";
    ASSERT_EQ(heartprep("phantom --size 24 --vsd-diameter 3 -o " + quoted(dir / "in" / "d.nii.gz")).exit_code, 0);
    ASSERT_EQ(heartprep("phantom --size 24 --vsd-diameter 6 -o " + quoted(dir / "in" / "killed.nii.gz")).exit_code, 0);
    write_script(dir / "heartprep-oom", "#!/bin/sh\n"
                                        "# heartprep, except that the build of killed.nii.gz is killed as the kernel's\n"
                                        "# out-of-memory killer kills a process: SIGKILL.\n"
                                        "case \"$*\" in build*killed.nii.gz*) kill -KILL $$ ;; esac\n"
                                        "exec " + quoted(HEARTPREP_EXE) + " \"$@\"\n");
    const auto failing = snakemake("heartprep=" + quoted(dir / "heartprep-oom") + " --keep-going");
    EXPECT_NE(failing.exit_code, 0) << failing.output;
    summary = read_json(dir / "out" / "summary.json");
    const auto broken = summary_entry(summary, "broken");
    EXPECT_EQ(broken["status"], "failed");
    EXPECT_NE(broken["message"].get<std::string>().find("broken.nii.gz"), std::string::npos) << broken.dump();
    EXPECT_GT(broken["seconds"].get<double>(), 0.0);
    const auto killed = summary_entry(summary, "killed");
    EXPECT_EQ(killed["status"], "failed");
    EXPECT_NE(killed["message"].get<std::string>().find("killed by SIGKILL"), std::string::npos) << killed.dump();
    EXPECT_EQ(summary_entry(summary, "d")["status"], "built by the workflow");
    for (const auto& [id, vsd] : cases) EXPECT_EQ(summary_entry(summary, id)["status"], "reused") << id;
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("6 cases: 1 built by the workflow, 3 reused, 2 failed.", 0), 0u)
        << read_file_text(dir / "out" / "summary.md");
    const std::string markdown = read_file_text(dir / "out" / "summary.md");
    EXPECT_NE(markdown.find("| broken | failed |"), std::string::npos) << markdown;
    // And batch, building the failed cases itself, reports them failed too.
    const auto again = heartprep(batch);
    EXPECT_EQ(again.exit_code, 1) << again.output;
    summary = read_json(dir / "out" / "summary.json");
    EXPECT_EQ(summary_entry(summary, "broken")["status"], "failed");
    EXPECT_EQ(summary_entry(summary, "killed")["status"], "built") << "the real heartprep builds it";
    EXPECT_EQ(summary_entry(summary, "d")["status"], "reused");
}

// --no-build reports a case whose build began and never ended (its job killed outright, the
// record left saying `running`) as failed, and a case no build has reached as not started.
TEST(HeartprepWorkflow, ABuildThatNeverEndedIsFailedAndOneNeverBegunNotStarted) {
    test::TempDir dir;
    fs::create_directory(dir / "in");
    for (const char* id : {"ended", "begun", "waiting"})
        ASSERT_EQ(heartprep("phantom --size 24 -o " + quoted(dir / "in" / (std::string(id) + ".nii.gz"))).exit_code, 0);
    const std::string batch = "batch " + quoted(dir / "in") + " -o " + quoted(dir / "out") + " --options '--particles 2000' --no-preview";
    const auto plan = nlohmann::json::parse(heartprep(batch + " --plan").output);
    auto key_of = [&](const std::string& id) {
        for (const auto& entry : plan["cases"])
            if (entry["case_id"] == id) return entry["key"].get<std::string>();
        ADD_FAILURE() << "no case " << id;
        return std::string();
    };
    fs::create_directories(dir / "out" / "logs");
    // A build of "begun" through workflow/build_case.py, the job killed outright (SIGKILL, as Slurm
    // ends a job past its time limit's grace) while it runs; the "build" is a sleep.
    const fs::path record = dir / "out" / "logs" / "begun.build.json";
    const auto killed = test::run_command(
        "cd " + quoted(dir.path()) + " && { python3 " + quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "build_case.py") +
        " --record " + quoted(record) + " --run-file out/logs/workflow-run --case begun --key " + key_of("begun") +
        " --log out/logs/begun.log -- sh -c 'echo $$ > sleeper.pid; exec sleep 30' & } ; job=$!; "
        "for i in $(seq 100); do [ -s sleeper.pid ] && grep -qs running " + quoted(record) + " && break; sleep 0.1; done; "
        "kill -KILL $job; wait $job; echo status $?; kill -KILL $(cat sleeper.pid)");
    EXPECT_NE(killed.output.find("status 137"), std::string::npos) << killed.output;
    EXPECT_EQ(read_json(record)["status"], "running");
    ASSERT_EQ(heartprep("build " + quoted(dir / "in" / "ended.nii.gz") + " -o " + quoted(dir / "out" / "ended.h5") + " --particles 2000 -q" +
                        " --batch-key " + key_of("ended"))
                  .exit_code,
              0);

    const auto report = heartprep(batch + " --no-build --workflow-run some-run");
    EXPECT_EQ(report.exit_code, 1) << report.output;  // a case failed
    const auto summary = read_json(dir / "out" / "summary.json");
    const auto begun = summary_entry(summary, "begun");
    EXPECT_EQ(begun["status"], "failed");
    EXPECT_NE(begun["message"].get<std::string>().find("never reported an end"), std::string::npos) << begun.dump();
    EXPECT_EQ(summary_entry(summary, "waiting")["status"], "not started");
    // Built by hand with the right key, without a record: reused, its build time unknown.
    const auto ended = summary_entry(summary, "ended");
    EXPECT_EQ(ended["status"], "reused");
    EXPECT_TRUE(ended["seconds"].is_null()) << ended.dump();
    EXPECT_NE(read_file_text(dir / "out" / "summary.md").find("| ended | reused |"), std::string::npos);
    EXPECT_FALSE(fs::exists(dir / "out" / "waiting.h5")) << "--no-build built a case";
    // --no-build and --force contradict each other; --workflow-run needs --no-build.
    EXPECT_EQ(heartprep(batch + " --no-build --force").exit_code, 2);
    EXPECT_EQ(heartprep(batch + " --workflow-run x").exit_code, 2);
}

// The Slurm profile's job-state check (Snakemake 7's --cluster-status), against what sacct and
// squeue print. Slurm cannot run here: `sacct` and `squeue` are test doubles on PATH that print
// the states a cluster's would.
TEST(HeartprepWorkflow, TheSlurmStatusCheckMapsEveryJobState) {
    test::TempDir dir;
    fs::create_directory(dir / "bin");
    fs::create_directory(dir / "jobs");
    // A job's accounting state is jobs/<id>.sacct; a job only the controller knows yet, jobs/<id>.squeue.
    write_script(dir / "bin" / "sacct", "#!/bin/sh\n# sacct test double: a Slurm cluster cannot exist in this test.\n"
                                        "echo \"$*\" >> \"$FAKE_SLURM/sacct.calls\"\n"
                                        "[ -z \"$FAKE_SACCT_DOWN\" ] || { echo 'sacct: error: Problem talking to the database' >&2; exit 1; }\n"
                                        "while [ $# -gt 0 ]; do [ \"$1\" = -j ] && id=$2; shift; done\n"
                                        "cat \"$FAKE_SLURM/$id.sacct\" 2>/dev/null; exit 0\n");
    write_script(dir / "bin" / "squeue", "#!/bin/sh\n# squeue test double: a Slurm cluster cannot exist in this test.\n"
                                         "while [ $# -gt 0 ]; do [ \"$1\" = -j ] && id=$2; shift; done\n"
                                         "[ -f \"$FAKE_SLURM/$id.squeue\" ] && { cat \"$FAKE_SLURM/$id.squeue\"; exit 0; }\n"
                                         "echo 'slurm_load_jobs error: Invalid job id specified' >&2; exit 1\n");
    const fs::path status_script = fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "profiles" / "slurm" / "slurm-status.sh";
    auto status = [&](const std::string& job, const std::string& environment = "") {
        // Its stdout alone, as Snakemake reads it (its messages on stderr go to Snakemake's log).
        const auto run = test::run_command("(PATH=" + quoted(dir / "bin") + ":\"$PATH\" FAKE_SLURM=" + quoted(dir / "jobs") + " " +
                                           environment + " " + quoted(status_script) + " '" + job + "' 2>/dev/null)");
        EXPECT_EQ(run.exit_code, 0) << job << ": " << run.output;
        return run.output;
    };
    const std::vector<std::pair<std::string, std::string>> states{
        {"COMPLETED", "success"},    {"PENDING", "running"},      {"RUNNING", "running"},       {"COMPLETING", "running"},
        {"CONFIGURING", "running"},  {"SUSPENDED", "running"},    {"REQUEUED", "running"},      {"FAILED", "failed"},
        {"TIMEOUT", "failed"},       {"OUT_OF_MEMORY", "failed"}, {"CANCELLED by 1234", "failed"}, {"NODE_FAIL", "failed"},
        {"PREEMPTED", "failed"},     {"BOOT_FAIL", "failed"},     {"DEADLINE", "failed"}};
    int job = 100;
    for (const auto& [state, expected] : states) {
        std::ofstream(dir / "jobs" / (std::to_string(++job) + ".sacct")) << state << "\n";
        EXPECT_EQ(status(std::to_string(job)), expected + "\n") << state;
    }
    // The id as `sbatch --parsable` prints it on a multi-cluster site: "id;cluster".
    EXPECT_EQ(status("101;cluster2"), "success\n");
    EXPECT_NE(read_file_text(dir / "jobs" / "sacct.calls").find("-j 101 -X"), std::string::npos) << read_file_text(dir / "jobs" / "sacct.calls");
    // Just submitted, not in accounting yet: squeue's state.
    std::ofstream(dir / "jobs" / "200.squeue") << "PENDING\n";
    EXPECT_EQ(status("200"), "running\n");
    // Known to neither: gone without a trace, failed.
    EXPECT_EQ(status("300"), "failed\n");
    // The database not answering: asked again later.
    EXPECT_EQ(status("300", "FAKE_SACCT_DOWN=1"), "running\n");
}

// The Slurm profile end to end with the Snakemake in Debian 12 (7.x: cluster: + cluster-status:).
// Slurm cannot run here: `sbatch`, `sacct`, `squeue` and `scancel` are test doubles on PATH, a
// one-machine stand-in for a cluster that runs each job script here and keeps its state. One job
// is ended as Slurm ends a job past its time limit (killed as soon as its build has begun, state
// TIMEOUT): Snakemake learns it from the status check, marks the case failed, and the summary
// says so; the others are built by the workflow.
TEST(HeartprepWorkflow, ThroughTheSlurmProfileAJobSlurmEndsIsMarkedFailed) {
    if (!snakemake_installed()) GTEST_SKIP() << "snakemake (Debian package snakemake) is not installed; scripts/install-deps.sh installs it";
    if (snakemake_major() != 7)
        GTEST_SKIP() << "this test drives Snakemake 7's cluster profile (config.yaml); Snakemake " << snakemake_major()
                     << " reads config.v8+.yaml, which needs the slurm executor plugin and a real Slurm";
    test::TempDir dir;
    fs::create_directory(dir / "in");
    fs::create_directory(dir / "bin");
    fs::create_directory(dir / "jobs");
    for (const char* id : {"a", "b"})
        ASSERT_EQ(heartprep("phantom --size 24 -o " + quoted(dir / "in" / (std::string(id) + ".nii.gz"))).exit_code, 0);
    // Big enough that its build is still running when the double kills its job.
    ASSERT_EQ(heartprep("phantom --size 96 -o " + quoted(dir / "in" / "late.nii.gz")).exit_code, 0);
    write_script(dir / "bin" / "sbatch",
                 "#!/bin/sh\n"
                 "# sbatch test double: a Slurm cluster cannot exist in this test. Runs the job script on this\n"
                 "# machine in the background, its state in $FAKE_SLURM/<id>.sacct, and prints the job id as\n"
                 "# `sbatch --parsable` does. The job named for $FAKE_SLURM_KILL is killed, process group and all\n"
                 "# (procps kill: the shell's own takes no process group), as soon as its build record says it is\n"
                 "# running: state TIMEOUT.\n"
                 "jobs=$FAKE_SLURM\n"
                 "id=$(( $(cat \"$jobs/last-id\" 2>/dev/null || echo 1000) + 1 )); echo $id > \"$jobs/last-id\"\n"
                 "for a; do case $a in --job-name=*) name=${a#--job-name=} ;; esac; script=$a; done\n"
                 "echo \"$name\" > \"$jobs/$id.name\"; echo RUNNING > \"$jobs/$id.sacct\"\n"
                 "case $name in\n"
                 "*\"$FAKE_SLURM_KILL\"*)\n"
                 "  setsid sh \"$script\" > \"$jobs/$id.out\" 2>&1 < /dev/null &\n"
                 "  job=$!\n"
                 "  ( for i in $(seq 600); do grep -qs '\"running\"' \"$FAKE_SLURM_RECORD\" && break; sleep 0.05; done\n"
                 "    env kill -s KILL -- -$job; echo TIMEOUT > \"$jobs/$id.sacct\" ) > /dev/null 2>&1 < /dev/null & ;;\n"
                 "*)\n"
                 "  ( if sh \"$script\" > \"$jobs/$id.out\" 2>&1 < /dev/null; then echo COMPLETED; else echo FAILED; fi > \"$jobs/$id.sacct\" ) \\\n"
                 "    > /dev/null 2>&1 < /dev/null & ;;\n"
                 "esac\n"
                 "echo $id\n");
    write_script(dir / "bin" / "sacct", "#!/bin/sh\n# sacct test double: a Slurm cluster cannot exist in this test.\n"
                                        "while [ $# -gt 0 ]; do [ \"$1\" = -j ] && id=$2; shift; done\n"
                                        "cat \"$FAKE_SLURM/$id.sacct\" 2>/dev/null; exit 0\n");
    write_script(dir / "bin" / "squeue", "#!/bin/sh\n# squeue test double: knows no job (sacct's double knows them all).\n"
                                         "echo 'slurm_load_jobs error: Invalid job id specified' >&2; exit 1\n");
    write_script(dir / "bin" / "scancel", "#!/bin/sh\n# scancel test double: a Slurm cluster cannot exist in this test.\nexit 0\n");
    const auto run = test::run_command(
        "cd " + quoted(dir.path()) + " && PATH=" + quoted(dir / "bin") + ":" + quoted(fs::path(HEARTPREP_EXE).parent_path()) +
        ":\"$PATH\" FAKE_SLURM=" + quoted(dir / "jobs") + " FAKE_SLURM_KILL=case=late FAKE_SLURM_RECORD=" +
        quoted(dir / "out" / "logs" / "late.build.json") + " timeout 300 snakemake -s " +
        quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "Snakefile") + " --profile " +
        quoted(fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "profiles" / "slurm") +
        " --latency-wait 5 --max-status-checks-per-second 10 --config manifest=in out=out preview=0 options='--particles 2000' 2>&1");
    EXPECT_NE(run.exit_code, 0) << run.output;
    EXPECT_NE(run.exit_code, 124) << "Snakemake never learnt that Slurm ended the job:\n" << run.output;
    // Every job went through sbatch, and the status check was asked.
    std::size_t submitted = 0;
    for (const auto& entry : fs::directory_iterator(dir / "jobs")) submitted += entry.path().extension() == ".name";
    EXPECT_EQ(submitted, 3u) << run.output;
    EXPECT_NE(run.output.find("Error in rule build"), std::string::npos) << run.output;
    const auto summary = read_json(dir / "out" / "summary.json");
    EXPECT_EQ(summary_entry(summary, "a")["status"], "built by the workflow");
    EXPECT_EQ(summary_entry(summary, "b")["status"], "built by the workflow");
    const auto late = summary_entry(summary, "late");
    EXPECT_EQ(late["status"], "failed");
    EXPECT_NE(late["message"].get<std::string>().find("never reported an end"), std::string::npos) << late.dump();
    EXPECT_EQ(count_line(dir / "out" / "summary.md").rfind("3 cases: 2 built by the workflow, 0 reused, 1 failed.", 0), 0u)
        << read_file_text(dir / "out" / "summary.md");
}

// Both Slurm profiles: Snakemake 7's (config.yaml) names a status check that is there and runs;
// Snakemake 8's (config.v8+.yaml, read by Snakemake 8 and later instead) uses the slurm executor
// plugin with the same job sizes. Snakemake 8 itself is not in Debian 12: this reads the file.
TEST(HeartprepWorkflow, TheSlurmProfileServesSnakemake7And8) {
    const fs::path profile = fs::path(HEARTSIM_SOURCE_DIR) / "workflow" / "profiles" / "slurm";
    const auto check = test::run_command(
        "python3 -c 'import sys, yaml\n"
        "v7 = yaml.safe_load(open(sys.argv[1])); v8 = yaml.safe_load(open(sys.argv[2]))\n"
        "assert v7[\"cluster-status\"] == \"slurm-status.sh\" and v7[\"cluster-cancel\"] == \"scancel\", v7\n"
        "assert \"sbatch --parsable\" in v7[\"cluster\"], v7\n"
        "assert v8[\"executor\"] == \"slurm\" and \"cluster\" not in v8, v8\n"
        "assert v8[\"default-resources\"] == {\"mem_mb\": 1000, \"runtime\": 10}, v8\n"
        "assert sorted(v7[\"default-resources\"]) == [\"mem_mb=1000\", \"runtime=10\"], v7\n"
        "print(\"profiles ok\")' " +
        quoted(profile / "config.yaml") + " " + quoted(profile / "config.v8+.yaml") + " 2>&1");
    if (check.output.find("No module named 'yaml'") != std::string::npos) GTEST_SKIP() << "python3-yaml is not installed";
    EXPECT_EQ(check.output, "profiles ok\n");
    EXPECT_EQ(::access((profile / "slurm-status.sh").c_str(), X_OK), 0) << "the status check is not executable";
}
