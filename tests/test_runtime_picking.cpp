// Probe contacts (docs/runtime.md "Probe contacts"): the picking buffer against the direct searches on a flat
// block pressed by a probe: the same contact particles, the same force, and the force error of a
// stale picking buffer (refreshed every K force requests) while the probe moves.
// GL tests run on whatever EGL device there is (Mesa llvmpipe in CI) and skip with a message
// where there is none. docs/runtime.md, "Probe contacts".
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/gl/gl_context.h"
#include "runtime/gl/picking.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <iterator>
#include <optional>

using namespace heartsim;
namespace fs = std::filesystem;

namespace {

/// A flat block of tissue (label 1, 20 × 20 × 8 mm at 1 mm) on an anchoring slab (label 2), built
/// by heartprep as users build scenarios; read once per test program.
const Scenario& block_scenario() {
    static std::optional<Scenario> scenario;
    static test::TempDir dir;
    if (scenario) return *scenario;
    LabelVolume volume;
    volume.geometry.dims = {24, 24, 13};
    volume.labels.assign(volume.geometry.voxel_count(), 0);
    for (int k = 0; k < 13; ++k)
        for (int j = 2; j < 22; ++j)
            for (int i = 2; i < 22; ++i) {
                int label = 0;
                if (k >= 1 && k < 3) label = 2;       // the anchoring slab under the block
                else if (k >= 3 && k < 11) label = 1; // the block: its top face is free
                volume.labels[volume.geometry.linear(i, j, k)] = label;
            }
    const fs::path input = dir / "block.nrrd", output = dir / "block.h5";
    write_label_volume(input, volume);
    const auto run = test::run_command(std::string("'") + HEARTPREP_EXE + "' build '" + input.string() + "' -o '" + output.string() +
                                       "' --tissue=1 --anchor-label 2 --spacing 1 --no-visual -q");
    if (run.exit_code != 0) throw std::runtime_error("heartprep build failed: " + run.output);
    scenario = read_scenario(output);
    return *scenario;
}

/// The block's free top face: outward normal n (unit, along the axis of the anchors' offset) and
/// the centre of the face.
struct Face {
    Eigen::Vector3d centre, normal;
};

Face top_face(const Scenario& scenario) {
    const auto& p = scenario.lattice.particles;
    Eigen::Vector3d all = Eigen::Vector3d::Zero(), anchored = Eigen::Vector3d::Zero();
    std::size_t anchored_count = 0;
    for (std::size_t i = 0; i < p.size(); ++i) {
        const Eigen::Vector3d x(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        all += x;
        if (p.anchored[i]) anchored += x, ++anchored_count;
    }
    all /= double(p.size());
    anchored /= double(std::max<std::size_t>(anchored_count, 1));
    Eigen::Vector3d axis = all - anchored;
    Eigen::Index k = 0;
    axis.cwiseAbs().maxCoeff(&k);
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    normal[k] = axis[k] > 0 ? 1.0 : -1.0;
    double top = -1e30;
    for (std::size_t i = 0; i < p.size(); ++i) top = std::max(top, normal[k] * double(p.rest_position[i][std::size_t(k)]));
    Face face{all, normal};
    face.centre[k] = normal[k] * top;
    return face;
}

/// A pose whose tool +z (the probe's axis, base → tip) points into the face.
InstrumentPose probe_pose(const Face& face, const Eigen::Vector3d& semi, double depth_mm, const Eigen::Vector3d& slide) {
    InstrumentPose pose;
    pose.orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), -face.normal);
    pose.position = face.centre + slide + face.normal * (semi.z() - depth_mm);
    return pose;
}

std::vector<std::int32_t> difference(const std::vector<std::int32_t>& a, const std::vector<std::int32_t>& b) {
    std::vector<std::int32_t> out;
    std::set_difference(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
    return out;
}

double relative(const Eigen::Vector3d& a, const Eigen::Vector3d& reference) { return (a - reference).norm() / reference.norm(); }

const Eigen::Vector3d semi_axes(3.0, 2.5, 3.5);

TEST(RuntimePicking, ContactModesParse) {
    EXPECT_EQ(parse_contact_mode("direct"), ContactMode::direct);
    EXPECT_EQ(parse_contact_mode("picking"), ContactMode::picking);
    EXPECT_EQ(parse_contact_mode("search"), ContactMode::search);
    EXPECT_THROW(parse_contact_mode("raycast"), InputError);
    const Scenario& scenario = block_scenario();
    auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
    EXPECT_THROW(cpu->set_contact({.mode = ContactMode::picking}), InputError);
    EXPECT_NO_THROW(cpu->set_contact({.mode = ContactMode::direct}));
}

// The test: for a probe touching a flat block, the picking buffer finds the same contact
// particles as the direct search (exactly: every surface particle within the tolerance), the
// particles the step projected (the cpu reference's set) are among them, and the forces agree.
TEST(RuntimePicking, FlatBlockPickingFindsTheDirectContacts) {
    REQUIRE_GL();
    const Scenario& scenario = block_scenario();
    ASSERT_TRUE(scenario.simulation_surface.has_value());
    const Face face = top_face(scenario);
    auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options_from(scenario.solver));
    gl->set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = semi_axes});
    gl->set_pose(0, probe_pose(face, semi_axes, -0.5, Eigen::Vector3d::Zero()));
    const int press = 60, hold = 60;
    for (int s = 1; s <= press + hold; ++s) {
        gl->set_pose(0, probe_pose(face, semi_axes, -0.5 + 2.0 * std::min(1.0, double(s) / press), Eigen::Vector3d::Zero()));
        gl->step(1);
    }
    const InstrumentForces direct = gl->instrument_forces();
    const auto touched = gl->contact_particles(0);
    gl->set_contact({.mode = ContactMode::search});
    const InstrumentForces searched = gl->instrument_forces();
    const auto search_set = gl->contact_particles(0);
    gl->set_contact({.mode = ContactMode::picking, .picking_refresh = 1});
    const InstrumentForces picked = gl->instrument_forces();
    const auto picking_set = gl->contact_particles(0);
    gl->set_contact({.mode = ContactMode::direct});
    const InstrumentForces direct_again = gl->instrument_forces();

    const auto extra = difference(picking_set, touched), missing = difference(touched, picking_set);
    std::printf("block: %zu particles; probe (%.1f, %.1f, %.1f) mm pressed 1.5 mm\n", scenario.lattice.particles.size(), semi_axes.x(),
                semi_axes.y(), semi_axes.z());
    std::printf("contacts: step-touched %zu, search %zu, picking %zu (picking \\ touched %zu, touched \\ picking %zu)\n", touched.size(),
                search_set.size(), picking_set.size(), extra.size(), missing.size());
    std::printf("force direct (%.6g, %.6g, %.6g) N, search rel. diff %.3g, picking rel. diff %.3g\n", direct.hand[0].force_n.x(),
                direct.hand[0].force_n.y(), direct.hand[0].force_n.z(), relative(searched.hand[0].force_n, direct.hand[0].force_n),
                relative(picked.hand[0].force_n, direct.hand[0].force_n));

    ASSERT_GE(touched.size(), 5u) << "the probe must press on several particles";
    EXPECT_EQ(picking_set, search_set) << "the picking buffer must find exactly the surface particles within the tolerance";
    EXPECT_TRUE(missing.empty()) << missing.size() << " particles the step projected are not picked";
    EXPECT_LE(extra.size(), touched.size() / 2) << "picking keeps particles within the tolerance that the last substep did not push";
    EXPECT_EQ(picked.hand[0].particles, picking_set.size());
    EXPECT_LE(relative(picked.hand[0].force_n, direct.hand[0].force_n), 1e-3);
    EXPECT_LE(relative(searched.hand[0].force_n, direct.hand[0].force_n), 1e-3);
    EXPECT_EQ(direct_again.hand[0].force_n, direct.hand[0].force_n) << "switching back to direct is the step's list again";
    const PassTimes times = gl->pass_times();
    EXPECT_GE(times.picking_calls, 2);
    EXPECT_GE(times.picking_renders, 1);
    std::printf("picking pass %.3f ms per call (llvmpipe: a test device)\n", times.picking_ms / double(std::max(1LL, times.picking_calls)));
}

// A stale buffer while the probe slides across the block (pressed 1.5 mm, then 8 mm sideways):
// force error against the direct surface search (`search`, the same contact criterion) on the
// same state, for K = 1, 2, 4, 8, at 0.2 and 1 mm (0.2 and 1 lattice spacing) per step. The
// dynamics do not depend on the contact mode, so every run sees the same states.
TEST(RuntimePicking, StalePickingBufferErrorAgainstRefresh) {
    REQUIRE_GL();
    const Scenario& scenario = block_scenario();
    const Face face = top_face(scenario);
    const Eigen::Vector3d tangent = face.normal.unitOrthogonal();
    for (double speed : {0.2, 1.0}) {
        const int press = 40, slide = int(std::lround(8.0 / speed));
        auto run = [&](const ContactSettings& contact) {
            auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options_from(scenario.solver));
            gl->set_contact(contact);
            gl->set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = semi_axes});
            gl->set_pose(0, probe_pose(face, semi_axes, -0.5, -4.0 * tangent));
            std::vector<Eigen::Vector3d> forces;
            for (int s = 1; s <= press + slide; ++s) {
                const double depth = -0.5 + 2.0 * std::min(1.0, double(s) / press);
                const double along = -4.0 + speed * std::max(0, s - press);
                gl->set_pose(0, probe_pose(face, semi_axes, depth, along * tangent));
                gl->step(1);
                forces.push_back(gl->instrument_forces().hand[0].force_n);
            }
            return std::make_tuple(forces, gl->pass_times(), gl->time_step_ms());
        };
        const auto [reference, reference_times, step_ms] = run({.mode = ContactMode::search});
        double peak = 0;
        for (const auto& f : reference) peak = std::max(peak, f.norm());
        std::printf("slide at %.2g mm per step (%.3g m/s): reference (search) peak force %.4g N, search pass %.3f ms per call\n", speed,
                    speed / step_ms, peak, reference_times.picking_ms / double(std::max(1LL, reference_times.picking_calls)));
        std::printf("%4s %14s %14s %12s %14s\n", "K", "max rel. err", "mean rel. err", "renders", "ms per call");
        std::vector<double> max_errors, mean_errors;
        for (int k : {1, 2, 4, 8}) {
            const auto [forces, times, unused] = run({.mode = ContactMode::picking, .picking_refresh = k});
            double max_error = 0, sum = 0;
            int counted = 0;
            for (std::size_t f = press; f < forces.size(); ++f) {  // while sliding
                if (reference[f].norm() < 0.05 * peak) continue;
                const double e = relative(forces[f], reference[f]);
                max_error = std::max(max_error, e), sum += e, ++counted;
            }
            std::printf("%4d %14.4g %14.4g %12lld %14.3f\n", k, max_error, counted ? sum / counted : 0.0, times.picking_renders,
                        times.picking_ms / double(std::max(1LL, times.picking_calls)));
            max_errors.push_back(max_error), mean_errors.push_back(counted ? sum / counted : 0.0);
            EXPECT_EQ(times.picking_renders, (press + slide + k - 1) / k) << "one render every K force requests";
        }
        EXPECT_LE(max_errors[0], 1e-3) << "a buffer rendered every force request agrees with the direct search";
        // Documented (docs/runtime.md): the error comes from contacts that the stale buffer's
        // window no longer covers; it does not shrink as K grows, and stays bounded while the
        // probe moves less than its radius between renders.
        EXPECT_LE(mean_errors[1], mean_errors[3] + 1e-9);
        if (speed * 8 < semi_axes.minCoeff()) {
            for (double e : max_errors) EXPECT_LE(e, 0.25);
        }
    }
}

}  // namespace
