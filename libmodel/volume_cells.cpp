// The volume term's cells and moduli (volume_cells.h).
#include "libmodel/volume_cells.h"

#include "libmodel/errors.h"

#include <cmath>
#include <string>
#include <unordered_map>

namespace heartsim {

const std::array<std::array<int, 4>, 6> cell_faces{{
    {0, 4, 6, 2},  // −i
    {1, 3, 7, 5},  // +i
    {0, 1, 5, 4},  // −j
    {2, 6, 7, 3},  // +j
    {0, 2, 3, 1},  // −k
    {4, 5, 7, 6},  // +k
}};

const std::array<std::array<int, 2>, 24> cell_springs = [] {
    std::array<std::array<int, 2>, 24> springs{};
    int n = 0;
    for (int a = 0; a < 8; ++a)
        for (int b = a + 1; b < 8; ++b)
            if (const int bits = __builtin_popcount(unsigned(a ^ b)); bits == 1 || bits == 2) springs[std::size_t(n++)] = {a, b};
    return springs;
}();

double shear_modulus(double youngs_modulus_kpa, double poisson_ratio) {
    return 1e-3 * youngs_modulus_kpa / (2.0 * (1.0 + poisson_ratio));
}

double added_lame_modulus(double youngs_modulus_kpa, double poisson_ratio) {
    if (!(poisson_ratio >= 0.25 && poisson_ratio < 0.5))
        throw InputError("Poisson's ratio " + std::to_string(poisson_ratio) + " lies outside [0.25, 0.5): the lattice's springs give 1/4, the volume term only adds to it");
    return shear_modulus(youngs_modulus_kpa, poisson_ratio) * (4.0 * poisson_ratio - 1.0) / (1.0 - 2.0 * poisson_ratio);
}

std::vector<double> added_lame_moduli(const std::vector<Material>& materials) {
    std::vector<double> out;
    out.reserve(materials.size());
    for (const Material& m : materials) out.push_back(added_lame_modulus(m.youngs_modulus_kpa, m.poisson_ratio));
    return out;
}

double rest_cell_volume12(const Particles& particles, const std::array<std::int32_t, 8>& corner, double (*gradient)[3]) {
    double p[8][3];
    for (int q = 0; q < 8; ++q)
        for (int k = 0; k < 3; ++k)
            p[q][k] = double(particles.rest_position[std::size_t(corner[std::size_t(q)])][std::size_t(k)]) -
                      double(particles.rest_position[std::size_t(corner[0])][std::size_t(k)]);
    return cell_volume12<double>(p, gradient);
}

VolumeCells volume_cells(const Particles& particles, const std::vector<double>& added_modulus) {
    VolumeCells cells;
    bool any = false;
    for (double m : added_modulus) any = any || m > 0;
    if (!any || particles.size() == 0) return cells;
    if (particles.lattice_index.size() != particles.size())
        throw InputError("the volume term (a Poisson's ratio above 1/4) needs each particle's lattice index");
    auto key = [](long i, long j, long k) { return (std::uint64_t(k) << 42) | (std::uint64_t(j) << 21) | std::uint64_t(i); };
    std::unordered_map<std::uint64_t, std::int32_t> at;
    at.reserve(particles.size());
    for (std::size_t p = 0; p < particles.size(); ++p) {
        const auto& c = particles.lattice_index[p];
        at.emplace(key(c[0], c[1], c[2]), std::int32_t(p));
    }
    auto modulus_of = [&](std::int32_t p) {
        const std::size_t row = particles.material.empty() ? 0 : std::size_t(particles.material[std::size_t(p)]);
        return row < added_modulus.size() ? added_modulus[row] : 0.0;
    };
    for (std::size_t p = 0; p < particles.size(); ++p) {
        const auto& c = particles.lattice_index[p];
        std::array<std::int32_t, 8> corner{};
        bool whole = true;
        double modulus = 0.0;
        for (int q = 0; q < 8 && whole; ++q) {
            const auto found = at.find(key(c[0] + (q & 1), c[1] + ((q >> 1) & 1), c[2] + ((q >> 2) & 1)));
            if (found == at.end()) whole = false;
            else corner[std::size_t(q)] = found->second, modulus += modulus_of(found->second);
        }
        if (!whole || !(modulus > 0)) continue;
        const double volume = rest_cell_volume12(particles, corner) / 12.0;
        if (!(std::abs(volume) > 0)) continue;
        cells.corner.push_back(corner);
        cells.modulus.push_back(modulus / 8.0);
        cells.rest_volume.push_back(volume);
    }
    return cells;
}

}  // namespace heartsim
