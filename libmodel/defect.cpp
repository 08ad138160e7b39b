#include "libmodel/defect.h"

#include "libmodel/errors.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <limits>
#include <numbers>
#include <optional>
#include <unordered_set>

namespace heartsim {

namespace {

std::string mm(double value, int digits = 1) {
    char text[64];
    std::snprintf(text, sizeof text, "%.*f mm", digits, value);
    return text;
}

std::string point(const Eigen::Vector3d& p) {
    char text[96];
    std::snprintf(text, sizeof text, "%.1f,%.1f,%.1f", p.x(), p.y(), p.z());
    return text;
}

bool member(const std::vector<int>& labels, int label) { return std::find(labels.begin(), labels.end(), label) != labels.end(); }

/// The volume in its grid's own millimetres: g = diag(spacing)·ijk, world = origin + direction·g.
/// Distances and directions are measured here (the direction matrix is a rotation, or close to one).
class Grid {
public:
    explicit Grid(const LabelVolume& volume)
        : volume_(volume), geometry_(volume.geometry), spacing_(geometry_.spacing),
          to_grid_(geometry_.direction.inverse()) {}

    const VolumeGeometry& geometry() const { return geometry_; }
    Eigen::Vector3d to_grid(const Eigen::Vector3d& world) const { return to_grid_ * (world - geometry_.origin); }
    Eigen::Vector3d to_world(const Eigen::Vector3d& g) const { return geometry_.origin + geometry_.direction * g; }
    Eigen::Vector3d direction_to_world(const Eigen::Vector3d& n) const { return (geometry_.direction * n).normalized(); }
    double min_spacing() const { return spacing_.minCoeff(); }
    double max_spacing() const { return spacing_.maxCoeff(); }

    /// The voxel containing grid point g (nearest centre); false outside the volume.
    bool voxel(const Eigen::Vector3d& g, std::array<int, 3>& ijk) const {
        for (int a = 0; a < 3; ++a) {
            const double x = std::round(g[a] / spacing_[a]);
            if (!(x >= 0 && x < geometry_.dims[a])) return false;
            ijk[a] = int(x);
        }
        return true;
    }
    Eigen::Vector3d centre(int i, int j, int k) const { return Eigen::Vector3d(i, j, k).cwiseProduct(spacing_); }
    /// The label at grid point g; `outside` (below every label) outside the volume.
    static constexpr int outside = std::numeric_limits<int>::min();
    int label(const Eigen::Vector3d& g) const {
        std::array<int, 3> v;
        return voxel(g, v) ? volume_.labels[geometry_.linear(v[0], v[1], v[2])] : outside;
    }
    int label(int i, int j, int k) const { return volume_.labels[geometry_.linear(i, j, k)]; }

    /// The voxel index box holding every point within `radius` mm of g (clipped to the volume).
    void box(const Eigen::Vector3d& g, double radius, std::array<int, 3>& lo, std::array<int, 3>& hi) const {
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::max(0, int(std::floor((g[a] - radius) / spacing_[a])));
            hi[a] = std::min(geometry_.dims[a] - 1, int(std::ceil((g[a] + radius) / spacing_[a])));
        }
    }

private:
    const LabelVolume& volume_;
    const VolumeGeometry& geometry_;
    Eigen::Vector3d spacing_;
    Eigen::Matrix3d to_grid_;
};

std::string describe(int label, const SegmentNames& names) {
    if (label == Grid::outside) return "outside the volume";
    return "label " + describe_label(label, names);
}

/// The nearest voxel centre within `radius` of g whose label passes `wanted` and, when `away` is
/// non-zero, that lies on the far side of g from `away` ((c − g)·away < 0). False if none.
template <class Wanted>
bool nearest(const Grid& grid, const Eigen::Vector3d& g, double radius, Wanted wanted, const Eigen::Vector3d& away,
             Eigen::Vector3d& found) {
    std::array<int, 3> lo, hi;
    grid.box(g, radius, lo, hi);
    double best = radius * radius;
    bool any = false;
    for (int k = lo[2]; k <= hi[2]; ++k)
        for (int j = lo[1]; j <= hi[1]; ++j)
            for (int i = lo[0]; i <= hi[0]; ++i) {
                if (!wanted(grid.label(i, j, k))) continue;
                const Eigen::Vector3d c = grid.centre(i, j, k);
                const double d2 = (c - g).squaredNorm();
                if (d2 > best) continue;
                if (!away.isZero() && (c - g).dot(away) >= 0.0) continue;
                best = d2;
                found = c;
                any = true;
            }
    return any;
}

/// The wall crossed along a line: from a wall point the line leaves the wall at t_minus and
/// t_plus (mm along n from the start) into the labels there.
struct Crossing {
    double t_minus = 0.0, t_plus = 0.0;
    int label_minus = 0, label_plus = 0;
    double thickness() const { return t_plus - t_minus; }
};

/// Walks from wall point g along ±n in quarter-voxel steps until the line leaves the wall (at most
/// `limit` mm each way). False when it does not leave the wall within the limit. Where the wall
/// ends in unlabelled voxels (0) and a label of `blood` follows within `gap` mm, that label is
/// the one across (segmentations leave such seams between a wall and its pool).
bool cross_wall(const Grid& grid, const Eigen::Vector3d& g, const Eigen::Vector3d& n, const std::vector<int>& wall,
                double limit, Crossing& out, const std::vector<int>& blood = {}, double gap = 0.0) {
    const double h = 0.25 * grid.min_spacing();
    for (int side : {-1, +1}) {
        double t = 0.0;
        int label = grid.label(g);
        while (member(wall, label)) {
            t += h;
            if (t > limit) return false;
            label = grid.label(g + side * t * n);
        }
        const double boundary = t - 0.5 * h;
        if (label == 0 && gap > 0.0)
            for (double u = t + h; u <= t + gap; u += h) {
                const int next = grid.label(g + side * u * n);
                if (next == 0) continue;
                if (member(blood, next)) label = next;
                break;
            }
        if (side < 0) {
            out.t_minus = -boundary;
            out.label_minus = label;
        } else {
            out.t_plus = boundary;
            out.label_plus = label;
        }
    }
    return true;
}

/// Two unit vectors completing n to an orthonormal frame.
void frame(const Eigen::Vector3d& n, Eigen::Vector3d& u, Eigen::Vector3d& v) {
    const Eigen::Vector3d other = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    u = n.cross(other).normalized();
    v = n.cross(u);
}

/// A site on the wall: its mid-wall centre, axis (from side a to side b) and crossing there.
struct Site {
    Eigen::Vector3d centre;   ///< grid mm
    Eigen::Vector3d normal;   ///< grid frame, unit
    Crossing crossing;        ///< along normal from centre
};

class Carver {
public:
    Carver(const Grid& grid, const DefectOptions& options, const SegmentNames& names)
        : grid_(grid), o_(options), names_(names) {}

    bool is_wall(int label) const { return member(o_.wall_labels, label); }
    bool is_blood(int label) const { return member(o_.blood_labels, label); }
    bool sided() const { return o_.side_a != 0 && o_.side_b != 0; }
    std::string pools() const {
        return sided() ? describe(o_.side_a, names_) + " and " + describe(o_.side_b, names_) : std::string("two blood regions");
    }

    /// The site through the wall at grid point g (a wall voxel's centre): the axis from the
    /// nearest blood on one side to the nearest on the other, centred in the wall along it.
    /// Empty with `problem` set when the wall there is not between two pools.
    std::optional<Site> site_at(const Eigen::Vector3d& g, std::string& problem) const {
        const double reach = o_.max_wall_mm;
        Eigen::Vector3d a, b;
        if (sided()) {
            if (!nearest(grid_, g, reach, [&](int l) { return l == o_.side_a; }, Eigen::Vector3d::Zero(), a) ||
                !nearest(grid_, g, reach, [&](int l) { return l == o_.side_b; }, Eigen::Vector3d::Zero(), b)) {
                problem = "the wall there is not between " + pools() + " (one of them is farther than " + mm(reach, 0) + ")";
                return std::nullopt;
            }
        } else {
            if (!nearest(grid_, g, reach, [&](int l) { return is_blood(l); }, Eigen::Vector3d::Zero(), a) ||
                !nearest(grid_, g, reach, [&](int l) { return is_blood(l); }, a - g, b)) {
                problem = "the wall there is not between two blood regions (no blood within " + mm(reach, 0) + " on both sides)";
                return std::nullopt;
            }
        }
        Site site;
        site.normal = (b - a).normalized();
        if (!site.normal.allFinite()) {
            problem = "the blood on both sides of the wall is the same place";
            return std::nullopt;
        }
        Eigen::Vector3d start = g;
        // Three passes: each after the first re-aims the axis from the wall's middle.
        for (int pass = 0; pass < 3; ++pass) {
            Crossing c;
            if (!cross_wall(grid_, start, site.normal, o_.wall_labels, reach, c, o_.blood_labels, o_.gap_mm)) {
                problem = "the wall there is thicker than " + mm(reach, 0) + " along its normal: not a septum";
                return std::nullopt;
            }
            site.centre = start + 0.5 * (c.t_minus + c.t_plus) * site.normal;
            site.crossing = c;
            site.crossing.t_minus -= 0.5 * (c.t_minus + c.t_plus);
            site.crossing.t_plus -= 0.5 * (c.t_minus + c.t_plus);
            if (pass == 2) break;
            // The axis from the centroid of one side's blood to the other's, within a ball a little
            // wider than the wall: for a flat wall the two caps of blood are mirror images about
            // the normal, so voxel noise averages out (two nearest voxels alone tilt it by degrees).
            {
                const double reach_ball = 0.5 * c.thickness() + 2.0 * grid_.max_spacing();
                std::array<int, 3> lo, hi;
                grid_.box(site.centre, reach_ball, lo, hi);
                Eigen::Vector3d sum_a = Eigen::Vector3d::Zero(), sum_b = Eigen::Vector3d::Zero();
                double count_a = 0, count_b = 0;
                for (int k = lo[2]; k <= hi[2]; ++k)
                    for (int j = lo[1]; j <= hi[1]; ++j)
                        for (int i = lo[0]; i <= hi[0]; ++i) {
                            const int l = grid_.label(i, j, k);
                            const Eigen::Vector3d p = grid_.centre(i, j, k);
                            if ((p - site.centre).squaredNorm() > reach_ball * reach_ball) continue;
                            const bool minus = (p - site.centre).dot(site.normal) < 0.0;
                            if (minus && (sided() ? l == o_.side_a : is_blood(l))) sum_a += p, count_a += 1;
                            if (!minus && (sided() ? l == o_.side_b : is_blood(l))) sum_b += p, count_b += 1;
                        }
                if (count_a > 0 && count_b > 0) {
                    const Eigen::Vector3d n2 = (sum_b / count_b - sum_a / count_a).normalized();
                    if (n2.allFinite() && n2.dot(site.normal) > 0.5) site.normal = n2;
                }
            }
            start = site.centre;
            if (!is_wall(grid_.label(start))) break;
        }
        const Crossing& c = site.crossing;
        if (!is_blood(c.label_minus) || !is_blood(c.label_plus)) {
            const bool minus = !is_blood(c.label_minus);
            problem = "the wall there is not between two blood regions: across it, " +
                      describe(minus ? c.label_minus : c.label_plus, names_) + " lies " +
                      mm(minus ? -c.t_minus : c.t_plus) + " from its middle";
            return std::nullopt;
        }
        if (sided() && !((c.label_minus == o_.side_a && c.label_plus == o_.side_b))) {
            problem = "the wall there separates " + describe(c.label_minus, names_) + " from " + describe(c.label_plus, names_) +
                      ", not " + pools();
            return std::nullopt;
        }
        return site;
    }

    /// Whether every line along the axis at `radius` from it crosses the wall from the pool on
    /// one side to the pool on the other: the opening of that radius has wall all round it.
    bool rim_fits(const Site& site, double radius) const {
        Eigen::Vector3d u, v;
        frame(site.normal, u, v);
        const double h = 0.25 * grid_.min_spacing();
        const double window = 0.5 * site.crossing.thickness() + radius + 2.0 * grid_.max_spacing();
        constexpr int angles = 48;
        for (int a = 0; a < angles; ++a) {
            const double theta = 2.0 * std::numbers::pi * a / angles;
            const Eigen::Vector3d q = site.centre + radius * (std::cos(theta) * u + std::sin(theta) * v);
            // The wall point on this line nearest the centre's plane.
            double found = std::numeric_limits<double>::quiet_NaN();
            for (double t = 0.0; t <= window && std::isnan(found); t += h)
                for (double s : {t, -t})
                    if (is_wall(grid_.label(q + s * site.normal))) {
                        found = s;
                        break;
                    }
            if (std::isnan(found)) return false;
            Crossing c;
            if (!cross_wall(grid_, q + found * site.normal, site.normal, o_.wall_labels, window, c, o_.blood_labels, o_.gap_mm)) return false;
            if (c.label_minus != site.crossing.label_minus || c.label_plus != site.crossing.label_plus) return false;
        }
        return true;
    }

    /// The largest diameter whose rim fits at the site (0 if none), to a quarter voxel.
    double largest_fit(const Site& site) const {
        double lo = 0.0, hi = 0.5 * o_.diameter_mm + margin();
        if (!rim_fits(site, 0.5 * grid_.min_spacing())) return 0.0;
        while (hi - lo > 0.25 * grid_.min_spacing()) {
            const double mid = 0.5 * (lo + hi);
            (rim_fits(site, mid) ? lo : hi) = mid;
        }
        return std::max(0.0, 2.0 * (lo - margin()));
    }

    /// The rim of wall the opening must leave around it: one voxel.
    double margin() const { return grid_.max_spacing(); }


private:
    const Grid& grid_;
    const DefectOptions& o_;
    const SegmentNames& names_;
};

// --- Distances to the chambers' blood (automatic sites) -------------------------------------

/// Squared distances (mm²) from every voxel of a box to the nearest voxel where `feature` is set,
/// exact (Felzenszwalb & Huttenlocher's separable transform, with the grid's spacing).
class DistanceMap {
public:
    DistanceMap(const std::array<int, 3>& dims, const Eigen::Vector3d& spacing, const std::vector<std::uint8_t>& feature)
        : d_(feature.size()) {
        constexpr float inf = std::numeric_limits<float>::max() / 4;
        for (std::size_t i = 0; i < feature.size(); ++i) d_[i] = feature[i] ? 0.0f : inf;
        const std::size_t n = std::size_t(std::max({dims[0], dims[1], dims[2]}));
        std::vector<float> f(n), out(n), z(n + 1);
        std::vector<int> v(n);
        const std::array<std::size_t, 3> stride = {1, std::size_t(dims[0]), std::size_t(dims[0]) * std::size_t(dims[1])};
        for (int axis = 0; axis < 3; ++axis) {
            const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
            for (int p = 0; p < dims[a2]; ++p)
                for (int q = 0; q < dims[a1]; ++q) {
                    const std::size_t base = std::size_t(p) * stride[a2] + std::size_t(q) * stride[a1];
                    const int len = dims[axis];
                    for (int i = 0; i < len; ++i) f[std::size_t(i)] = d_[base + std::size_t(i) * stride[axis]];
                    line(f.data(), out.data(), len, float(spacing[axis]), v.data(), z.data());
                    for (int i = 0; i < len; ++i) d_[base + std::size_t(i) * stride[axis]] = out[std::size_t(i)];
                }
        }
    }
    float squared(std::size_t index) const { return d_[index]; }

private:
    /// One line: out(p) = min_q (s·(p − q))² + f(q), by the lower envelope of parabolas.
    static void line(const float* f, float* out, int n, float s, int* v, float* z) {
        constexpr float inf = std::numeric_limits<float>::max();
        int k = 0;
        v[0] = 0;
        z[0] = -inf;
        z[1] = inf;
        auto x = [s](int q) { return s * float(q); };
        for (int q = 1; q < n; ++q) {
            float cross;
            while (true) {
                const int r = v[k];
                cross = ((f[q] + x(q) * x(q)) - (f[r] + x(r) * x(r))) / (2.0f * (x(q) - x(r)));
                if (cross <= z[k] && k > 0) {
                    --k;
                    continue;
                }
                break;
            }
            if (cross <= z[k]) {  // k == 0: replace the first parabola
                v[0] = q;
                z[0] = -inf;
                z[1] = inf;
                continue;
            }
            ++k;
            v[k] = q;
            z[k] = cross;
            z[k + 1] = inf;
        }
        k = 0;
        for (int q = 0; q < n; ++q) {
            while (z[k + 1] < x(q)) ++k;
            const float d = x(q) - x(v[k]);
            out[q] = d * d + f[v[k]];
        }
    }

    std::vector<float> d_;
};

struct Candidate {
    Eigen::Vector3d g;       ///< grid mm
    double key = 0.0;        ///< order of preference (smaller first)
    double to_aorta = -1.0;  ///< mm
};

/// Places on the middle surface of the septum between side_a's and side_b's blood, in the order
/// the site prefers them.
std::vector<Candidate> septum_candidates(const LabelVolume& volume, const Grid& grid, const DefectOptions& o, DefectSite site,
                                         const SegmentNames& names) {
    const VolumeGeometry& geo = volume.geometry;
    // The box around both pools, widened by the thickest wall.
    std::array<int, 3> lo{geo.dims[0], geo.dims[1], geo.dims[2]}, hi{-1, -1, -1};
    std::size_t in_a = 0, in_b = 0;
    for (int k = 0; k < geo.dims[2]; ++k)
        for (int j = 0; j < geo.dims[1]; ++j)
            for (int i = 0; i < geo.dims[0]; ++i) {
                const int l = volume.labels[geo.linear(i, j, k)];
                if (l != o.side_a && l != o.side_b) continue;
                (l == o.side_a ? in_a : in_b) += 1;
                lo = {std::min(lo[0], i), std::min(lo[1], j), std::min(lo[2], k)};
                hi = {std::max(hi[0], i), std::max(hi[1], j), std::max(hi[2], k)};
            }
    if (in_a == 0 || in_b == 0)
        throw InputError("no voxel of " + describe(in_a == 0 ? o.side_a : o.side_b, names) +
                         ": the septum between the two pools cannot be found");
    for (int a = 0; a < 3; ++a) {
        const int widen = int(std::ceil(o.max_wall_mm / geo.spacing[a]));
        lo[a] = std::max(0, lo[a] - widen);
        hi[a] = std::min(geo.dims[a] - 1, hi[a] + widen);
    }
    const std::array<int, 3> dims{hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1};
    const std::size_t count = std::size_t(dims[0]) * std::size_t(dims[1]) * std::size_t(dims[2]);
    auto index = [&](int i, int j, int k) {
        return (std::size_t(k) * std::size_t(dims[1]) + std::size_t(j)) * std::size_t(dims[0]) + std::size_t(i);
    };
    auto distances = [&](int label) {
        std::vector<std::uint8_t> feature(count);
        for (int k = 0; k < dims[2]; ++k)
            for (int j = 0; j < dims[1]; ++j)
                for (int i = 0; i < dims[0]; ++i)
                    feature[index(i, j, k)] = volume.labels[geo.linear(lo[0] + i, lo[1] + j, lo[2] + k)] == label;
        return DistanceMap(dims, geo.spacing, feature);
    };
    const DistanceMap da = distances(o.side_a), db = distances(o.side_b);
    std::optional<DistanceMap> dao;
    const bool by_aorta = site == DefectSite::perimembranous || site == DefectSite::muscular || site == DefectSite::apical;
    if (by_aorta && o.aorta != 0) {
        // A distance to a label with no voxel in the box would be the transform's "infinity"
        // (about 9e18 mm), and every site the same place: an aorta named but absent is none.
        bool present = false;
        for (int k = 0; k < dims[2] && !present; ++k)
            for (int j = 0; j < dims[1] && !present; ++j)
                for (int i = 0; i < dims[0] && !present; ++i) present = volume.labels[geo.linear(lo[0] + i, lo[1] + j, lo[2] + k)] == o.aorta;
        if (!present)
            throw OptionError("the " + to_string(site) + " site is placed by its distance from the aorta's blood, and the volume has no voxel of " +
                              describe(o.aorta, names) + " within " + mm(o.max_wall_mm, 0) +
                              " of the ventricles; give {DefectOptions::at} X,Y,Z (LPS mm, a point in the septum)");
        dao.emplace(distances(o.aorta));
    }
    const double tolerance = geo.spacing.maxCoeff();
    std::vector<Candidate> out;
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                const int l = volume.labels[geo.linear(lo[0] + i, lo[1] + j, lo[2] + k)];
                if (!member(o.wall_labels, l)) continue;
                const std::size_t at = index(i, j, k);
                const double a = std::sqrt(double(da.squared(at))), b = std::sqrt(double(db.squared(at)));
                if (a + b > o.max_wall_mm || std::abs(a - b) > tolerance) continue;
                Candidate c;
                c.g = grid.centre(lo[0] + i, lo[1] + j, lo[2] + k);
                if (dao) c.to_aorta = std::sqrt(double(dao->squared(at)));
                out.push_back(c);
            }
    if (out.empty())
        throw InputError("no septum between " + describe(o.side_a, names) + " and " + describe(o.side_b, names) +
                         ": no wall of " + std::to_string(o.wall_labels.empty() ? 0 : o.wall_labels.front()) +
                         " lies between them at most " + mm(o.max_wall_mm, 0) + " thick");
    if (site == DefectSite::secundum) {
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (const Candidate& c : out) mean += c.g;
        mean /= double(out.size());
        for (Candidate& c : out) c.key = (c.g - mean).norm();
    } else {
        if (!dao)
            throw OptionError("the " + to_string(site) + " site is placed by its distance from the aorta, and the volume's labels name no aorta; "
                              "give {DefectOptions::at}");
        double near = std::numeric_limits<double>::max(), far = 0.0;
        for (const Candidate& c : out) near = std::min(near, c.to_aorta), far = std::max(far, c.to_aorta);
        for (Candidate& c : out)
            c.key = site == DefectSite::perimembranous ? c.to_aorta
                    : site == DefectSite::apical       ? -c.to_aorta
                                                       : std::abs(c.to_aorta - 0.5 * (near + far));
    }
    std::stable_sort(out.begin(), out.end(), [](const Candidate& x, const Candidate& y) { return x.key < y.key; });
    return out;
}

/// Carves the opening at `s` (carve_defect's last step), measures it and floods through it;
/// keeps it and fills `report` when its passage is clear and it joins the pools, else restores
/// every voxel and returns false (report's measures say why).
/// Whether c lies in site s's cylinder: within `r` of its axis and `w` of its middle along it.
bool in_cylinder(const Site& s, const Eigen::Vector3d& c, double r, double w) {
    const Eigen::Vector3d rel = c - s.centre;
    const double t = rel.dot(s.normal);
    return std::abs(t) <= w && (rel - t * s.normal).squaredNorm() <= r * r;
}

/// An unlabelled seam between the wall and a pool (DefectOptions::gap_mm) opens with the wall:
/// a 0 voxel with the pool within the gap along the axis.
bool on_seam(const Grid& grid, const Site& s, double gap_mm, const Eigen::Vector3d& c) {
    const double h = 0.25 * grid.min_spacing();
    for (double u = h; u <= gap_mm + h; u += h)
        for (double side : {-1.0, 1.0}) {
            const int l = grid.label(c + side * u * s.normal);
            if (l == s.crossing.label_minus || l == s.crossing.label_plus) return true;
        }
    return false;
}

/// The wall voxel the carving starts from: the one at the site's centre, or, where the middle of
/// a wall one voxel thick falls between voxel centres, the wall voxel nearest it. False if none.
bool carving_seed(const Grid& grid, const Carver& carver, const Site& s, std::array<int, 3>& seed) {
    if (grid.voxel(s.centre, seed) && carver.is_wall(grid.label(seed[0], seed[1], seed[2]))) return true;
    Eigen::Vector3d w;
    return nearest(grid, s.centre, grid.max_spacing() * 2, [&](int l) { return carver.is_wall(l); }, Eigen::Vector3d::Zero(), w) &&
           grid.voxel(w, seed);
}

/// The voxels one carving may touch (within the box [lo, hi]) and the cylinder's half length.
struct CarvingBounds {
    std::array<int, 3> lo, hi;
    double window = 0.0;
};

/// Carves the wall voxels whose centres lie within r of the axis, connected to `seed` (each into
/// the pool on its side; a seam voxel too), and returns them with their labels before.
std::vector<std::pair<std::size_t, std::int32_t>> carve_cylinder(LabelVolume& volume, const Grid& grid, const Carver& carver,
                                                                 const DefectOptions& o, const Site& s, const std::array<int, 3>& seed,
                                                                 const CarvingBounds& bounds, double r) {
    const VolumeGeometry& geo = volume.geometry;
    // Named references, not a structured binding: a lambda below uses the window (clang 14 does
    // not capture structured bindings).
    const std::array<int, 3>& lo = bounds.lo;
    const std::array<int, 3>& hi = bounds.hi;
    const double window = bounds.window;
    std::unordered_set<std::size_t> seen;
    std::deque<std::array<int, 3>> queue;
    queue.push_back(seed);
    seen.insert(geo.linear(seed[0], seed[1], seed[2]));
    std::vector<std::array<int, 3>> carved;
    while (!queue.empty()) {
        const auto v = queue.front();
        queue.pop_front();
        carved.push_back(v);
        for (int dk = -1; dk <= 1; ++dk)
            for (int dj = -1; dj <= 1; ++dj)
                for (int di = -1; di <= 1; ++di) {
                    const int i = v[0] + di, j = v[1] + dj, k = v[2] + dk;
                    if (i < lo[0] || j < lo[1] || k < lo[2] || i > hi[0] || j > hi[1] || k > hi[2]) continue;
                    const std::size_t at = geo.linear(i, j, k);
                    if (seen.count(at) || !in_cylinder(s, grid.centre(i, j, k), r, window)) continue;
                    if (!carver.is_wall(volume.labels[at]) && !(volume.labels[at] == 0 && on_seam(grid, s, o.gap_mm, grid.centre(i, j, k))))
                        continue;
                    seen.insert(at);
                    queue.push_back({i, j, k});
                }
    }
    // The seed itself may lie just outside a small cylinder: keep only voxels inside it.
    carved.erase(std::remove_if(carved.begin(), carved.end(),
                                [&](const auto& v) { return !in_cylinder(s, grid.centre(v[0], v[1], v[2]), r, window); }),
                 carved.end());
    std::vector<std::pair<std::size_t, std::int32_t>> changed;
    for (const auto& v : carved) changed.emplace_back(geo.linear(v[0], v[1], v[2]), volume.labels[geo.linear(v[0], v[1], v[2])]);
    for (const auto& v : carved) {
        const double t = (grid.centre(v[0], v[1], v[2]) - s.centre).dot(s.normal);
        volume.labels[geo.linear(v[0], v[1], v[2])] = t < 0.0 ? s.crossing.label_minus : s.crossing.label_plus;
    }
    return changed;
}

/// The opening's diameter: that of a disc with the area across the axis of the lines parallel to
/// it, a quarter voxel apart, that cross the wall's slab (along the axis from slab_lo to slab_hi)
/// without meeting wall, connected to the axis.
double passage_diameter(const Grid& grid, const Carver& carver, const Site& s, double radius, double slab_lo, double slab_hi) {
    Eigen::Vector3d u, v;
    frame(s.normal, u, v);
    const double h = 0.25 * grid.min_spacing();
    const double extent = radius + 3.0 * grid.max_spacing();
    const int n = int(std::ceil(extent / h));
    const int side = 2 * n + 1;
    std::vector<std::uint8_t> open(std::size_t(side) * std::size_t(side)), reached(open.size());
    for (int b = -n; b <= n; ++b)
        for (int a = -n; a <= n; ++a) {
            if (a * a + b * b > n * n) continue;
            const Eigen::Vector3d q = s.centre + h * (a * u + b * v);
            bool clear = true;
            for (double t = slab_lo; t <= slab_hi && clear; t += h) clear = !carver.is_wall(grid.label(q + t * s.normal));
            open[std::size_t(b + n) * std::size_t(side) + std::size_t(a + n)] = clear;
        }
    std::size_t area = 0;
    const std::size_t centre = std::size_t(n) * std::size_t(side) + std::size_t(n);
    if (open[centre]) {
        std::vector<std::size_t> stack{centre};
        reached[centre] = 1;
        while (!stack.empty()) {
            const std::size_t at = stack.back();
            stack.pop_back();
            ++area;
            const int a = int(at % std::size_t(side)), b = int(at / std::size_t(side));
            const std::array<std::array<int, 2>, 4> steps{{{1, 0}, {-1, 0}, {0, 1}, {0, -1}}};
            for (const auto& d : steps) {
                const int a2 = a + d[0], b2 = b + d[1];
                if (a2 < 0 || b2 < 0 || a2 >= side || b2 >= side) continue;
                const std::size_t next = std::size_t(b2) * std::size_t(side) + std::size_t(a2);
                if (!open[next] || reached[next]) continue;
                reached[next] = 1;
                stack.push_back(next);
            }
        }
    }
    return 2.0 * std::sqrt(double(area) * h * h / std::numbers::pi);
}

/// Whether the two pools (labels a and b) connect through the opening: a flood fill through
/// blood, within the cylinder of radius r and half length w, from a voxel a step beyond the
/// wall's face on one side to one on the other; nullopt where either of those is not blood.
std::optional<bool> pools_connected(const LabelVolume& volume, const Grid& grid, const Site& s, int label_a, int label_b, double r, double w) {
    const VolumeGeometry& geo = volume.geometry;
    auto blood = [&](int l) { return l == label_a || l == label_b; };
    std::array<int, 3> from, to;
    const double step = grid.max_spacing();
    bool ends = grid.voxel(s.centre + (s.crossing.t_minus - step) * s.normal, from) && grid.voxel(s.centre + (s.crossing.t_plus + step) * s.normal, to);
    ends = ends && blood(grid.label(from[0], from[1], from[2])) && blood(grid.label(to[0], to[1], to[2]));
    if (!ends) return std::nullopt;
    std::unordered_set<std::size_t> reached{geo.linear(from[0], from[1], from[2])};
    std::deque<std::array<int, 3>> q{from};
    const std::size_t target = geo.linear(to[0], to[1], to[2]);
    constexpr std::array<std::array<int, 3>, 6> steps{{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}}};
    while (!q.empty() && !reached.count(target)) {
        const auto v = q.front();
        q.pop_front();
        for (const auto& d : steps) {
            const int i = v[0] + d[0], j = v[1] + d[1], k = v[2] + d[2];
            if (!geo.contains(i, j, k)) continue;
            const std::size_t at = geo.linear(i, j, k);
            if (reached.count(at) || !blood(volume.labels[at]) || !in_cylinder(s, grid.centre(i, j, k), r, w)) continue;
            reached.insert(at);
            q.push_back({i, j, k});
        }
    }
    return reached.count(target) != 0;
}

bool open_site(LabelVolume& volume, const Grid& grid, const Carver& carver, const DefectOptions& o, const Site& s,
               DefectReport& report) {
    const double radius = 0.5 * o.diameter_mm;
    CarvingBounds bounds;
    bounds.window = 0.5 * s.crossing.thickness() + radius + 2.0 * grid.max_spacing();
    grid.box(s.centre, std::hypot(bounds.window, radius) + grid.max_spacing(), bounds.lo, bounds.hi);
    std::array<int, 3> seed;
    if (!carving_seed(grid, carver, s, seed)) return false;
    // Only the wall's own slab counts for the passage (as thick as at the centre, plus a voxel and
    // a little for a curved wall each way): another wall across a pool beyond it does not close
    // the opening.
    const double slab_lo = s.crossing.t_minus - grid.max_spacing() - 0.25 * radius;
    const double slab_hi = s.crossing.t_plus + grid.max_spacing() + 0.25 * radius;
    // Voxels are carved whole: the clear passage of a cylinder of voxel centres is up to half a
    // voxel narrower than the cylinder. The smallest cylinder (in quarter-voxel steps, at most a
    // voxel wider) whose passage reaches the diameter asked is kept.
    std::vector<std::pair<std::size_t, std::int32_t>> carved;
    for (double r = radius;; r += 0.25 * grid.min_spacing()) {
        for (const auto& [at, label] : carved) volume.labels[at] = label;
        carved = carve_cylinder(volume, grid, carver, o, s, seed, bounds, r);
        report.measured_diameter_mm = passage_diameter(grid, carver, s, radius, slab_lo, slab_hi);
        if (report.measured_diameter_mm >= o.diameter_mm || r >= radius + grid.max_spacing()) break;
    }
    report.voxels_carved = carved.size();
    report.label_a = s.crossing.label_minus;
    report.label_b = s.crossing.label_plus;
    report.centre = grid.to_world(s.centre);
    report.normal = grid.direction_to_world(s.normal);
    report.wall_thickness_mm = s.crossing.thickness();
    // (Where the fill has no ends, report.connected stays as it was.)
    if (const std::optional<bool> connected = pools_connected(volume, grid, s, report.label_a, report.label_b,
                                                              radius + 2.0 * grid.max_spacing(), bounds.window + 2.0 * grid.max_spacing()))
        report.connected = *connected;

    // Open only if clear (a passage within a voxel of the diameter: no other wall across it) and
    // joining the pools; else every voxel back as it was.
    if (report.measured_diameter_mm >= o.diameter_mm - grid.max_spacing() && report.connected) return true;
    for (const auto& [at, label] : carved) volume.labels[at] = label;
    report.voxels_carved = 0;
    return false;
}

}  // namespace

DefectType parse_defect_type(const std::string& text) {
    if (text == "vsd") return DefectType::vsd;
    if (text == "asd") return DefectType::asd;
    throw OptionError("{DefectOptions::type} must be vsd (ventricular septal defect) or asd (atrial septal defect), got '" + text + "'");
}

DefectSite parse_defect_site(const std::string& text) {
    for (DefectSite s : {DefectSite::perimembranous, DefectSite::muscular, DefectSite::apical, DefectSite::secundum})
        if (text == to_string(s)) return s;
    throw OptionError("{DefectOptions::site} must be perimembranous, muscular or apical (vsd) or secundum (asd), got '" + text + "'");
}

std::string to_string(DefectType type) { return type == DefectType::vsd ? "vsd" : "asd"; }

std::string to_string(DefectSite site) {
    switch (site) {
    case DefectSite::perimembranous: return "perimembranous";
    case DefectSite::muscular: return "muscular";
    case DefectSite::apical: return "apical";
    case DefectSite::secundum: return "secundum";
    }
    return "?";
}

DefectSite default_defect_site(DefectType type) { return type == DefectType::vsd ? DefectSite::perimembranous : DefectSite::secundum; }

DefectReport carve_defect(LabelVolume& volume, const DefectOptions& o, const SegmentNames& names, Progress& progress) {
    const auto start = std::chrono::steady_clock::now();
    if (!(o.diameter_mm > 0.0) || !std::isfinite(o.diameter_mm))
        throw OptionError("{DefectOptions::diameter_mm} must be a positive number of mm");
    if (o.wall_labels.empty()) throw OptionError("no wall labels: {SelectionOptions::tissue_labels} names the septum's labels");
    if (o.blood_labels.empty()) throw OptionError("no blood labels: {SelectionOptions::cavity_labels} names the pools the defect joins");
    const Grid grid(volume);
    Carver carver(grid, o, names);
    DefectReport report;
    report.type = o.type;
    report.diameter_mm = o.diameter_mm;

    std::optional<Site> site;
    if (o.at) {
        ProgressStage stage(progress, "find the septum", 0);
        const Eigen::Vector3d g = grid.to_grid(*o.at);
        Eigen::Vector3d wall_point = g;
        const int here = grid.label(g);
        if (!carver.is_wall(here)) {
            if (!nearest(grid, g, o.search_mm, [&](int l) { return carver.is_wall(l); }, Eigen::Vector3d::Zero(), wall_point))
                throw InputError("no septum at " + point(*o.at) + " (LPS mm): the voxel there is " + describe(here, names) +
                                 " and no wall (" + describe(o.wall_labels.front(), names) + ") lies within " + mm(o.search_mm, 0));
        }
        std::string problem;
        site = carver.site_at(wall_point, problem);
        if (!site) throw InputError("no septum at " + point(*o.at) + " (LPS mm): " + problem);
        if (!carver.rim_fits(*site, 0.5 * o.diameter_mm + carver.margin())) {
            const double fits = carver.largest_fit(*site);
            throw InputError("a " + mm(o.diameter_mm) + " opening does not fit the septum at " + point(*o.at) +
                             " (LPS mm): the wall around it must separate " + carver.pools() + " all round the opening with a rim of " +
                             mm(carver.margin()) + "; " +
                             (fits > 0.0 ? "at most " + mm(fits) + " fits there" : "no opening fits there"));
        }
        ProgressStage carving(progress, "carve the defect", 0);
        if (!open_site(volume, grid, carver, o, *site, report))
            throw InputError("the opening at " + point(*o.at) + " (LPS mm) is not clear: " +
                             (report.connected ? "its passage through the wall measures " + mm(report.measured_diameter_mm) +
                                                     " across (another wall crosses it)"
                                               : std::string("it does not join the two pools")) +
                             "; try another point");
    } else {
        if (o.side_a == 0 || o.side_b == 0)
            throw OptionError("the chambers are not labelled apart, so the septum cannot be found without a point: give "
                              "{DefectOptions::at} X,Y,Z (LPS mm, a point in the septum)");
        const DefectSite wanted = o.site.value_or(default_defect_site(o.type));
        if ((o.type == DefectType::vsd) == (wanted == DefectSite::secundum))
            throw OptionError("the " + to_string(wanted) + " site is not a site of a" + (o.type == DefectType::vsd ? " ventricular" : "n atrial") +
                              " septal defect (vsd: perimembranous, muscular, apical; asd: secundum)");
        std::vector<Candidate> candidates;
        {
            ProgressStage stage(progress, "find the septum", 0);
            candidates = septum_candidates(volume, grid, o, wanted, names);
        }
        ProgressStage stage(progress, "place the defect", candidates.size());
        std::vector<Eigen::Vector3d> tried;
        double best_fit = 0.0;
        const double spread = std::max(2.0, 0.25 * o.diameter_mm);  // tried places this far apart
        constexpr std::size_t most = 400;
        for (std::size_t c = 0; c < candidates.size() && tried.size() < most; ++c) {
            stage.update(c);
            const Candidate& candidate = candidates[c];
            if (std::any_of(tried.begin(), tried.end(), [&](const Eigen::Vector3d& t) { return (t - candidate.g).norm() < spread; }))
                continue;
            tried.push_back(candidate.g);
            std::string problem;
            std::optional<Site> s = carver.site_at(candidate.g, problem);
            if (!s) continue;
            if (!carver.rim_fits(*s, 0.5 * o.diameter_mm + carver.margin())) {
                best_fit = std::max(best_fit, carver.largest_fit(*s));
                continue;
            }
            if (!open_site(volume, grid, carver, o, *s, report)) continue;
            site = s;
            report.site = wanted;
            report.distance_to_aorta_mm = candidate.to_aorta;
            break;
        }
        report.sites_tried = tried.size();
        if (!site)
            throw InputError("no place on the septum between " + carver.pools() + " fits a " + mm(o.diameter_mm) + " opening (" +
                             std::to_string(tried.size()) + " places tried" +
                             (best_fit > 0.0 ? "; the largest that fits is " + mm(best_fit) : std::string()) + ")");
    }

    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return report;
}

}  // namespace heartsim
