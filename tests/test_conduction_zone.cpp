// libmodel/surgery/conduction_zone.h: a defect's conduction zone from constructed tricuspid and
// aortic rings, whose nearest points to the rim, and so the zone's direction, are known in closed
// form; its arc and band by their definitions; no zone for a muscular defect or missing rings.
#include "libmodel/surgery/conduction_zone.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <numbers>

using namespace heartsim;

namespace {

constexpr double pi = std::numbers::pi;

/// A ring of 48 points of radius `radius` round `centre` in the plane spanned by the unit,
/// perpendicular `u` and `v`, its first point at centre + radius·u.
Landmark ring(const std::string& name, const Eigen::Vector3d& centre, const Eigen::Vector3d& u, const Eigen::Vector3d& v, double radius) {
    Landmark l;
    l.name = name;
    l.kind = LandmarkKind::ring;
    for (int k = 0; k < 48; ++k) {
        const double a = 2.0 * pi * k / 48.0;
        l.points.push_back(centre + radius * (std::cos(a) * u + std::sin(a) * v));
    }
    l.centre = centre;
    l.normal = u.cross(v);
    l.diameter_mm = 2.0 * radius;
    return l;
}

/// A 10 mm defect at the origin along x (the septum the plane x = 0). The tricuspid ring: radius 6
/// round (0, 14, 0) in the septum's plane, its point nearest the rim (0, 8, 0), 3 mm beyond the
/// rim (radius 5); the aortic ring: radius 6 round (0, 0, 15 + extra), nearest (0, 0, 9 + extra),
/// 4 + extra mm beyond it.
Landmarks rings(double aortic_extra_mm = 0.0) {
    Landmarks l;
    const Eigen::Vector3d y = Eigen::Vector3d::UnitY(), z = Eigen::Vector3d::UnitZ();
    l.found.push_back(ring("tricuspid_ring", 14.0 * y, y, z, 6.0));
    l.found.push_back(ring("aortic_ring", (15.0 + aortic_extra_mm) * z, z, y, 6.0));
    return l;
}

const Eigen::Vector3d centre = Eigen::Vector3d::Zero(), axis = Eigen::Vector3d::UnitX();

}  // namespace

// The rim comes 3 mm from the tricuspid ring (toward +y) and 4 mm from the aortic ring (toward +z):
// perimembranous. The middle is t − a + p with t = (0, 1, 0), a = (0, 0, 1) and p = (0, 1, −1)/√2:
// (0, 1 + 1/√2, −1 − 1/√2), i.e. (0, 1, −1)/√2, posteroinferior. The arc spans 60° either side,
// the band to 3 mm beyond the edge (8 mm from the axis), through the whole wall.
TEST(ConductionZone, ConstructedRingsGiveThePosteroinferiorArcAndBand) {
    const ConductionZone zone = conduction_zone(centre, axis, 10.0, rings());
    ASSERT_TRUE(zone.found) << zone.reason;
    EXPECT_NE(zone.reason.find("perimembranous"), std::string::npos) << zone.reason;
    EXPECT_NEAR(zone.tricuspid_mm, 3.0, 1e-9);
    EXPECT_NEAR(zone.aortic_mm, 4.0, 1e-9);
    EXPECT_TRUE(zone.tricuspid_point.isApprox(Eigen::Vector3d(0, 8, 0), 1e-12));
    EXPECT_TRUE(zone.aortic_point.isApprox(Eigen::Vector3d(0, 0, 9), 1e-12));
    EXPECT_TRUE(zone.direction.isApprox(Eigen::Vector3d(0, 1, -1).normalized(), 1e-12)) << zone.direction.transpose();
    EXPECT_DOUBLE_EQ(zone.edge_mm, 5.0);
    EXPECT_DOUBLE_EQ(zone.outer_mm, 8.0);
    // Round the axis at angle θ from the middle, r from the axis, h along it.
    const Eigen::Vector3d m = zone.direction, side = axis.cross(m);
    auto at = [&](double theta_deg, double r, double h) {
        const double t = theta_deg * pi / 180.0;
        return Eigen::Vector3d(centre + r * (std::cos(t) * m + std::sin(t) * side) + h * axis);
    };
    EXPECT_NEAR(zone.angle_from_middle_deg(at(37.0, 7.0, 0.0)), 37.0, 1e-9);
    EXPECT_NEAR(zone.angle_from_middle_deg(at(-150.0, 7.0, 2.0)), 150.0, 1e-9);
    EXPECT_TRUE(zone.holds(at(0.0, 7.0, 0.0)));
    EXPECT_TRUE(zone.holds(at(59.0, 7.0, 3.0)));     // within the arc, either face
    EXPECT_TRUE(zone.holds(at(-59.0, 7.9, -3.0)));
    EXPECT_FALSE(zone.holds(at(61.0, 7.0, 0.0)));    // past the arc
    EXPECT_FALSE(zone.holds(at(-61.0, 7.0, 0.0)));
    EXPECT_FALSE(zone.holds(at(0.0, 8.1, 0.0)));     // past the band
    EXPECT_FALSE(zone.holds(at(180.0, 6.0, 0.0)));   // the anterosuperior rim
    EXPECT_FALSE(zone.holds(centre));                // on the axis: the opening, no bite
    // Of 12 points at 7 mm, one every 30° from 15° past the middle, those within ±60° (15°, 45°,
    // 315°, 345°): 4.
    std::vector<Eigen::Vector3d> points;
    for (int k = 0; k < 12; ++k) points.push_back(at(15.0 + 30.0 * k, 7.0, 0.0));
    EXPECT_EQ(points_in_zone(zone, points), (std::vector<int>{0, 1, 10, 11}));
    // A wider arc and band by the options.
    const ConductionZone wide = conduction_zone(centre, axis, 10.0, rings(), {.band_mm = 4.0, .half_width_deg = 90.0});
    EXPECT_TRUE(wide.holds(at(89.0, 8.9, 0.0)));
    EXPECT_FALSE(wide.holds(at(91.0, 7.0, 0.0)));
}

// The aortic ring moved 7 mm farther (11 mm from the rim): beyond the 10 mm reach, a muscular
// defect, no zone; within a reach of 12 mm, the zone again.
TEST(ConductionZone, ARimFarFromARingIsMuscularWithNoZone) {
    const ConductionZone far = conduction_zone(centre, axis, 10.0, rings(7.0));
    EXPECT_FALSE(far.found);
    EXPECT_NEAR(far.aortic_mm, 11.0, 1e-9);
    EXPECT_NE(far.reason.find("not perimembranous"), std::string::npos) << far.reason;
    EXPECT_NE(far.reason.find("11.0 mm from the aortic ring"), std::string::npos) << far.reason;
    EXPECT_FALSE(far.holds(Eigen::Vector3d(0, 5, -5)));
    EXPECT_TRUE(conduction_zone(centre, axis, 10.0, rings(7.0), {.ring_reach_mm = 12.0}).found);
}

// Rings the label map could not give (HVSMR 2016's one blood pool): no zone, the reason theirs.
TEST(ConductionZone, MissingRingsGiveNoZoneAndSayWhy) {
    Landmarks none;
    none.missing.push_back({"tricuspid_ring", "HVSMR 2016 labels one blood pool for every chamber"});
    none.missing.push_back({"aortic_ring", "HVSMR 2016 labels one blood pool for every chamber"});
    const ConductionZone zone = conduction_zone(centre, axis, 10.0, none);
    EXPECT_FALSE(zone.found);
    EXPECT_TRUE(std::isnan(zone.tricuspid_mm));
    EXPECT_NE(zone.reason.find("no tricuspid ring (HVSMR 2016 labels one blood pool"), std::string::npos) << zone.reason;
    EXPECT_NE(zone.reason.find("no aortic ring"), std::string::npos) << zone.reason;
    Landmarks only_tricuspid = rings();
    only_tricuspid.found.pop_back();
    const ConductionZone half = conduction_zone(centre, axis, 10.0, only_tricuspid);
    EXPECT_FALSE(half.found);
    EXPECT_EQ(half.reason.find("no tricuspid ring"), std::string::npos) << half.reason;
    EXPECT_NE(half.reason.find("no aortic ring (the scenario's /landmarks does not hold it)"), std::string::npos) << half.reason;
}
