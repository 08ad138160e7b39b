// Whether a patch closes a septal defect (closure.h): the wall's thickness from lines along the
// axis, the rim and its gap to the patch, the tissue and the patch rasterised on a grid in the
// defect's frame, and a flood fill from the opening at mid-wall to beyond the patch. Everything after the input checks works in the
// defect's frame: x, y across the axis, z along it (s), origin at the defect's centre.
#include "libmodel/surgery/closure.h"

#include "libmodel/errors.h"
#include "libmodel/ray_triangle.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>
#include <string>
#include <utility>

namespace heartsim {
namespace {

using Vector2 = Eigen::Vector2d;
using Vector3 = Eigen::Vector3d;
using Triangle = std::array<std::int32_t, 3>;

/// A triangle mesh in the defect's frame.
struct FrameMesh {
    std::vector<Vector3> points;
    const std::vector<Triangle>& triangles;
    const Vector3& corner(std::size_t t, int c) const { return points[std::size_t(triangles[t][std::size_t(c)])]; }
};

std::string format_point(const Vector3& p) {
    std::ostringstream text;
    text.precision(4);
    text << "(" << p.x() << ", " << p.y() << ", " << p.z() << ") mm";
    return text.str();
}

void require_mesh(const std::vector<std::array<float, 3>>& positions, const std::vector<Triangle>& triangles, const char* what) {
    for (std::size_t v = 0; v < positions.size(); ++v)
        for (float c : positions[v])
            if (!std::isfinite(c)) throw InputError(std::string(what) + " position " + std::to_string(v) + " is not finite");
    for (std::size_t t = 0; t < triangles.size(); ++t)
        for (std::int32_t v : triangles[t])
            if (v < 0 || std::size_t(v) >= positions.size())
                throw InputError(std::string(what) + " triangle " + std::to_string(t) + " names vertex " + std::to_string(v) + ", outside [0, " +
                                 std::to_string(positions.size()) + ")");
}

/// Where a line parallel to one frame axis crosses a triangle: `along` is the line's coordinate
/// there, `sign` +1 where the line enters the mesh going forward (the outward normal points against
/// the line), −1 where it leaves.
struct Crossing {
    double along;
    int sign;
};

/// The crossing of the line through `point` with a triangle, the triangle given by its corners
/// projected onto the two axes across the line (p0, p1, p2) and their coordinates along it (w0,
/// w1, w2); the two axes and the line's direction must be right-handed in that order. False when
/// the line misses the triangle or the triangle is edge-on to it (ray_triangle.h, whose edge rule
/// counts an edge in both its triangles: callers keep their lines off vertices and edges,
/// irrational offsets, so each crossing of a closed mesh is counted once).
bool cross_line(const Vector2& point, const Vector2& p0, const Vector2& p1, const Vector2& p2, double w0, double w1, double w2,
                Crossing& crossing) {
    const auto hit = line_triangle(Vector3(point.x(), point.y(), 0.0), Vector3::UnitZ(), Vector3(p0.x(), p0.y(), w0),
                                   Vector3(p1.x(), p1.y(), w1), Vector3(p2.x(), p2.y(), w2));
    if (!hit) return false;
    crossing.along = hit->along;
    crossing.sign = hit->det > 0.0 ? +1 : -1;  // det > 0: the outward normal against the line, entering
    return true;
}

/// The crossing of the line (x, y) = `point` parallel to the frame's z axis with triangle t.
bool cross_along_axis(const FrameMesh& mesh, std::size_t t, const Vector2& point, Crossing& crossing) {
    const Vector3 &a = mesh.corner(t, 0), &b = mesh.corner(t, 1), &c = mesh.corner(t, 2);
    if (point.x() < std::min({a.x(), b.x(), c.x()}) || point.x() > std::max({a.x(), b.x(), c.x()}) ||
        point.y() < std::min({a.y(), b.y(), c.y()}) || point.y() > std::max({a.y(), b.y(), c.y()}))
        return false;
    return cross_line(point, a.head<2>(), b.head<2>(), c.head<2>(), a.z(), b.z(), c.z(), crossing);
}

/// The closest point of triangle (a, b, c) to p (Ericson, Real-Time Collision Detection, 5.1.5).
Vector3 closest_on_triangle(const Vector3& p, const Vector3& a, const Vector3& b, const Vector3& c) {
    const Vector3 ab = b - a, ac = c - a, ap = p - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0.0 && d2 <= 0.0) return a;
    const Vector3 bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0.0 && d4 <= d3) return b;
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + ab * (d1 / (d1 - d3));
    const Vector3 cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0.0 && d5 <= d6) return c;
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + ac * (d2 / (d2 - d6));
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    const double denominator = va + vb + vc;
    if (denominator == 0.0) {  // a degenerate triangle: the nearest of its corners
        const double da = (p - a).squaredNorm(), db = (p - b).squaredNorm(), dc = (p - c).squaredNorm();
        return da <= db && da <= dc ? a : (db <= dc ? b : c);
    }
    return a + ab * (vb / denominator) + ac * (vc / denominator);
}

double distance_to_mesh(const Vector3& p, const FrameMesh& mesh) {
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        nearest = std::min(nearest, (closest_on_triangle(p, mesh.corner(t, 0), mesh.corner(t, 1), mesh.corner(t, 2)) - p).squaredNorm());
    return std::sqrt(nearest);
}

void sort_along(std::vector<Crossing>& crossings) {
    std::sort(crossings.begin(), crossings.end(), [](const Crossing& x, const Crossing& y) { return x.along < y.along; });
}

/// Step 1: the median length of the tissue intervals (winding number ≠ 0) of eight lines parallel
/// to the axis at `rim_radius`, each the interval containing s = 0 or nearest it, within `reach`.
/// The angles are offset by an irrational fraction of a turn so the lines miss the edges of a mesh
/// built with rotational symmetry. Lines whose crossings do not sum to zero (an open mesh) are
/// skipped. NaN when no line finds a wall. `distances`: each line's distance from s = 0 to its
/// interval (0 where the interval holds it: the centre lies within the wall there).
double wall_thickness(const FrameMesh& tissue, double rim_radius, double reach, std::vector<double>& distances) {
    std::vector<double> lengths;
    std::vector<Crossing> crossings;
    for (int line = 0; line < 8; ++line) {
        const double angle = 2.0 * std::numbers::pi * (line + 0.1 * std::numbers::sqrt2) / 8.0;
        const Vector2 point(rim_radius * std::cos(angle), rim_radius * std::sin(angle));
        crossings.clear();
        for (std::size_t t = 0; t < tissue.triangles.size(); ++t) {
            Crossing crossing{};
            if (cross_along_axis(tissue, t, point, crossing)) crossings.push_back(crossing);
        }
        sort_along(crossings);
        int winding = 0;
        double start = 0.0, nearest = std::numeric_limits<double>::infinity(), length = 0.0;
        for (const Crossing& c : crossings) {
            const int before = winding;
            winding += c.sign;
            if (before == 0 && winding != 0) start = c.along;
            if (before != 0 && winding == 0) {
                const double distance = std::max({start, -c.along, 0.0});
                if (distance < nearest) nearest = distance, length = c.along - start;
            }
        }
        if (winding == 0 && nearest <= reach) lengths.push_back(length), distances.push_back(nearest);
    }
    if (lengths.empty()) return std::numeric_limits<double>::quiet_NaN();
    std::sort(lengths.begin(), lengths.end());
    const std::size_t middle = lengths.size() / 2;
    return lengths.size() % 2 ? lengths[middle] : 0.5 * (lengths[middle - 1] + lengths[middle]);
}

/// One axis of the voxel grid: n layers of `h` mm, layer i centred at first + i·h.
struct GridAxis {
    double first = 0.0, h = 0.0;
    long n = 0;
    double centre(long i) const { return first + double(i) * h; }
    /// The layers whose centres lie in [low, high]; false when none.
    bool layers(double low, double high, long& from, long& to) const {
        const double lo = (low - first) / h, hi = (high - first) / h;
        if (!(lo <= double(n - 1)) || !(hi >= 0.0)) return false;
        from = std::max(0L, long(std::ceil(lo)));
        to = std::min(n - 1, long(std::floor(hi)));
        return from <= to;
    }
};

/// The voxel grid, axes along the defect's frame: x and y across the axis centred on it, z along
/// it. The region (a cylinder) leaves at least one layer of the grid outside it all round, so every
/// region voxel has its six neighbours in the grid.
struct Grid {
    static constexpr std::uint8_t in_region = 1, blocked = 2, visited = 4, on_path = 8, patch = 16;
    double h = 0.0;
    GridAxis across, along;  // across: x and y; along: z
    std::size_t side = 0, layer = 0;
    std::vector<std::uint8_t> flags;

    /// The cylinder ρ ≤ `radius`, 0 ≤ s ≤ `top`: layers along z from s = −h/2 (outside) to one
    /// past the last centre ≤ top.
    Grid(double voxel_mm, double radius, double top) : h(voxel_mm) {
        const long half = long(std::ceil(radius / h)) + 1;
        across = {(0.5 - double(half)) * h, h, 2 * half};
        along = {-0.5 * h, h, long(std::floor(top / h + 0.5)) + 2};
        side = std::size_t(across.n);
        layer = side * side;
    }
    double voxels() const { return double(across.n) * double(across.n) * double(along.n); }
    std::size_t index(long i, long j, long k) const { return std::size_t(i) + side * std::size_t(j) + layer * std::size_t(k); }
    /// The centre of voxel `at` (an index()), in the defect's frame.
    Vector3 centre(std::size_t at) const {
        return {across.centre(long(at % side)), across.centre(long((at % layer) / side)), along.centre(long(at / layer))};
    }
    /// Breadth first from the voxels in `queue` to every face neighbour whose flags `admits`:
    /// marks each with `mark` and appends it to `queue`.
    template <class Admits> void flood(std::vector<std::uint32_t>& queue, std::uint8_t mark, Admits admits) {
        for (std::size_t head = 0; head < queue.size(); ++head) {
            const std::size_t at = queue[head];
            for (const std::size_t next : {at - 1, at + 1, at - side, at + side, at - layer, at + layer}) {
                if (!admits(next)) continue;
                flags[next] |= mark;
                queue.push_back(std::uint32_t(next));
            }
        }
    }
};

/// Step 4: blocks the region's voxels whose centres the closed mesh winds around (winding number
/// ≠ 0), counted along rows parallel to the frame's x axis. Row (j, k) is the line
/// (y_j + δy, z_k + δz); δ, small irrational fractions of a voxel, keep it off the vertices and
/// edges of meshes built on round numbers. Triangles are binned by the rows their (y, z) bounding
/// box spans: every triangle of the mesh, for a voxel's winding number counts every crossing
/// before it along its row, also those outside the region. Only rows that pass through the
/// region (|y| ≤ the cylinder's radius) are binned.
void block_tissue(Grid& grid, const FrameMesh& tissue, double radius) {
    const double dy = grid.h * 1e-2 * (std::numbers::sqrt2 - 1.0), dz = grid.h * 1e-2 * (std::numbers::sqrt3 - 1.0);
    const std::size_t rows = grid.side * std::size_t(grid.along.n);
    auto row_in_region = [&](long j) { return std::abs(grid.across.centre(j)) <= radius; };
    // Rows' triangles, compressed: row r holds binned[start[r] .. start[r + 1]).
    std::vector<std::uint32_t> start(rows + 1, 0), binned, fill;
    for (int pass = 0; pass < 2; ++pass) {
        if (pass == 1) {
            for (std::size_t r = 0; r < rows; ++r) start[r + 1] += start[r];
            binned.resize(start[rows]);
            fill.assign(start.begin(), start.end() - 1);
        }
        for (std::size_t t = 0; t < tissue.triangles.size(); ++t) {
            const Vector3 &a = tissue.corner(t, 0), &b = tissue.corner(t, 1), &c = tissue.corner(t, 2);
            long j0, j1, k0, k1;
            if (!grid.across.layers(std::min({a.y(), b.y(), c.y()}) - dy, std::max({a.y(), b.y(), c.y()}) - dy, j0, j1) ||
                !grid.along.layers(std::min({a.z(), b.z(), c.z()}) - dz, std::max({a.z(), b.z(), c.z()}) - dz, k0, k1))
                continue;
            for (long k = k0; k <= k1; ++k)
                for (long j = j0; j <= j1; ++j) {
                    if (!row_in_region(j)) continue;
                    const std::size_t row = std::size_t(j) + grid.side * std::size_t(k);
                    if (pass == 0) ++start[row + 1];
                    else binned[fill[row]++] = std::uint32_t(t);
                }
        }
    }
    std::vector<Crossing> crossings;
    for (long k = 0; k < grid.along.n; ++k)
        for (long j = 0; j < grid.across.n; ++j) {
            const std::size_t row = std::size_t(j) + grid.side * std::size_t(k);
            if (start[row] == start[row + 1]) continue;
            const Vector2 point(grid.across.centre(j) + dy, grid.along.centre(k) + dz);
            crossings.clear();
            for (std::uint32_t b = start[row]; b < start[row + 1]; ++b) {
                const Vector3 &p0 = tissue.corner(binned[b], 0), &p1 = tissue.corner(binned[b], 1), &p2 = tissue.corner(binned[b], 2);
                Crossing crossing{};
                // (y, z, x) is right-handed, as cross_line asks.
                if (cross_line(point, p0.tail<2>(), p1.tail<2>(), p2.tail<2>(), p0.x(), p1.x(), p2.x(), crossing)) crossings.push_back(crossing);
            }
            sort_along(crossings);
            int winding = 0;
            std::size_t next = 0;
            for (long i = 0; i < grid.across.n; ++i) {
                while (next < crossings.size() && crossings[next].along < grid.across.centre(i)) winding += crossings[next++].sign;
                std::uint8_t& flags = grid.flags[grid.index(i, j, k)];
                if (winding != 0 && (flags & Grid::in_region)) flags |= Grid::blocked;
            }
        }
}

/// Step 4: blocks the region's voxels whose centres lie within `reach` of a patch triangle.
void block_patch(Grid& grid, const FrameMesh& patch, double reach) {
    for (std::size_t t = 0; t < patch.triangles.size(); ++t) {
        const Vector3 &a = patch.corner(t, 0), &b = patch.corner(t, 1), &c = patch.corner(t, 2);
        const Vector3 low = (a.cwiseMin(b).cwiseMin(c).array() - reach).matrix(), high = (a.cwiseMax(b).cwiseMax(c).array() + reach).matrix();
        long i0, i1, j0, j1, k0, k1;
        if (!grid.across.layers(low.x(), high.x(), i0, i1) || !grid.across.layers(low.y(), high.y(), j0, j1) ||
            !grid.along.layers(low.z(), high.z(), k0, k1))
            continue;
        for (long k = k0; k <= k1; ++k)
            for (long j = j0; j <= j1; ++j)
                for (long i = i0; i <= i1; ++i) {
                    std::uint8_t& flags = grid.flags[grid.index(i, j, k)];
                    if (flags != Grid::in_region) continue;  // outside, or already blocked
                    const Vector3 p(grid.across.centre(i), grid.across.centre(j), grid.along.centre(k));
                    if ((closest_on_triangle(p, a, b, c) - p).squaredNorm() <= reach * reach) flags |= Grid::blocked | Grid::patch;
                }
    }
}

/// How much of the opening the patch covers: points on a square grid of `spacing` across the
/// axis (offset by irrational fractions of it, off the vertices of meshes built on round numbers)
/// within `radius` of it, each covered where its line along the axis meets a patch triangle at a
/// height in [low, high] (and `anywhere` where it meets one at any height).
struct Cover {
    std::size_t samples = 0, covered = 0, anywhere = 0;
    Vector2 uncovered_sum = Vector2::Zero();  ///< the sum of the uncovered samples' positions
};
Cover cover_opening(const FrameMesh& patch, double radius, double spacing, double low, double high) {
    const double dx = spacing * 0.1 * (std::numbers::sqrt2 - 1.0), dy = spacing * 0.1 * (std::numbers::sqrt3 - 1.0);
    const GridAxis axis{-double(long(std::ceil(radius / spacing))) * spacing, spacing, 2 * long(std::ceil(radius / spacing)) + 1};
    const std::size_t side = std::size_t(axis.n);
    auto point = [&](long i, long j) { return Vector2(axis.centre(i) + dx, axis.centre(j) + dy); };
    std::vector<std::uint8_t> state(side * side, 0);  // 1 in the disc, 2 met at any height, 4 met within reach
    for (long j = 0; j < axis.n; ++j)
        for (long i = 0; i < axis.n; ++i)
            if (point(i, j).norm() <= radius) state[std::size_t(i) + side * std::size_t(j)] = 1;
    for (std::size_t t = 0; t < patch.triangles.size(); ++t) {
        const Vector3 &a = patch.corner(t, 0), &b = patch.corner(t, 1), &c = patch.corner(t, 2);
        long i0, i1, j0, j1;
        if (!axis.layers(std::min({a.x(), b.x(), c.x()}) - dx, std::max({a.x(), b.x(), c.x()}) - dx, i0, i1) ||
            !axis.layers(std::min({a.y(), b.y(), c.y()}) - dy, std::max({a.y(), b.y(), c.y()}) - dy, j0, j1))
            continue;
        for (long j = j0; j <= j1; ++j)
            for (long i = i0; i <= i1; ++i) {
                std::uint8_t& at = state[std::size_t(i) + side * std::size_t(j)];
                Crossing crossing{};
                if (!(at & 1) || (at & 4) || !cross_along_axis(patch, t, point(i, j), crossing)) continue;
                at |= 2;
                if (crossing.along >= low && crossing.along <= high) at |= 4;
            }
    }
    Cover cover;
    for (long j = 0; j < axis.n; ++j)
        for (long i = 0; i < axis.n; ++i) {
            const std::uint8_t at = state[std::size_t(i) + side * std::size_t(j)];
            if (!(at & 1)) continue;
            ++cover.samples;
            if (at & 2) ++cover.anywhere;
            if (at & 4) ++cover.covered;
            else cover.uncovered_sum += point(i, j);
        }
    return cover;
}

/// The input checks of check_closure (closure.h says what each throws).
void require_closure_inputs(const std::vector<std::array<float, 3>>& tissue_positions, const std::vector<Triangle>& tissue_triangles,
                            const std::vector<std::array<float, 3>>& patch_positions, const std::vector<Triangle>& patch_triangles,
                            double patch_thickness_mm, const DefectFrame& defect, const ClosureOptions& options) {
    if (!(options.voxel_mm > 0.0) || !std::isfinite(options.voxel_mm)) throw OptionError("ClosureOptions::voxel_mm must be a positive number of mm");
    if (!(options.margin_mm >= 0.0) || !std::isfinite(options.margin_mm)) throw OptionError("ClosureOptions::margin_mm must be a number of mm ≥ 0");
    if (options.rim_samples < 1) throw OptionError("ClosureOptions::rim_samples must be at least 1");
    for (const Eigen::Vector3d& stitch : options.stitches)
        if (!stitch.allFinite()) throw OptionError("ClosureOptions::stitches holds a point that is not finite");
    if (!(options.rim_offset_mm >= 0.0) || !std::isfinite(options.rim_offset_mm))
        throw OptionError("ClosureOptions::rim_offset_mm must be a number of mm ≥ 0");
    if (tissue_positions.empty() || tissue_triangles.empty()) throw InputError("the tissue mesh is empty: the closure check needs the detailed mesh");
    require_mesh(tissue_positions, tissue_triangles, "tissue");
    require_mesh(patch_positions, patch_triangles, "patch");
    if (!defect.centre.allFinite()) throw InputError("the defect's centre is not finite");
    if (!defect.axis.allFinite() || !(std::abs(defect.axis.norm() - 1.0) <= 1e-3))
        throw InputError("the defect's axis must be a unit vector, not one of length " + std::to_string(defect.axis.norm()));
    if (!(defect.diameter_mm > 0.0) || !std::isfinite(defect.diameter_mm)) throw InputError("the defect's diameter must be a positive number of mm");
    if (!(patch_thickness_mm >= 0.0) || !std::isfinite(patch_thickness_mm)) throw InputError("the patch's thickness must be a number of mm ≥ 0");
}

/// The rotation from world axes into the defect's frame: its rows are x, y across the axis and z
/// along it (right-handed).
Eigen::Matrix3d defect_frame_rotation(const DefectFrame& defect) {
    const Vector3 z_axis = defect.axis.normalized();
    int least_aligned = 0;
    z_axis.cwiseAbs().minCoeff(&least_aligned);
    const Vector3 x_axis = z_axis.cross(Vector3::Unit(least_aligned)).normalized();
    const Vector3 y_axis = z_axis.cross(x_axis);
    Eigen::Matrix3d to_frame;
    to_frame << x_axis.transpose(), y_axis.transpose(), z_axis.transpose();
    return to_frame;
}

/// A world mesh moved into the defect's frame (origin at its centre, rotated by `to_frame`).
FrameMesh in_defect_frame(const Eigen::Matrix3d& to_frame, const DefectFrame& defect, const std::vector<std::array<float, 3>>& positions,
                          const std::vector<Triangle>& triangles) {
    FrameMesh mesh{std::vector<Vector3>(positions.size()), triangles};
    for (std::size_t v = 0; v < positions.size(); ++v)
        mesh.points[v] = to_frame * (Vector3(positions[v][0], positions[v][1], positions[v][2]) - defect.centre);
    return mesh;
}

/// What step 2 found along the rim.
struct Rim {
    int points = 0;            ///< rim samples where the tissue surface was found
    double largest_gap = 0.0;  ///< the largest distance from a rim point to the patch, less half its thickness (0 without a patch)
    double top = -std::numeric_limits<double>::infinity();  ///< the highest rim point's s
};

/// Step 2: the rim. Rays along −z from s = `ray_start` at `rim_radius`, `samples` of them evenly
/// round; the first surface that faces the patch's side (outward normal along +z) within `reach`
/// of the centre is the rim point there. The triangles that can meet those rays are gathered once.
/// The gap to the patch is measured only where `has_patch`.
Rim find_rim(const FrameMesh& tissue, const FrameMesh& patch, bool has_patch, double thickness, double rim_radius, double reach,
             double ray_start, int samples) {
    std::vector<std::uint32_t> near_rim;
    for (std::size_t t = 0; t < tissue.triangles.size(); ++t) {
        const Vector3 &a = tissue.corner(t, 0), &b = tissue.corner(t, 1), &c = tissue.corner(t, 2);
        const Vector3 low = a.cwiseMin(b).cwiseMin(c), high = a.cwiseMax(b).cwiseMax(c);
        if (high.x() >= -rim_radius && low.x() <= rim_radius && high.y() >= -rim_radius && low.y() <= rim_radius && high.z() >= -reach &&
            low.z() <= ray_start)
            near_rim.push_back(std::uint32_t(t));
    }
    Rim rim;
    for (int sample = 0; sample < samples; ++sample) {
        const double angle = 2.0 * std::numbers::pi * (sample + 1e-3 * std::numbers::sqrt2) / samples;
        const Vector2 point(rim_radius * std::cos(angle), rim_radius * std::sin(angle));
        double hit = -std::numeric_limits<double>::infinity();
        for (std::uint32_t t : near_rim) {
            Crossing crossing{};
            // A crossing that leaves the mesh going +z is a surface facing +z.
            if (cross_along_axis(tissue, t, point, crossing) && crossing.sign < 0 && crossing.along <= ray_start) hit = std::max(hit, crossing.along);
        }
        if (!(rim_radius * rim_radius + hit * hit <= reach * reach)) continue;
        ++rim.points;
        rim.top = std::max(rim.top, hit);
        if (has_patch) rim.largest_gap = std::max(rim.largest_gap, distance_to_mesh(Vector3(point.x(), point.y(), hit), patch) - 0.5 * thickness);
    }
    return rim;
}

/// The patch's highest point over the cylinder of `radius` round the axis (−∞ where none): the
/// triangles with a corner within the radius plus the triangle's longest edge across the axis.
double patch_top_over(const FrameMesh& patch, double radius) {
    double top = -std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < patch.triangles.size(); ++t) {
        const Vector3 &a = patch.corner(t, 0), &b = patch.corner(t, 1), &c = patch.corner(t, 2);
        const double edge = std::max({(b - a).head<2>().norm(), (c - b).head<2>().norm(), (a - c).head<2>().norm()});
        if (std::min({a.head<2>().norm(), b.head<2>().norm(), c.head<2>().norm()}) <= radius + edge)
            top = std::max({top, a.z(), b.z(), c.z()});
    }
    return top;
}

/// Step 3: flags the voxels of the region, the cylinder ρ ≤ `radius`, 0 ≤ s ≤ `top`, in a grid
/// of cleared flags; returns how many there are.
std::size_t mark_region(Grid& grid, double radius, double top) {
    grid.flags.assign(grid.layer * std::size_t(grid.along.n), 0);
    std::size_t voxels = 0;
    for (long k = 0; k < grid.along.n; ++k) {
        const double z = grid.along.centre(k);
        if (z < 0.0 || z > top) continue;
        for (long j = 0; j < grid.across.n; ++j)
            for (long i = 0; i < grid.across.n; ++i)
                if (std::pow(grid.across.centre(i), 2) + std::pow(grid.across.centre(j), 2) <= radius * radius) {
                    grid.flags[grid.index(i, j, k)] = Grid::in_region;
                    ++voxels;
                }
    }
    return voxels;
}

/// Whether voxel `at` lies in the region's top layer, the fill's targets.
bool at_top(const Grid& grid, std::size_t at, double top) { return grid.along.centre(long(at / grid.layer)) >= top - grid.h; }

/// Step 5's seeds: the free voxels of the opening at mid-wall (s below `seed_below`, ρ below
/// `seed_radius`), marked visited; throws InputError where there is none, or where the region's
/// top layer (`top`, `cylinder` its radius, for the message) has no free voxel to reach.
std::vector<std::uint32_t> seed_fill(Grid& grid, const DefectFrame& defect, double seed_below, double seed_radius, double top, double cylinder) {
    std::vector<std::uint32_t> queue;
    std::size_t targets = 0;
    for (long k = 1; k + 1 < grid.along.n; ++k)
        for (long j = 1; j + 1 < grid.across.n; ++j)
            for (long i = 1; i + 1 < grid.across.n; ++i) {
                const std::size_t at = grid.index(i, j, k);
                if (grid.flags[at] != Grid::in_region) continue;  // outside, or blocked
                if (grid.along.centre(k) < seed_below &&
                    std::pow(grid.across.centre(i), 2) + std::pow(grid.across.centre(j), 2) < seed_radius * seed_radius) {
                    grid.flags[at] |= Grid::visited;
                    queue.push_back(std::uint32_t(at));
                } else if (at_top(grid, at, top)) {
                    ++targets;
                }
            }
    if (queue.empty()) {
        std::ostringstream what;
        what << "the opening is not open at mid-wall: no free voxel of the defect at " << format_point(defect.centre) << " within "
             << seed_radius << " mm of its axis between s = 0 and " << seed_below
             << " mm (tissue or patch fills the opening there, or the centre is not in it)";
        throw InputError(what.str());
    }
    if (targets == 0) {
        std::ostringstream what;
        what << "no free voxel on the patch's side of the defect at " << format_point(defect.centre) << ": the region's top layer, "
             << top << " mm above the wall's middle and within " << cylinder << " mm of the axis, is all tissue or patch";
        throw InputError(what.str());
    }
    return queue;
}

/// The figures the verdict's reasons quote.
struct VerdictFigures {
    double rim_radius = 0.0, reach = 0.0;           ///< step 2's rim radius and reach, mm
    double reach_low = 0.0, reach_high = 0.0;       ///< the heights within which the patch covers the opening, mm
    std::size_t in_wall = 0;                        ///< step 1's lines whose wall interval holds the centre
};

/// Why the verdict is not yes (empty where it is): cannot tell (no rim point, or the centre out of
/// the wall), no patch, a patch that does not cover the opening (and a way out where the fill
/// found one too), or a way out past the patch. `wall_distances`: step 1's, per line.
std::string explain_verdict(const ClosureResult& result, const DefectFrame& defect, const FrameMesh& patch, const Cover& cover,
                            std::vector<double> wall_distances, const VerdictFigures& figures, bool has_patch, bool covers) {
    const bool centre_in_wall = 2 * figures.in_wall >= wall_distances.size();
    if (result.rim_points == 0) {
        std::ostringstream why;
        why.precision(3);
        why << "cannot tell: no rim point meets the wall (no tissue surface faces the patch's side " << figures.rim_radius
            << " mm from the axis within " << figures.reach << " mm of the defect's centre " << format_point(defect.centre)
            << "; is the centre in the opening?)";
        return why.str();
    }
    if (!centre_in_wall) {
        std::sort(wall_distances.begin(), wall_distances.end());
        std::ostringstream why;
        why.precision(3);
        why << "cannot tell: the defect's centre " << format_point(defect.centre) << " is not in the wall (" << figures.in_wall << " of "
            << wall_distances.size() << " lines along the axis " << figures.rim_radius << " mm from it meet the wall there; the median lies "
            << wall_distances[wall_distances.size() / 2] << " mm from it along the axis; is the centre in the opening?)";
        return why.str();
    }
    if (!has_patch) return "no patch covers the opening";
    if (!covers) {  // and, where the fill found a way out, that too
        // Where the patch lies: its vertices' mean, across the axis and along it.
        Vector3 middle = Vector3::Zero();
        for (const Vector3& p : patch.points) middle += p;
        middle /= double(patch.points.size());
        std::ostringstream why;
        why.precision(3);
        why << "the patch does not cover the opening: ";
        if (cover.covered == 0 && cover.anywhere == cover.samples)
            why << "it lies over it " << middle.z() << " mm from the wall's middle, beyond the wall's reach (" << figures.reach_low << " to "
                << figures.reach_high << " mm)";
        else if (cover.covered == 0)
            why << "it lies " << middle.head<2>().norm() << " mm from the defect's axis";
        else
            why << "it covers " << 100.0 * result.covered << " % of it within the wall's reach (" << figures.reach_low << " to "
                << figures.reach_high << " mm), its middle " << middle.head<2>().norm() << " mm from the defect's axis";
        if (!result.sealed) why << "; a way out of the opening passes it";
        return why.str();
    }
    if (!result.sealed) return "a way out of the opening passes the patch";
    return {};
}

/// Where the leak's way out passes the rim, in the defect's frame; none where it never does (it
/// goes through the patch). `grid`: the fill's flags with the way marked on_path. Per rim
/// sample's arc (`bins` of them): in each column of voxels at the rim's radius that starts in the
/// tissue, the free voxels just above the tissue, up to the patch (none where the patch lies on
/// the tissue), that are on the way, and their heights.
std::optional<Vector3> leak_past_rim(const Grid& grid, double rim_radius, int bins) {
    std::vector<std::size_t> columns(std::size_t(bins), 0), count(std::size_t(bins), 0);
    std::vector<double> height(std::size_t(bins), 0.0);
    for (long j = 1; j + 1 < grid.across.n; ++j)
        for (long i = 1; i + 1 < grid.across.n; ++i) {
            const double x = grid.across.centre(i), y = grid.across.centre(j);
            if (std::abs(std::hypot(x, y) - rim_radius) > 0.5 * grid.h) continue;
            const std::size_t bin = std::size_t(
                std::clamp(long(std::floor((std::atan2(y, x) + std::numbers::pi) / (2.0 * std::numbers::pi) * bins)), 0L, long(bins) - 1));
            ++columns[bin];
            auto flags = [&](long layer) { return grid.flags[grid.index(i, j, layer)]; };
            long k = 1;
            if (!(flags(k) & Grid::blocked) || (flags(k) & Grid::patch)) continue;  // not on the wall
            while (k + 1 < grid.along.n && (flags(k) & Grid::blocked) && !(flags(k) & Grid::patch)) ++k;  // the tissue
            for (; k + 1 < grid.along.n && (flags(k) & Grid::in_region) && !(flags(k) & Grid::blocked); ++k)
                if (flags(k) & Grid::on_path) ++count[bin], height[bin] += grid.along.centre(k);
        }
    // The way's height per arc (its voxels over the arc's columns). The widest arc, and the arcs
    // next to it the way passes as wide (within a voxel, and at least half as wide): the leak
    // passes the rim in their middle. Where that is the whole rim (the patch lifted evenly all
    // round), at the widest arc.
    std::vector<double> wide(std::size_t(bins), 0.0);
    for (std::size_t b = 0; b < wide.size(); ++b)
        if (columns[b] > 0) wide[b] = grid.h * double(count[b]) / double(columns[b]);
    const long widest = long(std::max_element(wide.begin(), wide.end()) - wide.begin());
    if (count[std::size_t(widest)] == 0) return std::nullopt;
    const double as_wide = std::max(wide[std::size_t(widest)] - grid.h, 0.5 * wide[std::size_t(widest)]);
    auto arc = [&](long b) { return std::size_t((b % bins + bins) % bins); };
    auto joins = [&](long b) { return count[arc(b)] > 0 && wide[arc(b)] >= as_wide; };
    long first = widest, last = widest;
    while (last - first + 1 < bins && joins(first - 1)) --first;
    while (last - first + 1 < bins && joins(last + 1)) ++last;
    if (last - first + 1 >= bins) first = last = widest;
    double sum = 0.0;
    std::size_t voxels = 0;
    for (long b = first; b <= last; ++b) sum += height[arc(b)], voxels += count[arc(b)];
    const double turn = -std::numbers::pi + (0.5 * double(first + last) + 0.5) * 2.0 * std::numbers::pi / bins;
    return Vector3(rim_radius * std::cos(turn), rim_radius * std::sin(turn), sum / double(voxels));
}

/// The stitches either side of the leak at `leak` (defect frame): the least turn from it to each,
/// one way ([0], turning back) and the other ([1], ahead).
std::array<std::size_t, 2> stitches_either_side(const Vector3& leak, const std::vector<Eigen::Vector3d>& stitches, const Eigen::Matrix3d& to_frame,
                                                const DefectFrame& defect) {
    const double at = std::atan2(leak.y(), leak.x());
    std::array<double, 2> least{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
    std::array<std::size_t, 2> between{};
    for (std::size_t s = 0; s < stitches.size(); ++s) {
        const Vector3 p = to_frame * (stitches[s] - defect.centre);
        const double turn = std::remainder(std::atan2(p.y(), p.x()) - at, 2.0 * std::numbers::pi);  // (−π, π]
        const double back = turn <= 0 ? -turn : 2.0 * std::numbers::pi - turn, ahead = turn > 0 ? turn : 2.0 * std::numbers::pi + turn;
        if (back < least[0]) least[0] = back, between[0] = s;
        if (ahead < least[1]) least[1] = ahead, between[1] = s;
    }
    return between;
}

}  // namespace

ClosureResult check_closure(const std::vector<std::array<float, 3>>& tissue_positions, const std::vector<Triangle>& tissue_triangles,
                            const std::vector<std::array<float, 3>>& patch_positions, const std::vector<Triangle>& patch_triangles,
                            double patch_thickness_mm, const DefectFrame& defect, const ClosureOptions& options) {
    const auto started = std::chrono::steady_clock::now();
    require_closure_inputs(tissue_positions, tissue_triangles, patch_positions, patch_triangles, patch_thickness_mm, defect, options);
    const bool has_patch = !patch_triangles.empty();
    const double thickness = has_patch ? patch_thickness_mm : 0.0;

    const Eigen::Matrix3d to_frame = defect_frame_rotation(defect);
    const FrameMesh tissue = in_defect_frame(to_frame, defect, tissue_positions, tissue_triangles);
    const FrameMesh patch = in_defect_frame(to_frame, defect, patch_positions, patch_triangles);

    ClosureResult result;
    const double radius = 0.5 * defect.diameter_mm;
    const double rim_radius = radius + options.rim_offset_mm;

    // 1. The wall's thickness.
    std::vector<double> wall_distances;
    const double wall = wall_thickness(tissue, rim_radius, radius + options.margin_mm, wall_distances);
    if (std::isnan(wall)) {
        std::ostringstream what;
        what << "no wall around the defect at " << format_point(defect.centre) << ": no line parallel to its axis " << rim_radius
             << " mm from it meets tissue within " << radius + options.margin_mm << " mm of the centre";
        throw InputError(what.str());
    }
    result.wall_thickness_mm = wall;

    // 2. The rim, rays from T/2 + margin down to the surface within `reach` of the centre.
    const double reach = radius + options.margin_mm + 0.5 * wall;
    const Rim rim = find_rim(tissue, patch, has_patch, thickness, rim_radius, reach, 0.5 * wall + options.margin_mm, options.rim_samples);
    result.rim_points = rim.points;
    result.largest_rim_gap_mm = has_patch && result.rim_points > 0 ? rim.largest_gap : defect.diameter_mm;

    // 3. The region: the cylinder ρ ≤ D/2 + margin from mid-wall (s = 0) to 2 mm above both the
    // patch where it lies on the rim (rim top + thickness) and the patch's highest point over the
    // cylinder (a patch domed into its side rises above the rim).
    const double cylinder = radius + options.margin_mm;
    const double patch_top = patch_top_over(patch, cylinder);
    const double surface = result.rim_points > 0 ? std::max(rim.top, 0.0) : 0.5 * wall;

    // Whether the patch covers the opening: its disc, seen along the axis, under the patch within
    // the wall's reach, from the wall's far face to the rim's radius above the highest rim point
    // (a patch held at the rim and domed by the pressure rises over the opening by less: a
    // hemisphere on the rim rises by its radius). A patch laid away from the opening (across the
    // axis, or along it beyond the wall) covers none of it.
    const double reach_low = -0.5 * wall, reach_high = surface + rim_radius + 0.5 * thickness;
    const Cover cover = cover_opening(patch, radius, std::min(options.voxel_mm, 0.05 * defect.diameter_mm), reach_low, reach_high);
    result.covered = cover.samples ? double(cover.covered) / double(cover.samples) : 0.0;
    const double top = std::max(surface + thickness, patch_top + 0.5 * thickness) + 2.0;
    result.top_mm = top;
    Grid grid(options.voxel_mm, cylinder, top);
    if (grid.voxels() > 2e8)
        throw OptionError("ClosureOptions::voxel_mm " + std::to_string(grid.h) + " makes a grid of " + std::to_string(grid.voxels()) +
                          " voxels around a cylinder " + std::to_string(2 * cylinder) + " mm across and " + std::to_string(top) +
                          " mm tall; use a coarser grid");
    result.voxels = mark_region(grid, cylinder, top);

    // 4. The tissue's and the patch's voxels. The patch's reach is widened by half a voxel's
    // diagonal so that no two free voxels meet face to face across it, however thin it is.
    block_tissue(grid, tissue, cylinder);
    if (has_patch) block_patch(grid, patch, 0.5 * thickness + 0.5 * std::numbers::sqrt3 * grid.h);

    // 5. Seeds: the opening at mid-wall (s below 1 mm, or one voxel where that is coarser; ρ within
    // the opening less a voxel). Targets: the region's top layer. The region starts at s = 0, so
    // a path around the septum through the far side's blood is not in it: the fill looks only for
    // a way out of the opening past the patch.
    std::vector<std::uint32_t> queue = seed_fill(grid, defect, std::max(1.0, grid.h), radius - grid.h, top, cylinder);
    grid.flood(queue, Grid::visited, [&](std::size_t at) { return grid.flags[at] == Grid::in_region; });  // not outside, blocked or visited
    result.reached = queue.size();
    std::vector<std::uint32_t> leak_path;
    for (const std::uint32_t at : queue)
        if (at_top(grid, at, top)) {
            grid.flags[at] |= Grid::on_path;
            leak_path.push_back(at);
        }

    // 6. The verdict. The centre must lie within the wall: on at least half the lines of step 1
    // the wall's interval holds s = 0. A centre moved into the blood on either side (beyond the
    // patch, say) seeds the fill where the opening is not, and the fill then says nothing about
    // the patch.
    result.sealed = leak_path.empty();
    const bool covers = has_patch && cover.covered == cover.samples;
    const auto in_wall = std::size_t(std::count(wall_distances.begin(), wall_distances.end(), 0.0));
    const bool centre_in_wall = 2 * in_wall >= wall_distances.size();
    result.cannot_tell = result.rim_points == 0 || !centre_in_wall;
    result.closed = result.sealed && covers && !result.cannot_tell;
    result.why = explain_verdict(result, defect, patch, cover, wall_distances,
                                 {.rim_radius = rim_radius, .reach = reach, .reach_low = reach_low, .reach_high = reach_high, .in_wall = in_wall},
                                 has_patch, covers);
    if (!result.sealed && !result.cannot_tell) {
        // The leak's way out past the rim: the reached voxels outside the rim's circle (less half a
        // voxel) that a fill back from the top reaches without coming inside it, so a pocket under
        // the patch sealed farther out is not on it.
        const double inside = rim_radius - 0.5 * grid.h;
        grid.flood(leak_path, Grid::on_path, [&](std::size_t at) {  // reached, not yet on the way, and outside
            if (grid.flags[at] != (Grid::in_region | Grid::visited)) return false;
            const Vector3 c = grid.centre(at);
            return std::hypot(c.x(), c.y()) >= inside;
        });
        Vector3 leak = Vector3::Zero();  // no patch: the opening itself
        if (has_patch) {
            if (const std::optional<Vector3> past_rim = leak_past_rim(grid, rim_radius, options.rim_samples)) {
                leak = *past_rim;
                result.leak_way = ClosureResult::LeakWay::rim;
            } else {  // the way out never passes the rim (through the patch): where it reaches the top
                result.leak_way = ClosureResult::LeakWay::through_patch;
                leak = grid.centre(leak_path.front());
            }
        }
        result.leak_mm = defect.centre + to_frame.transpose() * leak;
        if (result.leak_way == ClosureResult::LeakWay::rim && !options.stitches.empty())
            result.leak_between = stitches_either_side(leak, options.stitches, to_frame, defect);
    } else if (!result.closed && !result.cannot_tell && has_patch) {
        // Sealed but not covered: the opening leaks where the patch leaves it uncovered.
        const Vector2 middle = cover.uncovered_sum / double(cover.samples - cover.covered);
        result.leak_way = ClosureResult::LeakWay::uncovered;
        result.leak_mm = defect.centre + to_frame.transpose() * Vector3(middle.x(), middle.y(), 0.0);
    }

    result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
    return result;
}

double distance_from_axis(const DefectFrame& defect, const Eigen::Vector3d& point) {
    const Eigen::Vector3d d = point - defect.centre;
    return (d - d.dot(defect.axis) * defect.axis).norm();
}

ClosureOptions repair_closure_options(const DefectFrame& defect, double patch_reach_mm, const std::vector<Eigen::Vector3d>& stitches) {
    ClosureOptions options;
    if (patch_reach_mm > 0) options.margin_mm = std::max(options.margin_mm, patch_reach_mm + 3.0 - 0.5 * defect.diameter_mm);
    if (!stitches.empty()) {
        double rim = 0;
        for (const Eigen::Vector3d& stitch : stitches) rim += distance_from_axis(defect, stitch);
        options.rim_offset_mm = std::max(options.rim_offset_mm, rim / double(stitches.size()) - 0.5 * defect.diameter_mm);
        options.stitches = stitches;
    }
    return options;
}

std::string leak_place(const ClosureResult& result) {
    if (result.closed || !result.leak_mm) return {};
    if (result.leak_way == ClosureResult::LeakWay::no_patch) return "no patch covers the opening";
    if (result.leak_way == ClosureResult::LeakWay::uncovered) return "where the patch does not cover the opening";
    if (result.leak_way == ClosureResult::LeakWay::through_patch) return "through the patch";
    if (!result.leak_between) return "where no stitch holds the patch";
    const auto [clockwise, counter] = *result.leak_between;
    if (clockwise == counter) return "beside stitch " + std::to_string(clockwise + 1) + ", the only one";
    const auto [first, second] = std::minmax(clockwise, counter);
    return "between stitches " + std::to_string(first + 1) + " and " + std::to_string(second + 1);
}

}  // namespace heartsim
