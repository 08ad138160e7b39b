/// @file xdmf.h
/// @brief The XDMF description written beside every scenario, saved state and recording
/// (`case.h5` → `case.xmf2`), so ParaView shows what the .h5 holds without a plugin. XDMF 2: a
/// small XML file whose DataItems name datasets inside the .h5 by a path relative to the
/// description's folder (`case.h5:/visual/positions`); it copies no data but a recording's per-step
/// tool values and the particle grid's vertex list. Coordinates are as stored: world millimetres,
/// LPS (ParaView applies no transform). What each file shows: docs/user-guide.md ("Open in
/// ParaView"), docs/scenario-format.md and docs/runtime.md.
///
/// Why `.xmf2`, not `.xdmf`: ParaView (5.11) offers three readers for `.xdmf`, and the one it
/// picks by itself, "Xdmf3 Reader (Top Level Partition)", reads the top-level grids as pieces of
/// one partitioned data set (vtkXdmf3Reader with FileSeriesAsTime off flattens every grid it
/// reads, whatever the Grid nesting): the detailed mesh, the simulation surface and the particles
/// then come as one unnamed block, drawn on top of one another. `.xmf2` is claimed by ParaView's
/// XDMF 2 reader alone ("XDMF Reader"), which keeps each top-level grid as a block named by the
/// grid's Name (tests/paraview_open.py checks what File ▸ Open shows).
#pragma once

#include "formats/atomic_file.h"

#include <cstddef>
#include <filesystem>
#include <string>

namespace heartsim {

struct Scenario;
struct SimulationState;
struct Recording;

/// The description's extension: the one ParaView opens with its XDMF 2 reader alone (above).
inline constexpr const char* xdmf_extension = ".xmf2";

/// `case.h5` → `case.xmf2` (the same folder, the extension replaced; `x.xmf2` → `x.xmf2.xmf2`).
/// `.h5` → `.xmf2` adds two bytes: an .h5 name of up to 253 bytes keeps its description within
/// the 255 bytes a file name may take.
std::filesystem::path xdmf_beside(const std::filesystem::path& h5);
/// Where `path` is named as a description (`.xmf2`, or `.xdmf` as earlier versions wrote), the
/// words that say what it is and which file to give instead: the .h5 beside it that xdmf_beside
/// maps to it (`case.h5`, else `case.hdf5`), named whether or not it is there. Empty for any
/// other name. The HDF5 reader adds them to its "not an HDF5 file".
std::string xdmf_given_instead_of_h5(const std::filesystem::path& path);
/// The description `text` as a file written together with `h5` (atomic_file.h FileBeside): a
/// failure at either leaves both old files as they were.
FileBeside xdmf_file_beside(const std::filesystem::path& h5, const std::string& text);

/// Throws OutputError unless the description beside `h5` can be written (check_destination: not
/// a folder, a folder that takes a file), naming it as the description of `h5`. Called by the
/// writers below before they write the .h5, so a description that cannot be written leaves no .h5
/// without one, and by the commands before their work starts.
void check_xdmf_destination(const std::filesystem::path& h5);

/// The scenario file's grids: `detailed_mesh` (/visual, with its normals), `simulation_surface`
/// (/simsurface/triangles over /particles/rest_position) and `particles` (one vertex per particle,
/// with material, anchored and mass), each only when the file holds it.
std::string scenario_xdmf(const std::string& h5_name, const Scenario& scenario);

/// The saved state's grids: `particles` (/positions, deformed) and, when the state names its
/// scenario (SimulationState::scenario_path), the deformed `simulation_surface` and
/// `detailed_mesh`: the state's positions with the scenario's triangles, which the state does not
/// hold (the .xdmf refers to the scenario by its path relative to the .xdmf's folder); once a
/// patch was laid, the `patch` (/patch/positions, /patch/triangles) and its `stitches` (one vertex
/// per stitch at its tissue point, /patch/stitch_anchor, carrying force_n, /patch/stitch_force).
/// `xdmf_folder` is where the .xdmf will lie.
std::string state_xdmf(const std::string& h5_name, const SimulationState& state, const std::filesystem::path& xdmf_folder);

/// The recording's `instruments`: a temporal collection with one grid per simulation step (at
/// most xdmf_max_time_steps: a longer recording is shown every k-th step, and its last), two
/// points per step (the hands' tool positions, world mm, /steps/tool_position_mm) carrying
/// force_n (N, world), applied and grab; the time is /steps/time_ms (simulated ms). These few
/// values are copied into the XML rather than named in the .h5: VTK's Xdmf3 reader reads no
/// HyperSlab (the row of a step in the [S,2,3] datasets) and its XDMF 2 reader logs an error
/// for each.
std::string recording_xdmf(const std::string& h5_name, const Recording& recording);
inline constexpr std::size_t xdmf_max_time_steps = 2000;
/// The steps recording_xdmf shows, in order: every one when there are at most
/// xdmf_max_time_steps, else every k-th (k = ceil(S / xdmf_max_time_steps)) and the last.
std::size_t xdmf_step_stride(std::size_t steps);

/// Writes `text` to xdmf_beside(h5), atomically. The writers of the .h5 files make the text
/// before they write the .h5 and write it after, so running out of memory cannot leave an .h5
/// without its .xdmf. Throws OutputError naming the .xdmf.
void write_xdmf(const std::filesystem::path& h5, const std::string& text);
/// write_xdmf of scenario_xdmf of the file at `h5` (heartprep batch, for a scenario built without
/// one); the state's and the recording's writers write theirs themselves.
void write_scenario_xdmf(const std::filesystem::path& h5, const Scenario& scenario);

}  // namespace heartsim
