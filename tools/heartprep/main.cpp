// heartprep: a segmented heart volume to a heartsim scenario. Subcommands are added in
// commands_*.cpp files as the pipeline grows.
#include <CLI/CLI.hpp>

int main(int argc, char** argv) {
    CLI::App app{"heartprep: segmented heart MRI to a heartsim simulation scenario"};
    app.require_subcommand(1);
    CLI11_PARSE(app, argc, argv);
    return 0;
}
