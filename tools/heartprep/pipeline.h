/// @file pipeline.h
/// @brief The heartprep stages wired together: read → select → surface → layout → stability →
/// scenario. Each stage is a libmodel function; this file sequences, times and reports them, and
/// holds what only a build decides: the tissue labels when none are given, which warnings a
/// technician sees (with heartprep's flags), the step when nothing bounds it. The step policy
/// itself is libmodel's (stability.h time_step_limits), shared with the solver.
#pragma once

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/defect.h"
#include "libmodel/label_conventions.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/packing.h"
#include "libmodel/simulation_surface.h"
#include "libmodel/mesh.h"
#include "libmodel/segment_names.h"
#include "libmodel/select.h"
#include "libmodel/stability.h"
#include "libmodel/supports.h"
#include "libmodel/surface.h"
#include "libmodel/walls.h"

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace heartsim::cli {

/// Labels as given on the command line, each a label number or a segment name (case-insensitive),
/// resolved against the volume's segment names once it is read (read_and_select).
struct LabelChoice {
    std::vector<std::string> tissue;   ///< --tissue; empty = default_tissue_labels (label 1 unless names say otherwise)
    std::vector<std::string> cavity;   ///< --cavity
    std::vector<std::string> anchor;   ///< --anchor-label
    /// --labels: a label convention's name (label_conventions.h: mmwhs, hvsmr2016, ...) or a label
    /// table (formats/label_table.h) naming the labels of a volume that carries no names, or
    /// renaming those of a .seg.nrrd; empty = none.
    std::filesystem::path label_table;
};

/// A septal defect to carve into the label map before anything is built from it (defect.h).
struct DefectChoice {
    DefectType type = DefectType::vsd;
    double diameter_mm = 10.0;
    std::optional<Eigen::Vector3d> at;   ///< --at, LPS mm
    std::optional<DefectSite> site;      ///< --site
    double max_wall_mm = 20.0;           ///< --max-wall
};

/// What `heartprep build` makes by default, as a number that changes when a default changes what it
/// makes (a batch's content key holds it, so a batch rebuilds rather than reuses a case built by the
/// old defaults). 2: walls grown where the labels show only blood.
inline constexpr int build_defaults_revision = 2;

/// Walls grown where the labels show blood without wall (libmodel/walls.h, docs/user-guide.md
/// "Walls grown where the labels show only blood").
struct WallChoice {
    bool grow = true;           ///< --walls grown; false: --walls labelled (the label map as it is)
    WallThicknesses thickness;  ///< --wall-rv, --wall-lv, --wall-atria, --wall-aorta, --wall-pa, --wall-blood-pool (mm)
};

/// A wall grown, with what growing it did.
struct GrownStructure {
    WallStructure structure;
    GrownWall grown;
};

/// What the walls stage did.
struct WallsReport {
    bool asked = false;                  ///< --walls grown
    std::string convention;              ///< the convention whose blood was lined ("" for none)
    std::string none_because;            ///< why no wall was grown, when none was
    std::vector<GrownStructure> grown;   ///< the walls grown, each with at least one voxel
    std::vector<GrownStructure> bare;    ///< structures whose blood faced no background: nothing grown
};

struct BuildOptions {
    std::filesystem::path input;
    LabelChoice labels;              ///< resolved into `selection`'s label lists by read_and_select
    SelectionOptions selection;      ///< the label lists here are replaced by `labels`' resolution
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
    std::optional<DefectChoice> defect;  ///< --defect: carved into the label map first
    WallChoice walls;                    ///< --walls: grown after the defect, before the selection
    std::string batch_key;           ///< see Scenario::batch_key
};

struct StageTime {
    std::string stage;
    double seconds = 0.0;
};

struct BuildReport {
    VolumeHeader header;
    SegmentNames segment_names;         ///< the volume's segment names, with --labels' table over them
    std::string convention;             ///< the label convention --labels named ("" for none or a table)
    /// A convention the volume's labels match when it names none and --labels gave none: a line
    /// for the summary and for errors ("the labels match MM-WHS 2017: --labels mmwhs names them").
    std::string convention_hint;
    std::string convention_match;       ///< that convention's name
    std::optional<DefectReport> defect; ///< the defect carved, if one was asked for
    WallsReport walls;                  ///< the walls grown
    SelectionReport selection;
    /// The tissue's volume per tissue label (labelled and grown), mm³, after small islands are dropped.
    std::map<int, double> tissue_volume_by_label_mm3;
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
/// Resolves `labels` against the volume's segment names (and --labels' table) into `options`'
/// tissue, cavity and anchor labels; warns (report.warnings) about the reader's findings and a
/// tissue whose name is not heart muscle. Throws InputError naming `input` for a name that
/// names no segment.
struct SelectedVolume {
    LabelVolume volume;
    Selection selection;
};
/// With `walls` (grow), the walls are grown after the defect and their labels join `options`' tissue labels.
SelectedVolume read_and_select(const std::filesystem::path& input, const LabelChoice& labels, SelectionOptions& options,
                               Progress& progress, BuildReport& report, const std::optional<DefectChoice>& defect = std::nullopt,
                               const WallChoice& walls = WallChoice{.grow = false, .thickness = {}});

/// Grows the walls `choice` asks for into `volume` (libmodel/walls.h): around the blood of the label
/// convention --labels names or the volume's labels match (MM-WHS's chambers and great vessels,
/// HVSMR's blood pool), when the tissue is that convention's myocardium; otherwise around the
/// --cavity labels as one blood pool. The grown labels (above every label of the volume) join
/// `options`' tissue labels and report.segment_names. Sets report.walls.
void walls_stage(LabelVolume& volume, const WallChoice& choice, SelectionOptions& options, Progress& progress, BuildReport& report);

/// What a scenario's heart is made of, in words, for summaries: "a heart of 412.0 mL of tissue (the
/// left ventricle's wall with the septum 134.3 mL as labelled; the right ventricle's free wall, …
/// grown, 1.5-3.5 mm: 278 mL)". The volume is the scenario's tissue volume, or the particles' where
/// the file holds none.
std::string heart_contents(const Scenario& scenario);

/// Reads `input` and resolves `labels` (the first half of read_and_select): the volume, with
/// report.segment_names, convention and convention_hint set and `options`' label lists resolved.
LabelVolume read_and_resolve(const std::filesystem::path& input, const LabelChoice& labels, SelectionOptions& options,
                             Progress& progress, BuildReport& report);

/// Carves `defect` into `volume` (defect.h) with the walls, pools and chambers that the resolved
/// labels name: the wall is the tissue labels; the pools are the cavity labels, or else every
/// label but the tissue's and 0; the chambers come from the segment names (a convention's, a
/// .seg.nrrd's or a table's: "left ventricle", "right atrium", "aorta", ...). Sets report.defect.
/// Throws InputError naming `input` when the defect cannot be made, or when the opening carved
/// does not join the two pools.
void defect_stage(LabelVolume& volume, const std::filesystem::path& input, const DefectChoice& defect,
                  const SelectionOptions& options, Progress& progress, BuildReport& report);

/// The lines describing a carved defect, for the summaries of `defect` and `build`.
void print_defect_summary(const DefectReport& defect, const SegmentNames& names);

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

/// Prints every figure of `report` (and the scenario) to stdout: `build --verbose`.
void print_build_summary(const BuildReport& report, const Scenario& scenario);

/// Prints the technician's summary of a build written to `output`: what was built and how it is
/// held, whether it is fit for simulation (and if not, what to look at), and the next commands.
void print_plain_summary(const BuildReport& report, const Scenario& scenario, const std::filesystem::path& output);

/// Each warning as `heartprep: warning: …` on stderr. Printed with and without -q: -q silences the
/// progress and the summary, not what the user must hear (a qform that disagrees with the sform, a
/// segment that is not heart muscle, a heart that sags).
void print_warnings(const std::vector<std::string>& warnings);

}  // namespace heartsim::cli
