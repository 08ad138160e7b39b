/// @file mapping_embedding.cpp
/// @brief A visual vertex embedded in a lattice cell (mapping_embedding.h).
#include "libmodel/mapping_embedding.h"

#include "libmodel/errors.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <string>

namespace heartsim::mapping_internal {

namespace {

/// Corners of a cell (2×2×2 particles from (i, j, k)), i fastest.
constexpr std::array<std::array<int, 3>, 8> corner_offsets{
    {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}}};

/// Smallest eigenvalue of the carriers' scatter (lattice units) below which they count as flat:
/// four corners of one face have 0; the flattest set of cell corners spanning a volume (a face
/// and one corner off it) about 0.1.
constexpr double flat_scatter = 1e-3;

}  // namespace

CellEmbedder::CellEmbedder(const Lattice& lattice, const std::vector<Eigen::Vector3d>& rest)
    : rest_(rest), grid_(lattice), world_to_index_(lattice.index_to_world.inverse()), spacing_(lattice.spacing) {
    if (!(spacing_ > 0) || lattice.dims[0] <= 0 || lattice.dims[1] <= 0 || lattice.dims[2] <= 0)
        throw InputError("mapping: the lattice has no cells (spacing or dims not positive)");
    if (lattice.particles.lattice_index.size() != rest.size())
        throw InputError("mapping: the lattice has " + std::to_string(lattice.particles.lattice_index.size()) +
                         " particle indices for " + std::to_string(rest.size()) + " particles");
    const Eigen::Matrix3d linear = lattice.index_to_world.topLeftCorner<3, 3>();
    // The smallest singular value of the index-to-world map: the least world length of a unit step.
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> squared(linear.transpose() * linear, Eigen::EigenvaluesOnly);
    mm_per_cell_ = std::sqrt(std::max(0.0, squared.eigenvalues().minCoeff()));
    for (std::size_t p = 0; p < rest.size(); ++p) {
        const auto& c = lattice.particles.lattice_index[p];
        const Eigen::Vector3d at = linear * Eigen::Vector3d(c[0], c[1], c[2]) + lattice.index_to_world.topRightCorner<3, 1>();
        off_lattice_ = std::max(off_lattice_, (rest[p] - at).norm());
    }
}

bool CellEmbedder::affine(const Eigen::Vector3d& v, const std::int32_t* ids, int count, Embedding& out) const {
    if (count < 4) return false;
    std::array<Eigen::Vector3d, 8> r;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int k = 0; k < count; ++k) {
        r[std::size_t(k)] = (rest_[std::size_t(ids[k])] - v) / spacing_;
        mean += r[std::size_t(k)];
    }
    mean /= double(count);
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    Eigen::Matrix4d normal = Eigen::Matrix4d::Zero();
    for (int k = 0; k < count; ++k) {
        const Eigen::Vector3d c = r[std::size_t(k)] - mean;
        scatter += c * c.transpose();
        Eigen::Vector4d b;
        b << r[std::size_t(k)], 1.0;
        normal += b * b.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
    eigen.computeDirect(scatter, Eigen::EigenvaluesOnly);
    if (!(eigen.eigenvalues()[0] > flat_scatter)) return false;
    // min |w|² subject to Σ w_k·(x_k − v) = 0 and Σ w_k = 1: w = Bᵀ(B·Bᵀ)⁻¹·e₄, B's columns (r_k, 1).
    const Eigen::Vector4d y = normal.ldlt().solve(Eigen::Vector4d(0, 0, 0, 1));
    if (!y.allFinite()) return false;
    Embedding e;
    e.count = count;
    e.convex = true;
    for (int k = 0; k < count; ++k) {
        e.particles[std::size_t(k)] = ids[k];
        e.weights[std::size_t(k)] = r[std::size_t(k)].dot(y.head<3>()) + y[3];
        e.amplification += std::abs(e.weights[std::size_t(k)]);
        e.convex = e.convex && e.weights[std::size_t(k)] >= 0.0 && e.weights[std::size_t(k)] <= 1.0;
    }
    if (!std::isfinite(e.amplification)) return false;
    out = e;
    return true;
}

Embedding CellEmbedder::embed(const Eigen::Vector3d& v) const { return embed(v, {}); }

Embedding CellEmbedder::embed(const Eigen::Vector3d& v, const std::function<bool(std::int32_t)>& usable) const {
    const Eigen::Vector3d q = (world_to_index_ * v.homogeneous()).head<3>();
    const std::array<long, 3> base{long(std::floor(q[0])), long(std::floor(q[1])), long(std::floor(q[2]))};
    // `usable` is asked once a particle of the 4×4×4 around v's cell (the corners of the 27 cells),
    // and beyond them only as far as the choice of the nearest goes (below): it may be costly.
    std::array<std::int8_t, 64> asked;
    asked.fill(-1);
    auto particle_at = [&](long i, long j, long k) {
        const std::int32_t p = grid_.at(i, j, k);
        if (p < 0 || !usable) return p;
        std::int8_t& known = asked[std::size_t((i - base[0] + 1) + 4 * (j - base[1] + 1) + 16 * (k - base[2] + 1))];
        if (known < 0) known = usable(p) ? 1 : 0;
        return known ? p : -1;
    };
    Embedding best;
    auto consider = [&](long ci, long cj, long ck) {
        std::array<std::int32_t, 8> ids{};
        int count = 0;
        for (const auto& o : corner_offsets) {
            const std::int32_t p = particle_at(ci + o[0], cj + o[1], ck + o[2]);
            if (p >= 0) ids[std::size_t(count++)] = p;
        }
        Embedding e;
        if (count == 8) {
            // Trilinear: exact for the lattice's affine index_to_world, and a partition of unity
            // that is continuous from cell to cell.
            const Eigen::Vector3d t = q - Eigen::Vector3d(double(ci), double(cj), double(ck));
            e.count = 8;
            e.particles = ids;
            e.convex = (t.array() >= 0.0).all() && (t.array() <= 1.0).all();
            for (int c = 0; c < 8; ++c) {
                double w = 1.0;
                for (int a = 0; a < 3; ++a) w *= corner_offsets[std::size_t(c)][std::size_t(a)] ? t[a] : 1.0 - t[a];
                e.weights[std::size_t(c)] = w;
                e.amplification += std::abs(w);
            }
        } else if (!affine(v, ids.data(), count, e)) {
            return;
        }
        if (!best.found() || e.amplification < best.amplification) best = e;
    };
    consider(base[0], base[1], base[2]);
    if (best.found() && best.convex && best.count == 8) return best;
    for (long dk = -1; dk <= 1; ++dk)
        for (long dj = -1; dj <= 1; ++dj)
            for (long di = -1; di <= 1; ++di)
                if (di || dj || dk) consider(base[0] + di, base[1] + dj, base[2] + dk);
    if (best.found()) return best;

    // Far from any cell with a volume of particles: the 8 nearest particles within 6 cells; if
    // they are flat (a sheet), the 7 nearest and the nearest one off their plane. The particles
    // within reach are taken in the order of (distance, index), from a heap, and asked of `usable`
    // in that order, as far as the choice goes: the same choice as ordering the usable ones alone.
    // The cells come into the heap shell by shell (shell s: s cells beyond v's 2×2×2 block along
    // some axis, none along any other by more), each shell only once a particle in it could be
    // the nearest left: the heap then pops what it would hold with all of them, in the same order.
    std::vector<std::pair<double, std::int32_t>> near;
    const std::greater<> nearer_last;
    constexpr long reach = 6;
    long shells = 0;  // shells 0 .. shells − 1 are in the heap
    auto add = [&](long i, long j, long k) {
        if (const std::int32_t p = grid_.at(i, j, k); p >= 0) {
            near.emplace_back((rest_[std::size_t(p)] - v).squaredNorm(), p);
            std::push_heap(near.begin(), near.end(), nearer_last);
        }
    };
    auto take_shell = [&](long s) {
        for (long k = base[2] - s; k <= base[2] + 1 + s; ++k) {
            const bool k_out = k == base[2] - s || k == base[2] + 1 + s;
            for (long j = base[1] - s; j <= base[1] + 1 + s; ++j) {
                if (k_out || j == base[1] - s || j == base[1] + 1 + s) {
                    for (long i = base[0] - s; i <= base[0] + 1 + s; ++i) add(i, j, k);
                } else {
                    add(base[0] - s, j, k);
                    add(base[0] + 1 + s, j, k);
                }
            }
        }
    };
    // A particle in shell s lies at least s cells from v in index space, so this far in world mm
    // (less its distance from its lattice point, and a margin for rounding).
    const double margin = off_lattice_ + 1e-9 * (spacing_ + v.norm());
    auto nearest_beyond = [&](long s) {
        const double d = std::max(0.0, mm_per_cell_ * double(s) - margin);
        return d * d;
    };
    auto next_usable = [&]() -> std::int32_t {
        while (true) {
            while (shells <= reach && (near.empty() || nearest_beyond(shells) <= near.front().first)) take_shell(shells++);
            if (near.empty()) return -1;
            std::pop_heap(near.begin(), near.end(), nearer_last);
            const std::int32_t p = near.back().second;
            near.pop_back();
            if (!usable || usable(p)) return p;
        }
    };
    std::array<std::int32_t, 8> ids{};
    std::size_t count = 0;
    for (std::int32_t p; count < 8 && (p = next_usable()) >= 0;) ids[count++] = p;
    auto chosen = [&] {
        best.far_found = int(count);
        return best;
    };
    if (count < 4) return chosen();
    if (affine(v, ids.data(), int(count), best) || count < 8) return chosen();
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < 7; ++k) mean += rest_[std::size_t(ids[k])];
    mean /= 7.0;
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    for (std::size_t k = 0; k < 7; ++k) {
        const Eigen::Vector3d c = rest_[std::size_t(ids[k])] - mean;
        scatter += c * c.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
    eigen.computeDirect(scatter);
    const Eigen::Vector3d normal = eigen.eigenvectors().col(0);
    for (std::int32_t p = ids[7]; p >= 0; p = next_usable())
        if (std::abs((rest_[std::size_t(p)] - mean).dot(normal)) > 0.5 * spacing_) {
            ids[7] = p;
            affine(v, ids.data(), 8, best);
            break;
        }
    return chosen();
}

}  // namespace heartsim::mapping_internal
