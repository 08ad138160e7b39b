/// @file landmark_stage.h
/// @brief The build's landmark stage: the grooves, coronary courses and valve rings of the label
/// map's chambers (libmodel/landmarks.h), put on the scenario's detailed surface as /landmarks.
#pragma once

#include "pipeline.h"

namespace heartsim::cli {

/// Finds the landmarks of `volume` (the label map as built) on scenario.visual and stores them in
/// scenario.landmarks, every one the label map cannot give listed missing with its reason: a label
/// map whose convention has one blood pool (HVSMR 2016), chambers not named (no --labels), no
/// detailed surface. Adds its time to report.times.
void landmark_stage(Scenario& scenario, const LabelVolume& volume, BuildReport& report);

}  // namespace heartsim::cli
