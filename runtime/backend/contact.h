/// @file contact.h
/// @brief How the force pass finds a probe's contact particles: `direct` (the step's own list of
/// the particles it pushed, every backend), or on the gl backend the seed's picking buffer
/// (`picking`) or a search over the particles (`search`): runtime/gl/picking.h.
#pragma once

#include <string>
#include <vector>

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

struct Scenario;
/// The scenario's contact skin (libmodel/contact_skin.h) in its packed order, which both backends
/// give their step (Solver::set_contact_skin): from its detailed mesh (/visual), or all zeros
/// where it has none (its drawn surface is then the simulation surface, through the particles).
std::vector<float> scenario_contact_skin(const Scenario& scenario);

}  // namespace heartsim
