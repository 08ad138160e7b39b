#include "landmark_stage.h"

#include "libmodel/label_conventions.h"

#include <chrono>

namespace heartsim::cli {

namespace {

/// Why the chambers have no labels, in the words of the volume's convention; empty when they do.
std::string unlabelled_reason(const ChamberLabels& chambers, const BuildReport& report) {
    const std::string named = !report.convention.empty() ? report.convention : report.convention_match;
    if (const LabelConvention* convention = named.empty() ? nullptr : find_label_convention(named); convention && !convention->chambers())
        return convention->title + " labels one blood pool for every chamber";
    const bool none = !chambers.left_atrium && !chambers.left_ventricle && !chambers.right_atrium && !chambers.right_ventricle;
    if (none && !report.convention_hint.empty()) return "the chambers' labels are not named (" + report.convention_hint + ")";
    if (none) return "the label map names no chamber (--labels names them: a convention such as mmwhs, or a label table)";
    return "";
}

}  // namespace

void landmark_stage(Scenario& scenario, const LabelVolume& volume, BuildReport& report) {
    const auto start = std::chrono::steady_clock::now();
    if (!scenario.visual) {
        scenario.landmarks = missing_landmarks("no detailed surface (/visual) to put them on");
        return;
    }
    TriangleMesh surface;
    for (const auto& p : scenario.visual->positions) surface.positions.emplace_back(p[0], p[1], p[2]);
    surface.triangles = scenario.visual->triangles;  // normals from the triangles: outward, whatever /visual holds
    const ChamberLabels chambers = chamber_labels_from_names(report.segment_names);
    scenario.landmarks = find_landmarks(volume, chambers, surface, {}, unlabelled_reason(chambers, report));
    report.times.push_back({"landmarks", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()});
}

}  // namespace heartsim::cli
