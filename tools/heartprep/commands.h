/// @file commands.h
/// @brief The heartprep subcommands, each registered on the CLI11 app with its options and the
/// callback that runs it. Callbacks throw heartsim::InputError / OutputError; main() prints the
/// one-line cause and exits non-zero.
#pragma once

#include <string>
#include <vector>

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
void add_defect_command(CLI::App& app);

struct DefectChoice;
/// The options that choose a septal defect, for `defect` and `build`: --type or --defect (as
/// `type_flag` says), --diameter, --at, --site, --max-wall. `apply` turns what was given into
/// `choice` (throws UsageError for an --at that is not three numbers).
struct DefectFlags {
    std::string type;
    double diameter_mm = 10.0;
    std::vector<double> at;
    std::string site;
    double max_wall_mm = 20.0;
    void add(CLI::App& command, const char* type_flag, const char* group);
    void apply(DefectChoice& choice) const;
};

}  // namespace heartsim::cli
