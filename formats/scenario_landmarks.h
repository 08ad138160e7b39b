/// @file scenario_landmarks.h
/// @brief The scenario's /landmarks group (docs/scenario-format.md "/landmarks"): the grooves,
/// coronary courses and valve rings of libmodel/landmarks.h, and the landmarks a label map could
/// not give, each with its reason. Used by scenario.cpp; not a public header.
#pragma once

#include "formats/hdf5_io.h"
#include "libmodel/landmarks.h"

namespace heartsim {

/// Writes `landmarks` as /landmarks.
void write_landmarks(h5::Writer& w, const Landmarks& landmarks);

/// Reads /landmarks (the caller checks that it exists), refusing a misshapen or non-finite point
/// list, an unknown kind, a ring without a unit normal or a positive diameter, a landmark both
/// found and missing, and a found landmark in a file without /visual (it lies on it).
Landmarks read_landmarks(const h5::Reader& r, bool has_visual);

}  // namespace heartsim
