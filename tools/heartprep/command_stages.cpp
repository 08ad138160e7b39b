// The stage subcommands that work on a scenario file: pack, simsurface, map, export.
#include "commands.h"
#include "pipeline.h"
#include "terminal_progress.h"

#include "formats/atomic_file.h"
#include "formats/mesh_io.h"
#include "formats/state.h"
#include "formats/xdmf.h"
#include "cli/cli_messages.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <cctype>
#include <cstdio>
#include <memory>
#include <optional>

namespace heartsim::cli {

namespace {

/// Input scenario and output path shared by the stage commands: -o defaults to updating the
/// input in place (atomically: the old file stays intact until the new one is complete).
struct StageFiles {
    std::filesystem::path input;
    std::filesystem::path output;
    bool quiet = false;
    std::filesystem::path target() const { return output.empty() ? input : output; }
};

std::shared_ptr<StageFiles> add_stage_files(CLI::App& command) {
    auto files = std::make_shared<StageFiles>();
    command.add_option("scenario", files->input, "Scenario file (.h5) made by `heartprep build`")->required();
    command.add_option("-o,--output", files->output, "Write here instead of updating the input in place")
        ->check(cli_messages::output_extension({".h5", ".hdf5"}, "a scenario is an HDF5 file"));
    command.add_flag("-q,--quiet", files->quiet, "No progress and no summary (warnings are still printed)");
    return files;
}

std::shared_ptr<std::string> add_mapping_option(CLI::App& command) {
    auto method = std::make_shared<std::string>("auto");
    command.add_option("--mapping", *method, "auto (visual vertices embedded in lattice cells) or tangent (the tangent-space mapping alone)")
        ->check(CLI::IsMember({"auto", "tangent"}))
        ->capture_default_str();
    return method;
}

/// The scenario a stage writes and its ParaView description: places that cannot take them are
/// refused before the stage's work, as heartprep build does.
void check_stage_output(const StageFiles& files) {
    if (!files.output.empty()) check_destination(files.output);
    check_xdmf_destination(files.target());
}

void finish(const StageFiles& files, const BuildReport& report, const Scenario& scenario, TerminalProgress& progress) {
    {
        ProgressStage stage(progress, "write scenario", 0);
        write_readable_scenario(files.target(), scenario);
    }
    print_warnings(report.warnings);
    if (files.quiet) return;
    for (const auto& t : report.times) std::printf("%-14s %.3f s\n", t.stage.c_str(), t.seconds);
    std::printf("wrote          %s\n", files.target().c_str());
}

void add_pack_command(CLI::App& app) {
    auto* command = app.add_subcommand("pack", "Reorder a scenario's particles for the GPU; write /packing (neighbour table, texels)");
    auto files = add_stage_files(*command);
    auto scheme = std::make_shared<std::string>("bricks");
    command->add_option("--packing", *scheme, "bricks (Morton-ordered 4³ bricks) or slices (Sørensen & Mosegaard's z-slice texture)")
        ->check(CLI::IsMember({"bricks", "slices"}))
        ->capture_default_str();
    auto width = std::make_shared<int>(0);
    command->add_option("--texture-width", *width, "Texture width for bricks, texels (0: power of two ≥ √N)")
        ->check(CLI::Range(0, 16384))
        ->capture_default_str();
    command->callback([=] {
        check_stage_output(*files);
        TerminalProgress progress(files->quiet);
        Scenario scenario = read_scenario(files->input);
        BuildReport report;
        pack_stage(scenario, {.scheme = parse_packing_scheme(*scheme), .texture_width = *width}, progress, report);
        if (!files->quiet)
            std::printf("packing        %s, %d x %d texels, %.1f%% occupied, position texture %.2f MB, neighbours %.2f MB, "
                        "%.0f%% of springs within a 4 KB window\n",
                        scheme->c_str(), report.packing.width, report.packing.height, 100 * report.packing.occupancy,
                        double(report.packing.texture_bytes) / 1e6, double(report.packing.neighbour_bytes) / 1e6,
                        100 * report.packing.springs_within_window);
        finish(*files, report, scenario, progress);
    });
}

void add_simsurface_command(CLI::App& app) {
    auto* command = app.add_subcommand("simsurface", "Build /simsurface: the closed surface over the boundary particles "
                                                     "(and redo /mapping when there is a visual mesh)");
    auto files = add_stage_files(*command);
    auto method = add_mapping_option(*command);
    command->callback([=] {
        check_stage_output(*files);
        TerminalProgress progress(files->quiet);
        Scenario scenario = read_scenario(files->input);
        BuildReport report;
        simulation_surface_stage(scenario, progress, report);
        if (scenario.visual) mapping_stage(scenario, {}, progress, report, parse_mapping_method(*method));
        const auto& r = report.simulation_surface;
        if (!files->quiet)
            std::printf("simsurface     %zu triangles over %zu boundary particles, %zu component(s), Euler characteristic %ld, "
                        "%zu non-manifold edges, %zu non-manifold vertices, %zu thin-wall triangles in %zu sheet region(s)\n",
                        r.triangles, r.boundary_particles, r.components, r.euler_characteristic, r.nonmanifold_edges,
                        r.nonmanifold_vertices, r.thin_wall_triangles, r.sheet_regions);
        finish(*files, report, scenario, progress);
    });
}

void add_map_command(CLI::App& app) {
    auto* command = app.add_subcommand("map", "Tie every visual vertex to the simulation surface: write /mapping");
    command->footer("\nWith --visual-mesh, a mesh made elsewhere (e.g. exported from 3D Slicer, LPS mm) replaces /visual.");
    auto files = add_stage_files(*command);
    auto mesh = std::make_shared<std::filesystem::path>();
    command->add_option("--visual-mesh", *mesh, "STL/OBJ/PLY/glTF mesh to use as the visual mesh");
    auto method = add_mapping_option(*command);
    command->callback([=] {
        check_stage_output(*files);
        TerminalProgress progress(files->quiet);
        Scenario scenario = read_scenario(files->input);
        if (!scenario.visual && mesh->empty())
            throw InputError(files->input.string() + ": has no /visual mesh to map; give --visual-mesh FILE");
        BuildReport report;
        mapping_stage(scenario, *mesh, progress, report, parse_mapping_method(*method));
        if (!mesh->empty() && scenario.landmarks)  // found on the surface just replaced: no longer on it
            scenario.landmarks = missing_landmarks("the detailed surface was replaced (--visual-mesh) after they were found on the "
                                                   "label map's: heartprep build finds them on its own surface");
        if (!files->quiet)
            std::printf("mapping        %zu visual vertices (%zu embedded in lattice cells, %zu in tangent space), rest error "
                        "max %.2g mm, tangent offset mean %.3f mm max %.3f mm, sensitivity bound max %.2f\n",
                        scenario.mapping->offset.size(), report.mapping.embedded, report.mapping.tangent,
                        report.mapping.max_rest_error_mm, report.mapping.mean_offset_mm, report.mapping.max_offset_mm,
                        report.mapping.max_amplification);
        finish(*files, report, scenario, progress);
    });
}

void add_export_command(CLI::App& app) {
    auto* command = app.add_subcommand("export", "Write a scenario's or a saved state's meshes for 3D Slicer / MeshLab / ParaView");
    command->footer("\nFormats by extension: .stl .obj .ply (LPS mm, 3D Slicer's default for model files, SPACE=LPS in the\n"
                    "header), .vtp (VTK XML PolyData for ParaView, LPS mm as stored, no transform) and .glb (glTF's own\n"
                    "frame: metres, +Y superior, +Z anterior). ParaView also opens the scenario itself through the\n"
                    "case.xmf2 written beside case.h5.\n"
                    "A saved state (heartsim run --save-state) gives its meshes as they ended: the deformed detailed mesh\n"
                    "(opened, caps included, once a scalpel cut it) and the patch laid on it, by default both in one mesh.\n"
                    "An uncut state keeps the detailed mesh's positions but not its triangles, and no simulation surface:\n"
                    "give the scenario it ran with --scenario.");
    auto input = std::make_shared<std::filesystem::path>();
    auto output = std::make_shared<std::filesystem::path>();
    auto scenario_path = std::make_shared<std::filesystem::path>();
    auto what = std::make_shared<std::string>();
    command->add_option("file", *input, "Scenario file (.h5), or a state saved by heartsim run --save-state")->required();
    command->add_option("--what", *what,
                        "visual (the detailed mesh; a scenario's default), simsurface, or of a saved state: patch, "
                        "visual+patch (its default where a patch was laid)")
        ->check(CLI::IsMember({"simsurface", "visual", "patch", "visual+patch"}));
    command->add_option("--scenario", *scenario_path, "With a saved state: the scenario it ran, for the triangles it does not keep");
    command->add_option("-o,--output", *output, "Mesh file: .stl, .obj, .ply, .vtp, .glb")->required();
    command->callback([=] {
        check_destination(*output);  // a folder ("unsupported mesh format ''"), /proc ("disk full?" after the work)
        if (!is_writable_mesh_path(*output))
            throw UsageError(output->string() + ": unsupported mesh format '" + output->extension().string() + "' (expected " +
                             writable_mesh_formats + ")");
        TriangleMesh mesh;
        std::string part = *what;
        if (is_state_file(*input)) {
            const SimulationState state = read_state(*input);
            if (part.empty()) part = state.patch ? "visual+patch" : "visual";
            std::optional<Scenario> scenario;
            // The scenario's triangles over the state's positions: the scenario must be the one it ran.
            auto ran = [&](const char* triangles) -> const Scenario& {
                if (scenario) return *scenario;
                if (scenario_path->empty())
                    throw UsageError(input->string() + ": a saved state keeps no " + triangles + ": give the scenario it ran, --scenario " +
                                     (state.scenario.empty() ? std::string("CASE.h5") : state.scenario));
                scenario = read_scenario(*scenario_path);
                if (scenario->lattice.particles.size() != state.positions.size())
                    throw InputError(input->string() + ": holds " + std::to_string(state.positions.size()) + " particles and --scenario " +
                                     scenario_path->string() + " " + std::to_string(scenario->lattice.particles.size()) +
                                     ": give the scenario the state was saved from (it names '" + state.scenario + "')");
                return *scenario;
            };
            if (part == "simsurface") {
                const Scenario& s = ran("simulation surface triangles");
                if (!s.simulation_surface) throw InputError(scenario_path->string() + ": has no /simsurface (run `heartprep simsurface`)");
                mesh = simulation_surface_mesh(state.positions, s.simulation_surface->triangles);
            }
            if (part == "visual" || part == "visual+patch") {
                if (state.visual_positions.empty())
                    throw InputError(input->string() + ": holds no detailed mesh (/visual: the scenario it ran has none)");
                if (!state.visual_triangles.empty()) {
                    mesh = simulation_surface_mesh(state.visual_positions, state.visual_triangles);
                } else {
                    const Scenario& s = ran("detailed mesh triangles until a scalpel opened it");
                    if (!s.visual || s.visual->positions.size() != state.visual_positions.size())
                        throw InputError(input->string() + ": holds " + std::to_string(state.visual_positions.size()) +
                                         " detailed mesh vertices and --scenario " + scenario_path->string() + " " +
                                         std::to_string(s.visual ? s.visual->positions.size() : 0) +
                                         ": give the scenario the state was saved from (it names '" + state.scenario + "')");
                    mesh = simulation_surface_mesh(state.visual_positions, s.visual->triangles);
                }
            }
            if (part == "patch" || part == "visual+patch") {
                if (!state.patch || state.patch->triangles.empty())
                    throw InputError(input->string() + ": holds no patch (/patch: none was laid in the run)" +
                                     (part == "visual+patch" ? "; --what visual gives the detailed mesh alone" : ""));
                // The patch after the detailed mesh's vertices, in one mesh.
                const TriangleMesh patch = simulation_surface_mesh(state.patch->positions, state.patch->triangles);
                const auto offset = std::int32_t(mesh.positions.size());
                mesh.positions.insert(mesh.positions.end(), patch.positions.begin(), patch.positions.end());
                for (auto t : patch.triangles) mesh.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
            }
        } else {
            if (!scenario_path->empty())
                throw UsageError("--scenario " + scenario_path->string() + ": --scenario is for a saved state, and " + input->string() +
                                 " is a scenario");
            if (part.empty()) part = "visual";
            if (part == "patch" || part == "visual+patch")
                throw UsageError("--what " + part + ": a scenario holds no patch; a state saved by heartsim run --save-state after a "
                                 "repair does");
            const Scenario scenario = read_scenario(*input);
            if (part == "simsurface") {
                if (!scenario.simulation_surface) throw InputError(input->string() + ": has no /simsurface (run `heartprep simsurface`)");
                mesh = simulation_surface_mesh(scenario.lattice.particles.rest_position, scenario.simulation_surface->triangles);
            } else {
                if (!scenario.visual) throw InputError(input->string() + ": has no /visual mesh");
                for (const auto& p : scenario.visual->positions) mesh.positions.emplace_back(p[0], p[1], p[2]);
                for (const auto& n : scenario.visual->normals) mesh.normals.emplace_back(n[0], n[1], n[2]);
                mesh.triangles = scenario.visual->triangles;
            }
        }
        write_mesh(*output, mesh);
        const MeshReport check = analyse_mesh(mesh);
        std::printf("wrote %s: %s, %zu vertices, %zu triangles, %s, %s\n", output->c_str(), part.c_str(), check.vertices,
                    check.faces, check.closed() && check.manifold() ? "closed 2-manifold" : "not a closed 2-manifold",
                    written_mesh_frame(*output));
    });
}

}  // namespace

void add_stage_commands(CLI::App& app) {
    add_pack_command(app);
    add_simsurface_command(app);
    add_map_command(app);
    add_export_command(app);
}

}  // namespace heartsim::cli
