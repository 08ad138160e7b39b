// `heartprep build` and `heartprep surface`: the pipeline from a label map.
#include "commands.h"
#include "pipeline.h"
#include "terminal_progress.h"

#include "formats/atomic_file.h"
#include "formats/mesh_io.h"
#include "formats/xdmf.h"
#include "cli/cli_messages.h"
#include "libmodel/stability.h"
#include "libmodel/plausible.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <tbb/global_control.h>

#include <cstdio>
#include <memory>
#include <optional>

namespace heartsim::cli {

namespace {

void add_selection_options(CLI::App& command, LabelChoice& labels, SelectionOptions& o) {
    command.add_option("--tissue", labels.tissue,
                       "Labels that become simulated tissue: numbers, or segment names (case-insensitive) from a 3D Slicer "
                       ".seg.nrrd or --labels (e.g. --tissue myocardium). Default: 1 (HVSMR: 1 = myocardium), unless the "
                       "segments are named and label 1 is not heart muscle by name: then the segments named as heart muscle")
        ->delimiter(',')
        ->type_name("L[,L...]")
        ->group("Tissue");
    command.add_option("--cavity", labels.cavity, "Labels (numbers or segment names) of blood-filled cavities (HVSMR: 2 = blood pool), reported")
        ->delimiter(',')
        ->type_name("L[,L...]")
        ->group("Tissue");
    command.add_option("--anchor-label", labels.anchor,
                       "Tissue touching voxels of these labels (numbers or segment names) is anchored (does not move)")
        ->delimiter(',')
        ->type_name("L[,L...]")
        ->group("Tissue");
    command.add_option("--labels", labels.label_table,
                       "Label names for a volume that carries none (NIfTI, MetaImage, NRRD), or to rename a .seg.nrrd's: a "
                       "convention by name (" + label_convention_names() + ": mmwhs is MM-WHS 2017's 205 myocardium, 420 "
                       "left atrium, 500 left ventricle, 550 right atrium, 600 right ventricle, 820 aorta, 850 pulmonary "
                       "artery; with a convention the tissue defaults to its myocardium and the cavities to its blood), or "
                       "a file: a 3D Slicer colour table (VALUE NAME R G B A), an ITK-SNAP label description file (VALUE R "
                       "G B A VIS MSH \"NAME\") or a CSV (VALUE,NAME,...)")
        ->type_name("NAME|FILE")
        ->group("Tissue");
    command.add_flag("--anchor-border", o.anchor_border,
                     "Anchor tissue where it touches the volume border (vessels cut by the crop)")
        ->group("Tissue");
    command.add_option("--min-island", o.min_island_mm3, "Drop detached tissue islands smaller than this, mm³")
        ->check(cli_messages::non_negative())
        ->capture_default_str()
        ->group("Tissue");
}

void add_surface_options(CLI::App& command, SurfaceOptions& o) {
    command.add_option("--smoothing", o.smoothing_factor,
                       "Surface smoothing factor in [0, 1] as in 3D Slicer (windowed-sinc pass band 10^(-4·factor)); 0 = off")
        ->check(CLI::Range(0.0, 1.0))
        ->capture_default_str()
        ->group("Surface");
    command.add_option("--smoothing-iterations", o.smoothing_iterations, "Windowed-sinc iterations")
        ->check(CLI::Range(1, 1000))
        ->capture_default_str()
        ->group("Surface");
    command.add_option("--decimate", o.decimation, "Fraction of surface triangles to remove, in [0, 1); 0 = none")
        ->check(CLI::Range(0.0, 0.99))
        ->capture_default_str()
        ->group("Surface");
}

void check_output_path(const std::filesystem::path& output, const std::string& extension_hint) {
    if (output.empty()) throw UsageError("no output file given (-o " + extension_hint + ")");
    check_destination(output);  // a folder, a path through a file, a missing or read-only folder
}

/// A scenario's output and the ParaView description written beside it (OUT.xmf2).
void check_scenario_output_path(const std::filesystem::path& output) {
    check_output_path(output, "OUT.h5");
    check_xdmf_destination(output);
}

/// What `build`'s flags hold until its callback turns them into BuildOptions.
struct BuildFlags {
    BuildOptions options;
    std::string output;
    Material material;
    double density = 1.06;  // g/cm³
    bool quiet = false, verbose = false, strict = false;
    int threads = 0;
    std::string packing = "bricks", thin_walls = "thicken", mapping = "auto", support = "posterior", rest_state = "balanced";
    std::string walls = "grown";
    std::vector<double> gravity;
    DefectFlags defect;
    std::string batch_key;
};

void add_wall_options(CLI::App& command, std::string& walls, WallThicknesses& t) {
    command.add_option("--walls", walls,
                       "grown: where a chamber's or vessel's blood faces background (its wall not labelled: MM-WHS's right "
                       "ventricle, atria and great vessels, HVSMR's atria and vessels), grow a wall of the thickness below "
                       "outward into background only, so the heart is whole (docs/user-guide.md, \"Walls grown where the labels "
                       "show only blood\"); labelled: the label map's walls as they are")
        ->check(CLI::IsMember({"grown", "labelled"}))
        ->capture_default_str()
        ->group("Walls");
    const struct {
        const char* flag;
        double* value;
        const char* help;
    } thicknesses[] = {
        {"--wall-rv", &t.right_ventricle, "Grown right ventricle free wall, mm (typical adult: 3-5)"},
        {"--wall-lv", &t.left_ventricle, "Grown wall where the left ventricle's blood has no labelled wall, mm"},
        {"--wall-atria", &t.atria, "Grown left and right atrial walls, mm (typical adult: about 2)"},
        {"--wall-aorta", &t.aorta, "Grown aortic wall, mm (typical adult: about 2)"},
        {"--wall-pa", &t.pulmonary_artery, "Grown pulmonary artery wall, mm (typical adult: 1-1.5)"},
        {"--wall-blood-pool", &t.blood_pool, "Grown wall around one blood label for every chamber and vessel (HVSMR 2016's blood pool, or --cavity without a convention), mm"},
    };
    for (const auto& entry : thicknesses)
        command.add_option(entry.flag, *entry.value, entry.help)
            ->check(cli_messages::within(plausible::wall_thickness_mm))
            ->capture_default_str()
            ->group("Walls");
}

void add_particle_options(CLI::App& command, BuildFlags& f) {
    LayoutOptions& layout = f.options.layout;
    command.add_option("--packing", f.packing, "GPU layout: bricks (Morton-ordered 4³ bricks) or slices (Sørensen & Mosegaard's z-slice texture)")
        ->check(CLI::IsMember({"bricks", "slices"}))
        ->capture_default_str()
        ->group("Particles");
    command.add_option("--spacing", layout.spacing_mm, "Lattice spacing, mm (default: chosen to meet --particles)")
        ->check(cli_messages::within(plausible::lattice_spacing_mm))
        ->group("Particles");
    command.add_option("--particles", layout.particle_budget, "Particle budget when the spacing is chosen")
        ->check(CLI::Range(std::size_t(1), std::size_t(50'000'000)))
        ->capture_default_str()
        ->group("Particles");
    command.add_option("--occupancy", layout.occupancy, "Minimal tissue fraction of a cell to get a particle, (0, 1]")
        ->check(CLI::Range(1e-6, 1.0))
        ->capture_default_str()
        ->group("Particles");
    command.add_option("--thin-walls", f.thin_walls,
                       "thicken: a wall too thin for any cell to reach --occupancy still gets particles along its ridge "
                       "(cells holding at least --ridge-fraction), and where a wall is one particle thick along a lattice "
                       "axis the neighbour cell on the side with more tissue also gets one (if it holds at least "
                       "--thicken-fraction), so the wall can bend and the visual mesh has a cell of particles to follow; "
                       "keep: only cells reaching --occupancy")
        ->check(CLI::IsMember({"thicken", "keep"}))
        ->capture_default_str()
        ->group("Particles");
    command.add_option("--ridge-fraction", layout.ridge_fraction,
                       "Least tissue fraction of a cell on the ridge of a thin wall to get a particle, (0, 1]")
        ->check(CLI::Range(1e-6, 1.0))
        ->capture_default_str()
        ->group("Particles");
    command.add_option("--thicken-fraction", layout.thicken_fraction,
                       "Least tissue fraction of a cell added to thicken a wall, (0, 1]")
        ->check(CLI::Range(1e-6, 1.0))
        ->capture_default_str()
        ->group("Particles");
}

void add_material_options(CLI::App& command, BuildFlags& f) {
    command.add_option("--mapping", f.mapping,
                       "How visual vertices follow the particles: auto (each vertex embedded in a lattice cell: a "
                       "weighted sum of up to 8 particles, exact under any affine motion; in tangent space only where no "
                       "cell embeds it well and that is less sensitive to particle motion), or tangent (the "
                       "tangent-space mapping of Mosegaard & Sørensen alone, for comparison)")
        ->check(CLI::IsMember({"auto", "tangent"}))
        ->capture_default_str()
        ->group("Surface");
    command.add_option("--density", f.density, "Tissue density, g/cm³ (stored as g/mm³)")
        ->check(cli_messages::within(plausible::density_g_per_cm3))
        ->capture_default_str()
        ->group("Material");
    command.add_option("--youngs-modulus", f.material.youngs_modulus_kpa,
                       "Young's modulus, kPa (passive myocardium: 10-50); spring stiffness k = E·spacing/(2(1 + ν)), 0.4·E·spacing at ν = 0.25")
        ->check(cli_messages::within(plausible::youngs_modulus_kpa))
        ->capture_default_str()
        ->group("Material");
    command.add_option("--damping-ratio", f.material.damping_ratio, "Spring damping as a fraction of critical damping")
        ->check(cli_messages::within(plausible::damping_ratio))
        ->capture_default_str()
        ->group("Material");
    command.add_option("--poisson-ratio", f.material.poisson_ratio,
                       "Poisson's ratio, 0.25 to 0.499 (myocardium is nearly incompressible: 0.45-0.5). The springs "
                       "give the tissue 0.25; above it a volume term on the lattice's cells makes up the rest, and the "
                       "simulation costs more: the step shrinks 1.8x at 0.45 and 4.2x at 0.49, and each substep takes "
                       "about 2.3x as long on the cpu backend (docs/benchmarks.md \"The tissue's own Poisson's ratio\")")
        ->check(cli_messages::within(plausible::poisson_ratio))
        ->capture_default_str()
        ->group("Material");
}

void add_holding_options(CLI::App& command, BuildFlags& f) {
    BuildOptions& o = f.options;
    command.add_option("--support", f.support,
                       "How the heart is held besides its anchors: posterior (springs on the heart's back, where it lies "
                       "on the posterior mediastinum), boundary (springs on every surface particle: the whole pericardium) "
                       "or none")
        ->check(CLI::IsMember({"posterior", "boundary", "none"}))
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_option("--support-stiffness", o.supports.stiffness_kpa_per_mm,
                       "Support stiffness per supported area, kPa/mm (N/mm per mm² × 1000)")
        ->check(cli_messages::non_negative())
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_option("--embedding-stiffness", o.supports.embedding_kpa_per_mm2,
                       "Weak elastic foundation on every free particle (surrounding tissue and fluid), kPa/mm² "
                       "(N/mm per mm³ × 1000); holds the one-particle-thick parts of a wall; 0 = off")
        ->check(cli_messages::non_negative())
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_option("--support-damping", o.supports.damping_ratio,
                       "Damping ratio of each support against its particle's mass (a dashpot c = 2ζ√(k·m)): the viscous "
                       "tissue around the heart; 0 lets the heart ring on its supports")
        ->check(cli_messages::within(plausible::damping_ratio))
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_option("--rest-state", f.rest_state,
                       "balanced: the imaged shape is the static equilibrium under gravity (pre-stressed springs: nothing "
                       "sags at t = 0); imaged: unstressed springs at the imaged shape (it sags when the simulation starts)")
        ->check(CLI::IsMember({"balanced", "imaged"}))
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_option("--drop-free-below", o.free_pieces.drop_below_particles,
                       "Lattice pieces held by nothing (no anchor, no support) with fewer particles are dropped; larger "
                       "ones are an error")
        ->check(CLI::Range(std::size_t(0), std::size_t(50'000'000)))
        ->capture_default_str()
        ->group("Holding the heart");
    command.add_flag("--allow-free", o.free_pieces.allow_free,
                     "Keep pieces held by nothing, of any size (they fall under gravity and drift under instruments)")
        ->group("Holding the heart");
}

void add_solver_and_run_options(CLI::App& command, BuildFlags& f) {
    command.add_option("--gravity", f.gravity, "Gravity vector in LPS, mm/ms² (default 0 0.00981 0: supine patient, 9.81 m/s² to posterior)")
        ->expected(3)
        ->group("Solver");
    command.add_option("--drag", f.options.solver.damping, "Global velocity damping rate, 1/ms")
        ->check(cli_messages::within(plausible::drag_per_ms))
        ->capture_default_str()
        ->group("Solver");
    command.add_option("--dt-safety", f.options.solver.safety_factor, "Default dt as a fraction of the damped critical step (dashpots and supports included); "
                       "the runtime keeps every substep within the same fraction")
        ->check(CLI::Range(min_safety_factor, max_safety_factor))
        ->capture_default_str()
        ->group("Solver");
    command.add_flag("-q,--quiet", f.quiet, "No progress and no summary (warnings are still printed)");
    command.add_flag("-v,--verbose", f.verbose,
                     "Every figure of the build after the summary: volumes and islands, the surface's topology, the lattice, "
                     "supports and rest state, the time step, packing, simulation surface, mapping, stage times");
    command.add_flag("--strict", f.strict,
                     "Refuse to write a scenario whose build warned (exit 1, the warnings printed): for batches, where "
                     "nobody reads the warnings of each case");
    command.add_option("--threads", f.threads, "Threads the build may use (0 = every core); `batch` sets it per case")
        ->check(CLI::Range(0, 4096))
        ->capture_default_str();
    f.defect.add(command, "--defect", "Septal defect (heartprep defect --help)");
    command.add_option("--batch-key", f.batch_key, "Stored in the file so `heartprep batch` can skip unchanged cases")->group("");
}

/// Turns the flags into f.options; throws UsageError for a combination the flags' own checks cannot see.
void apply_build_flags(BuildFlags& f, const CLI::App& command) {
    BuildOptions& o = f.options;
    check_scenario_output_path(f.output);
    // A file given but missing (exit 1, docs/user-guide.md) is refused now, not after the surface is built.
    if (!o.visual_mesh.empty() && !std::filesystem::is_regular_file(o.visual_mesh))
        throw InputError(o.visual_mesh.string() + ": cannot read the mesh: no such file");
    if (!f.gravity.empty()) {
        o.solver.gravity = Eigen::Vector3d(f.gravity[0], f.gravity[1], f.gravity[2]);
        if (!o.solver.gravity.allFinite()) throw UsageError("--gravity must be three finite numbers");
        if (!plausible::gravity_mm_per_ms2.contains(o.solver.gravity.stableNorm()))
            throw UsageError("--gravity: " + plausible::outside("its length", o.solver.gravity.stableNorm(), plausible::gravity_mm_per_ms2) +
                             " (9.81 m/s² is 0.00981 mm/ms²)");
    }
    o.supports.region = parse_support_region(f.support);
    if (f.rest_state != "balanced" && f.rest_state != "imaged")
        throw UsageError("--rest-state must be balanced or imaged, got '" + f.rest_state + "'");
    o.balance_rest_state = f.rest_state == "balanced";
    if (f.thin_walls != "thicken" && f.thin_walls != "keep")
        throw UsageError("--thin-walls must be thicken or keep, got '" + f.thin_walls + "'");
    o.layout.thicken_walls = f.thin_walls == "thicken";
    o.walls.grow = f.walls == "grown";
    if (!o.walls.grow)
        for (const char* thickness : {"--wall-rv", "--wall-lv", "--wall-atria", "--wall-aorta", "--wall-pa", "--wall-blood-pool"})
            if (command.count(thickness) > 0)
                throw UsageError(std::string(thickness) + " is the thickness of a grown wall, and --walls labelled grows none: leave one out");
    o.mapping = parse_mapping_method(f.mapping);
    f.material.density = f.density * 1e-3;
    o.layout.materials = {f.material};  // label and name follow the tissue chosen (build_scenario)
    o.packing.scheme = parse_packing_scheme(f.packing);
    o.batch_key = f.batch_key;
    if (!f.defect.type.empty()) {
        DefectChoice choice;
        f.defect.apply(choice);
        o.defect = choice;
    } else {
        // Without --defect these shape nothing: a build that silently made no defect was taken for one with it.
        for (const char* shaping : {"--at", "--site", "--diameter", "--max-wall"})
            if (command.count(shaping) > 0)
                throw UsageError(std::string(shaping) + " shapes a septal defect, and no --defect was given: add --defect vsd or "
                                                        "--defect asd, or leave " + shaping + " out");
    }
}

/// Builds, writes and reports the scenario the flags describe.
void run_build(BuildFlags& f) {
    // Every parallel loop of the pipeline is oneTBB's: its global limit is the build's.
    std::optional<tbb::global_control> thread_limit;
    if (f.threads > 0) thread_limit.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(f.threads));
    TerminalProgress progress(f.quiet);
    BuildReport report;
    Scenario scenario = build_scenario(f.options, progress, report);
    scenario.batch_key = f.options.batch_key;
    scenario.build_warnings = report.warnings;
    if (f.strict && !report.warnings.empty()) {
        print_warnings(report.warnings);
        throw InputError(f.options.input.string() + ": --strict: the build warned " + std::to_string(report.warnings.size()) +
                         " time(s) (above); nothing written");
    }
    {
        ProgressStage stage(progress, "write scenario", 0);
        write_readable_scenario(f.output, scenario);
    }
    if (!f.quiet) {
        print_plain_summary(report, scenario, f.output);
        if (f.verbose) print_build_summary(report, scenario);
        std::printf("wrote       %s (%.1f MB)\n", f.output.c_str(), double(std::filesystem::file_size(f.output)) / 1e6);
    }
    print_warnings(report.warnings);
}

}  // namespace

void add_build_command(CLI::App& app) {
    auto* command = app.add_subcommand("build", "All stages: label map -> scenario (surface, particles, springs, time step)");
    command->footer(
        "\nExamples:\n  heartprep build training_axial_crop_pat1-label.nii.gz -o pat1.h5\n"
        "  heartprep build case.seg.nrrd -o case.h5 --tissue myocardium --cavity \"blood pool\"\n"
        "  heartprep build case.nii.gz --labels case-labels.txt -o case.h5 --tissue myocardium\n"
        "  heartprep build ct_train_1002_label.nii.gz --labels mmwhs -o ct1002.h5 --wall-rv 4\n"
        "Segment names come from a 3D Slicer .seg.nrrd or --labels; a tissue whose name is not heart muscle\n"
        "(blood pool, cavity, vessel, ...) is built with a warning (docs/user-guide.md, \"Segment names\").\n"
        "Where a convention's blood faces background (MM-WHS's right ventricle, atria and great vessels; HVSMR's\n"
        "atria and vessels), a wall is grown into the background (--walls; docs/user-guide.md, \"Walls grown\n"
        "where the labels show only blood\").\n"
        "A NIfTI whose qform and sform disagree is read as ITK and 3D Slicer read it, with a warning saying\n"
        "which one is used and how far apart they are.\n"
        "By default the heart lies on support springs on its posterior surface and its imaged shape is the\n"
        "equilibrium under gravity: it stays where it was imaged (docs/user-guide.md, \"How the heart is held\").\n"
        "By default the lattice spacing is chosen so the model has at most --particles particles.\n"
        "The output is written atomically: a failed run leaves no file behind.");
    auto flags = std::make_shared<BuildFlags>();
    BuildOptions& options = flags->options;
    command->add_option("input", options.input, "Label map: .nii, .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd")->required();
    command->add_option("-o,--output", flags->output, "Scenario file to write (.h5)")
        ->required()
        ->check(cli_messages::output_extension({".h5", ".hdf5"}, "a scenario is an HDF5 file (meshes: heartprep surface or export)"));
    add_selection_options(*command, options.labels, options.selection);
    add_wall_options(*command, flags->walls, options.walls.thickness);
    add_surface_options(*command, options.surface);
    command->add_flag("--no-visual", [flags](std::int64_t) { flags->options.visual = false; },
                      "Skip the visual surface (the runtime then draws the simulation surface)")
        ->group("Surface");
    command->add_option("--visual-mesh", options.visual_mesh,
                        "Use this mesh (STL/OBJ/PLY in LPS mm, e.g. from 3D Slicer; glTF in its own metres, +Y up) as the visual mesh instead of marching cubes")
        ->group("Surface");
    add_particle_options(*command, *flags);
    add_material_options(*command, *flags);
    add_holding_options(*command, *flags);
    add_solver_and_run_options(*command, *flags);
    command->callback([flags, command] {
        apply_build_flags(*flags, *command);
        run_build(*flags);
    });
}

void add_surface_command(CLI::App& app) {
    auto* command = app.add_subcommand("surface", "The detailed tissue surface only: label map -> mesh file (LPS, mm)");
    command->footer("\nExample:\n  heartprep surface case.nii.gz -o heart.stl --smoothing 0.5\n"
                    "Formats by extension: .stl (binary), .obj, .ply (binary), .vtp (VTK XML PolyData, for ParaView), .glb.\n"
                    "STL, OBJ, PLY and VTP hold LPS mm, the default frame of 3D Slicer's model files (STL, OBJ and PLY\n"
                    "say SPACE=LPS in their header; STL facets carry their true normals). A .glb is in glTF's own frame:\n"
                    "metres, +Y superior, +Z anterior.");
    auto input = std::make_shared<std::filesystem::path>();
    auto output = std::make_shared<std::string>();
    auto labels = std::make_shared<LabelChoice>();
    auto selection = std::make_shared<SelectionOptions>();
    auto surface = std::make_shared<SurfaceOptions>();
    auto quiet = std::make_shared<bool>(false);
    command->add_option("input", *input, "Label map: .nii, .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd")->required();
    command->add_option("-o,--output", *output, "Mesh file to write: .stl, .obj, .ply, .vtp, .glb")->required();
    add_selection_options(*command, *labels, *selection);
    auto walls_mode = std::make_shared<std::string>("grown");
    auto walls = std::make_shared<WallChoice>();
    add_wall_options(*command, *walls_mode, walls->thickness);
    add_surface_options(*command, *surface);
    command->add_flag("-q,--quiet", *quiet, "No progress and no summary (warnings are still printed)");
    command->callback([=] {
        walls->grow = *walls_mode == "grown";
        check_output_path(*output, "OUT.stl");
        if (!is_writable_mesh_path(*output))
            throw UsageError(*output + ": unsupported mesh format '" + std::filesystem::path(*output).extension().string() +
                             "' (expected " + writable_mesh_formats + ")");
        TerminalProgress progress(*quiet);
        BuildReport report;
        auto selected = read_and_select(*input, *labels, *selection, progress, report, std::nullopt, *walls);
        TriangleMesh mesh = extract_surface(selected.selection.tissue, *surface, progress, &report.surface);
        const MeshReport check = analyse_mesh(mesh);
        {
            ProgressStage stage(progress, "write mesh", 0);
            write_mesh(*output, mesh);
        }
        if (!*quiet) {
            std::printf("surface  %zu vertices, %zu triangles; %s; Euler characteristic %ld; %zu component(s); "
                        "area %.0f mm²; volume %.1f mL\n",
                        check.vertices, check.faces, check.closed() && check.manifold() ? "closed 2-manifold" : "NOT closed/manifold",
                        check.euler_characteristic, check.components, check.area, check.volume / 1000.0);
            std::printf("time     marching cubes %.3f s, smoothing %.3f s, decimation %.3f s\n", report.surface.seconds_marching_cubes,
                        report.surface.seconds_smoothing, report.surface.seconds_decimation);
            std::printf("wrote    %s (%s)\n", output->c_str(), written_mesh_frame(*output));
        }
        print_warnings(report.warnings);
        print_warnings(report.surface.warnings);
    });
}

}  // namespace heartsim::cli
