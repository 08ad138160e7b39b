// The visualisation step (docs/runtime.md "Rendering") and its outputs: the vertex-shader mapping against
// libmodel's apply_mapping (read back through transform feedback from the drawing shader
// itself), the normals pass against particle_normals, a headless screenshot of the phantom
// against a golden image, the simulation surface drawn when there is no visual mesh, the
// section view, an incision's opened mesh, a septal defect's patch and stitches, the
// window mode under Xvfb, and the PNG writer. GL tests skip with a message where there is no
// EGL/OpenGL 4.3 device; the window test where Xvfb is not installed.
//
// Golden image: tests/data/golden/phantom_rest.png. Regenerate (after an intended change of the
// picture) with HEARTSIM_UPDATE_GOLDEN=1 ./test_runtime_render --gtest_filter='*Golden*'.
#include "defect_block_scenario.h"
#include "incision_gesture.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/incision_state.h"
#include "libmodel/mapping.h"
#include "runtime/backend/backend.h"
#include "runtime/gl/backend_gl.h"
#include "runtime/gl/gl_context.h"
#include "runtime/view/png.h"
#include "runtime/gl/renderer.h"
#include "runtime/surgery/repair.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/view/section_plane.h"
#include "formats/volume_io.h"
#include "runtime/core/trajectory.h"

#include <gtest/gtest.h>

#include <cstdio>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <map>
#include <optional>

using namespace heartsim;
using test::compare_images;
using test::ImageDifference;
using test::golden_reference;
using test::write_golden_failure;
using test::cut_pixels;
using test::quoted;
namespace fs = std::filesystem;

namespace {

test::TempDir& scratch() {
    static test::TempDir dir;
    return dir;
}

/// The phantom scenario, built once with heartprep as users build it.
const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border"); }

const Scenario& phantom_scenario() {
    static std::optional<Scenario> scenario;
    if (!scenario) scenario = read_scenario(phantom());
    return *scenario;
}

test::CommandResult run_heartsim(const std::string& arguments) {
    return test::run_command("timeout 600 " + quoted(HEARTSIM_EXE) + " " + arguments);
}

/// A probe pressing `depth_mm` into the phantom at its right-most free particle next to an
/// anchor, over `steps` steps (the pattern of test_runtime_backend).
Trajectory pressing_probe(const Scenario& scenario, int steps, double depth_mm) {
    const auto& rest = scenario.lattice.particles.rest_position;
    const auto& anchored = scenario.lattice.particles.anchored;
    const auto& neighbours = scenario.packing->neighbours;
    std::size_t right = 0;
    bool have = false;
    for (std::size_t i = 0; i < rest.size(); ++i) {
        if (anchored[i]) continue;
        if (std::none_of(neighbours[i].begin(), neighbours[i].end(), [&](std::int32_t j) { return j >= 0 && anchored[std::size_t(j)]; }))
            continue;
        if (!have || rest[i][0] > rest[right][0]) right = i, have = true;
    }
    const double spacing = scenario.lattice.spacing, radius = 1.5 * spacing, dt = scenario.solver.dt_ms;
    const Eigen::Vector3d r(rest[right][0], rest[right][1], rest[right][2]);
    Trajectory t;
    for (int k = 0; k <= 2; ++k) {
        InstrumentKeyframe key;
        key.time_ms = k * steps * dt / 2;
        key.hand = 0;
        key.kind = InstrumentKind::probe;
        key.semi_axes = Eigen::Vector3d(radius, 0.8 * radius, 1.2 * radius);
        key.pose.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(0, 1, 1).normalized()));
        key.pose.position = r + Eigen::Vector3d(radius + 0.5 * spacing - std::min(1.0, k / 1.0) * (0.5 * spacing + depth_mm), 0, 0);
        t.keyframes.push_back(key);
    }
    return t;
}

struct MappingCheck {
    double max_vertex_error_mm = 0, max_normal_error = 0, max_displacement_mm = 0;
    std::size_t vertices = 0;
};

/// Runs `steps` steps of a pressing probe on `backend`, then compares the drawing shader's
/// vertices (transform feedback) with apply_mapping on the read-back positions, and the
/// normals pass with particle_normals.
MappingCheck check_mapping(Backend& backend, const Scenario& scenario, int steps) {
    const ScriptedRunResult run = run_scripted(backend, pressing_probe(scenario, steps, 3.0), {.steps = steps});
    EXPECT_EQ(run.watchdog_events, 0u) << run.last_watchdog_message;
    Renderer renderer(scenario, {.width = 64, .height = 64});
    EXPECT_TRUE(renderer.draws_visual_mesh());
    const auto captured = renderer.capture_vertices(backend);
    const auto normals = renderer.read_particle_normals();
    const auto positions = backend.positions();
    const auto expected = apply_mapping(*scenario.mapping, positions, *scenario.simulation_surface);
    const auto expected_normals = particle_normals(positions, *scenario.simulation_surface);
    MappingCheck c;
    c.vertices = captured.size();
    EXPECT_EQ(captured.size(), expected.size());
    for (std::size_t v = 0; v < std::min(captured.size(), expected.size()); ++v)
        for (int k = 0; k < 3; ++k) {
            c.max_vertex_error_mm = std::max(c.max_vertex_error_mm, double(std::abs(captured[v][k] - expected[v][k])));
            c.max_displacement_mm = std::max(c.max_displacement_mm, double(std::abs(expected[v][k] - scenario.visual->positions[v][k])));
        }
    for (std::size_t i = 0; i < normals.size(); ++i)
        for (int k = 0; k < 3; ++k) c.max_normal_error = std::max(c.max_normal_error, double(std::abs(normals[i][k] - expected_normals[i][k])));
    std::printf("  %zu visual vertices after %d steps: max displacement %.3f mm, max |vertex shader - apply_mapping| %.3g mm, "
                "max |normals pass - particle_normals| %.3g\n",
                c.vertices, steps, c.max_displacement_mm, c.max_vertex_error_mm, c.max_normal_error);
    return c;
}

/// Pixels that differ from the background colour (the model or an instrument).
double coverage(const Image& image) {
    const std::uint8_t* corner = image.pixels.data();
    std::size_t covered = 0;
    const std::size_t pixels = std::size_t(image.width) * std::size_t(image.height);
    for (std::size_t p = 0; p < pixels; ++p)
        for (int c = 0; c < 3; ++c)
            if (std::abs(int(image.pixels[p * 3 + std::size_t(c)]) - int(corner[c])) > 8) {
                ++covered;
                break;
            }
    return double(covered) / double(pixels);
}

/// The golden scene: the phantom at rest, anterior view, 256×256, with a probe beside its
/// right-most particle (drawn as its ellipsoid).
std::string golden_arguments(const Scenario& scenario) {
    const auto& rest = scenario.lattice.particles.rest_position;
    std::size_t right = 0;
    for (std::size_t i = 0; i < rest.size(); ++i)
        if (rest[i][0] > rest[right][0]) right = i;
    const double r = 1.5 * scenario.lattice.spacing;
    char probe[256];
    std::snprintf(probe, sizeof probe, "%.3f,%.3f,%.3f,%.3f,%.3f,%.3f", rest[right][0] + r + 1.0, rest[right][1] - 2 * r, rest[right][2],
                  r, r, 2 * r);
    return std::string(" --headless --steps 0 --size 256x256 --view anterior --probe ") + probe;
}


/// The area, mm², where the plane (`point`, unit `normal`) cuts the solid that the closed surface
/// (`positions`, `triangles` counter-clockwise seen from outside) bounds. Each triangle the plane
/// crosses gives a segment of the section's boundary; oriented along normal × (the triangle's
/// outward normal) it runs counter-clockwise about `normal` around the solid (clockwise around a
/// hole), so the shoelace sum ½ Σ normal·(a × b) over the segments is the area (Green's theorem).
/// A double-sided sheet's two faces cancel. A vertex on the plane counts as behind it.
template <class Positions, class Triangles>
double cross_section_area(const Positions& positions, const Triangles& triangles, const Eigen::Vector3d& point, const Eigen::Vector3d& normal) {
    double twice_area = 0;
    for (const auto& t : triangles) {
        Eigen::Vector3d p[3];
        double d[3];
        for (int k = 0; k < 3; ++k) {
            const auto& v = positions[std::size_t(t[std::size_t(k)])];
            p[k] = Eigen::Vector3d(v[0], v[1], v[2]) - point;
            d[k] = normal.dot(p[k]);
        }
        std::vector<Eigen::Vector3d> crossing;
        for (int k = 0; k < 3; ++k) {
            const int j = (k + 1) % 3;
            if ((d[k] > 0) != (d[j] > 0)) crossing.push_back(p[k] + (d[k] / (d[k] - d[j])) * (p[j] - p[k]));
        }
        if (crossing.size() != 2) continue;
        Eigen::Vector3d a = crossing[0], b = crossing[1];
        const Eigen::Vector3d outward = (p[1] - p[0]).cross(p[2] - p[0]);
        if ((b - a).dot(normal.cross(outward)) < 0) std::swap(a, b);
        twice_area += normal.dot(a.cross(b));
    }
    return 0.5 * twice_area;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

TEST(Png, RoundTripAndDamageDetection) {
    test::TempDir dir;
    Image image{37, 21, 3, {}};
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x)
            for (int c = 0; c < 3; ++c) image.pixels.push_back(std::uint8_t((x * 7 + y * 13 + c * 50 + x * y) & 255));
    write_png(dir / "a.png", image);
    const Image back = read_png(dir / "a.png");
    EXPECT_EQ(back.width, image.width);
    EXPECT_EQ(back.height, image.height);
    EXPECT_EQ(back.channels, 3);
    EXPECT_EQ(back.pixels, image.pixels);
    // Only the file itself remains (the temporary was renamed).
    EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);
    // A flipped byte in IDAT is caught by the CRC.
    std::vector<std::uint8_t> bytes = encode_png(image);
    bytes[bytes.size() / 2] ^= 0x40;
    EXPECT_THROW(decode_png(bytes, "damaged"), InputError);
    bytes = encode_png(image);
    bytes.resize(bytes.size() - 12);  // IEND cut off
    EXPECT_THROW(decode_png(bytes, "truncated"), InputError);
    // Signature, then IHDR first (PNG 1.2).
    bytes = encode_png(image);
    EXPECT_EQ(bytes[12], 'I');
    EXPECT_EQ(bytes[15], 'R');
    EXPECT_THROW(write_png(dir / "missing-folder" / "x.png", image), OutputError);
}

TEST(RenderCamera, DefaultAnteriorViewPutsThePatientsLeftOnTheRight) {
    const Eigen::AlignedBox3f box(Eigen::Vector3f(-10, -20, -30), Eigen::Vector3f(10, 20, 30));
    const Camera camera = fit_camera(box, ViewDirection::anterior, 1.0f);
    // The eye is anterior (−y in LPS) of the centre; +x (patient's left) maps to +x on screen,
    // +z (superior) up.
    EXPECT_LT(camera.eye().y(), -camera.radius);
    const Eigen::Matrix4f vp = camera.projection(1.0f) * camera.view();
    auto screen = [&](Eigen::Vector3f p) {
        const Eigen::Vector4f c = vp * p.homogeneous();
        return Eigen::Vector2f(c.x() / c.w(), c.y() / c.w());
    };
    EXPECT_GT(screen({10, 0, 0}).x(), 0.1f);
    EXPECT_GT(screen({0, 0, 30}).y(), 0.1f);
    // The whole box is inside the frame.
    for (int corner = 0; corner < 8; ++corner) {
        const Eigen::Vector2f s = screen(box.corner(Eigen::AlignedBox3f::CornerType(corner)));
        EXPECT_LE(s.cwiseAbs().maxCoeff(), 1.0f) << corner;
    }
    EXPECT_THROW(parse_view_direction("sideways"), InputError);
}

// The surgeon's view: the patient supine, the surgeon standing on the patient's right and looking
// down into the chest. The eye is anterior (−y) and out over the patient's right (−x), mostly
// above; the far side of the table (the patient's left, +x) is up on the screen; facing across
// the table, the surgeon has the patient's head (+z) on the left and the feet on the right.
TEST(RenderCamera, TheSurgeonsViewLooksDownOnTheChestFromThePatientsRight) {
    const Eigen::AlignedBox3f box(Eigen::Vector3f(-30, -30, -30), Eigen::Vector3f(30, 30, 30));
    ASSERT_EQ(parse_view_direction("surgeon"), ViewDirection::surgeon);
    const Camera camera = fit_camera(box, ViewDirection::surgeon, 1.0f);
    const Eigen::Vector3f eye = camera.eye() - camera.target;
    EXPECT_LT(eye.y(), 0.0f);
    EXPECT_LT(eye.x(), 0.0f);
    EXPECT_GT(std::abs(eye.y()), 2.0f * std::abs(eye.x())) << "mostly from above";
    EXPECT_NEAR(eye.z(), 0.0f, 1e-3f * eye.norm());
    const Eigen::Matrix4f vp = camera.projection(1.0f) * camera.view();
    auto screen = [&](Eigen::Vector3f p) {
        const Eigen::Vector4f c = vp * p.homogeneous();
        return Eigen::Vector2f(c.x() / c.w(), c.y() / c.w());
    };
    EXPECT_GT(screen({30, 0, 0}).y(), 0.1f) << "the patient's left is across the table, up";
    EXPECT_LT(screen({0, 0, 30}).x(), -0.1f) << "the head on the surgeon's left";
    EXPECT_GT(screen({0, 0, -30}).x(), 0.1f) << "the feet on the right";
}

TEST(RenderMapping, VertexShaderEqualsTheCpuFormulaOnTheGlBackend) {
    REQUIRE_GL();
    const Scenario& scenario = phantom_scenario();
    ASSERT_TRUE(scenario.visual && scenario.mapping && scenario.simulation_surface) << "the phantom scenario should have a mapped visual mesh";
    auto backend = make_gl_backend(*test::shared_gl_context(), scenario, options_from(scenario.solver));
    const MappingCheck c = check_mapping(*backend, scenario, 300);
    EXPECT_GT(c.max_displacement_mm, 0.5) << "the probe and gravity should deform the mesh";
    EXPECT_LE(c.max_vertex_error_mm, 1e-4);
    EXPECT_LE(c.max_normal_error, 1e-5);
}

TEST(RenderMapping, VertexShaderEqualsTheCpuFormulaOnTheCpuBackend) {
    REQUIRE_GL();
    const Scenario& scenario = phantom_scenario();
    auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
    const MappingCheck c = check_mapping(*backend, scenario, 100);  // positions uploaded per frame
    EXPECT_GT(c.max_displacement_mm, 0.1);
    EXPECT_LE(c.max_vertex_error_mm, 1e-4);
    EXPECT_LE(c.max_normal_error, 1e-5);
}

TEST(RenderGolden, HeadlessScreenshotOfThePhantomMatchesTheGoldenImage) {
    REQUIRE_GL();
    const fs::path golden = fs::path(HEARTSIM_SOURCE_DIR) / "tests/data/golden/phantom_rest.png";
    const std::string arguments = golden_arguments(phantom_scenario());
    for (const char* backend : {"gl", "cpu"}) {
        const fs::path shot = scratch() / (std::string("phantom_rest_") + backend + ".png");
        const auto run = run_heartsim("run " + quoted(phantom()) + arguments + " --backend " + backend + " --screenshot " + quoted(shot) + " --stats");
        ASSERT_EQ(run.exit_code, 0) << run.output;
        EXPECT_NE(run.output.find("visualisation step"), std::string::npos) << run.output;
        const Image image = read_png(shot);
        ASSERT_EQ(image.width, 256);
        ASSERT_EQ(image.height, 256);
        EXPECT_GT(coverage(image), 0.15) << "the phantom should fill a good part of the frame";
        const std::optional<Image> golden_image = golden_reference(golden, image, std::string(backend) == "gl");
        if (!golden_image) GTEST_SKIP() << "no golden image " << golden << " (HEARTSIM_UPDATE_GOLDEN=1 writes it)";
        const Image& reference = *golden_image;
        ASSERT_EQ(reference.width, image.width);
        ASSERT_EQ(reference.height, image.height);
        ASSERT_EQ(reference.channels, 3);
        Image diff;
        const ImageDifference d = compare_images(image, reference, 16, &diff);
        std::printf("  %s backend: mean |difference| %.4f / 255, %.4f %% of pixels differ by more than 16 / 255\n", backend, d.mean_abs,
                    100 * d.fraction_over);
        // Tolerance: llvmpipe on another CPU or Mesa version may round edges and shading
        // differently; a wrong view, mapping or lighting moves far more than this.
        const bool pass = d.mean_abs < 2.0 && d.fraction_over < 0.01;
        if (!pass) write_golden_failure(std::string("phantom_rest_") + backend, diff, image);
        EXPECT_TRUE(pass) << backend << ": mean " << d.mean_abs << ", fraction " << d.fraction_over;
    }
}

TEST(RenderScreenshot, SimulationSurfaceIsDrawnWithoutAVisualMeshAndEveryNWritesNumberedFrames) {
    REQUIRE_GL();
    test::TempDir dir;
    Scenario scenario = phantom_scenario();
    scenario.visual.reset();
    scenario.mapping.reset();
    write_scenario(dir / "surface.h5", scenario);
    const auto run = run_heartsim("run " + quoted(dir / "surface.h5") + " --headless --steps 4 --size 128x96 --screenshot " +
                                  quoted(dir / "s.png") + " --screenshot-every 2 --stats");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("the simulation surface"), std::string::npos) << run.output;
    EXPECT_EQ(run.output.find("particle normals"), std::string::npos) << "no normals pass without a visual mesh\n" << run.output;
    for (const char* name : {"s.png", "s-000002.png", "s-000004.png"}) {
        ASSERT_TRUE(fs::exists(dir / name)) << name << "\n" << run.output;
        const Image image = read_png(dir / name);
        EXPECT_EQ(image.width, 128);
        EXPECT_EQ(image.height, 96);
        EXPECT_GT(coverage(image), 0.15) << name;
    }
    EXPECT_FALSE(fs::exists(dir / "s-000001.png"));
}

TEST(RenderScreenshot, HeadlessWithoutScreenshotSkipsRendering) {
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --stats");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("skipped (headless, no --screenshot)"), std::string::npos) << run.output;
    EXPECT_EQ(run.output.find("render:"), std::string::npos) << run.output;
    const auto bad = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --screenshot-every 2");
    EXPECT_EQ(bad.exit_code, 2) << bad.output;
    EXPECT_NE(bad.output.find("--screenshot-every needs --screenshot"), std::string::npos) << bad.output;
}

TEST(RenderWindow, TheCpuBackendSimulatesOnItsOwnThreadPacedToTheWallClock) {
    // `heartsim scenario.h5` the way staff start a session: the simulation must follow the wall
    // clock (never ahead of it), not take one step per frame (docs/runtime.md "Window mode").
    if (test::run_command("command -v xvfb-run && command -v Xvfb").exit_code != 0)
        GTEST_SKIP() << "Xvfb is not installed (Debian: xvfb xauth; scripts/install-deps.sh)";
    REQUIRE_GL();
    const auto run = test::run_command(test::in_xvfb_window() + quoted(HEARTSIM_EXE) + " run " + quoted(phantom()) +
                                       " --backend cpu --seconds 0.5 --size 320x240 2>&1");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("simulation on its own thread, paced to the wall clock"), std::string::npos) << run.output;
    long long frames = 0;
    double wall_s = 0, simulated_ms = 0;
    long long steps = 0;
    // The closing line ("window: N frames in S s ..."; a slow run also prints "window: the simulation runs at ...").
    std::size_t window = run.output.find("window: ");
    while (window != std::string::npos && std::sscanf(run.output.c_str() + window, "window: %lld frames in %lf s", &frames, &wall_s) != 2)
        window = run.output.find("window: ", window + 1);
    ASSERT_NE(window, std::string::npos) << run.output;
    const auto simulated = run.output.find(" ms simulated", window);
    ASSERT_NE(simulated, std::string::npos) << run.output;
    simulated_ms = std::stod(run.output.substr(run.output.rfind(' ', simulated - 1) + 1));
    const auto ran = run.output.find("ran ");
    ASSERT_NE(ran, std::string::npos) << run.output;
    ASSERT_EQ(std::sscanf(run.output.c_str() + ran, "ran %lld steps", &steps), 1) << run.output;
    std::printf("  %lld frames, %lld steps, %.1f ms simulated in %.2f s of wall clock\n", frames, steps, simulated_ms, wall_s);
    // Within one step of the end; --real-time auto may lengthen the step on a slow machine ("real
    // time: … mass scale S, steps of X ms …").
    double step_ms = phantom_scenario().solver.dt_ms;
    for (std::size_t at = run.output.find(", steps of "); at != std::string::npos; at = run.output.find(", steps of ", at + 1))
        step_ms = std::max(step_ms, std::stod(run.output.substr(at + 11)));
    EXPECT_NEAR(simulated_ms, 500.0, step_ms) << "the whole --seconds";
    EXPECT_GE(wall_s * 1e3, simulated_ms * 0.99) << "never ahead of the wall clock";
    EXPECT_GT(steps, 3 * frames) << "not one step per frame";
}

// The tissue's surface under a pixel comes from the last frame's depth: there is none before the
// first frame (a click then finds no tissue, where the undefined depth put the mouse device off
// the heart), the drawn surface in the middle of the fitted view once a frame is drawn, and none
// over the background at a corner.
TEST(RenderPicking, TheSurfaceUnderAPixelIsNoneBeforeTheFirstFrame) {
    REQUIRE_GL();
    const Scenario& scenario = phantom_scenario();
    ASSERT_TRUE(scenario.visual.has_value());
    auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
    const int size = 128;
    Renderer renderer(scenario, {.width = size, .height = size});
    EXPECT_FALSE(renderer.surface_point(size / 2, size / 2, size, size).has_value()) << "no frame drawn yet";
    renderer.render(*backend, {});
    const std::optional<Eigen::Vector3f> hit = renderer.surface_point(size / 2, size / 2, size, size);
    ASSERT_TRUE(hit.has_value()) << "the model fills the middle of the fitted view";
    double nearest = 1e30;  // to the detailed mesh at rest (its edges are about a millimetre)
    for (const auto& v : scenario.visual->positions)
        nearest = std::min(nearest, (Eigen::Vector3d(v[0], v[1], v[2]) - hit->cast<double>()).norm());
    EXPECT_LT(nearest, 2.0) << hit->transpose();
    EXPECT_FALSE(renderer.surface_point(1, 1, size, size).has_value()) << "the background at a corner";
}

TEST(RenderWindow, StartsUnderXvfbRendersFramesAndExitsCleanly) {
    if (test::run_command("command -v xvfb-run && command -v Xvfb").exit_code != 0)
        GTEST_SKIP() << "Xvfb is not installed (Debian: xvfb xauth; scripts/install-deps.sh)";
    REQUIRE_GL();
    test::TempDir dir;
    const auto run = test::run_command(test::in_xvfb_window() + quoted(HEARTSIM_EXE) + " run " +
                                       quoted(phantom()) + " --steps 20 --size 320x240 --screenshot " + quoted(dir / "window.png") +
                                       " --stats 2>&1");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("window: "), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("ran 20 steps"), std::string::npos) << run.output;
    ASSERT_TRUE(fs::exists(dir / "window.png")) << run.output;
    const Image image = read_png(dir / "window.png");
    EXPECT_EQ(image.width, 320);
    EXPECT_EQ(image.height, 240);
    EXPECT_GT(coverage(image), 0.1) << run.output;
    std::printf("%s", run.output.c_str());
}

// The section view (--clip): the plane cuts the phantom's wall open where the scenario's own
// surface says it should. Seen square on through the orbit centre, a plane is drawn at one scale
// (the camera's mm per pixel at the centre's depth; at depth D beyond it, × (distance + D) /
// distance), so the cut wall's pixels times that pixel area must be the area where the plane cuts
// the solid the drawn surface bounds, computed here from its triangles. Without --clip no pixel
// has the cut colour; with it every cut pixel lies inside the whole heart's silhouette, and part
// of what was the near wall now shows the interior.
TEST(RenderSection, TheCutWallIsTheAreaWhereThePlaneCutsTheSurface) {
    REQUIRE_GL();
    test::TempDir dir;
    const Scenario& scenario = phantom_scenario();
    ASSERT_TRUE(scenario.visual && scenario.mapping);
    const int size = 512;
    Eigen::AlignedBox3f box;
    for (const auto& v : scenario.visual->positions) box.extend(Eigen::Vector3f(v[0], v[1], v[2]));
    const Camera camera = fit_camera(box, ViewDirection::anterior, 1.0f);
    const Eigen::Vector3d centre = box.center().cast<double>(), towards_eye(0, -1, 0);  // anterior: the eye at -y
    const double mm_per_pixel = camera.mm_per_pixel(size);
    const std::string common = " --headless --steps 0 --view anterior --size " + std::to_string(size) + "x" + std::to_string(size);

    const auto whole_run = run_heartsim("run " + quoted(phantom()) + common + " --screenshot " + quoted(dir / "whole.png"));
    ASSERT_EQ(whole_run.exit_code, 0) << whole_run.output;
    const Image whole = read_png(dir / "whole.png");
    EXPECT_EQ(cut_pixels(whole), 0u) << "no cut colour without a section";
    const std::uint8_t* background = whole.pixels.data();  // the corner

    struct Case {
        std::string clip;  // --clip's value
        double depth_mm;   // the plane beyond the centre, away from the eye
    };
    char deeper[128], nearer[128];
    // Normals of any length: only the direction counts.
    std::snprintf(deeper, sizeof deeper, "%.6f,%.6f,%.6f,0,-3,0", centre.x(), centre.y() + 12.0, centre.z());
    std::snprintf(nearer, sizeof nearer, "%.6f,%.6f,%.6f,0,-0.5,0", centre.x(), centre.y() - 12.0, centre.z());
    for (const Case& c : {Case{"centre", 0.0}, Case{deeper, 12.0}, Case{nearer, -12.0}}) {
        SCOPED_TRACE("--clip " + c.clip);
        const fs::path shot = dir / ("section" + std::to_string(int(c.depth_mm)) + ".png");
        const auto run = run_heartsim("run " + quoted(phantom()) + common + " --clip " + c.clip + " --screenshot " + quoted(shot));
        ASSERT_EQ(run.exit_code, 0) << run.output;
        char said[64];
        std::snprintf(said, sizeof said, "section view: the plane %.2f mm beyond the heart's centre", c.depth_mm);
        EXPECT_NE(run.output.find(said), std::string::npos) << run.output;
        const Image image = read_png(shot);
        ASSERT_EQ(image.width, size);
        const double area = cross_section_area(scenario.visual->positions, scenario.visual->triangles,
                                               centre - c.depth_mm * towards_eye, towards_eye);
        const double scale = mm_per_pixel * (camera.distance + c.depth_mm) / camera.distance;
        const double expected = area / (scale * scale), seen = double(cut_pixels(image));
        std::size_t outside = 0, interior = 0, covered = 0;
        for (std::size_t p = 0; p < std::size_t(size) * size; ++p) {
            const std::uint8_t* a = &whole.pixels[3 * p];
            const std::uint8_t* b = &image.pixels[3 * p];
            const bool was_covered = std::abs(a[0] - background[0]) + std::abs(a[1] - background[1]) + std::abs(a[2] - background[2]) > 8;
            const bool cut = std::abs(b[0] - section_cut_rgb[0]) <= 2 && std::abs(b[1] - section_cut_rgb[1]) <= 2 &&
                             std::abs(b[2] - section_cut_rgb[2]) <= 2;
            const bool background_now = std::abs(b[0] - background[0]) + std::abs(b[1] - background[1]) + std::abs(b[2] - background[2]) <= 8;
            covered += was_covered;
            outside += cut && !was_covered;
            interior += was_covered && !cut && !background_now && std::max({std::abs(a[0] - b[0]), std::abs(a[1] - b[1]), std::abs(a[2] - b[2])}) > 24;
        }
        std::printf("  depth %+5.1f mm: section %.1f mm² = %.0f pixels expected, %.0f cut pixels (%+.2f %%); %zu of %zu heart pixels show "
                    "the interior\n",
                    c.depth_mm, area, expected, seen, 100 * (seen / expected - 1), interior, covered);
        EXPECT_GT(area, 100.0) << "the plane should cut the wall";
        // Measured: within 0.05 %; the boundary's pixels decide the rest.
        EXPECT_NEAR(seen / expected, 1.0, 0.01) << "the cut wall's pixels against the section's area";
        EXPECT_EQ(outside, 0u) << "cut pixels outside the whole heart's silhouette";
        EXPECT_GT(double(interior), 0.1 * double(covered)) << "the near wall removed: the inside shows";
    }
}

TEST(RenderSection, TheSimulationSurfaceIsCutTheSameWay) {
    // Without a visual mesh the simulation surface is drawn (over the rest positions at --steps 0)
    // and cut by the same rule: the cut pixels are its own section's area.
    REQUIRE_GL();
    test::TempDir dir;
    Scenario scenario = phantom_scenario();
    scenario.visual.reset();
    scenario.mapping.reset();
    write_scenario(dir / "surface.h5", scenario);
    const auto& rest = scenario.lattice.particles.rest_position;
    const SimulationSurface& surface = *scenario.simulation_surface;
    Eigen::AlignedBox3f box;
    for (const auto& t : surface.triangles)
        for (int k : t) box.extend(Eigen::Vector3f(rest[std::size_t(k)][0], rest[std::size_t(k)][1], rest[std::size_t(k)][2]));
    const int width = 480, height = 400;
    const Camera camera = fit_camera(box, ViewDirection::left, float(width) / float(height));
    const Eigen::Vector3d towards_eye(1, 0, 0);  // the left view: the eye at +x
    const auto run = run_heartsim("run " + quoted(dir / "surface.h5") + " --headless --steps 0 --view left --size 480x400 --clip centre "
                                  "--screenshot " + quoted(dir / "s.png"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("normal (1.0000, 0.0000, 0.0000)"), std::string::npos) << "centre: facing the camera\n" << run.output;
    const double area = cross_section_area(rest, surface.triangles, box.center().cast<double>(), towards_eye);
    const double pixel = camera.mm_per_pixel(height);
    const double expected = area / (pixel * pixel), seen = double(cut_pixels(read_png(dir / "s.png")));
    std::printf("  simulation surface, left view: section %.1f mm² = %.0f pixels expected, %.0f cut pixels (%+.2f %%)\n", area, expected, seen,
                100 * (seen / expected - 1));
    EXPECT_GT(area, 100.0);
    EXPECT_NEAR(seen / expected, 1.0, 0.01);
}

namespace {

/// Pixels in an incision's cap colour: lit incision_cap_rgb keeps its hue, green under a third of
/// red (the lit epicardium keeps at least 0.41 of it, renderer.h), bright enough to be lit.
std::size_t cap_pixels(const Image& image) {
    std::size_t count = 0;
    for (std::size_t p = 0; p < std::size_t(image.width) * std::size_t(image.height); ++p) {
        const std::uint8_t* c = &image.pixels[3 * p];
        count += c[0] > 40 && c[1] < 0.33 * c[0] && c[2] < 0.33 * c[0];
    }
    return count;
}

}  // namespace

// The phantom opened by the incision of incision_gesture.h (simulated on the cpu backend, whose
// positions the renderer uploads; the gl backend cuts the same springs, test_runtime_backend):
// the vertex shader
// deforms the opened mesh (new vertices, caps) exactly as libmodel's apply_mapping does, the
// drawn mesh is the state's closed mesh, and the caps show in their own shade only once cut.
TEST(RenderIncision, TheOpenedMeshIsDrawnAsTheMappingSaysWithItsCapsInTheirShade) {
    REQUIRE_GL();
    const Scenario& scenario = phantom_scenario();
    auto backend = make_cpu_backend(scenario, options_from(scenario.solver));
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 20});
    IncisionState incisions(scenario.lattice, scenario.visual->positions, scenario.visual->normals, scenario.visual->triangles,
                            *scenario.mapping, *scenario.simulation_surface);
    ScriptedRunOptions options{.steps = int(std::ceil(plan.end_ms / backend->time_step_ms()))};
    options.on_step = [&](int, const StepReport&) {
        if (incisions.pending(backend->strokes(), false)) incisions.update(backend->strokes(), backend->positions(), false);
    };
    Renderer renderer(scenario, {.width = 256, .height = 256});
    renderer.render(*backend, {});
    EXPECT_EQ(cap_pixels(renderer.read_pixels()), 0u) << "no cap colour before a cut";
    const ScriptedRunResult run = run_scripted(*backend, plan.trajectory, options);
    EXPECT_EQ(run.watchdog_events, 0u) << run.last_watchdog_message;
    ASSERT_TRUE(incisions.cut());
    std::string why;
    EXPECT_TRUE(closed_manifold(incisions.drawn_triangles(), &why)) << why;
    renderer.set_visual(incisions.rest_positions(), incisions.rest_normals(), incisions.drawn_triangles(), incisions.mapping(),
                        incisions.cap_first());
    EXPECT_EQ(renderer.vertex_count(), incisions.mesh().rest.size());
    EXPECT_EQ(renderer.triangle_count(), incisions.drawn_triangles().size());
    const auto captured = renderer.capture_vertices(*backend);
    const auto expected = apply_mapping(incisions.mapping(), backend->positions(), *scenario.simulation_surface);
    ASSERT_EQ(captured.size(), expected.size());
    double error = 0;
    for (std::size_t v = 0; v < captured.size(); ++v)
        for (int k = 0; k < 3; ++k) error = std::max(error, double(std::abs(captured[v][k] - expected[v][k])));
    std::printf("  %zu vertices (%zu added by the cut), %zu cap triangles: max |vertex shader - apply_mapping| %.3g mm\n", captured.size(),
                captured.size() - scenario.visual->positions.size(), incisions.drawn_triangles().size() - incisions.cap_first(), error);
    EXPECT_LE(error, 1e-4);
    // The retractors hold the incision open facing the camera: its caps are in sight.
    Renderer close_up(scenario, {.width = 256, .height = 256});
    close_up.set_visual(incisions.rest_positions(), incisions.rest_normals(), incisions.drawn_triangles(), incisions.mapping(),
                        incisions.cap_first());
    close_up.render(*backend, {});
    const std::size_t caps = cap_pixels(close_up.read_pixels());
    std::printf("  %zu pixels in the caps' shade\n", caps);
    EXPECT_GT(caps, 0u);
}

namespace {

/// Pixels in a pericardium patch's colour (patch_rgb("pericardium"), lit or cut flat: its hue kept,
/// green 0.96 and blue 0.82 of red, a specular highlight moving both toward 1); the tissue's lit
/// red keeps green under 0.55 of red, the background is darker, the suture blue.
bool patch_coloured(const std::uint8_t* c) {
    const double r = c[0], g = c[1], b = c[2];
    return r > 50 && std::abs(g / r - 0.957) < 0.04 && b / r > 0.78 && b / r < 0.95 && b < g;
}

/// Pixels in the suture's blue (suture_rgb, lit): blue well above red and green.
bool suture_coloured(const std::uint8_t* c) { return c[2] > 40 && c[2] > 1.8 * c[0] && c[2] > 1.5 * c[1]; }

/// The screen box (pixels from the top left) of `points` through `camera` in a `size`² frame,
/// widened by `margin` pixels.
Eigen::AlignedBox2d screen_box(const Camera& camera, int size, const std::vector<Eigen::Vector3d>& points, double margin) {
    const Eigen::Matrix4f view_projection = camera.projection(1.0f) * camera.view();
    Eigen::AlignedBox2d box;
    for (const Eigen::Vector3d& p : points) {
        const Eigen::Vector4f clip = view_projection * Eigen::Vector4f(float(p.x()), float(p.y()), float(p.z()), 1.0f);
        box.extend(Eigen::Vector2d(0.5 * (clip.x() / clip.w() + 1.0) * size, 0.5 * (1.0 - clip.y() / clip.w()) * size));
    }
    if (!box.isEmpty()) box.extend(box.min() - Eigen::Vector2d::Constant(margin)), box.extend(box.max() + Eigen::Vector2d::Constant(margin));
    return box;
}

}  // namespace

// A septal defect's repair as drawn: the two-chamber block of defect_block.h (a 6 mm septum) with
// an 8 mm VSD, the patch of plan_repair laid over the opening on the right side and its eight
// stitches tied, seen in the section view across the defect as `--clip defect --view section`
// shows it (the plane through the defect's axis, the camera square on to it). The patch is
// opaque and depth-tested, so drawing it changes no pixel outside the screen box of the patch
// and its stitches; the pixels in its colour lie where its kept half (the side of the plane that
// is drawn) projects; the stitches' knots on that side show in the suture's blue; and after
// clear_patch() no pixel has either colour.
TEST(RenderRepair, TheLaidPatchAndItsStitchesAreDrawnOverTheDefectInTheSectionView) {
    REQUIRE_GL();
    using namespace test::defect_block;
    test::TempDir dir;
    build_block_scenario(make_block(), dir / "block.nrrd", dir / "vsd.h5", "vsd", 4000);
    const Scenario scenario = read_scenario(dir / "vsd.h5");
    const RepairPlan plan = plan_repair(scenario);

    // The plan's gesture without the steps: the patch laid where hand 0 lays it, each stitch tied
    // at its site; the tissue at rest.
    std::unique_ptr<Backend> backend = with_repair(make_cpu_backend(scenario, options_from(scenario.solver)), scenario, {});
    RepairBackend* repair = repair_of(*backend);
    ASSERT_NE(repair, nullptr);
    const double radius = 0.5 * plan.patch_diameter_mm;
    backend->set_instrument(0, {.kind = InstrumentKind::patch, .semi_axes = Eigen::Vector3d(radius, radius, 0.5 * plan.patch_thickness_mm)});
    backend->set_pose(0, {plan.patch_centre, plan.patch_orientation});
    backend->begin_grab(0);
    backend->set_instrument(1, {.kind = InstrumentKind::needle, .semi_axes = RepairPlanOptions{}.needle_semi_axes});
    for (const RepairStitch& stitch : plan.stitches) {
        backend->set_pose(1, {stitch.site, plan.needle_orientation});
        backend->begin_grab(1);
        backend->release(1);
    }
    const PatchModel* patch = repair->patch();
    ASSERT_NE(patch, nullptr);
    ASSERT_EQ(patch->stitches().size(), plan.stitches.size());
    const DrawnPatch drawn = drawn_patch(*patch, repair->stitch_anchors());
    EXPECT_EQ(drawn.rgb, patch_rgb("pericardium"));

    const int size = 400;
    Renderer renderer(scenario, {.width = size, .height = size});
    const SectionPlane plane = section_through_defect(renderer.camera(), scenario.source.defect_centre.cast<float>(),
                                                      scenario.source.defect_axis.cast<float>());
    aim_at_section(renderer.camera(), plane);
    renderer.set_section(plane);
    const Camera& camera = renderer.camera();
    renderer.set_patch(drawn);
    EXPECT_TRUE(renderer.draws_patch());
    renderer.render(*backend, {});
    const Image with = renderer.read_pixels();
    renderer.clear_patch();
    EXPECT_FALSE(renderer.draws_patch());
    renderer.render(*backend, {});
    const Image without = renderer.read_pixels();

    // Everything drawn, the kept half, and the knots on the kept side (by more than a knot's size).
    auto kept = [&](const Eigen::Vector3d& x, double by) { return plane.normal.cast<double>().dot(x - plane.point.cast<double>()) < -by; };
    std::vector<Eigen::Vector3d> all, kept_half;
    int kept_knots = 0;
    for (const auto& x : drawn.positions) {
        const Eigen::Vector3d p(x[0], x[1], x[2]);
        all.push_back(p);
        if (kept(p, 0.0)) kept_half.push_back(p);
    }
    for (std::size_t k = 0; k < drawn.stitch_from.size(); ++k) {
        const Eigen::Vector3d a(drawn.stitch_from[k][0], drawn.stitch_from[k][1], drawn.stitch_from[k][2]);
        const Eigen::Vector3d b(drawn.stitch_to[k][0], drawn.stitch_to[k][1], drawn.stitch_to[k][2]);
        all.push_back(a), all.push_back(b);
        kept_knots += kept(a, 1.0);
    }
    // A pixel's margin beyond the sheet's half thickness and the knots' radius (0.6 mm) round the points.
    const double margin = 1.0 / camera.mm_per_pixel(size) + 2.0;
    const Eigen::AlignedBox2d everything = screen_box(camera, size, all, margin), kept_box = screen_box(camera, size, kept_half, margin);
    ASSERT_FALSE(kept_half.empty()) << "the plane holds the defect's axis: half the patch is on the side drawn";
    std::size_t patch_seen = 0, patch_outside = 0, suture_seen = 0, changed = 0, changed_outside = 0, after = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            const std::size_t p = 3 * (std::size_t(y) * size + std::size_t(x));
            const Eigen::Vector2d centre(x + 0.5, y + 0.5);
            const bool differs = !std::equal(&with.pixels[p], &with.pixels[p] + 3, &without.pixels[p]);
            changed += differs;
            changed_outside += differs && !everything.contains(centre);
            if (patch_coloured(&with.pixels[p])) ++patch_seen, patch_outside += !kept_box.contains(centre);
            suture_seen += suture_coloured(&with.pixels[p]);
            after += patch_coloured(&without.pixels[p]) || suture_coloured(&without.pixels[p]);
        }
    std::printf("  patch %zu vertices, %zu triangles, %zu stitches (%d knots on the side drawn); %zu pixels changed by it, %zu in its colour "
                "(%zu outside its kept half's box), %zu in the suture's; %zu in either colour after clear_patch\n",
                drawn.positions.size(), drawn.triangles.size(), drawn.stitch_from.size(), kept_knots, changed, patch_seen, patch_outside,
                suture_seen, after);
    if (HasFailure() || std::getenv("HEARTSIM_KEEP_PICTURES")) write_png("repair_section.png", with), write_png("repair_cleared.png", without);
    EXPECT_GT(patch_seen, 50u) << "the patch shows over the defect";
    EXPECT_EQ(patch_outside, 0u) << "patch pixels beyond where its kept half projects";
    EXPECT_EQ(changed_outside, 0u) << "pixels the patch changed outside its screen box";
    if (kept_knots > 0) {
        EXPECT_GT(suture_seen, 0u) << "the knots on the side drawn show";
    }
    EXPECT_EQ(after, 0u) << "clear_patch draws neither patch nor stitches";

    // A leak's marker, 3 mm on the side the section cuts away from the defect's centre: a ball of
    // 1.2 mm in leak_rgb drawn whole over everything, within its screen box and filling most of its
    // disc; no other pixel has its hue.
    DrawnPatch leaking = drawn;
    const Eigen::Vector3d leak = scenario.source.defect_centre + 3.0 * plane.normal.cast<double>();
    leaking.leak = std::array<float, 3>{float(leak.x()), float(leak.y()), float(leak.z())};
    renderer.set_patch(leaking);
    renderer.render(*backend, {});
    const Image marked = renderer.read_pixels();
    auto cyan = [](const std::uint8_t* c) { return c[1] > 60 && c[2] > 60 && c[0] < 0.5 * std::min(c[1], c[2]); };
    const double ball = 1.2 / camera.mm_per_pixel(size);  // its radius in pixels
    const Eigen::AlignedBox2d marker = screen_box(camera, size, {leak}, ball + 2.0);
    std::size_t cyan_in = 0, cyan_out = 0, cyan_before = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            const std::size_t p = 3 * (std::size_t(y) * size + std::size_t(x));
            const bool in = marker.contains(Eigen::Vector2d(x + 0.5, y + 0.5));
            if (cyan(&marked.pixels[p])) ++(in ? cyan_in : cyan_out);
            cyan_before += cyan(&with.pixels[p]);
        }
    std::printf("  a leak's marker: %zu cyan pixels in its box (its disc %.0f), %zu outside; %zu before it was set\n", cyan_in,
                std::numbers::pi * ball * ball, cyan_out, cyan_before);
    if (HasFailure() || std::getenv("HEARTSIM_KEEP_PICTURES")) write_png("repair_leak.png", marked);
    EXPECT_EQ(cyan_before, 0u);
    EXPECT_GT(double(cyan_in), 0.5 * std::numbers::pi * ball * ball) << "the marker shows whole, though on the side cut away";
    EXPECT_EQ(cyan_out, 0u);
}

namespace {

/// A pixel in the coronary artery's crimson (coronary_artery_rgb, lit): green under 0.36 of red,
/// blue over 0.38 of it; the lit epicardium's green is at least 0.41 of its red, the cut
/// myocardium's blue under 0.25, the fat's green 0.86.
bool artery_coloured(const std::uint8_t* c) { return c[0] > 40 && c[1] < 0.36 * c[0] && c[2] > 0.38 * c[0]; }

Eigen::Vector2d pixel_of(const Camera& camera, int size, const Eigen::Vector3d& p) {
    const Eigen::Matrix4f view_projection = camera.projection(1.0f) * camera.view();
    const Eigen::Vector4f clip = view_projection * Eigen::Vector4f(float(p.x()), float(p.y()), float(p.z()), 1.0f);
    return {0.5 * (clip.x() / clip.w() + 1.0) * size, 0.5 * (1.0 - clip.y() / clip.w()) * size};
}

double distance_to_polyline(const Eigen::Vector2d& q, const std::vector<Eigen::Vector2d>& line) {
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k + 1 < line.size(); ++k) {
        const Eigen::Vector2d ab = line[k + 1] - line[k];
        const double t = ab.squaredNorm() > 0 ? std::clamp((q - line[k]).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
        best = std::min(best, (q - (line[k] + t * ab)).norm());
    }
    return best;
}

}  // namespace

// The coronary arteries as drawn: an anterior descending course laid across the phantom's front
// (visual vertices under a row of the frame's pixels, as heartprep puts a course on the detailed
// surface) is drawn in the artery's crimson where it projects and nowhere else, and not without
// coronaries; a grabber then pulls the tissue under it 5 mm up the screen, and the crimson is
// found where the course's vertices went (the drawing shader's own vertices), no longer where
// they were: the artery moves with the tissue.
TEST(RenderCoronaries, AnArteryIsDrawnWhereItsCourseProjectsAndMovesWithTheTissueUnderAGrab) {
    REQUIRE_GL();
    Scenario scenario = phantom_scenario();
    const auto& visual = scenario.visual->positions;
    const int size = 400;
    std::unique_ptr<Backend> backend = make_cpu_backend(scenario, options_from(scenario.solver));

    // The course: the visual vertex nearest to the surface under every 4th pixel of the middle row.
    Renderer plain(scenario, {.width = size, .height = size, .coronaries = false});
    plain.render(*backend, {});
    const Image without = plain.read_pixels();
    std::vector<std::size_t> course_vertices;
    for (int x = size / 4; x <= 3 * size / 4; x += 4) {
        const auto point = plain.surface_point(x + 0.5, size / 2 + 0.5, size, size);
        if (!point) continue;
        std::size_t nearest = 0;
        float best = std::numeric_limits<float>::infinity();
        for (std::size_t v = 0; v < visual.size(); ++v) {
            const float d = (Eigen::Vector3f(visual[v][0], visual[v][1], visual[v][2]) - *point).squaredNorm();
            if (d < best) best = d, nearest = v;
        }
        if (course_vertices.empty() || course_vertices.back() != nearest) course_vertices.push_back(nearest);
    }
    ASSERT_GE(course_vertices.size(), 20u) << "the phantom fills the middle row";
    Landmark lad{"lad_course", LandmarkKind::course, "left ventricle, right ventricle", {}};
    for (std::size_t v : course_vertices) lad.points.emplace_back(visual[v][0], visual[v][1], visual[v][2]);
    scenario.landmarks = Landmarks{{lad}, {}};

    Renderer renderer(scenario, {.width = size, .height = size});
    const Camera& camera = renderer.camera();
    const double radius_px = 1.85 / camera.mm_per_pixel(size);
    auto count = [&](const Image& image, const std::vector<Eigen::Vector3d>& points) {
        int coloured = 0;
        for (const Eigen::Vector3d& p : points) {
            const Eigen::Vector2d q = pixel_of(camera, size, p);
            const std::size_t at = 3 * (std::size_t(q.y()) * size + std::size_t(q.x()));
            coloured += artery_coloured(&image.pixels[at]);
        }
        return coloured;
    };
    renderer.render(*backend, {});
    const Image with = renderer.read_pixels();
    std::vector<Eigen::Vector2d> line;
    for (const Eigen::Vector3d& p : lad.points) line.push_back(pixel_of(camera, size, p));
    std::size_t crimson = 0, astray = 0, crimson_without = 0;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            const std::size_t p = 3 * (std::size_t(y) * size + std::size_t(x));
            crimson_without += artery_coloured(&without.pixels[p]);
            if (!artery_coloured(&with.pixels[p])) continue;
            ++crimson;
            astray += distance_to_polyline({x + 0.5, y + 0.5}, line) > 1.3 * radius_px + 2.0;
        }
    const int on_course = count(with, lad.points), on_course_without = count(without, lad.points);
    std::printf("  course of %zu vertices, artery %.1f px wide: %d of them crimson (%d without coronaries); %zu crimson pixels, %zu "
                "beyond the artery's width from the course; %zu without coronaries\n",
                lad.points.size(), 2 * radius_px, on_course, on_course_without, crimson, astray, crimson_without);
    EXPECT_GE(on_course, int(0.8 * double(lad.points.size()))) << "the artery shows where its course projects";
    EXPECT_EQ(on_course_without, 0);
    EXPECT_EQ(crimson_without, 0u);
    EXPECT_EQ(astray, 0u) << "crimson only along the course";
    EXPECT_GT(double(crimson), 0.8 * 2 * radius_px * (line.back() - line.front()).norm()) << "the artery's band, not a line";

    // The grab: a grabber over the course's middle vertex lifts the tissue 5 mm up the screen.
    const Eigen::Vector3d middle = lad.points[lad.points.size() / 2];
    const Eigen::Vector3d up = (camera.orientation.toRotationMatrix() * Eigen::Vector3f::UnitY()).cast<double>();
    const double reach = 2.0 * scenario.lattice.spacing;
    backend->set_instrument(0, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(reach)});
    backend->set_pose(0, {middle, Eigen::Quaterniond::Identity()});
    ASSERT_GT(backend->begin_grab(0), 0u);
    for (int k = 1; k <= 20; ++k) {
        backend->set_pose(0, {middle + (5.0 * k / 20.0) * up, Eigen::Quaterniond::Identity()});
        backend->step(10);
    }
    backend->step(200);
    renderer.render(*backend, {});
    const Image pulled = renderer.read_pixels();
    const auto moved = renderer.capture_vertices(*backend);
    std::vector<Eigen::Vector3d> now, left_behind;
    for (std::size_t k = 0; k < course_vertices.size(); ++k) {
        const auto& m = moved[course_vertices[k]];
        now.emplace_back(m[0], m[1], m[2]);
        // Those carried up by more than the artery's width: where they were is no longer crimson.
        if ((pixel_of(camera, size, now.back()) - line[k]).norm() > 2.5 * radius_px) left_behind.push_back(lad.points[k]);
    }
    const int followed = count(pulled, now), stayed = count(pulled, left_behind);
    std::printf("  after the grab: %d of %zu course vertices crimson where they went; %zu moved more than the artery's width, %d of "
                "those still crimson where they were\n",
                followed, now.size(), left_behind.size(), stayed);
    if (HasFailure() || std::getenv("HEARTSIM_KEEP_PICTURES"))
        write_png("coronary_rest.png", with), write_png("coronary_pulled.png", pulled);
    EXPECT_GE(followed, int(0.8 * double(now.size()))) << "the artery is drawn where its course's vertices went";
    ASSERT_GE(left_behind.size(), 3u) << "the grab moved part of the course by more than the artery's width";
    EXPECT_LE(stayed, int(left_behind.size() / 5)) << "the artery left where the tissue left";
}

// The section's cut through a grown wall: the phantom cut through its centre, once as built (its
// walls labelled), once with every material marked grown and once with its first material alone
// (the myocardium) marked grown. The pixels in the grown walls' ochre are none, then every pixel
// that was cut colour (the same geometry), then some but not all; ochre and the labelled cut colour
// never share a pixel.
TEST(RenderSection, AGrownWallIsCutInItsOwnColourBesideTheLabelledMyocardium) {
    REQUIRE_GL();
    const int size = 256;
    auto section_of = [&](const Scenario& scenario) {
        std::unique_ptr<Backend> backend = make_cpu_backend(scenario, options_from(scenario.solver));
        Renderer renderer(scenario, {.width = size, .height = size});
        renderer.set_section(SectionPlane{renderer.model_centre(), Eigen::Vector3f(0, -1, 0)});
        renderer.render(*backend, {});
        return renderer.read_pixels();
    };
    auto ochre = [](const Image& image) {
        std::size_t n = 0;
        for (std::size_t p = 0; p + 2 < image.pixels.size(); p += 3) {
            bool same = true;
            for (std::size_t c = 0; c < 3; ++c) same = same && std::abs(int(image.pixels[p + c]) - grown_wall_cut_rgb[c]) <= 2;
            n += same;
        }
        return n;
    };
    const Scenario& built = phantom_scenario();
    const Image labelled = section_of(built);
    const std::size_t cut = cut_pixels(labelled);
    ASSERT_GT(cut, 500u);
    EXPECT_EQ(ochre(labelled), 0u);

    Scenario all = built;
    all.tissue_origin.assign(all.lattice.materials.size(), TissueOrigin{});
    for (TissueOrigin& o : all.tissue_origin) o.grown = true, o.thickness_mm = 2.0;
    const Image grown = section_of(all);
    EXPECT_EQ(cut_pixels(grown), 0u);
    EXPECT_EQ(ochre(grown), cut);

    std::printf("  %zu pixels of cut wall; all ochre when every material is grown\n", cut);
    if (all.lattice.materials.size() > 1) {
        Scenario first = built;
        first.tissue_origin.assign(first.lattice.materials.size(), TissueOrigin{});
        first.tissue_origin[0].grown = true;
        const Image part = section_of(first);
        std::printf("  the first of %zu materials grown: %zu ochre, %zu labelled cut\n", first.lattice.materials.size(), ochre(part),
                    cut_pixels(part));
        EXPECT_LE(ochre(part) + cut_pixels(part), cut);
    }
}
