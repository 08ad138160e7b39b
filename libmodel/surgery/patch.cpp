#include "libmodel/surgery/patch.h"

#include "libmodel/ellipsoid.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/patch_internal.h"
#include "libmodel/ray_triangle.h"
#include "libmodel/triangle_point.h"

#include <algorithm>
#include <limits>
#include <cmath>
#include <map>
#include <numbers>

namespace heartsim {

PatchMaterial patch_material_named(const std::string& name) {
    if (name == "pericardium") return {"pericardium", 30.0, 0.45, 1.1e-3};
    if (name == "ptfe") return {"ptfe", 40.0, 0.45, 1.5e-3};
    if (name == "dacron") return {"dacron", 200.0, 0.3, 1.38e-3};
    throw InputError("patch material '" + name + "': expected pericardium, ptfe or dacron");
}

namespace {

using patch_internal::barycentric;
using patch_internal::vec;

}  // namespace

PatchModel::PatchModel(const PatchSpec& spec, const std::vector<std::array<float, 3>>& rest, ContactSurface surface,
                       std::vector<double> tissue_inverse_mass)
    : spec_(spec), rest_(rest), tissue_inverse_mass_(std::move(tissue_inverse_mass)), surface_(std::move(surface)) {
    if (!tissue_inverse_mass_.empty() && tissue_inverse_mass_.size() != rest_.size())
        throw InputError("patch: " + std::to_string(tissue_inverse_mass_.size()) + " inverse masses for " + std::to_string(rest_.size()) +
                         " particles");
    auto positive = [](double value, const char* what) {
        if (!(value > 0) || !std::isfinite(value)) throw InputError(std::string("patch: ") + what + " must be positive and finite");
    };
    positive(spec_.thickness_mm, "the thickness (mm)");
    positive(spec_.radius_x_mm, "the half-diameter along x (mm)");
    positive(spec_.radius_y_mm, "the half-diameter along y (mm)");
    positive(spec_.edge_mm, "the triangles' size (mm)");
    positive(spec_.material.youngs_modulus_mpa, "the material's Young's modulus (MPa)");
    positive(spec_.material.density, "the material's density (g/mm³)");
    positive(spec_.tie_ms, "the tying time (ms)");
    positive(spec_.stitch_stiffness, "the suture's stiffness (N/mm)");
    if (!(spec_.material.poisson_ratio >= 0 && spec_.material.poisson_ratio < 0.5)) throw InputError("patch: Poisson's ratio must be in [0, 0.5)");
    if (!(spec_.standoff_mm >= 0) || !(spec_.damping_per_ms >= 0) || spec_.iterations < 1)
        throw InputError("patch: the standoff and damping must not be negative and the iterations at least 1");
    if (std::max(spec_.radius_x_mm, spec_.radius_y_mm) / spec_.edge_mm > 200)
        throw InputError("patch: more than 200 triangles across its radius (give a larger edge)");
    for (const auto& v : surface_.vertices)
        for (const auto& [particle, weight] : v.carriers)
            if (particle < 0 || std::size_t(particle) >= rest_.size()) throw InputError("patch: a surface carrier is not a particle");
    for (const auto& t : surface_.triangles)
        for (int corner : t)
            if (corner < 0 || std::size_t(corner) >= surface_.vertices.size()) throw InputError("patch: a surface triangle's vertex is out of range");
    refresh_particles();
    build_mesh();
}

void PatchModel::refresh_particles() {
    particles_.clear();
    for (const auto& v : surface_.vertices)
        for (const auto& c : v.carriers) particles_.push_back(c.first);
    std::sort(particles_.begin(), particles_.end());
    particles_.erase(std::unique(particles_.begin(), particles_.end()), particles_.end());
    // Each surface vertex as x = base + Σ w_k x_k over its carriers' slots in particles_, base =
    // rest − Σ w_k X_k: a step reads no rest position.
    slot_of_surface_.clear();
    surface_weight_.clear();
    vertex_first_.assign(surface_.vertices.size() + 1, 0);
    largest_weight_sum_ = 1.0;
    surface_base_.resize(surface_.vertices.size());
    for (std::size_t v = 0; v < surface_.vertices.size(); ++v) {
        const CarriedPoint& point = surface_.vertices[v];
        vertex_first_[v] = slot_of_surface_.size();
        Eigen::Vector3d base = point.rest;
        for (const auto& [particle, weight] : point.carriers) {
            slot_of_surface_.push_back(int(std::lower_bound(particles_.begin(), particles_.end(), particle) - particles_.begin()));
            surface_weight_.push_back(weight);
            base -= weight * vec(rest_[std::size_t(particle)]);
        }
        surface_base_[v] = base;
        double sum = 0;
        for (const auto& c : point.carriers) sum += std::abs(c.second);
        largest_weight_sum_ = std::max(largest_weight_sum_, sum);
    }
    vertex_first_[surface_.vertices.size()] = slot_of_surface_.size();
}

void PatchModel::build_mesh() {
    // Rings of 6k vertices at radius k/K of the oval (k = 0…K), joined ring to ring by angle.
    const int rings = std::max(2, int(std::ceil(std::max(spec_.radius_x_mm, spec_.radius_y_mm) / spec_.edge_mm)));
    material_.clear();
    triangles_.clear();
    std::vector<int> first(rings + 1);
    for (int k = 0; k <= rings; ++k) {
        first[k] = int(material_.size());
        const int count = k == 0 ? 1 : 6 * k;
        for (int m = 0; m < count; ++m) {
            const double angle = 2.0 * std::numbers::pi * m / count, r = double(k) / rings;
            material_.push_back({spec_.radius_x_mm * r * std::cos(angle), spec_.radius_y_mm * r * std::sin(angle)});
        }
    }
    for (int k = 1; k <= rings; ++k) {
        const int inner = k == 1 ? 1 : 6 * (k - 1), outer = 6 * k;
        int i = 0, j = 0;
        auto angle = [](int index, int count) { return double(index) / count; };
        while (i < inner || j < outer) {
            const int a = first[k - 1] + i % inner, b = first[k] + j % outer;
            const bool advance_outer = i >= inner || (j < outer && (k == 1 || angle(j + 1, outer) <= angle(i + 1, inner)));
            if (advance_outer) {
                triangles_.push_back({a, b, first[k] + (j + 1) % outer});
                ++j;
            } else {
                triangles_.push_back({a, b, first[k - 1] + (i + 1) % inner});
                ++i;
            }
            if (k == 1 && j == outer) break;
        }
    }
}

void PatchModel::begin_surface(const ParticlePositions& positions) {
    if (positions.size() != particles_.size())
        throw InputError("patch: " + std::to_string(positions.size()) + " positions given for " + std::to_string(particles_.size()) + " particles");
    // How the tissue moved since the last call: its particles' mean displacement, and the largest
    // departure from it (tissue_shift_, tissue_travel_).
    if (slot_x_.size() != positions.size()) {
        slot_x_.assign(positions.size(), Eigen::Vector3d::Zero());
        std::fill(searched_travel_.begin(), searched_travel_.end(), std::numeric_limits<double>::quiet_NaN());  // each vertex looks again
        for (std::size_t k = 0; k < positions.size(); ++k) slot_x_[k] = vec(positions[k]);
    }
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < positions.size(); ++k) mean += vec(positions[k]) - slot_x_[k];
    if (!positions.empty()) mean /= double(positions.size());
    double departed2 = 0.0;
    for (std::size_t k = 0; k < positions.size(); ++k) {
        const Eigen::Vector3d x = vec(positions[k]);
        departed2 = std::max(departed2, (x - slot_x_[k] - mean).squaredNorm());
        slot_x_[k] = x;
    }
    tissue_shift_ += mean;
    tissue_travel_ += largest_weight_sum_ * std::sqrt(departed2);
    surface_x_.resize(surface_.vertices.size());
    surface_normal_.resize(surface_.triangles.size());
    x_stamp_.resize(surface_.vertices.size(), 0);
    normal_stamp_.resize(surface_.triangles.size(), 0);
    ++stamp_;
}

const Eigen::Vector3d& PatchModel::sx(std::size_t v) {
    if (x_stamp_[v] != stamp_) {
        surface_x_[v] = surface_point(v, slot_x_);
        x_stamp_[v] = stamp_;
    }
    return surface_x_[v];
}

const Eigen::Vector3d& PatchModel::sn(std::size_t t) {
    if (normal_stamp_[t] != stamp_) {
        const auto& [a, b, c] = surface_.triangles[t];
        surface_normal_[t] = unit_normal(sx(std::size_t(a)), sx(std::size_t(b)), sx(std::size_t(c)));
        normal_stamp_[t] = stamp_;
    }
    return surface_normal_[t];
}

void PatchModel::deform_surface(const ParticlePositions& positions) {
    begin_surface(positions);
    for (std::size_t v = 0; v < surface_.vertices.size(); ++v) sx(v);
    for (std::size_t t = 0; t < surface_.triangles.size(); ++t) sn(t);
}

PatchModel::SurfaceGrid PatchModel::grid_over(const std::vector<Eigen::Vector3d>& surface_x, const std::vector<Eigen::Vector3d>& normals) const {
    // A 2D grid in the laid patch's plane over the triangles that face it: each triangle in the
    // cells its outline covers grown by grid_margin (the surface drifts, and a point a leaning
    // triangle holds in front of it projects a little off its outline); a vertex finds the
    // triangle under it among the few of its cell whose box holds it.
    SurfaceGrid g;
    const Eigen::Vector3d e1 = frame_.col(0), e2 = frame_.col(1);
    std::vector<Eigen::Vector2d> across(surface_x.size());  // each surface vertex in the patch's plane
    Eigen::AlignedBox2d box;
    for (std::size_t v = 0; v < surface_x.size(); ++v) {
        across[v] = Eigen::Vector2d(surface_x[v].dot(e1), surface_x[v].dot(e2));
        box.extend(across[v]);
    }
    if (box.isEmpty()) return g;
    g.origin = Eigen::Vector3d(box.min().x() - grid_margin, box.min().y() - grid_margin, 0);
    g.dims = Eigen::Vector3i(std::clamp(int(std::ceil((box.sizes().x() + 2 * grid_margin) / grid_cell_)) + 1, 1, 4096),
                             std::clamp(int(std::ceil((box.sizes().y() + 2 * grid_margin) / grid_cell_)) + 1, 1, 4096), 1);
    g.cells.assign(std::size_t(g.dims.x()) * std::size_t(g.dims.y()), {});
    g.box.assign(surface_.triangles.size(), {});
    for (std::size_t t = 0; t < surface_.triangles.size(); ++t) {
        if (!(normals[t].dot(facing_) < -0.3)) continue;  // only surface that faces the patch
        Eigen::AlignedBox2d tb;
        for (int corner : surface_.triangles[t]) tb.extend(across[std::size_t(corner)]);
        // Where a point the triangle holds can be: across, within the margin of its outline; along
        // the patch's +z, from 2 mm behind its nearest corner to 3 mm plus the thickness in front
        // of its farthest (the range triangle_under takes), each widened by the drift allowed.
        double near = std::numeric_limits<double>::infinity(), far = -near;
        for (int corner : surface_.triangles[t]) {
            const double along = surface_x[std::size_t(corner)].dot(facing_);
            near = std::min(near, along), far = std::max(far, along);
        }
        const double slack = 0.5 * grid_margin;
        g.box[t] = {float(tb.min().x() - grid_margin), float(tb.min().y() - grid_margin), float(tb.max().x() + grid_margin),
                    float(tb.max().y() + grid_margin), float(near - 3.0 - spec_.thickness_mm - slack), float(far + 2.0 + slack)};
        const int i0 = std::clamp(int(std::floor((tb.min().x() - grid_margin - g.origin.x()) / grid_cell_)), 0, g.dims.x() - 1);
        const int i1 = std::clamp(int(std::floor((tb.max().x() + grid_margin - g.origin.x()) / grid_cell_)), 0, g.dims.x() - 1);
        const int j0 = std::clamp(int(std::floor((tb.min().y() - grid_margin - g.origin.y()) / grid_cell_)), 0, g.dims.y() - 1);
        const int j1 = std::clamp(int(std::floor((tb.max().y() + grid_margin - g.origin.y()) / grid_cell_)), 0, g.dims.y() - 1);
        for (int j = j0; j <= j1; ++j)
            for (int i = i0; i <= i1; ++i) g.cells[std::size_t(j * g.dims.x() + i)].push_back(std::int32_t(t));
    }
    return g;
}

void PatchModel::build_surface_grid() {
    // Rebuilt whenever some surface vertex may have moved by half the margin since (surface_moved).
    grid_ = grid_over(surface_x_, surface_normal_);
    grid_slot_x_ = slot_x_;
    std::fill(searched_travel_.begin(), searched_travel_.end(), std::numeric_limits<double>::quiet_NaN());  // each vertex looks again
}

Eigen::Vector3d PatchModel::surface_point(std::size_t v, const std::vector<Eigen::Vector3d>& slot_x) const {
    Eigen::Vector3d x = surface_base_[v];
    for (std::size_t k = vertex_first_[v]; k < vertex_first_[v + 1]; ++k) x += surface_weight_[k] * slot_x[std::size_t(slot_of_surface_[k])];
    return x;
}

Eigen::Vector3d PatchModel::unit_normal(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
    const Eigen::Vector3d n = (b - a).cross(c - a);
    const double length = n.norm();
    return length > 0 ? Eigen::Vector3d(n / length) : Eigen::Vector3d::Zero();
}

PatchModel::SurfaceGrid PatchModel::grid_at(const std::vector<Eigen::Vector3d>& slot_x) const {
    std::vector<Eigen::Vector3d> points(surface_.vertices.size()), normals(surface_.triangles.size());
    for (std::size_t v = 0; v < points.size(); ++v) points[v] = surface_point(v, slot_x);
    for (std::size_t t = 0; t < normals.size(); ++t) {
        const auto& [a, b, c] = surface_.triangles[t];
        normals[t] = unit_normal(points[std::size_t(a)], points[std::size_t(b)], points[std::size_t(c)]);
    }
    return grid_over(points, normals);
}

bool PatchModel::surface_moved() const {
    // A surface vertex moves by Σ w_k Δx_k: at most max_k |Δx_k| times the largest Σ |w_k|.
    if (grid_slot_x_.size() != slot_x_.size()) return true;
    double drift2 = 0;
    for (std::size_t k = 0; k < slot_x_.size(); ++k) drift2 = std::max(drift2, (slot_x_[k] - grid_slot_x_[k]).squaredNorm());
    const double limit = 0.5 * grid_margin / largest_weight_sum_;
    return drift2 > limit * limit;
}

int PatchModel::triangle_under(const Eigen::Vector3d& p, Eigen::Vector3d& bary, double& depth) {
    if (grid_.cells.empty()) return -1;
    const int i = int(std::floor((p.dot(frame_.col(0)) - grid_.origin.x()) / grid_cell_));
    const int j = int(std::floor((p.dot(frame_.col(1)) - grid_.origin.y()) / grid_cell_));
    if (i < 0 || j < 0 || i >= grid_.dims.x() || j >= grid_.dims.y()) return -1;
    int best = -1;
    double best_depth = std::numeric_limits<double>::infinity();
    const float u = float(p.dot(frame_.col(0))), v = float(p.dot(frame_.col(1))), along = float(p.dot(facing_));
    for (std::int32_t t : grid_.cells[std::size_t(j * grid_.dims.x() + i)]) {
        const auto& box = grid_.box[std::size_t(t)];
        if (u < box[0] || v < box[1] || u > box[2] || v > box[3] || along < box[4] || along > box[5]) continue;
        const Eigen::Vector3d& normal = sn(std::size_t(t));
        const auto& [a, b, c] = surface_.triangles[std::size_t(t)];
        const Eigen::Vector3d& pa = sx(std::size_t(a));
        const double d = (p - pa).dot(normal);
        if (d < -2.0 || d > 3.0 + spec_.thickness_mm) continue;  // another layer of the tissue
        if (!(normal.dot(facing_) < -0.3)) continue;
        const Eigen::Vector3d w = barycentric(p, pa, sx(std::size_t(b)), sx(std::size_t(c)));
        if (w.minCoeff() < -1e-9) continue;
        if (std::abs(d) < std::abs(best_depth)) best = int(t), best_depth = d, bary = w;
    }
    depth = best_depth;
    return best;
}

bool PatchModel::nearest_on_surface(const Eigen::Vector3d& p, double reach, int& triangle, Eigen::Vector3d& bary) const {
    double best = reach * reach;
    triangle = -1;
    for (std::size_t t = 0; t < surface_.triangles.size(); ++t) {
        const auto& [a, b, c] = surface_.triangles[t];
        const Eigen::Vector3d w = closest_barycentric(p, surface_x_[std::size_t(a)], surface_x_[std::size_t(b)], surface_x_[std::size_t(c)]);
        const Eigen::Vector3d q = w[0] * surface_x_[std::size_t(a)] + w[1] * surface_x_[std::size_t(b)] + w[2] * surface_x_[std::size_t(c)];
        const double d2 = (q - p).squaredNorm();
        if (d2 < best) best = d2, triangle = int(t), bary = w;
    }
    return triangle >= 0;
}

CarriedPoint PatchModel::carried_at(int triangle, const Eigen::Vector3d& bary) const {
    std::map<std::int32_t, double> weights;
    CarriedPoint point;
    for (int corner = 0; corner < 3; ++corner) {
        const CarriedPoint& v = surface_.vertices[std::size_t(surface_.triangles[std::size_t(triangle)][corner])];
        point.rest += bary[corner] * v.rest;
        for (const auto& [particle, weight] : v.carriers) weights[particle] += bary[corner] * weight;
    }
    for (const auto& [particle, weight] : weights)
        if (weight != 0) point.carriers.push_back({particle, weight});
    return point;
}

double PatchModel::vertex_inverse_mass(std::size_t v) const {
    if (surface_inverse_mass_.size() != surface_.vertices.size()) {
        surface_inverse_mass_.resize(surface_.vertices.size());
        for (std::size_t k = 0; k < surface_.vertices.size(); ++k) surface_inverse_mass_[k] = inverse_mass_of(surface_.vertices[k]) * mass_scale_;
    }
    return surface_inverse_mass_[v] / mass_scale_;
}

double PatchModel::inverse_mass_of(const CarriedPoint& point) const {
    if (tissue_inverse_mass_.empty()) return 0.0;  // a rigid tissue
    double w = 0;
    for (const auto& [particle, weight] : point.carriers) w += weight * weight * tissue_inverse_mass_[std::size_t(particle)];
    return w / mass_scale_;
}

Eigen::Vector3d PatchModel::where(const CarriedPoint& point, const ParticlePositions& positions) const {
    Eigen::Vector3d x = point.rest;
    for (const auto& [particle, weight] : point.carriers) {
        const auto it = std::lower_bound(particles_.begin(), particles_.end(), particle);
        if (it == particles_.end() || *it != particle) throw InputError("patch: a carried point's particle is not among particles()");
        x += weight * (vec(positions[std::size_t(it - particles_.begin())]) - vec(rest_[std::size_t(particle)]));
    }
    return x;
}

double PatchModel::mass_g() const {
    double mass = 0;
    for (double w : inverse_mass_)
        if (w > 0) mass += 1.0 / w;
    return mass;
}

void PatchModel::lay(const InstrumentPose& pose, const ParticlePositions& positions) {
    deform_surface(positions);
    const Eigen::Matrix3d rotation = pose.orientation.normalized().toRotationMatrix();
    const Eigen::Vector3d e1 = rotation.col(0), e2 = rotation.col(1), f = rotation.col(2);
    facing_ = f;
    frame_ = rotation;
    build_surface_grid();
    const std::size_t n = material_.size();
    x_.assign(n, Eigen::Vector3d::Zero());
    v_.assign(n, Eigen::Vector3d::Zero());
    std::vector<double> offset(n, 0.0);
    std::vector<char> hit(n, 0);
    const double behind = spec_.standoff_mm + 0.5 * spec_.thickness_mm;
    for (std::size_t i = 0; i < n; ++i) {
        const Eigen::Vector3d p = pose.position + e1 * material_[i].x() + e2 * material_[i].y();
        const Eigen::Vector3d origin = p - 6.0 * f;
        double nearest = -1;
        for (std::size_t t = 0; t < surface_.triangles.size(); ++t) {
            if (!(surface_normal_[t].dot(f) < -0.3)) continue;  // only surface that faces the patch
            const auto& [a, b, c] = surface_.triangles[t];
            const double s = ray_triangle(origin, f, surface_x_[std::size_t(a)], surface_x_[std::size_t(b)], surface_x_[std::size_t(c)]);
            if (s >= 0 && s <= 12.0 && (nearest < 0 || s < nearest)) nearest = s;
        }
        if (nearest >= 0) {
            offset[i] = nearest - 6.0 - behind;
            hit[i] = 1;
        }
    }
    // Vertices over no surface (the opening) follow their neighbours' offsets.
    std::vector<std::vector<int>> neighbours(n);
    for (const auto& t : triangles_)
        for (int e = 0; e < 3; ++e) {
            neighbours[std::size_t(t[e])].push_back(t[(e + 1) % 3]);
            neighbours[std::size_t(t[(e + 1) % 3])].push_back(t[e]);
        }
    // A vertex that meets the surface more than 1.5 mm deeper than the median of its neighbours
    // that met it looks into the opening (its own wall, or the far side): the patch spans the
    // opening and does not line it.
    for (int pass = 0; pass < 3; ++pass) {
        std::vector<char> deep(n, 0);
        for (std::size_t i = 0; i < n; ++i) {
            if (!hit[i]) continue;
            std::vector<double> around;
            for (int j : neighbours[i])
                if (hit[std::size_t(j)]) around.push_back(offset[std::size_t(j)]);
            if (around.size() < 2) continue;
            std::nth_element(around.begin(), around.begin() + std::ptrdiff_t(around.size() / 2), around.end());
            if (offset[i] > around[around.size() / 2] + 1.5) deep[i] = 1;
        }
        for (std::size_t i = 0; i < n; ++i)
            if (deep[i]) hit[i] = 0;
    }
    if (std::find(hit.begin(), hit.end(), 1) != hit.end())
        for (int sweep = 0; sweep < 200; ++sweep)
            for (std::size_t i = 0; i < n; ++i) {
                if (hit[i] || neighbours[i].empty()) continue;
                double sum = 0;
                for (int j : neighbours[i]) sum += offset[std::size_t(j)];
                offset[i] = sum / double(neighbours[i].size());
            }
    for (std::size_t i = 0; i < n; ++i) x_[i] = pose.position + e1 * material_[i].x() + e2 * material_[i].y() + f * offset[i];
    laid_ = x_;

    // Masses, stretch and bending constraints from the laid shape.
    inverse_mass_.assign(n, 0.0);
    alpha_dt_ = -1.0;
    stepped_slot_x_.clear();
    std::vector<double> mass(n, 0.0);
    std::map<std::pair<int, int>, std::vector<int>> opposite;  // edge → the vertices opposite it
    for (const auto& t : triangles_) {
        const double area = 0.5 * (x_[std::size_t(t[1])] - x_[std::size_t(t[0])]).cross(x_[std::size_t(t[2])] - x_[std::size_t(t[0])]).norm();
        for (int e = 0; e < 3; ++e) {
            mass[std::size_t(t[e])] += spec_.material.density * spec_.thickness_mm * area / 3.0;
            const int a = t[e], b = t[(e + 1) % 3];
            opposite[{std::min(a, b), std::max(a, b)}].push_back(t[(e + 2) % 3]);
        }
    }
    std::map<std::pair<int, int>, double> edge_area;
    for (const auto& t : triangles_) {
        const double area = 0.5 * (x_[std::size_t(t[1])] - x_[std::size_t(t[0])]).cross(x_[std::size_t(t[2])] - x_[std::size_t(t[0])]).norm();
        for (int e = 0; e < 3; ++e) edge_area[{std::min(t[e], t[(e + 1) % 3]), std::max(t[e], t[(e + 1) % 3])}] += area / 3.0;
    }
    for (std::size_t i = 0; i < n; ++i) inverse_mass_[i] = mass[i] > 0 ? 1.0 / mass[i] : 0.0;
    area_.assign(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) area_[i] = mass[i] / (spec_.material.density * spec_.thickness_mm);
    distances_.clear();
    const double E = spec_.material.youngs_modulus_mpa, t = spec_.thickness_mm, nu = spec_.material.poisson_ratio;
    const double bending_rigidity = E * t * t * t / (12.0 * (1.0 - nu * nu));  // N·mm
    for (const auto& [edge, area] : edge_area) {
        const double length = (x_[std::size_t(edge.first)] - x_[std::size_t(edge.second)]).norm();
        // A triangular net of springs k has in-plane stiffness (2/√3)·k; per edge k = 3·E·t·A/ℓ²
        // with A its share of area (√3/6·ℓ² on an equilateral net) gives E·t.
        const double stiffness = 3.0 * E * t * area / (length * length);
        distances_.push_back({edge.first, edge.second, length, 1.0 / stiffness});
    }
    for (const auto& [edge, across] : opposite) {
        if (across.size() != 2) continue;
        const double length = (x_[std::size_t(across[0])] - x_[std::size_t(across[1])]).norm();
        if (!(length > 0)) continue;
        distances_.push_back({across[0], across[1], length, length * length / (2.0 * bending_rigidity)});
    }
    // Gauss–Seidel by colour: constraints that share no vertex one after another, so the processor
    // overlaps their square roots and divisions (a chain through shared vertices would wait on
    // each); within a colour their order does not matter. Greedy colouring, deterministic.
    {
        std::vector<int> colour(distances_.size(), -1);
        std::vector<std::vector<int>> used(n);  // per vertex: the colours of its constraints so far
        int colours = 0;
        for (std::size_t k = 0; k < distances_.size(); ++k) {
            const auto& ua = used[std::size_t(distances_[k].a)];
            const auto& ub = used[std::size_t(distances_[k].b)];
            int c = 0;
            while (std::find(ua.begin(), ua.end(), c) != ua.end() || std::find(ub.begin(), ub.end(), c) != ub.end()) ++c;
            colour[k] = c;
            used[std::size_t(distances_[k].a)].push_back(c);
            used[std::size_t(distances_[k].b)].push_back(c);
            colours = std::max(colours, c + 1);
        }
        std::vector<Distance> ordered;
        ordered.reserve(distances_.size());
        colour_first_.clear();
        for (int c = 0; c < colours; ++c) {
            colour_first_.push_back(std::int32_t(ordered.size()));
            for (std::size_t k = 0; k < distances_.size(); ++k)
                if (colour[k] == c) ordered.push_back(distances_[k]);
        }
        colour_first_.push_back(std::int32_t(ordered.size()));
        distances_ = std::move(ordered);
    }
    stitches_.clear();
    under_.assign(x_.size(), -1);
    searched_travel_.assign(x_.size(), std::numeric_limits<double>::quiet_NaN());
    asleep_positions_.clear();
    held_ = true;
    contact_force_.setZero();
    clear_loads();
}

std::optional<std::size_t> PatchModel::tie(const Eigen::Vector3d& tip, double time_ms, const ParticlePositions& positions, std::string* why,
                                           double reach_mm) {
    if (!laid()) {
        if (why) *why = "no patch is laid";
        return std::nullopt;
    }
    deform_surface(positions);
    // The patch vertex over the tip as the patch was laid, seen along the way it faced.
    int vertex = 0;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < laid_.size(); ++i) {
        const Eigen::Vector3d d = laid_[i] - tip;
        const double d2 = (d - d.dot(facing_) * facing_).squaredNorm();
        if (d2 < best) best = d2, vertex = int(i);
    }
    if (std::sqrt(best) > reach_mm) {
        if (why) *why = "the needle's tip is not over the patch (within " + std::to_string(int(reach_mm)) + " mm)";
        return std::nullopt;
    }
    // The tissue under that vertex: the stitch goes straight through patch and tissue, so tying it
    // pulls across neither.
    const Eigen::Vector3d& x = x_[std::size_t(vertex)];
    int triangle = -1;
    Eigen::Vector3d bary;
    double nearest = -1;
    for (std::size_t t = 0; t < surface_.triangles.size(); ++t) {
        if (!(surface_normal_[t].dot(facing_) < -0.3)) continue;
        const auto& [a, b, c] = surface_.triangles[t];
        const double along = ray_triangle(x - 2.0 * facing_, facing_, surface_x_[std::size_t(a)], surface_x_[std::size_t(b)], surface_x_[std::size_t(c)]);
        if (along >= 0 && along <= reach_mm + 2.0 && (nearest < 0 || along < nearest)) {
            nearest = along, triangle = int(t);
            bary = barycentric(x - 2.0 * facing_ + along * facing_, surface_x_[std::size_t(a)], surface_x_[std::size_t(b)], surface_x_[std::size_t(c)]);
        }
    }
    if (triangle < 0 && !nearest_on_surface(x, reach_mm, triangle, bary)) {
        if (why) *why = "no tissue surface within " + std::to_string(int(reach_mm)) + " mm of the patch there";
        return std::nullopt;
    }
    Stitch stitch;
    stitch.vertex = vertex;
    stitch.anchor = carried_at(triangle, bary);
    stitch.tied_ms = time_ms;
    stitch.start_length = (x_[std::size_t(vertex)] - where(stitch.anchor, positions)).norm();
    stitches_.push_back(stitch);
    held_ = false;
    return stitches_.size() - 1;
}

void PatchModel::add_load(const CarriedPoint& point, const Eigen::Vector3d& force) {
    for (const auto& [particle, weight] : point.carriers) add_load(slot_of(particle), weight * force);
}

void PatchModel::add_load(std::size_t slot, const Eigen::Vector3d& force) {
    if (slot_force_.size() != particles_.size()) slot_force_.assign(particles_.size(), Eigen::Vector3d::Zero()), slot_loaded_.assign(particles_.size(), 0);
    if (!slot_loaded_[slot]) slot_loaded_[slot] = 1, loaded_slots_.push_back(std::int32_t(slot));
    slot_force_[slot] += force;
}

std::size_t PatchModel::slot_of(std::int32_t particle) const {
    const auto it = std::lower_bound(particles_.begin(), particles_.end(), particle);
    if (it == particles_.end() || *it != particle) throw InputError("patch: a carried point's particle is not among particles()");
    return std::size_t(it - particles_.begin());
}

void PatchModel::clear_loads() {
    for (std::int32_t slot : loaded_slots_) slot_force_[std::size_t(slot)].setZero(), slot_loaded_[std::size_t(slot)] = 0;
    loaded_slots_.clear();
}

void PatchModel::set_obstacles(std::vector<PatchObstacle> obstacles) {
    for (const PatchObstacle& o : obstacles)
        if (!o.pose.position.allFinite() || !o.pose.orientation.coeffs().allFinite() || !(o.semi_axes.minCoeff() > 0) || !o.semi_axes.allFinite())
            throw InputError("patch: an obstacle needs a finite pose and positive semi-axes");
    obstacles_ = std::move(obstacles);
    obstacle_force_.assign(obstacles_.size(), Eigen::Vector3d::Zero());
}

bool PatchModel::obstacle_near() const {
    const double margin = 0.5 * spec_.thickness_mm + spec_.edge_mm;
    for (const PatchObstacle& o : obstacles_) {
        const double reach = o.semi_axes.maxCoeff() + margin;
        for (const Eigen::Vector3d& x : x_)
            if ((x - o.pose.position).squaredNorm() < reach * reach) return true;
    }
    return false;
}

bool PatchModel::at_rest(const ParticlePositions& positions, double time_ms) const {
    if (pressure_ > 0 || asleep_positions_.size() != positions.size() || obstacle_near()) return false;
    for (const Stitch& s : stitches_)
        if (time_ms < s.tied_ms + spec_.tie_ms) return false;  // still drawing tight
    constexpr double still = 1e-5;  // mm/ms, and mm for the tissue since the patch last stepped
    for (const Eigen::Vector3d& v : v_)
        if (v.squaredNorm() > still * still) return false;
    for (std::size_t k = 0; k < positions.size(); ++k)
        for (int c = 0; c < 3; ++c)
            if (std::abs(double(positions[k][c]) - double(asleep_positions_[k][c])) > still) return false;
    return true;
}

std::vector<ParticleLoad> PatchModel::loads() const {
    std::vector<std::int32_t> slots = loaded_slots_;
    std::sort(slots.begin(), slots.end());  // particles_ is sorted: so are the loads
    std::vector<ParticleLoad> out;
    out.reserve(slots.size());
    for (std::int32_t slot : slots) out.push_back({particles_[std::size_t(slot)], slot_force_[std::size_t(slot)]});
    return out;
}

PatchModel PatchModel::under_pressure(const ParticlePositions& positions, double pressure_n_mm2, double duration_ms, double dt_ms) const {
    PatchModel test = *this;
    test.held_ = false;  // nothing holds it but its stitches
    test.obstacles_.clear();  // nor any instrument
    test.pressure_ = pressure_n_mm2;
    // A quasi-static test: the patch made a hundredfold heavier and overdamped, so the pressure
    // moves it by little per step and the constraints keep up (its mass changes nothing at rest).
    for (double& w : test.inverse_mass_) w *= 1e-2;
    test.alpha_dt_ = -1.0;  // its compliance terms again, with those masses
    test.spec_.damping_per_ms = std::max(test.spec_.damping_per_ms, 1.0);
    test.spec_.iterations = std::max(test.spec_.iterations, 16);  // off the clock: converged
    test.tissue_inverse_mass_.clear();                             // the tissue held as it is
    test.surface_inverse_mass_.clear();
    for (double t = 0; t < duration_ms; t += dt_ms) test.step(positions, dt_ms, 1e12);  // every stitch drawn tight
    return test;
}

void PatchModel::recover(const ParticlePositions& positions, double time_ms) {
    if (!laid()) return;
    for (auto& v : v_) v.setZero();
    stepped_slot_x_.clear();  // the tissue's jump back carries nothing
    clear_loads();
    contact_force_.setZero();
    asleep_positions_.clear();
    for (Stitch& s : stitches_) {
        s.tied_ms = time_ms;
        s.start_length = (x_[std::size_t(s.vertex)] - where(s.anchor, positions)).norm();
        s.force_n.setZero();
    }
}

}  // namespace heartsim
