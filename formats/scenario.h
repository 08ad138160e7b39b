/// @file scenario.h
/// @brief The scenario file, version 1 (shared/SCENARIO.md, docs/scenario-format.md): the
/// contract between heartprep and heartsim. A writer that writes atomically and a reader that
/// validates shapes, types, index ranges and finiteness before anything uses the data.
#pragma once

#include "libmodel/landmarks.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/packing.h"
#include "libmodel/sim/solver.h"
#include "libmodel/mesh.h"
#include "libmodel/volume.h"

#include <Eigen/Core>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// 2: pre-stressed rest lengths with supports and /solver balanced_gravity (docs/scenario-format.md).
/// A version-1 reader would read a version-2 file's pre-stressed springs without the supports that
/// balance them; this reader reads both (a version-1 file has no supports and no pre-stress).
/// 3: /mapping/particles and /mapping/weights, the carriers of embedded visual vertices; a
/// version-2 reader would ignore them and draw those vertices wrongly. Earlier files read as
/// tangent-space mappings.
inline constexpr int scenario_format_version = 3;
inline constexpr int scenario_oldest_format_version = 1;

/// Where the scenario came from (/source attributes).
struct ScenarioSource {
    std::string file_name;            ///< input volume file name (no folder)
    std::string sha256;               ///< SHA-256 of the input file's bytes
    VolumeGeometry geometry;          ///< dims, spacing, voxel-to-world
    std::vector<int> tissue_labels;
    std::vector<int> cavity_labels;
    std::vector<int> anchor_labels;
    bool anchor_border = false;
    /// A septal defect carved into the label map before the build (libmodel/defect.h): "vsd",
    /// "asd", or empty for none; its centre and axis (LPS) and diameter.
    std::string defect;
    /// The tissue's volume, mm³: its voxels in the label map after small islands are dropped (the
    /// one tissue volume every report gives); 0 when not stored.
    double tissue_volume_mm3 = 0.0;
    Eigen::Vector3d defect_centre{0, 0, 0};
    Eigen::Vector3d defect_axis{0, 0, 1};
    double defect_diameter_mm = 0.0;
};

/// /solver attributes: the step settings (libmodel/sim/solver_options.h StepSettings: dt_ms, damping,
/// gravity, balanced_gravity, critical_dt_ms, damped_critical_dt_ms, safety_factor; same names,
/// units and defaults as the file's attributes) plus what only the file holds. The solver's rules
/// and kernel options are heartsim's, not the scenario's (options_from). Units: ms, mm/ms².
struct SolverSettings : StepSettings {
    int substeps = 1;                 ///< written as 1; not used by heartsim (docs/scenario-format.md)
    double critical_dt_bound_ms = 0.0;///< proven lower bound on the critical step (Gershgorin)
};

/// The visual mesh (/visual): float32 positions and normals, int32 triangles.
struct VisualMesh {
    std::vector<std::array<float, 3>> positions;
    std::vector<std::array<float, 3>> normals;
    std::vector<std::array<std::int32_t, 3>> triangles;
};

/// Where a material's tissue came from (/materials/origin, wall_thickness_mm, grown_from,
/// tissue_volume_mm3; docs/scenario-format.md): labelled in the input, or a wall heartprep grew
/// around a blood label that had none (libmodel/walls.h).
struct TissueOrigin {
    bool grown = false;         ///< grown around blood; false: labelled in the input volume
    double thickness_mm = 0.0;  ///< the grown wall's thickness, mm; 0 for labelled tissue
    int grown_from = 0;         ///< the blood label the wall lines (the first, where several); 0 for labelled tissue
    double volume_mm3 = 0.0;    ///< the material's voxels in the label map as built (islands dropped), mm³; 0 if unknown
};

struct Scenario {
    std::string generator;            ///< tool name and version
    /// `heartprep batch`'s key: SHA-256 of (input bytes, build options, generator); empty outside
    /// a batch. A batch skips a case whose existing scenario carries the key it would write.
    std::string batch_key;
    /// The warnings of the `heartprep build` that wrote the file (/build_warnings), so a batch that
    /// reuses the file still reports them; nullopt for a file from before the dataset existed.
    std::optional<std::vector<std::string>> build_warnings;
    ScenarioSource source;
    Lattice lattice;                  ///< spacing, dims, index_to_world, materials, particles, springs
    /// One per row of lattice.materials where a wall was grown; empty for a build of the labels as
    /// they are (and a file without /materials/origin): every material labelled.
    std::vector<TissueOrigin> tissue_origin;
    std::optional<VisualMesh> visual;
    SolverSettings solver;
    /// /packing: present once the particles are packed (then particles are in packed order).
    std::optional<Packing> packing;
    /// /simsurface: triangles (particle indices, counter-clockwise seen from outside) and
    /// normal_weight (1 = counts in particle normals; a file without it reads as all ones).
    std::optional<SimulationSurface> simulation_surface;
    /// /mapping: one row per visual vertex; needs /visual and /simsurface.
    std::optional<VisualMapping> mapping;
    /// /landmarks: the grooves, coronary courses and valve rings on the detailed surface, and those
    /// the label map could not give with the reason (libmodel/landmarks.h); nullopt: none stored.
    std::optional<Landmarks> landmarks;
};

/// The solver options of a scenario: its step settings, with heartsim's rules and kernel options.
SolverOptions options_from(const SolverSettings& settings);

/// Converts a world-space mesh to the file's float32 layout.
VisualMesh to_visual_mesh(const TriangleMesh& mesh);

/// Writes `scenario` to `path` atomically (a temporary file beside it, then rename): a failed
/// write leaves no file and no partial file. Then the XDMF description beside it (xdmf.h:
/// `case.h5` → `case.xmf2`, for ParaView), atomically too. Throws OutputError naming the file.
void write_scenario(const std::filesystem::path& path, const Scenario& scenario);

/// write_scenario, but the file is read back with read_scenario's every check before it takes its
/// name, so what heartprep writes is a scenario that heartsim and inspect read. A value outside
/// their plausible ranges (a voxel spacing in metres, an absurd option) throws InputError
/// "the scenario would not be readable: …; nothing was written", and no file is left.
void write_readable_scenario(const std::filesystem::path& path, const Scenario& scenario);

/// Reads and validates a scenario. Throws InputError naming the file, the dataset or attribute,
/// and what was expected, for: a missing file, not HDF5, a wrong `format`, a newer
/// `format_version`, a missing or misshapen dataset, a wrong element type, an index out of
/// range, a non-finite value, a non-positive mass, spacing or time step; a neighbour table that
/// is not symmetric or disagrees with /springs; texels outside the texture or shared; mapping
/// rows that do not match /visual or point outside /simsurface.
Scenario read_scenario(const std::filesystem::path& path);

/// SHA-256 of a file's bytes, lowercase hex. Throws InputError if it cannot be read.
std::string sha256_file(const std::filesystem::path& path);
/// SHA-256 of a label map's content, lowercase hex: of the file; for a detached header (a NRRD
/// `data file`, a MetaImage `ElementDataFile`: volume_io.h VolumeHeader::data_file), of the
/// header's hash and the data file's hash, one per line, so a changed voxel file changes it.
/// What a scenario's source_sha256 and a batch's content key use.
std::string label_map_sha256(const std::filesystem::path& path);

/// SHA-256 of a string's bytes, lowercase hex.
std::string sha256_text(const std::string& text);

}  // namespace heartsim
