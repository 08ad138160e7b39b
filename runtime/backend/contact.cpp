#include "runtime/backend/contact.h"

#include "formats/scenario.h"
#include "libmodel/contact_skin.h"
#include "libmodel/errors.h"

namespace heartsim {

ContactMode parse_contact_mode(const std::string& name) {
    if (name == "direct") return ContactMode::direct;
    if (name == "picking") return ContactMode::picking;
    if (name == "search") return ContactMode::search;
    throw InputError("{ContactMode} must be direct, picking or search, not '" + name + "'");
}

const char* to_string(ContactMode mode) {
    switch (mode) {
    case ContactMode::direct: return "direct";
    case ContactMode::picking: return "picking";
    case ContactMode::search: return "search";
    }
    return "?";
}

std::vector<float> scenario_contact_skin(const Scenario& scenario) {
    const std::size_t n = scenario.lattice.particles.size();
    if (!scenario.visual || !scenario.packing || scenario.packing->neighbours.size() != n) return std::vector<float>(n, 0.0f);
    const VisualMesh& visual = *scenario.visual;
    return contact_skin(scenario.lattice.particles.rest_position, scenario.packing->neighbours, visual.positions, visual.normals,
                        visual.triangles, scenario.lattice.spacing);
}

}  // namespace heartsim
