// The cost of many scalpel strokes (docs/benchmarks.md "Many strokes"): on one scenario, random
// strokes (a fixed seed) opened in the detailed mesh one by one, each at the moment its blade
// lifts, as heartsim opens them (libmodel/surgery/incision_state.h IncisionState::update, the particles at
// rest). A stroke: a blade (8 mm, or --blade) from 2 mm outside a random vertex of the uncut mesh,
// pointing into the tissue (tilted up to 20° off the inward normal), drawn 8-20 mm along a random
// tangent, turning up to 40° on the way, a pose every 0.5 mm. The strokes of a count are the
// first of the same sequence, so one run of the largest count gives every smaller one on the way.
// Per count: the wall time (and this process's CPU time) of all the lifts so far, the last
// lift's, the mesh's size, the triangles the lifts re-meshed, the strokes the mesh could not open
// along, whether the mesh is a closed 2-manifold (checked outside the timing), and a digest of the
// mesh and its mapping (two builds that give the same digest gave the same state, bit for bit).
// Usage: stroke_bench SCENARIO.h5 [--seed N] [--counts 1,25,50,100,200] [--blade MM]
#include "formats/scenario.h"
#include "libmodel/sim/cutting.h"
#include "libmodel/surgery/incision_state.h"

#include <Eigen/Geometry>

#include <chrono>
#include <cmath>
#include <ctime>
#include <cstdio>
#include <random>
#include <sstream>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

/// This process's CPU time, s: on a shared machine the lifts' own cost, where wall time counts
/// the other processes' too.
double cpu_seconds() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
}

/// Uniform in [0, 1) from the generator's bits (the same sequence on every standard library).
double uniform(std::mt19937_64& random) { return double(random() >> 11) * 0x1.0p-53; }

/// One random stroke's poses (above).
std::vector<InstrumentPose> random_stroke(std::mt19937_64& random, const VisualMesh& mesh) {
    const std::size_t v = std::size_t(uniform(random) * double(mesh.positions.size()));
    const Eigen::Vector3d at(mesh.positions[v][0], mesh.positions[v][1], mesh.positions[v][2]);
    Eigen::Vector3d normal(mesh.normals[v][0], mesh.normals[v][1], mesh.normals[v][2]);
    normal.normalize();
    const Eigen::Vector3d any = std::abs(normal.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d u = normal.cross(any).normalized(), w = normal.cross(u);
    const double heading = 2 * M_PI * uniform(random), turn = (uniform(random) - 0.5) * 80.0 * M_PI / 180.0;
    const double tilt = 20.0 * M_PI / 180.0 * uniform(random), tilt_towards = 2 * M_PI * uniform(random);
    const double travel = 8.0 + 12.0 * uniform(random);
    const Eigen::Vector3d blade =
        (-normal * std::cos(tilt) + std::sin(tilt) * (std::cos(tilt_towards) * u + std::sin(tilt_towards) * w)).normalized();
    const Eigen::Quaterniond orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), blade);
    const int steps = int(std::ceil(travel / 0.5));
    std::vector<InstrumentPose> poses;
    Eigen::Vector3d p = at + 2.0 * normal;
    poses.push_back({p, orientation});
    for (int k = 1; k <= steps; ++k) {
        const double angle = heading + turn * double(k) / steps;
        p += (travel / steps) * (std::cos(angle) * u + std::sin(angle) * w);
        poses.push_back({p, orientation});
    }
    return poses;
}

/// FNV-1a over the bytes of `values`, continuing from `hash`.
template <class T>
std::uint64_t fnv1a(const std::vector<T>& values, std::uint64_t hash) {
    const auto* bytes = reinterpret_cast<const unsigned char*>(values.data());
    for (std::size_t i = 0; i < values.size() * sizeof(T); ++i) hash = (hash ^ bytes[i]) * 0x100000001b3ull;
    return hash;
}

/// A digest of everything the incision state hands on (the mesh at rest, its caps and normals, the
/// drawn order and the mapping): two runs that give the same digest gave the same state, bit for bit.
std::uint64_t digest(const IncisionState& incisions) {
    std::uint64_t h = 0xcbf29ce484222325ull;
    const IncisionMesh& mesh = incisions.mesh();
    const VisualMapping& mapping = incisions.mapping();
    h = fnv1a(mesh.rest, h);
    h = fnv1a(mesh.triangles, h);
    h = fnv1a(mesh.cap, h);
    h = fnv1a(mesh.normals, h);
    h = fnv1a(incisions.drawn_triangles(), h);
    h = fnv1a(mapping.triangle, h);
    h = fnv1a(mapping.barycentric, h);
    h = fnv1a(mapping.offset, h);
    h = fnv1a(mapping.particles, h);
    return fnv1a(mapping.weights, h);
}

/// `text` as a number, or an error naming `option`.
double number(const std::string& option, const std::string& text) {
    std::size_t used = 0;
    double value = 0;
    try {
        value = std::stod(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (used == 0 || used != text.size()) throw std::invalid_argument(option + ": expected a number, got " + text);
    return value;
}

std::vector<std::size_t> parse_counts(const std::string& text) {
    std::vector<std::size_t> counts;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        const double n = number("--counts", item);
        if (n < 1 || n > 1e6 || n != std::floor(n)) throw std::invalid_argument("--counts: expected positive integers separated by commas, got " + text);
        if (!counts.empty() && std::size_t(n) <= counts.back()) throw std::invalid_argument("--counts: expected increasing counts, got " + text);
        counts.push_back(std::size_t(n));
    }
    if (counts.empty()) throw std::invalid_argument("--counts: expected at least one count");
    return counts;
}

}  // namespace

int main(int argc, char** argv) {
    std::string path, counts_text = "1,25,50,100,200", seed_text = "1", blade_text = "8";
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--seed" && i + 1 < argc) seed_text = argv[++i];
        else if (a == "--counts" && i + 1 < argc) counts_text = argv[++i];
        else if (a == "--blade" && i + 1 < argc) blade_text = argv[++i];
        else if (path.empty() && a[0] != '-') path = a;
        else {
            std::fprintf(stderr, "usage: stroke_bench SCENARIO.h5 [--seed N] [--counts 1,25,50,100,200] [--blade MM]\n");
            return 2;
        }
    }
    if (path.empty()) {
        std::fprintf(stderr, "usage: stroke_bench SCENARIO.h5 [--seed N] [--counts 1,25,50,100,200] [--blade MM]\n");
        return 2;
    }
    try {
        const double seed_value = number("--seed", seed_text), length = number("--blade", blade_text);
        if (!(seed_value >= 0 && seed_value < 1e18) || seed_value != std::floor(seed_value))
            throw std::invalid_argument("--seed: expected a non-negative integer, got " + seed_text);
        if (!(length > 0 && length < 1e3)) throw std::invalid_argument("--blade: expected a length in mm above 0, got " + blade_text);
        const auto seed = std::uint64_t(seed_value);
        const std::vector<std::size_t> counts = parse_counts(counts_text);
        const Scenario scenario = read_scenario(path);
        if (!scenario.visual || !scenario.mapping || !scenario.simulation_surface || scenario.visual->normals.size() != scenario.visual->positions.size())
            throw std::runtime_error(path + ": expected a scenario with a detailed mesh, its normals and its mapping");
        const VisualMesh& visual = *scenario.visual;
        IncisionState incisions(scenario.lattice, visual.positions, visual.normals, visual.triangles, *scenario.mapping,
                                *scenario.simulation_surface);
        const auto& rest = scenario.lattice.particles.rest_position;
        std::mt19937_64 random(seed);
        StrokeLog log;
        double total = 0.0, last = 0.0, cpu = 0.0;
        std::size_t failures = 0, remeshed = 0;
        std::printf("%zu vertices, %zu triangles, %zu particles, seed %llu\n", visual.positions.size(), visual.triangles.size(),
                    scenario.lattice.particles.size(), (unsigned long long)seed);
        std::printf("| strokes | all lifts, s (cpu s) | last lift, ms | vertices | triangles | cut faces | re-meshed, last lift / all | not opened | closed | digest |\n");
        std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
        std::size_t next = 0;
        for (std::size_t stroke = 1; stroke <= counts.back(); ++stroke) {
            const std::vector<InstrumentPose> poses = random_stroke(random, visual);
            for (std::size_t k = 1; k < poses.size(); ++k) log.sweep(0, poses[k - 1], poses[k], length);
            log.lift(0);
            const auto start = std::chrono::steady_clock::now();
            const double cpu_start = cpu_seconds();
            const IncisionUpdate update = incisions.update(log, rest, false);
            cpu += cpu_seconds() - cpu_start;
            last = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            total += last;
            failures += update.failures.size();
            remeshed += update.remeshed;
            if (stroke != counts[next]) continue;
            ++next;
            const bool closed = closed_manifold(incisions.drawn_triangles());
            std::printf("| %zu | %.2f (%.2f) | %.0f | %zu | %zu | %zu | %zu / %zu | %zu | %s | %016llx |\n", stroke, total, cpu, 1e3 * last, incisions.mesh().rest.size(),
                        incisions.drawn_triangles().size(), incisions.drawn_triangles().size() - incisions.cap_first(), update.remeshed, remeshed,
                        failures, closed ? "yes" : "NO", (unsigned long long)digest(incisions));
            std::fflush(stdout);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "stroke_bench: %s\n", e.what());
        return 1;
    }
    return 0;
}
