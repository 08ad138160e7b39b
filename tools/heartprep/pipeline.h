/// @file pipeline.h
/// @brief The heartprep stages wired together: read → select → surface → layout → stability →
/// scenario. Each stage is a libmodel function; this file only sequences, times and reports.
#pragma once

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/mesh.h"
#include "libmodel/select.h"
#include "libmodel/stability.h"
#include "libmodel/surface.h"

#include <filesystem>
#include <string>
#include <vector>

namespace heartsim::cli {

struct BuildOptions {
    std::filesystem::path input;
    SelectionOptions selection;
    SurfaceOptions surface;
    bool visual = true;              ///< extract the visual mesh (the marching-cubes surface)
    LayoutOptions layout;
    SolverSettings solver;           ///< gravity, damping and safety factor are inputs; steps computed
};

struct StageTime {
    std::string stage;
    double seconds = 0.0;
};

struct BuildReport {
    VolumeHeader header;
    SelectionReport selection;
    SurfaceReport surface;
    MeshReport mesh;
    LayoutReport layout;
    StabilityEstimate stability;
    std::vector<StageTime> times;
    std::vector<std::string> warnings;  ///< every stage's warnings, in order
};

/// Reads a label volume and selects tissue: the first stages shared by `build` and `surface`.
struct SelectedVolume {
    LabelVolume volume;
    Selection selection;
};
SelectedVolume read_and_select(const std::filesystem::path& input, const SelectionOptions& options,
                               Progress& progress, BuildReport& report);

/// Runs every stage and returns the scenario (not yet written).
Scenario build_scenario(const BuildOptions& options, Progress& progress, BuildReport& report);

/// Prints a human summary of `report` (and the scenario) to stdout.
void print_build_summary(const BuildReport& report, const Scenario& scenario);

}  // namespace heartsim::cli
