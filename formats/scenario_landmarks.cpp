// /landmarks of the scenario file: one float64 [N,3] dataset per landmark found, its figures as
// attributes; the names and reasons of those missing as two string datasets.
#include "scenario_landmarks.h"
#include "scenario_checks.h"

#include <algorithm>
#include <cmath>

namespace heartsim {

namespace {

const char* const group = "landmarks";

}  // namespace

void write_landmarks(h5::Writer& w, const Landmarks& landmarks) {
    w.group(group);
    w.attribute(group, "frame", "LPS");
    w.attribute(group, "surface", "/visual");
    for (const Landmark& l : landmarks.found) {
        const std::string name = std::string(group) + "/" + l.name;
        std::vector<double> flat;
        flat.reserve(3 * l.points.size());
        for (const auto& p : l.points) flat.insert(flat.end(), {p.x(), p.y(), p.z()});
        w.dataset(name, flat, {l.points.size(), 3});
        w.attribute(name, "kind", to_string(l.kind));
        w.attribute(name, "between", l.between);
        w.attribute(name, "closed", std::int32_t(l.closed()));
        w.attribute(name, "length_mm", l.length_mm);
        w.attribute(name, "surface_distance_mm", l.surface_distance_mm);
        w.attribute(name, "coverage", l.coverage);
        if (l.kind == LandmarkKind::ring) {
            w.attribute(name, "centre", l.centre.data(), {3});
            w.attribute(name, "normal", l.normal.data(), {3});
            w.attribute(name, "diameter_mm", l.diameter_mm);
        }
    }
    if (!landmarks.missing.empty()) {
        std::vector<std::string> names, reasons;
        for (const MissingLandmark& m : landmarks.missing) names.push_back(m.name), reasons.push_back(m.reason);
        w.strings(std::string(group) + "/missing", names);
        w.strings(std::string(group) + "/missing_reason", reasons);
    }
}

Landmarks read_landmarks(const h5::Reader& r, bool has_visual) {
    Landmarks out;
    // The landmarks heartprep knows, by name; a later heartprep's others are left for it.
    for (const std::string& known : landmark_names()) {
        const std::string name = std::string(group) + "/" + known;
        if (!r.exists(name)) continue;
        // A landmark lies on the detailed surface; the missing ones' reasons need none.
        if (!has_visual) r.fail(name, "present without /visual (its points lie on the detailed surface)");
        Landmark l;
        l.name = known;
        std::size_t rows = 0;
        const auto flat = r.dataset<double>(name, {-1, 3}, &rows);
        r.require_finite(name, flat);
        require_plausible(r, name, flat, plausible::coordinate_mm);
        for (std::size_t i = 0; i < rows; ++i) l.points.emplace_back(flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]);
        try {
            l.kind = parse_landmark_kind(r.string_attribute(name, "kind"));
        } catch (const InputError& e) {
            r.fail(name, std::string("attribute kind: ") + e.what());
        }
        const std::size_t least = l.kind == LandmarkKind::groove ? 1 : l.kind == LandmarkKind::course ? 2 : 3;
        if (rows < least) r.fail(name, "a " + std::string(to_string(l.kind)) + " of " + std::to_string(rows) + " points (at least " +
                                           std::to_string(least) + ")");
        l.between = r.string_attribute(name, "between");
        l.length_mm = r.number<double>(name, "length_mm");
        l.surface_distance_mm = r.number<double>(name, "surface_distance_mm");
        l.coverage = r.number<double>(name, "coverage");
        if (!(l.length_mm >= 0) || !(l.surface_distance_mm >= 0)) r.fail(name, "length_mm and surface_distance_mm must not be negative");
        if (!(l.coverage > 0 && l.coverage <= 1)) r.fail(name, "coverage must lie in (0, 1]");
        if (l.kind == LandmarkKind::ring) {
            const auto centre = r.numbers<double>(name, "centre", 3), normal = r.numbers<double>(name, "normal", 3);
            l.centre = {centre[0], centre[1], centre[2]};
            l.normal = {normal[0], normal[1], normal[2]};
            if (!(std::abs(l.normal.norm() - 1.0) < 1e-3)) r.fail(name, "normal must be a unit vector");
            l.diameter_mm = r.number<double>(name, "diameter_mm");
            if (!(l.diameter_mm > 0 && l.diameter_mm < 1000)) r.fail(name, "diameter_mm must be a positive length under 1 m");
        }
        out.found.push_back(std::move(l));
    }
    const bool has_missing = r.exists(std::string(group) + "/missing"), has_reason = r.exists(std::string(group) + "/missing_reason");
    if (has_missing != has_reason)
        r.fail(std::string(group) + (has_missing ? "/missing_reason" : "/missing"), "missing (missing and missing_reason go together)");
    if (has_missing) {
        const auto names = r.strings(std::string(group) + "/missing", -1);
        const auto reasons = r.strings(std::string(group) + "/missing_reason", long(names.size()));
        for (std::size_t i = 0; i < names.size(); ++i) {
            if (out.find(names[i])) r.fail(std::string(group) + "/missing", "'" + names[i] + "' is both found and missing");
            out.missing.push_back({names[i], reasons[i]});
        }
    }
    return out;
}

}  // namespace heartsim
