// The renderer's geometry made on the host (render_geometry.h): the records and lists its passes
// read, the instruments' sphere, the sheets; and a patch as the renderer draws it (renderer.h
// drawn_patch, patch_rgb). No GL here.
#include "runtime/gl/render_geometry.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <utility>

namespace heartsim {

namespace {

Eigen::Vector3f to_vector(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

}  // namespace

std::vector<float> grown_particles(const Scenario& scenario) {
    std::vector<float> grown;
    if (std::any_of(scenario.tissue_origin.begin(), scenario.tissue_origin.end(), [](const TissueOrigin& o) { return o.grown; })) {
        const auto& rest = scenario.lattice.particles.rest_position;
        const auto& material = scenario.lattice.particles.material;
        grown.assign(rest.size(), 0.0f);
        for (std::size_t i = 0; i < std::min(rest.size(), material.size()); ++i) {
            const std::size_t row = std::size_t(material[i]);
            grown[i] = row < scenario.tissue_origin.size() && scenario.tissue_origin[row].grown ? 1.0f : 0.0f;
        }
    }
    return grown;
}

SurfaceIncidence surface_incidence(const SimulationSurface& surface, std::size_t particles) {
    SurfaceIncidence lists;
    std::vector<std::uint32_t> count(particles, 0);
    for (std::size_t row = 0; row < surface.triangles.size(); ++row)
        if (surface.normal_weight[row])
            for (int v : surface.triangles[row]) ++count[std::size_t(v)];
    std::vector<std::uint32_t> slot_of(particles, 0);
    for (std::size_t i = 0; i < particles; ++i)
        if (count[i]) {
            slot_of[i] = lists.start.back();
            lists.surface_list.push_back(std::uint32_t(i));
            lists.start.push_back(lists.start.back() + count[i]);
        }
    lists.incidence.resize(lists.start.back());
    for (std::size_t row = 0; row < surface.triangles.size(); ++row) {
        if (!surface.normal_weight[row]) continue;
        const auto& t = surface.triangles[row];
        for (int v : t) lists.incidence[slot_of[std::size_t(v)]++] = {t[0], t[1], t[2], 0};
    }
    return lists;
}

std::vector<VertexRecord> particle_records(const std::vector<std::array<float, 3>>& rest, const std::vector<float>& grown) {
    std::vector<VertexRecord> records(rest.size());
    for (std::size_t i = 0; i < rest.size(); ++i) {
        const std::int32_t p = std::int32_t(i);
        records[i] = {{p, p, p}, {1, 0, 0}, 0, {0, 0, 0}, {0, 0, 0}, {p, p, p, p, p, p, p, p}, {1, 0, 0, 0, 0, 0, 0, 0},
                      {rest[i][0], rest[i][1], rest[i][2]}, grown.empty() ? 0.0f : grown[i]};
    }
    return records;
}

/// The unit sphere the instruments are drawn with (latitude-longitude, 32 × 16).
void unit_sphere(std::vector<float>& vertices, std::vector<std::uint32_t>& indices) {
    constexpr int slices = 32, stacks = 16;
    const double pi = 3.14159265358979323846;
    for (int i = 0; i <= stacks; ++i) {
        const double theta = pi * i / stacks;
        for (int j = 0; j <= slices; ++j) {
            const double phi = 2 * pi * j / slices;
            vertices.push_back(float(std::sin(theta) * std::cos(phi)));
            vertices.push_back(float(std::sin(theta) * std::sin(phi)));
            vertices.push_back(float(std::cos(theta)));
        }
    }
    for (int i = 0; i < stacks; ++i)
        for (int j = 0; j < slices; ++j) {
            const std::uint32_t a = std::uint32_t(i * (slices + 1) + j), b = a + slices + 1;
            indices.insert(indices.end(), {a, b, a + 1, a + 1, b, b + 1});
        }
}

/// Per triangle of `elements` (3 indices each), 1 where the same triangle is also drawn reversed:
/// the simulation surface's double-sided sheets at one-particle-thick walls (scenario-format.md
/// /simsurface). The section view lights both sides of those: they enclose no tissue to cut.
std::vector<std::uint32_t> sheet_triangles(const std::vector<std::uint32_t>& elements) {
    // A triangle as its indices turned so that the smallest comes first (the orientation kept).
    auto key = [](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
        if (b < a && b < c) return std::array<std::uint32_t, 3>{b, c, a};
        if (c < a && c < b) return std::array<std::uint32_t, 3>{c, a, b};
        return std::array<std::uint32_t, 3>{a, b, c};
    };
    const std::size_t count = elements.size() / 3;
    std::vector<std::array<std::uint32_t, 3>> keys(count);
    for (std::size_t t = 0; t < count; ++t) keys[t] = key(elements[3 * t], elements[3 * t + 1], elements[3 * t + 2]);
    std::vector<std::array<std::uint32_t, 3>> sorted = keys;
    std::sort(sorted.begin(), sorted.end());
    std::vector<std::uint32_t> sheet(std::max<std::size_t>(count, 1), 0);
    for (std::size_t t = 0; t < count; ++t) {
        const auto reversed = key(keys[t][0], keys[t][2], keys[t][1]);
        sheet[t] = std::binary_search(sorted.begin(), sorted.end(), reversed) ? 1u : 0u;
    }
    return sheet;
}

/// A patch's mid-surface made a closed sheet `thickness` thick: the surface moved half the
/// thickness along its vertex normals each way (the far side wound the other way), and a rim of
/// quads along its boundary edges, wound so that every face is counter-clockwise seen from
/// outside. The section view then shows where the plane cuts it as back faces, as it does the
/// wall's. `vertices`: position, normal (6 floats each); `elements`: 3 per triangle.
void patch_sheet(const DrawnPatch& patch, std::vector<float>& vertices, std::vector<std::uint32_t>& elements) {
    const std::size_t n = patch.positions.size();
    std::vector<Eigen::Vector3f> normal(n, Eigen::Vector3f::Zero());
    auto at = [&](std::int32_t i) { return to_vector(patch.positions[std::size_t(i)]); };
    for (const auto& t : patch.triangles) {
        const Eigen::Vector3f area = (at(t[1]) - at(t[0])).cross(at(t[2]) - at(t[0]));  // twice the area, along the winding's normal
        for (std::int32_t v : t) normal[std::size_t(v)] += area;
    }
    for (Eigen::Vector3f& m : normal) m = m.norm() > 0 ? Eigen::Vector3f(m.normalized()) : Eigen::Vector3f::UnitZ();
    const float half = 0.5f * patch.thickness_mm;
    auto vertex = [&](const Eigen::Vector3f& p, const Eigen::Vector3f& m) {
        vertices.insert(vertices.end(), {p.x(), p.y(), p.z(), m.x(), m.y(), m.z()});
    };
    for (std::size_t i = 0; i < n; ++i) vertex(to_vector(patch.positions[i]) + half * normal[i], normal[i]);   // near side: 0 … n−1
    for (std::size_t i = 0; i < n; ++i) vertex(to_vector(patch.positions[i]) - half * normal[i], -normal[i]);  // far side: n … 2n−1
    const auto far = std::uint32_t(n);
    for (const auto& t : patch.triangles) {
        elements.insert(elements.end(), {std::uint32_t(t[0]), std::uint32_t(t[1]), std::uint32_t(t[2])});
        elements.insert(elements.end(), {far + std::uint32_t(t[0]), far + std::uint32_t(t[2]), far + std::uint32_t(t[1])});
    }
    // Boundary edges: those of one triangle only, in that triangle's direction a → b. The near
    // side runs a → b along it, so the rim runs b → a there and a → b along the far side.
    std::map<std::pair<std::int32_t, std::int32_t>, int> edges;
    for (const auto& t : patch.triangles)
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            ++edges[{std::min(a, b), std::max(a, b)}];
        }
    for (const auto& t : patch.triangles)
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            if (edges[{std::min(a, b), std::max(a, b)}] != 1) continue;
            const auto first = std::uint32_t(vertices.size() / 6);
            const Eigen::Vector3f na = half * normal[std::size_t(a)], nb = half * normal[std::size_t(b)];
            for (const Eigen::Vector3f& p : {Eigen::Vector3f(at(b) + nb), Eigen::Vector3f(at(a) + na), Eigen::Vector3f(at(a) - na),
                                             Eigen::Vector3f(at(b) - nb)})
                vertex(p, Eigen::Vector3f::Zero());  // flat: the rim's face normal
            elements.insert(elements.end(), {first, first + 1, first + 2, first, first + 2, first + 3});
        }
}

std::array<int, 3> patch_rgb(const std::string& material) {
    if (material == "ptfe") return {214, 218, 222};
    if (material == "dacron") return {242, 242, 236};
    return {232, 222, 190};
}

DrawnPatch drawn_patch(const PatchModel& patch, const std::vector<Eigen::Vector3d>& anchors) {
    DrawnPatch drawn;
    auto to_float = [](const Eigen::Vector3d& x) { return std::array<float, 3>{float(x.x()), float(x.y()), float(x.z())}; };
    for (const Eigen::Vector3d& x : patch.positions()) drawn.positions.push_back(to_float(x));
    drawn.triangles = patch.triangles();
    drawn.thickness_mm = float(patch.spec().thickness_mm);
    drawn.material = patch.spec().material.name;
    drawn.rgb = patch_rgb(drawn.material);
    for (std::size_t k = 0; k < patch.stitches().size() && k < anchors.size(); ++k) {
        drawn.stitch_from.push_back(drawn.positions[std::size_t(patch.stitches()[k].vertex)]);
        drawn.stitch_to.push_back(to_float(anchors[k]));
    }
    return drawn;
}

}  // namespace heartsim
