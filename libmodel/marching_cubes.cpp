/// @file marching_cubes.cpp
/// @brief Marching cubes on a binary mask with a case table built at start-up from one face rule,
/// so that neighbouring cells always agree and the surface is a closed, oriented 2-manifold.
#include "libmodel/errors.h"
#include "libmodel/surface.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <atomic>
#include <limits>
#include <stdexcept>

namespace heartsim {

namespace {

// Cube corner c sits at (c & 1, (c >> 1) & 1, (c >> 2) & 1) in cell units.
Eigen::Vector3d corner_position(int corner) {
    return Eigen::Vector3d(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
}

/// The 12 cube edges as (lower corner, axis): edges 0–3 run along x, 4–7 along y, 8–11 along z.
struct CubeEdge {
    int lower_corner;
    int axis;
};

constexpr std::array<CubeEdge, 12> cube_edges{{
    {0, 0}, {2, 0}, {4, 0}, {6, 0},
    {0, 1}, {1, 1}, {4, 1}, {5, 1},
    {0, 2}, {1, 2}, {2, 2}, {3, 2},
}};

int edge_between(int corner_a, int corner_b) {
    const int lower = std::min(corner_a, corner_b);
    const int axis_bit = corner_a ^ corner_b;
    const int axis = axis_bit == 1 ? 0 : (axis_bit == 2 ? 1 : 2);
    for (int e = 0; e < 12; ++e)
        if (cube_edges[std::size_t(e)].lower_corner == lower && cube_edges[std::size_t(e)].axis == axis) return e;
    throw std::logic_error("marching cubes: corners are not adjacent");
}

Eigen::Vector3d edge_midpoint(int edge) {
    const auto& e = cube_edges[std::size_t(edge)];
    return corner_position(e.lower_corner) + 0.5 * Eigen::Vector3d::Unit(e.axis);
}

/// Bit set of the two cube faces (face id = 2·axis + side) that contain `edge`.
unsigned faces_of_edge(int edge) {
    const auto& e = cube_edges[std::size_t(edge)];
    unsigned faces = 0;
    for (int axis = 0; axis < 3; ++axis)
        if (axis != e.axis) faces |= 1u << (2 * axis + ((e.lower_corner >> axis) & 1));
    return faces;
}

/// Triangles (as cube edge ids, counter-clockwise from outside the mask) for each of the 256
/// inside/outside corner patterns.
struct CaseTable {
    std::array<std::array<std::array<std::uint8_t, 3>, 12>, 256> triangles{};
    std::array<std::uint8_t, 256> triangle_count{};
};

/// Splits the loop `polygon` (cube edge ids, in boundary order) into triangles of the same
/// orientation, never using a diagonal between two edges of one cube face: such a diagonal would
/// lie in the face and could coincide with one from the neighbouring cell.
bool triangulate_loop(std::vector<int>& polygon, std::vector<std::array<int, 3>>& triangles) {
    const std::size_t n = polygon.size();
    if (n == 3) {
        triangles.push_back({polygon[0], polygon[1], polygon[2]});
        return true;
    }
    // Clipping the ear at position 1 first and repeatedly gives a fan from polygon[0].
    for (std::size_t offset = 1; offset <= n; ++offset) {
        const std::size_t ear = offset % n;
        const int previous = polygon[(ear + n - 1) % n], tip = polygon[ear], next = polygon[(ear + 1) % n];
        if (faces_of_edge(previous) & faces_of_edge(next)) continue;
        triangles.push_back({previous, tip, next});
        polygon.erase(polygon.begin() + std::ptrdiff_t(ear));
        if (triangulate_loop(polygon, triangles)) return true;
        polygon.insert(polygon.begin() + std::ptrdiff_t(ear), tip);
        triangles.pop_back();
    }
    return false;
}

CaseTable build_case_table() {
    CaseTable table;
    for (int pattern = 0; pattern < 256; ++pattern) {
        auto inside = [pattern](int corner) { return ((pattern >> corner) & 1) != 0; };
        std::array<int, 12> next_edge;
        next_edge.fill(-1);

        // Per face: connect the edge crossings into directed segments. A segment runs so that
        // face_normal × direction points to the outside corners, which makes the loops run
        // counter-clockwise seen from outside the mask.
        for (int axis = 0; axis < 3; ++axis) {
            for (int side = 0; side < 2; ++side) {
                const int u = (axis + 1) % 3, v = (axis + 2) % 3;
                const std::array<int, 4> ring{side << axis, (side << axis) | (1 << u),
                                              (side << axis) | (1 << u) | (1 << v), (side << axis) | (1 << v)};
                const Eigen::Vector3d face_normal = (2.0 * side - 1.0) * Eigen::Vector3d::Unit(axis);
                std::vector<int> crossings;
                for (int q = 0; q < 4; ++q)
                    if (inside(ring[std::size_t(q)]) != inside(ring[std::size_t((q + 1) % 4)]))
                        crossings.push_back(edge_between(ring[std::size_t(q)], ring[std::size_t((q + 1) % 4)]));

                auto add_segment = [&](int edge_a, int edge_b, const std::vector<int>& cut_off_corners) {
                    Eigen::Vector3d cut_off = Eigen::Vector3d::Zero(), rest = Eigen::Vector3d::Zero();
                    for (int corner : ring) {
                        const bool is_cut = std::find(cut_off_corners.begin(), cut_off_corners.end(), corner) !=
                                            cut_off_corners.end();
                        (is_cut ? cut_off : rest) += corner_position(corner);
                    }
                    cut_off /= double(cut_off_corners.size());
                    rest /= double(4 - cut_off_corners.size());
                    // cut_off holds inside corners here, so rest − cut_off points outwards.
                    const Eigen::Vector3d direction = edge_midpoint(edge_b) - edge_midpoint(edge_a);
                    if (face_normal.cross(direction).dot(rest - cut_off) < 0.0) std::swap(edge_a, edge_b);
                    if (next_edge[std::size_t(edge_a)] != -1) throw std::logic_error("marching cubes: edge used twice");
                    next_edge[std::size_t(edge_a)] = edge_b;
                };

                if (crossings.size() == 2) {
                    std::vector<int> inside_corners;
                    for (int corner : ring)
                        if (inside(corner)) inside_corners.push_back(corner);
                    add_segment(crossings[0], crossings[1], inside_corners);
                } else if (crossings.size() == 4) {
                    // Ambiguous face (diagonal corners alike): each inside corner is cut off on
                    // its own, so inside corners never connect across a face. The rule reads
                    // only this face's corners, so the cell on the other side agrees.
                    for (int q = 0; q < 4; ++q) {
                        const int corner = ring[std::size_t(q)];
                        if (!inside(corner)) continue;
                        add_segment(edge_between(ring[std::size_t((q + 3) % 4)], corner),
                                    edge_between(corner, ring[std::size_t((q + 1) % 4)]), {corner});
                    }
                }
            }
        }

        // Chain the segments into loops and triangulate each loop.
        std::vector<std::array<int, 3>> triangles;
        std::array<bool, 12> visited{};
        for (int start = 0; start < 12; ++start) {
            if (next_edge[std::size_t(start)] == -1 || visited[std::size_t(start)]) continue;
            std::vector<int> loop;
            for (int e = start; !visited[std::size_t(e)]; e = next_edge[std::size_t(e)]) {
                visited[std::size_t(e)] = true;
                loop.push_back(e);
                if (next_edge[std::size_t(e)] == -1) throw std::logic_error("marching cubes: open loop");
            }
            if (!triangulate_loop(loop, triangles)) throw std::logic_error("marching cubes: loop not triangulable");
        }
        if (triangles.size() > 12) throw std::logic_error("marching cubes: too many triangles in a cell");
        table.triangle_count[std::size_t(pattern)] = std::uint8_t(triangles.size());
        for (std::size_t t = 0; t < triangles.size(); ++t)
            for (int c = 0; c < 3; ++c)
                table.triangles[std::size_t(pattern)][t][std::size_t(c)] = std::uint8_t(triangles[t][std::size_t(c)]);
    }
    return table;
}

const CaseTable& case_table() {
    static const CaseTable table = build_case_table();
    return table;
}

/// The mask copied with one layer of zeros on every side: the surface then closes at the
/// volume border and the inner loops need no bounds checks.
struct PaddedMask {
    int size_x, size_y, size_z;
    std::vector<std::uint8_t> values;
    std::size_t linear(int i, int j, int k) const {
        return (std::size_t(k) * std::size_t(size_y) + std::size_t(j)) * std::size_t(size_x) + std::size_t(i);
    }
};

PaddedMask pad(const Mask& mask) {
    const auto& dims = mask.geometry.dims;
    PaddedMask padded{dims[0] + 2, dims[1] + 2, dims[2] + 2, {}};
    padded.values.assign(std::size_t(padded.size_x) * std::size_t(padded.size_y) * std::size_t(padded.size_z), 0);
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j) {
            const std::uint8_t* source = &mask.values[mask.geometry.linear(0, j, k)];
            std::uint8_t* target = &padded.values[padded.linear(1, j + 1, k + 1)];
            for (int i = 0; i < dims[0]; ++i) target[i] = source[i] != 0 ? 1 : 0;
        }
    return padded;
}

/// Vertex indices of the edge crossings of one z-plane of the padded grid (x- and y-edges) and
/// of the z-edges from that plane to the next; -1 where the edge does not cross.
struct PlaneIndices {
    std::vector<std::int32_t> x_edges, y_edges, z_edges;
};

/// Number of vertices owned by plane k: its x- and y-edge crossings, and its z-edge crossings
/// towards plane k + 1. Vertices are numbered plane by plane in this order, so the numbering is
/// the same for any thread count.
struct PlaneCounts {
    std::size_t xy = 0, z = 0;
};

/// Pass 1: per padded plane, the crossings (the surface's vertices) on its x and y edges and on
/// its z edges to the next plane. `finish_unit` is called once per slab.
template <class FinishUnit>
std::vector<PlaneCounts> count_plane_crossings(const PaddedMask& padded, const std::atomic<bool>& stop, FinishUnit&& finish_unit) {
    const int size_x = padded.size_x, size_y = padded.size_y, size_z = padded.size_z;
    const std::size_t plane_size = std::size_t(size_x) * std::size_t(size_y);
    const int slab_count = size_z - 1;
    std::vector<PlaneCounts> counts(static_cast<std::size_t>(size_z));
    tbb::parallel_for(0, size_z, [&](int k) {
        if (stop) return;
        PlaneCounts count;
        const std::uint8_t* plane = &padded.values[padded.linear(0, 0, k)];
        const std::uint8_t* above = k + 1 < size_z ? plane + plane_size : nullptr;
        for (int j = 0; j < size_y; ++j) {
            const std::uint8_t* row = plane + std::size_t(j) * std::size_t(size_x);
            for (int i = 0; i + 1 < size_x; ++i) count.xy += row[i] != row[i + 1];
            if (j + 1 < size_y)
                for (int i = 0; i < size_x; ++i) count.xy += row[i] != row[i + size_x];
            if (above)
                for (int i = 0; i < size_x; ++i) count.z += row[i] != row[i + plane_size];
        }
        counts[std::size_t(k)] = count;
        if (k < slab_count) finish_unit();
    });
    return counts;
}

/// The surface's vertices, one per crossed edge, numbered plane by plane: plane k's x/y crossings
/// in scan order from first_vertex[k], then its z crossings to plane k + 1.
struct VertexNumbering {
    const PaddedMask& padded;
    const std::vector<PlaneCounts>& counts;
    std::vector<std::size_t> first_vertex;  ///< per plane, and one past the last
    Eigen::Matrix3d index_to_world;
    Eigen::Vector3d world_of_padded_zero;
    std::vector<Eigen::Vector3d>& positions;  ///< written by index_plane (where asked) and index_slab

    /// Continuous padded index p maps to voxel index p − 1, then to the world.
    VertexNumbering(const PaddedMask& padded_mask, const std::vector<PlaneCounts>& plane_counts, const VolumeGeometry& geometry,
                    std::vector<Eigen::Vector3d>& vertex_positions)
        : padded(padded_mask), counts(plane_counts), index_to_world(geometry.direction * geometry.spacing.asDiagonal()),
          world_of_padded_zero(geometry.origin - index_to_world * Eigen::Vector3d::Ones()), positions(vertex_positions) {
        first_vertex.assign(counts.size() + 1, 0);
        for (std::size_t k = 0; k < counts.size(); ++k) first_vertex[k + 1] = first_vertex[k] + counts[k].xy + counts[k].z;
    }
    Eigen::Vector3d world(double i, double j, double k) const {
        return Eigen::Vector3d(world_of_padded_zero + index_to_world * Eigen::Vector3d(i, j, k));
    }
    /// Numbers plane k's x/y crossings in scan order; writes their positions only where
    /// `write_positions` (where the calling worker owns the plane).
    void index_plane(int k, std::vector<std::int32_t>& x_edges, std::vector<std::int32_t>& y_edges, bool write_positions) const {
        const int size_x = padded.size_x, size_y = padded.size_y;
        std::size_t next = first_vertex[std::size_t(k)];
        const std::uint8_t* plane = &padded.values[padded.linear(0, 0, k)];
        for (int j = 0; j < size_y; ++j) {
            const std::size_t row_start = std::size_t(j) * std::size_t(size_x);
            const std::uint8_t* row = plane + row_start;
            for (int i = 0; i < size_x; ++i) {
                std::int32_t x_index = -1, y_index = -1;
                if (i + 1 < size_x && row[i] != row[i + 1]) {
                    if (write_positions) positions[next] = world(i + 0.5, j, k);
                    x_index = std::int32_t(next++);
                }
                if (j + 1 < size_y && row[i] != row[i + size_x]) {
                    if (write_positions) positions[next] = world(i, j + 0.5, k);
                    y_index = std::int32_t(next++);
                }
                x_edges[row_start + std::size_t(i)] = x_index;
                y_edges[row_start + std::size_t(i)] = y_index;
            }
        }
    }
    /// Numbers and places plane k's crossings to plane k + 1.
    void index_slab(int k, std::vector<std::int32_t>& z_edges) const {
        const int size_x = padded.size_x;
        const std::size_t plane_size = std::size_t(size_x) * std::size_t(padded.size_y);
        std::size_t next = first_vertex[std::size_t(k)] + counts[std::size_t(k)].xy;
        const std::uint8_t* plane = &padded.values[padded.linear(0, 0, k)];
        for (std::size_t p = 0; p < plane_size; ++p) {
            std::int32_t index = -1;
            if (plane[p] != plane[p + plane_size]) {
                const int i = int(p % std::size_t(size_x)), j = int(p / std::size_t(size_x));
                positions[next] = world(i, j, k + 0.5);
                index = std::int32_t(next++);
            }
            z_edges[p] = index;
        }
    }
};

/// Appends the triangles of slab k (the cells between planes k and k + 1) to `triangles`, their
/// corners the vertex numbers of `lower` (plane k's edges and the slab's z edges) and `upper`
/// (plane k + 1's). `mirrored`: the volume's direction matrix mirrors, so each triangle turns.
void triangulate_slab(const PaddedMask& padded, const CaseTable& table, int k, const PlaneIndices& lower, const PlaneIndices& upper,
                      bool mirrored, std::vector<std::array<std::int32_t, 3>>& triangles) {
    const int size_x = padded.size_x, size_y = padded.size_y;
    const std::size_t plane_size = std::size_t(size_x) * std::size_t(size_y);
    // Spreads column bits (cy + 2·cz) to corner bits (cx + 2·cy + 4·cz) with cx = 0.
    constexpr std::array<std::uint8_t, 16> spread{0, 1, 4, 5, 16, 17, 20, 21, 64, 65, 68, 69, 80, 81, 84, 85};
    // Per cube edge: the index array and the offset from the cell's (i, j).
    std::array<const std::int32_t*, 12> edge_base;
    std::array<std::size_t, 12> edge_offset;
    for (int e = 0; e < 12; ++e) {
        const auto& edge = cube_edges[std::size_t(e)];
        const int cx = edge.lower_corner & 1, cy = (edge.lower_corner >> 1) & 1, cz = (edge.lower_corner >> 2) & 1;
        const PlaneIndices& plane = cz ? upper : lower;
        edge_base[std::size_t(e)] = edge.axis == 0 ? plane.x_edges.data() : edge.axis == 1 ? plane.y_edges.data() : lower.z_edges.data();
        edge_offset[std::size_t(e)] = std::size_t(cy) * std::size_t(size_x) + std::size_t(cx);
    }
    const std::uint8_t* plane = &padded.values[padded.linear(0, 0, k)];
    for (int j = 0; j + 1 < size_y; ++j) {
        const std::size_t row_start = std::size_t(j) * std::size_t(size_x);
        const std::uint8_t* row00 = plane + row_start;   // (y, z) offsets (0,0)
        const std::uint8_t* row10 = row00 + size_x;      // (1,0)
        const std::uint8_t* row01 = row00 + plane_size;  // (0,1)
        const std::uint8_t* row11 = row01 + size_x;      // (1,1)
        auto column = [&](int i) { return row00[i] | (row10[i] << 1) | (row01[i] << 2) | (row11[i] << 3); };
        int left = column(0);
        for (int i = 0; i + 1 < size_x; ++i) {
            const int right = column(i + 1);
            const int pattern = spread[std::size_t(left)] | (spread[std::size_t(right)] << 1);
            left = right;
            if (pattern == 0 || pattern == 255) continue;
            const std::size_t cell = row_start + std::size_t(i);
            const auto& cell_triangles = table.triangles[std::size_t(pattern)];
            for (int t = 0; t < table.triangle_count[std::size_t(pattern)]; ++t) {
                std::array<std::int32_t, 3> triangle;
                for (int c = 0; c < 3; ++c) {
                    const int e = cell_triangles[std::size_t(t)][std::size_t(c)];
                    triangle[std::size_t(c)] = edge_base[std::size_t(e)][cell + edge_offset[std::size_t(e)]];
                }
                // A mirroring direction matrix turns counter-clockwise into clockwise.
                if (mirrored) std::swap(triangle[1], triangle[2]);
                triangles.push_back(triangle);
            }
        }
    }
}

}  // namespace

TriangleMesh marching_cubes(const Mask& mask, Progress& progress) {
    const auto& geometry = mask.geometry;
    if (mask.values.size() != geometry.voxel_count())
        throw InputError("marching cubes: mask holds " + std::to_string(mask.values.size()) + " values, expected " +
                         std::to_string(geometry.voxel_count()));
    TriangleMesh mesh;
    if (geometry.voxel_count() == 0) return mesh;

    const CaseTable& table = case_table();
    const PaddedMask padded = pad(mask);
    const std::size_t plane_size = std::size_t(padded.size_x) * std::size_t(padded.size_y);
    const int slab_count = padded.size_z - 1;

    ProgressStage stage(progress, "marching cubes", std::uint64_t(2 * slab_count));
    std::atomic<std::uint64_t> work_done{0};
    std::atomic<bool> stop{false};
    auto finish_unit = [&] {
        stage.update(++work_done);
        if (progress.cancelled()) stop = true;
    };

    const std::vector<PlaneCounts> counts = count_plane_crossings(padded, stop, finish_unit);
    if (stop) throw Cancelled();
    const VertexNumbering numbering(padded, counts, geometry, mesh.positions);
    const std::size_t vertex_count = numbering.first_vertex.back();
    if (vertex_count > std::size_t(std::numeric_limits<std::int32_t>::max()))
        throw InputError("marching cubes: the surface has more vertices than 32-bit indices allow");
    mesh.positions.resize(vertex_count);

    // Pass 2: fixed chunks of slabs (independent of the thread count), each with its own
    // triangle list; concatenated in slab order, the result is the same for any thread count.
    constexpr int slabs_per_chunk = 4;
    const int chunk_count = (slab_count + slabs_per_chunk - 1) / slabs_per_chunk;
    std::vector<std::vector<std::array<std::int32_t, 3>>> chunk_triangles(static_cast<std::size_t>(chunk_count));
    const bool mirrored = geometry.direction.determinant() < 0.0;

    tbb::parallel_for(0, chunk_count, [&](int chunk) {
        const int first_slab = chunk * slabs_per_chunk;
        const int end_slab = std::min(slab_count, first_slab + slabs_per_chunk);
        PlaneIndices lower, upper;
        for (auto* indices : {&lower, &upper}) {
            indices->x_edges.resize(plane_size);
            indices->y_edges.resize(plane_size);
        }
        lower.z_edges.resize(plane_size);
        numbering.index_plane(first_slab, lower.x_edges, lower.y_edges, true);
        for (int k = first_slab; k < end_slab; ++k) {
            if (stop) return;
            numbering.index_slab(k, lower.z_edges);
            // Plane k + 1 belongs to the next chunk when k is this chunk's last slab.
            numbering.index_plane(k + 1, upper.x_edges, upper.y_edges, k + 1 < end_slab);
            triangulate_slab(padded, table, k, lower, upper, mirrored, chunk_triangles[std::size_t(chunk)]);
            std::swap(lower.x_edges, upper.x_edges);
            std::swap(lower.y_edges, upper.y_edges);
            finish_unit();
        }
    });
    if (stop) throw Cancelled();

    std::size_t triangle_count = 0;
    for (const auto& triangles : chunk_triangles) triangle_count += triangles.size();
    mesh.triangles.reserve(triangle_count);
    for (const auto& triangles : chunk_triangles) mesh.triangles.insert(mesh.triangles.end(), triangles.begin(), triangles.end());
    return mesh;
}

}  // namespace heartsim
