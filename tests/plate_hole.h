/// @file plate_hole.h
/// @brief A plate with a round hole through it as a closed triangle mesh (an annulus-shaped slab,
/// outward normals), the analytic shape the patch and closure tests sew and check.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <vector>

namespace test {

struct PlateMesh {
    std::vector<std::array<float, 3>> positions;
    std::vector<std::array<std::int32_t, 3>> triangles;
};

/// A slab from z = −thickness/2 to +thickness/2 between radius hole_diameter/2 and outer_radius
/// around the z axis: `rings` rings of `around` vertices on each face, `layers` layers up each wall.
inline PlateMesh plate_with_hole(double hole_diameter, double outer_radius, double thickness, int around = 96, int rings = 24,
                                 int layers = 6) {
    PlateMesh m;
    const double inner = 0.5 * hole_diameter;
    // The boundary loop of the cross-section (r, z), counter-clockwise in the (r, z) plane so that
    // revolving it gives outward normals: bottom face outward, outer wall up, top face inward,
    // inner wall down.
    std::vector<std::array<double, 2>> loop;
    for (int i = 0; i < rings; ++i) loop.push_back({inner + (outer_radius - inner) * i / rings, -0.5 * thickness});
    for (int i = 0; i < layers; ++i) loop.push_back({outer_radius, -0.5 * thickness + thickness * i / layers});
    for (int i = 0; i < rings; ++i) loop.push_back({outer_radius - (outer_radius - inner) * i / rings, 0.5 * thickness});
    for (int i = 0; i < layers; ++i) loop.push_back({inner, 0.5 * thickness - thickness * i / layers});
    const int n = int(loop.size());
    for (int a = 0; a < around; ++a) {
        const double angle = 2.0 * std::numbers::pi * a / around;
        for (const auto& [r, z] : loop) m.positions.push_back({float(r * std::cos(angle)), float(r * std::sin(angle)), float(z)});
    }
    auto id = [&](int a, int k) { return std::int32_t((a % around) * n + (k % n)); };
    for (int a = 0; a < around; ++a)
        for (int k = 0; k < n; ++k) {
            // Quad (a, k) (a, k+1) (a+1, k+1) (a+1, k): the loop runs counter-clockwise in (r, z)
            // and the angle grows about +z, so this order faces outward.
            m.triangles.push_back({id(a, k), id(a + 1, k), id(a + 1, k + 1)});
            m.triangles.push_back({id(a, k), id(a + 1, k + 1), id(a, k + 1)});
        }
    return m;
}

}  // namespace test
