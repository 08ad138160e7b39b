#include "libmodel/walls.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <set>

namespace heartsim {

namespace {

constexpr float infinity = std::numeric_limits<float>::infinity();

/// One line of the separable transform: d[p] = min over q of f[q] + h²·(p − q)², the lower
/// envelope of parabolas rooted where f is finite (Felzenszwalb & Huttenlocher 2012, "dt"), and
/// the feature of the minimising q. `root` and `bound` are scratch of n and n + 1 entries.
void transform_line(std::vector<float>& f, std::vector<std::int32_t>& feature, int n, double h2, std::vector<int>& root,
                    std::vector<double>& bound, std::vector<float>& d_out, std::vector<std::int32_t>& feature_out) {
    int k = -1;
    for (int q = 0; q < n; ++q) {
        if (!std::isfinite(f[std::size_t(q)])) continue;
        if (k < 0) {
            k = 0;
            root[0] = q;
            bound[0] = -std::numeric_limits<double>::infinity();
            bound[1] = std::numeric_limits<double>::infinity();
            continue;
        }
        const double fq = double(f[std::size_t(q)]) + h2 * double(q) * double(q);
        double s = 0.0;
        while (true) {  // bound[0] is −∞: the loop stops at k = 0 at the latest
            const int r = root[std::size_t(k)];
            s = (fq - (double(f[std::size_t(r)]) + h2 * double(r) * double(r))) / (2.0 * h2 * double(q - r));
            if (s <= bound[std::size_t(k)]) --k;
            else break;
        }
        ++k;
        root[std::size_t(k)] = q;
        bound[std::size_t(k)] = s;
        bound[std::size_t(k) + 1] = std::numeric_limits<double>::infinity();
    }
    if (k < 0) {
        std::fill(d_out.begin(), d_out.begin() + n, infinity);
        std::fill(feature_out.begin(), feature_out.begin() + n, -1);
        return;
    }
    int j = 0;
    for (int p = 0; p < n; ++p) {
        while (bound[std::size_t(j) + 1] < double(p)) ++j;
        const int r = root[std::size_t(j)];
        d_out[std::size_t(p)] = float(double(f[std::size_t(r)]) + h2 * double(p - r) * double(p - r));
        feature_out[std::size_t(p)] = feature[std::size_t(r)];
    }
}

/// One pass of the transform along `axis`, in place, parallel over the lines.
void transform_axis(const std::array<int, 3>& dims, int axis, double h, std::vector<float>& d, std::vector<std::int32_t>& nearest) {
    const int n = dims[std::size_t(axis)];
    const std::size_t stride = axis == 0 ? 1 : axis == 1 ? std::size_t(dims[0]) : std::size_t(dims[0]) * std::size_t(dims[1]);
    const int a = axis == 0 ? 1 : 0, b = axis == 2 ? 1 : 2;  // the other two axes
    const std::size_t lines = std::size_t(dims[std::size_t(a)]) * std::size_t(dims[std::size_t(b)]);
    const std::size_t stride_a = a == 0 ? 1 : std::size_t(dims[0]);
    const std::size_t stride_b = b == 1 ? std::size_t(dims[0]) : std::size_t(dims[0]) * std::size_t(dims[1]);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, lines), [&](const tbb::blocked_range<std::size_t>& range) {
        const std::size_t length = std::size_t(n);
        std::vector<float> f(length), out(length);
        std::vector<std::int32_t> feature(length), feature_out(length);
        std::vector<int> root(length);
        std::vector<double> bound(length + 1);
        for (std::size_t line = range.begin(); line != range.end(); ++line) {
            const std::size_t base = (line % std::size_t(dims[std::size_t(a)])) * stride_a + (line / std::size_t(dims[std::size_t(a)])) * stride_b;
            for (int p = 0; p < n; ++p) {
                f[std::size_t(p)] = d[base + std::size_t(p) * stride];
                feature[std::size_t(p)] = nearest[base + std::size_t(p) * stride];
            }
            transform_line(f, feature, n, h * h, root, bound, out, feature_out);
            for (int p = 0; p < n; ++p) {
                d[base + std::size_t(p) * stride] = out[std::size_t(p)];
                nearest[base + std::size_t(p) * stride] = feature_out[std::size_t(p)];
            }
        }
    });
}

/// A box of the volume: voxels low..high (inclusive) along each axis.
struct Box {
    std::array<int, 3> low{0, 0, 0}, high{-1, -1, -1};
    std::array<int, 3> dims() const { return {high[0] - low[0] + 1, high[1] - low[1] + 1, high[2] - low[2] + 1}; }
    std::size_t count() const {
        const auto d = dims();
        return std::size_t(d[0]) * std::size_t(d[1]) * std::size_t(d[2]);
    }
};

void check_structures(const LabelVolume& volume, const std::vector<WallStructure>& structures) {
    std::set<int> present(volume.labels.begin(), volume.labels.end()), wall_labels;
    for (const WallStructure& s : structures) {
        plausible::require(s.thickness_mm, plausible::wall_thickness_mm, "the wall thickness", "the " + s.name);
        if (s.wall_label == 0) throw InputError("the " + s.name + ": its grown voxels need a label other than 0 (background)");
        if (present.count(s.wall_label))
            throw InputError("the " + s.name + ": label " + std::to_string(s.wall_label) + " for its grown voxels already occurs in the label map");
        if (!wall_labels.insert(s.wall_label).second)
            throw InputError("the " + s.name + ": label " + std::to_string(s.wall_label) + " is given to two grown walls");
    }
}

/// The box around every structure's blood, widened by the thickest wall (and a voxel).
Box growth_box(const LabelVolume& volume, const std::vector<WallStructure>& structures, const std::vector<std::uint8_t>& is_blood,
               const std::vector<int>& blood_values) {
    const auto& g = volume.geometry;
    Box box{{g.dims[0], g.dims[1], g.dims[2]}, {-1, -1, -1}};
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                const std::int32_t label = volume.labels[g.linear(i, j, k)];
                const auto at = std::lower_bound(blood_values.begin(), blood_values.end(), label);
                if (at == blood_values.end() || *at != label || !is_blood[std::size_t(at - blood_values.begin())]) continue;
                const std::array<int, 3> v{i, j, k};
                for (int a = 0; a < 3; ++a) {
                    box.low[std::size_t(a)] = std::min(box.low[std::size_t(a)], v[std::size_t(a)]);
                    box.high[std::size_t(a)] = std::max(box.high[std::size_t(a)], v[std::size_t(a)]);
                }
            }
    if (box.high[0] < 0) return box;
    double thickest = 0.0;
    for (const WallStructure& s : structures) thickest = std::max(thickest, s.thickness_mm);
    for (int a = 0; a < 3; ++a) {
        const int margin = int(std::ceil(thickest / g.spacing[a])) + 1;
        box.low[std::size_t(a)] = std::max(0, box.low[std::size_t(a)] - margin);
        box.high[std::size_t(a)] = std::min(g.dims[std::size_t(a)] - 1, box.high[std::size_t(a)] + margin);
    }
    return box;
}

/// The faces of a structure's blood voxels (all inside `box`): towards background, and towards anything else.
void count_faces(const LabelVolume& volume, const Box& box, const std::vector<int>& blood, GrownWall& wall) {
    const auto& g = volume.geometry;
    auto is = [&](std::int32_t label) { return std::find(blood.begin(), blood.end(), label) != blood.end(); };
    for (int k = box.low[2]; k <= box.high[2]; ++k)
        for (int j = box.low[1]; j <= box.high[1]; ++j)
            for (int i = box.low[0]; i <= box.high[0]; ++i) {
                if (!is(volume.labels[g.linear(i, j, k)])) continue;
                const int step[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
                for (const auto& d : step) {
                    const int x = i + d[0], y = j + d[1], z = k + d[2];
                    if (!g.contains(x, y, z)) continue;
                    const std::int32_t other = volume.labels[g.linear(x, y, z)];
                    if (is(other)) continue;
                    ++wall.blood_faces;
                    if (other == 0) ++wall.faces_to_background;
                }
            }
}

}  // namespace

void feature_transform(const std::array<int, 3>& dims, const Eigen::Vector3d& spacing, const std::vector<std::uint8_t>& feature,
                       std::vector<float>& squared_distance, std::vector<std::int32_t>& nearest) {
    const std::size_t count = std::size_t(dims[0]) * std::size_t(dims[1]) * std::size_t(dims[2]);
    if (count > std::size_t(std::numeric_limits<std::int32_t>::max()))
        throw InputError("distance transform: " + std::to_string(count) + " voxels, more than 2^31 - 1");
    if (feature.size() != count) throw InputError("distance transform: the feature mask does not match the grid");
    squared_distance.assign(count, infinity);
    nearest.assign(count, -1);
    for (std::size_t v = 0; v < count; ++v)
        if (feature[v]) squared_distance[v] = 0.0f, nearest[v] = std::int32_t(v);
    for (int axis = 0; axis < 3; ++axis)
        if (dims[std::size_t(axis)] > 0) transform_axis(dims, axis, spacing[axis], squared_distance, nearest);
}

WallGrowthReport grow_walls(LabelVolume& volume, const std::vector<WallStructure>& structures, Progress& progress) {
    const auto start = std::chrono::steady_clock::now();
    check_structures(volume, structures);
    WallGrowthReport report;
    report.walls.resize(structures.size());
    ProgressStage stage(progress, "grow walls", structures.size() + 1);
    // Every blood label of every structure, sorted, for the box.
    std::vector<int> blood_values;
    for (const WallStructure& s : structures) blood_values.insert(blood_values.end(), s.blood_labels.begin(), s.blood_labels.end());
    std::sort(blood_values.begin(), blood_values.end());
    blood_values.erase(std::unique(blood_values.begin(), blood_values.end()), blood_values.end());
    const std::vector<std::uint8_t> all(blood_values.size(), 1);
    const Box box = growth_box(volume, structures, all, blood_values);
    if (box.high[0] < 0) return report;  // no blood of any structure
    for (std::size_t s = 0; s < structures.size(); ++s) count_faces(volume, box, structures[s].blood_labels, report.walls[s]);

    const auto& g = volume.geometry;
    const auto dims = box.dims();
    const std::size_t count = box.count();
    auto volume_index = [&](std::size_t v) {
        const std::size_t i = v % std::size_t(dims[0]), j = (v / std::size_t(dims[0])) % std::size_t(dims[1]),
                          k = v / (std::size_t(dims[0]) * std::size_t(dims[1]));
        return g.linear(int(i) + box.low[0], int(j) + box.low[1], int(k) + box.low[2]);
    };
    std::vector<std::int32_t> labels(count);  // the box's labels, copied once
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t v = range.begin(); v != range.end(); ++v) labels[v] = volume.labels[volume_index(v)];
    });
    std::vector<float> best(count, infinity);         // squared distance to the owner's nearest blood voxel, mm²
    std::vector<std::uint16_t> owner(count, 0xffff);  // structure claiming the voxel
    std::vector<std::uint8_t> feature(count);
    std::vector<float> squared;
    std::vector<std::int32_t> nearest;
    for (std::size_t s = 0; s < structures.size(); ++s) {
        stage.update(s);
        const auto& blood = structures[s].blood_labels;
        std::size_t found = 0;
        for (std::size_t v = 0; v < count; ++v) {
            feature[v] = std::find(blood.begin(), blood.end(), labels[v]) != blood.end();
            found += feature[v];
        }
        if (found == 0) continue;
        feature_transform(dims, g.spacing, feature, squared, nearest);
        // The blood's surface lies beyond its outermost voxel centres: half a voxel on a face
        // square to an axis, less on a curved or oblique one, where the nearest of many centres lies
        // close to it. A quarter of the mean spacing is that offset on average: with it, a ball's
        // grown shell has the volume of the closed form within about 4 % (tests/test_walls.cpp).
        const double reach = structures[s].thickness_mm + 0.25 * g.spacing.mean();
        const float reach2 = float(reach * reach);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count), [&](const tbb::blocked_range<std::size_t>& range) {
            for (std::size_t v = range.begin(); v != range.end(); ++v) {
                if (squared[v] > reach2 || squared[v] >= best[v] || labels[v] != 0) continue;
                best[v] = squared[v];
                owner[v] = std::uint16_t(s);
            }
        });
    }
    stage.update(structures.size());
    for (std::size_t v = 0; v < count; ++v) {
        if (owner[v] == 0xffff) continue;
        volume.labels[volume_index(v)] = structures[owner[v]].wall_label;
        ++report.walls[owner[v]].voxels;
    }
    for (GrownWall& wall : report.walls) wall.volume_mm3 = double(wall.voxels) * g.voxel_volume();
    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return report;
}

}  // namespace heartsim
