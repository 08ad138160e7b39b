#include "runtime/backend/contact.h"

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

}  // namespace heartsim
