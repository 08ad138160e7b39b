/// @file volume_cells.h
/// @brief The tissue's own Poisson's ratio. Central springs on a cubic lattice obey the Cauchy
/// relations (λ = μ: ν = 1/4 whatever their stiffness), so the springs give the tissue its shear
/// modulus μ and a volume term gives it the rest of Lamé's first parameter, Δλ = λ − μ: every
/// cubic cell of the lattice whose eight corners are particles stores W = ½·Δλ·|V₀|·(V/V₀ − 1)²,
/// V the volume of the cell the eight particles span now (each face the bilinear patch through
/// its four corners), V₀ at rest. For a small strain V/V₀ − 1 = tr ε, so the springs and the cells
/// together have λ = μ + Δλ: the linear-elastic solid with E and ν (Golec et al., "Hybrid 3D
/// mass-spring system for simulation of isotropic materials with any Poisson's ratio", The
/// Visual Computer 2020). docs/solver.md "The volume term".
///
/// Units: mm, N; moduli N/mm² (1 kPa = 1e-3 N/mm²).
#pragma once

#include "libmodel/lattice.h"

#include <array>
#include <cstdint>
#include <vector>

namespace heartsim {

/// The shear modulus μ = E/(2(1 + ν)), N/mm², for E in kPa.
double shear_modulus(double youngs_modulus_kpa, double poisson_ratio);
/// Δλ = λ − μ = μ(4ν − 1)/(1 − 2ν), N/mm²: what the volume term adds to the springs' λ = μ.
/// Zero at ν = 1/4 (the springs alone); ν must lie in [1/4, 1/2).
double added_lame_modulus(double youngs_modulus_kpa, double poisson_ratio);
/// Each material row's Δλ (added_lame_modulus), N/mm², for SolverOptions::volume_modulus.
std::vector<double> added_lame_moduli(const std::vector<Material>& materials);

/// Corner c of a cell lies at lattice offset (c & 1, (c >> 1) & 1, (c >> 2) & 1) from corner 0.
/// The six faces, each as four corners in order about the outward normal (of a lattice whose
/// index-to-world map keeps orientation; a mirrored one turns every sign, V₀ with them).
extern const std::array<std::array<int, 4>, 6> cell_faces;
/// The 24 springs of a cell: its 12 edges (face springs) and its 12 face diagonals (edge
/// springs), as corner pairs (lower first). A cell whose spring is cut has no volume term.
extern const std::array<std::array<int, 2>, 24> cell_springs;

/// The lattice's cells with a volume term: those whose eight corners are particles and whose
/// Δλ (the mean of the corners' materials' rows of `added_modulus`) is positive. The tissue's
/// outer half cell (the label map's tissue reaches half a spacing past the outer particles) has
/// no cell: there the springs alone hold it (docs/solver.md "The volume term").
struct VolumeCells {
    std::vector<std::array<std::int32_t, 8>> corner;  ///< particle indices
    std::vector<double> modulus;                      ///< Δλ, N/mm²
    std::vector<double> rest_volume;                  ///< V₀ at the rest positions, mm³ (signed)
    std::size_t size() const { return corner.size(); }
    bool empty() const { return corner.empty(); }
};

/// The cells of `particles` (by their lattice indices) for the per-material Δλ `added_modulus`
/// (a row past its end: 0). None where every row is 0. Throws InputError where some row is
/// positive and the particles have no lattice indices.
VolumeCells volume_cells(const Particles& particles, const std::vector<double>& added_modulus);

/// Twelve times the volume of a cell whose corners lie at p[c] (any common origin), and, unless
/// null, twelve times its gradient: gradient[c] = 12·∂V/∂p[c]. Twelfths keep every operation a
/// product or a sum: the same operations in the same order for float and double, and in the gl
/// backend's shader (runtime/gl/shaders/solver_shaders.h `cell_pass`).
template <class Real>
[[gnu::always_inline]] inline Real cell_volume12(const Real (&p)[8][3], Real (*gradient)[3]) {
    Real volume{};  // zero (Real{} also for a SIMD vector of floats, lane by lane the same operations)
    if (gradient)
        for (int c = 0; c < 8; ++c) gradient[c][0] = gradient[c][1] = gradient[c][2] = Real{};
    auto cross = [](const Real* a, const Real* b, Real* out) {
        out[0] = a[1] * b[2] - a[2] * b[1];
        out[1] = a[2] * b[0] - a[0] * b[2];
        out[2] = a[0] * b[1] - a[1] * b[0];
    };
    for (const auto& face : cell_faces) {
        // The cone from the origin over the bilinear patch (p0, p1, p2, p3) is the mean of its two
        // triangulations' cones (the patch halves the tetrahedron of its corners): S/12, with
        // S = p0·(p1×p2 + p2×p3) + p1·(p2×p3 + p3×p0).
        const Real* p0 = p[face[0]];
        const Real* p1 = p[face[1]];
        const Real* p2 = p[face[2]];
        const Real* p3 = p[face[3]];
        Real c01[3], c02[3], c03[3], c12[3], c13[3], c23[3];
        cross(p0, p1, c01), cross(p0, p2, c02), cross(p0, p3, c03);
        cross(p1, p2, c12), cross(p1, p3, c13), cross(p2, p3, c23);
        for (int k = 0; k < 3; ++k) volume = volume + (p0[k] * (c12[k] + c23[k]) + p1[k] * (c23[k] - c03[k]));
        if (!gradient) continue;
        for (int k = 0; k < 3; ++k) {
            gradient[face[0]][k] = gradient[face[0]][k] + ((c12[k] + c23[k]) + c13[k]);
            gradient[face[1]][k] = gradient[face[1]][k] + ((c23[k] - c02[k]) - c03[k]);
            gradient[face[2]][k] = gradient[face[2]][k] + ((c01[k] - c03[k]) - c13[k]);
            gradient[face[3]][k] = gradient[face[3]][k] + ((c02[k] + c12[k]) + c01[k]);
        }
    }
    return volume;
}

/// Twelve times the volume of the cell whose corners are the particles `corner` at their rest
/// positions (double, corner 0 the origin), and, unless null, twelve times its gradient.
double rest_cell_volume12(const Particles& particles, const std::array<std::int32_t, 8>& corner, double (*gradient)[3] = nullptr);

/// A cell's forces on its corners, N, 3 per corner: f = −Δλ/|V₀|·(V − V₀)·∂V/∂x written in
/// twelfths, −k₁₂·(12V − 12V₀)·(12∂V/∂x) with k₁₂ = Δλ/(144·|V₀|). `x` the corners' positions, in
/// any Real (those of corner 0 subtracted first). The cpu solver's pass and its force on one
/// particle, and the gl backend's `cell_pass`, make these same operations.
template <class Real>
void cell_forces(const Real* const (&x)[8], Real k12, Real rest12, Real* out) {
    Real p[8][3], g[8][3];
    for (int q = 0; q < 8; ++q)
        for (int k = 0; k < 3; ++k) p[q][k] = x[q][k] - x[0][k];
    const Real volume12 = cell_volume12<Real>(p, g);
    const Real pressure = -(k12 * (volume12 - rest12));
    for (int q = 0; q < 8; ++q)
        for (int k = 0; k < 3; ++k) out[3 * q + k] = pressure * g[q][k];
}

}  // namespace heartsim
