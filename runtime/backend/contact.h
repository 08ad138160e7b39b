/// @file contact.h
/// @brief How the force pass finds a probe's contact particles: `direct` (the step's own list of
/// the particles it pushed, every backend), or on the gl backend the seed's picking buffer
/// (`picking`) or a search over the particles (`search`): runtime/gl/picking.h.
#pragma once

#include <string>

namespace heartsim {

enum class ContactMode { direct, picking, search };
/// "direct", "picking" or "search"; throws InputError naming {ContactMode} (heartsim's --contact)
/// otherwise.
ContactMode parse_contact_mode(const std::string& name);
const char* to_string(ContactMode mode);

struct ContactSettings {
    ContactMode mode = ContactMode::direct;
    int picking_refresh = 1;       ///< K: the picking buffer is rendered every K force requests (≥ 1)
    int picking_resolution = 128;  ///< pixels per side of the picking buffer
    int sampling_grid = 64;        ///< sampling points: a G×G grid over the probe's silhouette, lifted onto its front half, + a rim ring of 4G
    double tolerance_mm = 0.0;     ///< a particle within this of the probe is in contact; 0 = 1e-3 × lattice spacing
};

}  // namespace heartsim
