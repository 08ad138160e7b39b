// How well a scenario holds its heart (docs/benchmarks.md "Holding a real heart"): for each
// scenario file given, with the cpu solver and the scenario's own settings,
//   1. drift: the largest distance of a particle from its imaged place after S seconds with no
//      instrument (default 5 s);
//   2. a press: a sphere of radius R (default 3 mm) placed touching the anterior wall (the
//      surface particle farthest towards −y within 5 mm of the heart's vertical axis through
//      its centre of mass) and pushed 5 mm along +y over 0.5 s, then held 0.5 s. Reported: the
//      probe's force at 1..5 mm and its slope (N/mm), the rigid part of the final motion (the
//      least-squares rotation and translation of all particles, Kabsch), what remains (local
//      dent), and the largest spring strain.
// Usage: holding_bench [--seconds S] [--radius R] [--csv OUT] scenario.h5 [...]
// One CSV row per scenario; the table goes to stdout. Not a test: it asserts nothing.
#include "formats/scenario.h"
#include "libmodel/sim/solver.h"

#include <Eigen/Dense>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

struct Row {
    std::string file;
    std::size_t particles = 0, anchored = 0, supported = 0;
    double drift_max_mm = 0, drift_mean_mm = 0;
    bool drift_diverged = false;
    double force_n[5] = {0, 0, 0, 0, 0};
    double slope_n_per_mm = 0;
    double translation_mm = 0, rotation_deg = 0, local_max_mm = 0, max_strain = 0, min_strain = 0;
    double wall_s = 0;
};

Eigen::Vector3d rest_of(const Particles& p, std::size_t i) { return {p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]}; }

/// Least-squares rigid motion (Kabsch) from rest to current positions: rotation angle (deg),
/// translation of the centroid (mm), and the largest residual (the local deformation, mm).
void rigid_part(const std::vector<Eigen::Vector3d>& from, const std::vector<Eigen::Vector3d>& to, Row& row) {
    Eigen::Vector3d a = Eigen::Vector3d::Zero(), b = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < from.size(); ++i) a += from[i], b += to[i];
    a /= double(from.size()), b /= double(to.size());
    Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
    for (std::size_t i = 0; i < from.size(); ++i) h += (from[i] - a) * (to[i] - b).transpose();
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
    d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
    const Eigen::Matrix3d r = svd.matrixV() * d * svd.matrixU().transpose();
    row.rotation_deg = Eigen::AngleAxisd(r).angle() * 180.0 / M_PI;
    row.translation_mm = (b - a).norm();
    row.local_max_mm = 0;
    for (std::size_t i = 0; i < from.size(); ++i) row.local_max_mm = std::max(row.local_max_mm, (to[i] - (r * (from[i] - a) + b)).norm());
}

Row measure(const std::string& path, double seconds, double radius) {
    Row row;
    row.file = path;
    const auto start = std::chrono::steady_clock::now();
    const Scenario s = read_scenario(path);
    const Particles& p = s.lattice.particles;
    row.particles = p.size();
    for (std::size_t i = 0; i < p.size(); ++i) {
        row.anchored += p.anchored[i];
        row.supported += p.supported() && p.support_stiffness[i] > 0;
    }
    std::vector<Eigen::Vector3d> rest(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) rest[i] = rest_of(p, i);

    // 1. Drift with no instrument.
    {
        Solver solver(s.lattice, s.packing->neighbours, options_from(s.solver));
        const StepReport r = solver.step(int(std::ceil(seconds * 1000.0 / solver.time_step_ms())));
        row.drift_diverged = r.diverged || solver.watchdog_events() > 0;
        double sum = 0;
        for (std::size_t i = 0; i < p.size(); ++i) {
            const double d = (solver.position(i) - rest[i]).norm();
            row.drift_max_mm = std::max(row.drift_max_mm, d);
            sum += d;
        }
        row.drift_mean_mm = sum / double(p.size());
    }

    // 2. The press on the anterior wall.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double mass = 0;
    for (std::size_t i = 0; i < p.size(); ++i) centre += double(p.mass[i]) * rest[i], mass += p.mass[i];
    centre /= mass;
    std::size_t site = 0;
    double front = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < p.size(); ++i) {
        const Eigen::Vector3d d = rest[i] - centre;
        if (std::hypot(d.x(), d.z()) < 5.0 && rest[i].y() < front) front = rest[i].y(), site = i;
    }
    Solver solver(s.lattice, s.packing->neighbours, options_from(s.solver));
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(radius)});
    const Eigen::Vector3d touch = rest[site] - Eigen::Vector3d(0, radius + 0.01, 0);
    const double dt = solver.time_step_ms();
    const int push_steps = int(std::ceil(500.0 / dt)), hold_steps = int(std::ceil(500.0 / dt));
    int next_depth = 1;
    std::vector<double> depths, forces;
    for (int k = 1; k <= push_steps; ++k) {
        const double depth = 5.0 * double(k) / push_steps;
        solver.set_pose(0, {touch + Eigen::Vector3d(0, depth, 0), Eigen::Quaterniond::Identity()});
        solver.step(1);
        if (depth + 1e-9 >= next_depth && next_depth <= 5) {
            row.force_n[next_depth - 1] = -solver.instrument_forces().hand[0].force_n.y();
            ++next_depth;
        }
    }
    solver.step(hold_steps);
    row.force_n[4] = -solver.instrument_forces().hand[0].force_n.y();
    // Slope: least squares through the origin over 1..5 mm.
    double fx = 0, xx = 0;
    for (int d = 1; d <= 5; ++d) fx += d * row.force_n[d - 1], xx += d * d;
    row.slope_n_per_mm = fx / xx;
    std::vector<Eigen::Vector3d> now(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) now[i] = solver.position(i);
    rigid_part(rest, now, row);
    row.max_strain = -1e9, row.min_strain = 1e9;
    for (std::size_t q = 0; q < s.lattice.springs.size(); ++q) {
        const auto [a, b] = s.lattice.springs.pairs[q];
        const double length = (now[std::size_t(b)] - now[std::size_t(a)]).norm(), rest_length = s.lattice.springs.rest_length[q];
        const double strain = length / rest_length - 1.0;
        row.max_strain = std::max(row.max_strain, strain), row.min_strain = std::min(row.min_strain, strain);
    }
    row.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return row;
}

}  // namespace

int main(int argc, char** argv) {
    double seconds = 5.0, radius = 3.0;
    std::string csv;
    std::vector<std::string> files;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--seconds" && i + 1 < argc) seconds = std::stod(argv[++i]);
        else if (a == "--radius" && i + 1 < argc) radius = std::stod(argv[++i]);
        else if (a == "--csv" && i + 1 < argc) csv = argv[++i];
        else if (a == "-h" || a == "--help") {
            std::printf("usage: holding_bench [--seconds S] [--radius R] [--csv OUT] scenario.h5 [...]\n");
            return 0;
        } else files.push_back(a);
    }
    if (files.empty()) {
        std::fprintf(stderr, "holding_bench: no scenario given (--help)\n");
        return 2;
    }
    std::vector<Row> rows;
    std::printf("%-28s %7s %6s %6s %10s %10s %9s %9s %8s %8s %8s %9s %9s %6s\n", "scenario", "N", "anch", "supp", "drift max",
                "drift mean", "F@5mm N", "N/mm", "transl", "rot deg", "dent mm", "strain+", "strain-", "s");
    for (const auto& f : files) {
        try {
            const Row r = measure(f, seconds, radius);
            rows.push_back(r);
            std::printf("%-28s %7zu %6zu %6zu %10.4g %10.4g %9.4g %9.4g %8.4g %8.4g %8.4g %8.1f%% %8.1f%% %6.1f%s\n",
                        std::filesystem::path(f).filename().c_str(), r.particles, r.anchored, r.supported, r.drift_max_mm, r.drift_mean_mm,
                        r.force_n[4], r.slope_n_per_mm, r.translation_mm, r.rotation_deg, r.local_max_mm, 100 * r.max_strain,
                        100 * r.min_strain, r.wall_s, r.drift_diverged ? "  (watchdog fired)" : "");
            std::fflush(stdout);
        } catch (const std::exception& e) {
            std::fprintf(stderr, "holding_bench: %s: %s\n", f.c_str(), e.what());
            return 1;
        }
    }
    if (!csv.empty()) {
        std::ofstream out(csv);
        out << "scenario,particles,anchored,supported,drift_max_mm,drift_mean_mm,f1_n,f2_n,f3_n,f4_n,f5_n,slope_n_per_mm,"
               "translation_mm,rotation_deg,dent_max_mm,max_strain,min_strain,wall_s\n";
        for (const auto& r : rows) {
            out << std::filesystem::path(r.file).filename().string() << ',' << r.particles << ',' << r.anchored << ',' << r.supported << ','
                << r.drift_max_mm << ',' << r.drift_mean_mm;
            for (double f : r.force_n) out << ',' << f;
            out << ',' << r.slope_n_per_mm << ',' << r.translation_mm << ',' << r.rotation_deg << ',' << r.local_max_mm << ','
                << r.max_strain << ',' << r.min_strain << ',' << r.wall_s << '\n';
        }
        std::printf("wrote %s\n", csv.c_str());
    }
    return 0;
}
