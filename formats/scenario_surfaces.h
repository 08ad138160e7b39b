/// @file scenario_surfaces.h
/// @brief The scenario's surfaces (docs/scenario-format.md): /visual, the detailed mesh drawn;
/// /packing, the particles' texture layout; /simsurface, the particles' outer triangles; and
/// /mapping, which carries the visual vertices with the particles. Used by scenario.cpp; not a
/// public header.
#pragma once

#include "formats/hdf5_io.h"
#include "formats/scenario.h"

namespace heartsim {

/// Writes those of /visual, /packing, /simsurface and /mapping that `s` holds; throws InputError
/// when the simulation surface's normal weights or the mapping's carrier rows do not match in count.
void write_surfaces(h5::Writer& w, const Scenario& s);

/// Reads /visual, when present.
void read_visual(const h5::Reader& r, Scenario& s);

/// Reads /packing, /simsurface and /mapping, each optional, validated against the particles
/// (and /mapping against /visual and /simsurface); the caller reads the particles and /visual first.
void read_packing_and_mapping(const h5::Reader& r, Scenario& s);

}  // namespace heartsim
