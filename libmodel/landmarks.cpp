#include "libmodel/landmarks.h"

#include "libmodel/errors.h"
#include "libmodel/text.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <numeric>
#include <optional>
#include <unordered_map>

namespace heartsim {

namespace {

constexpr float far_away = std::numeric_limits<float>::infinity();

const char* const interventricular_anterior = "interventricular_anterior_groove";
const char* const interventricular_posterior = "interventricular_posterior_groove";
const char* const right_av_groove = "right_av_groove";
const char* const left_av_groove = "left_av_groove";
const char* const lad_course = "lad_course";
const char* const rca_course = "rca_course";
const char* const lcx_course = "lcx_course";
const char* const tricuspid_ring = "tricuspid_ring";
const char* const mitral_ring = "mitral_ring";
const char* const aortic_ring = "aortic_ring";
const char* const pulmonary_ring = "pulmonary_ring";

/// A distance map on a part of the label map's grid, sampled at world points.
struct Field {
    VolumeGeometry geometry;
    Eigen::Matrix3d to_index;
    std::vector<float> distance;

    double at(const Eigen::Vector3d& world) const {
        const Eigen::Vector3d ijk = to_index * (world - geometry.origin);
        std::array<int, 3> base{};
        std::array<double, 3> t{};
        for (int a = 0; a < 3; ++a) {
            if (!(ijk[a] >= -0.5 && ijk[a] <= geometry.dims[std::size_t(a)] - 0.5)) return far_away;
            const int last = std::max(geometry.dims[std::size_t(a)] - 2, 0);
            base[std::size_t(a)] = std::clamp(int(std::floor(ijk[a])), 0, last);
            t[std::size_t(a)] = std::clamp(ijk[a] - base[std::size_t(a)], 0.0, 1.0);
        }
        double sum = 0.0;
        for (int corner = 0; corner < 8; ++corner) {
            double weight = 1.0;
            std::array<int, 3> c{};
            for (int a = 0; a < 3; ++a) {
                const int bit = (corner >> a) & 1;
                c[std::size_t(a)] = std::min(base[std::size_t(a)] + bit, geometry.dims[std::size_t(a)] - 1);
                weight *= bit ? t[std::size_t(a)] : 1.0 - t[std::size_t(a)];
            }
            if (weight == 0.0) continue;
            sum += weight * double(distance[geometry.linear(c[0], c[1], c[2])]);
        }
        return sum;
    }
};

/// The vertices of a mesh in buckets, for the nearest vertex to a point.
class VertexGrid {
public:
    VertexGrid(const std::vector<Eigen::Vector3d>& points, double cell) : points_(points), cell_(cell) {
        for (std::size_t i = 0; i < points.size(); ++i) buckets_[key(cell_of(points[i]))].push_back(int(i));
    }
    /// The nearest vertex within `reach` mm, or −1; `distance` receives its distance.
    int nearest(const Eigen::Vector3d& p, double reach, double* distance) const {
        const auto c = cell_of(p);
        const int rings = int(std::ceil(reach / cell_));
        int best = -1;
        double best_d2 = reach * reach;
        for (int dz = -rings; dz <= rings; ++dz)
            for (int dy = -rings; dy <= rings; ++dy)
                for (int dx = -rings; dx <= rings; ++dx) {
                    const auto found = buckets_.find(key({c[0] + dx, c[1] + dy, c[2] + dz}));
                    if (found == buckets_.end()) continue;
                    for (int i : found->second) {
                        const double d2 = (points_[std::size_t(i)] - p).squaredNorm();
                        if (d2 <= best_d2) best_d2 = d2, best = i;
                    }
                }
        if (distance) *distance = std::sqrt(best_d2);
        return best;
    }
private:
    std::array<long, 3> cell_of(const Eigen::Vector3d& p) const {
        return {long(std::floor(p.x() / cell_)), long(std::floor(p.y() / cell_)), long(std::floor(p.z() / cell_))};
    }
    static std::uint64_t key(const std::array<long, 3>& c) {
        return (std::uint64_t(c[0] & 0x1fffff) << 42) | (std::uint64_t(c[1] & 0x1fffff) << 21) | std::uint64_t(c[2] & 0x1fffff);
    }
    const std::vector<Eigen::Vector3d>& points_;
    double cell_;
    std::unordered_map<std::uint64_t, std::vector<int>> buckets_;
};

/// Centroid and second moments of one label's voxel centres.
struct LabelMoments {
    std::size_t count = 0;
    Eigen::Vector3d sum{0, 0, 0};
    Eigen::Matrix3d outer = Eigen::Matrix3d::Zero();
    Eigen::Vector3d centroid() const { return count ? Eigen::Vector3d(sum / double(count)) : Eigen::Vector3d::Zero(); }
    Eigen::Matrix3d covariance() const {
        if (!count) return Eigen::Matrix3d::Zero();
        const Eigen::Vector3d c = centroid();
        return outer / double(count) - c * c.transpose();
    }
};

/// A valve's orifice as the label map has it: centre, unit normal from the first blood to the second.
struct Plane {
    Eigen::Vector3d centre{0, 0, 0}, normal{0, 0, 1};
    double radius = 0.0;  ///< the rim's mean radius
};

/// What a ring's orifice is: where two bloods touch.
struct Contact {
    std::vector<Eigen::Vector3d> centres;  ///< voxel-face centres, world
    std::vector<double> areas;             ///< mm²
    Eigen::Vector3d a_to_b{0, 0, 0};       ///< Σ area · unit direction from the first blood to the second
};

/// Plain-words name of a chamber label slot, for reasons.
struct Chamber {
    int label = 0;
    const char* name = "";
};

class Finder {
public:
    Finder(const LabelVolume& volume, const ChamberLabels& chambers, const TriangleMesh& surface, const LandmarkOptions& options,
           std::string unlabelled_reason)
        : volume_(volume), chambers_(chambers), surface_(surface), options_(options), unlabelled_(std::move(unlabelled_reason)),
          grid_(surface_.positions, std::max(options.max_surface_distance_mm, 1.0)) {
        if (surface_.normals.size() != surface_.positions.size()) compute_vertex_normals(surface_);
        const auto& g = volume_.geometry;
        to_index_ = (g.direction * g.spacing.asDiagonal()).inverse();
        measure_labels();
    }

    Landmarks run() {
        const Chamber la{chambers_.left_atrium, "left atrium"}, lv{chambers_.left_ventricle, "left ventricle"},
            ra{chambers_.right_atrium, "right atrium"}, rv{chambers_.right_ventricle, "right ventricle"},
            ao{chambers_.aorta, "aorta"}, pa{chambers_.pulmonary_artery, "pulmonary artery"};
        // The rings first: the atrioventricular grooves lie about their planes.
        const std::optional<Plane> tricuspid = add_ring(tricuspid_ring, ra, rv), mitral = add_ring(mitral_ring, la, lv),
                                   aortic = add_ring(aortic_ring, lv, ao);
        add_ring(pulmonary_ring, rv, pa);
        // The grooves and the courses along them.
        std::vector<int> anterior, posterior, right_av, left_av;
        std::string interventricular_problem = problem({lv, rv}), right_problem = problem({ra, rv}), left_problem = problem({la, lv});
        if (interventricular_problem.empty()) {
            const std::vector<int> both = groove_vertices(lv, rv, std::nullopt);
            split_interventricular(both, anterior, posterior);
            if (both.empty()) interventricular_problem = no_groove(lv, rv, false);
        }
        if (right_problem.empty() && (right_av = groove_vertices(ra, rv, tricuspid)).empty()) right_problem = no_groove(ra, rv, bool(tricuspid));
        if (left_problem.empty() && (left_av = groove_vertices(la, lv, mitral)).empty()) left_problem = no_groove(la, lv, bool(mitral));
        add_groove(interventricular_anterior, lv, rv, anterior,
                   !interventricular_problem.empty() ? interventricular_problem
                   : anterior.empty() ? "no groove vertex lies anterior to the septum" : "");
        add_groove(interventricular_posterior, lv, rv, posterior,
                   !interventricular_problem.empty() ? interventricular_problem
                   : posterior.empty() ? "no groove vertex lies posterior to the septum" : "");
        add_groove(right_av_groove, ra, rv, right_av, right_problem);
        add_groove(left_av_groove, la, lv, left_av, left_problem);

        add_lad(lv, rv, anterior, interventricular_problem);
        // The crux, where the posterior interventricular groove meets the atrioventricular grooves:
        // its most basal step.
        std::optional<Eigen::Vector3d> crux;
        if (!posterior.empty()) {
            const Eigen::Vector3d axis = long_axis(), origin = moments(chambers_.left_ventricle).centroid();
            double base = std::numeric_limits<double>::infinity();
            for (int v : posterior) base = std::min(base, (surface_.positions[std::size_t(v)] - origin).dot(axis));
            Eigen::Vector3d sum{0, 0, 0};
            std::size_t count = 0;
            for (int v : posterior)
                if ((surface_.positions[std::size_t(v)] - origin).dot(axis) <= base + options_.course_step_mm)
                    sum += surface_.positions[std::size_t(v)], ++count;
            crux = sum / double(count);
        }
        std::optional<Eigen::Vector3d> root;
        if (aortic) root = aortic->centre;
        else if (moments(ao.label).count) root = moments(ao.label).centroid();
        add_av_course(rca_course, ra, rv, right_av, right_problem, tricuspid, crux, root);
        add_av_course(lcx_course, la, lv, left_av, left_problem, mitral, crux, root);

        // In the documented order.
        Landmarks ordered;
        for (const std::string& name : landmark_names()) {
            for (auto& l : result_.found)
                if (l.name == name) ordered.found.push_back(std::move(l));
            for (auto& m : result_.missing)
                if (m.name == name) ordered.missing.push_back(std::move(m));
        }
        return ordered;
    }

private:
    // ---- the label map ------------------------------------------------------------------------

    void measure_labels() {
        const auto& g = volume_.geometry;
        const std::array<int, 6> wanted = {chambers_.left_atrium,     chambers_.left_ventricle, chambers_.right_atrium,
                                           chambers_.right_ventricle, chambers_.aorta,          chambers_.pulmonary_artery};
        for (int label : wanted)
            if (label != 0) moments_[label];
        low_ = {g.dims[0], g.dims[1], g.dims[2]};
        high_ = {-1, -1, -1};
        for (int k = 0; k < g.dims[2]; ++k)
            for (int j = 0; j < g.dims[1]; ++j)
                for (int i = 0; i < g.dims[0]; ++i) {
                    const int label = volume_.labels[g.linear(i, j, k)];
                    if (label == 0) continue;
                    const auto found = moments_.find(label);
                    if (found == moments_.end()) continue;
                    LabelMoments& m = found->second;
                    const Eigen::Vector3d x = g.to_world(Eigen::Vector3d(i, j, k));
                    ++m.count;
                    m.sum += x;
                    m.outer += x * x.transpose();
                    low_ = {std::min(low_[0], i), std::min(low_[1], j), std::min(low_[2], k)};
                    high_ = {std::max(high_[0], i), std::max(high_[1], j), std::max(high_[2], k)};
                }
        // Distances are wanted up to the groove's reach beyond the chambers, and the surface lies
        // a wall's thickness out: a margin of the reach and a few voxels.
        for (int a = 0; a < 3; ++a) {
            const int margin = int(std::ceil((options_.groove_reach_mm + 3.0) / g.spacing[a])) + 2;
            low_[std::size_t(a)] = std::max(0, low_[std::size_t(a)] - margin);
            high_[std::size_t(a)] = std::min(g.dims[std::size_t(a)] - 1, high_[std::size_t(a)] + margin);
        }
    }

    const LabelMoments& moments(int label) const {
        static const LabelMoments none;
        const auto found = moments_.find(label);
        return found == moments_.end() ? none : found->second;
    }

    int label_at(const Eigen::Vector3d& world) const {
        const auto& g = volume_.geometry;
        const Eigen::Vector3d ijk = to_index_ * (world - g.origin);
        const int i = int(std::lround(ijk.x())), j = int(std::lround(ijk.y())), k = int(std::lround(ijk.z()));
        return g.contains(i, j, k) ? volume_.labels[g.linear(i, j, k)] : 0;
    }

    bool is_blood(int label) const { return label != 0 && moments_.count(label) > 0; }

    /// The distance map of one chamber's blood over the chambers' box, made once.
    const Field& field(int label) {
        auto found = fields_.find(label);
        if (found != fields_.end()) return found->second;
        const auto& g = volume_.geometry;
        Field f;
        f.geometry = g;
        for (int a = 0; a < 3; ++a) f.geometry.dims[std::size_t(a)] = high_[std::size_t(a)] - low_[std::size_t(a)] + 1;
        f.geometry.origin = g.to_world(Eigen::Vector3d(low_[0], low_[1], low_[2]));
        f.to_index = to_index_;
        std::vector<std::uint8_t> inside(f.geometry.voxel_count(), 0);
        const auto& d = f.geometry.dims;
        for (int k = 0; k < d[2]; ++k)
            for (int j = 0; j < d[1]; ++j)
                for (int i = 0; i < d[0]; ++i)
                    inside[f.geometry.linear(i, j, k)] = volume_.labels[g.linear(i + low_[0], j + low_[1], k + low_[2])] == label;
        f.distance = distance_map(f.geometry, inside);
        return fields_.emplace(label, std::move(f)).first->second;
    }

    // ---- reasons ------------------------------------------------------------------------------

    /// Why landmarks between these bloods cannot be made from this label map, or empty.
    std::string problem(std::initializer_list<Chamber> needed) const {
        for (const Chamber& c : needed)
            if (c.label == 0)
                return unlabelled_.empty() ? std::string("no label of the label map is named the ") + c.name + "'s blood"
                                           : unlabelled_ + ": no label for the " + c.name + "'s blood";
        for (const Chamber& c : needed)
            if (moments(c.label).count == 0) return "no voxel has the " + std::string(c.name) + "'s label (" + std::to_string(c.label) + ")";
        return "";
    }

    std::string no_groove(const Chamber& a, const Chamber& b, bool near_valve) const {
        char text[400];
        std::snprintf(text, sizeof text,
                      "no vertex of the detailed surface that faces away from the blood lies within %.3g mm of both the %s's and the "
                      "%s's blood (distances equal within %.3g mm)%s: the surface does not pass over that junction",
                      options_.groove_reach_mm, a.name, b.name, options_.groove_band_mm,
                      near_valve ? (" within " + format_mm(options_.av_plane_reach_mm) + " of the valve's plane").c_str() : "");
        return text;
    }

    static std::string format_mm(double value) {
        char text[32];
        std::snprintf(text, sizeof text, "%.3g mm", value);
        return text;
    }

    void add_missing(const std::string& name, const std::string& reason) { result_.missing.push_back({name, reason}); }

    // ---- grooves ------------------------------------------------------------------------------

    /// Vertices facing away from every blood: no blood label along the outward normal for three voxels.
    bool faces_out(std::size_t v) const {
        const Eigen::Vector3d& n = surface_.normals[v];
        if (n.squaredNorm() < 0.5) return false;
        const double h = volume_.geometry.spacing.maxCoeff();
        for (int step = 1; step <= 3; ++step)
            if (is_blood(label_at(surface_.positions[v] + n * (step * h)))) return false;
        return true;
    }

    /// A groove's vertices; an atrioventricular groove's within `av_plane_reach_mm` of its valve's
    /// plane and within the ring's radius plus `groove_reach_mm` of its axis.
    std::vector<int> groove_vertices(const Chamber& a, const Chamber& b, const std::optional<Plane>& valve) {
        const Field& fa = field(a.label);
        const Field& fb = field(b.label);
        std::vector<int> out;
        for (std::size_t v = 0; v < surface_.positions.size(); ++v) {
            const Eigen::Vector3d& p = surface_.positions[v];
            const double da = fa.at(p);
            if (!(da <= options_.groove_reach_mm)) continue;
            const double db = fb.at(p);
            if (!(db <= options_.groove_reach_mm) || std::abs(da - db) > options_.groove_band_mm) continue;
            if (valve) {  // beside the valve's ring: near its plane, no farther out than the groove's reach
                const Eigen::Vector3d r = p - valve->centre;
                const double height = r.dot(valve->normal);
                if (std::abs(height) > options_.av_plane_reach_mm ||
                    (r - height * valve->normal).norm() > valve->radius + options_.groove_reach_mm)
                    continue;
            }
            if (faces_out(v)) out.push_back(int(v));
        }
        return out;
    }

    /// The left ventricle's long axis, unit, from the base (the left atrium's side) to the apex.
    Eigen::Vector3d long_axis() const {
        const LabelMoments& lv = moments(chambers_.left_ventricle);
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(lv.covariance());
        Eigen::Vector3d axis = eigen.eigenvectors().col(2);
        Eigen::Vector3d base{0, 0, 0};
        if (moments(chambers_.left_atrium).count) base = moments(chambers_.left_atrium).centroid();
        else if (moments(chambers_.aorta).count) base = moments(chambers_.aorta).centroid();
        else return axis;
        if ((base - lv.centroid()).dot(axis) > 0) axis = -axis;
        return axis;
    }

    /// The interventricular groove's halves: anterior (towards −y, the patient's front) and
    /// posterior of the plane through the left ventricle's long axis and the right ventricle.
    void split_interventricular(const std::vector<int>& both, std::vector<int>& anterior, std::vector<int>& posterior) const {
        const Eigen::Vector3d axis = long_axis();
        const Eigen::Vector3d lv = moments(chambers_.left_ventricle).centroid(), rv = moments(chambers_.right_ventricle).centroid();
        Eigen::Vector3d across = rv - lv;
        across -= across.dot(axis) * axis;
        Eigen::Vector3d front = axis.cross(across.normalized());
        if (front.dot(Eigen::Vector3d(0, -1, 0)) < 0) front = -front;
        for (int v : both) (((surface_.positions[std::size_t(v)] - lv).dot(front) > 0) ? anterior : posterior).push_back(v);
    }

    void add_groove(const char* name, const Chamber& a, const Chamber& b, const std::vector<int>& vertices, const std::string& reason) {
        if (!reason.empty()) return add_missing(name, reason);
        Landmark l;
        l.name = name;
        l.kind = LandmarkKind::groove;
        l.between = std::string(a.name) + ", " + b.name;
        for (int v : vertices) l.points.push_back(surface_.positions[std::size_t(v)]);
        result_.found.push_back(std::move(l));
    }

    // ---- on the surface -----------------------------------------------------------------------

    /// Moves `points` onto the nearest surface vertices; leaves out those the surface does not
    /// reach. Returns the reason when fewer than half are reached, else empty.
    std::string put_on_surface(const std::vector<Eigen::Vector3d>& points, Landmark& l, bool dedupe) const {
        l.points.clear();
        l.surface_distance_mm = 0.0;
        std::size_t reached = 0;
        int previous = -1;
        for (const auto& p : points) {
            double distance = 0.0;
            const int v = grid_.nearest(p, options_.max_surface_distance_mm, &distance);
            if (v < 0) continue;
            ++reached;
            l.surface_distance_mm = std::max(l.surface_distance_mm, distance);
            if (dedupe && v == previous) continue;
            previous = v;
            l.points.push_back(surface_.positions[std::size_t(v)]);
        }
        if (dedupe && l.closed() && l.points.size() > 1 && l.points.front() == l.points.back()) l.points.pop_back();
        l.coverage = points.empty() ? 0.0 : double(reached) / double(points.size());
        if (points.empty() || 2 * reached < points.size() || l.points.size() < 3) {
            char text[320];
            std::snprintf(text, sizeof text,
                          "the detailed surface passes within %.3g mm of %zu of its %zu points in the label map: it does not cover the "
                          "junction of the %s",
                          options_.max_surface_distance_mm, reached, points.size(), l.between.c_str());
            return text;
        }
        double length = 0.0;
        for (std::size_t i = 1; i < l.points.size(); ++i) length += (l.points[i] - l.points[i - 1]).norm();
        if (l.closed()) length += (l.points.front() - l.points.back()).norm();
        l.length_mm = length;
        return "";
    }

    // ---- courses ------------------------------------------------------------------------------

    /// A course through `vertices` ordered by `along` (mm): the mean of each step's vertices, along
    /// the longest run of steps without a gap wider than three steps (the most vertices among equals).
    std::vector<Eigen::Vector3d> course_points(const std::vector<int>& vertices, const std::vector<double>& along) const {
        std::map<long, std::pair<Eigen::Vector3d, std::size_t>> steps;
        for (std::size_t n = 0; n < vertices.size(); ++n) {
            auto& s = steps[long(std::floor(along[n] / options_.course_step_mm))];
            if (s.second == 0) s.first.setZero();
            s.first += surface_.positions[std::size_t(vertices[n])];
            ++s.second;
        }
        std::vector<std::vector<std::pair<Eigen::Vector3d, std::size_t>>> runs;
        long last = 0;
        for (const auto& [step, s] : steps) {
            if (runs.empty() || step - last > 3) runs.emplace_back();
            runs.back().push_back({s.first / double(s.second), s.second});
            last = step;
        }
        std::size_t best = 0, best_steps = 0, best_count = 0;
        for (std::size_t r = 0; r < runs.size(); ++r) {
            std::size_t count = 0;
            for (const auto& s : runs[r]) count += s.second;
            if (runs[r].size() > best_steps || (runs[r].size() == best_steps && count > best_count))
                best_steps = runs[r].size(), best_count = count, best = r;
        }
        std::vector<Eigen::Vector3d> points;
        if (!runs.empty())
            for (const auto& s : runs[best]) points.push_back(s.first);
        // A light smoothing of the means (1-2-1), ends kept.
        std::vector<Eigen::Vector3d> smooth = points;
        for (std::size_t i = 1; i + 1 < points.size(); ++i) smooth[i] = 0.25 * points[i - 1] + 0.5 * points[i] + 0.25 * points[i + 1];
        return smooth;
    }

    void add_course(const char* name, const Chamber& a, const Chamber& b, const std::vector<Eigen::Vector3d>& points) {
        Landmark l;
        l.name = name;
        l.kind = LandmarkKind::course;
        l.between = std::string(a.name) + ", " + b.name;
        if (points.size() < 3) {
            char text[200];
            std::snprintf(text, sizeof text, "its groove spans fewer than 3 steps of %.3g mm", options_.course_step_mm);
            return add_missing(name, text);
        }
        const std::string reason = put_on_surface(points, l, true);
        if (!reason.empty()) return add_missing(name, reason);
        if (l.length_mm < options_.min_course_mm) {
            char text[300];
            std::snprintf(text, sizeof text,
                          "the detailed surface shows %.1f mm of its groove, less than %.3g mm: it does not pass over that junction",
                          l.length_mm, options_.min_course_mm);
            return add_missing(name, text);
        }
        result_.found.push_back(std::move(l));
    }

    /// The left anterior descending artery: the anterior interventricular groove from base to apex.
    void add_lad(const Chamber& lv, const Chamber& rv, const std::vector<int>& anterior, const std::string& reason) {
        if (!reason.empty()) return add_missing(lad_course, "its groove is missing: " + reason);
        if (anterior.empty()) return add_missing(lad_course, "the anterior interventricular groove is missing");
        const Eigen::Vector3d axis = long_axis(), origin = moments(chambers_.left_ventricle).centroid();
        std::vector<double> along;
        for (int v : anterior) along.push_back((surface_.positions[std::size_t(v)] - origin).dot(axis));
        add_course(lad_course, lv, rv, course_points(anterior, along));
    }

    /// The right coronary (right AV groove) or the circumflex (left AV groove): round the valve's
    /// ring by angle, from the end farther from the crux to the point nearest it (without a
    /// posterior interventricular groove: from the end nearer the aortic root, else the more
    /// anterior end, to the other).
    void add_av_course(const char* name, const Chamber& atrium, const Chamber& ventricle, const std::vector<int>& groove,
                       const std::string& reason, const std::optional<Plane>& valve, const std::optional<Eigen::Vector3d>& crux,
                       const std::optional<Eigen::Vector3d>& root) {
        if (!reason.empty()) return add_missing(name, "its groove is missing: " + reason);
        if (groove.empty()) return add_missing(name, "its groove is missing");
        // The axis round which the groove runs: the valve's ring, else the line between the chambers.
        Plane plane;
        if (valve) {
            plane = *valve;
        } else {
            const Eigen::Vector3d ca = moments(atrium.label).centroid(), cv = moments(ventricle.label).centroid();
            plane.centre = 0.5 * (ca + cv), plane.normal = (cv - ca).normalized();
        }
        const Eigen::Vector3d e1 = plane.normal.unitOrthogonal(), e2 = plane.normal.cross(e1);
        std::vector<double> angle;
        double radius = 0.0;
        for (int v : groove) {
            const Eigen::Vector3d r = surface_.positions[std::size_t(v)] - plane.centre;
            angle.push_back(std::atan2(r.dot(e2), r.dot(e1)));
            radius += (r - r.dot(plane.normal) * plane.normal).norm();
        }
        radius /= double(groove.size());
        // Start after the widest angular gap, so a C-shaped groove is one run.
        std::vector<double> sorted = angle;
        std::sort(sorted.begin(), sorted.end());
        double gap = sorted.front() + 2 * std::numbers::pi - sorted.back(), start = sorted.front();
        for (std::size_t i = 1; i < sorted.size(); ++i)
            if (sorted[i] - sorted[i - 1] > gap) gap = sorted[i] - sorted[i - 1], start = sorted[i];
        std::vector<double> along;
        for (double a : angle) {
            double turned = a - start;
            while (turned < 0) turned += 2 * std::numbers::pi;
            along.push_back(turned * radius);
        }
        std::vector<Eigen::Vector3d> points = course_points(groove, along);
        if (points.size() >= 2) {
            bool reverse = false;
            if (crux) reverse = (points.back() - *crux).norm() > (points.front() - *crux).norm();
            else if (root) reverse = (points.back() - *root).norm() < (points.front() - *root).norm();
            else reverse = points.back().y() < points.front().y();
            if (reverse) std::reverse(points.begin(), points.end());
            if (crux) {  // the artery runs in this groove as far as the crux
                std::size_t nearest = 0;
                for (std::size_t i = 1; i < points.size(); ++i)
                    if ((points[i] - *crux).norm() < (points[nearest] - *crux).norm()) nearest = i;
                points.resize(nearest + 1);
            }
        }
        add_course(name, atrium, ventricle, points);
    }

    // ---- rings --------------------------------------------------------------------------------

    Contact contact(int a, int b) const {
        const auto& g = volume_.geometry;
        Contact c;
        for (int axis = 0; axis < 3; ++axis) {
            std::array<int, 3> step{0, 0, 0};
            step[std::size_t(axis)] = 1;
            const Eigen::Vector3d direction = g.direction.col(axis);
            const double area = g.spacing.prod() / g.spacing[axis];
            for (int k = low_[2]; k + step[2] <= high_[2]; ++k)
                for (int j = low_[1]; j + step[1] <= high_[1]; ++j)
                    for (int i = low_[0]; i + step[0] <= high_[0]; ++i) {
                        const int here = volume_.labels[g.linear(i, j, k)];
                        if (here != a && here != b) continue;
                        const int there = volume_.labels[g.linear(i + step[0], j + step[1], k + step[2])];
                        if (!((here == a && there == b) || (here == b && there == a))) continue;
                        c.centres.push_back(g.to_world(Eigen::Vector3d(i + 0.5 * step[0], j + 0.5 * step[1], k + 0.5 * step[2])));
                        c.areas.push_back(area);
                        c.a_to_b += area * (here == a ? direction : Eigen::Vector3d(-direction));
                    }
        }
        return c;
    }

    /// The faces of the largest connected patch of contact (faces within a voxel of each other join).
    std::vector<std::size_t> largest_patch(const Contact& c) const {
        const std::size_t n = c.centres.size();
        std::vector<std::size_t> parent(n);
        std::iota(parent.begin(), parent.end(), std::size_t(0));
        auto root = [&](std::size_t i) {
            while (parent[i] != i) i = parent[i] = parent[parent[i]];
            return i;
        };
        const double link = 1.01 * volume_.geometry.spacing.maxCoeff();
        CellIndex cells;
        for (std::size_t i = 0; i < n; ++i) cells[cell_of(c.centres[i], link)].push_back(i);
        for (std::size_t i = 0; i < n; ++i)
            for (std::size_t j : neighbours(c.centres, cells, i, link)) {
                const std::size_t ri = root(i), rj = root(j);
                if (ri != rj) parent[ri] = rj;
            }
        std::unordered_map<std::size_t, double> area;
        for (std::size_t i = 0; i < n; ++i) area[root(i)] += c.areas[i];
        std::size_t best = 0;
        double best_area = -1.0;
        for (const auto& [r, a] : area)
            if (a > best_area) best_area = a, best = r;
        std::vector<std::size_t> out;
        for (std::size_t i = 0; i < n; ++i)
            if (root(i) == best) out.push_back(i);
        return out;
    }

    using CellIndex = std::unordered_map<std::uint64_t, std::vector<std::size_t>>;
    static std::uint64_t cell_key(long x, long y, long z) {
        return (std::uint64_t(x & 0x1fffff) << 42) | (std::uint64_t(y & 0x1fffff) << 21) | std::uint64_t(z & 0x1fffff);
    }
    static std::uint64_t cell_of(const Eigen::Vector3d& p, double cell) {
        return cell_key(long(std::floor(p.x() / cell)), long(std::floor(p.y() / cell)), long(std::floor(p.z() / cell)));
    }
    static std::vector<std::size_t> neighbours(const std::vector<Eigen::Vector3d>& points, const CellIndex& cells, std::size_t i,
                                               double cell) {
        std::vector<std::size_t> out;
        const Eigen::Vector3d& p = points[i];
        const long x = long(std::floor(p.x() / cell)), y = long(std::floor(p.y() / cell)), z = long(std::floor(p.z() / cell));
        for (long dz = -1; dz <= 1; ++dz)
            for (long dy = -1; dy <= 1; ++dy)
                for (long dx = -1; dx <= 1; ++dx) {
                    const auto found = cells.find(cell_key(x + dx, y + dy, z + dz));
                    if (found == cells.end()) continue;
                    for (std::size_t j : found->second)
                        if (j != i && (points[j] - p).squaredNorm() <= cell * cell) out.push_back(j);
                }
        return out;
    }

    /// Adds the ring between two bloods (or its reason to be missing); returns its plane where the
    /// bloods touch, whether or not the surface reaches the ring.
    std::optional<Plane> add_ring(const char* name, const Chamber& a, const Chamber& b) {
        if (const std::string reason = problem({a, b}); !reason.empty()) {
            add_missing(name, reason);
            return std::nullopt;
        }
        const Contact all = contact(a.label, b.label);
        if (all.centres.size() < 3) {
            add_missing(name, "the " + std::string(a.name) + "'s and the " + b.name + "'s blood do not touch in the label map");
            return std::nullopt;
        }
        const std::vector<std::size_t> patch = largest_patch(all);
        double total = 0.0;
        Eigen::Vector3d centre{0, 0, 0};
        for (std::size_t i : patch) total += all.areas[i], centre += all.areas[i] * all.centres[i];
        centre /= total;
        Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
        Eigen::Vector3d a_to_b{0, 0, 0};
        for (std::size_t i : patch) {
            const Eigen::Vector3d r = all.centres[i] - centre;
            covariance += all.areas[i] * r * r.transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance);
        Eigen::Vector3d normal = eigen.eigenvectors().col(0);
        if (normal.dot(all.a_to_b) < 0) normal = -normal;
        const Eigen::Vector3d e1 = eigen.eigenvectors().col(2), e2 = normal.cross(e1);
        // The rim: in each sector, the face farthest from the centre in the plane.
        const int sectors = std::max(options_.ring_sectors, 8);
        std::vector<double> reach(std::size_t(sectors), -1.0);
        std::vector<Eigen::Vector3d> rim(static_cast<std::size_t>(sectors));
        for (std::size_t i : patch) {
            const Eigen::Vector3d r = all.centres[i] - centre;
            const double x = r.dot(e1), y = r.dot(e2), radius = std::hypot(x, y);
            double angle = std::atan2(y, x);
            if (angle < 0) angle += 2 * std::numbers::pi;
            const std::size_t s = std::min(std::size_t(angle / (2 * std::numbers::pi) * sectors), std::size_t(sectors - 1));
            if (radius > reach[s]) reach[s] = radius, rim[s] = all.centres[i];
        }
        std::vector<Eigen::Vector3d> points;
        double radius = 0.0;
        for (int s = 0; s < sectors; ++s)
            if (reach[std::size_t(s)] >= 0) points.push_back(rim[std::size_t(s)]), radius += reach[std::size_t(s)];
        Landmark l;
        l.name = name;
        l.kind = LandmarkKind::ring;
        l.between = std::string(a.name) + ", " + b.name;
        l.centre = centre;
        l.normal = normal;
        l.diameter_mm = points.empty() ? 0.0 : 2.0 * radius / double(points.size());
        if (const std::string reason = put_on_surface(points, l, true); !reason.empty()) {
            char figures[160];
            std::snprintf(figures, sizeof figures, " (in the label map: %.1f mm across, centre %.1f, %.1f, %.1f)", l.diameter_mm, centre.x(),
                          centre.y(), centre.z());
            add_missing(name, reason + figures);
            return Plane{centre, normal, l.diameter_mm / 2};
        }
        result_.found.push_back(l);
        return Plane{centre, normal, l.diameter_mm / 2};
    }

    const LabelVolume& volume_;
    ChamberLabels chambers_;
    TriangleMesh surface_;
    LandmarkOptions options_;
    std::string unlabelled_;
    VertexGrid grid_;
    Eigen::Matrix3d to_index_;
    std::map<int, LabelMoments> moments_;
    std::array<int, 3> low_{}, high_{};
    std::map<int, Field> fields_;
    Landmarks result_;
};

}  // namespace

ChamberLabels chamber_labels_from_names(const SegmentNames& names) {
    ChamberLabels c;
    for (const auto& [label, name] : names) {
        if (classify_segment_name(name) == SegmentKind::heart_muscle) continue;
        std::string n = text::lowercase(text::trim(name));
        std::replace(n.begin(), n.end(), '_', ' ');
        const std::string padded = " " + n + " ";
        auto word = [&](const char* w) { return padded.find(std::string(" ") + w + " ") != std::string::npos; };
        auto has = [&](const char* w) { return n.find(w) != std::string::npos; };
        const bool left = has("left") || word("lv") || word("la"), right = has("right") || word("rv") || word("ra");
        const bool ventricle = has("ventric") || word("lv") || word("rv"), atrium = has("atri") || word("la") || word("ra");
        int* slot = nullptr;
        if (has("aort") || word("ao")) slot = &c.aorta;
        else if (has("pulmonary art") || has("pulmonary trunk") || word("pa")) slot = &c.pulmonary_artery;
        else if (left && !right && ventricle && !atrium) slot = &c.left_ventricle;
        else if (right && !left && ventricle && !atrium) slot = &c.right_ventricle;
        else if (left && !right && atrium && !ventricle) slot = &c.left_atrium;
        else if (right && !left && atrium && !ventricle) slot = &c.right_atrium;
        if (slot && *slot == 0) *slot = label;
    }
    return c;
}

const char* to_string(LandmarkKind kind) {
    switch (kind) {
    case LandmarkKind::groove: return "groove";
    case LandmarkKind::course: return "course";
    case LandmarkKind::ring: return "ring";
    }
    return "groove";
}

LandmarkKind parse_landmark_kind(const std::string& text) {
    for (LandmarkKind k : {LandmarkKind::groove, LandmarkKind::course, LandmarkKind::ring})
        if (text == to_string(k)) return k;
    throw InputError("landmark kind '" + text + "': expected groove, course or ring");
}

const Landmark* Landmarks::find(const std::string& name) const {
    for (const Landmark& l : found)
        if (l.name == name) return &l;
    return nullptr;
}

const std::vector<std::string>& landmark_names() {
    static const std::vector<std::string> names = {interventricular_anterior, interventricular_posterior, right_av_groove, left_av_groove,
                                                   lad_course, rca_course, lcx_course, tricuspid_ring, mitral_ring, aortic_ring,
                                                   pulmonary_ring};
    return names;
}

Landmarks find_landmarks(const LabelVolume& volume, const ChamberLabels& chambers, const TriangleMesh& surface,
                         const LandmarkOptions& options, const std::string& unlabelled_reason) {
    if (surface.positions.empty() || surface.triangles.empty()) return missing_landmarks("no detailed surface to put them on");
    return Finder(volume, chambers, surface, options, unlabelled_reason).run();
}

Landmarks missing_landmarks(const std::string& reason) {
    Landmarks out;
    for (const std::string& name : landmark_names()) out.missing.push_back({name, reason});
    return out;
}

}  // namespace heartsim
