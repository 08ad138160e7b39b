/// @file incision_state.cpp
/// @brief incision_state.h: strokes into rest-space strips, the mesh opened along them, and the
/// vertices beside the cut embedded again on their own side.
#include "libmodel/surgery/incision_state.h"

#include "libmodel/mapping_embedding.h"

#include <algorithm>
#include <array>
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

/// Points in buckets of one lattice spacing: those whose cells lie in the cells of the box
/// `low`–`high` (near() with `reach` sees all the points it would with every point in buckets
/// wherever its centre's cell lies `reach` cells or more inside the box's).
class PointBuckets {
public:
    PointBuckets(const std::vector<Eigen::Vector3d>& points, double size, const Eigen::Vector3d& low, const Eigen::Vector3d& high)
        : points_(points), size_(size) {
        const long i0 = cell(low.x()), j0 = cell(low.y()), k0 = cell(low.z()), i1 = cell(high.x()), j1 = cell(high.y()), k1 = cell(high.z());
        for (std::size_t p = 0; p < points.size(); ++p) {
            const long i = cell(points[p].x()), j = cell(points[p].y()), k = cell(points[p].z());
            if (i < i0 || i > i1 || j < j0 || j > j1 || k < k0 || k > k1) continue;
            cells_[cell_key(i, j, k)].push_back(std::int32_t(p));
        }
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
    const std::vector<Eigen::Vector3d>& points_;
    double size_;
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells_;
};

/// Whether triangle `t` meets the box `low`–`high` (the separating axis test: the box's three
/// axes, the triangle's normal, and the nine cross products of their edges).
bool triangle_meets_box(const std::array<Eigen::Vector3d, 3>& t, const Eigen::Vector3d& low, const Eigen::Vector3d& high) {
    const Eigen::Vector3d centre = 0.5 * (low + high), half = 0.5 * (high - low);
    const std::array<Eigen::Vector3d, 3> v{t[0] - centre, t[1] - centre, t[2] - centre};
    const std::array<Eigen::Vector3d, 3> edge{v[1] - v[0], v[2] - v[1], v[0] - v[2]};
    auto apart = [&](const Eigen::Vector3d& axis) {
        const double p0 = v[0].dot(axis), p1 = v[1].dot(axis), p2 = v[2].dot(axis);
        const double r = half.dot(axis.cwiseAbs());
        return std::min({p0, p1, p2}) > r || std::max({p0, p1, p2}) < -r;
    };
    for (int d = 0; d < 3; ++d)
        if (apart(Eigen::Vector3d::Unit(d))) return false;
    if (apart(edge[0].cross(edge[1]))) return false;
    for (int d = 0; d < 3; ++d)
        for (const Eigen::Vector3d& e : edge)
            if (apart(Eigen::Vector3d::Unit(d).cross(e))) return false;
    return true;
}

/// Narrows [enter, leave] to where a + t·d lies in [low, high] (one coordinate of a segment a + t·d,
/// t in [0, 1]); false when nothing is left.
bool clip(double a, double d, double low, double high, double& enter, double& leave) {
    if (d == 0.0) return a >= low && a <= high && enter <= leave;
    double t0 = (low - a) / d, t1 = (high - a) / d;
    if (t0 > t1) std::swap(t0, t1);
    enter = std::max(enter, t0);
    leave = std::min(leave, t1);
    return enter <= leave;
}

/// Every cut so far (the strips the strokes swept, at rest, each whole: it parts the particles also
/// where it passes beyond the mesh), in the order they were made, and in buckets of one lattice
/// spacing, for the test whether a segment passes through the cut. A face is in the buckets it
/// meets (its cells grown by a thousandth of a spacing, so that rounding leaves none out), not in
/// every bucket of its box: a long strip's faces lie across few of the cells their boxes span.
/// Faces are only ever added at the end, or dropped from the end (a preview given back), so each
/// bucket lists its faces in the order they were made, and a test may start from any face.
class CapIndex {
public:
    explicit CapIndex(double size) : size_(size) {}

    /// The faces that last stopped a segment from one point, the latest first: tested before the
    /// buckets (the segments from a point beside the cuts are mostly stopped by the same few faces,
    /// and a point walled in by cuts asks of every particle within reach). A face the segment
    /// passes through lies in a bucket the segment meets, so the answer is the same.
    struct Blockers {
        std::array<std::int32_t, 8> face{};
        std::size_t count = 0;
        void remember(std::int32_t f) {
            if (count < face.size()) ++count;
            std::copy_backward(face.begin(), face.begin() + std::ptrdiff_t(count) - 1, face.begin() + std::ptrdiff_t(count));
            face[0] = f;
        }
    };

    std::size_t size() const { return faces_.size(); }

    void add(const std::array<Eigen::Vector3d, 3>& face) {
        const auto id = std::int32_t(faces_.size());
        faces_.push_back(face);
        Eigen::AlignedBox3d box;
        for (const auto& p : face) box.extend(p);
        const double margin = 1e-3 * size_;
        for (long k = cell(box.min().z() - margin); k <= cell(box.max().z() + margin); ++k)
            for (long j = cell(box.min().y() - margin); j <= cell(box.max().y() + margin); ++j)
                for (long i = cell(box.min().x() - margin); i <= cell(box.max().x() + margin); ++i) {
                    const Eigen::Vector3d low = Eigen::Vector3d(double(i), double(j), double(k)) * size_;
                    if (!triangle_meets_box(face, low.array() - margin, (low.array() + size_ + margin).matrix())) continue;
                    const std::int64_t key = cell_key(i, j, k);
                    cells_[key].push_back(id);
                    added_.push_back(key);
                }
        filed_.push_back(added_.size());
    }

    /// Back to the first `count` faces.
    void truncate(std::size_t count) {
        if (count >= faces_.size()) return;
        const std::size_t keep = count == 0 ? 0 : filed_[count - 1];
        for (std::size_t a = added_.size(); a-- > keep;) cells_[added_[a]].pop_back();
        added_.resize(keep);
        filed_.resize(count);
        faces_.resize(count);
        seen_.resize(std::min(seen_.size(), count));
    }

    void clear() {
        faces_.clear();
        cells_.clear();
        added_.clear();
        filed_.clear();
        seen_.clear();
    }

    /// Whether the segment a–b passes through one of the faces from the `from`-th on (its ends
    /// touching one do not count). Looks in the buckets the segment meets (their cells grown as
    /// a face's), each face once, after the faces `recent` holds (which keeps the face found);
    /// `tests` counts the faces it tested.
    bool crosses(const Eigen::Vector3d& a, const Eigen::Vector3d& b, std::size_t from = 0, std::size_t* tests = nullptr,
                 Blockers* recent = nullptr) const {
        if (from >= faces_.size()) return false;
        if (++query_ == 0) {  // the stamps wrapped round: none counts as seen
            std::fill(seen_.begin(), seen_.end(), 0u);
            query_ = 1;
        }
        seen_.resize(faces_.size(), 0u);
        for (std::size_t r = 0; recent && r < recent->count; ++r) {
            const auto f = std::size_t(recent->face[r]);
            if (f < from || f >= faces_.size() || seen_[f] == query_) continue;
            seen_[f] = query_;
            if (tests) ++*tests;
            if (through(a, b, faces_[f])) {  // to the front
                std::rotate(recent->face.begin(), recent->face.begin() + std::ptrdiff_t(r), recent->face.begin() + std::ptrdiff_t(r) + 1);
                return true;
            }
        }
        const Eigen::Vector3d low = a.cwiseMin(b), high = a.cwiseMax(b), d = b - a;
        const double margin = 1e-3 * size_;
        for (long k = cell(low.z() - margin); k <= cell(high.z() + margin); ++k)
            for (long j = cell(low.y() - margin); j <= cell(high.y() + margin); ++j) {
                // The stretch of the segment in this row of cells (grown as a face's), then the
                // cells along x it passes.
                double enter = 0.0, leave = 1.0;
                if (!clip(a.y(), d.y(), double(j) * size_ - margin, double(j + 1) * size_ + margin, enter, leave) ||
                    !clip(a.z(), d.z(), double(k) * size_ - margin, double(k + 1) * size_ + margin, enter, leave))
                    continue;
                const double x0 = a.x() + enter * d.x(), x1 = a.x() + leave * d.x();
                for (long i = cell(std::min(x0, x1) - margin); i <= cell(std::max(x0, x1) + margin); ++i) {
                    const auto it = cells_.find(cell_key(i, j, k));
                    if (it == cells_.end()) continue;
                    const std::vector<std::int32_t>& list = it->second;
                    for (auto t = std::lower_bound(list.begin(), list.end(), std::int32_t(from)); t != list.end(); ++t) {
                        if (seen_[std::size_t(*t)] == query_) continue;
                        seen_[std::size_t(*t)] = query_;
                        if (tests) ++*tests;
                        if (through(a, b, faces_[std::size_t(*t)])) {
                            if (recent) recent->remember(*t);
                            return true;
                        }
                    }
                }
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
    double size_;
    std::vector<std::array<Eigen::Vector3d, 3>> faces_;
    std::unordered_map<std::int64_t, std::vector<std::int32_t>> cells_;
    std::vector<std::int64_t> added_;  ///< the bucket of each entry, in the order they were filed
    std::vector<std::size_t> filed_;   ///< per face: the entries filed up to and including its own
    mutable std::vector<std::uint32_t> seen_;  ///< per face: the last test that looked at it (crosses)
    mutable std::uint32_t query_ = 0;
};

/// The strip through a blade's (tip, end) pairs, one per pose in order: their points, and two
/// triangles between each pair and the next.
CutSurface strip_through(const std::vector<std::array<Eigen::Vector3d, 2>>& pairs) {
    CutSurface s;
    for (const auto& [tip, end] : pairs) s.points.push_back(tip), s.points.push_back(end);
    for (std::int32_t a = 0; a + 1 < std::int32_t(pairs.size()); ++a) {
        const std::int32_t b = a + 1;
        s.triangles.push_back({2 * a, 2 * a + 1, 2 * b + 1});
        s.triangles.push_back({2 * a, 2 * b + 1, 2 * b});
    }
    return s;
}

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
    // The particles within 12 cells of the blade's kept poses (the farthest to_rest looks), and
    // one cell more for rounding.
    Eigen::AlignedBox3d reached;
    for (std::size_t k : kept) {
        reached.extend(tip[k]);
        reached.extend(end[k]);
    }
    const PointBuckets buckets(now, h, reached.min().array() - 13 * h, reached.max().array() + 13 * h);
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
        std::vector<std::array<Eigen::Vector3d, 2>> pairs;
        for (std::size_t q = from; q <= to; ++q) pairs.push_back({to_rest(tip[kept[q]]), to_rest(end[kept[q]])});
        surfaces.push_back(strip_through(pairs));
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
    explicit Impl(const Lattice& lattice, const std::vector<Eigen::Vector3d>& rest) : embedder(lattice, rest), caps(lattice.spacing) {}
    mapping_internal::CellEmbedder embedder;
    CapIndex caps;
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
    impl_->caps.clear();
    settled_.clear();
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

namespace {

/// `strip` (stroke_surfaces: strip_through a (tip, end) pair per pose) with both its ends drawn
/// in `by` mm along the path of the blade's middle: the pairs passed dropped, the new end pair
/// between the two it falls between. None where the path is not longer than four times that.
std::optional<CutSurface> drawn_in(const CutSurface& strip, double by) {
    const std::size_t pairs = strip.points.size() / 2;
    if (pairs < 2 || strip.points.size() % 2 != 0) return std::nullopt;
    std::vector<std::array<Eigen::Vector3d, 2>> path(pairs);
    for (std::size_t k = 0; k < pairs; ++k) path[k] = {strip.points[2 * k], strip.points[2 * k + 1]};
    auto middle = [&](std::size_t k) { return 0.5 * (path[k][0] + path[k][1]); };
    double length = 0.0;
    for (std::size_t k = 1; k < pairs; ++k) length += (middle(k) - middle(k - 1)).norm();
    if (!(length > 4.0 * by)) return std::nullopt;
    // The pair `by` along the path from its front (the path as it is now).
    auto cut_front = [&]() {
        double left = by;
        std::size_t k = 0;
        while (k + 1 < path.size()) {
            const double step = (middle(k + 1) - middle(k)).norm();
            if (step > left) {
                const double f = left / step;
                for (int e = 0; e < 2; ++e) path[k][std::size_t(e)] += f * (path[k + 1][std::size_t(e)] - path[k][std::size_t(e)]);
                break;
            }
            left -= step;
            ++k;
        }
        path.erase(path.begin(), path.begin() + std::ptrdiff_t(k));
    };
    cut_front();
    std::reverse(path.begin(), path.end());
    cut_front();
    std::reverse(path.begin(), path.end());
    if (path.size() < 2) return std::nullopt;
    return strip_through(path);
}

}  // namespace

void IncisionState::apply(const BladeStroke& stroke, const std::vector<std::array<float, 3>>& positions, IncisionUpdate& update) {
    const double gap = 0.02 * lattice_.spacing;
    for (CutSurface surface : stroke_surfaces(stroke, positions, lattice_)) {
        IncisionResult result = open_along(mesh_, surface, gap);
        // Where the split does not close up (the strip meets the surface too intricately, often
        // along an edge or through a vertex), the strip moved a little along its normal meets it
        // elsewhere: 0.05, 0.1, 0.2 and 0.3 spacing each way are tried (within the cell the blade
        // cut the springs in); then, where it is the stroke's end that grazes the surface (a blade
        // lifted where the wall slopes steeply under it), the strip with both ends drawn in along
        // the stroke by 0.1, 0.2 and 0.3 spacing; then the mesh is left closed.
        if (!result.opened && result.failure.find("did not close up") != std::string::npos) {
            std::vector<CutSurface> tries;
            Eigen::Vector3d normal = Eigen::Vector3d::Zero();
            for (const auto& t : surface.triangles)
                normal += (surface.points[std::size_t(t[1])] - surface.points[std::size_t(t[0])])
                              .cross(surface.points[std::size_t(t[2])] - surface.points[std::size_t(t[0])]);
            if (normal.norm() > 0) {
                normal.normalize();
                for (const double move : {0.05, -0.05, 0.1, -0.1, 0.2, -0.2, 0.3, -0.3}) {
                    CutSurface& moved = tries.emplace_back(surface);
                    for (auto& p : moved.points) p += (move * lattice_.spacing) * normal;
                }
            }
            for (const double trim : {0.1, 0.2, 0.3})
                if (std::optional<CutSurface> shorter = drawn_in(surface, trim * lattice_.spacing)) tries.push_back(std::move(*shorter));
            for (CutSurface& moved : tries) {
                IncisionResult again = open_along(mesh_, moved, gap);
                if (!again.opened) continue;
                surface = std::move(moved);
                result = std::move(again);
                break;
            }
        }
        update.remeshed += result.patch_triangles;
        if (!result.failure.empty()) update.failures.push_back(result.failure);
        if (!result.opened) continue;
        // The whole strip parts the particles, as the physics cut parted them: also where it
        // passes between particles outside the detailed mesh (the lattice reaches up to half a
        // spacing beyond the surface).
        for (const auto& t : surface.triangles)
            impl_->caps.add({surface.points[std::size_t(t[0])], surface.points[std::size_t(t[1])], surface.points[std::size_t(t[2])]});
        update.cut_faces += surface.triangles.size();
        Eigen::AlignedBox3d region;
        for (const auto& p : surface.points) region.extend(p);
        region.min().array() -= 2 * lattice_.spacing;
        region.max().array() += 2 * lattice_.spacing;
        update.reembedded += reembed(result, region, update);
        update.opened = true;
    }
    ++update.strokes;
}

bool IncisionState::end_preview() {
    if (!committed_) return false;
    mesh_ = std::move(committed_->mesh);
    mapping_ = std::move(committed_->mapping);
    impl_->caps.truncate(committed_->cut_faces);
    settled_ = std::move(committed_->settled);
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
        update.remeshed += one.remeshed;
        update.cut_faces += one.cut_faces;
        update.carriers_tested += one.carriers_tested;
        update.face_tests += one.face_tests;
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
    committed_ = Committed{mesh_, mapping_, impl_->caps.size(), settled_};
    for (std::size_t r = 0; r < strokes.size(); ++r)
        if ((r >= applied_.size() || !applied_[r]) && !strokes[r].lifted && strokes[r].poses.size() >= 2) apply(strokes[r], positions, update);
    order_for_drawing();
    update.opened = true;
    update.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return update;
}

std::size_t IncisionState::reembed(const IncisionResult& result, const Eigen::AlignedBox3d& region, IncisionUpdate& update) {
    const CapIndex& caps = impl_->caps;
    const auto faces = std::uint32_t(caps.size());
    const std::size_t vertices = mesh_.rest.size();
    const std::size_t before = mapping_.offset.size();
    // Rows for the added vertices: the normal frame (triangle, λ) of an old vertex they share a
    // face with (it only turns the shading normal), carriers set below. An added vertex lies only
    // on the triangles the opening made (from result.triangles_from on).
    mapping_.triangle.resize(vertices, 0);
    mapping_.barycentric.resize(vertices, {1.0f, 0.0f, 0.0f});
    mapping_.offset.resize(vertices, 0.0f);
    mapping_.particles.resize(vertices, {});
    mapping_.weights.resize(vertices, {});
    settled_.resize(vertices);
    for (std::int32_t v : result.moved) settled_[std::size_t(v)] = {};
    std::vector<std::uint8_t> framed(vertices - before, 0);
    for (std::size_t t = result.triangles_from; t < mesh_.triangles.size(); ++t)
        for (std::int32_t v : mesh_.triangles[t]) {
            if (std::size_t(v) < before || framed[std::size_t(v) - before]) continue;
            for (std::int32_t w : mesh_.triangles[t])
                if (std::size_t(w) < before) {
                    mapping_.triangle[std::size_t(v)] = mapping_.triangle[std::size_t(w)];
                    mapping_.barycentric[std::size_t(v)] = mapping_.barycentric[std::size_t(w)];
                    framed[std::size_t(v) - before] = 1;
                    break;
                }
        }

    // Embedded again: the added vertices, the moved ones, and those near the cut whose carriers
    // reach across it. A vertex's carriers are tested against the faces cut since they were last
    // found clear of all (Settled::clear_of): the earlier ones they cross no more now than then.
    std::vector<std::uint8_t> again(vertices, 0);
    for (std::size_t v = before; v < vertices; ++v) again[v] = 1;
    for (std::int32_t v : result.moved) again[std::size_t(v)] = 1;
    for (std::size_t v = 0; v < before; ++v) {
        if (again[v] || !region.contains(mesh_.rest[v])) continue;
        for (int k = 0; k < 8 && !again[v]; ++k) {
            if (mapping_.weights[v][std::size_t(k)] == 0.0f) continue;
            ++update.carriers_tested;
            again[v] = caps.crosses(mesh_.rest[v], particle_rest_[std::size_t(mapping_.particles[v][std::size_t(k)])], settled_[v].clear_of,
                                    &update.face_tests);
        }
        if (!again[v]) settled_[v].clear_of = faces;
    }
    std::size_t count = 0;
    for (std::size_t v = 0; v < vertices; ++v) {
        if (!again[v]) continue;
        Settled& settled = settled_[v];
        if (settled.stranded) {  // a cut takes particles from its side, never gives: still none can carry it
            count += settled.stranded == 1;
            continue;
        }
        const Eigen::Vector3d& x = mesh_.rest[v];
        settled.clear_of = faces;  // embedded in particles on its own side: its carriers cross no cut
        CapIndex::Blockers blockers;
        mapping_internal::Embedding e =
            impl_->embedder.embed(x, [&](std::int32_t p) { return !caps.crosses(x, particle_rest_[std::size_t(p)], 0, nullptr, &blockers); });
        if (!e.found()) {  // no particle on its side nearby: the nearest any side, tested against every cut next time
            const bool stranded = e.far_found < 8;
            e = impl_->embedder.embed(x);
            settled.clear_of = 0;
            settled.stranded = !stranded ? 0 : e.found() ? 1 : 2;
        }
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
