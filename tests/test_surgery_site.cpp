// The line-triangle routine (libmodel/ray_triangle.h) and the surgery sites on plain arrays
// (libmodel/surgery/surgery_site.h), against shapes whose answers are known in closed form: a box, a slab
// with the defect's axis across it, a line through a shared edge.
#include "libmodel/ray_triangle.h"
#include "libmodel/surgery/surgery_site.h"

#include "libmodel/errors.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace heartsim {
namespace {

/// The closed box [lo, hi], 12 triangles counter-clockwise seen from outside.
struct BoxMesh {
    std::vector<std::array<float, 3>> positions;
    std::vector<std::array<std::int32_t, 3>> triangles;
};
BoxMesh box(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
    BoxMesh m;
    for (int k = 0; k < 8; ++k) m.positions.push_back({k & 1 ? hi.x() : lo.x(), k & 2 ? hi.y() : lo.y(), k & 4 ? hi.z() : lo.z()});
    // Each face's corners counter-clockwise seen from outside, split along its first diagonal.
    const int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& f : faces) {
        m.triangles.push_back({f[0], f[1], f[2]});
        m.triangles.push_back({f[0], f[2], f[3]});
    }
    return m;
}

TEST(LineTriangle, MeetsTheInsideWhereThePlaneIsAndMissesOutside) {
    const Eigen::Vector3d a(0, 0, 2), b(4, 0, 2), c(0, 4, 2);
    const auto hit = line_triangle(Eigen::Vector3d(1, 1, 7), Eigen::Vector3d(0, 0, -2), a, b, c);
    ASSERT_TRUE(hit);
    EXPECT_DOUBLE_EQ(hit->along, 2.5);  // 7 − 2.5·2 = 2
    EXPECT_DOUBLE_EQ(hit->u, 0.25);
    EXPECT_DOUBLE_EQ(hit->v, 0.25);
    EXPECT_FALSE(line_triangle(Eigen::Vector3d(3, 3, 7), Eigen::Vector3d(0, 0, -1), a, b, c));   // beyond the hypotenuse
    EXPECT_FALSE(line_triangle(Eigen::Vector3d(1, 1, 7), Eigen::Vector3d(1, 0, 0), a, b, c));    // parallel to its plane
    EXPECT_FALSE(line_triangle(Eigen::Vector3d(1, 1, 7), Eigen::Vector3d(0, 0, -1), a, a, c));   // degenerate
    // A line, not a ray: behind the origin counts; the ray does not.
    const auto behind = line_triangle(Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(0, 0, -1), a, b, c);
    ASSERT_TRUE(behind);
    EXPECT_DOUBLE_EQ(behind->along, -2.0);
    EXPECT_EQ(ray_triangle(Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(0, 0, -1), a, b, c), -1.0);
    EXPECT_DOUBLE_EQ(ray_triangle(Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(0, 0, 1), a, b, c), 2.0);
}

TEST(LineTriangle, EdgesAndCornersBelongToTheTriangleAndDetSaysWhichSide) {
    const Eigen::Vector3d a(0, 0, 0), b(2, 0, 0), c(0, 2, 0);
    // The counter-clockwise triangle faces +z: a line going down passes it from its front.
    const Eigen::Vector3d down(0, 0, -1);
    for (const Eigen::Vector3d& on : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(1, 1, 0), Eigen::Vector3d(0, 1, 0), Eigen::Vector3d(0, 0, 0),
                                      Eigen::Vector3d(2, 0, 0)}) {
        const auto hit = line_triangle(on + Eigen::Vector3d(0, 0, 3), down, a, b, c);
        ASSERT_TRUE(hit) << on.transpose();
        EXPECT_DOUBLE_EQ(hit->along, 3.0);
        EXPECT_GT(hit->det, 0.0);
    }
    const auto up = line_triangle(Eigen::Vector3d(0.5, 0.5, -3), Eigen::Vector3d(0, 0, 1), a, b, c);
    ASSERT_TRUE(up);
    EXPECT_LT(up->det, 0.0);
    // Two triangles sharing the edge (2,0)-(0,2): a line through its middle meets both.
    const Eigen::Vector3d d(2, 2, 0);
    EXPECT_TRUE(line_triangle(Eigen::Vector3d(1, 1, 3), down, a, b, c));
    EXPECT_TRUE(line_triangle(Eigen::Vector3d(1, 1, 3), down, b, d, c));
}

TEST(SurgerySite, ABoxIsOneStretchOfItsHeightAndALineThroughAnEdgeCountsOnce) {
    const BoxMesh m = box({-5, -5, -1.5f}, {5, 5, 2.5f});
    const Eigen::Vector3d up(0, 0, 1);
    // Through the faces' insides, and through the top and bottom faces' diagonals (x = y): every
    // crossing of a shared edge is counted once.
    for (const Eigen::Vector3d& point : {Eigen::Vector3d(1.25, -2.5, 0), Eigen::Vector3d(2, 2, 0), Eigen::Vector3d(-3, -3, 0)}) {
        const auto stretches = tissue_stretches(m.positions, m.triangles, point, up);
        ASSERT_EQ(stretches.size(), 1u) << point.transpose();
        EXPECT_DOUBLE_EQ(stretches[0].top, 2.5);
        EXPECT_DOUBLE_EQ(stretches[0].bottom, -1.5);
        EXPECT_DOUBLE_EQ(stretches[0].length(), 4.0);
    }
    EXPECT_TRUE(tissue_stretches(m.positions, m.triangles, Eigen::Vector3d(7, 0, 0), up).empty());
    // Seen along −z the box is the same stretch, heights counted the other way.
    const auto down = tissue_stretches(m.positions, m.triangles, Eigen::Vector3d(1.25, -2.5, 0), -up);
    ASSERT_EQ(down.size(), 1u);
    EXPECT_DOUBLE_EQ(down[0].top, 1.5);
    EXPECT_DOUBLE_EQ(down[0].bottom, -2.5);
}

TEST(SurgerySite, StitchesOnASlabLieOnItsFaceAndThePatchOnThem) {
    // A slab 4 mm thick across the defect's axis (z), the defect's centre mid-wall at the origin.
    const float half = 2.0f;
    const BoxMesh slab = box({-30, -30, -half}, {30, 30, half});
    const Eigen::Vector3d centre = Eigen::Vector3d::Zero(), axis = Eigen::Vector3d::UnitZ();
    for (const bool on_b : {true, false}) {
        const StitchCircle circle = stitch_circle(centre, axis, on_b, 7.0, 12);
        EXPECT_TRUE(circle.starts_anterior);  // the axis is superior-inferior
        EXPECT_TRUE(circle.first.isApprox(Eigen::Vector3d(0, -1, 0)));
        EXPECT_TRUE(circle.second.isApprox(circle.outward.cross(circle.first)));
        for (int k = 0; k < 12; ++k) {
            EXPECT_NEAR((circle.point(k) - centre).norm(), 7.0, 1e-12);
            EXPECT_NEAR(circle.angle_deg(k), 30.0 * k, 1e-12);
        }
        const StitchSites found = find_stitch_sites(slab.positions, slab.triangles, circle, 3.0);
        ASSERT_EQ(found.missing, -1);
        EXPECT_TRUE(found.mid_wall_found);
        EXPECT_NEAR(found.thickness_mm, 2.0 * half, 1e-12);
        EXPECT_NEAR(found.window_mm, 2.0 * half + 3.0, 1e-12);
        ASSERT_EQ(found.sites.size(), 12u);
        for (const StitchSite& s : found.sites) {
            EXPECT_NEAR(s.height_mm, half, 1e-12);  // on the chosen side's face
            EXPECT_NEAR(s.site.z(), on_b ? half : -half, 1e-12);
            EXPECT_NEAR(s.wall_mm, 2.0 * half, 1e-12);
        }
        EXPECT_NEAR(found.wall_median_mm, 2.0 * half, 1e-12);
        const PatchPlacement patch = place_patch(found.sites, circle, 0.5);
        EXPECT_TRUE(patch.facing.isApprox(-circle.outward, 1e-12));
        EXPECT_NEAR(patch.residual_mm, 0.0, 1e-12);
        EXPECT_NEAR(patch.tilt_deg, 0.0, 1e-5);
        EXPECT_TRUE(patch.centre.isApprox(Eigen::Vector3d(0, 0, on_b ? half + 0.25 : -half - 0.25), 1e-12));
        EXPECT_TRUE((patch.orientation * Eigen::Vector3d::UnitZ()).isApprox(patch.facing, 1e-12));
    }
}

TEST(SurgerySite, AStitchBeyondTheSlabIsMissingAndSaysWhatItsLineMet) {
    const BoxMesh slab = box({-5, -5, -2}, {5, 5, 2});
    // A circle of radius 9 reaches beyond the slab's 5 mm half-width on every side but the corners.
    const StitchCircle circle = stitch_circle(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), true, 9.0, 8);
    const StitchSites found = find_stitch_sites(slab.positions, slab.triangles, circle, 3.0);
    EXPECT_EQ(found.missing, 0);
    EXPECT_FALSE(found.mid_wall_found);  // no line of the eight crosses the slab
    EXPECT_TRUE(std::isinf(found.missing_nearest_mm));
    EXPECT_TRUE(found.missing_line.point.isApprox(circle.point(0)));
}

TEST(SurgerySite, APatchAlongTheAxisIsRefused) {
    // Sites on a plane that holds the axis: no wall across the opening.
    const StitchCircle circle = stitch_circle(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), true, 7.0, 4);
    std::vector<StitchSite> sites(4);
    for (int k = 0; k < 4; ++k) sites[std::size_t(k)].site = Eigen::Vector3d(k % 2 ? 7.0 : -7.0, 0.0, k < 2 ? 3.0 : -3.0);
    EXPECT_THROW(place_patch(sites, circle, 0.5), InputError);
}

TEST(SurgerySite, TheIncisionSiteIsTheRuleOnAColumnOfParticles) {
    // A block of particles 1 mm apart, x −5…5, y 0…6, z 0…30: the ventriculotomy enters at the
    // most anterior particle (smallest y) of the middle third in z, the blade a quarter spacing beside it.
    std::vector<std::array<float, 3>> rest;
    for (int z = 0; z <= 30; ++z)
        for (int y = 0; y <= 6; ++y)
            for (int x = -5; x <= 5; ++x) rest.push_back({float(x), float(y), float(z)});
    const IncisionSite site = incision_site(rest, 1.0, {.approach = IncisionApproach::ventriculotomy});
    EXPECT_EQ(site.entry.y(), 0.0);
    EXPECT_GE(site.entry.z(), 10.0);
    EXPECT_LE(site.entry.z(), 20.0);
    EXPECT_EQ(site.blade, Eigen::Vector3d::UnitY());
    EXPECT_DOUBLE_EQ(site.centre.x(), site.entry.x() + 0.25);
    // Through the block along +y: the particles reach 6 mm, points stay within 0.75 mm of one up
    // to 6.75 mm, and the tissue half a spacing beyond that.
    EXPECT_DOUBLE_EQ(site.wall_mm, 7.25);
    EXPECT_DOUBLE_EQ(wall_thickness(rest, 1.0, site.particle, Eigen::Vector3d::UnitY()), site.wall_mm);
    const int front = frontmost_near(rest, Eigen::Vector3d(2, 0, 15), Eigen::Vector3d::UnitY(), 0.5);
    ASSERT_GE(front, 0);
    EXPECT_EQ(rest[std::size_t(front)][0], 2.0f);
    EXPECT_EQ(rest[std::size_t(front)][1], 0.0f);
    EXPECT_EQ(rest[std::size_t(front)][2], 15.0f);
    EXPECT_EQ(frontmost_near(rest, Eigen::Vector3d(20, 0, 15), Eigen::Vector3d::UnitY(), 0.5), -1);
}

TEST(SurgerySite, TheIncisionSiteKeepsToTheChambersOwnWall) {
    // Two blocks, z 0…40: a "vessel" at x −10…−6, y −8…−1, further right and further front
    // than a "chamber wall" at x −3…3, y 0…6. On the whole, each rule takes the vessel; told the
    // chamber's wall, each stays on it.
    std::vector<std::array<float, 3>> rest;
    std::vector<std::uint8_t> wall;
    for (int z = 0; z <= 40; ++z)
        for (int y = -8; y <= 6; ++y)
            for (int x = -10; x <= 3; ++x) {
                const bool vessel = x <= -6 && y < 0, chamber = x >= -3 && y >= 0;
                if (!vessel && !chamber) continue;
                rest.push_back({float(x), float(y), float(z)});
                wall.push_back(chamber ? 1 : 0);
            }
    for (const IncisionApproach approach : {IncisionApproach::ventriculotomy, IncisionApproach::atriotomy}) {
        SCOPED_TRACE(approach == IncisionApproach::atriotomy ? "atriotomy" : "ventriculotomy");
        const IncisionSite whole = incision_site(rest, 1.0, {.approach = approach, .length_mm = 10});
        EXPECT_FALSE(whole.on_chamber_wall);
        EXPECT_LE(whole.entry.x(), -6.0);
        const IncisionSite chamber = incision_site(rest, 1.0, {.approach = approach, .length_mm = 10, .chamber_wall = wall});
        EXPECT_TRUE(chamber.on_chamber_wall);
        EXPECT_EQ(wall[chamber.particle], 1);
        if (approach == IncisionApproach::ventriculotomy) {
            EXPECT_EQ(chamber.entry.y(), 0.0);  // the chamber wall's front
        } else {
            EXPECT_EQ(chamber.entry.x(), -3.0);  // the chamber wall's rightmost face
            EXPECT_TRUE(chamber.whole_wall);
            // The middle half in z of the wall: 10…30.
            EXPECT_GE(chamber.entry.z(), 10.0);
            EXPECT_LE(chamber.entry.z(), 30.0);
        }
    }
    // Without a chamber, the atriotomy's upper half is that of the particles `height_from` flags:
    // here those up to z = 20, so the entry lies between z = 10 and 20 (on the whole, 20 to 40).
    std::vector<std::uint8_t> low_half(rest.size());
    for (std::size_t i = 0; i < rest.size(); ++i) low_half[i] = rest[i][2] <= 20.0f;
    const IncisionSite lower = incision_site(rest, 1.0, {.approach = IncisionApproach::atriotomy, .length_mm = 10, .height_from = low_half});
    EXPECT_GE(lower.entry.z(), 10.0);
    EXPECT_LE(lower.entry.z(), 20.0);
    EXPECT_GE(incision_site(rest, 1.0, {.approach = IncisionApproach::atriotomy, .length_mm = 10}).entry.z(), 20.0);
    // A flag list of the wrong length, or with none set, is the whole heart's rule.
    EXPECT_FALSE(incision_site(rest, 1.0, {.chamber_wall = std::vector<std::uint8_t>(3, 1)}).on_chamber_wall);
    EXPECT_FALSE(incision_site(rest, 1.0, {.chamber_wall = std::vector<std::uint8_t>(rest.size(), 0)}).on_chamber_wall);
}

}  // namespace
}  // namespace heartsim
