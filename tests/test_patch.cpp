// The patch (libmodel/surgery/patch.h) sewn over a hole in a rigid plate, checked by the closure check
// (libmodel/surgery/closure.h): enough stitches close the hole, too few or no patch leave it open; the
// tissue takes the opposite of every force on the patch (Newton's third law); a probe pressed on it
// pushes it and is pushed back.
#include "libmodel/surgery/closure.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/patch.h"
#include "plate_hole.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

using namespace heartsim;

namespace {

constexpr double hole = 10.0, thickness = 4.0, dt = 0.25;
constexpr double mmhg = mmhg_in_n_per_mm2;

/// A rigid plate: each vertex its own particle.
struct Plate {
    test::PlateMesh mesh = test::plate_with_hole(hole, 20.0, thickness);
    ContactSurface surface() const {
        ContactSurface s;
        for (std::size_t v = 0; v < mesh.positions.size(); ++v)
            s.vertices.push_back({Eigen::Vector3d(mesh.positions[v][0], mesh.positions[v][1], mesh.positions[v][2]), {{std::int32_t(v), 1.0}}});
        s.triangles = mesh.triangles;
        return s;
    }
};

/// Tool +z = world −z: the patch above the plate faces down onto it.
InstrumentPose facing_down(double height) {
    InstrumentPose pose;
    pose.position = {0, 0, height};
    pose.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()));
    return pose;
}

PatchSpec spec() {
    PatchSpec s;
    s.radius_x_mm = s.radius_y_mm = hole / 2 + 4.0;
    s.thickness_mm = 0.5;
    s.standoff_mm = 0.0;
    return s;
}

ParticlePositions positions_of(const Plate& plate, const PatchModel& patch) {
    ParticlePositions out;
    for (std::int32_t i : patch.particles()) out.push_back(plate.mesh.positions[std::size_t(i)]);
    return out;
}

std::vector<std::array<float, 3>> floats(const std::vector<Eigen::Vector3d>& x) {
    std::vector<std::array<float, 3>> out;
    for (const auto& p : x) out.push_back({float(p.x()), float(p.y()), float(p.z())});
    return out;
}

/// Lays the patch, ties `stitches` of 8 sites evenly round the rim (the first `stitches` in
/// order), steps `ms`, and checks the closure.
struct Sewn {
    ClosureResult closure;
    double spacing = 0;
    Eigen::Vector3d load_sum = Eigen::Vector3d::Zero(), patch_force_sum = Eigen::Vector3d::Zero();
    double largest_load = 0;
};

Sewn sew(int stitches, bool lay = true, double ms = 400.0) {
    Plate plate;
    PatchModel patch(spec(), plate.mesh.positions, plate.surface());
    const ParticlePositions at = positions_of(plate, patch);
    if (lay) patch.lay(facing_down(thickness / 2 + 3.0), at);
    const double rim = hole / 2 + 2.0;
    double t = 0;
    for (int k = 0; k < stitches; ++k) {
        const double angle = 2.0 * std::numbers::pi * k / 8;
        EXPECT_TRUE(patch.tie(Eigen::Vector3d(rim * std::cos(angle), rim * std::sin(angle), thickness / 2), t, at).has_value());
    }
    Sewn out;
    for (; t < ms; t += dt) patch.step(at, dt, t);
    // The leak test: 10 mmHg across the septum pushing the patch off the wall over the opening.
    const PatchModel tested = patch.under_pressure(at, 10 * mmhg);
    for (const ParticleLoad& load : tested.loads()) {
        out.load_sum += load.force_n;
        out.largest_load = std::max(out.largest_load, load.force_n.norm());
    }
    for (const Stitch& s : tested.stitches()) out.patch_force_sum += s.force_n;
    out.patch_force_sum += tested.contact_force();
    out.spacing = 2.0 * std::numbers::pi * rim / 8;
    std::vector<std::array<std::int32_t, 3>> triangles;
    if (lay) triangles = patch.triangles();
    ClosureOptions options;
    for (const Stitch& s : patch.stitches()) options.stitches.push_back(patch.where(s.anchor, at));
    out.closure = check_closure(plate.mesh.positions, plate.mesh.triangles, floats(tested.positions()), triangles, spec().thickness_mm,
                                DefectFrame{Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), hole}, options);
    return out;
}

/// Lays `patch` over the plate's hole, ties 8 stitches evenly round the rim at 0 ms, and steps
/// it 300 ms, the stitches drawn tight; false when a stitch does not tie.
bool sew_eight(PatchModel& patch, const ParticlePositions& at) {
    patch.lay(facing_down(thickness / 2 + 3.0), at);
    const double rim = hole / 2 + 2.0;
    for (int k = 0; k < 8; ++k) {
        const double angle = 2.0 * std::numbers::pi * k / 8;
        if (!patch.tie(Eigen::Vector3d(rim * std::cos(angle), rim * std::sin(angle), thickness / 2), 0.0, at)) return false;
    }
    for (double t = 0; t < 300; t += dt) patch.step(at, dt, t);
    return true;
}

}  // namespace

TEST(Patch, EightStitchesCloseAHoleInAPlate) {
    const Sewn s = sew(8);
    EXPECT_TRUE(s.closure.closed) << "reached " << s.closure.reached << " voxels";
    EXPECT_LT(s.closure.largest_rim_gap_mm, s.spacing);
}

TEST(Patch, TwoStitchesOrNoPatchLeaveItOpen) {
    const Sewn two = sew(2);
    EXPECT_FALSE(two.closure.closed);
    EXPECT_GT(two.closure.largest_rim_gap_mm, 0.25);
    // The stitches hold the patch at 0° and 45°: it lifts, and leaks, on the far side of the rim.
    ASSERT_TRUE(two.closure.leak_mm.has_value());
    const double leak_degrees = std::atan2(two.closure.leak_mm->y(), two.closure.leak_mm->x()) * 180.0 / std::numbers::pi;
    std::printf("  with stitches at 0° and 45° the leak passes the rim at %.0f°, %s\n", leak_degrees, leak_place(two.closure).c_str());
    EXPECT_TRUE(leak_degrees > 45.0 + 60.0 || leak_degrees < -60.0) << leak_degrees;
    EXPECT_EQ(leak_place(two.closure), "between stitches 1 and 2");
    const Sewn laid = sew(0);  // laid on the wall, never sewn: the pressure lifts it off
    EXPECT_FALSE(laid.closure.closed);
    const Sewn none = sew(0, false);
    EXPECT_FALSE(none.closure.closed);
    EXPECT_DOUBLE_EQ(none.closure.largest_rim_gap_mm, hole);
}

TEST(Patch, TheTissueTakesTheOppositeOfEveryForceOnThePatch) {
    const Sewn s = sew(8);  // held against the pressure by its stitches and the rim
    ASSERT_GT(s.largest_load, 0.0);
    EXPECT_LT((s.load_sum + s.patch_force_sum).norm(), 1e-9 * std::max(1.0, s.patch_force_sum.norm()) + 1e-12);
}

// Tissue that slides along itself carries a patch sewn to it: friction holds the patch's slip on
// the tissue, not its motion in space. The rigid plate slides 0.01 mm/ms along x for 400 ms under
// a patch sewn by eight stitches and pressed onto it; each vertex keeps its place on the plate.
TEST(Patch, ASewnPatchRidesOnTissueThatSlides) {
    Plate plate;
    // Pressed onto the plate (a strong pull toward it, no drag), so friction acts at every step.
    PatchSpec pressed = spec();
    pressed.gravity = Eigen::Vector3d(0, 0, -1e-2);  // mm/ms², toward the plate
    pressed.damping_per_ms = 0.0;
    pressed.friction = 1.0;
    PatchModel patch(pressed, plate.mesh.positions, plate.surface());
    const ParticlePositions at = positions_of(plate, patch);
    ASSERT_TRUE(sew_eight(patch, at));
    double t = 300;  // drawn tight on the still plate
    const std::vector<Eigen::Vector3d> before = patch.positions();
    constexpr double speed = 0.01, slide_ms = 400;  // mm/ms, ms
    for (; t < 300 + slide_ms; t += dt) {
        ParticlePositions moved = at;
        for (auto& p : moved) p[0] += float(speed * (t + dt - 300.0));
        patch.step(moved, dt, t);
    }
    double worst = 0;
    for (std::size_t i = 0; i < before.size(); ++i)
        worst = std::max(worst, (patch.positions()[i] - before[i] - Eigen::Vector3d(speed * slide_ms, 0, 0)).norm());
    std::printf("  after the plate slid %.1f mm, each vertex within %.4f mm of its place on it\n", speed * slide_ms, worst);
    EXPECT_LT(worst, 0.05);  // held by friction against its motion in space, it would lag 0.25 mm
}

// A probe pressed onto a sewn patch where it lies on the plate pushes it: no vertex stays inside
// the probe (grown by half the patch's thickness), the probe is pushed back (away from the plate),
// and the patch, at rest between the probe, the plate and its stitches, balances: the plate's and
// the stitches' forces on it equal its push on the probe. Lifted off, the probe feels nothing.
TEST(Patch, AProbePressedOnASewnPatchPushesItAndIsPushedBack) {
    Plate plate;
    PatchModel patch(spec(), plate.mesh.positions, plate.surface());
    const ParticlePositions at = positions_of(plate, patch);
    ASSERT_TRUE(sew_eight(patch, at));
    double t = 300;  // drawn tight on the plate
    const double rim = hole / 2 + 2.0;
    // A 2 mm ball over the patch where it lies on the plate (between the hole's edge and the
    // patch's), 0.4 mm into it: its centre 2 mm + half the thickness − 0.4 mm above the patch.
    double top = -1e9;
    for (const auto& x : patch.positions())
        if (std::hypot(x.x(), x.y() - rim) < 1.0) top = std::max(top, x.z());
    ASSERT_GT(top, thickness / 2) << "the patch lies on the plate there";
    const double radius = 2.0, half = 0.5 * spec().thickness_mm;
    PatchObstacle probe;
    probe.pose.position = Eigen::Vector3d(0, rim, top + half + radius - 0.4);
    probe.semi_axes = Eigen::Vector3d::Constant(radius);
    patch.set_obstacles({probe});
    for (; t < 600; t += dt) patch.step(at, dt, t);
    const Eigen::Vector3d push = patch.obstacle_forces().at(0);
    double closest = 1e9;
    for (const auto& x : patch.positions()) closest = std::min(closest, (x - probe.pose.position).norm());
    Eigen::Vector3d on_patch = patch.contact_force();
    for (const Stitch& st : patch.stitches()) on_patch += st.force_n;
    std::printf("  the patch pushes the probe with (%.4g, %.4g, %.4g) N; plate and stitches on it (%.4g, %.4g, %.4g) N; nearest vertex %.4f mm from its centre\n",
                push.x(), push.y(), push.z(), on_patch.x(), on_patch.y(), on_patch.z(), closest);
    EXPECT_GE(closest, radius + half - 1e-9) << "no vertex inside the probe";
    EXPECT_GT(push.z(), 0.0) << "pushed back, away from the plate";
    EXPECT_GT(push.z(), 10.0 * std::hypot(push.x(), push.y())) << "straight back: the ball presses straight down";
    EXPECT_LT((on_patch - push).norm(), 0.05 * push.norm()) << "the patch at rest: what pushes it balances what it pushes";
    probe.pose.position.z() += 5.0;  // lifted off
    patch.set_obstacles({probe});
    for (const double end = t + 50; t < end; t += dt) patch.step(at, dt, t);
    EXPECT_EQ(patch.obstacle_forces().at(0), Eigen::Vector3d::Zero());
    EXPECT_THROW(patch.set_obstacles({PatchObstacle{probe.pose, Eigen::Vector3d(1, 0, 1)}}), InputError);
}

TEST(Patch, RefusesWhatIsNotAPatch) {
    Plate plate;
    PatchSpec bad = spec();
    bad.thickness_mm = 0;
    EXPECT_THROW(PatchModel(bad, plate.mesh.positions, plate.surface()), InputError);
    bad = spec();
    bad.material.youngs_modulus_mpa = std::nan("");
    EXPECT_THROW(PatchModel(bad, plate.mesh.positions, plate.surface()), InputError);
    EXPECT_THROW(patch_material_named("leather"), InputError);
    PatchModel patch(spec(), plate.mesh.positions, plate.surface());
    std::string why;
    EXPECT_FALSE(patch.tie(Eigen::Vector3d(7, 0, 2), 0, positions_of(plate, patch), &why).has_value());
    EXPECT_NE(why.find("no patch"), std::string::npos);
}

// What a pass carries (libmodel/surgery/patch.h PatchPassInput, PatchPassState: the patch and all its step
// keeps between steps) goes back into a model exactly: a second model, sewn alike but stepped on
// a plate that slid elsewhere, takes the first one's state, and from there the two step on a
// sliding plate to the same bit.
TEST(Patch, WhatAPassCarriesGoesBackIntoTheModelExactly) {
    Plate plate;
    PatchSpec pressed = spec();
    pressed.gravity = Eigen::Vector3d(0, 0, -1e-2);  // pressed onto the plate: contact and friction at every step
    pressed.friction = 1.0;
    PatchModel a(pressed, plate.mesh.positions, plate.surface()), b(pressed, plate.mesh.positions, plate.surface());
    const ParticlePositions at = positions_of(plate, a);
    ASSERT_TRUE(sew_eight(a, at));
    ASSERT_TRUE(sew_eight(b, at));
    auto slid = [&](double by) {
        ParticlePositions moved = at;
        for (auto& p : moved) p[0] += float(by);
        return moved;
    };
    double t = 300;
    for (; t < 320; t += dt) a.step(slid(0.01 * (t + dt - 300.0)), dt, t);  // a: the plate slides along x
    for (double u = 300; u < 310; u += dt) b.step(slid(-0.02 * (u + dt - 300.0)), dt, u);  // b: elsewhere
    const PatchPassInput carried = a.pass_input(slid(0.01 * (t - 300.0)), 3.0);
    EXPECT_EQ(carried.x.size(), a.positions().size());
    EXPECT_EQ(carried.stitch_order.size(), 8u);
    ASSERT_EQ(carried.candidate_first.size(), a.positions().size() + 1);
    EXPECT_GT(carried.candidate.size(), a.positions().size());  // each vertex over the plate has some
    PatchPassState state;
    state.x = carried.x;
    state.v = carried.v;
    for (const Stitch& s : a.stitches()) state.stitch_force.push_back(s.force_n);
    state.stepped_slot_x = carried.stepped_slot_x;
    state.contact_force = a.contact_force();
    state.kept = carried.kept;
    b.take_pass_state(state, {});
    for (int k = 0; k < 200; ++k, t += dt) {
        const ParticlePositions moved = slid(0.01 * (t + dt - 300.0));
        a.step(moved, dt, t);
        b.step(moved, dt, t);
    }
    double worst = 0;
    for (std::size_t i = 0; i < a.positions().size(); ++i) worst = std::max(worst, (a.positions()[i] - b.positions()[i]).norm());
    std::printf("  after 200 steps from the carried state: max |x_a - x_b| = %.3g mm\n", worst);
    EXPECT_EQ(a.positions(), b.positions());
    ASSERT_EQ(a.loads().size(), b.loads().size());
    for (std::size_t k = 0; k < a.loads().size(); ++k) EXPECT_EQ(a.loads()[k].force_n, b.loads()[k].force_n);
    // A state of another size is refused.
    PatchPassState wrong = state;
    wrong.x.pop_back();
    EXPECT_THROW(b.take_pass_state(wrong, {}), InputError);
}
