// The detailed mesh of every real heart opened along a scripted incision, as heartsim opens it
// (libmodel/surgery/incision_state.h at the step the blade lifts), against what needs no incision code:
// the blade's plane (which side each vertex and its carrying particles lie on), the springs the
// solver cut (how far the two sides part), and rays cast through the incision (how deep one sees).
#include "libmodel/surgery/incision.h"
#include "libmodel/surgery/incision_state.h"
#include "libmodel/mapping.h"
#include "formats/scenario.h"
#include "incision_gesture.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime_test_support.h"
#include "runtime/core/trajectory.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <map>

using namespace heartsim;

namespace {

const std::filesystem::path& built_scenario(const std::string& key, const std::filesystem::path& input, const std::string& options) {
    static test::TempDir dir;
    static std::map<std::string, std::filesystem::path> built;
    if (auto found = built.find(key); found != built.end()) return found->second;
    const std::filesystem::path output = dir / (key + ".h5");
    const auto run = test::run_command(std::string(test::quoted(HEARTPREP_EXE)) + " build " + test::quoted(input) + " -o " +
                                       test::quoted(output) + " " + options);
    if (run.exit_code != 0) throw std::runtime_error("heartprep build failed: " + run.output);
    return built.emplace(key, output).first->second;
}

}  // namespace

namespace {

/// The distance along the ray from `from` in direction `d` (unit) to the first triangle of
/// `triangles` over `positions` it meets; infinity if none (Möller–Trumbore, both faces).
double first_hit(const Eigen::Vector3d& from, const Eigen::Vector3d& d, const std::vector<Eigen::Vector3f>& positions,
                 const std::vector<std::array<std::int32_t, 3>>& triangles) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& t : triangles) {
        const Eigen::Vector3d p0 = positions[std::size_t(t[0])].cast<double>();
        const Eigen::Vector3d e1 = positions[std::size_t(t[1])].cast<double>() - p0, e2 = positions[std::size_t(t[2])].cast<double>() - p0;
        const Eigen::Vector3d p = d.cross(e2);
        const double det = e1.dot(p);
        if (std::abs(det) < 1e-12) continue;
        const Eigen::Vector3d s = from - p0;
        const double u = s.dot(p) / det;
        if (u < 0 || u > 1) continue;
        const Eigen::Vector3d q = s.cross(e1);
        const double v = d.dot(q) / det;
        if (v < 0 || u + v > 1) continue;
        const double along = e2.dot(q) / det;
        if (along > 0 && along < best) best = along;
    }
    return best;
}

}  // namespace

// On every real heart (8,000 particles, the detailed mesh heartprep makes by default): the 30 mm
// incision of incision_gesture.h through the most anterior wall (the blade through the wall, as
// heartsim plan-incision plans it), the mesh opened where the blade lifts, then two retractors
// pulling the edges 6 mm apart. The mesh stays a closed 2-manifold; no vertex on one side of the
// blade's plane (in the rest shape: x = x_c less the mean displacement of the tissue beside it
// when the blade lifts) is carried by a particle on the other, both more than a tenth of a
// millimetre from it (the rest shape's strip is the blade taken through the tissue's local
// displacement, which this plane only approximates); the two caps stand apart at the end as the
// particles on either side do; every drawn position is finite; and one sees through the opened
// incision into the heart.
TEST(Incision, TheDetailedMeshOfEveryRealHeartOpensAlongAnIncision) {
    const std::vector<test::RealCase> real = test::real_cases();
    if (real.empty()) GTEST_SKIP() << "real data absent (../shared/data/real)";
    int cases = 0;
    for (const test::RealCase& c : real) {
        const std::string& name = c.name;
        SCOPED_TRACE(name);
        const Scenario scenario = read_scenario(built_scenario(name + "-8k", c.label_map, "--particles 8000 -q" + c.label_options));
        ASSERT_TRUE(scenario.visual && scenario.mapping && scenario.simulation_surface);
        // Through the wall (depth 0: heartsim plan-incision's default, the wall's thickness there
        // and 2 mm on).
        const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 30, .depth_mm = 0.0});
        auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
        IncisionState incisions(scenario.lattice, scenario.visual->positions, scenario.visual->normals, scenario.visual->triangles,
                                *scenario.mapping, *scenario.simulation_surface);
        std::string failure;
        ScriptedRunOptions options{.steps = int(std::ceil(plan.end_ms / cpu->time_step_ms()))};
        // Where the blade's plane lies in the rest shape: the tissue beside it moved (its weight,
        // the cut relieving the pre-load) by the mean displacement along x of the particles within
        // 3 mm of it when the blade lifts.
        double shift = 0;
        const auto& rest_of = scenario.lattice.particles.rest_position;
        options.on_step = [&](int, const StepReport&) {
            if (!incisions.pending(cpu->strokes(), false)) return;
            const auto now = cpu->positions();
            double sum = 0;
            int count = 0;
            for (std::size_t i = 0; i < now.size(); ++i)
                if (std::abs(rest_of[i][0] - plan.centre.x()) < 3.0 && std::abs(rest_of[i][2] - plan.centre.z()) < 15.0)
                    sum += now[i][0] - rest_of[i][0], ++count;
            shift = count ? sum / count : 0.0;
            const IncisionUpdate u = incisions.update(cpu->strokes(), now, false);
            if (!u.failures.empty()) failure = u.failures.front();
        };
        const ScriptedRunResult run = run_scripted(*cpu, plan.trajectory, options);
        EXPECT_EQ(run.watchdog_events, 0u) << run.last_watchdog_message;
        ASSERT_TRUE(incisions.cut()) << failure;
        const IncisionMesh& mesh = incisions.mesh();
        std::string why;
        EXPECT_TRUE(closed_manifold(incisions.drawn_triangles(), &why)) << why;

        const double x_c = plan.centre.x() - shift;
        const auto& rest = scenario.lattice.particles.rest_position;
        // Within the blade's sweep, a spacing and a half clear of its ends along the stroke
        // (beyond them the tissue is whole and a vertex may be carried around the end of the cut)
        // and a spacing short of its tip, which lies 2 mm into the cavity behind the wall.
        const double h = scenario.lattice.spacing;
        auto swept = [&](double y, double z) {
            return std::abs(z - plan.centre.z()) < 15.0 - 1.5 * h && y < plan.centre.y() + plan.depth_mm - 1.0 * h;
        };
        std::size_t checked = 0, across = 0;
        for (std::size_t v = 0; v < mesh.rest.size(); ++v) {
            const Eigen::Vector3d& x = mesh.rest[v];
            if (std::abs(x.x() - x_c) < 0.1 || std::abs(x.x() - x_c) > 3 * h || !swept(x.y(), x.z())) continue;
            for (int k = 0; k < 8; ++k) {
                if (incisions.mapping().weights[v][std::size_t(k)] == 0.0f) continue;
                const auto& r = rest[std::size_t(incisions.mapping().particles[v][std::size_t(k)])];
                if (std::abs(r[0] - x_c) < 0.1 || !swept(r[1], r[2])) continue;
                ++checked;
                if ((r[0] > x_c) != (x.x() > x_c)) ++across;
            }
        }
        EXPECT_GT(checked, 100u);
        EXPECT_EQ(across, 0u) << "of " << checked << " carriers of vertices beside the cut";

        const auto positions = cpu->positions();
        const std::vector<Eigen::Vector3f> drawn = apply_mapping(incisions.mapping(), positions, *scenario.simulation_surface);
        bool finite = true;
        for (const auto& p : drawn) finite = finite && p.allFinite();
        EXPECT_TRUE(finite);
        // The caps' vertices near the centre, each side's but the crack's front: their mean x.
        const test::CapFigures caps = test::cap_figures(incisions, drawn, plan);
        ASSERT_GT(caps.side_vertices[0], 0);
        ASSERT_GT(caps.side_vertices[1], 0);
        const double gap = caps.apart;
        const test::Opening opening = test::incision_opening(scenario, plan, cpu->cut_springs(), positions);
        std::printf("  %s: %zu particles, %zu vertices (%zu added), %zu cut faces; the caps %.2f mm apart near the centre, the cut "
                    "springs open by %.2f mm (mean)\n",
                    name.c_str(), rest.size(), mesh.rest.size(), mesh.rest.size() - scenario.visual->positions.size(),
                    incisions.drawn_triangles().size() - incisions.cap_first(), gap, opening.mean_mm);
        EXPECT_GT(gap, 0.5 * opening.mean_mm);

        // A line of sight through the opened incision into the heart: rays cast along the blade
        // (+y) from in front of the heart through a grid of points around the incision's centre.
        // On the uncut mesh at the same positions a ray meets the wall's outer face, then its inner
        // face; through the opened incision one passes both and goes on into the cavity.
        const std::vector<Eigen::Vector3f> uncut = apply_mapping(*scenario.mapping, positions, *scenario.simulation_surface);
        double deepest = 0, wall = 0;
        int through = 0;
        for (int i = -4; i <= 4; ++i)
            for (int k = -4; k <= 4; ++k) {
                const Eigen::Vector3d from(plan.centre.x() + 0.5 * i, plan.centre.y() - 20.0, plan.centre.z() + 1.0 * k);
                const double open = first_hit(from, Eigen::Vector3d::UnitY(), drawn, incisions.drawn_triangles());
                const double outer = first_hit(from, Eigen::Vector3d::UnitY(), uncut, scenario.visual->triangles);
                if (!std::isfinite(outer)) continue;
                const double inner = outer + 1e-4 + first_hit(from + (outer + 1e-4) * Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitY(), uncut,
                                                              scenario.visual->triangles);
                if (!std::isfinite(inner)) continue;
                if (open - outer > deepest) deepest = open - outer, wall = inner - outer;
                through += open > inner + 0.5;
            }
        std::printf("  %s: %d of 81 rays see through the opened wall into the heart; the deepest reaches %.1f mm past the uncut "
                    "surface, where the wall is %.1f mm thick\n",
                    name.c_str(), through, deepest, wall);
        EXPECT_GT(through, 0) << "no line of sight through the incision into the heart";
        ++cases;
    }
    EXPECT_GT(cases, 0);
}

// The retractor's one side on the gl backend as on the cpu: after the same incision through the
// phantom's anterior wall, a grabber closed across it (its centre nearest a particle beside the
// blade's + side) holds the same particles on both, all on that side of the blade's plane.
TEST(Incision, AGrabberAcrossTheCutTakesTheSameSideOnBothBackends) {
    REQUIRE_GL();
    const Scenario scenario = read_scenario(test::built_phantom("--cavity 2 --anchor-border"));
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 16, .retract = false});
    const double h = scenario.lattice.spacing;
    // The blade's plane x = centre.x lies a quarter spacing beyond a particle column: the next
    // column is 0.75 h on, so a centre 0.3 h beyond the plane is nearest that one.
    const Eigen::Vector3d centre = plan.centre + Eigen::Vector3d(0.3 * h, 0, 0);
    std::vector<std::vector<std::int32_t>> held;
    auto cpu = make_cpu_backend(scenario, options_from(scenario.solver));
    auto gl = make_gl_backend(*test::shared_gl_context(), scenario, options_from(scenario.solver));
    for (Backend* backend : {cpu.get(), gl.get()}) {
        const ScriptedRunResult run = run_scripted(*backend, plan.trajectory, {.steps = int(std::ceil(plan.end_ms / backend->time_step_ms()))});
        EXPECT_EQ(run.watchdog_events, 0u);
        ASSERT_FALSE(backend->cut_springs().empty());
        backend->set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(1.6 * h)});
        backend->set_pose(1, {.position = centre});
        EXPECT_GT(backend->begin_grab(1), 0u);
        backend->instrument_forces();
        held.push_back(backend->contact_particles(1));
    }
    ASSERT_EQ(held.size(), 2u);
    EXPECT_EQ(held[0], held[1]);
    const auto& rest = scenario.lattice.particles.rest_position;
    for (std::int32_t i : held[0]) EXPECT_GT(rest[std::size_t(i)][0], plan.centre.x()) << "particle " << i << " across the cut";
    std::printf("  %zu particles held on both backends, all on the grabber's side\n", held[0].size());
}
