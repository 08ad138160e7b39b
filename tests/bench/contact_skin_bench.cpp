// Where a probe first meets a heart: the drawn surface or deeper (docs/benchmarks.md "Where the
// hand first feels the heart"). For each scenario, a 3 mm ball is lowered at 0.01 mm a step onto
// outer particles spread over the heart (every K-th of those with a skin), along the line from
// the particle to the nearest point of the detailed mesh, from 0.5 mm outside that point; at the
// first step whose force pass finds a particle in contact, the detailed mesh's deepest point
// inside the ball (rest mesh: nothing has moved before the first touch) is the depth at which the
// hand first feels the heart. Negative: felt before the drawn surface reached the ball. With the
// skin (contact_skin 1) and without it (0, the particles themselves), on the cpu backend.
//
// Usage: contact_skin_bench SCENARIO.h5 [SCENARIO.h5 ...] [--presses 20] [--radius 3]
// Not a test: it asserts nothing (tests/test_contact_skin.cpp holds the block).
#include "formats/scenario.h"
#include "libmodel/triangle_point.h"
#include "runtime/backend/backend.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

Eigen::Vector3d vec(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

/// The detailed mesh's deepest point inside the ball (centre, radius): radius − distance, mm;
/// −(distance − radius) where it lies outside (the gap).
double deepest_inside(const VisualMesh& mesh, const Eigen::Vector3d& centre, double radius) {
    double nearest = 1e30;
    for (const auto& t : mesh.triangles) {
        const Eigen::Vector3d a = vec(mesh.positions[std::size_t(t[0])]), b = vec(mesh.positions[std::size_t(t[1])]),
                              c = vec(mesh.positions[std::size_t(t[2])]);
        if ((a - centre).norm() > radius + 10 && (b - centre).norm() > radius + 10) continue;
        const Eigen::Vector3d w = closest_barycentric(centre, a, b, c);
        nearest = std::min(nearest, (w.x() * a + w.y() * b + w.z() * c - centre).norm());
    }
    return radius - nearest;
}

struct Summary {
    std::vector<double> depth;
    int missed = 0;
    int crevice = 0;  ///< presses whose ball met the drawn surface elsewhere before it started
};

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string> files;
    int presses = 20;
    double radius = 3.0;
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--presses" && a + 1 < argc) presses = std::atoi(argv[++a]);
        else if (arg == "--radius" && a + 1 < argc) radius = std::atof(argv[++a]);
        else files.push_back(arg);
    }
    if (files.empty() || presses < 1 || !(radius > 0)) {
        std::fprintf(stderr, "usage: contact_skin_bench SCENARIO.h5 [...] [--presses 20] [--radius 3]\n");
        return 2;
    }
    std::printf("| scenario | particles | spacing mm | outer particles with a skin | skin mm, mean (max) | first felt, mm into the drawn surface, with the skin: mean (min to max) | without it | presses (in a crevice, left out) |\n");
    std::printf("|---|---|---|---|---|---|---|---|\n");
    for (const std::string& file : files) {
        const Scenario scenario = read_scenario(file);
        if (!scenario.visual) {
            std::printf("| %s | no detailed mesh |\n", file.c_str());
            continue;
        }
        const std::vector<float> skin = scenario_contact_skin(scenario);
        std::vector<std::size_t> skinned;
        double sum = 0, largest = 0;
        for (std::size_t i = 0; i < skin.size(); ++i)
            if (skin[i] > 0 && !scenario.lattice.particles.anchored[i]) {
                skinned.push_back(i);
                sum += skin[i];
                largest = std::max(largest, double(skin[i]));
            }
        if (skinned.empty()) continue;
        const VisualMesh& mesh = *scenario.visual;
        std::array<Summary, 2> result;
        for (int mode = 0; mode < 2; ++mode) {
            SolverOptions options = options_from(scenario.solver);
            options.contact_skin = mode == 0 ? 1.0 : 0.0;
            auto backend = make_cpu_backend(scenario, options);
            for (int k = 0; k < presses; ++k) {
                const std::size_t i = skinned[std::size_t(k) * skinned.size() / std::size_t(presses)];
                const Eigen::Vector3d x = vec(scenario.lattice.particles.rest_position[i]);
                // The nearest point of the drawn surface and the way out to it.
                double best = 1e30;
                Eigen::Vector3d point = x;
                for (const auto& t : mesh.triangles) {
                    const Eigen::Vector3d a = vec(mesh.positions[std::size_t(t[0])]);
                    if ((a - x).norm() > 3 * scenario.lattice.spacing) continue;
                    const Eigen::Vector3d b = vec(mesh.positions[std::size_t(t[1])]), c = vec(mesh.positions[std::size_t(t[2])]);
                    const Eigen::Vector3d w = closest_barycentric(x, a, b, c);
                    const Eigen::Vector3d p = w.x() * a + w.y() * b + w.z() * c;
                    if ((p - x).norm() < best) best = (p - x).norm(), point = p;
                }
                const Eigen::Vector3d out = (point - x).normalized();
                // A ball that does not fit outside the surface there (a crevice, a cavity narrower
                // than it) meets other tissue first: not a press onto this point.
                if (deepest_inside(mesh, point + out * (radius + 0.5), radius) > 0) {
                    ++result[std::size_t(mode)].crevice;
                    continue;
                }
                backend->reset_tissue();
                // A new instrument: its first pose places it, with no sweep from the last press.
                backend->set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(radius)});
                double felt = std::nan("");
                for (int s = 0; s <= 400; ++s) {  // from 0.5 mm outside to 3.5 mm in
                    const double depth = -0.5 + 0.01 * s;
                    InstrumentPose pose;
                    pose.position = point + out * (radius - depth);
                    backend->set_pose(0, pose);
                    backend->step(1);
                    if (backend->instrument_forces().hand[0].particles > 0) {
                        felt = deepest_inside(mesh, pose.position, radius);
                        if (std::getenv("CONTACT_SKIN_BENCH_DETAILS"))
                            std::printf("  particle %zu skin %.2f: felt at %.2f mm along the press, the drawn surface %.2f mm into the ball\n", i,
                                        double(skin[i]), depth, felt);
                        break;
                    }
                }
                if (std::isnan(felt)) ++result[std::size_t(mode)].missed;
                else result[std::size_t(mode)].depth.push_back(felt);
            }
        }
        auto cell = [](const Summary& s) {
            if (s.depth.empty()) return std::string("none felt");
            double mean = 0, low = 1e30, high = -1e30;
            int near = 0;
            for (double d : s.depth) mean += d, low = std::min(low, d), high = std::max(high, d), near += std::abs(d) <= 0.1;
            char text[200];
            std::snprintf(text, sizeof text, "%.2f (%.2f to %.2f), %d of %zu within 0.1 mm%s", mean / double(s.depth.size()), low, high, near,
                          s.depth.size(),
                          s.missed ? (" , " + std::to_string(s.missed) + " not felt within 3.5 mm").c_str() : "");
            return std::string(text);
        };
        std::string name = file.substr(file.find_last_of('/') + 1);
        std::printf("| %s | %zu | %.2f | %zu | %.2f (%.2f) | %s | %s | %d (%d) |\n", name.c_str(), scenario.lattice.particles.size(),
                    scenario.lattice.spacing, skinned.size(), sum / double(skinned.size()), largest, cell(result[0]).c_str(),
                    cell(result[1]).c_str(), presses, result[0].crevice);
        std::fflush(stdout);
    }
    return 0;
}
