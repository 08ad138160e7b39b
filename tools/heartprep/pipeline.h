/// @file pipeline.h
/// @brief The heartprep stages wired together: read → select → surface → layout → stability →
/// scenario. Each stage is a libmodel function; this file only sequences, times and reports.
#pragma once

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/packing.h"
#include "libmodel/simulation_surface.h"
#include "libmodel/mesh.h"
#include "libmodel/select.h"
#include "libmodel/stability.h"
#include "libmodel/supports.h"
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
    PackingOptions packing;
    SupportOptions supports;         ///< how the heart is held besides its anchors
    FreePieceOptions free_pieces;    ///< what happens to lattice pieces nothing holds
    /// Make the imaged shape the static equilibrium under gravity (pre-stressed springs and
    /// supports, supports.h balance_rest_state); false keeps unstressed springs (it then sags).
    bool balance_rest_state = true;
    /// A mesh made elsewhere (3D Slicer; STL/OBJ/PLY/glTF) to use as the visual mesh instead of
    /// the marching-cubes surface. Empty = none.
    std::filesystem::path visual_mesh;
    MappingMethod mapping = MappingMethod::automatic;  ///< how visual vertices are tied to particles
    std::string batch_key;           ///< see Scenario::batch_key
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
    SupportReport supports;
    FreePieceReport free_pieces;
    RestBalanceReport balance;
    StabilityEstimate stability;
    PackingReport packing;
    SimulationSurfaceReport simulation_surface;
    MappingReport mapping;
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

/// Packs the scenario's particles (re-packs a packed one); the simulation surface follows.
void pack_stage(Scenario& scenario, const PackingOptions& options, Progress& progress, BuildReport& report);

/// Builds /simsurface from the particles; drops a /mapping made for an older surface.
void simulation_surface_stage(Scenario& scenario, Progress& progress, BuildReport& report);

/// Maps /visual onto /simsurface (building the surface first if absent). With `visual_mesh`,
/// that file replaces /visual first.
void mapping_stage(Scenario& scenario, const std::filesystem::path& visual_mesh, Progress& progress, BuildReport& report,
                   MappingMethod method = MappingMethod::automatic);

/// Holds the laid-out lattice: supports, free pieces (dropped or refused), and the rest state
/// balanced under the options' gravity; sets /solver balanced_gravity.
void hold_stage(Scenario& scenario, const BuildOptions& options, Progress& progress, BuildReport& report);

/// Runs every stage and returns the scenario (not yet written).
Scenario build_scenario(const BuildOptions& options, Progress& progress, BuildReport& report);

/// Prints a human summary of `report` (and the scenario) to stdout.
void print_build_summary(const BuildReport& report, const Scenario& scenario);

}  // namespace heartsim::cli
