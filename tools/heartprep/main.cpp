// heartprep: a segmented heart MRI (label map) to a heartsim scenario, stage by stage.
#include "commands.h"
#include "terminal_progress.h"

#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <cstdio>
#include <string>

int main(int argc, char** argv) {
    CLI::App app{"heartprep: turns a segmented heart MRI (a label map: NIfTI, NRRD or MetaImage) into a heartsim\n"
                 "simulation scenario (HDF5). Units are mm, g, ms; the world frame is LPS, as ITK and DICOM.\n\n"
                 "Typical use:\n"
                 "  heartprep build case.nii.gz -o case.h5      all stages with sensible defaults\n"
                 "  heartprep inspect case.h5                   what a scenario holds\n"
                 "  heartprep surface case.nii.gz -o heart.stl  the detailed surface, for 3D Slicer or MeshLab\n"
                 "  heartprep phantom -o phantom.nii.gz         a synthetic two-ventricle heart with a septal defect\n"
                 "  heartprep batch cases.csv -o out/ -j 2      many cases, resumable, with a summary table\n"
                 "  heartprep export case.h5 --what simsurface -o sim.ply   meshes for 3D Slicer / MeshLab\n",
                 "heartprep"};
    app.set_version_flag("--version", std::string("heartprep ") + HEARTSIM_VERSION);
    app.require_subcommand(1);
    app.fallthrough();
    heartsim::cli::add_build_command(app);
    heartsim::cli::add_surface_command(app);
    heartsim::cli::add_inspect_command(app);
    heartsim::cli::add_phantom_command(app);
    heartsim::cli::add_stage_commands(app);
    heartsim::cli::add_batch_command(app);
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& error) {
        if (error.get_exit_code() == 0) return app.exit(error);  // --help, --version
        // One line like every other error (docs/user-guide.md), not CLI11's two and its exit code.
        std::fprintf(stderr, "heartprep: error: %s (heartprep --help lists the commands and options)\n", error.what());
        return 1;
    } catch (const heartsim::InputError& error) {
        std::fprintf(stderr, "heartprep: error: %s\n", error.what());
        return 1;
    } catch (const heartsim::OutputError& error) {
        std::fprintf(stderr, "heartprep: error: %s\n", error.what());
        return 1;
    } catch (const std::exception& error) {
        if (heartsim::is_out_of_memory(error)) {
            // Allocations, threads that could not start, HDF5's own allocations (hdf5_io.h): one line
            // naming the stage (from the progress reporting), whatever the library's words were.
            const std::string stage = heartsim::cli::TerminalProgress::last_stage();
            std::fprintf(stderr, "heartprep: error: out of memory while %s (try a coarser --spacing or a smaller volume)\n",
                         stage.empty() ? "starting" : ("running stage '" + stage + "'").c_str());
        } else {
            std::fprintf(stderr, "heartprep: error: %s\n", error.what());
        }
        return 1;
    }
    return 0;
}
