/// @file state.h
/// @brief The simulation state file `heartsim run --save-state OUT.h5` writes: final particle
/// positions and the last forces of each instrument. HDF5, written atomically (a temporary file
/// beside it, then rename). Layout (docs/runtime.md):
///   root attrs  format = "heartsim.state", format_version = 1, units = "mm g ms", frame = "LPS",
///               backend, scenario (file name), time_ms (simulated), steps, mass_scale (the explicit
///               mass scaling S at the end of the run; absent in states written before: 1)
///   /positions          float32 [N,3]  mm, packed order (as /particles/rest_position)
///   /instrument_forces  float64 [2,3]  N, the force the tissue exerts on each hand's instrument
///   /instrument_particles int32 [2]    particles held or touched per hand
///   /instrument_kind    int32 [2]      0 none, 1 probe, 2 grabber, 3 scalpel, 4 patch, 5 needle, 6 retractor
///   /cut_springs        int32 [K,2]    the springs a scalpel cut, as packed particle indices (lower
///                                      first, sorted); absent when none was cut
///   /visual/positions   float32 [V,3]  mm, the deformed detailed mesh (when the scenario has one)
///   /visual/triangles   int32 [T,3]    once a scalpel opened the detailed mesh: its triangles as
///                                      drawn (counter-clockwise from outside, a closed 2-manifold),
///                                      the tissue's surface first, then the incisions' caps from
///                                      the attribute cap_first on; V then counts the vertices the
///                                      incisions added. Absent while uncut (the scenario's triangles).
///   /patch              once a patch was laid (runtime/surgery/repair.h); attributes material, thickness_mm,
///                       youngs_modulus_mpa, and where the scenario has a defect its frame now:
///                       defect_centre [3] (mm), defect_axis [3] (unit, toward the patch's side),
///                       defect_diameter_mm, closed (1 or 0) and largest_rim_gap_mm (the closure
///                       check's, at leak_test_mmhg, its rim rim_offset_mm outside the opening, its
///                       cylinder margin_mm beyond it; when not closed, leak_mm [3] (mm): where the
///                       leak passes the rim, ClosureResult::leak_mm)
///   /patch/positions    float32 [P,3]  mm, the patch's mid-surface
///   /patch/leak_test_positions float32 [P,3] mm, where the closure check's leak test left it (when checked)
///   /patch/triangles    int32 [Q,3]    its triangles
///   /patch/stitch_vertex int32 [S]     per stitch: the patch's vertex it holds
///   /patch/stitch_anchor float32 [S,3] mm, the tissue point it holds, now
///   /patch/stitch_force float64 [S,3]  N, its pull on the patch in the last step (minus that on the tissue)
///   /patch/stitch_tied_ms float64 [S]  when its needle tied it
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// A laid patch and its stitches (/patch).
struct PatchState {
    std::string material;
    double thickness_mm = 0.0, youngs_modulus_mpa = 0.0;
    std::vector<std::array<float, 3>> positions;
    std::vector<std::array<float, 3>> leak_test_positions;  ///< empty when not checked
    std::vector<std::array<std::int32_t, 3>> triangles;
    std::vector<std::int32_t> stitch_vertex;
    std::vector<std::array<float, 3>> stitch_anchor;
    std::vector<std::array<double, 3>> stitch_force;
    std::vector<double> stitch_tied_ms;
    bool has_defect = false;  ///< the attributes below are stored
    std::array<double, 3> defect_centre{}, defect_axis{};
    double defect_diameter_mm = 0.0;
    bool closed = false;
    double largest_rim_gap_mm = 0.0, leak_test_mmhg = 0.0, rim_offset_mm = 0.0, margin_mm = 0.0;
    std::optional<std::array<double, 3>> leak_mm;  ///< not closed: where the leak passes the rim
};

struct SimulationState {
    std::string backend;                               ///< "cpu" or "gl"
    std::string scenario;                              ///< scenario file name
    double time_ms = 0.0;                              ///< simulated time, ms
    long long steps = 0;
    double mass_scale = 1.0;                           ///< SolverOptions::mass_scale at the end
    std::vector<std::array<float, 3>> positions;       ///< N×3, mm
    std::array<std::array<double, 3>, 2> force_n{};    ///< per hand, N
    std::array<std::int32_t, 2> particles{};           ///< per hand
    std::array<std::int32_t, 2> kind{};                ///< per hand: 0 none, 1 probe, 2 grabber, 3 scalpel, 4 patch, 5 needle, 6 retractor
    std::vector<std::array<std::int32_t, 2>> cut_springs;  ///< K×2 packed particle indices, lower first, sorted
    /// The deformed detailed mesh, V×3 mm (the scenario's mapping evaluated at `positions`, as the
    /// runtime draws it): /visual/positions. Empty when the scenario has no visual mesh.
    std::vector<std::array<float, 3>> visual_positions;
    /// The detailed mesh's triangles once an incision opened it (/visual/triangles), caps from
    /// `visual_cap_first` on; empty while uncut.
    std::vector<std::array<std::int32_t, 3>> visual_triangles;
    std::size_t visual_cap_first = 0;
    std::optional<PatchState> patch;                   ///< /patch, once a patch was laid
    /// Not stored in the file, read back empty: the scenario the state came from and its triangle
    /// counts, for the .xmf2 written beside the state (xdmf.h), which shows the deformed
    /// simulation surface and detailed mesh with the scenario's triangles. Empty: the .xmf2 shows
    /// the particles only.
    std::filesystem::path scenario_path;
    std::size_t scenario_simsurface_triangles = 0, scenario_visual_triangles = 0;
};

/// Writes atomically, and the XDMF description beside it (xdmf.h: `state.h5` → `state.xmf2`);
/// throws OutputError naming the file.
void write_state(const std::filesystem::path& path, const SimulationState& state);
/// Reads and validates; throws InputError naming the file and dataset.
SimulationState read_state(const std::filesystem::path& path);
/// Whether `path` is an HDF5 file whose root says it is a saved state (format heartsim.state);
/// false for anything else, which that file's own reader then refuses with its reason.
bool is_state_file(const std::filesystem::path& path);

}  // namespace heartsim
