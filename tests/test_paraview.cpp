// ParaView can open what heartsim writes: the .xmf2 beside a scenario, a saved state
// and a recording, and `heartprep export`'s .vtp/.stl/.obj/.ply, each opened by VTK's own readers
// (tests/vtk_open.py under /usr/bin/python3) and by ParaView's own File > Open (tests/paraview_open.py
// under pvpython: the reader ParaView picks by itself, which must show the scenario's three named
// blocks with their counts), and compared with what our readers find in the files. Skips with a
// message where that Python has no VTK or its VTK no XDMF reader; without pvpython that part is
// left out, with a message.
#include "formats/recording.h"
#include "formats/scenario.h"
#include "formats/state.h"
#include "formats/xdmf.h"
#include "libmodel/mesh.h"
#include "libmodel/simulation_surface.h"
#include "formats/mesh_io.h"
#include "runtime/core/trajectory.h"
#include "defect_block_scenario.h"
#include "incision_gesture.h"
#include "test_support.h"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <fstream>
#include <limits>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>

namespace heartsim {
namespace {

namespace fs = std::filesystem;
using test::quoted;

test::CommandResult run_heartsim(const std::string& arguments) { return test::run_command(quoted(HEARTSIM_EXE) + " " + arguments); }
const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border"); }
fs::path samples() { return fs::path(HEARTSIM_SOURCE_DIR) / "samples"; }

/// One line of vtk_open.py: its `key=value` words.
using Words = std::map<std::string, std::string>;

/// The `key=value` words of one line printed by the ParaView and VTK scripts.
Words words_of(const std::string& line) {
    Words words;
    std::istringstream in(line);
    for (std::string word; in >> word;) {
        const auto equals = word.find('=');
        if (equals != std::string::npos) words[word.substr(0, equals)] = word.substr(equals + 1);
    }
    return words;
}

std::size_t count(const Words& w, const std::string& key) { return w.count(key) ? std::stoull(w.at(key)) : std::size_t(-1); }

struct Opened {
    bool skipped = false;
    std::string output;
    std::vector<Words> lines;  ///< every line with at least one key=value word
    /// The blocks of `reader` at time index `time`, by name.
    std::map<std::string, Words> blocks(const std::string& reader, int time = 0) const {
        std::map<std::string, Words> found;
        for (const auto& w : lines)
            if (w.count("name") && w.at("reader") == reader && w.at("time") == std::to_string(time)) found[w.at("name")] = w;
        return found;
    }
    std::vector<std::string> readers() const {
        std::vector<std::string> names;
        for (const auto& w : lines)
            if (!w.count("name") && w.count("reader")) names.push_back(w.at("reader"));
        return names;
    }
};

/// Runs tests/vtk_open.py on `files`; skipped when it exits 3 (no VTK, or no reader for a kind).
Opened vtk_open(const std::vector<fs::path>& files) {
    Opened opened;
    if (!fs::exists("/usr/bin/python3")) {
        opened.skipped = true;
        opened.output = "/usr/bin/python3 is absent";
        return opened;
    }
    std::string command = "cd / && /usr/bin/python3 ";
    command += quoted(fs::path(HEARTSIM_SOURCE_DIR) / "tests/vtk_open.py");
    for (const auto& f : files) {
        command += ' ';
        command += quoted(f);
    }
    const auto run = test::run_command(command);
    opened.output = run.output;
    if (run.exit_code == 3) {
        opened.skipped = true;
        return opened;
    }
    EXPECT_EQ(run.exit_code, 0) << run.output;
    std::istringstream lines(run.output);
    for (std::string line; std::getline(lines, line);) {
        const Words words = words_of(line);
        if (!words.empty()) opened.lines.push_back(words);
    }
    return opened;
}

/// What ParaView's File > Open shows of a file (tests/paraview_open.py under pvpython).
struct ParaViewView {
    Words file;                              ///< reader (the one ParaView picks), readers (all it offers), points, cells, times
    std::vector<std::pair<std::string, Words>> blocks;  ///< each leaf data set: its block name ("-": none), points, cells
    std::string output;
    bool empty() const { return file.empty(); }
    /// The blocks named `name`.
    std::vector<Words> named(const std::string& name) const {
        std::vector<Words> found;
        for (const auto& [block, words] : blocks)
            if (block == name) found.push_back(words);
        return found;
    }
};

/// ParaView's File > Open of `file` (the reader ParaView picks by itself, at the first time step);
/// empty, with a message, where pvpython is absent.
ParaViewView paraview_open(const fs::path& file) {
    ParaViewView view;
    if (test::run_command("command -v pvpython").exit_code != 0) {
        std::printf("pvpython absent: ParaView's own File > Open not tried on %s\n", file.c_str());
        return view;
    }
    const auto run = test::run_command("cd / && pvpython " + quoted(fs::path(HEARTSIM_SOURCE_DIR) / "tests/paraview_open.py") + " " +
                                       quoted(file) + " 2>&1 | grep '^file=\\|^block \\|^paraview_open'");
    view.output = run.output;
    std::istringstream lines(run.output);
    for (std::string line; std::getline(lines, line);) {
        const Words words = words_of(line);
        if (line.rfind("block ", 0) == 0 && words.count("name"))
            view.blocks.emplace_back(words.at("name"), words);
        else if (line.rfind("file=", 0) == 0)
            view.file = words;
    }
    EXPECT_TRUE(view.file.count("reader")) << "ParaView did not open " << file << ": " << run.output;
    return view;
}

/// The parts of a scenario or a state as ParaView shows them by itself: its reader the only one it
/// offers (File > Open asks nothing), and one block per part, named, with these counts.
struct Part {
    std::string name;
    std::size_t points, cells;
};
void expect_paraview_parts(const fs::path& file, const std::vector<Part>& parts) {
    const ParaViewView pv = paraview_open(file);
    if (pv.empty()) return;
    const std::string reader = pv.file.count("reader") ? pv.file.at("reader") : "";
    EXPECT_EQ(pv.file.count("readers") ? pv.file.at("readers") : "", reader) << "ParaView offers other readers for " << file << "\n"
                                                                                 << pv.output;
    EXPECT_EQ(pv.blocks.size(), parts.size()) << reader << "\n" << pv.output;
    for (const Part& part : parts) {
        const auto found = pv.named(part.name);
        ASSERT_EQ(found.size(), 1u) << "no one block named " << part.name << " (" << reader << ")\n" << pv.output;
        EXPECT_EQ(count(found[0], "points"), part.points) << part.name << " (" << reader << ")";
        EXPECT_EQ(count(found[0], "cells"), part.cells) << part.name << " (" << reader << ")";
    }
}


/// VTK's bounds text "x0,x1,y0,y1,z0,z1" against the extent of `points`.
template <class P>
void expect_bounds(const Words& w, const std::vector<P>& points, double tolerance_mm, const std::string& what) {
    ASSERT_TRUE(w.count("bounds")) << what;
    std::vector<double> bounds;
    std::stringstream in(w.at("bounds"));
    for (std::string item; std::getline(in, item, ',');) bounds.push_back(std::stod(item));
    ASSERT_EQ(bounds.size(), 6u) << what;
    for (int a = 0; a < 3; ++a) {
        double low = std::numeric_limits<double>::max(), high = -low;
        for (const auto& p : points) low = std::min(low, double(p[a])), high = std::max(high, double(p[a]));
        EXPECT_NEAR(bounds[std::size_t(2 * a)], low, tolerance_mm) << what << " axis " << a;
        EXPECT_NEAR(bounds[std::size_t(2 * a + 1)], high, tolerance_mm) << what << " axis " << a;
    }
}

std::string text_of(const fs::path& path) {
    std::ifstream in(path);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// The scenario's grids as every XDMF reader sees them, against the scenario read by our reader.
void expect_scenario_grids(const fs::path& xdmf, const Scenario& s) {
    const Opened opened = vtk_open({xdmf});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    ASSERT_FALSE(opened.readers().empty()) << opened.output;
    const std::size_t n = s.lattice.particles.size();
    for (const auto& reader : opened.readers()) {
        const auto blocks = opened.blocks(reader);
        ASSERT_TRUE(blocks.count("detailed_mesh") && blocks.count("simulation_surface") && blocks.count("particles"))
            << reader << "\n" << opened.output;
        const Words& mesh = blocks.at("detailed_mesh");
        EXPECT_EQ(count(mesh, "points"), s.visual->positions.size()) << reader;
        EXPECT_EQ(count(mesh, "cells"), s.visual->triangles.size()) << reader;
        EXPECT_NE(mesh.at("arrays").find("normals"), std::string::npos) << reader;
        expect_bounds(mesh, s.visual->positions, 1e-3, reader + " detailed_mesh");
        const Words& surface = blocks.at("simulation_surface");
        EXPECT_EQ(count(surface, "points"), n) << reader;
        EXPECT_EQ(count(surface, "cells"), s.simulation_surface->size()) << reader;
        const Words& particles = blocks.at("particles");
        EXPECT_EQ(count(particles, "points"), n) << reader;
        EXPECT_EQ(count(particles, "cells"), n) << reader;
        for (const char* array : {"material", "anchored", "mass_g"}) EXPECT_NE(particles.at("arrays").find(array), std::string::npos) << reader;
        expect_bounds(particles, s.lattice.particles.rest_position, 1e-3, reader + " particles");
    }
}

/// ParaView's File > Open of a scenario's description: the detailed mesh, the simulation surface
/// and the particles as three named blocks, with the scenario file's counts.
void expect_scenario_parts_in_paraview(const fs::path& xdmf, const Scenario& s) {
    const std::size_t n = s.lattice.particles.size();
    expect_paraview_parts(xdmf, {{"detailed_mesh", s.visual->positions.size(), s.visual->triangles.size()},
                                 {"simulation_surface", n, s.simulation_surface->size()},
                                 {"particles", n, n}});
}

}  // namespace

TEST(ParaView, ScenarioXdmfOpensInVtkAndStaysWithItsH5WhenBothMove) {
    const Scenario s = read_scenario(phantom());
    ASSERT_TRUE(s.visual && s.simulation_surface);
    const fs::path xdmf = xdmf_beside(phantom());
    ASSERT_TRUE(fs::exists(xdmf)) << "heartprep build wrote no " << xdmf;
    // The .h5 is named by its final name relative to the .xdmf's folder: no folder, no temporary.
    const std::string text = text_of(xdmf);
    EXPECT_NE(text.find(">" + phantom().filename().string() + ":/visual/positions<"), std::string::npos) << text;
    EXPECT_EQ(text.find(phantom().parent_path().string()), std::string::npos) << "an absolute path in " << xdmf;
    expect_scenario_grids(xdmf, s);
    expect_scenario_parts_in_paraview(xdmf, s);
    // Moved together elsewhere, under another name for the folder, they still open.
    test::TempDir dir;
    fs::create_directory(dir / "moved");
    fs::copy_file(phantom(), dir / "moved" / phantom().filename());
    fs::copy_file(xdmf, dir / "moved" / xdmf.filename());
    expect_scenario_grids(dir / "moved" / xdmf.filename(), s);
}

TEST(ParaView, StateXdmfShowsTheDeformedParticlesSurfaceAndDetailedMesh) {
    const Scenario s = read_scenario(phantom());
    test::TempDir dir;
    const fs::path state_file = dir / "state.h5";
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --steps 40 --trajectory " +
                                  quoted(samples() / "probe_and_grab_phantom.csv") + " --save-state " + quoted(state_file));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const SimulationState state = read_state(state_file);
    ASSERT_EQ(state.visual_positions.size(), s.visual->positions.size());
    const fs::path xdmf = xdmf_beside(state_file);
    ASSERT_TRUE(fs::exists(xdmf));
    // The triangles come from the scenario, in another folder: named relative to the .xdmf's.
    const std::string text = text_of(xdmf);
    EXPECT_NE(text.find(">" + fs::relative(phantom(), dir.path()).generic_string() + ":/simsurface/triangles<"), std::string::npos) << text;
    const Opened opened = vtk_open({xdmf});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    ASSERT_FALSE(opened.readers().empty()) << opened.output;
    for (const auto& reader : opened.readers()) {
        const auto blocks = opened.blocks(reader);
        ASSERT_TRUE(blocks.count("detailed_mesh") && blocks.count("simulation_surface") && blocks.count("particles"))
            << reader << "\n" << opened.output;
        EXPECT_EQ(count(blocks.at("particles"), "points"), state.positions.size()) << reader;
        EXPECT_EQ(count(blocks.at("simulation_surface"), "points"), state.positions.size()) << reader;
        EXPECT_EQ(count(blocks.at("simulation_surface"), "cells"), s.simulation_surface->size()) << reader;
        EXPECT_EQ(count(blocks.at("detailed_mesh"), "points"), state.visual_positions.size()) << reader;
        EXPECT_EQ(count(blocks.at("detailed_mesh"), "cells"), s.visual->triangles.size()) << reader;
        // Deformed, not at rest: the extents are the state's.
        expect_bounds(blocks.at("particles"), state.positions, 1e-3, reader + " particles");
        expect_bounds(blocks.at("detailed_mesh"), state.visual_positions, 1e-3, reader + " detailed_mesh");
    }
    const std::size_t n = state.positions.size();
    expect_paraview_parts(xdmf, {{"detailed_mesh", state.visual_positions.size(), s.visual->triangles.size()},
                                 {"simulation_surface", n, s.simulation_surface->size()},
                                 {"particles", n, n}});
}

// A state saved after a scalpel opened the detailed mesh: its .xmf2 takes the state's own
// triangles (the opened mesh with its caps), not the scenario's, and VTK and ParaView open it
// with the state's counts.
TEST(ParaView, AnIncisedStateShowsTheOpenedMeshWithItsOwnTriangles) {
    const Scenario s = read_scenario(phantom());
    test::TempDir dir;
    const test::Incision plan = test::anterior_incision(s, {.length_mm = 16, .retract = false});
    test::write_trajectory_csv(plan.trajectory, dir / "incision.csv");
    const fs::path state_file = dir / "state.h5";
    char seconds[32];
    std::snprintf(seconds, sizeof seconds, "%.3f", plan.end_ms / 1000.0);
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --seconds " + seconds + " --trajectory " +
                                  quoted(dir / "incision.csv") + " --save-state " + quoted(state_file));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("incision: the detailed mesh opened along 1 stroke"), std::string::npos) << run.output;
    const SimulationState state = read_state(state_file);
    ASSERT_GT(state.visual_triangles.size(), s.visual->triangles.size());
    ASSERT_GT(state.visual_positions.size(), s.visual->positions.size());
    const fs::path xdmf = xdmf_beside(state_file);
    EXPECT_NE(text_of(xdmf).find(">state.h5:/visual/triangles<"), std::string::npos) << text_of(xdmf);
    const Opened opened = vtk_open({xdmf});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    for (const auto& reader : opened.readers()) {
        const auto blocks = opened.blocks(reader);
        ASSERT_TRUE(blocks.count("detailed_mesh")) << reader << "\n" << opened.output;
        EXPECT_EQ(count(blocks.at("detailed_mesh"), "points"), state.visual_positions.size()) << reader;
        EXPECT_EQ(count(blocks.at("detailed_mesh"), "cells"), state.visual_triangles.size()) << reader;
    }
    const std::size_t n = state.positions.size();
    expect_paraview_parts(xdmf, {{"detailed_mesh", state.visual_positions.size(), state.visual_triangles.size()},
                                 {"simulation_surface", n, s.simulation_surface->size()},
                                 {"particles", n, n}});
}

namespace {

/// The block's 8 mm VSD (defect_block_scenario.h) closed by `heartsim plan-repair`'s three-stitch
/// plan played to its end on the cpu backend: a saved state that holds a patch and its stitches,
/// its detailed mesh uncut.
struct RepairedState {
    test::TempDir dir;
    fs::path scenario = dir / "vsd.h5", state = dir / "repaired.h5";
    RepairedState() {
        test::defect_block::build_block_scenario(test::defect_block::make_block(), dir / "block.nrrd", scenario, "vsd", 3000);
        const auto planned = run_heartsim("plan-repair " + quoted(scenario) + " -o " + quoted(dir / "plan.csv") + " --stitches=3");
        if (planned.exit_code != 0) throw std::runtime_error("plan-repair failed: " + planned.output);
        double end_ms = 0.0;
        for (const InstrumentKeyframe& k : read_trajectory(dir / "plan.csv").keyframes) end_ms = std::max(end_ms, k.time_ms);
        char seconds[32];
        std::snprintf(seconds, sizeof seconds, "%.3f", 1e-3 * end_ms + 0.05);
        const auto run = run_heartsim("run " + quoted(scenario) + " --headless --backend cpu --trajectory " + quoted(dir / "plan.csv") +
                                      " --seconds " + seconds + " --leak-test 0 --save-state " + quoted(state));
        if (run.exit_code != 0) throw std::runtime_error("the repair's run failed: " + run.output);
    }
};
const RepairedState& repaired_state() {
    static const RepairedState made;
    return made;
}

}  // namespace

namespace {

/// What one HDF DataItem of an .xmf2 names: the dataset's path, its Dimensions, and its
/// NumberType and Precision.
struct HdfItem {
    std::string dataset;
    std::vector<hsize_t> dims;
    std::string number;
    int precision = 0;
};

/// Every HDF DataItem of the description `text` that reads a dataset of the file named `h5_name`.
std::vector<HdfItem> hdf_items(const std::string& text, const std::string& h5_name) {
    std::vector<HdfItem> items;
    const std::regex item(R"(<DataItem([^>]*)>([^<]*)</DataItem>)");
    auto attribute = [](const std::string& attributes, const std::string& name) {
        std::smatch m;
        return std::regex_search(attributes, m, std::regex(" " + name + "=\"([^\"]*)\"")) ? std::string(m[1]) : std::string();
    };
    for (auto it = std::sregex_iterator(text.begin(), text.end(), item); it != std::sregex_iterator(); ++it) {
        const std::string attributes = (*it)[1], content = (*it)[2];
        if (attribute(attributes, "Format") != "HDF") continue;
        const std::size_t colon = content.find(':');
        if (colon == std::string::npos || content.substr(0, colon) != h5_name) continue;
        HdfItem found{content.substr(colon + 1), {}, attribute(attributes, "NumberType"), std::atoi(attribute(attributes, "Precision").c_str())};
        std::istringstream dims(attribute(attributes, "Dimensions"));
        for (hsize_t d; dims >> d;) found.dims.push_back(d);
        items.push_back(found);
    }
    return items;
}

/// Each item is a dataset of `h5` with the item's shape and number type (read with HDF5's C API,
/// not heartsim's reader).
void expect_datasets_as_described(const fs::path& h5, const std::vector<HdfItem>& items) {
    const hid_t file = H5Fopen(h5.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    ASSERT_GE(file, 0) << h5;
    for (const HdfItem& item : items) {
        SCOPED_TRACE(item.dataset);
        // Each link on the way must exist (H5Lexists on a path whose parent is missing fails).
        bool exists = true;
        for (std::size_t slash = item.dataset.find('/', 1); exists; slash = item.dataset.find('/', slash + 1)) {
            const std::string prefix = item.dataset.substr(0, slash);
            exists = H5Lexists(file, prefix.c_str(), H5P_DEFAULT) > 0;
            if (slash == std::string::npos) break;
        }
        EXPECT_TRUE(exists) << "the .xmf2 names " << item.dataset << ", absent from " << h5;
        if (!exists) continue;
        const hid_t dataset = H5Dopen2(file, item.dataset.c_str(), H5P_DEFAULT);
        ASSERT_GE(dataset, 0);
        const hid_t space = H5Dget_space(dataset), type = H5Dget_type(dataset);
        std::vector<hsize_t> dims(std::size_t(std::max(H5Sget_simple_extent_ndims(space), 0)));
        H5Sget_simple_extent_dims(space, dims.data(), nullptr);
        EXPECT_EQ(dims, item.dims);
        const H5T_class_t type_class = H5Tget_class(type);
        EXPECT_EQ(item.number, type_class == H5T_FLOAT ? "Float" : type_class == H5T_INTEGER ? "Int" : "?");
        EXPECT_EQ(std::size_t(item.precision), H5Tget_size(type));
        H5Tclose(type), H5Sclose(space), H5Dclose(dataset);
    }
    H5Fclose(file);
}

}  // namespace

// A repaired state's .xmf2 shows the repair as it ended: besides the tissue, the `patch` (its
// mid-surface, /patch) and its `stitches` (a vertex per stitch at its tissue point, carrying its
// pull), with the state's counts, in VTK's readers and in ParaView's own File > Open.
TEST(ParaView, ARepairedStateShowsThePatchAndItsStitches) {
    const RepairedState& r = repaired_state();
    const SimulationState state = read_state(r.state);
    ASSERT_TRUE(state.patch.has_value());
    const PatchState& patch = *state.patch;
    const std::size_t stitches = patch.stitch_vertex.size();
    ASSERT_EQ(stitches, 3u);
    ASSERT_FALSE(patch.triangles.empty());
    // The plan's hand 0 lays the patch, hand 1 ties with the needle: kinds 4 and 5 (docs/runtime.md).
    EXPECT_EQ(state.kind, (std::array<std::int32_t, 2>{4, 5}));
    const Scenario s = read_scenario(r.scenario);
    const fs::path xdmf = xdmf_beside(r.state);
    const std::string text = text_of(xdmf);
    EXPECT_NE(text.find(">repaired.h5:/patch/triangles<"), std::string::npos) << text;
    EXPECT_NE(text.find(">repaired.h5:/patch/stitch_anchor<"), std::string::npos) << text;
    // Every dataset of the state the description reads is in the state file, with the shape and
    // number type it says; the patch's and the stitches' among them.
    const std::vector<HdfItem> items = hdf_items(text, "repaired.h5");
    std::set<std::string> named;
    for (const HdfItem& item : items) named.insert(item.dataset);
    for (const char* dataset : {"/positions", "/patch/positions", "/patch/triangles", "/patch/stitch_anchor", "/patch/stitch_force"})
        EXPECT_TRUE(named.count(dataset)) << dataset << " not read by the .xmf2:\n" << text;
    expect_datasets_as_described(r.state, items);
    std::printf("  the .xmf2 reads %zu datasets of repaired.h5 (%zu distinct), each checked there\n", items.size(), named.size());
    const std::size_t n = state.positions.size();
    const Opened opened = vtk_open({xdmf});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    ASSERT_FALSE(opened.readers().empty()) << opened.output;
    for (const auto& reader : opened.readers()) {
        const auto blocks = opened.blocks(reader);
        ASSERT_TRUE(blocks.count("patch") && blocks.count("stitches")) << reader << "\n" << opened.output;
        EXPECT_EQ(count(blocks.at("patch"), "points"), patch.positions.size()) << reader;
        EXPECT_EQ(count(blocks.at("patch"), "cells"), patch.triangles.size()) << reader;
        expect_bounds(blocks.at("patch"), patch.positions, 1e-3, reader + " patch");
        EXPECT_EQ(count(blocks.at("stitches"), "points"), stitches) << reader;
        EXPECT_EQ(count(blocks.at("stitches"), "cells"), stitches) << reader;
        EXPECT_NE(blocks.at("stitches").at("arrays").find("force_n"), std::string::npos) << reader;
        expect_bounds(blocks.at("stitches"), patch.stitch_anchor, 1e-3, reader + " stitches");
    }
    expect_paraview_parts(xdmf, {{"detailed_mesh", state.visual_positions.size(), s.visual->triangles.size()},
                                 {"simulation_surface", n, s.simulation_surface->size()},
                                 {"particles", n, n},
                                 {"patch", patch.positions.size(), patch.triangles.size()},
                                 {"stitches", stitches, stitches}});
}

// `heartprep export` of a saved state: its deformed detailed mesh with the patch by default, the
// patch alone or the mesh alone with --what, each with the state's own vertex and triangle counts;
// an uncut state keeps no triangles of its own, so without the scenario it ran (--scenario) the
// export says what to give.
TEST(ParaView, ExportOfARepairedStateWritesItsMeshAndPatch) {
    const RepairedState& r = repaired_state();
    const SimulationState state = read_state(r.state);
    ASSERT_TRUE(state.patch.has_value());
    ASSERT_TRUE(state.visual_triangles.empty()) << "uncut: the scenario's triangles apply";
    const Scenario s = read_scenario(r.scenario);
    test::TempDir dir;
    const auto without = test::heartprep("export " + quoted(r.state) + " -o " + quoted(dir / "x.ply"));
    EXPECT_EQ(without.exit_code, 2) << without.output;
    EXPECT_NE(without.output.find("give the scenario it ran, --scenario vsd.h5"), std::string::npos) << without.output;
    EXPECT_FALSE(fs::exists(dir / "x.ply"));
    const std::size_t mesh_vertices = state.visual_positions.size(), mesh_triangles = s.visual->triangles.size(),
                      patch_vertices = state.patch->positions.size(), patch_triangles = state.patch->triangles.size();
    struct Case {
        std::string what;
        std::size_t vertices, triangles;
    };
    for (const Case& c : {Case{"", mesh_vertices + patch_vertices, mesh_triangles + patch_triangles}, Case{"visual", mesh_vertices, mesh_triangles},
                          Case{"patch", patch_vertices, patch_triangles}}) {
        SCOPED_TRACE(c.what);
        const fs::path out = dir / ((c.what.empty() ? std::string("default") : c.what) + ".ply");
        const auto run = test::heartprep("export " + quoted(r.state) + " --scenario " + quoted(r.scenario) +
                                         (c.what.empty() ? "" : " --what " + c.what) + " -o " + quoted(out));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        const TriangleMesh read = read_mesh(out);
        EXPECT_EQ(read.positions.size(), c.vertices);
        EXPECT_EQ(read.triangles.size(), c.triangles);
        std::vector<std::array<float, 3>> expected = c.what == "patch" ? state.patch->positions : state.visual_positions;
        if (c.what.empty()) expected.insert(expected.end(), state.patch->positions.begin(), state.patch->positions.end());
        for (int a = 0; a < 3; ++a) {
            double low = 1e30, high = -1e30, read_low = 1e30, read_high = -1e30;
            for (const auto& p : expected) low = std::min(low, double(p[a])), high = std::max(high, double(p[a]));
            for (const auto& p : read.positions) read_low = std::min(read_low, p[a]), read_high = std::max(read_high, p[a]);
            EXPECT_NEAR(read_low, low, 1e-4) << "axis " << a;
            EXPECT_NEAR(read_high, high, 1e-4) << "axis " << a;
        }
    }
    // A state that holds no patch, and a scenario asked for one.
    const auto scenario_patch = test::heartprep("export " + quoted(r.scenario) + " --what patch -o " + quoted(dir / "p.ply"));
    EXPECT_EQ(scenario_patch.exit_code, 2) << scenario_patch.output;
    EXPECT_NE(scenario_patch.output.find("a scenario holds no patch"), std::string::npos) << scenario_patch.output;
}

TEST(ParaView, RecordingXdmfIsATimeSeriesOfTheToolsAndForces) {
    test::TempDir dir;
    const fs::path file = dir / "rec.h5";
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device scripted:" +
                                  quoted(samples() / "haptics/grab_phantom.csv") + " --seconds 1 --record " + quoted(file));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const Recording r = read_recording(file);
    ASSERT_GT(r.steps.size(), 1u);
    // The steps shown: every one, or every k-th and the last (xdmf.h).
    const std::size_t stride = xdmf_step_stride(r.steps.size());
    const std::size_t shown = (r.steps.size() - 1) / stride + 1 + ((r.steps.size() - 1) % stride != 0);
    const Opened opened = vtk_open({xdmf_beside(file)});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    ASSERT_FALSE(opened.readers().empty()) << opened.output;
    for (const auto& w : opened.lines) {
        if (w.count("name") || !w.count("reader")) continue;
        const std::string reader = w.at("reader");
        EXPECT_EQ(count(w, "times"), shown) << reader << " for " << r.steps.size() << " steps\n" << opened.output;
        ASSERT_TRUE(w.count("first") && w.count("last")) << opened.output;
        EXPECT_EQ(std::stod(w.at("first")), r.steps.time_ms.front()) << reader;
        EXPECT_EQ(std::stod(w.at("last")), r.steps.time_ms.back()) << reader;
        for (const int time : {0, 1}) {
            const auto blocks = opened.blocks(reader, time);
            ASSERT_EQ(blocks.size(), 1u) << reader << "\n" << opened.output;
            const Words& tools = blocks.begin()->second;
            EXPECT_EQ(count(tools, "points"), 2u) << reader;
            EXPECT_EQ(count(tools, "cells"), 2u) << reader;
            for (const char* array : {"force_n", "applied", "grab"}) EXPECT_NE(tools.at("arrays").find(array), std::string::npos) << reader;
            // The two hands' tool positions of that step.
            const auto& step = time == 0 ? r.steps.tool_position_mm.front() : r.steps.tool_position_mm.back();
            expect_bounds(tools, std::vector<std::array<double, 3>>(step.begin(), step.end()), 1e-9, reader + " tools");
        }
    }
    if (const ParaViewView pv = paraview_open(xdmf_beside(file)); !pv.empty()) {
        EXPECT_EQ(count(pv.file, "times"), shown) << pv.output;
        EXPECT_EQ(count(pv.file, "points"), 2u) << pv.output;
        // One data set (the two tools), not a multiblock: nothing to name.
        EXPECT_EQ(pv.blocks.size(), 1u) << pv.output;
    }
}

namespace {

/// A recording of `steps` steps, hand 0 moving along x, written by our writer.
Recording synthetic_recording(int steps) {
    Recording r;
    r.scenario = "phantom.h5";
    r.particles = 10;
    r.dt_ms = 0.1;
    r.substeps = 1;
    for (int s = 0; s < steps; ++s) {
        r.steps.time_ms.push_back(0.1 * (s + 1));
        r.steps.wall_ms.push_back(s);
        r.steps.tool_time_ms.push_back(s);
        r.steps.tool_position_mm.push_back({{{0.01 * s, 2, 3}, {4, 5, 6}}});
        r.steps.tool_orientation.push_back({{{1, 0, 0, 0}, {1, 0, 0, 0}}});
        r.steps.grab.push_back({0, 0});
        r.steps.applied.push_back({1, 0});
        r.steps.force_n.push_back({{{0, 0, 0.5 * s}, {0, 0, 0}}});
        r.steps.force_step.push_back(s - 1);
        r.steps.diverged.push_back(0);
    }
    return r;
}

}  // namespace

TEST(ParaView, RecoveredRecordingGetsItsXdmfUnderTheFinalNameAndLongOnesShowEveryKthStepAndTheLast) {
    test::TempDir dir;
    const Recording r = synthetic_recording(5);
    write_recording_data(dir / "plain.h5", r);
    EXPECT_FALSE(fs::exists(xdmf_beside(dir / "plain.h5"))) << "write_recording_data writes the HDF5 alone";
    write_recording(dir / "rec.h5", r);
    // Longer than xdmf_max_time_steps, by a count that is not a multiple of the stride.
    const Recording longer = synthetic_recording(int(2 * xdmf_max_time_steps + 1));
    write_recording(dir / "long.h5", longer);
    const Opened opened = vtk_open({xdmf_beside(dir / "rec.h5"), xdmf_beside(dir / "long.h5")});
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    std::vector<Words> series;
    for (const auto& w : opened.lines)
        if (!w.count("name") && w.count("reader")) series.push_back(w);
    ASSERT_EQ(series.size() % 2, 0u) << opened.output;
    for (std::size_t i = 0; i < series.size(); ++i) {
        const Recording& expected = i < series.size() / 2 ? r : longer;
        const std::size_t k = (expected.steps.size() + xdmf_max_time_steps - 1) / xdmf_max_time_steps;  // ⌈S / 2000⌉
        const std::size_t every_kth = (expected.steps.size() - 1) / k + 1;
        const bool last_extra = (expected.steps.size() - 1) % k != 0;
        EXPECT_EQ(count(series[i], "times"), every_kth + last_extra) << opened.output;
        EXPECT_EQ(std::stod(series[i].at("first")), expected.steps.time_ms.front());
        EXPECT_EQ(std::stod(series[i].at("last")), expected.steps.time_ms.back());
    }
}

TEST(ParaView, ExportsOpenInVtkReadersWithTheCountsOfTheScenario) {
    const Scenario s = read_scenario(phantom());
    TriangleMesh visual_mesh;
    for (const auto& p : s.visual->positions) visual_mesh.positions.emplace_back(p[0], p[1], p[2]);
    visual_mesh.triangles = s.visual->triangles;
    const TriangleMesh& visual = visual_mesh;
    const TriangleMesh surface = simulation_surface_mesh(s.lattice.particles.rest_position, s.simulation_surface->triangles);
    test::TempDir dir;
    std::vector<fs::path> files;
    std::map<std::string, const TriangleMesh*> meshes;
    for (const auto& [what, mesh] : {std::pair{"visual", &visual}, std::pair{"simsurface", &surface}})
        for (const char* extension : {".vtp", ".stl", ".obj", ".ply"}) {
            const fs::path out = dir / (std::string(what) + extension);
            const auto run = test::heartprep("export " + quoted(phantom()) + " --what " + what + " -o " + quoted(out));
            ASSERT_EQ(run.exit_code, 0) << run.output;
            files.push_back(out);
            meshes[out.string()] = mesh;
        }
    const Opened opened = vtk_open(files);
    if (opened.skipped) GTEST_SKIP() << "VTK cannot be used: " << opened.output;
    std::size_t seen = 0;
    for (const auto& w : opened.lines) {
        if (!w.count("file")) continue;
        ++seen;
        const std::string& file = w.at("file");
        const TriangleMesh& mesh = *meshes.at(file);
        const MeshReport report = analyse_mesh(mesh);
        EXPECT_EQ(count(w, "cells"), mesh.triangles.size()) << file;
        // STL stores corners per facet; merged, they are the vertices the triangles use.
        const bool stl = fs::path(file).extension() == ".stl";
        EXPECT_EQ(count(w, "points"), stl ? report.vertices : mesh.positions.size()) << file;
        EXPECT_EQ(count(w, "open_edges"), report.boundary_edges + report.nonmanifold_edges) << file;
        if (report.closed() && report.manifold()) {
            EXPECT_EQ(count(w, "open_edges"), 0u) << file;
        }
        std::vector<Eigen::Vector3d> used;
        for (const auto& t : mesh.triangles)
            for (const auto v : t) used.push_back(mesh.positions[std::size_t(v)]);
        expect_bounds(w, used, 1e-3, file);
    }
    EXPECT_EQ(seen, files.size()) << opened.output;
    if (const ParaViewView pv = paraview_open(dir / "visual.vtp"); !pv.empty()) {
        EXPECT_EQ(count(pv.file, "points"), visual.positions.size()) << pv.output;
        EXPECT_EQ(count(pv.file, "cells"), visual.triangles.size()) << pv.output;
    }
}

TEST(ParaView, RealCaseScenarioOpens) {
    const fs::path input = test::real_case("hvsmr16_pat1");
    if (input.empty() || !fs::exists(input)) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA;
    test::TempDir dir;
    const auto build = test::heartprep("build " + quoted(input) + " -o " + quoted(dir / "pat1.h5") + " --cavity 2 --anchor-border -q");
    ASSERT_EQ(build.exit_code, 0) << build.output;
    const Scenario s = read_scenario(dir / "pat1.h5");
    expect_scenario_grids(xdmf_beside(dir / "pat1.h5"), s);
    expect_scenario_parts_in_paraview(xdmf_beside(dir / "pat1.h5"), s);
}

}  // namespace heartsim
