#include "libmodel/lattice.h"

#include "libmodel/errors.h"
#include "libmodel/select.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace heartsim {

const std::array<std::array<int, 3>, 18> neighbour_offsets{{
    {1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1},
    {1, 1, 0}, {1, -1, 0}, {-1, 1, 0}, {-1, -1, 0},
    {1, 0, 1}, {1, 0, -1}, {-1, 0, 1}, {-1, 0, -1},
    {0, 1, 1}, {0, 1, -1}, {0, -1, 1}, {0, -1, -1},
}};

ParticleGrid::ParticleGrid(const Lattice& lattice) {
    for (std::size_t a = 0; a < 3; ++a) dims_[a] = std::max(0, lattice.dims[a]);
    cells_.assign(std::size_t(dims_[0] * dims_[1] * dims_[2]), -1);
    const auto& index = lattice.particles.lattice_index;
    for (std::size_t p = 0; p < index.size(); ++p) {
        const auto& c = index[p];
        if (c[0] < 0 || c[1] < 0 || c[2] < 0 || c[0] >= dims_[0] || c[1] >= dims_[1] || c[2] >= dims_[2])
            throw InputError("particle " + std::to_string(p) + " has a lattice index outside the lattice's dims");
        cells_[std::size_t((long(c[2]) * dims_[1] + c[1]) * dims_[0] + c[0])] = std::int32_t(p);
    }
}

std::vector<char> thin_wall_particles(const Lattice& lattice) {
    const ParticleGrid grid(lattice);
    const auto& index = lattice.particles.lattice_index;
    std::vector<char> thin(index.size(), 0);
    for (std::size_t p = 0; p < index.size(); ++p) {
        const auto& c = index[p];
        for (std::size_t a = 0; a < 3 && !thin[p]; ++a) {
            std::array<std::int32_t, 3> below = c, above = c;
            --below[a];
            ++above[a];
            thin[p] = grid.at(below) < 0 && grid.at(above) < 0;
        }
    }
    return thin;
}

ThinWallSummary summarise_thin_walls(const Lattice& lattice) {
    const auto& p = lattice.particles;
    const std::vector<char> thin = thin_wall_particles(lattice);
    ThinWallSummary summary;
    double thin_volume = 0.0, volume = 0.0;
    for (std::size_t i = 0; i < p.size(); ++i) {
        const auto row = std::size_t(p.material[i]);
        const double v = double(p.mass[i]) / (row < lattice.materials.size() ? lattice.materials[row].density : Material{}.density);
        volume += v;
        if (thin[i]) ++summary.particles, thin_volume += v;
    }
    summary.volume_share = volume > 0 ? thin_volume / volume : 0.0;
    return summary;
}

double spring_stiffness(double youngs_modulus_kpa, double spacing_mm, double poisson_ratio) {
    // 0.5/(1 + ν) is 0.4 to the bit at ν = 1/4.
    return (0.5 / (1.0 + poisson_ratio)) * (youngs_modulus_kpa * 1e-3) * spacing_mm;
}

namespace {

/// Overlap weights between lattice cells and voxels along one axis: cell c covers
/// [c·h, (c+1)·h) and voxel i covers [i·s, (i+1)·s) in mm from the volume's lower edge;
/// weight = overlap length / h, so summing weight × mask gives the cell's tissue fraction.
struct AxisWeights {
    struct Entry {
        int voxel;
        float weight;
    };
    int cells = 0;
    std::vector<std::vector<Entry>> per_cell;
};

AxisWeights axis_weights(int voxels, double voxel_size, double cell_size) {
    AxisWeights weights;
    const double length = voxels * voxel_size;
    weights.cells = std::max(1, int(std::ceil(length / cell_size - 1e-9)));
    weights.per_cell.resize(std::size_t(weights.cells));
    for (int c = 0; c < weights.cells; ++c) {
        const double low = c * cell_size, high = (c + 1) * cell_size;
        const int first = std::max(0, int(std::floor(low / voxel_size)));
        const int last = std::min(voxels - 1, int(std::ceil(high / voxel_size)) - 1);
        for (int i = first; i <= last; ++i) {
            const double overlap = std::min(high, (i + 1) * voxel_size) - std::max(low, i * voxel_size);
            if (overlap > 0) weights.per_cell[std::size_t(c)].push_back({i, float(overlap / cell_size)});
        }
    }
    return weights;
}

struct CellGrid {
    std::array<AxisWeights, 3> axes;
    std::array<int, 3> dims() const { return {axes[0].cells, axes[1].cells, axes[2].cells}; }
    std::size_t count() const { return std::size_t(axes[0].cells) * axes[1].cells * axes[2].cells; }
};

CellGrid make_cell_grid(const VolumeGeometry& g, double spacing) {
    CellGrid grid;
    for (int a = 0; a < 3; ++a) grid.axes[std::size_t(a)] = axis_weights(g.dims[std::size_t(a)], g.spacing[a], spacing);
    return grid;
}

/// Fraction of each cell covered by `mask`, exact for box-shaped voxels: three separable
/// passes (i, then j, then k), each parallel over independent slabs, so the result does not
/// depend on the thread count.
std::vector<float> cell_fractions(const Mask& mask, const CellGrid& grid) {
    const auto& g = mask.geometry;
    const int n1 = g.dims[1], n2 = g.dims[2];
    // Plain variables, not a structured binding: clang 14 (the sanitize preset) cannot capture
    // those in the lambdas below.
    const auto cells = grid.dims();
    const int c0 = cells[0], c1 = cells[1], c2 = cells[2];
    std::vector<float> pass_i(std::size_t(c0) * n1 * n2);
    tbb::parallel_for(0, n2, [&](int k) {
        for (int j = 0; j < n1; ++j) {
            const std::uint8_t* row = &mask.values[g.linear(0, j, k)];
            float* out = &pass_i[(std::size_t(k) * n1 + j) * c0];
            for (int c = 0; c < c0; ++c) {
                float sum = 0;
                for (const auto& e : grid.axes[0].per_cell[std::size_t(c)]) sum += e.weight * float(row[e.voxel]);
                out[c] = sum;
            }
        }
    });
    std::vector<float> pass_j(std::size_t(c0) * c1 * n2);
    tbb::parallel_for(0, n2, [&](int k) {
        for (int b = 0; b < c1; ++b) {
            float* out = &pass_j[(std::size_t(k) * c1 + b) * c0];
            std::fill(out, out + c0, 0.0f);
            for (const auto& e : grid.axes[1].per_cell[std::size_t(b)]) {
                const float* in = &pass_i[(std::size_t(k) * n1 + e.voxel) * c0];
                for (int a = 0; a < c0; ++a) out[a] += e.weight * in[a];
            }
        }
    });
    std::vector<float> fraction(grid.count());
    tbb::parallel_for(0, c2, [&](int c) {
        float* out = &fraction[std::size_t(c) * c0 * c1];
        std::fill(out, out + std::size_t(c0) * c1, 0.0f);
        for (const auto& e : grid.axes[2].per_cell[std::size_t(c)]) {
            const float* in = &pass_j[std::size_t(e.voxel) * c0 * c1];
            for (std::size_t n = 0; n < std::size_t(c0) * c1; ++n) out[n] += e.weight * in[n];
        }
    });
    return fraction;
}

/// The cells that get a particle: tissue fraction at least `occupancy` (compared in float); with
/// thin-wall handling also the ridges of thinner walls, then the fuller side neighbour of every
/// occupied cell that is one cell thick along an axis, if that neighbour holds at least
/// `thicken_fraction`. 1: occupied (threshold or ridge), 2: added to thicken.
std::vector<std::uint8_t> occupied_cells(const std::vector<float>& fraction, const std::array<int, 3>& dims,
                                         const LayoutOptions& options) {
    const float threshold = float(options.occupancy);
    std::vector<std::uint8_t> occupied(fraction.size(), 0);
    for (std::size_t c = 0; c < fraction.size(); ++c) occupied[c] = fraction[c] >= threshold ? 1 : 0;
    if (!options.thicken_walls) return occupied;
    const std::array<long, 3> stride{1, long(dims[0]), long(dims[0]) * dims[1]};
    // Walls thinner than half a cell: a cell whose fraction is a ridge across some axis (at least
    // both face neighbours' along it, more than one's), with at least `ridge_fraction` and no
    // occupied neighbour along that axis, holds a wall the occupancy threshold would lose. (A
    // bump of thick tissue's surface can pass this test too, along an axis tangent to the
    // surface: a light particle there, 3-5 % of the budget on the real cases; see docs.)
    const float ridge_fraction = float(options.ridge_fraction);
    std::vector<std::uint8_t> ridges(fraction.size(), 0);
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                const std::array<int, 3> at{i, j, k};
                const long cell = (long(k) * dims[1] + j) * dims[0] + i;
                const float f = fraction[std::size_t(cell)];
                if (occupied[std::size_t(cell)] || f < ridge_fraction) continue;
                for (std::size_t a = 0; a < 3 && !ridges[std::size_t(cell)]; ++a) {
                    const long below = at[a] > 0 ? cell - stride[a] : -1;
                    const long above = at[a] + 1 < dims[a] ? cell + stride[a] : -1;
                    const float f_below = below >= 0 ? fraction[std::size_t(below)] : 0.0f;
                    const float f_above = above >= 0 ? fraction[std::size_t(above)] : 0.0f;
                    const bool beside = (below >= 0 && occupied[std::size_t(below)]) || (above >= 0 && occupied[std::size_t(above)]);
                    ridges[std::size_t(cell)] = !beside && f >= f_below && f >= f_above && (f > f_below || f > f_above);
                }
            }
    for (std::size_t c = 0; c < fraction.size(); ++c)
        if (ridges[c]) occupied[c] = 1;
    const float enough = float(options.thicken_fraction);
    for (int k = 0; k < dims[2]; ++k)
        for (int j = 0; j < dims[1]; ++j)
            for (int i = 0; i < dims[0]; ++i) {
                const std::array<int, 3> at{i, j, k};
                const long cell = (long(k) * dims[1] + j) * dims[0] + i;
                if (occupied[std::size_t(cell)] != 1) continue;
                for (std::size_t a = 0; a < 3; ++a) {
                    // The two face neighbours along axis a (-1: outside the lattice); a neighbour
                    // already added for another particle thickens this one too.
                    const long below = at[a] > 0 ? cell - stride[a] : -1;
                    const long above = at[a] + 1 < dims[a] ? cell + stride[a] : -1;
                    if ((below >= 0 && occupied[std::size_t(below)]) || (above >= 0 && occupied[std::size_t(above)])) continue;
                    const float f_below = below >= 0 ? fraction[std::size_t(below)] : -1.0f;
                    const float f_above = above >= 0 ? fraction[std::size_t(above)] : -1.0f;
                    const long side = f_above >= f_below ? above : below;
                    if (side >= 0 && std::max(f_above, f_below) >= enough) occupied[std::size_t(side)] = 2;
                }
            }
    return occupied;
}

std::size_t count_occupied(const std::vector<float>& fraction, const std::array<int, 3>& dims, const LayoutOptions& options) {
    const auto occupied = occupied_cells(fraction, dims, options);
    return std::size_t(std::count_if(occupied.begin(), occupied.end(), [](std::uint8_t o) { return o != 0; }));
}

/// The spacing whose lattice holds the most particles without exceeding `budget`: bisection on
/// the spacing, starting from the tissue volume / budget estimate.
double spacing_for_budget(const Mask& tissue, std::size_t budget, const LayoutOptions& options, Progress& progress,
                          std::size_t& trials) {
    const auto& g = tissue.geometry;
    const double tissue_volume = double(tissue.count()) * g.voxel_volume();
    auto count_at = [&](double h) {
        ++trials;
        if (progress.cancelled()) throw Cancelled();
        const CellGrid grid = make_cell_grid(g, h);
        return count_occupied(cell_fractions(tissue, grid), grid.dims(), options);
    };
    const double finest = 0.25 * g.spacing.minCoeff();
    double high = std::max(finest, std::cbrt(tissue_volume / double(budget)));
    while (count_at(high) > budget) high *= 1.25;
    double low = high / 1.25;
    while (low > finest && count_at(low) <= budget) {
        high = low;
        low /= 1.25;
    }
    if (low <= finest) return high;
    for (int iteration = 0; iteration < 14; ++iteration) {
        const double middle = 0.5 * (low + high);
        (count_at(middle) <= budget ? high : low) = middle;
        progress.update(std::uint64_t(iteration + 1));
    }
    return high;
}

}  // namespace

Lattice layout_particles(const Selection& selection, const std::vector<int>& tissue_labels,
                         const LabelVolume& volume, const LayoutOptions& options, Progress& progress,
                         LayoutReport* report_out) {
    const auto& g = selection.tissue.geometry;
    if (!(options.occupancy > 0.0 && options.occupancy <= 1.0))
        throw InputError("{LayoutOptions::occupancy} must be in (0, 1], got " + std::to_string(options.occupancy));
    if (!(options.thicken_fraction > 0.0 && options.thicken_fraction <= 1.0))
        throw InputError("{LayoutOptions::thicken_fraction} must be in (0, 1], got " + std::to_string(options.thicken_fraction));
    if (!(options.ridge_fraction > 0.0 && options.ridge_fraction <= 1.0))
        throw InputError("{LayoutOptions::ridge_fraction} must be in (0, 1], got " + std::to_string(options.ridge_fraction));
    if (!std::isfinite(options.spacing_mm) || options.spacing_mm < 0.0)
        throw InputError("{LayoutOptions::spacing_mm} must be a positive number of mm, got " + std::to_string(options.spacing_mm));
    if (options.spacing_mm == 0.0 && options.particle_budget == 0)
        throw InputError("{LayoutOptions::particle_budget} must be at least 1");
    if (options.materials.empty()) throw InputError("no material given");
    for (const auto& m : options.materials)
        if (!(m.density > 0) || !(m.youngs_modulus_kpa > 0) || !(m.damping_ratio >= 0) || !std::isfinite(m.density) ||
            !std::isfinite(m.youngs_modulus_kpa) || !std::isfinite(m.damping_ratio))
            throw InputError("material '" + m.name + "': density and Young's modulus must be positive and finite, "
                             "damping ratio non-negative");

    LayoutReport report;
    double spacing = options.spacing_mm;
    {
        ProgressStage stage(progress, "choose spacing", spacing > 0 ? 0 : 14);
        if (spacing == 0.0)
            spacing = spacing_for_budget(selection.tissue, options.particle_budget, options, progress, report.spacing_trials);
    }
    ProgressStage stage(progress, "lay out particles", 3);

    Lattice lattice;
    lattice.spacing = spacing;
    const CellGrid grid = make_cell_grid(g, spacing);
    lattice.dims = grid.dims();
    const Eigen::Matrix3d axes = g.direction * spacing;
    lattice.index_to_world.topLeftCorner<3, 3>() = axes;
    lattice.index_to_world.topRightCorner<3, 1>() =
        g.origin + g.direction * (Eigen::Vector3d::Constant(0.5 * spacing) - 0.5 * g.spacing);

    // Material table: one row per tissue label, taken from the options by label.
    for (std::size_t t = 0; t < tissue_labels.size(); ++t) {
        auto found = std::find_if(options.materials.begin(), options.materials.end(),
                                  [&](const Material& m) { return m.label == tissue_labels[t]; });
        Material material = found != options.materials.end() ? *found : options.materials.front();
        if (found == options.materials.end() && t > 0) material.name = "label_" + std::to_string(tissue_labels[t]);
        material.label = tissue_labels[t];
        lattice.materials.push_back(material);
    }

    // Tissue fraction per cell, and per label where there are several tissue labels.
    const std::vector<float> fraction = cell_fractions(selection.tissue, grid);
    std::vector<std::vector<float>> label_fraction;
    if (tissue_labels.size() > 1) {
        Mask one_label{g, std::vector<std::uint8_t>(g.voxel_count())};
        for (int label : tissue_labels) {
            for (std::size_t v = 0; v < one_label.values.size(); ++v)
                one_label.values[v] = selection.tissue.values[v] && volume.labels[v] == label;
            label_fraction.push_back(cell_fractions(one_label, grid));
        }
    }
    const bool any_anchor = selection.anchors.count() > 0;
    const std::vector<float> anchor_fraction = any_anchor ? cell_fractions(selection.anchors, grid) : std::vector<float>();
    stage.update(1);

    const std::vector<std::uint8_t> occupied = occupied_cells(fraction, lattice.dims, options);
    const double cell_volume = spacing * spacing * spacing;
    std::vector<std::int32_t> particle_of_cell(grid.count(), -1);
    std::vector<float> particle_fraction;  // tissue fraction of each particle's cell
    auto& p = lattice.particles;
    for (int c = 0; c < lattice.dims[2]; ++c)
        for (int b = 0; b < lattice.dims[1]; ++b)
            for (int a = 0; a < lattice.dims[0]; ++a) {
                const std::size_t cell = (std::size_t(c) * lattice.dims[1] + b) * lattice.dims[0] + a;
                if (!occupied[cell]) continue;
                if (occupied[cell] == 2) ++report.thickened;
                if (occupied[cell] == 1 && fraction[cell] < float(options.occupancy)) ++report.ridges;
                std::size_t material = 0;
                for (std::size_t t = 1; t < label_fraction.size(); ++t)
                    if (label_fraction[t][cell] > label_fraction[material][cell]) material = t;
                particle_of_cell[cell] = std::int32_t(p.size());
                const Eigen::Vector3d x = (lattice.index_to_world * Eigen::Vector4d(a, b, c, 1)).head<3>();
                p.rest_position.push_back({float(x.x()), float(x.y()), float(x.z())});
                p.lattice_index.push_back({a, b, c});
                particle_fraction.push_back(std::min(1.0f, fraction[cell]));
                const double occupied = std::min(1.0, double(fraction[cell])) * cell_volume;
                p.mass.push_back(float(lattice.materials[material].density * occupied));
                p.material.push_back(std::int32_t(material));
                p.anchored.push_back(any_anchor && anchor_fraction[cell] > 0.0f ? 1 : 0);
                report.occupied_volume_mm3 += occupied;
                report.total_mass += p.mass.back();
                report.anchored += p.anchored.back();
            }
    if (p.size() == 0)
        throw InputError("no lattice cell reaches {LayoutOptions::occupancy} " + std::to_string(options.occupancy) +
                         " at spacing " + std::to_string(spacing) + " mm: lower the spacing or the occupancy");
    if (p.size() > std::size_t(std::numeric_limits<std::int32_t>::max() / 18))
        throw InputError("too many particles (" + std::to_string(p.size()) + "): raise {LayoutOptions::spacing_mm}");
    stage.update(2);

    // Springs: each particle to the neighbours at the 9 offsets whose first non-zero component
    // is positive (3 face + 6 edge), so every one of the 18 neighbour pairs appears exactly once.
    std::vector<double> stiffness_of_material;
    for (const auto& m : lattice.materials) stiffness_of_material.push_back(spring_stiffness(m.youngs_modulus_kpa, spacing, m.poisson_ratio));
    auto& s = lattice.springs;
    for (std::size_t i = 0; i < p.size(); ++i) {
        const auto [a, b, c] = p.lattice_index[i];
        for (std::size_t slot = 0; slot < neighbour_offsets.size(); ++slot) {
            const auto& o = neighbour_offsets[slot];
            const int first_nonzero = o[0] != 0 ? o[0] : (o[1] != 0 ? o[1] : o[2]);
            if (first_nonzero < 0) continue;
            const int na = a + o[0], nb = b + o[1], nc = c + o[2];
            if (na < 0 || nb < 0 || nc < 0 || na >= lattice.dims[0] || nb >= lattice.dims[1] || nc >= lattice.dims[2]) continue;
            const std::int32_t j = particle_of_cell[(std::size_t(nc) * lattice.dims[1] + nb) * lattice.dims[0] + na];
            if (j < 0) continue;
            s.pairs.push_back({std::min(std::int32_t(i), j), std::max(std::int32_t(i), j)});
            const Eigen::Vector3d offset = axes * Eigen::Vector3d(o[0], o[1], o[2]);
            s.rest_length.push_back(float(offset.norm()));
            const double ka = stiffness_of_material[std::size_t(p.material[i])];
            const double kb = stiffness_of_material[std::size_t(p.material[std::size_t(j)])];
            // A thin-wall particle's cell holds less tissue than the occupancy threshold (LayoutOptions::occupancy): its springs carry
            // that much less material, in proportion (so k/m, and the stable time step, stay
            // those of a cell at the occupancy).
            const double full = double(float(options.occupancy));  // the float the occupancy test compares with
            const double scale = std::min(1.0, double(std::min(particle_fraction[i], particle_fraction[std::size_t(j)])) / full);
            s.stiffness.push_back(float(scale * 2.0 * ka * kb / (ka + kb)));  // two half-springs in series
            (slot < 6 ? report.face_springs : report.edge_springs)++;
        }
    }
    stage.update(3);

    report.spacing = spacing;
    report.particles = p.size();
    const ThinWallSummary thin = summarise_thin_walls(lattice);
    report.thin_particles = thin.particles;
    report.thin_volume_share = thin.volume_share;
    if (report.anchored == 0 && any_anchor)
        report.warnings.push_back("anchor voxels exist but no particle cell contains one");
    if (report_out) *report_out = std::move(report);
    return lattice;
}

Lattice uniform_block(const std::array<int, 3>& dims, double spacing, const Material& material) {
    LabelVolume volume;
    volume.geometry.dims = dims;
    volume.geometry.spacing = Eigen::Vector3d::Constant(spacing);
    volume.labels.assign(volume.geometry.voxel_count(), material.label);
    SelectionOptions selection_options;
    selection_options.tissue_labels = {material.label};
    selection_options.min_island_mm3 = 0.0;
    const Selection selection = select_tissue(volume, selection_options);
    LayoutOptions layout;
    layout.spacing_mm = spacing;
    layout.occupancy = 0.5;
    layout.materials = {material};
    return layout_particles(selection, {material.label}, volume, layout);
}

}  // namespace heartsim
