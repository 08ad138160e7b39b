/// @file simulation_surface.cpp
/// @brief The simulation surface: marching cubes on the dual grid of the particle lattice (a dual
/// cube's 8 corners are 8 neighbouring cell centres), each crossing edge snapped to its occupied
/// end, so every vertex is a particle. See docs/simulation-surface-and-mapping.md for the
/// construction, why the result is closed and oriented, and what happens at thin walls.
#include "libmodel/simulation_surface.h"

#include "libmodel/errors.h"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>

namespace heartsim {

namespace {

// Corner c of a dual cube sits at offset (c & 1, (c >> 1) & 1, (c >> 2) & 1) from its lowest cell.
constexpr std::array<std::array<int, 2>, 12> cube_edges{{
    {0, 1}, {2, 3}, {4, 5}, {6, 7},  // along x
    {0, 2}, {1, 3}, {4, 6}, {5, 7},  // along y
    {0, 4}, {1, 5}, {2, 6}, {3, 7},  // along z
}};
// Each face's corners in cyclic order.
constexpr std::array<std::array<int, 4>, 6> cube_faces{{
    {0, 2, 6, 4}, {1, 3, 7, 5},  // x = 0, x = 1
    {0, 1, 5, 4}, {2, 3, 7, 6},  // y = 0, y = 1
    {0, 1, 3, 2}, {4, 5, 7, 6},  // z = 0, z = 1
}};

Eigen::Vector3d corner_position(int c) { return Eigen::Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1); }

int edge_between(int a, int b) {
    for (int e = 0; e < 12; ++e)
        if ((cube_edges[std::size_t(e)][0] == a && cube_edges[std::size_t(e)][1] == b) ||
            (cube_edges[std::size_t(e)][0] == b && cube_edges[std::size_t(e)][1] == a))
            return e;
    return -1;
}

using CornerTriangle = std::array<std::uint8_t, 3>;

/// Minimum-total-diagonal-length triangulation of a cyclic polygon over cube corners (at most 8
/// distinct corners), ties broken by the first found: deterministic. Keeps the polygon's orientation.
void triangulate_cycle(std::vector<int> cycle, std::vector<CornerTriangle>& out) {
    // Start at the smallest corner, so that ties do not depend on where the loop was entered: the
    // two sides of a one-particle-thick sheet then split each square along the same diagonal, and
    // every triangle there has its exact reverse.
    std::rotate(cycle.begin(), std::min_element(cycle.begin(), cycle.end()), cycle.end());
    const int n = int(cycle.size());
    if (n < 3) return;
    if (n == 3) {
        out.push_back({std::uint8_t(cycle[0]), std::uint8_t(cycle[1]), std::uint8_t(cycle[2])});
        return;
    }
    auto length = [&](int i, int j) { return (corner_position(cycle[std::size_t(i)]) - corner_position(cycle[std::size_t(j)])).norm(); };
    std::vector<std::vector<double>> cost(std::size_t(n), std::vector<double>(std::size_t(n), 0.0));
    std::vector<std::vector<int>> split(std::size_t(n), std::vector<int>(std::size_t(n), -1));
    for (int gap = 2; gap < n; ++gap)
        for (int i = 0; i + gap < n; ++i) {
            const int j = i + gap;
            double best = std::numeric_limits<double>::infinity();
            for (int k = i + 1; k < j; ++k) {
                double c = cost[std::size_t(i)][std::size_t(k)] + cost[std::size_t(k)][std::size_t(j)];
                if (k - i > 1) c += length(i, k);
                if (j - k > 1) c += length(k, j);
                if (c < best - 1e-12) {
                    best = c;
                    split[std::size_t(i)][std::size_t(j)] = k;
                }
            }
            cost[std::size_t(i)][std::size_t(j)] = best;
        }
    std::vector<std::array<int, 2>> stack{{0, n - 1}};
    while (!stack.empty()) {
        const auto [i, j] = stack.back();
        stack.pop_back();
        if (j - i < 2) continue;
        const int k = split[std::size_t(i)][std::size_t(j)];
        out.push_back({std::uint8_t(cycle[std::size_t(i)]), std::uint8_t(cycle[std::size_t(k)]), std::uint8_t(cycle[std::size_t(j)])});
        stack.push_back({i, k});
        stack.push_back({k, j});
    }
}

/// Removes consecutive repeats (cyclically), then splits the cycle at any corner that still
/// repeats (a figure of eight) into simple cycles. The boundary chain is unchanged by both steps.
void simple_cycles(std::vector<int> cycle, std::vector<std::vector<int>>& out) {
    std::vector<int> collapsed;
    for (int c : cycle)
        if (collapsed.empty() || collapsed.back() != c) collapsed.push_back(c);
    while (collapsed.size() > 1 && collapsed.front() == collapsed.back()) collapsed.pop_back();
    for (std::size_t i = 0; i < collapsed.size(); ++i)
        for (std::size_t j = i + 1; j < collapsed.size(); ++j)
            if (collapsed[i] == collapsed[j]) {
                std::vector<int> inner(collapsed.begin() + std::ptrdiff_t(i), collapsed.begin() + std::ptrdiff_t(j));
                std::vector<int> outer(collapsed.begin(), collapsed.begin() + std::ptrdiff_t(i));
                outer.insert(outer.end(), collapsed.begin() + std::ptrdiff_t(j), collapsed.end());
                simple_cycles(inner, out);
                simple_cycles(outer, out);
                return;
            }
    if (collapsed.size() >= 3) out.push_back(collapsed);
}

/// Triangles (as corners) of one dual-cube configuration: marching-cubes loops traced face by
/// face (on a face with two diagonal occupied corners the occupied corners are joined, as the
/// edge springs join them), oriented towards the empty corners, snapped to occupied corners.
std::vector<CornerTriangle> cube_triangles(int configuration) {
    auto occupied = [&](int c) { return ((configuration >> c) & 1) != 0; };
    // Segments on faces between crossing edges; each crossing edge lies on two faces.
    std::array<std::vector<int>, 12> linked;
    for (const auto& face : cube_faces) {
        std::vector<int> crossing;
        for (int k = 0; k < 4; ++k) {
            const int a = face[std::size_t(k)], b = face[std::size_t((k + 1) % 4)];
            if (occupied(a) != occupied(b)) crossing.push_back(edge_between(a, b));
        }
        if (crossing.size() == 2) {
            linked[std::size_t(crossing[0])].push_back(crossing[1]);
            linked[std::size_t(crossing[1])].push_back(crossing[0]);
        } else if (crossing.size() == 4) {
            // Two empty corners on a diagonal: cut each off alone (occupied corners stay joined).
            for (int k = 0; k < 4; ++k) {
                const int corner = face[std::size_t(k)];
                if (occupied(corner)) continue;
                const int e0 = edge_between(face[std::size_t((k + 3) % 4)], corner);
                const int e1 = edge_between(corner, face[std::size_t((k + 1) % 4)]);
                linked[std::size_t(e0)].push_back(e1);
                linked[std::size_t(e1)].push_back(e0);
            }
        }
    }
    std::vector<CornerTriangle> triangles;
    std::array<bool, 12> visited{};
    for (int start = 0; start < 12; ++start) {
        if (linked[std::size_t(start)].empty() || visited[std::size_t(start)]) continue;
        std::vector<int> loop;
        int previous = -1, current = start;
        while (!visited[std::size_t(current)]) {
            visited[std::size_t(current)] = true;
            loop.push_back(current);
            const auto& next = linked[std::size_t(current)];
            const int chosen = next[0] != previous ? next[0] : next[1];
            previous = current;
            current = chosen;
        }
        // Orient: the loop's area vector (Newell) must point from occupied to empty corners.
        Eigen::Vector3d area = Eigen::Vector3d::Zero(), outward = Eigen::Vector3d::Zero();
        for (std::size_t k = 0; k < loop.size(); ++k) {
            const auto& e0 = cube_edges[std::size_t(loop[k])];
            const auto& e1 = cube_edges[std::size_t(loop[(k + 1) % loop.size()])];
            const Eigen::Vector3d p0 = 0.5 * (corner_position(e0[0]) + corner_position(e0[1]));
            const Eigen::Vector3d p1 = 0.5 * (corner_position(e1[0]) + corner_position(e1[1]));
            area += p0.cross(p1);
            const int in = occupied(e0[0]) ? e0[0] : e0[1], out = occupied(e0[0]) ? e0[1] : e0[0];
            outward += corner_position(out) - corner_position(in);
        }
        if (area.dot(outward) < 0) std::reverse(loop.begin(), loop.end());
        std::vector<int> snapped;
        for (int e : loop) snapped.push_back(occupied(cube_edges[std::size_t(e)][0]) ? cube_edges[std::size_t(e)][0] : cube_edges[std::size_t(e)][1]);
        std::vector<std::vector<int>> cycles;
        simple_cycles(snapped, cycles);
        for (const auto& cycle : cycles) triangulate_cycle(cycle, triangles);
    }
    return triangles;
}

const std::array<std::vector<CornerTriangle>, 256>& cube_table() {
    static const std::array<std::vector<CornerTriangle>, 256> table = [] {
        std::array<std::vector<CornerTriangle>, 256> t;
        for (int c = 0; c < 256; ++c) t[std::size_t(c)] = cube_triangles(c);
        return t;
    }();
    return table;
}

/// A triangle rotated so that its smallest index comes first (orientation kept).
std::array<std::int32_t, 3> canonical(std::array<std::int32_t, 3> t) {
    while (t[0] > t[1] || t[0] > t[2]) t = {t[1], t[2], t[0]};
    return t;
}

}  // namespace

std::vector<std::uint8_t> compute_normal_weights(const std::vector<std::array<std::int32_t, 3>>& triangles,
                                                 NormalWeightReport* report_out) {
    const std::size_t count = triangles.size();
    std::vector<std::uint8_t> weight(count, 1);
    NormalWeightReport report;

    // Twins: triangle t and its exact reverse. Paired only when the pairing is mutual (a surface
    // with repeated oriented triangles, which build_simulation_surface never makes, pairs once).
    std::vector<std::int32_t> twin(count, -1);
    {
        std::vector<std::pair<std::array<std::int32_t, 3>, std::int32_t>> keys(count);
        for (std::size_t t = 0; t < count; ++t) keys[t] = {canonical(triangles[t]), std::int32_t(t)};
        std::sort(keys.begin(), keys.end());
        for (std::size_t t = 0; t < count; ++t) {
            const auto& tri = triangles[t];
            const auto reverse = canonical({tri[0], tri[2], tri[1]});
            const auto it = std::lower_bound(keys.begin(), keys.end(), std::make_pair(reverse, std::int32_t(-1)));
            if (it != keys.end() && it->first == reverse && std::size_t(it->second) != t) twin[t] = it->second;
        }
        for (std::size_t t = 0; t < count; ++t)
            if (twin[t] >= 0 && twin[std::size_t(twin[t])] != std::int32_t(t)) twin[t] = -1;
        for (std::size_t t = 0; t < count; ++t)
            if (twin[t] >= 0 && twin[std::size_t(twin[t])] < 0) twin[t] = -1;
    }
    // Pairs, numbered in the order of their lower-index triangle (the pair's reference).
    std::vector<std::int32_t> pair_of(count, -1), reference;
    for (std::size_t t = 0; t < count; ++t)
        if (twin[t] > std::int32_t(t)) {
            pair_of[t] = pair_of[std::size_t(twin[t])] = std::int32_t(reference.size());
            reference.push_back(std::int32_t(t));
        }
    const std::size_t pairs = reference.size();
    report.sheet_pairs = pairs;
    if (pairs == 0) {
        if (report_out) *report_out = report;
        return weight;
    }

    // Undirected edges: (edge key, triangle, direction +1 when it runs from the lower to the
    // higher particle index), grouped by key.
    struct EdgeUse {
        std::uint64_t key;
        std::int32_t triangle;
        std::int8_t direction;
    };
    std::vector<EdgeUse> uses;
    uses.reserve(3 * count);
    for (std::size_t t = 0; t < count; ++t)
        for (int e = 0; e < 3; ++e) {
            const std::int32_t a = triangles[t][std::size_t(e)], b = triangles[t][std::size_t((e + 1) % 3)];
            const std::uint64_t lo = std::uint32_t(std::min(a, b)), hi = std::uint32_t(std::max(a, b));
            uses.push_back({(lo << 32) | hi, std::int32_t(t), std::int8_t(a < b ? 1 : -1)});
        }
    std::sort(uses.begin(), uses.end(), [](const EdgeUse& p, const EdgeUse& q) {
        return p.key != q.key ? p.key < q.key : p.triangle < q.triangle;
    });

    // σ_p = +1 keeps pair p's reference triangle, −1 its twin. Across an edge shared by exactly two
    // pairs and nothing else, the kept triangles must run opposite ways: with d the directions of
    // the references on the edge, d_p·σ_p = −d_q·σ_q, i.e. σ_q = −d_p·d_q·σ_p (a link of that
    // sign). Along an edge shared with thick triangles, each thick triangle A proposes a seed for
    // every pair there: d_p·σ_p = −d_A. Each pair remembers the proposal of lowest A.
    std::vector<std::vector<std::pair<std::int32_t, std::int8_t>>> links(pairs);
    std::vector<std::pair<std::int32_t, std::int8_t>> seed(pairs, {std::numeric_limits<std::int32_t>::max(), 0});
    std::vector<std::pair<std::int32_t, std::int8_t>> sheet;  // (pair, reference direction) on this edge
    for (std::size_t begin = 0; begin < uses.size();) {
        std::size_t end = begin;
        while (end < uses.size() && uses[end].key == uses[begin].key) ++end;
        sheet.clear();
        std::int32_t thick = -1;
        std::int8_t thick_direction = 0;
        for (std::size_t u = begin; u < end; ++u) {
            const std::int32_t t = uses[u].triangle, p = pair_of[std::size_t(t)];
            if (p < 0) {
                if (thick < 0) {  // sorted by triangle: the first is the lowest
                    thick = t;
                    thick_direction = uses[u].direction;
                }
            } else if (reference[std::size_t(p)] == t) {
                sheet.push_back({p, uses[u].direction});
            }
        }
        if (thick >= 0) {
            for (const auto& [p, d] : sheet)
                if (thick < seed[std::size_t(p)].first) seed[std::size_t(p)] = {thick, std::int8_t(-thick_direction * d)};
        } else if (sheet.size() == 2) {
            const auto [p, dp] = sheet[0];
            const auto [q, dq] = sheet[1];
            const std::int8_t sign = std::int8_t(-dp * dq);
            links[std::size_t(p)].push_back({q, sign});
            links[std::size_t(q)].push_back({p, sign});
        }
        begin = end;
    }
    for (auto& l : links) std::sort(l.begin(), l.end());

    // Regions: components of the link graph, in the order of their lowest pair. Each is seeded by
    // its proposal of lowest thick triangle (ties: lowest pair), else its lowest pair keeps its
    // reference; breadth-first from the seed.
    std::vector<std::int8_t> sigma(pairs, 0);
    std::vector<char> visited(pairs, 0);
    std::vector<std::int32_t> region, queue;
    for (std::size_t first = 0; first < pairs; ++first) {
        if (visited[first]) continue;
        region.clear();
        region.push_back(std::int32_t(first));
        visited[first] = 1;
        for (std::size_t r = 0; r < region.size(); ++r)
            for (const auto& [q, sign] : links[std::size_t(region[r])])
                if (!visited[std::size_t(q)]) {
                    visited[std::size_t(q)] = 1;
                    region.push_back(q);
                }
        ++report.sheet_regions;
        // `first` is the region's lowest pair (all lower ones belong to earlier regions).
        std::int32_t start = std::int32_t(first);
        std::int8_t start_sigma = 1;
        std::pair<std::int32_t, std::int32_t> best{std::numeric_limits<std::int32_t>::max(), 0};
        for (std::int32_t p : region)
            if (seed[std::size_t(p)].second != 0 && std::make_pair(seed[std::size_t(p)].first, p) < best) {
                best = {seed[std::size_t(p)].first, p};
                start = p;
                start_sigma = seed[std::size_t(p)].second;
            }
        if (best.first == std::numeric_limits<std::int32_t>::max()) ++report.sheet_regions_unseeded;
        queue.clear();
        queue.push_back(start);
        sigma[std::size_t(start)] = start_sigma;
        for (std::size_t r = 0; r < queue.size(); ++r) {
            const std::int32_t p = queue[r];
            for (const auto& [q, sign] : links[std::size_t(p)]) {
                const std::int8_t wanted = std::int8_t(sign * sigma[std::size_t(p)]);
                if (sigma[std::size_t(q)] == 0) {
                    sigma[std::size_t(q)] = wanted;
                    queue.push_back(q);
                } else if (sigma[std::size_t(q)] != wanted && p < q) {
                    ++report.sheet_orientation_conflicts;
                }
            }
        }
    }
    for (std::size_t p = 0; p < pairs; ++p) {
        const std::size_t kept = std::size_t(reference[p]), other = std::size_t(twin[kept]);
        weight[kept] = sigma[p] > 0 ? 1 : 0;
        weight[other] = sigma[p] > 0 ? 0 : 1;
    }
    if (report_out) *report_out = report;
    return weight;
}

SimulationSurface SimulationSurface::with_computed_weights(std::vector<std::array<std::int32_t, 3>> triangles) {
    SimulationSurface surface;
    surface.normal_weight = compute_normal_weights(triangles);
    surface.triangles = std::move(triangles);
    return surface;
}

SimulationSurface SimulationSurface::all_counted(std::vector<std::array<std::int32_t, 3>> triangles) {
    SimulationSurface surface;
    surface.normal_weight.assign(triangles.size(), 1);
    surface.triangles = std::move(triangles);
    return surface;
}

SimulationSurface build_simulation_surface(const Lattice& lattice, Progress& progress, SimulationSurfaceReport* report_out) {
    const auto& particles = lattice.particles;
    const std::size_t n = particles.size();
    if (n > std::size_t(std::numeric_limits<std::int32_t>::max()))
        throw InputError("simulation surface: too many particles");
    ProgressStage stage(progress, "simulation surface", 4);

    // Occupancy grid padded by one empty cell on every side: cell -> particle index, −1 if void.
    const std::array<int, 3> dims{lattice.dims[0] + 2, lattice.dims[1] + 2, lattice.dims[2] + 2};
    auto cell_of = [&](int i, int j, int k) { return (std::size_t(k) * std::size_t(dims[1]) + std::size_t(j)) * std::size_t(dims[0]) + std::size_t(i); };
    std::vector<std::int32_t> grid(std::size_t(dims[0]) * std::size_t(dims[1]) * std::size_t(dims[2]), -1);
    for (std::size_t p = 0; p < n; ++p) {
        const auto& ijk = particles.lattice_index[p];
        for (int a = 0; a < 3; ++a)
            if (ijk[std::size_t(a)] < 0 || ijk[std::size_t(a)] >= lattice.dims[std::size_t(a)])
                throw InputError("simulation surface: particle " + std::to_string(p) + " lies outside the lattice");
        std::int32_t& slot = grid[cell_of(ijk[0] + 1, ijk[1] + 1, ijk[2] + 1)];
        if (slot >= 0) throw InputError("simulation surface: two particles share lattice cell of particle " + std::to_string(p));
        slot = std::int32_t(p);
    }
    stage.update(1);
    if (progress.cancelled()) throw Cancelled();

    // Dual cubes, slab by slab (parallel), concatenated in slab order: deterministic.
    const auto& table = cube_table();
    const int slabs = dims[2] - 1;
    std::vector<std::vector<std::array<std::int32_t, 3>>> per_slab(std::size_t(std::max(slabs, 0)));
    tbb::parallel_for(0, slabs, [&](int k) {
        auto& out = per_slab[std::size_t(k)];
        for (int j = 0; j + 1 < dims[1]; ++j)
            for (int i = 0; i + 1 < dims[0]; ++i) {
                std::array<std::int32_t, 8> corner;
                int configuration = 0;
                for (int c = 0; c < 8; ++c) {
                    corner[std::size_t(c)] = grid[cell_of(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1))];
                    if (corner[std::size_t(c)] >= 0) configuration |= 1 << c;
                }
                if (configuration == 0 || configuration == 255) continue;
                for (const auto& t : table[std::size_t(configuration)])
                    out.push_back({corner[t[0]], corner[t[1]], corner[t[2]]});
            }
    });
    stage.update(2);
    if (progress.cancelled()) throw Cancelled();

    // A mirroring index-to-world matrix turns counter-clockwise into clockwise: flip back.
    const bool mirrored = lattice.index_to_world.topLeftCorner<3, 3>().determinant() < 0;
    std::vector<std::array<std::int32_t, 3>> triangles;
    for (auto& slab : per_slab)
        for (auto t : slab) triangles.push_back(mirrored ? std::array<std::int32_t, 3>{t[0], t[2], t[1]} : t);

    // The same oriented triangle cannot come from two cubes (see docs); drop repeats defensively.
    std::size_t duplicates = 0, thin_wall = 0;
    {
        std::vector<std::array<std::int32_t, 3>> keys(triangles.size());
        for (std::size_t t = 0; t < triangles.size(); ++t) keys[t] = canonical(triangles[t]);
        std::vector<std::size_t> order(triangles.size());
        for (std::size_t t = 0; t < order.size(); ++t) order[t] = t;
        std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return keys[a] < keys[b]; });
        std::vector<char> keep(triangles.size(), 1);
        for (std::size_t r = 1; r < order.size(); ++r)
            if (keys[order[r]] == keys[order[r - 1]]) {
                keep[order[r]] = 0;
                ++duplicates;
            }
        std::vector<std::array<std::int32_t, 3>> kept;
        kept.reserve(triangles.size());
        for (std::size_t t = 0; t < triangles.size(); ++t)
            if (keep[t]) kept.push_back(triangles[t]);
        triangles.swap(kept);
        // Thin walls: a triangle whose reverse is also present (both sides of a one-particle sheet).
        std::vector<std::array<std::int32_t, 3>> sorted;
        for (const auto& t : triangles) sorted.push_back(canonical(t));
        std::sort(sorted.begin(), sorted.end());
        for (const auto& t : sorted)
            if (std::binary_search(sorted.begin(), sorted.end(), canonical({t[0], t[2], t[1]}))) ++thin_wall;
    }
    stage.update(3);

    NormalWeightReport sheets;
    std::vector<std::uint8_t> weights = compute_normal_weights(triangles, &sheets);
    stage.update(4);

    if (report_out) {
        SimulationSurfaceReport report;
        report.triangles = triangles.size();
        TriangleMesh mesh;
        mesh.positions.resize(n, Eigen::Vector3d::Zero());
        for (std::size_t p = 0; p < n; ++p)
            mesh.positions[p] = Eigen::Vector3d(particles.rest_position[p][0], particles.rest_position[p][1], particles.rest_position[p][2]);
        mesh.triangles = triangles;
        const MeshReport check = analyse_mesh(mesh);
        report.boundary_particles = check.vertices;
        report.components = check.components;
        report.euler_characteristic = check.euler_characteristic;
        report.nonmanifold_edges = check.nonmanifold_edges;
        report.nonmanifold_vertices = check.nonmanifold_vertices;
        report.thin_wall_triangles = thin_wall;
        report.duplicate_triangles_removed = duplicates;
        report.sheet_regions = sheets.sheet_regions;
        report.sheet_regions_unseeded = sheets.sheet_regions_unseeded;
        report.sheet_orientation_conflicts = sheets.sheet_orientation_conflicts;
        if (triangles.empty())
            report.warnings.push_back("simulation surface is empty: no particle has a 2×2 patch of neighbours to span a triangle");
        // Non-manifold edges where the tissue is one particle thick are what a thin wall is on a
        // lattice; the summary counts them (SimulationSurfaceReport) and the mapping copes (its
        // normal weights). Nothing for the user to do: no warning.
        if (sheets.sheet_orientation_conflicts > 0)
            report.warnings.push_back(std::to_string(sheets.sheet_orientation_conflicts) +
                                      " places where a one-particle-thick sheet cannot be oriented consistently "
                                      "(a non-orientable sheet): particle normals turn over there");
        *report_out = std::move(report);
    }
    SimulationSurface surface;
    surface.triangles = std::move(triangles);
    surface.normal_weight = std::move(weights);
    return surface;
}

TriangleMesh simulation_surface_mesh(const std::vector<std::array<float, 3>>& positions,
                                     const std::vector<std::array<std::int32_t, 3>>& triangles) {
    TriangleMesh mesh;
    mesh.positions.reserve(positions.size());
    for (const auto& p : positions) mesh.positions.emplace_back(p[0], p[1], p[2]);
    for (const auto& t : triangles)
        for (int v : t)
            if (v < 0 || std::size_t(v) >= positions.size())
                throw InputError("simulation surface: triangle refers to particle " + std::to_string(v) + " of " +
                                 std::to_string(positions.size()));
    mesh.triangles = triangles;
    return mesh;
}

}  // namespace heartsim
