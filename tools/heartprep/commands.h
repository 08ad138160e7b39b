/// @file commands.h
/// @brief The heartprep subcommands, each registered on the CLI11 app with its options and the
/// callback that runs it. Callbacks throw heartsim::InputError / OutputError; main() prints the
/// one-line cause and exits non-zero.
#pragma once

namespace CLI {
class App;
}

namespace heartsim::cli {

void add_build_command(CLI::App& app);
void add_surface_command(CLI::App& app);
void add_inspect_command(CLI::App& app);
void add_phantom_command(CLI::App& app);
void add_stage_commands(CLI::App& app);  ///< pack, simsurface, map, export
void add_batch_command(CLI::App& app);

}  // namespace heartsim::cli
