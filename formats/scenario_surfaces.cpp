// /visual, /packing, /simsurface and /mapping of the scenario file.
#include "scenario_surfaces.h"

#include "scenario_checks.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace heartsim {

void write_surfaces(h5::Writer& w, const Scenario& s) {
    if (s.visual) {
        const std::string g = "visual";
        w.group(g);
        const auto& v = *s.visual;
        w.dataset(g + "/positions", v.positions, {v.positions.size(), 3});
        w.dataset(g + "/normals", v.normals, {v.normals.size(), 3});
        w.dataset(g + "/triangles", v.triangles, {v.triangles.size(), 3});
    }
    if (s.packing) {
        const std::string g = "packing";
        w.group(g);
        const auto& p = *s.packing;
        w.dataset(g + "/neighbours", p.neighbours, {p.neighbours.size(), 18});
        w.dataset(g + "/texture_coord", p.texture_coord, {p.texture_coord.size(), 2});
        w.attribute(g + "/texture_coord", "width", std::int32_t(p.width));
        w.attribute(g + "/texture_coord", "height", std::int32_t(p.height));
        w.attribute(g + "/texture_coord", "scheme", std::string(to_string(p.scheme)));
    }
    if (s.simulation_surface) {
        const std::string g = "simsurface";
        w.group(g);
        const auto& surface = *s.simulation_surface;
        if (surface.normal_weight.size() != surface.triangles.size())
            throw InputError("scenario: the simulation surface has " + std::to_string(surface.normal_weight.size()) +
                             " normal weights for " + std::to_string(surface.triangles.size()) + " triangles");
        w.dataset(g + "/triangles", surface.triangles, {surface.triangles.size(), 3});
        w.dataset(g + "/normal_weight", surface.normal_weight, {surface.normal_weight.size()});
    }
    if (s.mapping) {
        const std::string g = "mapping";
        w.group(g);
        const auto& m = *s.mapping;
        w.dataset(g + "/triangle", m.triangle, {m.triangle.size()});
        w.dataset(g + "/barycentric", m.barycentric, {m.barycentric.size(), 3});
        w.dataset(g + "/offset", m.offset, {m.offset.size()});
        if (m.particles.size() != m.weights.size() || (!m.particles.empty() && m.particles.size() != m.triangle.size()))
            throw InputError("scenario: the mapping has " + std::to_string(m.particles.size()) + " carrier rows and " +
                             std::to_string(m.weights.size()) + " weight rows for " + std::to_string(m.triangle.size()) +
                             " visual vertices");
        if (!m.particles.empty()) {
            w.dataset(g + "/particles", m.particles, {m.particles.size(), 8});
            w.dataset(g + "/weights", m.weights, {m.weights.size(), 8});
        }
    }
}

/// /visual, when present.
void read_visual(const h5::Reader& r, Scenario& s) {
    if (!r.exists("visual")) return;
    VisualMesh v;
    std::size_t count = 0;
    auto positions = r.dataset<float>("visual/positions", {-1, 3}, &count);
    r.require_finite("visual/positions", positions);
    require_plausible(r, "visual/positions", positions, plausible::coordinate_mm);
    auto normals = r.dataset<float>("visual/normals", {long(count), 3});
    r.require_finite("visual/normals", normals);
    auto triangles = r.dataset<std::int32_t>("visual/triangles", {-1, 3});
    require_indices(r, "visual/triangles", triangles, count);
    v.positions = h5::rows_of<3>(positions);
    v.normals = h5::rows_of<3>(normals);
    v.triangles = h5::rows_of<3>(triangles);
    s.visual = std::move(v);
}

/// /packing, /simsurface and /mapping, each optional, validated against the particles.
void read_packing_and_mapping(const h5::Reader& r, Scenario& s) {
    const std::size_t n = s.lattice.particles.size();
    if (r.exists("packing")) {
        Packing p;
        auto flat = r.dataset<std::int32_t>("packing/neighbours", {long(n), 18});
        p.neighbours = h5::rows_of<18>(flat);
        for (std::size_t i = 0; i < n; ++i)
            for (int slot = 0; slot < 18; ++slot) {
                const std::int32_t j = p.neighbours[i][std::size_t(slot)];
                if (j == -1) continue;
                if (j < 0 || std::size_t(j) >= n)
                    r.fail("packing/neighbours", "row " + std::to_string(i) + " slot " + std::to_string(slot) + " is " +
                                                     std::to_string(j) + ", outside [-1, " + std::to_string(n) + ")");
                if (p.neighbours[std::size_t(j)][std::size_t(opposite_slot(slot))] != std::int32_t(i))
                    r.fail("packing/neighbours", "not symmetric: particle " + std::to_string(i) + " slot " + std::to_string(slot) +
                                                     " holds " + std::to_string(j) + " but " + std::to_string(j) +
                                                     "'s opposite slot does not hold " + std::to_string(i));
            }
        for (std::size_t k = 0; k < s.lattice.springs.size(); ++k) {
            const auto [a, b] = s.lattice.springs.pairs[k];
            const auto& row = p.neighbours[std::size_t(a)];
            if (std::find(row.begin(), row.end(), b) == row.end())
                r.fail("packing/neighbours", "spring " + std::to_string(k) + " (" + std::to_string(a) + ", " + std::to_string(b) +
                                                 ") has no neighbour slot");
        }
        p.texture_coord = h5::rows_of<2>(r.dataset<std::int32_t>("packing/texture_coord", {long(n), 2}));
        p.width = r.number<std::int32_t>("packing/texture_coord", "width");
        p.height = r.number<std::int32_t>("packing/texture_coord", "height");
        try {
            p.scheme = parse_packing_scheme(r.string_attribute("packing/texture_coord", "scheme"));
        } catch (const InputError& e) {
            r.fail("/packing/texture_coord", std::string("attribute scheme: ") + e.what());
        }
        if (p.width <= 0 || p.height <= 0) r.fail("/packing/texture_coord", "width and height must be positive");
        if (p.width > max_texture_side || p.height > max_texture_side)
            r.fail("/packing/texture_coord", "width x height " + std::to_string(p.width) + " x " + std::to_string(p.height) +
                                                 ": at most " + std::to_string(max_texture_side) +
                                                 " texels a side (what heartprep packs and every GPU holds)");
        std::vector<std::uint8_t> used(std::size_t(p.width) * std::size_t(p.height), 0);
        for (std::size_t i = 0; i < n; ++i) {
            const auto [x, y] = p.texture_coord[i];
            if (x < 0 || y < 0 || x >= p.width || y >= p.height)
                r.fail("packing/texture_coord", "row " + std::to_string(i) + " lies outside the " + std::to_string(p.width) + " x " +
                                                    std::to_string(p.height) + " texture");
            if (used[std::size_t(y) * std::size_t(p.width) + std::size_t(x)]++)
                r.fail("packing/texture_coord", "row " + std::to_string(i) + " shares its texel with another particle");
        }
        s.packing = std::move(p);
    }
    if (r.exists("simsurface")) {
        auto flat = r.dataset<std::int32_t>("simsurface/triangles", {-1, 3});
        require_indices(r, "simsurface/triangles", flat, n);
        SimulationSurface surface;
        surface.triangles = h5::rows_of<3>(flat);
        if (r.exists("simsurface/normal_weight")) {
            // ➕ One per triangle, 0 or 1. Files written before it existed count every triangle.
            surface.normal_weight = r.dataset<std::uint8_t>("simsurface/normal_weight", {long(surface.triangles.size())});
            for (std::size_t t = 0; t < surface.normal_weight.size(); ++t)
                if (surface.normal_weight[t] > 1)
                    r.fail("simsurface/normal_weight", "entry " + std::to_string(t) + " is " +
                                                           std::to_string(int(surface.normal_weight[t])) + ", not 0 or 1");
        } else {
            surface.normal_weight.assign(surface.triangles.size(), 1);
        }
        s.simulation_surface = std::move(surface);
    }
    if (r.exists("mapping")) {
        if (!s.visual) r.fail("mapping", "present without /visual");
        if (!s.simulation_surface) r.fail("mapping", "present without /simsurface");
        const long v = long(s.visual->positions.size());
        VisualMapping m;
        m.triangle = r.dataset<std::int32_t>("mapping/triangle", {v});
        require_indices(r, "mapping/triangle", m.triangle, s.simulation_surface->size());
        auto weights = r.dataset<float>("mapping/barycentric", {v, 3});
        r.require_finite("mapping/barycentric", weights);
        m.barycentric = h5::rows_of<3>(weights);
        for (std::size_t i = 0; i < m.barycentric.size(); ++i) {
            const auto& b = m.barycentric[i];
            if (std::abs(double(b[0]) + b[1] + b[2] - 1.0) > 1e-3)
                r.fail("mapping/barycentric", "row " + std::to_string(i) + " does not sum to 1");
        }
        m.offset = r.dataset<float>("mapping/offset", {v});
        r.require_finite("mapping/offset", m.offset);
        {  // |offset| is a distance to the nearest simulation-surface point: never beyond the model's extent
            Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), high = -low;
            for (const auto* points : {&s.lattice.particles.rest_position, &s.visual->positions})
                for (const auto& x : *points) {
                    const Eigen::Vector3d y(x[0], x[1], x[2]);
                    low = low.cwiseMin(y), high = high.cwiseMax(y);
                }
            const double reach = (high - low).norm();
            for (std::size_t i = 0; i < m.offset.size(); ++i)
                if (!(std::abs(double(m.offset[i])) <= reach * (1 + 1e-6)))
                    r.fail("mapping/offset", "entry " + std::to_string(i) + " is " + std::to_string(m.offset[i]) +
                                                 " mm, farther than the " + std::to_string(reach) +
                                                 " mm across the particles and the visual mesh");
        }
        // ➕ The carriers (format_version 3). A file without them reads as the triangle's three.
        const bool has_particles = r.exists("mapping/particles"), has_weights = r.exists("mapping/weights");
        if (has_particles != has_weights)
            r.fail(has_particles ? "mapping/weights" : "mapping/particles", "missing (mapping/particles and mapping/weights go together)");
        if (has_particles) {
            auto carriers = r.dataset<std::int32_t>("mapping/particles", {v, 8});
            require_indices(r, "mapping/particles", carriers, s.lattice.particles.size());
            m.particles = h5::rows_of<8>(carriers);
            auto carried = r.dataset<float>("mapping/weights", {v, 8});
            r.require_finite("mapping/weights", carried);
            m.weights = h5::rows_of<8>(carried);
            for (std::size_t i = 0; i < m.weights.size(); ++i) {
                double sum = 0.0;
                for (float w : m.weights[i]) sum += double(w);
                if (std::abs(sum - 1.0) > 1e-3) r.fail("mapping/weights", "row " + std::to_string(i) + " does not sum to 1");
            }
        }
        s.mapping = std::move(m);
    }
}

}  // namespace heartsim
