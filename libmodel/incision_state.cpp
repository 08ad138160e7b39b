/// @file incision_state.cpp
/// @brief incision_state.h: strokes into rest-space strips, the mesh opened along them, and the
/// vertices beside the cut embedded again on their own side.
#include "incision_state.h"

#include "mapping_embedding.h"

#include <algorithm>
#include <chrono>
#include <optional>
#include <cmath>
#include <unordered_map>

namespace heartsim {

namespace {

double distance_to_segment(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double length2 = ab.squaredNorm();
    const double t = length2 > 0 ? std::clamp((p - a).dot(ab) / length2, 0.0, 1.0) : 0.0;
    return (a + t * ab - p).norm();
}

std::int64_t cell_key(long i, long j, long k) {
    return (std::int64_t(i) + (1 << 20)) | ((std::int64_t(j) + (1 << 20)) << 21) | ((std::int64_t(k) + (1 << 20)) << 42);
}

/// Points in buckets of one lattice spacing.
class PointBuckets {
public:
    PointBuckets(const std::vector<Eigen::Vector3d>& points, double size) : points_(points), size_(size) {
        for (std::size_t p = 0; p < points.size(); ++p) cells_[key(points[p])].push_back(std::int32_t(p));
    }
    template <class F>
    void near(const Eigen::Vector3d& c, long reach, F&& visit) const {
        const long i = cell(c.x()), j = cell(c.y()), k = cell(c.z());
        for (long dk = -reach; dk <= reach; ++dk)
            for (long dj = -reach; dj <= reach; ++dj)
                for (long di = -reach; di <= reach; ++di)
                    if (auto it = cells_.find(cell_key(i + di, j + dj, k + dk)); it != cells_.end())
                        for (std::int32_t p : it->second) visit(p);
    }

private:
    long cell(double x) const { return long(std::floor(x / size_)); }
    std::int64_t key(const Eigen::Vector3d& p) const { return cell_key(cell(p.x()), cell(p.y()), cell(p.z())); }
    const std::vector<Eigen::Vector3d>& points_;
    double size_;
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells_;
};

/// The cut faces (the swept strip inside the tissue, where the blade passed) in buckets of one
/// lattice spacing, for the test whether a segment passes through the cut.
class CapIndex {
public:
    CapIndex(const std::vector<std::array<Eigen::Vector3d, 3>>& faces, double size) : faces_(faces), size_(size) {
        for (std::size_t t = 0; t < faces.size(); ++t) {
            Eigen::AlignedBox3d box;
            for (const auto& p : faces[t]) box.extend(p);
            for (long k = cell(box.min().z()); k <= cell(box.max().z()); ++k)
                for (long j = cell(box.min().y()); j <= cell(box.max().y()); ++j)
                    for (long i = cell(box.min().x()); i <= cell(box.max().x()); ++i) cells_[cell_key(i, j, k)].push_back(std::int32_t(t));
        }
    }
    /// Whether the segment a–b passes through a cut face (its ends touching one do not count).
    bool crosses(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const {
        const Eigen::Vector3d low = a.cwiseMin(b), high = a.cwiseMax(b);
        for (long k = cell(low.z()); k <= cell(high.z()); ++k)
            for (long j = cell(low.y()); j <= cell(high.y()); ++j)
                for (long i = cell(low.x()); i <= cell(high.x()); ++i) {
                    const auto it = cells_.find(cell_key(i, j, k));
                    if (it == cells_.end()) continue;
                    for (std::int32_t t : it->second)
                        if (through(a, b, faces_[std::size_t(t)])) return true;
                }
        return false;
    }

private:
    static bool through(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const std::array<Eigen::Vector3d, 3>& t) {
        // Möller–Trumbore, the triangle's edges included, the segment's ends excluded.
        const Eigen::Vector3d& p0 = t[0];
        const Eigen::Vector3d e1 = t[1] - p0, e2 = t[2] - p0, d = b - a;
        const Eigen::Vector3d p = d.cross(e2);
        const double det = e1.dot(p);
        if (std::abs(det) < 1e-14 * d.norm() * e1.norm() * e2.norm()) return false;
        const Eigen::Vector3d s = a - p0;
        const double u = s.dot(p) / det;
        if (u < 0.0 || u > 1.0) return false;
        const Eigen::Vector3d q = s.cross(e1);
        const double v = d.dot(q) / det;
        if (v < 0.0 || u + v > 1.0) return false;
        const double t_hit = e2.dot(q) / det;
        return t_hit > 1e-6 && t_hit < 1.0 - 1e-6;
    }
    long cell(double x) const { return long(std::floor(x / size_)); }
    const std::vector<std::array<Eigen::Vector3d, 3>>& faces_;
    double size_;
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells_;
};

}  // namespace

std::vector<CutSurface> stroke_surfaces(const BladeStroke& stroke, const std::vector<std::array<float, 3>>& positions,
                                        const Lattice& lattice) {
    const std::size_t n = stroke.poses.size();
    if (n < 2 || stroke.length <= 0) return {};
    const double h = lattice.spacing;
    std::vector<Eigen::Vector3d> tip(n), end(n);
    for (std::size_t k = 0; k < n; ++k) {
        const auto segment = blade_segment(stroke.poses[k], stroke.length);
        tip[k] = segment[0];
        end[k] = segment[1];
    }
    // Douglas–Peucker on the blade's two ends together.
    std::vector<std::uint8_t> keep(n, 0);
    keep.front() = keep.back() = 1;
    std::vector<std::pair<std::size_t, std::size_t>> spans{{0, n - 1}};
    const double tolerance = 0.05 * h;
    while (!spans.empty()) {
        const auto [i, j] = spans.back();
        spans.pop_back();
        double worst = 0.0;
        std::size_t at = i;
        for (std::size_t k = i + 1; k < j; ++k) {
            const double d = std::max(distance_to_segment(tip[k], tip[i], tip[j]), distance_to_segment(end[k], end[i], end[j]));
            if (d > worst) {
                worst = d;
                at = k;
            }
        }
        if (worst > tolerance) {
            keep[at] = 1;
            spans.push_back({i, at});
            spans.push_back({at, j});
        }
    }
    std::vector<std::size_t> kept;
    for (std::size_t k = 0; k < n; ++k)
        if (keep[k]) kept.push_back(k);

    // Into the rest shape: p − the particles' displacement around p.
    const std::size_t count = lattice.particles.rest_position.size();
    std::vector<Eigen::Vector3d> now(count), rest(count);
    for (std::size_t p = 0; p < count; ++p) {
        const auto& x = positions[p];
        const auto& r = lattice.particles.rest_position[p];
        now[p] = {x[0], x[1], x[2]};
        rest[p] = {r[0], r[1], r[2]};
    }
    const PointBuckets buckets(now, h);
    auto to_rest = [&](const Eigen::Vector3d& p) -> Eigen::Vector3d {
        Eigen::Vector3d shift = Eigen::Vector3d::Zero();
        double total = 0.0;
        buckets.near(p, 2, [&](std::int32_t q) {
            const double d2 = (now[std::size_t(q)] - p).squaredNorm();
            if (d2 > 4 * h * h) return;
            const double w = std::exp(-d2 / (h * h));
            shift += w * (now[std::size_t(q)] - rest[std::size_t(q)]);
            total += w;
        });
        if (total > 0) return p - shift / total;
        for (long reach = 3; reach <= 12; reach *= 2) {
            double best = INFINITY;
            std::int32_t nearest = -1;
            buckets.near(p, reach, [&](std::int32_t q) {
                const double d2 = (now[std::size_t(q)] - p).squaredNorm();
                if (d2 < best) {
                    best = d2;
                    nearest = q;
                }
            });
            if (nearest >= 0) return p - (now[std::size_t(nearest)] - rest[std::size_t(nearest)]);
        }
        return p;
    };

    // Pieces, split where the blade's middle turns back.
    std::vector<CutSurface> surfaces;
    std::size_t first = 0;
    auto emit = [&](std::size_t from, std::size_t to) {  // kept[from..to]
        if (to <= from) return;
        CutSurface s;
        for (std::size_t q = from; q <= to; ++q) {
            s.points.push_back(to_rest(tip[kept[q]]));
            s.points.push_back(to_rest(end[kept[q]]));
        }
        for (std::int32_t a = 0; a + 1 < std::int32_t(to - from + 1); ++a) {
            const std::int32_t b = a + 1;
            s.triangles.push_back({2 * a, 2 * a + 1, 2 * b + 1});
            s.triangles.push_back({2 * a, 2 * b + 1, 2 * b});
        }
        surfaces.push_back(std::move(s));
    };
    for (std::size_t q = 1; q + 1 < kept.size(); ++q) {
        const Eigen::Vector3d before = (tip[kept[q]] + end[kept[q]]) - (tip[kept[q - 1]] + end[kept[q - 1]]);
        const Eigen::Vector3d after = (tip[kept[q + 1]] + end[kept[q + 1]]) - (tip[kept[q]] + end[kept[q]]);
        if (before.dot(after) < 0) {
            emit(first, q);
            first = q;
        }
    }
    emit(first, kept.size() - 1);
    return surfaces;
}

struct IncisionState::Impl {
    explicit Impl(const Lattice& lattice, const std::vector<Eigen::Vector3d>& rest) : embedder(lattice, rest) {}
    mapping_internal::CellEmbedder embedder;
};

IncisionState::IncisionState(const Lattice& lattice, const std::vector<std::array<float, 3>>& positions,
                             const std::vector<std::array<float, 3>>& normals, const std::vector<std::array<std::int32_t, 3>>& triangles,
                             const VisualMapping& mapping, const SimulationSurface& surface)
    : lattice_(lattice) {
    for (const auto& r : lattice.particles.rest_position) particle_rest_.emplace_back(r[0], r[1], r[2]);
    impl_ = std::make_unique<Impl>(lattice, particle_rest_);
    uncut_ = incision_mesh(positions, normals, triangles);
    uncut_mapping_ = mapping;
    if (uncut_mapping_.particles.size() != positions.size()) {  // carriers implied by the triangle: made explicit
        uncut_mapping_.particles.resize(positions.size());
        uncut_mapping_.weights.resize(positions.size());
        for (std::size_t v = 0; v < positions.size(); ++v)
            mapping_carriers(mapping, surface, v, uncut_mapping_.particles[v], uncut_mapping_.weights[v]);
    }
    uncut_triangles_ = triangles.size();
    restore();
}

IncisionState::~IncisionState() = default;

void IncisionState::restore() {
    committed_.reset();
    mesh_ = uncut_;
    mapping_ = uncut_mapping_;
    cut_faces_.clear();
    applied_.clear();
    order_for_drawing();
}

void IncisionState::order_for_drawing() {
    drawn_.clear();
    drawn_.reserve(mesh_.triangles.size());
    for (std::size_t t = 0; t < mesh_.triangles.size(); ++t)
        if (!mesh_.cap[t]) drawn_.push_back(mesh_.triangles[t]);
    cap_first_ = drawn_.size();
    for (std::size_t t = 0; t < mesh_.triangles.size(); ++t)
        if (mesh_.cap[t]) drawn_.push_back(mesh_.triangles[t]);
}

std::vector<std::array<float, 3>> IncisionState::rest_positions() const {
    std::vector<std::array<float, 3>> out(mesh_.rest.size());
    for (std::size_t v = 0; v < out.size(); ++v) out[v] = {float(mesh_.rest[v].x()), float(mesh_.rest[v].y()), float(mesh_.rest[v].z())};
    return out;
}

std::vector<std::array<float, 3>> IncisionState::rest_normals() const {
    std::vector<std::array<float, 3>> out(mesh_.normals.size());
    for (std::size_t v = 0; v < out.size(); ++v) out[v] = {mesh_.normals[v].x(), mesh_.normals[v].y(), mesh_.normals[v].z()};
    return out;
}

bool IncisionState::pending(const StrokeLog& log, bool finish) const {
    if (log.clears() != generation_) return true;
    const auto& strokes = log.strokes();
    for (std::size_t r = 0; r < strokes.size(); ++r)
        if ((r >= applied_.size() || !applied_[r]) && (strokes[r].lifted || finish) && strokes[r].poses.size() >= 2) return true;
    return false;
}

void IncisionState::apply(const BladeStroke& stroke, const std::vector<std::array<float, 3>>& positions, IncisionUpdate& update) {
    const double gap = 0.02 * lattice_.spacing;
    for (const CutSurface& surface : stroke_surfaces(stroke, positions, lattice_)) {
        const IncisionResult result = open_along(mesh_, surface, gap);
        if (!result.failure.empty()) update.failures.push_back(result.failure);
        if (!result.opened) continue;
        // The whole strip parts the particles, as the physics cut parted them: also where it
        // passes between particles outside the detailed mesh (the lattice reaches up to half a
        // spacing beyond the surface).
        for (const auto& t : surface.triangles)
            cut_faces_.push_back({surface.points[std::size_t(t[0])], surface.points[std::size_t(t[1])], surface.points[std::size_t(t[2])]});
        Eigen::AlignedBox3d region;
        for (const auto& p : surface.points) region.extend(p);
        region.min().array() -= 2 * lattice_.spacing;
        region.max().array() += 2 * lattice_.spacing;
        update.reembedded += reembed(result, region);
        update.opened = true;
    }
    ++update.strokes;
}

bool IncisionState::end_preview() {
    if (!committed_) return false;
    mesh_ = std::move(committed_->mesh);
    mapping_ = std::move(committed_->mapping);
    cut_faces_ = std::move(committed_->cut_faces);
    committed_.reset();
    order_for_drawing();
    return true;
}

IncisionUpdate IncisionState::update(const StrokeLog& log, const std::vector<std::array<float, 3>>& positions, bool finish) {
    const auto start = std::chrono::steady_clock::now();
    IncisionUpdate update;
    update.opened = end_preview();
    if (log.clears() != generation_) {
        update.opened = update.opened || cut();
        restore();
        generation_ = log.clears();
    }
    const auto& strokes = log.strokes();
    applied_.resize(std::max(applied_.size(), strokes.size()), 0);
    bool changed = false;
    for (std::size_t r = 0; r < strokes.size(); ++r) {
        if (applied_[r] || !(strokes[r].lifted || finish)) continue;
        applied_[r] = 1;
        IncisionUpdate one;
        apply(strokes[r], positions, one);
        changed = changed || one.opened;
        update.strokes += one.strokes;
        update.reembedded += one.reembedded;
        update.failures.insert(update.failures.end(), one.failures.begin(), one.failures.end());
    }
    if (changed) order_for_drawing();
    update.opened = update.opened || changed;
    update.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return update;
}

IncisionUpdate IncisionState::preview(const StrokeLog& log, const std::vector<std::array<float, 3>>& positions) {
    const auto start = std::chrono::steady_clock::now();
    IncisionUpdate update;
    update.opened = end_preview();
    if (log.clears() != generation_) {  // a reset: the uncut mesh
        update.opened = update.opened || cut();
        restore();
        generation_ = log.clears();
    }
    const auto& strokes = log.strokes();
    bool open = false;
    for (std::size_t r = 0; r < strokes.size(); ++r)
        open = open || ((r >= applied_.size() || !applied_[r]) && !strokes[r].lifted && strokes[r].poses.size() >= 2);
    if (!open) return update;
    committed_ = Committed{mesh_, mapping_, cut_faces_};
    for (std::size_t r = 0; r < strokes.size(); ++r)
        if ((r >= applied_.size() || !applied_[r]) && !strokes[r].lifted && strokes[r].poses.size() >= 2) apply(strokes[r], positions, update);
    order_for_drawing();
    update.opened = true;
    update.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return update;
}

std::size_t IncisionState::reembed(const IncisionResult& result, const Eigen::AlignedBox3d& region) {
    const CapIndex caps(cut_faces_, lattice_.spacing);
    const std::size_t vertices = mesh_.rest.size();
    const std::size_t before = mapping_.offset.size();
    // Rows for the added vertices: the normal frame (triangle, λ) of an old vertex they share a
    // face with (it only turns the shading normal), carriers set below.
    mapping_.triangle.resize(vertices, 0);
    mapping_.barycentric.resize(vertices, {1.0f, 0.0f, 0.0f});
    mapping_.offset.resize(vertices, 0.0f);
    mapping_.particles.resize(vertices, {});
    mapping_.weights.resize(vertices, {});
    std::vector<std::uint8_t> framed(vertices, 0);
    for (const auto& t : mesh_.triangles)
        for (std::int32_t v : t) {
            if (std::size_t(v) < before || framed[std::size_t(v)]) continue;
            for (std::int32_t w : t)
                if (std::size_t(w) < before) {
                    mapping_.triangle[std::size_t(v)] = mapping_.triangle[std::size_t(w)];
                    mapping_.barycentric[std::size_t(v)] = mapping_.barycentric[std::size_t(w)];
                    framed[std::size_t(v)] = 1;
                    break;
                }
        }

    std::vector<std::uint8_t> again(vertices, 0);
    for (std::size_t v = before; v < vertices; ++v) again[v] = 1;
    for (std::int32_t v : result.moved) again[std::size_t(v)] = 1;
    for (std::size_t v = 0; v < before; ++v) {
        if (again[v] || !region.contains(mesh_.rest[v])) continue;
        for (int k = 0; k < 8; ++k)
            if (mapping_.weights[v][std::size_t(k)] != 0.0f &&
                caps.crosses(mesh_.rest[v], particle_rest_[std::size_t(mapping_.particles[v][std::size_t(k)])])) {
                again[v] = 1;
                break;
            }
    }
    std::size_t count = 0;
    for (std::size_t v = 0; v < vertices; ++v) {
        if (!again[v]) continue;
        const Eigen::Vector3d& x = mesh_.rest[v];
        mapping_internal::Embedding e =
            impl_->embedder.embed(x, [&](std::int32_t p) { return !caps.crosses(x, particle_rest_[std::size_t(p)]); });
        if (!e.found()) e = impl_->embedder.embed(x);  // no particle on its side nearby: the nearest any side
        if (!e.found()) continue;
        for (int k = 0; k < 8; ++k) {
            mapping_.particles[v][std::size_t(k)] = k < e.count ? e.particles[std::size_t(k)] : e.particles[0];
            mapping_.weights[v][std::size_t(k)] = k < e.count ? float(e.weights[std::size_t(k)]) : 0.0f;
        }
        mapping_.offset[v] = 0.0f;
        ++count;
    }
    return count;
}

}  // namespace heartsim
