// The coronary field against closed forms: the distance from a straight segment and from two
// arteries of different radii, the direction away from the course, and the grid's cover.
#include "libmodel/coronary_field.h"
#include "libmodel/errors.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

using namespace heartsim;

namespace {

Eigen::Vector3d node_of(const CoronaryField& f, int i, int j, int k) {
    return f.origin + f.spacing_mm * Eigen::Vector3d(i, j, k);
}

/// Distance from p to segment [a, b], by the closed form for a capsule's axis.
double segment_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    return (p - (a + t * ab)).norm();
}

}  // namespace

TEST(CoronaryField, StraightArteryGivesTheCapsulesDistanceInRadiiAndPointsAwayFromTheAxis) {
    // An artery of radius 2 mm along x from 0 to 20 mm, sampled every 5 mm (collinear points).
    CoronaryCourse course{"lad_course", {}, 2.0};
    for (int s = 0; s <= 4; ++s) course.points.emplace_back(5.0 * s, 0.0, 0.0);
    const CoronaryField f = coronary_field({course}, 0.5, 3.0);
    ASSERT_FALSE(f.empty());
    int inside = 0, on_axis = 0;
    for (int k = 0; k < f.nz; ++k)
        for (int j = 0; j < f.ny; ++j)
            for (int i = 0; i < f.nx; ++i) {
                const Eigen::Vector3d p = node_of(f, i, j, k);
                const double expected = std::min(segment_distance(p, course.points.front(), course.points.back()) / 2.0, 3.0);
                const std::size_t at = f.index(i, j, k);
                ASSERT_NEAR(f.distance[at], expected, 1e-5) << "node " << p.transpose();
                if (expected >= 3.0) {
                    EXPECT_EQ(f.away[at].norm(), 0.0f);
                    continue;
                }
                ++inside;
                if (expected == 0.0) {
                    ++on_axis;
                    continue;
                }
                // Beside the segment (not past its ends) the direction is radial: (0, y, z) / r.
                if (p.x() > 0.0 && p.x() < 20.0) {
                    const Eigen::Vector3f radial = Eigen::Vector3f(0.0f, float(p.y()), float(p.z())).normalized();
                    ASSERT_LT((f.away[at] - radial).norm(), 1e-5f) << "node " << p.transpose();
                }
                ASSERT_NEAR(f.away[at].norm(), 1.0f, 1e-5f);
            }
    // The grid covers the whole capsule of 3 radii: its nodes within reach are those of a
    // cylinder of radius 6 mm and length 20 mm with two half-balls, volume π·6²·20 + 4/3·π·6³,
    // at 0.5 mm spacing 8 nodes per mm³ (within the lattice's boundary error).
    const double capsule = M_PI * 36.0 * 20.0 + 4.0 / 3.0 * M_PI * 216.0;
    EXPECT_NEAR(inside / 8.0, capsule, 0.03 * capsule);
    EXPECT_GT(on_axis, 0);
}

TEST(CoronaryField, TheNearestArteryInItsOwnRadiiDecides) {
    // Two parallel arteries 10 mm apart, radii 1 and 2 mm: at a node between them the field holds
    // min(d1 / 1, d2 / 2).
    const CoronaryCourse thin{"lcx_course", {{0, 0, 0}, {0, 0, 30}}, 1.0};
    const CoronaryCourse wide{"rca_course", {{10, 0, 0}, {10, 0, 30}}, 2.0};
    const CoronaryField f = coronary_field({thin, wide}, 0.25, 4.0);
    int checked = 0;
    for (int k = 0; k < f.nz; ++k)
        for (int j = 0; j < f.ny; ++j)
            for (int i = 0; i < f.nx; ++i) {
                const Eigen::Vector3d p = node_of(f, i, j, k);
                const double d1 = segment_distance(p, thin.points[0], thin.points[1]) / 1.0;
                const double d2 = segment_distance(p, wide.points[0], wide.points[1]) / 2.0;
                ASSERT_NEAR(f.distance[f.index(i, j, k)], std::min({d1, d2, 4.0}), 1e-5);
                ++checked;
            }
    EXPECT_GT(checked, 100000);
}

TEST(CoronaryField, AGridTooLargeIsCoarsenedToFitAndStillCoversTheCourse) {
    const CoronaryCourse long_course{"rca_course", {{-100, -100, -100}, {100, 100, 100}}, 2.0};
    const std::size_t limit = 1u << 18;
    const CoronaryField f = coronary_field({long_course}, 0.5, 3.0, limit);
    EXPECT_LE(static_cast<std::size_t>(f.nx) * f.ny * f.nz, limit);
    EXPECT_GT(f.spacing_mm, 0.5);
    // Both ends lie inside the grid with the reach around them.
    for (const Eigen::Vector3d& end : long_course.points) {
        const Eigen::Vector3d lo = f.origin, hi = node_of(f, f.nx - 1, f.ny - 1, f.nz - 1);
        EXPECT_TRUE(((end.array() - 6.0) >= lo.array()).all() && ((end.array() + 6.0) <= hi.array()).all());
    }
}

TEST(CoronaryField, CoursesComeFromTheLandmarksWithTheirArteriesRadii) {
    Landmarks landmarks;
    landmarks.found.push_back({"lad_course", LandmarkKind::course, "left ventricle, right ventricle", {{0, 0, 0}, {0, 0, 40}}});
    landmarks.found.push_back({"rca_course", LandmarkKind::course, "right atrium, right ventricle", {{5, 0, 0}}});
    landmarks.found.push_back({"mitral_ring", LandmarkKind::ring, "left atrium, left ventricle", {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}});
    const std::vector<CoronaryCourse> courses = coronary_courses(landmarks);
    ASSERT_EQ(courses.size(), 1u);  // one point is no course; a ring is no artery
    EXPECT_EQ(courses[0].name, "lad_course");
    EXPECT_DOUBLE_EQ(courses[0].radius_mm, 1.85);
    EXPECT_TRUE(coronary_field({}).empty());
}

TEST(CoronaryField, RefusesANonFinitePointAndAnImpossibleRadius) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(coronary_field({{"lad_course", {{0, 0, 0}, {nan, 0, 0}}, 1.8}}), InputError);
    EXPECT_THROW(coronary_field({{"lad_course", {{0, 0, 0}, {1, 0, 0}}, 0.0}}), InputError);
    EXPECT_THROW(coronary_field({{"lad_course", {{0, 0, 0}, {1, 0, 0}}, 1.8}}, 0.0), InputError);
}

TEST(CoronaryField, ACourseThatZigzagsAcrossItsLineIsDrawnAlongItsMeanLine) {
    // Points alternating ±0.5 mm about the x axis: the drawn course keeps its ends and comes within
    // a tenth of the zigzag's amplitude of the axis inside; a straight course stays straight.
    Landmarks landmarks;
    Landmark zigzag{"rca_course", LandmarkKind::course, "right atrium, right ventricle", {}};
    for (int k = 0; k <= 20; ++k) zigzag.points.emplace_back(1.0 * k, k % 2 ? 0.5 : -0.5, 0.0);
    landmarks.found.push_back(zigzag);
    const std::vector<CoronaryCourse> courses = coronary_courses(landmarks);
    ASSERT_EQ(courses.size(), 1u);
    const auto& p = courses[0].points;
    ASSERT_EQ(p.size(), zigzag.points.size());
    EXPECT_EQ(p.front(), zigzag.points.front());
    EXPECT_EQ(p.back(), zigzag.points.back());
    for (std::size_t k = 3; k + 3 < p.size(); ++k) {
        EXPECT_LT(std::abs(p[k].y()), 0.05) << k;
        EXPECT_NEAR(p[k].x(), double(k), 1e-12) << k;
    }
}
