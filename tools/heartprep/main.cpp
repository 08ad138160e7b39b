// heartprep: a segmented heart MRI (label map) to a heartsim scenario, stage by stage.
#include "commands.h"
#include "terminal_progress.h"

#include "cli/cli_messages.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "cli/exit_codes.h"
#include "cli/option_flags.h"
#include "libmodel/text.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

namespace {

/// The file the command that ran was given (its positional argument: a label map, a scenario, a
/// manifest); empty for a command without one.
std::string command_file(const CLI::App& app) {
    for (const CLI::App* command : app.get_subcommands())
        for (const char* name : {"input", "scenario", "file", "manifest"})
            if (const CLI::Option* option = command->get_option_no_throw(name); option && !option->results().empty())
                return option->results().front();
    return "";
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{"heartprep: turns a segmented heart MRI (a label map: NIfTI, NRRD or MetaImage) into a heartsim\n"
                 "simulation scenario (HDF5). Units are mm, g, ms; the world frame is LPS, as ITK and DICOM.\n\n"
                 "Typical use:\n"
                 "  heartprep build case.nii.gz -o case.h5      all stages with sensible defaults\n"
                 "  heartprep inspect case.h5                   what a scenario holds\n"
                 "  heartprep surface case.nii.gz -o heart.stl  the detailed surface, for 3D Slicer or MeshLab\n"
                 "  heartprep phantom -o phantom.nii.gz         a synthetic two-ventricle heart with a septal defect\n"
                 "  heartprep defect case.nii.gz --labels mmwhs --diameter 10 -o vsd.nii.gz   a septal defect in a label map\n"
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
    heartsim::cli::add_defect_command(app);
    for (CLI::App* command : app.get_subcommands({})) command->footer(command->get_footer() + "\n" + heartsim::heartprep_exit_status_help);
    heartsim::cli_messages::require_finite_numbers(app);
    app.footer(heartsim::heartprep_exit_status_help);
    using heartsim::ExitCode;
    using heartsim::exit_status;
    // Every failure is one line `heartprep: error: FILE: what` and an exit status of the table in
    // cli/exit_codes.h (docs/user-guide.md, "Exit status"); an option libmodel names by its meaning
    // is spelled as heartprep's flag (cli/option_flags.h).
    auto fail = [](ExitCode code, const std::string& message) {
        const std::string spelled = heartsim::cli::spell_options(message, heartsim::cli::heartprep_flags);
        std::fprintf(stderr, "heartprep: error: %s\n", heartsim::one_line(spelled).c_str());
        return exit_status(code);
    };
    // A word where the command goes that names none: say which word, list the commands and
    // suggest the nearest (CLI11 would only say that a subcommand is required).
    std::vector<std::string> words;
    for (const CLI::App* command : app.get_subcommands({})) words.push_back(command->get_name());
    if (argc > 1 && argv[1][0] != '-' && std::find(words.begin(), words.end(), argv[1]) == words.end()) {
        const std::string nearest = heartsim::text::nearest_word(argv[1], words);
        return fail(ExitCode::usage, "unknown command '" + std::string(argv[1]) + "'" + (nearest.empty() ? "" : " (did you mean '" + nearest + "'?)") +
                                         "; the commands are " + heartsim::text::join(words) + " (heartprep --help)");
    }
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& error) {
        if (error.get_exit_code() == 0) return app.exit(error);  // --help, --version
        // Not CLI11's two lines and its own exit codes (104-114).
        return fail(ExitCode::usage, heartsim::cli_messages::parse_error_message(app, error, argc, argv));
    } catch (const heartsim::OptionError& error) {
        return fail(ExitCode::usage, error.what());
    } catch (const heartsim::InputError& error) {
        // libmodel names no file: the one the command was given is the one at fault.
        return fail(ExitCode::input_error, heartsim::with_file(command_file(app), error).what());
    } catch (const heartsim::OutputError& error) {
        return fail(ExitCode::internal_error, error.what());
    } catch (const std::exception& error) {
        if (heartsim::is_out_of_memory(error)) {
            // Allocations, threads that could not start, HDF5's own allocations (hdf5_io.h): one line
            // naming the stage (from the progress reporting), whatever the library's words were.
            const std::string stage = heartsim::cli::TerminalProgress::last_stage();
            return fail(ExitCode::internal_error, "out of memory while " + (stage.empty() ? std::string("starting") : "running stage '" + stage + "'") +
                                                      " (try a coarser --spacing or a smaller volume)");
        }
        return fail(ExitCode::internal_error, error.what());
    }
    return exit_status(ExitCode::success);
}
