// The XDMF description beside each .h5 (xdmf.h): XML text that names the .h5's datasets (a
// recording's: copies of its few per-step values).
#include "xdmf.h"

#include "atomic_file.h"
#include "recording.h"
#include "scenario.h"
#include "state.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <vector>
#include <sstream>

namespace heartsim {

namespace {

std::string escaped(const std::string& text) {
    std::string out;
    for (const char c : text) {
        switch (c) {
        case '&': out += "&amp;"; break;
        case '<': out += "&lt;"; break;
        case '>': out += "&gt;"; break;
        case '"': out += "&quot;"; break;
        default: out += c;
        }
    }
    return out;
}

/// XDMF's NumberType and Precision of the element types our files use.
struct Type {
    const char* number;
    int precision;
};
constexpr Type f32{"Float", 4}, f64{"Float", 8}, i32{"Int", 4}, u8{"UChar", 1};

std::string dims_text(std::initializer_list<std::size_t> dims) {
    std::string text;
    for (const std::size_t d : dims) {
        if (!text.empty()) text += ' ';
        text += std::to_string(d);
    }
    return text;
}

std::string number(double value) {
    char text[40];
    std::snprintf(text, sizeof text, "%.17g", value);
    return text;
}

/// A DataItem of `type` and `dims` whose content is `content` in `format` (HDF: a dataset's path;
/// XML: the values themselves).
std::string data_item(std::initializer_list<std::size_t> dims, Type type, const char* format, const std::string& content,
                      const std::string& indent) {
    return indent + "<DataItem Dimensions=\"" + dims_text(dims) + "\" NumberType=\"" + type.number + "\" Precision=\"" +
           std::to_string(type.precision) + "\" Format=\"" + format + "\">" + content + "</DataItem>\n";
}

/// A DataItem reading dataset `dataset` of `file` (a path relative to the .xdmf's folder).
std::string hdf(const std::string& file, const std::string& dataset, std::initializer_list<std::size_t> dims, Type type,
                const std::string& indent) {
    return data_item(dims, type, "HDF", escaped(file) + ":" + dataset, indent);
}

/// A DataItem holding `values` in the XML itself.
template <class T>
std::string inline_values(const std::vector<T>& values, std::initializer_list<std::size_t> dims, Type type, const std::string& indent) {
    std::string text;
    for (const T value : values) {
        if (!text.empty()) text += ' ';
        text += number(double(value));
    }
    return data_item(dims, type, "XML", text, indent);
}

const char* header = "<?xml version=\"1.0\" ?>\n<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n";

std::string document(const std::string& comment, const std::string& grids) {
    return std::string(header) + "<!-- " + comment + " -->\n<Xdmf Version=\"2.0\">\n  <Domain>\n" + grids + "  </Domain>\n</Xdmf>\n";
}

/// A uniform grid of triangles over `points` (a DataItem's text, [points, 3]).
std::string triangle_grid(const std::string& name, const std::string& file, const std::string& triangles, std::size_t count,
                          const std::string& geometry, const std::string& attributes = "") {
    return "    <Grid Name=\"" + name + "\" GridType=\"Uniform\">\n      <Topology TopologyType=\"Triangle\" NumberOfElements=\"" +
           std::to_string(count) + "\">\n" + hdf(file, triangles, {count, 3}, i32, "        ") +
           "      </Topology>\n      <Geometry GeometryType=\"XYZ\">\n" + geometry + "      </Geometry>\n" + attributes + "    </Grid>\n";
}

/// A uniform grid of one vertex cell per point. The connectivity 0 … count−1 is written out in
/// the XML: the Xdmf3 reader makes no cells from a Polyvertex topology without one, and the .h5
/// holds no such index list.
std::string vertex_grid(const std::string& name, std::size_t count, const std::string& geometry, const std::string& attributes = "",
                        const std::string& time = "") {
    std::string indices;
    indices.reserve(count * 7);
    for (std::size_t i = 0; i < count; ++i) {
        indices += std::to_string(i);
        indices += (i + 1) % 16 == 0 && i + 1 < count ? '\n' : ' ';
    }
    if (!indices.empty()) indices.pop_back();
    return "    <Grid Name=\"" + name + "\" GridType=\"Uniform\">\n" + time + "      <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"" +
           std::to_string(count) + "\" NodesPerElement=\"1\">\n" + data_item({count}, i32, "XML", indices, "        ") + "      </Topology>\n" +
           "      <Geometry GeometryType=\"XYZ\">\n" + geometry + "      </Geometry>\n" + attributes + "    </Grid>\n";
}

std::string attribute(const std::string& name, const char* kind, const std::string& item) {
    return "      <Attribute Name=\"" + name + "\" AttributeType=\"" + kind + "\" Center=\"Node\">\n" + item + "      </Attribute>\n";
}

}  // namespace

std::filesystem::path xdmf_beside(const std::filesystem::path& h5) {
    std::filesystem::path path = h5;
    path.replace_extension(xdmf_extension);
    // An .h5 someone named `x.xmf2` keeps its data: its description is `x.xmf2.xmf2`.
    return path == h5 ? std::filesystem::path(h5.string() + xdmf_extension) : path;
}

std::string xdmf_given_instead_of_h5(const std::filesystem::path& path) {
    std::string extension = path.extension().string();
    std::transform(extension.begin(), extension.end(), extension.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (extension != xdmf_extension && extension != ".xdmf") return {};
    // The names xdmf_beside maps to `path`: x.h5, x.hdf5, and `x.xmf2` itself for `x.xmf2.xmf2`.
    std::vector<std::filesystem::path> described;
    for (const char* h5 : {".h5", ".hdf5"}) described.push_back(std::filesystem::path(path).replace_extension(h5));
    if (path.stem().extension() == xdmf_extension) described.push_back(path.parent_path() / path.stem());
    std::error_code error;
    const auto found = std::find_if(described.begin(), described.end(), [&](const auto& h5) {
        return std::filesystem::is_regular_file(h5, error) && xdmf_beside(h5) == path;
    });
    if (found != described.end())
        return "it is ParaView's description (XDMF) of " + found->string() + " beside it, which holds the data: give " + found->string();
    return "it is ParaView's description (XDMF) of an .h5 that holds the data and should lie beside it (" + described.front().string() +
           ", not there): give that .h5";
}

void check_xdmf_destination(const std::filesystem::path& h5) {
    const auto path = xdmf_beside(h5);
    try {
        check_destination(path);
    } catch (const OutputError& e) {
        throw OutputError(std::string(e.what()) + " (the ParaView description written beside " + h5.string() + ")");
    }
}

std::string scenario_xdmf(const std::string& h5, const Scenario& s) {
    std::string grids;
    const std::size_t n = s.lattice.particles.size();
    const std::string rest = hdf(h5, "/particles/rest_position", {n, 3}, f32, "        ");
    if (s.visual) {
        const std::size_t v = s.visual->positions.size();
        grids += triangle_grid("detailed_mesh", h5, "/visual/triangles", s.visual->triangles.size(),
                               hdf(h5, "/visual/positions", {v, 3}, f32, "        "),
                               attribute("normals", "Vector", hdf(h5, "/visual/normals", {v, 3}, f32, "        ")));
    }
    if (s.simulation_surface) grids += triangle_grid("simulation_surface", h5, "/simsurface/triangles", s.simulation_surface->size(), rest);
    grids += vertex_grid("particles", n, rest,
                         attribute("material", "Scalar", hdf(h5, "/particles/material", {n}, i32, "        ")) +
                             attribute("anchored", "Scalar", hdf(h5, "/particles/anchored", {n}, u8, "        ")) +
                             attribute("mass_g", "Scalar", hdf(h5, "/particles/mass", {n}, f32, "        ")));
    return document("heartsim scenario " + escaped(h5) + ": world mm, LPS, as stored (docs/scenario-format.md)", grids);
}

std::string state_xdmf(const std::string& h5, const SimulationState& state, const std::filesystem::path& xdmf_folder) {
    std::string grids;
    const std::size_t n = state.positions.size();
    const std::string time = "      <Time Value=\"" + number(state.time_ms) + "\"/>\n";
    const std::string positions = hdf(h5, "/positions", {n, 3}, f32, "        ");
    if (!state.scenario_path.empty()) {
        namespace fs = std::filesystem;
        std::error_code error;
        const fs::path scenario = fs::weakly_canonical(fs::absolute(state.scenario_path), error);
        const fs::path folder = fs::weakly_canonical(fs::absolute(xdmf_folder.empty() ? fs::path(".") : xdmf_folder), error);
        fs::path relative = scenario.lexically_relative(folder);
        if (relative.empty()) relative = scenario;
        const std::string file = relative.generic_string();
        if (!state.visual_triangles.empty())  // opened by an incision: the state's own triangles
            grids += triangle_grid("detailed_mesh", h5, "/visual/triangles", state.visual_triangles.size(),
                                   hdf(h5, "/visual/positions", {state.visual_positions.size(), 3}, f32, "        "));
        else if (!state.visual_positions.empty() && state.scenario_visual_triangles > 0)
            grids += triangle_grid("detailed_mesh", file, "/visual/triangles", state.scenario_visual_triangles,
                                   hdf(h5, "/visual/positions", {state.visual_positions.size(), 3}, f32, "        "));
        if (state.scenario_simsurface_triangles > 0)
            grids += triangle_grid("simulation_surface", file, "/simsurface/triangles", state.scenario_simsurface_triangles, positions);
    }
    grids += vertex_grid("particles", n, positions, "", time);
    if (state.patch) {
        // The repair as it ended: the patch's mid-surface, and each stitch's tissue point carrying
        // its pull on the patch.
        const PatchState& patch = *state.patch;
        if (!patch.triangles.empty())
            grids += triangle_grid("patch", h5, "/patch/triangles", patch.triangles.size(),
                                   hdf(h5, "/patch/positions", {patch.positions.size(), 3}, f32, "        "));
        const std::size_t stitches = patch.stitch_vertex.size();
        if (stitches > 0)
            grids += vertex_grid("stitches", stitches, hdf(h5, "/patch/stitch_anchor", {stitches, 3}, f32, "        "),
                                 attribute("force_n", "Vector", hdf(h5, "/patch/stitch_force", {stitches, 3}, f64, "        ")));
    }
    return document("heartsim saved state " + escaped(h5) + " (" + escaped(state.scenario) + ", " + number(state.time_ms) +
                        " ms simulated): world mm, LPS, as stored (docs/runtime.md)",
                    grids);
}

std::size_t xdmf_step_stride(std::size_t steps) {
    return steps <= xdmf_max_time_steps ? 1 : (steps + xdmf_max_time_steps - 1) / xdmf_max_time_steps;
}

std::string recording_xdmf(const std::string& h5, const Recording& r) {
    // The columns agree in a recording that write_recording_data accepts; the shortest bounds the
    // rows read here in case they do not (that writer then refuses the recording).
    const std::size_t steps = std::min({r.steps.time_ms.size(), r.steps.tool_position_mm.size(), r.steps.force_n.size(),
                                        r.steps.applied.size(), r.steps.grab.size()}),
                      stride = xdmf_step_stride(steps);
    std::string grids = "    <Grid Name=\"instruments\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
    const std::string in = "          ";
    // Steps 0, k, 2k, … and the last.
    std::vector<std::size_t> shown;
    for (std::size_t step = 0; step < steps; step += stride) shown.push_back(step);
    if (steps > 0 && shown.back() != steps - 1) shown.push_back(steps - 1);
    for (const std::size_t step : shown) {
        // The step's values are copied into the XML: VTK's Xdmf3 reader reads no HyperSlab of the
        // [S,2,3] datasets (it makes no points of one) and its XDMF 2 reader logs an error for each.
        std::vector<double> position, force;
        std::vector<int> applied, grab;
        for (int hand = 0; hand < 2; ++hand) {
            for (int c = 0; c < 3; ++c) {
                position.push_back(r.steps.tool_position_mm[step][std::size_t(hand)][std::size_t(c)]);
                force.push_back(r.steps.force_n[step][std::size_t(hand)][std::size_t(c)]);
            }
            applied.push_back(r.steps.applied[step][std::size_t(hand)]);
            grab.push_back(r.steps.grab[step][std::size_t(hand)]);
        }
        const std::string grid = vertex_grid("step_" + std::to_string(step), 2, inline_values(position, {2, 3}, f64, in),
                                             attribute("force_n", "Vector", inline_values(force, {2, 3}, f64, in)) +
                                                 attribute("applied", "Scalar", inline_values(applied, {2}, i32, in)) +
                                                 attribute("grab", "Scalar", inline_values(grab, {2}, i32, in)),
                                             "      <Time Value=\"" + number(r.steps.time_ms[step]) + "\"/>\n");
        // One level deeper than a top-level grid.
        std::string indented;
        std::istringstream lines(grid);
        for (std::string line; std::getline(lines, line);) indented += "  " + line + "\n";
        grids += indented;
    }
    grids += "    </Grid>\n";
    return document("heartsim recording " + escaped(h5) + " (" + escaped(r.scenario) +
                        "): the two hands' tool positions and forces per simulation step, copied from its /steps, world mm, LPS "
                        "(docs/runtime.md)",
                    grids);
}

FileBeside xdmf_file_beside(const std::filesystem::path& h5, const std::string& text) {
    return {xdmf_beside(h5), text, "the XDMF description"};
}

void write_xdmf(const std::filesystem::path& h5, const std::string& text) {
    const auto path = xdmf_beside(h5);
    write_bytes_atomically(path, text.data(), text.size(), "the XDMF description " + path.string());
}

void write_scenario_xdmf(const std::filesystem::path& h5, const Scenario& scenario) {
    write_xdmf(h5, scenario_xdmf(h5.filename().string(), scenario));
}

}  // namespace heartsim
