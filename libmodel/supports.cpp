#include "libmodel/supports.h"

#include "libmodel/errors.h"
#include "libmodel/packing.h"

#include <Eigen/Dense>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

namespace heartsim {

const char* to_string(SupportRegion region) {
    switch (region) {
    case SupportRegion::none: return "none";
    case SupportRegion::posterior: return "posterior";
    case SupportRegion::boundary: return "boundary";
    }
    return "?";
}

SupportRegion parse_support_region(const std::string& text) {
    if (text == "none") return SupportRegion::none;
    if (text == "posterior") return SupportRegion::posterior;
    if (text == "boundary") return SupportRegion::boundary;
    throw InputError("{SupportOptions::region} must be posterior, boundary or none, got '" + text + "'");
}

SupportReport add_supports(Lattice& lattice, const SupportOptions& options) {
    auto& p = lattice.particles;
    SupportReport report;
    report.region = options.region;
    report.stiffness_kpa_per_mm = options.stiffness_kpa_per_mm;
    report.embedding_kpa_per_mm2 = options.embedding_kpa_per_mm2;
    if (options.region == SupportRegion::none) {
        p.support_stiffness.clear();
        p.support_point.clear();
        p.support_damping.clear();
        return report;
    }
    if (!(options.stiffness_kpa_per_mm >= 0) || !std::isfinite(options.stiffness_kpa_per_mm))
        throw InputError("{SupportOptions::stiffness_kpa_per_mm} must be a non-negative number of kPa/mm");
    if (!(options.embedding_kpa_per_mm2 >= 0) || !std::isfinite(options.embedding_kpa_per_mm2))
        throw InputError("{SupportOptions::embedding_kpa_per_mm2} must be a non-negative number of kPa/mm²");
    if (!(options.posterior.norm() > 0) || !options.posterior.allFinite()) throw InputError("supports: the posterior direction is zero");
    if (!(options.damping_ratio >= 0) || !std::isfinite(options.damping_ratio))
        throw InputError("{SupportOptions::damping_ratio} must be a non-negative damping ratio");
    const std::size_t n = p.size();
    std::vector<double> area(n, 0.0);
    const double face = lattice.spacing * lattice.spacing;
    // How full of tissue a particle's cell is, relative to a cell at the occupancy (at most 1).
    auto fill_of = [&](std::size_t i) {
        const auto row = std::size_t(p.material[i]);
        const double density = row < lattice.materials.size() ? lattice.materials[row].density : Material{}.density;
        const double fraction = double(p.mass[i]) / density / (face * lattice.spacing);
        return options.full_fraction > 0 ? std::min(1.0, fraction / options.full_fraction) : 1.0;
    };

    if (options.region == SupportRegion::posterior) {
        // The lattice axis nearest to the posterior direction, and which way along it is posterior.
        const Eigen::Matrix3d axes = lattice.index_to_world.topLeftCorner<3, 3>();
        const Eigen::Vector3d back = options.posterior.normalized();
        int axis = 0;
        double best = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double c = axes.col(a).normalized().dot(back);
            if (std::abs(c) > std::abs(best)) best = c, axis = a;
        }
        // In each line along that axis, the particle farthest posteriorly: one pass for each
        // line's extreme index (counted so that larger is more posterior), one to mark it.
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        const int sign = best > 0 ? 1 : -1;
        const auto& d = lattice.dims;
        auto line = [&](const std::array<std::int32_t, 3>& c) { return std::size_t(c[std::size_t(u)]) * std::size_t(d[std::size_t(v)]) + std::size_t(c[std::size_t(v)]); };
        std::vector<int> extreme(std::size_t(d[std::size_t(u)]) * std::size_t(d[std::size_t(v)]), std::numeric_limits<int>::min());
        for (const auto& c : p.lattice_index) extreme[line(c)] = std::max(extreme[line(c)], sign * c[std::size_t(axis)]);
        // A support carries the tissue of its cell: a light particle (a thin wall's ridge or
        // thickening particle, fraction below the occupancy) at a line's extreme takes its share of
        // the face, and the particles behind it, inwards, the rest.
        const ParticleGrid grid(lattice);
        for (std::size_t i = 0; i < n; ++i) {
            if (sign * p.lattice_index[i][std::size_t(axis)] != extreme[line(p.lattice_index[i])]) continue;
            double left = 1.0;
            std::array<std::int32_t, 3> c = p.lattice_index[i];
            for (std::int32_t q = std::int32_t(i); q >= 0 && left > 0.0;) {
                const double share = std::min(left, fill_of(std::size_t(q)));
                area[std::size_t(q)] += share * face;
                left -= share;
                c[std::size_t(axis)] -= sign;
                q = grid.at(c);
            }
        }
    } else {
        // An exposed face: a face slot (the table's first 6) with no neighbour.
        const auto table = neighbour_table(lattice);
        for (std::size_t i = 0; i < n; ++i)
            for (int f = 0; f < 6; ++f)
                if (table[i][std::size_t(f)] < 0) area[i] += face * fill_of(i);
    }

    p.support_stiffness.assign(n, 0.0f);
    p.support_damping.assign(n, 0.0f);
    p.support_point = p.rest_position;
    const double per_area = options.stiffness_kpa_per_mm * 1e-3;         // N/mm per mm²
    const double per_volume = options.embedding_kpa_per_mm2 * 1e-3;      // N/mm per mm³
    for (std::size_t i = 0; i < n; ++i) {
        if (p.anchored[i]) continue;
        const auto row = std::size_t(p.material[i]);
        const double density = row < lattice.materials.size() ? lattice.materials[row].density : Material{}.density;
        const double embedding = per_volume * double(p.mass[i]) / density;
        p.support_stiffness[i] = float(per_area * area[i] + embedding);
        report.embedding_stiffness += embedding;
        if (area[i] == 0.0 || per_area == 0.0) continue;
        report.area_mm2 += area[i];
    }
    for (std::size_t i = 0; i < n; ++i) {
        report.total_stiffness += double(p.support_stiffness[i]);
        p.support_damping[i] = float(2.0 * options.damping_ratio * std::sqrt(double(p.support_stiffness[i]) * double(p.mass[i])));
    }
    // Counted as inspect and batch count them from the file: a particle whose share of a face is a
    // rounding's remainder is not on a support.
    report.supported = count_surface_supported(lattice);
    return report;
}

std::size_t count_surface_supported(const Lattice& lattice) {
    const auto& p = lattice.particles;
    if (!p.supported()) return 0;
    // k·ρ/m: the support's stiffness per tissue volume, N/mm per mm³.
    auto per_volume = [&](std::size_t i) {
        const auto row = std::size_t(p.material[i]);
        const double density = row < lattice.materials.size() ? lattice.materials[row].density : Material{}.density;
        return double(p.support_stiffness[i]) * density / double(p.mass[i]);
    };
    double least = std::numeric_limits<double>::infinity();
    bool foundation = true;
    std::size_t supported = 0;
    for (std::size_t i = 0; i < p.size(); ++i) {
        if (p.anchored[i]) continue;
        if (!(p.support_stiffness[i] > 0.0f) || !(p.mass[i] > 0.0f)) {
            foundation = foundation && p.support_stiffness[i] > 0.0f;
            continue;
        }
        ++supported;
        least = std::min(least, per_volume(i));
    }
    if (!foundation) return supported;
    std::size_t surface = 0;
    for (std::size_t i = 0; i < p.size(); ++i)
        if (!p.anchored[i] && p.support_stiffness[i] > 0.0f && p.mass[i] > 0.0f && per_volume(i) > 1.5 * least) ++surface;
    return surface;
}

Pieces find_pieces(const Particles& particles, const Springs& springs) {
    const std::size_t n = particles.size();
    // Union-find over the springs.
    std::vector<std::int32_t> parent(n);
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](std::int32_t i) {
        while (parent[std::size_t(i)] != i) i = parent[std::size_t(i)] = parent[std::size_t(parent[std::size_t(i)])];
        return i;
    };
    for (const auto& [a, b] : springs.pairs) {
        const std::int32_t ra = find(a), rb = find(b);
        if (ra != rb) parent[std::size_t(std::max(ra, rb))] = std::min(ra, rb);
    }
    std::vector<std::int32_t> root_piece(n, -1);
    std::vector<std::size_t> size;
    std::vector<bool> held;
    std::vector<std::int32_t> raw(n);
    for (std::size_t i = 0; i < n; ++i) {
        const std::int32_t r = find(std::int32_t(i));
        if (root_piece[std::size_t(r)] < 0) {
            root_piece[std::size_t(r)] = std::int32_t(size.size());
            size.push_back(0);
            held.push_back(false);
        }
        const std::int32_t k = root_piece[std::size_t(r)];
        raw[i] = k;
        ++size[std::size_t(k)];
        const bool supported = particles.supported() && particles.support_stiffness[i] > 0.0f;
        if (particles.anchored[i] || supported) held[std::size_t(k)] = true;
    }
    // Largest first (ties by first particle: deterministic).
    std::vector<std::int32_t> order(size.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) { return size[std::size_t(a)] > size[std::size_t(b)]; });
    std::vector<std::int32_t> rank(size.size());
    for (std::size_t r = 0; r < order.size(); ++r) rank[std::size_t(order[r])] = std::int32_t(r);
    Pieces pieces;
    pieces.piece.resize(n);
    for (std::size_t i = 0; i < n; ++i) pieces.piece[i] = rank[std::size_t(raw[i])];
    for (std::int32_t k : order) {
        pieces.size.push_back(size[std::size_t(k)]);
        pieces.held.push_back(held[std::size_t(k)]);
    }
    return pieces;
}

FreePieceReport drop_free_pieces(Lattice& lattice, const FreePieceOptions& options) {
    auto& p = lattice.particles;
    const Pieces pieces = find_pieces(p, lattice.springs);
    FreePieceReport report;
    report.pieces = pieces.size.size();
    report.piece_sizes = pieces.size;
    std::vector<bool> drop_piece(pieces.size.size(), false);
    for (std::size_t k = 0; k < pieces.size.size(); ++k) {
        if (pieces.held[k]) continue;
        if (options.allow_free) {
            ++report.free_pieces_kept;
            report.free_particles_kept += pieces.size[k];
        } else if (pieces.size[k] < options.drop_below_particles) {
            drop_piece[k] = true;
            ++report.dropped_pieces;
            report.dropped_particles += pieces.size[k];
        } else {
            throw InputError("a piece of " + std::to_string(pieces.size[k]) + " of the " + std::to_string(p.size()) +
                             " particles is held by nothing (no anchored and no supported particle): it would fall away. "
                             "Hold it with {SupportOptions::region} posterior or {SupportOptions::region} boundary, anchor it ({SelectionOptions::anchor_labels}, {SelectionOptions::anchor_border}), "
                             "raise {FreePieceOptions::drop_below_particles} above " + std::to_string(pieces.size[k]) + " particles to drop it, "
                             "or keep it free with {FreePieceOptions::allow_free}");
        }
    }
    if (report.dropped_particles == 0) return report;

    const std::size_t n = p.size();
    std::vector<std::int32_t> new_index(n, -1);
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i)
        if (!drop_piece[std::size_t(pieces.piece[i])]) new_index[i] = std::int32_t(kept++);
    auto compact = [&](auto& values) {
        if (values.empty()) return;
        std::size_t w = 0;
        for (std::size_t i = 0; i < n; ++i)
            if (new_index[i] >= 0) values[w++] = values[i];
        values.resize(w);
    };
    compact(p.rest_position);
    compact(p.lattice_index);
    compact(p.mass);
    compact(p.material);
    compact(p.anchored);
    compact(p.support_stiffness);
    compact(p.support_point);
    compact(p.support_damping);
    Springs kept_springs;
    auto& s = lattice.springs;
    for (std::size_t q = 0; q < s.size(); ++q) {
        const std::int32_t a = new_index[std::size_t(s.pairs[q][0])], b = new_index[std::size_t(s.pairs[q][1])];
        if (a < 0 || b < 0) continue;  // a spring never joins two pieces
        kept_springs.pairs.push_back({std::min(a, b), std::max(a, b)});
        kept_springs.rest_length.push_back(s.rest_length[q]);
        kept_springs.stiffness.push_back(s.stiffness[q]);
    }
    s = std::move(kept_springs);
    return report;
}

namespace {

/// The float rest distance of a spring, evaluated as the solvers' kernels evaluate a length.
float float_distance(const std::array<float, 3>& a, const std::array<float, 3>& b) {
    const float dx = b[0] - a[0], dy = b[1] - a[1], dz = b[2] - a[2];
    float length2 = dx * dx + dy * dy;
    length2 = length2 + dz * dz;
    return std::sqrt(length2);
}

struct SpringEnd {
    std::int32_t other;
    std::int32_t spring;
};

using Vectors = std::vector<Eigen::Vector3d>;

/// The linear static problem of balance_rest_state at rest, K·u = M·g over its unknowns (the free
/// particles of held pieces): springs k·n·nᵀ, supports k·I, every other particle fixed.
struct RestStatics {
    const Particles& p;
    const Springs& s;
    std::vector<std::uint8_t> unknown;      ///< per particle: 1 where it is an unknown
    std::vector<Eigen::Vector3d> unit;      ///< per spring: its direction at rest (double)
    std::vector<std::size_t> first;         ///< per particle and one past: its first entry in ends
    std::vector<SpringEnd> ends;            ///< per particle, its springs and their other ends (a race-free gather)
    std::vector<Eigen::Matrix3d> block_inverse;  ///< per particle: its diagonal block's inverse (3×3 block-Jacobi)

    RestStatics(const Lattice& lattice, std::vector<std::uint8_t> unknown_particles)
        : p(lattice.particles), s(lattice.springs), unknown(std::move(unknown_particles)) {
        const std::size_t n = p.size();
        unit.resize(s.size());
        for (std::size_t q = 0; q < s.size(); ++q) {
            const auto& a = p.rest_position[std::size_t(s.pairs[q][0])];
            const auto& b = p.rest_position[std::size_t(s.pairs[q][1])];
            const Eigen::Vector3d dvec(double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]);
            unit[q] = dvec.norm() > 0 ? Eigen::Vector3d(dvec.normalized()) : Eigen::Vector3d::Zero();
        }
        first.assign(n + 1, 0);
        for (const auto& [a, b] : s.pairs) ++first[std::size_t(a) + 1], ++first[std::size_t(b) + 1];
        for (std::size_t i = 0; i < n; ++i) first[i + 1] += first[i];
        ends.resize(first[n]);
        std::vector<std::size_t> fill(first.begin(), first.end() - 1);
        for (std::size_t q = 0; q < s.size(); ++q) {
            const auto [a, b] = s.pairs[q];
            ends[fill[std::size_t(a)]++] = {b, std::int32_t(q)};
            ends[fill[std::size_t(b)]++] = {a, std::int32_t(q)};
        }
        block_inverse.assign(n, Eigen::Matrix3d::Zero());
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) {
            if (!unknown[i]) return;
            Eigen::Matrix3d block = support(i) * Eigen::Matrix3d::Identity();
            for (std::size_t e = first[i]; e < first[i + 1]; ++e) {
                const auto q = std::size_t(ends[e].spring);
                block += double(s.stiffness[q]) * unit[q] * unit[q].transpose();
            }
            Eigen::FullPivLU<Eigen::Matrix3d> lu(block);
            if (lu.isInvertible()) block_inverse[i] = lu.inverse();
            else {
                const double trace = block.trace();
                block_inverse[i] = trace > 0 ? Eigen::Matrix3d(Eigen::Matrix3d::Identity() * (3.0 / trace)) : Eigen::Matrix3d::Zero();
            }
        });
    }
    double support(std::size_t i) const { return p.supported() ? double(p.support_stiffness[i]) : 0.0; }
    /// y = K x over the unknowns.
    void multiply(const Vectors& x, Vectors& y) const {
        tbb::parallel_for(std::size_t(0), p.size(), [&](std::size_t i) {
            if (!unknown[i]) {
                y[i].setZero();
                return;
            }
            Eigen::Vector3d sum = support(i) * x[i];
            for (std::size_t e = first[i]; e < first[i + 1]; ++e) {
                const auto q = std::size_t(ends[e].spring);
                const auto j = std::size_t(ends[e].other);
                const Eigen::Vector3d relative = unknown[j] ? Eigen::Vector3d(x[i] - x[j]) : x[i];
                sum += double(s.stiffness[q]) * unit[q] * unit[q].dot(relative);
            }
            y[i] = sum;
        });
    }
    /// Σ a·b in fixed blocks, the block partials summed in order: the same result for any thread count.
    double dot(const Vectors& a, const Vectors& b) const {
        const std::size_t n = p.size();
        const std::size_t block = 4096, blocks = (n + block - 1) / block;
        std::vector<double> partial(blocks, 0.0);
        tbb::parallel_for(std::size_t(0), blocks, [&](std::size_t k) {
            double sum = 0;
            for (std::size_t i = k * block; i < std::min(n, (k + 1) * block); ++i) sum += a[i].dot(b[i]);
            partial[k] = sum;
        });
        return std::accumulate(partial.begin(), partial.end(), 0.0);
    }
};

/// Solves K·u = f by preconditioned conjugate gradients from u = 0; returns the relative residual
/// |K·u − f|/|f| it stopped at (within the tolerance, diverging past 1e6, at a direction with no
/// stiffness, or after max_iterations) and the iterations in `iterations`.
double solve_sag(const RestStatics& statics, const Vectors& f, Vectors& u, const RestBalanceOptions& options, Progress& progress,
                 int& iterations) {
    const std::size_t n = f.size();
    Vectors r(n), z(n), d(n), kd(n);
    r = f;
    for (std::size_t i = 0; i < n; ++i) z[i] = statics.block_inverse[i] * r[i];
    d = z;
    double rz = statics.dot(r, z);
    const double f_norm = std::sqrt(statics.dot(f, f));
    ProgressStage stage(progress, "balance the rest state", 0);
    int iteration = 0;
    double residual = 1.0;
    for (; iteration < options.max_iterations; ++iteration) {
        residual = std::sqrt(statics.dot(r, r)) / f_norm;
        if (residual <= options.tolerance) break;
        if (residual > 1e6) break;  // diverging: a load across a mechanism (below)
        if ((iteration & 63) == 0 && progress.cancelled()) throw Cancelled();
        statics.multiply(d, kd);
        const double curvature = statics.dot(d, kd);
        if (!(curvature > 0)) break;  // a direction with no stiffness: a mechanism nothing holds
        const double alpha = rz / curvature;
        for (std::size_t i = 0; i < n; ++i) {
            u[i] += alpha * d[i];
            r[i] -= alpha * kd[i];
            z[i] = statics.block_inverse[i] * r[i];
        }
        const double rz_next = statics.dot(r, z);
        const double beta = rz_next / rz;
        rz = rz_next;
        for (std::size_t i = 0; i < n; ++i) d[i] = z[i] + beta * d[i];
    }
    iterations = iteration;
    return residual;
}

/// Pre-stress: each spring keeps the tension of the sagged shape `u` at the rest positions (its
/// rest length the rest distance less the elongation), each support the load (its point x − u).
void prestress(Lattice& lattice, const RestStatics& statics, const Vectors& u, RestBalanceReport& report) {
    auto& p = lattice.particles;
    auto& s = lattice.springs;
    for (std::size_t q = 0; q < s.size(); ++q) {
        const auto a = std::size_t(s.pairs[q][0]), b = std::size_t(s.pairs[q][1]);
        if (!statics.unknown[a] && !statics.unknown[b]) continue;
        const double elongation = statics.unit[q].dot(u[b] - u[a]);
        const double distance = double(float_distance(p.rest_position[a], p.rest_position[b]));
        const double rest = distance - elongation;
        if (!(rest > 0)) throw InputError("balancing the rest state compressed a spring to zero length: the supports are far too weak");
        s.rest_length[q] = float(rest);
        report.max_prestrain = std::max(report.max_prestrain, std::abs(elongation) / distance);
    }
    if (p.supported())
        for (std::size_t i = 0; i < p.size(); ++i)
            if (statics.unknown[i] && p.support_stiffness[i] > 0)
                for (int c = 0; c < 3; ++c) p.support_point[i][std::size_t(c)] = float(double(p.rest_position[i][std::size_t(c)]) - u[i][c]);
}

}  // namespace

RestBalanceReport balance_rest_state(Lattice& lattice, const Eigen::Vector3d& gravity, const RestBalanceOptions& options,
                                     Progress& progress) {
    RestBalanceReport report;
    auto& p = lattice.particles;
    auto& s = lattice.springs;
    const std::size_t n = p.size();
    if (!gravity.allFinite()) throw InputError("balance_rest_state: gravity must be finite");
    if (gravity.norm() == 0.0 || n == 0) return report;

    const Pieces pieces = find_pieces(p, s);
    // Unknowns: free particles of held pieces. Anchored particles and free pieces stay put.
    std::vector<std::uint8_t> unknown(n, 0);
    std::size_t unknowns = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (p.anchored[i]) continue;
        if (!pieces.held[std::size_t(pieces.piece[i])]) {
            ++report.unbalanced_particles;
            continue;
        }
        unknown[i] = 1;
        ++unknowns;
    }
    if (report.unbalanced_particles > 0)
        report.warnings.push_back(std::to_string(report.unbalanced_particles) +
                                  " particles in pieces that nothing holds are not balanced: they fall under gravity");
    if (unknowns == 0) return report;

    const RestStatics statics(lattice, std::move(unknown));
    Vectors f(n, Eigen::Vector3d::Zero()), u(n, Eigen::Vector3d::Zero());
    for (std::size_t i = 0; i < n; ++i)
        if (statics.unknown[i]) {
            f[i] = double(p.mass[i]) * gravity;
            report.weight_n += double(p.mass[i]) * gravity.norm();
        }
    const double residual = solve_sag(statics, f, u, options, progress, report.iterations);
    report.relative_residual = residual;
    if (!(residual <= std::max(options.tolerance, 1e-6)))
        throw InputError("the rest state cannot be balanced under gravity (conjugate gradients stopped at a relative residual of " +
                         std::to_string(residual) + " after " + std::to_string(report.iterations) +
                         " iterations): a part of the heart is held at too few points to resist rotation. Use {SupportOptions::region} boundary, "
                         "anchor more, or {rest_state} imaged");

    double sag_sum = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const double sag = u[i].norm();
        report.max_sag_mm = std::max(report.max_sag_mm, sag);
        sag_sum += sag;
    }
    report.mean_sag_mm = sag_sum / double(unknowns);
    prestress(lattice, statics, u, report);
    report.balanced = true;
    return report;
}

RestResidual rest_force_residual(const Lattice& lattice, const Eigen::Vector3d& gravity) {
    const auto& p = lattice.particles;
    const auto& s = lattice.springs;
    std::vector<Eigen::Vector3d> force(p.size(), Eigen::Vector3d::Zero());
    for (std::size_t i = 0; i < p.size(); ++i) {
        force[i] = double(p.mass[i]) * gravity;
        if (p.supported())
            for (int c = 0; c < 3; ++c)
                force[i][c] += double(p.support_stiffness[i]) * (double(p.support_point[i][std::size_t(c)]) - p.rest_position[i][std::size_t(c)]);
    }
    for (std::size_t q = 0; q < s.size(); ++q) {
        const auto a = std::size_t(s.pairs[q][0]), b = std::size_t(s.pairs[q][1]);
        const auto& xa = p.rest_position[a];
        const auto& xb = p.rest_position[b];
        const Eigen::Vector3d d(double(xb[0]) - xa[0], double(xb[1]) - xa[1], double(xb[2]) - xa[2]);
        const double length = d.norm();
        const Eigen::Vector3d f = double(s.stiffness[q]) * (length - double(s.rest_length[q])) / length * d;
        force[a] += f;
        force[b] -= f;
    }
    RestResidual residual;
    for (std::size_t i = 0; i < p.size(); ++i) {
        if (p.anchored[i]) continue;
        residual.total += force[i];
        residual.max_particle_n = std::max(residual.max_particle_n, force[i].norm());
    }
    return residual;
}

}  // namespace heartsim
