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
///   /instrument_kind    int32 [2]      0 none, 1 probe, 2 grabber, 3 scalpel
///   /cut_springs        int32 [K,2]    the springs a scalpel cut, as packed particle indices (lower
///                                      first, sorted); absent when none was cut
///   /visual/positions   float32 [V,3]  mm, the deformed detailed mesh (when the scenario has one)
///   /visual/triangles   int32 [T,3]    once a scalpel opened the detailed mesh: its triangles as
///                                      drawn (counter-clockwise from outside, a closed 2-manifold),
///                                      the tissue's surface first, then the incisions' caps from
///                                      the attribute cap_first on; V then counts the vertices the
///                                      incisions added. Absent while uncut (the scenario's triangles).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace heartsim {

struct SimulationState {
    std::string backend;                               ///< "cpu" or "gl"
    std::string scenario;                              ///< scenario file name
    double time_ms = 0.0;                              ///< simulated time, ms
    long long steps = 0;
    double mass_scale = 1.0;                           ///< SolverOptions::mass_scale at the end
    std::vector<std::array<float, 3>> positions;       ///< N×3, mm
    std::array<std::array<double, 3>, 2> force_n{};    ///< per hand, N
    std::array<std::int32_t, 2> particles{};           ///< per hand
    std::array<std::int32_t, 2> kind{};                ///< per hand: 0 none, 1 probe, 2 grabber, 3 scalpel
    std::vector<std::array<std::int32_t, 2>> cut_springs;  ///< K×2 packed particle indices, lower first, sorted
    /// The deformed detailed mesh, V×3 mm (the scenario's mapping evaluated at `positions`, as the
    /// runtime draws it): /visual/positions. Empty when the scenario has no visual mesh.
    std::vector<std::array<float, 3>> visual_positions;
    /// The detailed mesh's triangles once an incision opened it (/visual/triangles), caps from
    /// `visual_cap_first` on; empty while uncut.
    std::vector<std::array<std::int32_t, 3>> visual_triangles;
    std::size_t visual_cap_first = 0;
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

}  // namespace heartsim
