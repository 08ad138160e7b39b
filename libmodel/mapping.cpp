/// @file mapping.cpp
/// @brief The visual-mesh mapping (Mosegaard & Sørensen, EGVE 2005) with the formula of
/// SCENARIO.md solved exactly: for each visual vertex v, over candidate triangles (a,b,c) from an
/// AABB tree, Newton's method on F(λb, λc, d) = λa·x_a + λb·x_b + λc·x_c + d·m̂(λ) − v = 0
/// (λa = 1 − λb − λc, m = Σ λ·n), started from the closest point. Among exact solutions the one
/// with all weights in [0, 1] and the smallest |d| wins; else the least extrapolated. Particle
/// normals count only the triangles of normal weight 1 (one side of each thin-wall sheet).
/// One file because the per-vertex solve, the driver that falls back to lattice
/// embedding, and the runtime's evaluation of the result all share the Problem/Solution types and
/// the exact formula, which must not drift apart; the candidate search and the lattice embedding
/// live in mapping_candidates.cpp and mapping_embedding.cpp.
#include "libmodel/mapping.h"
#include "libmodel/triangle_point.h"

#include "libmodel/errors.h"
#include "libmodel/mapping_candidates.h"
#include "libmodel/mapping_embedding.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <iomanip>
#include <sstream>

namespace heartsim {

namespace {

using Vec3 = Eigen::Vector3d;

void check_surface(std::size_t particles, const SimulationSurface& surface) {
    const auto& triangles = surface.triangles;
    for (std::size_t t = 0; t < triangles.size(); ++t)
        for (int v : triangles[t])
            if (v < 0 || std::size_t(v) >= particles)
                throw InputError("mapping: simulation-surface triangle " + std::to_string(t) + " refers to particle " +
                                 std::to_string(v) + ", but there are " + std::to_string(particles));
    if (surface.normal_weight.size() != triangles.size())
        throw InputError("mapping: the simulation surface has " + std::to_string(surface.normal_weight.size()) +
                         " normal weights for " + std::to_string(triangles.size()) + " triangles");
    for (std::size_t t = 0; t < triangles.size(); ++t)
        if (surface.normal_weight[t] > 1)
            throw InputError("mapping: normal weight of simulation-surface triangle " + std::to_string(t) + " is " +
                             std::to_string(int(surface.normal_weight[t])) + ", not 0 or 1");
}

Eigen::Vector3f to_vector(const std::array<float, 3>& p) { return Eigen::Vector3f(p[0], p[1], p[2]); }

/// The formula in float32, in the order documented in mapping.h (the shader's order).
Eigen::Vector3f evaluate_float(const std::array<std::int32_t, 8>& carriers, const std::array<float, 8>& w,
                               const std::array<std::int32_t, 3>& t, const std::array<float, 3>& lambda, float d,
                               const std::vector<std::array<float, 3>>& x, const std::vector<Eigen::Vector3f>& n) {
    const Eigen::Vector3f& na = n[std::size_t(t[0])];
    const Eigen::Vector3f& nb = n[std::size_t(t[1])];
    const Eigen::Vector3f& nc = n[std::size_t(t[2])];
    Eigen::Vector3f p = Eigen::Vector3f::Zero(), m = Eigen::Vector3f::Zero();
    for (int k = 0; k < 3; ++k) {
        float sum = w[0] * x[std::size_t(carriers[0])][std::size_t(k)];
        for (std::size_t c = 1; c < 8; ++c) sum = sum + w[c] * x[std::size_t(carriers[c])][std::size_t(k)];
        p[k] = sum;
        m[k] = (lambda[0] * na[k] + lambda[1] * nb[k]) + lambda[2] * nc[k];
    }
    const float length = std::sqrt(m.dot(m));
    if (length > 0.0f)
        for (int k = 0; k < 3; ++k) p[k] += d * (m[k] / length);
    return p;
}

/// A tangent-space vertex's carriers: (a, b, c, a, a, a, a, a) with (λ, 0, …, 0).
void triangle_carriers(const std::array<std::int32_t, 3>& t, const std::array<float, 3>& lambda,
                       std::array<std::int32_t, 8>& particles, std::array<float, 8>& weights) {
    particles.fill(t[0]);
    weights.fill(0.0f);
    for (std::size_t k = 0; k < 3; ++k) {
        particles[k] = t[k];
        weights[k] = lambda[k];
    }
}

/// The closest point of triangle `tri` (over positions x) to v: its weights in `lambda`; returns
/// the distance.
double distance_to_triangle(const std::vector<Vec3>& x, const std::array<std::int32_t, 3>& tri, const Vec3& v, Vec3& lambda) {
    const Vec3 &a = x[std::size_t(tri[0])], &b = x[std::size_t(tri[1])], &c = x[std::size_t(tri[2])];
    lambda = closest_barycentric(v, a, b, c);
    return (lambda[0] * a + lambda[1] * b + lambda[2] * c - v).norm();
}

struct Solution {
    std::int32_t triangle = -1;
    Vec3 lambda{1, 0, 0};
    double offset = 0.0;
    double residual = std::numeric_limits<double>::infinity();
    /// How far the weights leave [0, 1]: max(0, −min λ, max λ − 1).
    double extrapolation = std::numeric_limits<double>::infinity();
    bool exact = false;
    bool unstable_normal = false;
};

/// Everything the per-vertex solve reads.
struct Problem {
    const std::vector<Vec3>& x;                        ///< particle positions, double
    const std::vector<Vec3>& n;                        ///< particle normals (the float ones, widened)
    const std::vector<char>& unstable;                 ///< particle normal nearly cancels
    const std::vector<std::array<std::int32_t, 3>>& triangles;
};

constexpr double accept_residual_mm = 1e-6;   // the contract's solve tolerance (double)
constexpr double target_residual_mm = 1e-10;  // what Newton aims for, to leave room for float32
constexpr double inside_tolerance = 1e-7;     // weights this far outside [0, 1] count as inside
constexpr double min_normal_length = 0.2;     // |Σ λ·n| below this: the normal field is unreliable

/// Residual and Jacobian of F(λb, λc, d) on triangle t.
struct Evaluation {
    Vec3 residual = Vec3::Zero();
    Eigen::Matrix3d jacobian = Eigen::Matrix3d::Zero();
    double normal_length = 0.0;
};

Evaluation evaluate(const Problem& problem, std::int32_t t, const Vec3& unknowns, const Vec3& v, bool with_jacobian = true) {
    const auto& tri = problem.triangles[std::size_t(t)];
    const Vec3& xa = problem.x[std::size_t(tri[0])];
    const Vec3 eb = problem.x[std::size_t(tri[1])] - xa, ec = problem.x[std::size_t(tri[2])] - xa;
    const Vec3& na = problem.n[std::size_t(tri[0])];
    const Vec3 fb = problem.n[std::size_t(tri[1])] - na, fc = problem.n[std::size_t(tri[2])] - na;
    const double lb = unknowns[0], lc = unknowns[1], d = unknowns[2];
    const Vec3 m = na + lb * fb + lc * fc;
    Evaluation e;
    e.normal_length = m.norm();
    if (!(e.normal_length > 0)) return e;
    const Vec3 unit = m / e.normal_length;
    e.residual = xa + lb * eb + lc * ec + d * unit - v;
    if (!with_jacobian) return e;
    const Eigen::Matrix3d projector = (Eigen::Matrix3d::Identity() - unit * unit.transpose()) / e.normal_length;
    e.jacobian.col(0) = eb + d * projector * fb;
    e.jacobian.col(1) = ec + d * projector * fc;
    e.jacobian.col(2) = unit;
    return e;
}

/// Solves J·x = b by Cramer's rule (cross products): cheaper than an LU for 3×3. False when J is
/// singular or the result is not finite.
bool solve3(const Eigen::Matrix3d& J, const Vec3& b, Vec3& x) {
    const Vec3 c0 = J.col(0), c1 = J.col(1), c2 = J.col(2);
    const Vec3 c12 = c1.cross(c2);
    const double det = c0.dot(c12);
    if (!(std::abs(det) > 1e-300)) return false;
    x = Vec3(b.dot(c12), c0.dot(b.cross(c2)), c0.dot(c1.cross(b))) / det;
    return x.allFinite();
}

/// Newton's method with backtracking from the closest point of triangle t.
Solution solve_on_triangle(const Problem& problem, std::int32_t t, const Vec3& v, const Vec3& start_lambda) {
    Solution s;
    s.triangle = t;
    const auto& tri = problem.triangles[std::size_t(t)];
    s.unstable_normal = problem.unstable[std::size_t(tri[0])] || problem.unstable[std::size_t(tri[1])] ||
                        problem.unstable[std::size_t(tri[2])];
    Vec3 u(start_lambda[1], start_lambda[2], 0.0);
    {
        const Vec3 p0 = start_lambda[0] * problem.x[std::size_t(tri[0])] + start_lambda[1] * problem.x[std::size_t(tri[1])] +
                        start_lambda[2] * problem.x[std::size_t(tri[2])];
        const Vec3 m = start_lambda[0] * problem.n[std::size_t(tri[0])] + start_lambda[1] * problem.n[std::size_t(tri[1])] +
                       start_lambda[2] * problem.n[std::size_t(tri[2])];
        if (!(m.norm() > 0)) return s;
        u[2] = (v - p0).dot(m.normalized());
    }
    Evaluation e = evaluate(problem, t, u, v);
    if (e.normal_length < min_normal_length) return s;
    double r = e.residual.norm();
    for (int iteration = 0; iteration < 40 && r > target_residual_mm; ++iteration) {
        Vec3 step;
        if (!solve3(e.jacobian, -e.residual, step)) break;
        double alpha = 1.0;
        bool improved = false;
        for (int halving = 0; halving < 12; ++halving, alpha *= 0.5) {
            const Vec3 trial = u + alpha * step;
            const Evaluation trial_e = evaluate(problem, t, trial, v, false);
            if (trial_e.normal_length < min_normal_length) continue;
            const double trial_r = trial_e.residual.norm();
            if (trial_r < r) {
                u = trial;
                e = evaluate(problem, t, trial, v);
                r = trial_r;
                improved = true;
                break;
            }
        }
        if (!improved) break;
        if (std::abs(u[0]) > 20 || std::abs(u[1]) > 20) break;  // diverging: far outside the triangle
    }
    s.lambda = Vec3(1.0 - u[0] - u[1], u[0], u[1]);
    s.offset = u[2];
    s.residual = r;
    s.exact = r < accept_residual_mm && e.normal_length >= min_normal_length;
    s.extrapolation = std::max({0.0, -s.lambda.minCoeff(), s.lambda.maxCoeff() - 1.0});
    return s;
}

/// Preference tiers of an exact solution, best first: 0 inside the triangle with stable normals;
/// 1 stable, weights at most `mild_extrapolation` outside [0, 1]; 2 inside but on a thin wall's
/// unstable normal; 3 stable, further out; 4 the rest.
constexpr double mild_extrapolation = 0.5;
int tier(const Solution& s) {
    const bool inside = s.extrapolation <= inside_tolerance;
    if (!s.unstable_normal) return inside ? 0 : (s.extrapolation <= mild_extrapolation ? 1 : 3);
    return inside ? 2 : 4;
}

/// Is `a` a better exact solution than `b`? The lower tier; within a tier the smallest |d|
/// (inside) or the least extrapolation (outside); ties to the lower triangle row.
bool better(const Solution& a, const Solution& b) {
    if (!b.exact) return a.exact;
    if (!a.exact) return false;
    const int ta = tier(a), tb = tier(b);
    if (ta != tb) return ta < tb;
    if (ta == 0 || ta == 2) {
        if (std::abs(a.offset) != std::abs(b.offset)) return std::abs(a.offset) < std::abs(b.offset);
    } else if (a.extrapolation != b.extrapolation) {
        return a.extrapolation < b.extrapolation;
    }
    return a.triangle < b.triangle;
}

struct Candidate {
    double distance;
    std::int32_t triangle;
    Vec3 lambda;
};

Solution solve_vertex(const Problem& problem, const mapping_internal::TriangleSearch& search, const Vec3& v,
                      double edge_length, std::vector<std::int32_t>& ids, std::vector<Candidate>& candidates,
                      std::size_t& solve_count) {
    const auto [closest_triangle, closest_point] = search.closest(v);
    const double closest_distance = (v - closest_point).norm();
    auto distance_to = [&](std::int32_t t, Vec3& lambda) { return distance_to_triangle(problem.x, problem.triangles[std::size_t(t)], v, lambda); };
    // Fast path: solve on the closest triangle first. An inside solution on any triangle lies |d|
    // from v, so if the closest triangle's solution is inside with stable normals, only triangles
    // nearer than its |d| can beat it: solve those (usually the closest triangle's neighbours
    // around its closest point), nearest first, and stop. The choice is the same as the full
    // search's below: the inside solution of smallest |d|, ties to the lower triangle row.
    Solution first;
    {
        Vec3 lambda0;
        distance_to(closest_triangle, lambda0);
        ++solve_count;
        first = solve_on_triangle(problem, closest_triangle, v, lambda0);
        if (first.exact && tier(first) == 0) {
            Solution best = first;
            const double reach = std::abs(best.offset);
            ids.clear();
            search.near(v, reach, ids);
            candidates.clear();
            for (std::int32_t t : ids) {
                if (t == closest_triangle) continue;
                Vec3 lambda;
                const double distance = distance_to(t, lambda);
                if (distance <= reach) candidates.push_back({distance, t, lambda});
            }
            std::sort(candidates.begin(), candidates.end(), [](const Candidate& p, const Candidate& q) {
                return p.distance != q.distance ? p.distance < q.distance : p.triangle < q.triangle;
            });
            for (const Candidate& candidate : candidates) {
                if (candidate.distance > std::abs(best.offset)) break;
                ++solve_count;
                const Solution s = solve_on_triangle(problem, candidate.triangle, v, candidate.lambda);
                if (better(s, best)) best = s;
            }
            return best;
        }
    }
    // Search radii: first the closest distance plus half an edge; then, without a stable inside
    // solution, up to two edges more (an inside solution's triangle lies within |d| of v, so a
    // stable inside |d| beyond the radius widens it to |d|). At most `max_solves` Newton solves.
    const double widest = closest_distance + 2.0 * edge_length;
    double radius = closest_distance + 0.5 * edge_length;
    constexpr int max_solves = 64;
    int solves = 0;
    // Otherwise the search by rounds, the closest triangle's solution already in hand.
    Solution best = first;
    double searched = -1.0;  // candidates with distance <= searched have been solved
    for (int round = 0; round < 3 && solves < max_solves; ++round) {
        ids.clear();
        search.near(v, radius, ids);
        candidates.clear();
        for (std::int32_t t : ids) {
            Vec3 lambda;
            const double distance = distance_to(t, lambda);
            if (distance > radius || distance <= searched || t == closest_triangle) continue;
            candidates.push_back({distance, t, lambda});
        }
        std::sort(candidates.begin(), candidates.end(), [](const Candidate& p, const Candidate& q) {
            return p.distance != q.distance ? p.distance < q.distance : p.triangle < q.triangle;
        });
        for (const Candidate& candidate : candidates) {
            // An inside solution on a triangle lies |d| from v, so a triangle farther than the best
            // stable inside |d| cannot beat it.
            if (best.exact && tier(best) == 0 && candidate.distance > std::abs(best.offset)) break;
            if (solves++ >= max_solves) break;
            ++solve_count;
            const Solution s = solve_on_triangle(problem, candidate.triangle, v, candidate.lambda);
            if (better(s, best)) best = s;
        }
        searched = radius;
        if (best.exact && tier(best) == 0) {
            if (std::abs(best.offset) <= radius) break;
            radius = std::abs(best.offset) * (1 + 1e-9) + 1e-9;
        } else {
            // A stable solution at most mildly extrapolated among the triangles nearest v: take
            // it rather than search two edges out for an inside one farther away (at thin walls'
            // free rims, where the visual surface wraps around the sheet's edge, no inside
            // solution exists and the wide search only costs time).
            if (best.exact && tier(best) == 1) break;
            if (radius >= widest) break;
            radius = widest;
        }
    }
    if (!best.exact) {
        // Nothing exact nearby (a thin wall's cancelled normals all round, or visual surface with
        // no particles under it): wider searches, 6 to 48 edges, up to 512 more solves each.
        for (double edges = 6.0; edges <= 48.0 && !best.exact; edges *= 2.0) {
        const double wide = closest_distance + edges * edge_length;
        ids.clear();
        search.near(v, wide, ids);
        candidates.clear();
        for (std::int32_t t : ids) {
            Vec3 lambda;
            const double distance = distance_to(t, lambda);
            if (distance > searched && distance <= wide) candidates.push_back({distance, t, lambda});
        }
        std::sort(candidates.begin(), candidates.end(), [](const Candidate& p, const Candidate& q) {
            return p.distance != q.distance ? p.distance < q.distance : p.triangle < q.triangle;
        });
        if (candidates.size() > 512) candidates.resize(512);
        for (const Candidate& candidate : candidates) {
            ++solve_count;
            const Solution s = solve_on_triangle(problem, candidate.triangle, v, candidate.lambda);
            if (better(s, best)) best = s;
        }
        searched = wide;
        }
    }
    if (!best.exact) {
        // No exact solution anywhere near: the closest-point projection (reported, not exact).
        const auto& tri = problem.triangles[std::size_t(closest_triangle)];
        best = Solution{};
        best.triangle = closest_triangle;
        best.lambda = closest_barycentric(v, problem.x[std::size_t(tri[0])], problem.x[std::size_t(tri[1])],
                                          problem.x[std::size_t(tri[2])]);
        const Vec3 m = best.lambda[0] * problem.n[std::size_t(tri[0])] + best.lambda[1] * problem.n[std::size_t(tri[1])] +
                       best.lambda[2] * problem.n[std::size_t(tri[2])];
        best.offset = m.norm() > 0 ? (v - closest_point).dot(m.normalized()) : 0.0;
        best.extrapolation = 0.0;
        best.exact = false;
    }
    return best;
}

}  // namespace

std::vector<Eigen::Vector3f> particle_normals(const std::vector<std::array<float, 3>>& positions,
                                              const SimulationSurface& surface) {
    check_surface(positions.size(), surface);
    std::vector<Eigen::Vector3f> normals(positions.size(), Eigen::Vector3f::Zero());
    for (std::size_t row = 0; row < surface.triangles.size(); ++row) {
        if (!surface.normal_weight[row]) continue;
        const auto& t = surface.triangles[row];
        const Eigen::Vector3f a = to_vector(positions[std::size_t(t[0])]);
        const Eigen::Vector3f area = (to_vector(positions[std::size_t(t[1])]) - a).cross(to_vector(positions[std::size_t(t[2])]) - a);
        for (int v : t) normals[std::size_t(v)] += area;
    }
    for (auto& n : normals) {
        const float length = std::sqrt(n.dot(n));
        n = length > 0.0f ? Eigen::Vector3f(n / length) : Eigen::Vector3f::Zero();
    }
    return normals;
}

MappingMethod parse_mapping_method(const std::string& text) {
    if (text == "auto") return MappingMethod::automatic;
    if (text == "tangent") return MappingMethod::tangent;
    throw InputError("{MappingOptions::method} must be auto or tangent, got '" + text + "'");
}

void mapping_carriers(const VisualMapping& mapping, const SimulationSurface& surface, std::size_t v,
                      std::array<std::int32_t, 8>& particles, std::array<float, 8>& weights) {
    if (!mapping.particles.empty()) {
        particles = mapping.particles[v];
        weights = mapping.weights[v];
    } else {
        triangle_carriers(surface.triangles[std::size_t(mapping.triangle[v])], mapping.barycentric[v], particles, weights);
    }
}

std::vector<Eigen::Vector3f> apply_mapping(const VisualMapping& mapping, const std::vector<std::array<float, 3>>& positions,
                                           const SimulationSurface& surface) {
    const auto& triangles = surface.triangles;
    const std::size_t count = mapping.triangle.size();
    if (mapping.barycentric.size() != count || mapping.offset.size() != count)
        throw InputError("mapping: triangle, barycentric and offset must have one entry per visual vertex");
    if (mapping.particles.size() != mapping.weights.size() || (!mapping.particles.empty() && mapping.particles.size() != count))
        throw InputError("mapping: particles and weights must both be empty or have one row per visual vertex");
    for (std::size_t v = 0; v < count; ++v) {
        if (mapping.triangle[v] < 0 || std::size_t(mapping.triangle[v]) >= triangles.size())
            throw InputError("mapping: vertex " + std::to_string(v) + " refers to triangle " +
                             std::to_string(mapping.triangle[v]) + " of " + std::to_string(triangles.size()));
        if (!mapping.particles.empty())
            for (std::int32_t p : mapping.particles[v])
                if (p < 0 || std::size_t(p) >= positions.size())
                    throw InputError("mapping: vertex " + std::to_string(v) + " is carried by particle " + std::to_string(p) +
                                     " of " + std::to_string(positions.size()));
    }
    const std::vector<Eigen::Vector3f> normals = particle_normals(positions, surface);
    std::vector<Eigen::Vector3f> out(count);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 1024), [&](const tbb::blocked_range<std::size_t>& range) {
        std::array<std::int32_t, 8> carriers;
        std::array<float, 8> weights;
        for (std::size_t v = range.begin(); v < range.end(); ++v) {
            mapping_carriers(mapping, surface, v, carriers, weights);
            out[v] = evaluate_float(carriers, weights, triangles[std::size_t(mapping.triangle[v])], mapping.barycentric[v],
                                    mapping.offset[v], positions, normals);
        }
    });
    return out;
}

namespace {

/// The input checks of map_visual_mesh (mapping.h says what each throws).
void require_mapping_inputs(const std::vector<Eigen::Vector3d>& visual_positions, const std::vector<std::array<float, 3>>& rest_positions,
                            const SimulationSurface& surface) {
    if (visual_positions.empty()) throw InputError("mapping: the visual mesh has no vertices");
    if (surface.triangles.empty()) throw InputError("mapping: the simulation surface has no triangles");
    check_surface(rest_positions.size(), surface);
    for (std::size_t v = 0; v < visual_positions.size(); ++v)
        if (!visual_positions[v].allFinite())
            throw InputError("mapping: visual vertex " + std::to_string(v) + " is not finite");
    for (const auto& p : rest_positions)
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
            throw InputError("mapping: a particle rest position is not finite");
}

/// What the solves need to know of the simulation surface's counted triangles (normal weight 1).
struct CountedSurface {
    /// Per particle: a normal whose summed (counted) area vectors nearly cancel (|Σ c| < 0.3 Σ|c|)
    /// has an ill-defined direction: avoid triangles that use it. The normal weights remove this
    /// at sheets with exact twins; it remains at thin walls whose two sides are triangulated
    /// differently (staircase or diagonal walls) and at sharp folds.
    std::vector<char> unstable;
    /// Per particle: the normal's sensitivity P_j/|S_j| (mapping.h, MappingReport::amplification):
    /// moving the particles by at most δ turns n_j by at most δ·P_j/|S_j|.
    std::vector<double> sensitivity;
    std::vector<std::int32_t> rows;  ///< the counted triangles' rows: a twin adds nothing new
    double edge_length = 0.0;        ///< their mean edge length, mm
};

/// The counted triangles of `surface` over the particles at `x`; throws InputError where none counts.
CountedSurface counted_surface(const std::vector<Vec3>& x, const SimulationSurface& surface) {
    const std::size_t particle_count = x.size();
    const auto& triangles = surface.triangles;
    CountedSurface counted;
    counted.unstable.assign(particle_count, 0);
    counted.sensitivity.assign(particle_count, std::numeric_limits<double>::infinity());
    double edge_sum = 0.0;
    std::vector<Vec3> sum(particle_count, Vec3::Zero());
    std::vector<double> magnitude(particle_count, 0.0), perimeter(particle_count, 0.0);
    for (std::size_t row = 0; row < triangles.size(); ++row) {
        if (!surface.normal_weight[row]) continue;
        counted.rows.push_back(std::int32_t(row));
        const auto& t = triangles[row];
        const Vec3 c = (x[std::size_t(t[1])] - x[std::size_t(t[0])]).cross(x[std::size_t(t[2])] - x[std::size_t(t[0])]);
        const double edges = (x[std::size_t(t[1])] - x[std::size_t(t[0])]).norm() +
                             (x[std::size_t(t[2])] - x[std::size_t(t[1])]).norm() + (x[std::size_t(t[0])] - x[std::size_t(t[2])]).norm();
        for (int v : t) {
            sum[std::size_t(v)] += c;
            magnitude[std::size_t(v)] += c.norm();
            perimeter[std::size_t(v)] += edges;
        }
        edge_sum += edges;
    }
    for (std::size_t i = 0; i < particle_count; ++i) {
        counted.unstable[i] = magnitude[i] > 0 && sum[i].norm() < 0.3 * magnitude[i];
        if (sum[i].norm() > 0) counted.sensitivity[i] = perimeter[i] / sum[i].norm();
    }
    if (counted.rows.empty()) throw InputError("mapping: no simulation-surface triangle counts in the particle normals");
    counted.edge_length = edge_sum / (3.0 * double(counted.rows.size()));
    return counted;
}

/// The tangent-space sensitivity bound of a solution (MappingReport::amplification).
double tangent_amplification(const Solution& s, const Problem& problem, const std::vector<double>& sensitivity) {
    if (!s.exact) return std::numeric_limits<double>::infinity();
    const auto& tri = problem.triangles[std::size_t(s.triangle)];
    double a = s.lambda.cwiseAbs().sum();
    if (s.offset == 0.0) return a;
    Vec3 m = Vec3::Zero();
    double turn = 0.0;
    for (int k = 0; k < 3; ++k) {
        m += s.lambda[k] * problem.n[std::size_t(tri[std::size_t(k)])];
        if (s.lambda[k] != 0.0) turn += std::abs(s.lambda[k]) * sensitivity[std::size_t(tri[std::size_t(k)])];
    }
    return m.norm() > 0 ? a + std::abs(s.offset) / m.norm() * turn : std::numeric_limits<double>::infinity();
}

bool unstable_triangle(const Problem& problem, std::int32_t t) {
    const auto& tri = problem.triangles[std::size_t(t)];
    return problem.unstable[std::size_t(tri[0])] || problem.unstable[std::size_t(tri[1])] || problem.unstable[std::size_t(tri[2])];
}

/// An embedded vertex's normal frame (for shading only): the closest point of the nearest
/// surface triangle whose particle normals are stable (a frame on normals that nearly cancel
/// would turn the shading at random), else the closest. `ids`: scratch.
Solution embedded_frame(const Problem& problem, const mapping_internal::TriangleSearch& search, const Vec3& p, double edge_length,
                        std::vector<std::int32_t>& ids) {
    const auto [row, point] = search.closest(p);
    std::int32_t frame = row;
    Vec3 frame_lambda;
    distance_to_triangle(problem.x, problem.triangles[std::size_t(row)], p, frame_lambda);
    if (unstable_triangle(problem, row)) {
        double nearest = std::numeric_limits<double>::infinity();
        ids.clear();
        search.near(p, (p - point).norm() + edge_length, ids);
        for (std::int32_t t : ids) {
            if (unstable_triangle(problem, t)) continue;
            Vec3 lambda;
            const double distance = distance_to_triangle(problem.x, problem.triangles[std::size_t(t)], p, lambda);
            if (distance < nearest || (distance == nearest && t < frame)) nearest = distance, frame = t, frame_lambda = lambda;
        }
    }
    Solution s{};
    s.triangle = frame;
    s.lambda = frame_lambda;
    s.offset = 0.0;
    s.exact = true;
    return s;
}

/// Each visual vertex's solution, in double: embedded in a lattice cell or mapped in tangent space.
struct VertexSolutions {
    std::vector<Solution> solutions;  ///< the tangent-space solution, or an embedded vertex's normal frame
    std::vector<mapping_internal::Embedding> embeddings;  ///< count > 0: the vertex is embedded
    std::vector<double> amplification;                    ///< the sensitivity bound of the kind chosen
    std::size_t solves = 0;                               ///< Newton solves over all vertices
};

/// Solves every visual vertex, in parallel: embedded where `embedder` (none: tangent space only)
/// embeds it well or better conditioned than the tangent-space solution. Each vertex is solved
/// independently of the others: deterministic for any thread count.
VertexSolutions solve_vertices(const std::vector<Eigen::Vector3d>& visual_positions, const Problem& problem,
                               const mapping_internal::TriangleSearch& search, const CountedSurface& counted,
                               const mapping_internal::CellEmbedder* embedder, const MappingOptions& options, Progress& progress) {
    const std::size_t count = visual_positions.size();
    VertexSolutions solved;
    solved.solutions.resize(count);
    solved.embeddings.resize(count);
    solved.amplification.assign(count, 0.0);
    std::atomic<std::size_t> solve_total{0};
    ProgressStage stage(progress, "map visual mesh", count);
    std::atomic<std::uint64_t> done{0};
    constexpr std::size_t chunk = 256;
    const std::size_t chunks = (count + chunk - 1) / chunk;
    tbb::parallel_for(std::size_t(0), chunks, [&](std::size_t c) {
        if (progress.cancelled()) throw Cancelled();
        std::vector<std::int32_t> ids;
        std::vector<Candidate> candidates;
        std::size_t local_solves = 0;
        const std::size_t end = std::min(count, (c + 1) * chunk);
        for (std::size_t v = c * chunk; v < end; ++v) {
            const Vec3& p = visual_positions[v];
            mapping_internal::Embedding e;
            if (embedder) e = embedder->embed(p);
            auto embed = [&] {
                solved.solutions[v] = embedded_frame(problem, search, p, counted.edge_length, ids);
                solved.embeddings[v] = e;
                solved.amplification[v] = e.amplification;
            };
            if (e.found() && e.amplification <= options.embed_below_amplification) {
                // A well-conditioned embedding: it follows every affine motion exactly, which
                // a tangent-space offset does not (a stretch leaves d unscaled).
                embed();
                continue;
            }
            solved.solutions[v] = solve_vertex(problem, search, p, counted.edge_length, ids, candidates, local_solves);
            solved.amplification[v] = tangent_amplification(solved.solutions[v], problem, counted.sensitivity);
            if (e.found() && e.amplification <= solved.amplification[v]) embed();  // the better conditioned
        }
        solve_total += local_solves;
        stage.update(done += end - c * chunk);
    });
    solved.solves = solve_total.load();
    return solved;
}

/// Barycentric weights in float32, λa from the other two, so the stored weights sum to 1 as
/// closely as float allows.
std::array<float, 3> round_barycentric(const Vec3& lambda) {
    const float lb = float(lambda[1]), lc = float(lambda[2]);
    return std::array<float, 3>{float(1.0 - double(lb) - double(lc)), lb, lc};
}

/// Stores vertex v's solution in `mapping`, rounded to float32; returns the float evaluation's
/// distance from the vertex at rest. Where rounding leaves more than 1e-5 mm, a few Newton
/// corrections on the float evaluation's own residual (iterative refinement) bring it back to
/// rounding level.
double store_rounded(std::size_t v, const Solution& s, const mapping_internal::Embedding& e, const Problem& problem,
                     const std::vector<Eigen::Vector3d>& visual_positions, const std::vector<std::array<float, 3>>& rest_positions,
                     const std::vector<Eigen::Vector3f>& normals_float, VisualMapping& mapping) {
    const auto& tri = problem.triangles[std::size_t(s.triangle)];
    std::array<float, 3> lambda = round_barycentric(s.lambda);
    float d = float(s.offset);
    std::array<std::int32_t, 8> carriers;
    std::array<float, 8> weights;
    if (e.found()) {
        carriers.fill(e.particles[0]);
        weights.fill(0.0f);
        double rest = 1.0;  // w_0 from the others, so the weights sum to 1 as closely as float allows
        for (int k = 1; k < e.count; ++k) {
            carriers[std::size_t(k)] = e.particles[std::size_t(k)];
            weights[std::size_t(k)] = float(e.weights[std::size_t(k)]);
            rest -= double(weights[std::size_t(k)]);
        }
        weights[0] = float(rest);
        d = 0.0f;
    } else {
        triangle_carriers(tri, lambda, carriers, weights);
    }
    auto float_error = [&](const std::array<float, 8>& w, const std::array<float, 3>& l, float o) {
        const Eigen::Vector3f p = evaluate_float(carriers, w, tri, l, o, rest_positions, normals_float);
        return Vec3(double(p[0]) - visual_positions[v][0], double(p[1]) - visual_positions[v][1], double(p[2]) - visual_positions[v][2]);
    };
    Vec3 err = float_error(weights, lambda, d);
    if (!e.found() && s.exact && err.norm() > 1e-5) {
        Vec3 u(s.lambda[1], s.lambda[2], s.offset);
        for (int pass = 0; pass < 3 && err.norm() > 1e-5; ++pass) {
            const Evaluation at = evaluate(problem, s.triangle, u, visual_positions[v]);
            const Vec3 trial_u = u + at.jacobian.partialPivLu().solve(-err);
            const std::array<float, 3> trial_lambda = round_barycentric(Vec3(1 - trial_u[0] - trial_u[1], trial_u[0], trial_u[1]));
            std::array<std::int32_t, 8> trial_carriers;
            std::array<float, 8> trial_weights;
            triangle_carriers(tri, trial_lambda, trial_carriers, trial_weights);
            const Vec3 trial_e = float_error(trial_weights, trial_lambda, float(trial_u[2]));
            if (!(trial_e.norm() < err.norm())) break;
            u = trial_u;
            lambda = trial_lambda;
            weights = trial_weights;
            d = float(trial_u[2]);
            err = trial_e;
        }
    }
    mapping.triangle[v] = s.triangle;
    mapping.barycentric[v] = lambda;
    mapping.offset[v] = d;
    mapping.particles[v] = carriers;
    mapping.weights[v] = weights;
    return err.norm();
}

/// The report's figures and warnings (all but the time). `error`: store_rounded's, per vertex.
MappingReport summarise_mapping(const VertexSolutions& solved, const VisualMapping& mapping, const std::vector<double>& error,
                                const MappingOptions& options) {
    const std::size_t count = solved.solutions.size();
    MappingReport report;
    double offset_sum = 0.0, amplification_sum = 0.0;
    for (std::size_t v = 0; v < count; ++v) {
        const Solution& s = solved.solutions[v];
        report.max_rest_error_mm = std::max(report.max_rest_error_mm, error[v]);
        report.max_amplification = std::max(report.max_amplification, solved.amplification[v]);
        amplification_sum += solved.amplification[v];
        if (solved.amplification[v] > options.max_amplification) ++report.over_amplification;
        if (solved.embeddings[v].found()) {
            ++report.embedded;
            if (solved.embeddings[v].convex) ++report.embedded_convex;
            continue;
        }
        ++report.tangent;
        offset_sum += std::abs(double(mapping.offset[v]));
        report.max_offset_mm = std::max(report.max_offset_mm, std::abs(double(mapping.offset[v])));
        if (s.extrapolation > 1e-6) ++report.outside_triangle;
        if (!s.exact) ++report.unsolved;
        if (s.unstable_normal) ++report.unstable_normal;
    }
    report.mean_offset_mm = report.tangent ? offset_sum / double(report.tangent) : 0.0;
    report.mean_amplification = amplification_sum / double(count);
    report.candidate_solves = solved.solves;
    if (report.mean_offset_mm > options.far_warning_spacings * options.lattice_spacing_mm) {
        std::ostringstream message;
        const double share = 100.0 * double(report.tangent) / double(count);
        message << report.tangent << " of " << count << " visual vertices (" << std::setprecision(share < 1 ? 1 : 3) << share
                << std::setprecision(6) << " %) lie far from the tissue: outside its cells, on average " << report.mean_offset_mm
                << " mm from the simulation surface, more than " << options.far_warning_spacings << " lattice spacings ("
                << options.lattice_spacing_mm << " mm); they follow it in tangent space";
        report.warnings.push_back(message.str());
    }
    if (report.unsolved > 0)
        report.warnings.push_back(std::to_string(report.unsolved) +
                                  " visual vertices have no exact mapping (closest-point projection used); largest rest error " +
                                  std::to_string(report.max_rest_error_mm) + " mm");
    if (report.over_amplification > 0) {
        std::ostringstream message;
        message << report.over_amplification << " visual vertices have a sensitivity bound above " << options.max_amplification
                << " (largest " << report.max_amplification
                << "): moving the particles by 1 um may move them by more than that many um (tissue too thin for a cell of "
                   "particles, mapped in tangent space on normals that nearly cancel)";
        report.warnings.push_back(message.str());
    }
    return report;
}

VisualMapping map_impl(const std::vector<Eigen::Vector3d>& visual_positions, const std::vector<std::array<float, 3>>& rest_positions,
                       const Lattice* lattice, const SimulationSurface& surface, const MappingOptions& options,
                       Progress& progress, MappingReport* report_out) {
    const auto start_time = std::chrono::steady_clock::now();
    const auto& triangles = surface.triangles;
    require_mapping_inputs(visual_positions, rest_positions, surface);

    const std::size_t particle_count = rest_positions.size();
    std::vector<Vec3> x(particle_count);
    for (std::size_t i = 0; i < particle_count; ++i) x[i] = Vec3(rest_positions[i][0], rest_positions[i][1], rest_positions[i][2]);
    // Solve against the float normals the runtime computes, widened: the float evaluation then
    // differs from the solved one by rounding only.
    const std::vector<Eigen::Vector3f> normals_float = particle_normals(rest_positions, surface);
    std::vector<Vec3> n(particle_count);
    for (std::size_t i = 0; i < particle_count; ++i) n[i] = normals_float[i].cast<double>();
    const CountedSurface counted = counted_surface(x, surface);

    std::vector<std::array<std::int32_t, 3>> candidate_triangles;
    candidate_triangles.reserve(counted.rows.size());
    for (std::int32_t row : counted.rows) candidate_triangles.push_back(triangles[std::size_t(row)]);
    const mapping_internal::TriangleSearch search(x, candidate_triangles, counted.rows);
    const Problem problem{x, n, counted.unstable, triangles};
    std::optional<mapping_internal::CellEmbedder> embedder;
    if (lattice && options.method == MappingMethod::automatic) embedder.emplace(*lattice, x);
    const VertexSolutions solved =
        solve_vertices(visual_positions, problem, search, counted, embedder ? &*embedder : nullptr, options, progress);

    const std::size_t count = visual_positions.size();
    VisualMapping mapping;
    mapping.triangle.resize(count);
    mapping.barycentric.resize(count);
    mapping.offset.resize(count);
    mapping.particles.resize(count);
    mapping.weights.resize(count);
    std::vector<double> error(count, 0.0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 1024), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t v = range.begin(); v < range.end(); ++v)
            error[v] = store_rounded(v, solved.solutions[v], solved.embeddings[v], problem, visual_positions, rest_positions, normals_float,
                                     mapping);
    });

    MappingReport report = summarise_mapping(solved, mapping, error, options);
    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_time).count();
    if (report_out) *report_out = std::move(report);
    return mapping;
}

}  // namespace

VisualMapping map_visual_mesh(const std::vector<Eigen::Vector3d>& visual_positions, const Lattice& lattice,
                              const SimulationSurface& surface, const MappingOptions& options, Progress& progress,
                              MappingReport* report) {
    return map_impl(visual_positions, lattice.particles.rest_position, &lattice, surface, options, progress, report);
}

VisualMapping map_visual_mesh(const std::vector<Eigen::Vector3d>& visual_positions,
                              const std::vector<std::array<float, 3>>& rest_positions, const SimulationSurface& surface,
                              const MappingOptions& options, Progress& progress, MappingReport* report) {
    return map_impl(visual_positions, rest_positions, nullptr, surface, options, progress, report);
}

}  // namespace heartsim
