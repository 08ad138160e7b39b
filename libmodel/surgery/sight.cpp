#include "libmodel/surgery/sight.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace heartsim {

TissueOccupancy::TissueOccupancy(const std::vector<std::array<float, 3>>& rest, double spacing) : rest_(rest), spacing_(spacing) {
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const auto& r = rest[i];
        cells_[key(std::int64_t(std::floor(r[0] / spacing)), std::int64_t(std::floor(r[1] / spacing)),
                   std::int64_t(std::floor(r[2] / spacing)))]
            .push_back(std::int32_t(i));
    }
}

int TissueOccupancy::particle_at(const Eigen::Vector3d& point) const {
    const double reach2 = 0.5625 * spacing_ * spacing_;
    const std::int64_t ci = std::int64_t(std::floor(point.x() / spacing_)), cj = std::int64_t(std::floor(point.y() / spacing_)),
                       ck = std::int64_t(std::floor(point.z() / spacing_));
    int best = -1;
    double best2 = reach2;
    for (std::int64_t i = ci - 1; i <= ci + 1; ++i)
        for (std::int64_t j = cj - 1; j <= cj + 1; ++j)
            for (std::int64_t k = ck - 1; k <= ck + 1; ++k) {
                const auto found = cells_.find(key(i, j, k));
                if (found == cells_.end()) continue;
                for (const std::int32_t p : found->second) {
                    const auto& r = rest_[std::size_t(p)];
                    const double d2 = (Eigen::Vector3d(r[0], r[1], r[2]) - point).squaredNorm();
                    if (d2 <= best2) best2 = d2, best = p;
                }
            }
    return best;
}

std::vector<SightSpan> tissue_along(const TissueOccupancy& tissue, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    std::vector<SightSpan> spans;
    const double length = (b - a).norm(), step = 0.25 * tissue.spacing();
    if (!(length > 0.0)) return spans;
    const Eigen::Vector3d along = (b - a) / length;
    bool in = false;
    for (double t = 0.0; t <= length + 1e-9; t += step) {
        const bool here = tissue.inside(a + t * along);
        if (here && !in) spans.push_back({t, t});
        if (here) spans.back().to = t;
        in = here;
    }
    return spans;
}

WayOut way_out(const TissueOccupancy& tissue, const Eigen::Vector3d& from, const Eigen::Vector3d& way, double reach) {
    const double step = 0.25 * tissue.spacing();
    WayOut out{0.0, reach};
    for (double t = step; t < reach; t += step) {
        if (tissue.inside(from + t * way)) out.last_inside = t;
        else if (!tissue.inside(from + (t + step) * way)) {
            out.exit = t;
            break;
        }
    }
    return out;
}

SightLines sight_lines(const TissueOccupancy& tissue, const SightOptions& o) {
    SightLines found;
    const double cos_cone = std::cos(o.cone_deg * std::numbers::pi / 180.0);
    const double golden = std::numbers::pi * (3.0 - std::sqrt(5.0));
    for (int n = 0; n < o.directions; ++n) {
        const double z = 1.0 - (2.0 * n + 1.0) / o.directions, r = std::sqrt(std::max(0.0, 1.0 - z * z));
        const Eigen::Vector3d d(r * std::cos(golden * n), r * std::sin(golden * n), z);
        if (d.dot(o.outward) < cos_cone) continue;
        ++found.tried;
        const Eigen::Vector3d start = o.target + o.start_mm * d;
        const std::vector<SightSpan> spans = tissue_along(tissue, start, start + (o.max_wall_mm + o.reach_mm + 200.0) * d);
        if (spans.empty()) {
            ++found.never_out;
            continue;
        }
        const SightSpan& wall = spans.front();
        if (wall.from + o.start_mm < o.min_blood_mm) {
            ++found.no_blood;
            continue;
        }
        if (wall.length() > o.max_wall_mm) {
            ++found.thick_wall;
            continue;
        }
        if (spans.size() > 1 && spans[1].from - wall.to < o.reach_mm) {
            ++found.more_tissue;
            continue;
        }
        SightLine line;
        line.direction = d;
        line.wall_in_mm = o.start_mm + wall.from;
        // The tissue reaches half a spacing beyond its last sample inside.
        line.wall_out_mm = o.start_mm + wall.to + 0.25 * tissue.spacing();
        line.wall_particle = tissue.particle_at(line.wall_middle(o.target));
        if (line.wall_particle < 0) line.wall_particle = tissue.particle_at(o.target + (o.start_mm + wall.from) * d);
        if (o.accepts && !o.accepts(line.wall_particle, line)) {
            ++found.not_accepted;
            continue;
        }
        found.lines.push_back(line);
    }
    return found;
}

bool Opening::holds(const Eigen::Vector3d& point) const {
    const Eigen::Vector3d d = point - centre;
    return std::abs(d.dot(cut)) <= half_length && std::abs(d.dot(side)) <= half_width && std::abs(d.dot(sight)) <= half_depth;
}

bool seen_through(const TissueOccupancy& tissue, const Eigen::Vector3d& eye, const Eigen::Vector3d& point, const Opening& opening,
                  double end_slack_mm) {
    const double length = (point - eye).norm(), step = 0.25 * tissue.spacing();
    if (!(length > 0.0)) return true;
    const Eigen::Vector3d along = (point - eye) / length;
    for (double t = 0.0; t < length - end_slack_mm; t += step) {
        const Eigen::Vector3d q = eye + t * along;
        if (tissue.inside(q) && !opening.holds(q)) return false;
    }
    return true;
}

}  // namespace heartsim
