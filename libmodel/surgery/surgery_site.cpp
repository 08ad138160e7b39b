// Where the scripted operations act (surgery_site.h): the incision's place on the particles, the
// stitch sites and the patch on the detailed mesh.
#include "libmodel/surgery/surgery_site.h"

#include "libmodel/errors.h"
#include "libmodel/ray_triangle.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <string>
#include <utility>

namespace heartsim {

std::pair<int, double> axis_of(const Eigen::Vector3d& v) {
    int axis = 0;
    v.cwiseAbs().maxCoeff(&axis);
    return {axis, v[axis] < 0 ? -1.0 : 1.0};
}

namespace {

/// Whether options.chamber_wall tells the chamber apart: one flag per rest position, one set.
bool on_chamber_wall(const std::vector<std::array<float, 3>>& rest, const IncisionSiteOptions& o) {
    return o.chamber_wall.size() == rest.size() && std::find(o.chamber_wall.begin(), o.chamber_wall.end(), 1) != o.chamber_wall.end();
}

/// The chosen particle of each approach (runtime/surgery/incision_plan.h); `whole` tells whether the atriotomy's
/// place holds the whole incision.
std::size_t entry_particle(const std::vector<std::array<float, 3>>& rest, double spacing, const IncisionSiteOptions& o, bool& whole) {
    double z_low = std::numeric_limits<double>::infinity(), z_high = -z_low;
    for (const auto& p : rest) z_low = std::min(z_low, double(p[2])), z_high = std::max(z_high, double(p[2]));
    std::size_t front = 0;
    bool found = false;
    whole = true;
    const bool chamber = on_chamber_wall(rest, o);
    auto allowed = [&](std::size_t i) { return !chamber || o.chamber_wall[i] != 0; };
    if (o.approach == IncisionApproach::ventriculotomy) {
        // The most anterior point of the middle third (in z) of the model: the free wall, not an
        // apex or a vessel stump at the model's ends. On the chamber's wall where it is told
        // apart; where none of it lies in the middle third, its most anterior point anywhere.
        for (int pass = 0; pass < 2 && !found; ++pass)
            for (std::size_t i = 0; i < rest.size(); ++i) {
                const double z = rest[i][2];
                if (!allowed(i) || (pass == 0 && (z < z_low + (z_high - z_low) / 3 || z > z_high - (z_high - z_low) / 3))) continue;
                if (!found || rest[i][1] < rest[front][1]) front = i, found = true;
            }
        return front;
    }
    // The atriotomy: the right surface seen from the patient's right, as the most rightward
    // particle (smallest x) of each (y, z) column one spacing wide. Of the columns in the upper
    // half (in z) and the anterior two thirds (in y), the most rightward whose neighbourhood holds
    // the whole incision: along the stroke (± length / 2 in z) and on the retractors' columns
    // (± 2 columns in y) the surface lies within the blade's reach (from its tip, `clearance` in
    // front, to `depth` behind). That keeps the cut on a continuous wall, off the rim of an opening
    // of the segmentation (a valve ring, a vessel's mouth) where the next column's surface lies deep
    // inside the heart.
    double y_low = std::numeric_limits<double>::infinity(), y_high = -y_low;
    for (const auto& p : rest) y_low = std::min(y_low, double(p[1])), y_high = std::max(y_high, double(p[1]));
    double z_mid = z_low + 0.5 * (z_high - z_low), y_limit = y_low + 2.0 * (y_high - y_low) / 3.0, z_top = z_high;
    if (chamber) {
        // On the atrium's own wall: the middle half (in z) of that wall, clear of the venae cavae
        // above and below it, anterior or posterior alike.
        double c_low = std::numeric_limits<double>::infinity(), c_high = -c_low;
        for (std::size_t i = 0; i < rest.size(); ++i)
            if (allowed(i)) c_low = std::min(c_low, double(rest[i][2])), c_high = std::max(c_high, double(rest[i][2]));
        z_mid = c_low + 0.25 * (c_high - c_low), z_top = c_high - 0.25 * (c_high - c_low), y_limit = y_high;
    } else if (o.height_from.size() == rest.size()) {
        double r_low = std::numeric_limits<double>::infinity(), r_high = -r_low;
        for (std::size_t i = 0; i < rest.size(); ++i)
            if (o.height_from[i]) r_low = std::min(r_low, double(rest[i][2])), r_high = std::max(r_high, double(rest[i][2]));
        if (r_low < r_high) z_mid = r_low + 0.5 * (r_high - r_low), z_top = r_high;
    }
    const double h = spacing;
    const int ny = int(std::lround((y_high - y_low) / h)) + 1, nz = int(std::lround((z_high - z_low) / h)) + 1;
    std::vector<int> surface(std::size_t(ny) * std::size_t(nz), -1);
    auto column = [&](int by, int bz) -> int& { return surface[std::size_t(bz) * std::size_t(ny) + std::size_t(by)]; };
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const int by = std::clamp(int(std::lround((rest[i][1] - y_low) / h)), 0, ny - 1);
        const int bz = std::clamp(int(std::lround((rest[i][2] - z_low) / h)), 0, nz - 1);
        int& f = column(by, bz);
        if (f < 0 || rest[i][0] < rest[std::size_t(f)][0]) f = int(i);
    }
    const int half = std::max(1, int(std::lround(0.5 * o.length_mm / h))), wide = 2;
    const double reach = o.depth_mm > 0 ? o.depth_mm : 6.0;  // "through the wall": a wall 6 mm deep around the place
    for (int bz = 0; bz < nz; ++bz)
        for (int by = 0; by < ny; ++by) {
            const int c = column(by, bz);
            if (c < 0 || !allowed(std::size_t(c)) || rest[std::size_t(c)][2] < z_mid || rest[std::size_t(c)][2] > z_top ||
                rest[std::size_t(c)][1] > y_limit)
                continue;
            const double x0 = rest[std::size_t(c)][0];
            if (found && x0 >= rest[front][0]) continue;
            bool holds = bz - half >= 0 && bz + half < nz && by - wide >= 0 && by + wide < ny;
            for (int dz = -half; holds && dz <= half; ++dz)
                for (int dy = -wide; holds && dy <= wide; ++dy) {
                    const int f = column(by + dy, bz + dz);
                    holds = f >= 0 && rest[std::size_t(f)][0] >= x0 - o.clearance_mm && rest[std::size_t(f)][0] <= x0 + reach;
                }
            if (holds) front = std::size_t(c), found = true;
        }
    if (found) return front;
    // No such place (a heart smaller than the incision): the most rightward particle of the upper
    // half among the anterior two thirds.
    whole = false;
    for (int pass = 0; pass < 2 && !found; ++pass)  // the second pass without the y limit: never empty
        for (std::size_t i = 0; i < rest.size(); ++i) {
            if (!allowed(i) || rest[i][2] < z_mid || (pass == 0 && (rest[i][1] > y_limit || rest[i][2] > z_top))) continue;
            if (!found || rest[i][0] < rest[front][0]) front = i, found = true;
        }
    return front;
}

/// Where a line crosses the closed surface: `height` along the line's direction `up` (from the
/// point the line was given at), and whether, followed downward (along −up), it enters the tissue.
struct Crossing {
    double height;
    bool entering;
};

double median(std::vector<double> values) {
    if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
    std::sort(values.begin(), values.end());
    const std::size_t n = values.size();
    return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace

IncisionSite incision_site(const std::vector<std::array<float, 3>>& rest, double spacing, const IncisionSiteOptions& o) {
    IncisionSite site;
    const std::size_t front = entry_particle(rest, spacing, o, site.whole_wall);
    site.particle = front;
    site.on_chamber_wall = on_chamber_wall(rest, o);
    site.entry = Eigen::Vector3d(rest[front][0], rest[front][1], rest[front][2]);
    if (o.approach == IncisionApproach::ventriculotomy) {
        // The blade points posterior (the tool's +z onto the world's +y) with its width along the
        // cut (the tool's x onto the world's +z, the direction it moves), its flat faces facing ±x.
        site.blade = Eigen::Vector3d::UnitY(), site.cut = Eigen::Vector3d::UnitZ(), site.side = Eigen::Vector3d::UnitX();
    } else {
        // The blade points medially (+x), drawn superior; its flat faces facing ±y (cut × side = blade).
        site.blade = Eigen::Vector3d::UnitX(), site.cut = Eigen::Vector3d::UnitZ(), site.side = -Eigen::Vector3d::UnitY();
    }
    // The blade's plane a quarter spacing beside the particle's column: a particle on the plane
    // would be cut from its neighbours on one side or the other by the rounding of the spring test.
    const auto [side_axis, side_sign] = axis_of(site.side);
    site.centre = site.entry;
    site.centre[side_axis] = double(rest[front][std::size_t(side_axis)]) + side_sign * 0.25 * spacing;
    site.wall_mm = wall_thickness(rest, spacing, front, site.blade);
    return site;
}

double wall_thickness(const std::vector<std::array<float, 3>>& rest, double spacing, std::size_t from, const Eigen::Vector3d& direction) {
    const double h = spacing;
    const Eigen::Vector3d start(rest[from][0], rest[from][1], rest[from][2]);
    // The particles near the line, once.
    std::vector<Eigen::Vector3d> near;
    for (const auto& r : rest) {
        const Eigen::Vector3d p(r[0], r[1], r[2]);
        const Eigen::Vector3d d = p - start;
        if (d.dot(direction) > -h && (d - d.dot(direction) * direction).norm() <= 0.75 * h) near.push_back(p);
    }
    double inside = 0.0;
    for (double t = 0.25 * h; t < 200.0; t += 0.25 * h) {
        const Eigen::Vector3d q = start + t * direction;
        bool covered = false;
        for (const auto& p : near)
            if ((p - q).squaredNorm() <= 0.5625 * h * h) {
                covered = true;
                break;
            }
        if (!covered) break;
        inside = t;
    }
    return inside + 0.5 * h;
}

int frontmost_near(const std::vector<std::array<float, 3>>& rest, const Eigen::Vector3d& point, const Eigen::Vector3d& blade, double radius) {
    const auto [axis, sign] = axis_of(blade);
    const int u = axis == 0 ? 1 : 0, v = axis == 2 ? 1 : 2;  // the two other axes, in order
    int best = -1;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        if (std::hypot(rest[i][u] - point[u], rest[i][v] - point[v]) > radius) continue;
        const std::size_t b = std::size_t(best);
        if (best < 0 || (sign > 0 ? rest[i][axis] < rest[b][axis] : rest[i][axis] > rest[b][axis])) best = int(i);
    }
    return best;
}

std::vector<TissueStretch> tissue_stretches(const std::vector<std::array<float, 3>>& positions,
                                            const std::vector<std::array<std::int32_t, 3>>& triangles, const Eigen::Vector3d& point,
                                            const Eigen::Vector3d& up) {
    std::vector<Crossing> crossings;
    const Eigen::Vector3d down = -up;
    for (const auto& t : triangles) {
        const auto& pa = positions[std::size_t(t[0])];
        const auto& pb = positions[std::size_t(t[1])];
        const auto& pc = positions[std::size_t(t[2])];
        const Eigen::Vector3d a(pa[0], pa[1], pa[2]), b(pb[0], pb[1], pb[2]), c(pc[0], pc[1], pc[2]);
        const std::optional<LineTriangleHit> hit = line_triangle(point, down, a, b, c);
        if (!hit) continue;
        // hit->along: the distance travelled downward from `point`; det > 0: the triangle's
        // outward normal against the downward direction, entering.
        crossings.push_back({-hit->along, hit->det > 0.0});
    }
    std::sort(crossings.begin(), crossings.end(), [](const Crossing& x, const Crossing& y) { return x.height > y.height; });
    std::vector<TissueStretch> stretches;
    bool inside = false;
    double top = 0.0, last = std::numeric_limits<double>::infinity();
    bool last_entering = false;
    for (const Crossing& c : crossings) {
        if (std::abs(c.height - last) < 1e-7 && c.entering == last_entering) continue;  // the same crossing, through an edge
        last = c.height, last_entering = c.entering;
        if (c.entering && !inside) inside = true, top = c.height;
        else if (!c.entering && inside) inside = false, stretches.push_back({top, c.height});
    }
    return stretches;
}

Eigen::Vector3d StitchCircle::point(int k) const {
    const double angle = 2.0 * std::numbers::pi * double(k) / double(count);
    return centre + radius_of(k) * (std::cos(angle) * first + std::sin(angle) * second);
}

double StitchCircle::angle_deg(int k) const { return 360.0 * double(k) / double(count); }

StitchCircle stitch_circle(const Eigen::Vector3d& centre, const Eigen::Vector3d& axis, bool on_b, double radius_mm, int count) {
    StitchCircle circle;
    circle.centre = centre;
    circle.axis = axis;
    circle.outward = on_b ? axis : Eigen::Vector3d(-axis);
    circle.radius_mm = radius_mm;
    circle.count = count;
    // The circle's first direction: superior (+z) across the axis, or anterior (−y) where the axis
    // is within 25° of superior-inferior; the second makes them counter-clockwise seen from outside.
    circle.starts_anterior = std::abs(axis.z()) > std::cos(25.0 * std::numbers::pi / 180.0);
    const Eigen::Vector3d reference = circle.starts_anterior ? Eigen::Vector3d(0, -1, 0) : Eigen::Vector3d(0, 0, 1);
    const Eigen::Vector3d& outward = circle.outward;
    circle.first = (reference - reference.dot(outward) * outward).normalized();
    circle.second = outward.cross(circle.first);
    return circle;
}

StitchSites find_stitch_sites(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<std::int32_t, 3>>& triangles,
                              const StitchCircle& circle, double window_margin_mm) {
    // The tissue along each stitch's line, heights from the centre's plane along outward.
    const int n = circle.count;
    std::vector<StitchSite> lines(std::size_t(std::max(n, 0)));
    std::vector<std::vector<TissueStretch>> along(lines.size());
    std::vector<double> mid_wall;
    for (int k = 0; k < n; ++k) {
        StitchSite& line = lines[std::size_t(k)];
        line.angle_deg = circle.angle_deg(k);
        line.point = circle.point(k);
        along[std::size_t(k)] = tissue_stretches(positions, triangles, line.point, circle.outward);
        for (const TissueStretch& s : along[std::size_t(k)])
            if (s.holds(0.0)) mid_wall.push_back(s.length());
    }
    // T: the septum's thickness, from the stretches that hold mid-wall; without any, the window is
    // the margin alone.
    StitchSites found;
    found.mid_wall_found = !mid_wall.empty();
    found.thickness_mm = mid_wall.empty() ? 0.0 : median(mid_wall);
    found.window_mm = found.thickness_mm + window_margin_mm;
    for (int k = 0; k < n; ++k) {
        const auto& stretches = along[std::size_t(k)];
        const auto hit = std::find_if(stretches.begin(), stretches.end(),
                                      [&](const TissueStretch& s) { return std::abs(s.top) <= found.window_mm; });
        StitchSite line = lines[std::size_t(k)];
        if (hit == stretches.end()) {
            found.missing = k;
            found.missing_line = line;
            found.missing_nearest_mm = std::numeric_limits<double>::infinity();
            for (const TissueStretch& s : stretches) found.missing_nearest_mm = std::min(found.missing_nearest_mm, std::abs(s.top));
            found.wall_median_mm = found.wall_min_mm = found.wall_max_mm = std::numeric_limits<double>::quiet_NaN();
            return found;
        }
        line.height_mm = hit->top;
        line.site = line.point + hit->top * circle.outward;
        line.wall_mm = hit->length();
        found.sites.push_back(line);
    }
    std::vector<double> walls;
    for (const StitchSite& site : found.sites) walls.push_back(site.wall_mm);
    found.wall_median_mm = median(walls);
    found.wall_min_mm = walls.empty() ? std::numeric_limits<double>::quiet_NaN() : *std::min_element(walls.begin(), walls.end());
    found.wall_max_mm = walls.empty() ? std::numeric_limits<double>::quiet_NaN() : *std::max_element(walls.begin(), walls.end());
    return found;
}

PatchPlacement place_patch(const std::vector<StitchSite>& sites, const StitchCircle& circle, double thickness_mm) {
    // The plane through the sites (least squares: the normal is the direction of least spread),
    // its normal turned toward the tissue.
    const Eigen::Vector3d& outward = circle.outward;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const StitchSite& s : sites) mean += s.site;
    mean /= double(sites.size());
    Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();
    for (const StitchSite& s : sites) spread += (s.site - mean) * (s.site - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(spread);
    Eigen::Vector3d facing = solver.eigenvectors().col(0).normalized();
    if (facing.dot(outward) > 0) facing = -facing;
    if (-facing.dot(outward) < 0.1) {
        char degrees[32];
        std::snprintf(degrees, sizeof degrees, "%.0f", std::acos(std::clamp(-facing.dot(outward), -1.0, 1.0)) * 180.0 / std::numbers::pi);
        throw InputError(std::string("the stitch sites lie on a surface almost along the defect's axis (its normal ") + degrees +
                         "° from it), not across it: there is no wall round the opening for a patch to cover");
    }
    PatchPlacement patch;
    for (const StitchSite& s : sites) patch.residual_mm = std::max(patch.residual_mm, std::abs((s.site - mean).dot(facing)));
    patch.facing = facing;
    patch.tilt_deg = std::acos(std::clamp(-facing.dot(outward), -1.0, 1.0)) * 180.0 / std::numbers::pi;
    // Where the axis meets the plane, then along the axis, away from the tissue, until half the
    // thickness off the plane: the patch stays centred on the axis and its underside on the plane.
    const double along_axis = facing.dot(mean - circle.centre) / facing.dot(circle.axis);
    patch.centre = circle.centre + along_axis * circle.axis + (0.5 * thickness_mm / -facing.dot(outward)) * outward;
    const Eigen::Vector3d patch_x = (circle.first - circle.first.dot(facing) * facing).normalized();
    Eigen::Matrix3d patch_frame;
    patch_frame << patch_x, facing.cross(patch_x), facing;
    patch.orientation = Eigen::Quaterniond(patch_frame).normalized();
    return patch;
}

}  // namespace heartsim
