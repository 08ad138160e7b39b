/// @file contact_skin.h
/// @brief The skin of each particle: how far the drawn (detailed) surface lies beyond it at rest.
/// The lattice's outer particles lie inside the surface the trainee sees (up to about half a
/// spacing on a label map's flat face, more at a rounded one); an instrument that met the particles
/// themselves would sink that far into what is drawn before it touched anything. The solver's
/// contact reaches across the skin instead (SolverRules::contact_skin): a particle meets a probe,
/// grabber or retractor grown by its skin, so the instrument meets the tissue where it is drawn.
///
///     std::vector<float> skin = contact_skin(lattice.particles.rest_position, packing.neighbours,
///                                            visual.positions, visual.normals, visual.triangles,
///                                            lattice.spacing);
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace heartsim {

/// Per particle (the order of `rest`), mm: for a particle on the lattice's boundary (one of its 18
/// neighbour slots empty, −1), the distance from its rest position to the nearest point of the
/// drawn surface within `spacing`, positive where the particle lies inside that surface and
/// negative where it lies outside it (an instrument then meets it only as it reaches the drawn
/// surface); 0 for every other particle (inside the lattice, or with no drawn surface within a
/// spacing), so an inner particle never meets an instrument before the layer above it. Inside:
/// the surface's normal (`normals`, outward, interpolated at the nearest point) points away from
/// the particle.
/// An empty surface gives all zeros (a scenario whose drawn surface is the simulation surface,
/// which passes through the particles). Throws InputError when the arrays disagree in size, a
/// triangle names a vertex out of range, or spacing is not positive.
std::vector<float> contact_skin(const std::vector<std::array<float, 3>>& rest,
                                const std::vector<std::array<std::int32_t, 18>>& neighbours,
                                const std::vector<std::array<float, 3>>& positions,
                                const std::vector<std::array<float, 3>>& normals,
                                const std::vector<std::array<std::int32_t, 3>>& triangles, double spacing);

}  // namespace heartsim
