// The force a spherical probe feels against Hertz's contact law (docs/benchmarks.md "Felt force
// against Hertz"). A cube block of tissue (default 60 mm, E = 10 kPa, the bottom layer anchored,
// no gravity) is laid out from a label volume as heartprep lays out a heart, at several lattice
// spacings; a sphere of radius R (default 5 mm) centred above the middle of the top face is
// pressed quasi-statically (a slow ramp, then a hold until the force settles) to depths
// d = 0.1R … 0.4R below the top particle layer, at three lateral placements relative to the
// lattice (over a particle, between two, between four). The probe's normal force
// (instrument_forces().hand[0].force_n.z()) is compared with
//
//     Hertz    F = 4/3 · E/(1 − ν²) · √R · d^1.5               ν = 1/4 (lattice.h spring_stiffness)
//     Sneddon  d = a/2 · ln((R + a)/(R − a)),  F = E/(2(1 − ν²)) · ((a² + R²) ln((R + a)/(R − a)) − 2aR)
//
// (Sneddon: the exact linear-elastic sphere, of which Hertz is the small-a/R limit). Depth zero
// is the top particle layer, which is also the simulation surface (docs/simulation-surface-and-
// mapping.md: the surface of a block passes through its outer particles); the label map's
// boundary, where the visual mesh lies, is half a spacing above it: the table also gives Hertz
// with the depth counted from there.
//
// Diagnostics per press (--details): the particles the probe touched in the last substep against
// those lying on its surface, and the sum of the forces on the latter; the probe's force against
// the anchors' reaction (Newton's third law at rest); the force's change over the last hold
// window (settling). --linear also solves the same lattice linearised (small displacements, the
// sphere's constraint on the rest surface: the problem Sneddon solves in the continuum), which
// parts the lattice's discretisation (linear lattice against Sneddon) from its large-deformation
// response (solver against linear lattice). It costs minutes per placement below 2 mm.
//
// --reference FILE (repeatable) adds a finite-element reference to the summary table: the CSV of
// tests/bench/fe_indentation.py (`nu,d_over_R,depth_mm,force_N,force_over_hertz`: CalculiX, an
// axisymmetric neo-Hookean cylinder of the block's height and cross-section under a rigid
// frictionless sphere, large deformations). For each Poisson's ratio in the file, the FE force at
// each depth and the measured force's error against it. The file must be for this --radius and
// E = 10 kPa (checked from its depths and its forces over Hertz); a depth it lacks prints "–".
//
// Usage: hertz_bench [--spacings 3,2,default,1.5] [--size 60] [--thickness T] [--radius 5]
//                    [--depths 0.1,0.2,0.3,0.4] [--placements particle,edge,face] [--threads N]
//                    [--drag 0.1] [--damping-ratio 0.3] [--tolerance 1e-4] [--ramp-speed 0.02]
//                    [--quick] [--details] [--linear] [--reference fe.csv] [--drawn] [--poisson-ratio 0.25]
// --poisson-ratio gives the block that ν (the volume term above 1/4) and Hertz and Sneddon the same.
// --drawn counts the depth from the drawn surface, as heartsim meets it (Settings::drawn).
// "default" is the spacing heartprep chooses for a cube of --size mm with its 30k particle budget
// (size/31: 1.935 mm for 60 mm). Not a test: it asserts nothing (tests/test_hertz.cpp does).
#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/select.h"
#include "libmodel/sim/solver.h"

#include <tbb/global_control.h>

#include <Eigen/Core>
#include <Eigen/Dense>
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

constexpr double youngs_kpa = 10.0;
double poisson = 0.25;  // the block's (--poisson-ratio): the lattice's springs alone give 1/4, the volume term the rest (libmodel/volume_cells.h)

double reduced_modulus() { return youngs_kpa * 1e-3 / (1 - poisson * poisson); }  // N/mm²

double hertz(double radius, double depth) {
    return depth <= 0 ? 0.0 : 4.0 / 3.0 * reduced_modulus() * std::sqrt(radius) * std::pow(depth, 1.5);
}

/// Sneddon's sphere: the contact radius a for depth d by bisection, then the force.
double sneddon(double radius, double depth) {
    if (depth <= 0) return 0.0;
    auto depth_of = [&](double a) { return 0.5 * a * std::log((radius + a) / (radius - a)); };
    double lo = 0, hi = radius * (1 - 1e-12);
    for (int i = 0; i < 200; ++i) {
        const double mid = 0.5 * (lo + hi);
        (depth_of(mid) < depth ? lo : hi) = mid;
    }
    const double a = 0.5 * (lo + hi);
    return 0.5 * reduced_modulus() * ((a * a + radius * radius) * std::log((radius + a) / (radius - a)) - 2 * a * radius);
}

struct Block {
    Lattice lattice;
    Packing packing;
    double spacing = 0;
    int n = 0, nz = 0;
    double top = 0;            ///< z of the top particle layer, mm
    Eigen::Vector3d middle;    ///< the top particle nearest the middle of the top face
};

/// An n × n × nz block of label-1 voxels of `spacing` mm, laid out at that spacing (a particle per
/// voxel, at its centre), the bottom particle layer anchored, packed.
Block make_block(int n, int nz, double spacing, double damping_ratio) {
    Material material;
    material.youngs_modulus_kpa = youngs_kpa;
    material.damping_ratio = damping_ratio;
    material.poisson_ratio = poisson;
    Block b;
    b.lattice = uniform_block({n, n, nz}, spacing, material);
    b.spacing = spacing;
    b.n = n;
    b.nz = nz;
    Particles& p = b.lattice.particles;
    for (std::size_t i = 0; i < p.size(); ++i) p.anchored[i] = p.lattice_index[i][2] == 0;
    b.packing = pack_particles(b.lattice);
    b.top = -1e30;
    for (const auto& r : p.rest_position) b.top = std::max(b.top, double(r[2]));
    const Eigen::Vector3d centre(0.5 * (n - 1) * spacing, 0.5 * (n - 1) * spacing, b.top);
    double best = 1e30;
    for (const auto& r : p.rest_position) {
        const Eigen::Vector3d x(r[0], r[1], r[2]);
        if (std::abs(x.z() - b.top) > 1e-3 * spacing) continue;
        const double d = (x - centre).norm() + 1e-9 * (x.x() + 1e-3 * x.y());  // lowest x, then y, of equals
        if (d < best) best = d, b.middle = x;
    }
    return b;
}

struct Settings {
    double radius = 5.0;
    double drag = 0.1;           ///< 1/ms
    double damping_ratio = 0.3;
    double ramp_speed = 0.02;    ///< mm/ms
    double window_ms = 10.0;
    double tolerance = 1e-4;     ///< relative force change over a window to call it settled
    double max_hold_ms = 2000.0;
    /// --drawn: the depth counted from the drawn surface, the label map's boundary half a spacing
    /// above the top layer, and the solver meeting it there through each outer particle's contact
    /// skin (libmodel/contact_skin.h), as heartsim does: half a spacing on every outer particle of
    /// the block, what contact_skin gives for the block's box (tests/test_contact_skin.cpp).
    bool drawn = false;
};

struct Press {
    double depth = 0;            ///< below the top particle layer, mm
    double force = 0;            ///< probe's normal (z) force, N
    double anchors = 0;          ///< −(anchor force z), N: equals the probe's at rest
    double surface_sum = 0;      ///< Σ particle forces (z) over every particle on the probe's surface
    std::size_t touched = 0;     ///< particles touched in the last substep
    std::size_t on_surface = 0;  ///< particles within 1e-4·R of the probe's surface
    double last_change = 0;      ///< relative force change over the last window
    double hold_ms = 0;
    bool settled = false;
};

/// Presses the probe at `offset` (mm, in x and y from the middle particle) to each depth in turn.
std::vector<Press> press(const Block& b, const Eigen::Vector2d& offset, const std::vector<double>& depths, const Settings& s) {
    SolverOptions o;
    o.gravity.setZero();
    o.damping = s.drag;
    o.damping_ratio = {s.damping_ratio};
    Solver solver(b.lattice, b.packing.neighbours, o);
    std::vector<float> skin(b.lattice.particles.size(), 0.0f);
    if (s.drawn) {
        for (std::size_t i = 0; i < skin.size(); ++i)
            for (const std::int32_t j : b.packing.neighbours[i])
                if (j < 0) skin[i] = float(0.5 * b.spacing);
        solver.set_contact_skin(skin);
    }
    const double surface = b.top + (s.drawn ? 0.5 * b.spacing : 0.0);  // where depth 0 lies
    solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d::Constant(s.radius)});
    const double h = solver.time_step_ms();
    auto pose_at = [&](double depth) {
        return InstrumentPose{Eigen::Vector3d(b.middle.x() + offset.x(), b.middle.y() + offset.y(), surface + s.radius - depth),
                              Eigen::Quaterniond::Identity()};
    };
    double current = -0.2;  // the probe's bottom 0.2 mm above the top layer
    solver.set_pose(0, pose_at(current));
    solver.step();
    std::vector<Press> out;
    const Particles& p = b.lattice.particles;
    for (const double depth : depths) {
        // Ramp at ramp_speed, one window at a time.
        while (current < depth) {
            const double next = std::min(depth, current + s.ramp_speed * s.window_ms);
            solver.set_pose(0, pose_at(next));
            const StepReport r = solver.step(std::max(1, int(std::lround((next - current) / s.ramp_speed / h))));
            if (r.diverged) {
                std::fprintf(stderr, "hertz_bench: %s\n", r.message.c_str());
                std::exit(1);
            }
            current = next;
        }
        Press row;
        row.depth = depth;
        const int window = std::max(1, int(std::lround(s.window_ms / h)));
        double previous = solver.instrument_forces().hand[0].force_n.z();
        int quiet = 0;
        while (row.hold_ms < s.max_hold_ms) {
            const StepReport r = solver.step(window);
            if (r.diverged) {
                std::fprintf(stderr, "hertz_bench: %s\n", r.message.c_str());
                std::exit(1);
            }
            row.hold_ms += window * h;
            const double f = solver.instrument_forces().hand[0].force_n.z();
            row.last_change = std::abs(f - previous) / std::max(std::abs(f), 1e-12);
            previous = f;
            quiet = row.last_change < s.tolerance ? quiet + 1 : 0;
            if (quiet >= 3) {
                row.settled = true;
                break;
            }
        }
        const InstrumentForces forces = solver.instrument_forces();
        row.force = forces.hand[0].force_n.z();
        row.touched = forces.hand[0].particles;
        row.anchors = -solver.anchor_force().z();
        if (solver.pierced_particles() > 0)
            std::fprintf(stderr, "hertz_bench: the probe pierced %zu times by depth %g mm\n", solver.pierced_particles(), depth);
        const Eigen::Vector3d centre = pose_at(depth).position;
        for (std::size_t i = 0; i < p.size(); ++i) {
            if (p.anchored[i]) continue;
            if ((solver.position(i) - centre).norm() < (s.radius + skin[i]) * (1 + 1e-4)) {
                ++row.on_surface;
                row.surface_sum += solver.particle_force(i).z();
            }
        }
        out.push_back(row);
    }
    return out;
}

/// The same lattice, linearised: springs of stiffness k along their rest directions (small
/// displacements, f = k·n₀n₀ᵀ(u_j − u_i)), pressed by the sphere in linear contact theory (the
/// constraint on the vertical displacement of each top-layer particle at its rest lateral place,
/// frictionless: u_z ≤ −(d − (R − √(R² − r₀²)))), which is the problem Sneddon solves in the
/// continuum. The top-layer particles under the probe are the only candidates; their vertical
/// compliance matrix comes from one conjugate-gradient solve each, and each depth's contact set
/// from an active-set loop on it. Returns the force at each depth (N). What the nonlinear solver
/// gives beyond it is the spring network's large-deformation response.
std::vector<double> linear_press(const Block& b, const Eigen::Vector2d& offset, const std::vector<double>& depths, double radius) {
    const Particles& p = b.lattice.particles;
    const Springs& springs = b.lattice.springs;
    std::vector<int> dof(p.size(), -1);
    int free = 0;
    for (std::size_t i = 0; i < p.size(); ++i)
        if (!p.anchored[i]) dof[i] = 3 * free++;
    auto rest = [&](std::size_t i) { return Eigen::Vector3d(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]); };
    std::vector<Eigen::Triplet<double>> triplets;
    triplets.reserve(springs.size() * 36);
    for (std::size_t s = 0; s < springs.size(); ++s) {
        const std::size_t a = std::size_t(springs.pairs[s][0]), c = std::size_t(springs.pairs[s][1]);
        const Eigen::Vector3d n = (rest(c) - rest(a)).normalized();
        const Eigen::Matrix3d block = double(springs.stiffness[s]) * n * n.transpose();
        const int da = dof[a], dc = dof[c];
        for (int r = 0; r < 3; ++r)
            for (int q = 0; q < 3; ++q) {
                if (da >= 0) triplets.emplace_back(da + r, da + q, block(r, q));
                if (dc >= 0) triplets.emplace_back(dc + r, dc + q, block(r, q));
                if (da >= 0 && dc >= 0) {
                    triplets.emplace_back(da + r, dc + q, -block(r, q));
                    triplets.emplace_back(dc + r, da + q, -block(r, q));
                }
            }
    }
    Eigen::SparseMatrix<double> k(3 * free, 3 * free);
    k.setFromTriplets(triplets.begin(), triplets.end());
    const Eigen::Vector2d centre(b.middle.x() + offset.x(), b.middle.y() + offset.y());
    const double reach = std::min(0.95 * radius, 1.3 * std::sqrt(radius * depths.back()) + b.spacing);
    std::vector<std::size_t> candidates;
    std::vector<double> lateral;
    for (std::size_t i = 0; i < p.size(); ++i) {
        const Eigen::Vector3d r = rest(i);
        const double l = (r.head<2>() - centre).norm();
        if (!p.anchored[i] && std::abs(r.z() - b.top) < 1e-3 * b.spacing && l < reach) candidates.push_back(i), lateral.push_back(l);
    }
    const int m = int(candidates.size());
    Eigen::ConjugateGradient<Eigen::SparseMatrix<double>, Eigen::Lower | Eigen::Upper, Eigen::IncompleteCholesky<double>> cg;
    cg.setTolerance(1e-10);
    cg.setMaxIterations(20000);
    cg.compute(k);
    Eigen::MatrixXd compliance(m, m);  // downward displacement of i per unit downward force on j, mm/N
    for (int j = 0; j < m; ++j) {
        Eigen::VectorXd load = Eigen::VectorXd::Zero(3 * free);
        load[dof[candidates[std::size_t(j)]] + 2] = -1.0;
        const Eigen::VectorXd u = cg.solve(load);
        for (int i = 0; i < m; ++i) compliance(i, j) = -u[dof[candidates[std::size_t(i)]] + 2];
    }
    compliance = 0.5 * (compliance + compliance.transpose());
    std::vector<double> out;
    for (const double d : depths) {
        // Needed downward displacement of each candidate: d minus the sphere's rise at its place.
        Eigen::VectorXd need(m);
        for (int i = 0; i < m; ++i) need[i] = d - (radius - std::sqrt(radius * radius - lateral[std::size_t(i)] * lateral[std::size_t(i)]));
        std::vector<char> in_contact(static_cast<std::size_t>(m), 0);
        for (int i = 0; i < m; ++i) in_contact[std::size_t(i)] = need[i] > 0;
        Eigen::VectorXd f = Eigen::VectorXd::Zero(m);
        for (int iteration = 0; iteration < 200; ++iteration) {
            std::vector<int> set;
            for (int i = 0; i < m; ++i)
                if (in_contact[std::size_t(i)]) set.push_back(i);
            Eigen::MatrixXd caa(set.size(), set.size());
            Eigen::VectorXd rhs(set.size());
            for (std::size_t r = 0; r < set.size(); ++r) {
                rhs[Eigen::Index(r)] = need[set[r]];
                for (std::size_t q = 0; q < set.size(); ++q) caa(Eigen::Index(r), Eigen::Index(q)) = compliance(set[r], set[q]);
            }
            const Eigen::VectorXd fa = set.empty() ? Eigen::VectorXd() : Eigen::VectorXd(caa.ldlt().solve(rhs));
            f.setZero();
            for (std::size_t r = 0; r < set.size(); ++r) f[set[r]] = fa[Eigen::Index(r)];
            const Eigen::VectorXd w = compliance * f;
            bool changed = false;
            // Drop the most tensile one, else add the most penetrating one.
            int worst = -1;
            for (int i = 0; i < m; ++i)
                if (in_contact[std::size_t(i)] && f[i] < 0 && (worst < 0 || f[i] < f[worst])) worst = i;
            if (worst >= 0) in_contact[std::size_t(worst)] = 0, changed = true;
            else {
                for (int i = 0; i < m; ++i)
                    if (!in_contact[std::size_t(i)] && w[i] < need[i] - 1e-9 * d && (worst < 0 || need[i] - w[i] > need[worst] - w[worst])) worst = i;
                if (worst >= 0) in_contact[std::size_t(worst)] = 1, changed = true;
            }
            if (!changed) break;
        }
        out.push_back(f.sum());
    }
    return out;
}

std::vector<std::string> split(const std::string& text) {
    std::vector<std::string> parts;
    std::stringstream in(text);
    for (std::string part; std::getline(in, part, ',');)
        if (!part.empty()) parts.push_back(part);
    return parts;
}

/// A finite-element reference (fe_indentation.py's CSV): force (N) by Poisson's ratio, then d/R.
using Reference = std::map<double, std::map<double, double>>;

std::string number(double value) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", value);
    return text;
}

[[noreturn]] void reference_error(const std::string& path, int line, const std::string& what) {
    std::fprintf(stderr, "hertz_bench: --reference %s line %d: %s\n", path.c_str(), line, what.c_str());
    std::exit(2);
}

/// Reads `path` into `out`: the header `nu,d_over_R,depth_mm,force_N,force_over_hertz`, then a row
/// per (ν, d/R). Each row's depth must be d/R · `radius` and its force over Hertz's (for its ν and
/// E = youngs_kpa) what it says, which checks the file was computed for this probe and tissue.
void read_reference(const std::string& path, double radius, Reference& out) {
    std::ifstream in(path);
    if (!in) {
        std::fprintf(stderr, "hertz_bench: --reference %s: cannot open it (a CSV of tests/bench/fe_indentation.py)\n", path.c_str());
        std::exit(2);
    }
    const std::string header = "nu,d_over_R,depth_mm,force_N,force_over_hertz";
    std::string text;
    int line = 0, rows = 0;
    while (std::getline(in, text)) {
        ++line;
        if (!text.empty() && text.back() == '\r') text.pop_back();
        if (text.empty()) continue;
        if (line == 1) {
            if (text != header) reference_error(path, line, "expected the header '" + header + "', found '" + text + "'");
            continue;
        }
        const std::vector<std::string> fields = split(text);
        double v[5];
        if (fields.size() != 5) reference_error(path, line, "expected 5 numbers (" + header + "), found '" + text + "'");
        for (std::size_t i = 0; i < 5; ++i) {
            char* end = nullptr;
            v[i] = std::strtod(fields[i].c_str(), &end);
            if (end == fields[i].c_str() || *end != '\0' || !std::isfinite(v[i]))
                reference_error(path, line, "'" + fields[i] + "' is not a number");
        }
        const double nu = v[0], d_over_r = v[1], depth = v[2], force = v[3], ratio = v[4];
        if (!(nu > -1 && nu < 0.5) || d_over_r <= 0 || force <= 0) reference_error(path, line, "expected -1 < nu < 0.5, d/R > 0, force > 0");
        if (std::abs(depth - d_over_r * radius) > 1e-4 * depth)
            reference_error(path, line, "depth " + fields[2] + " mm is not d/R · R for R = " + number(radius) +
                                            " mm (--radius): computed for another sphere");
        const double hertz_nu = 4.0 / 3.0 * youngs_kpa * 1e-3 / (1 - nu * nu) * std::sqrt(radius) * std::pow(depth, 1.5);
        if (std::abs(force / hertz_nu - ratio) > 1e-3 * ratio)
            reference_error(path, line, "force over Hertz for E = " + number(youngs_kpa) + " kPa is " + number(force / hertz_nu) +
                                            ", the file says " + fields[4] + ": computed for another modulus or radius");
        out[nu][d_over_r] = force;
        ++rows;
    }
    if (rows == 0) reference_error(path, line, "no rows");
}

}  // namespace

int main(int argc, char** argv) {
    Settings s;
    std::vector<std::string> spacings{"3", "2", "default", "1.5"};
    std::vector<double> depths{0.1, 0.2, 0.3, 0.4};
    std::vector<std::string> placements{"particle", "edge", "face"};
    double size = 60.0, thickness = 0.0;
    int threads = 0;
    bool details = false, linear = false;
    Reference reference;
    std::vector<std::string> reference_files;
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        auto value = [&]() -> std::string {
            if (a + 1 >= argc) {
                std::fprintf(stderr, "hertz_bench: %s needs a value\n", arg.c_str());
                std::exit(2);
            }
            return argv[++a];
        };
        if (arg == "--spacings") spacings = split(value());
        else if (arg == "--size") size = std::stod(value());
        else if (arg == "--thickness") thickness = std::stod(value());
        else if (arg == "--radius") s.radius = std::stod(value());
        else if (arg == "--depths") {
            depths.clear();
            for (const auto& d : split(value())) depths.push_back(std::stod(d));
        } else if (arg == "--placements") placements = split(value());
        else if (arg == "--threads") threads = std::stoi(value());
        else if (arg == "--drag") s.drag = std::stod(value());
        else if (arg == "--damping-ratio") s.damping_ratio = std::stod(value());
        else if (arg == "--tolerance") s.tolerance = std::stod(value());
        else if (arg == "--ramp-speed") s.ramp_speed = std::stod(value());
        else if (arg == "--details") details = true;
        else if (arg == "--linear") linear = true;
        else if (arg == "--drawn") s.drawn = true;
        else if (arg == "--poisson-ratio") poisson = std::stod(value());
        else if (arg == "--reference") reference_files.push_back(value());
        else if (arg == "--quick") {
            spacings = {"3", "default"};
            depths = {0.2, 0.4};
            placements = {"particle", "face"};
        } else {
            std::fprintf(stderr, "usage: hertz_bench [--spacings 3,2,default,1.5] [--size 60] [--thickness T] [--radius 5]\n"
                                 "       [--depths 0.1,0.2,0.3,0.4] [--placements particle,edge,face] [--threads N]\n"
                                 "       [--drag 0.1] [--damping-ratio 0.3] [--tolerance 1e-4] [--ramp-speed 0.02] [--quick] [--details] [--linear]\n"
                                 "       [--reference fe.csv] [--drawn] [--poisson-ratio 0.25]\n");
            return 2;
        }
    }
    if (thickness <= 0) thickness = size;
    if (!(poisson >= 0.25 && poisson <= 0.499)) {
        std::fprintf(stderr, "hertz_bench: --poisson-ratio %g: expected 0.25 (the springs alone) to 0.499\n", poisson);
        return 2;
    }
    if (linear && poisson > 0.25) {  // linear_press linearises the springs only
        std::fprintf(stderr, "hertz_bench: --linear solves the springs alone; it takes no --poisson-ratio above 0.25\n");
        return 2;
    }
    for (const std::string& file : reference_files) read_reference(file, s.radius, reference);
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    std::sort(depths.begin(), depths.end());

    std::printf("# Probe R = %g mm on a %g x %g x %g mm block, E = %g kPa, nu = %g, bottom anchored, no gravity\n", s.radius, size,
                size, thickness, youngs_kpa, poisson);
    std::printf("# drag %g /ms, spring damping ratio %g, ramp %g mm/ms, settled: force change < %g per %g ms window, 3 in a row\n\n",
                s.drag, s.damping_ratio, s.ramp_speed, s.tolerance, s.window_ms);
    std::printf("# depth counted from %s\n\n", s.drawn ? "the drawn surface (the label map's boundary, half a spacing above the top particle "
                                                        "layer), met through the outer particles' contact skin"
                                                      : "the top particle layer");

    struct Cell {
        double hertz = 0, sneddon = 0, label_hertz = 0;
        std::vector<double> forces, linear;
    };
    std::map<std::pair<double, double>, Cell> summary;  // (spacing, d/R)
    std::vector<double> spacing_values;

    if (details)
        std::printf("| spacing mm | particles | placement | d/R | d mm | F N | -anchor N | sum on surface N | touched | on surface | "
                    "settle ms | last change | F Hertz N | error %% | error vs Sneddon %% | error vs Hertz from label surface %% |%s\n"
                    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|%s\n",
                    linear ? " F linear lattice N | F / F linear − 1 % |" : "", linear ? "---|---|" : "");
    for (const std::string& text : spacings) {
        const int n = text == "default" ? int(std::floor(std::cbrt(30000.0) + 1e-9)) : int(std::lround(size / std::stod(text)));
        const double spacing = text == "default" ? size / n : std::stod(text);
        const int nx = text == "default" ? n : int(std::lround(size / spacing));
        const int nz = std::max(2, int(std::lround(thickness / spacing)));
        const auto start = std::chrono::steady_clock::now();
        const Block b = make_block(nx, nz, spacing, s.damping_ratio);
        spacing_values.push_back(spacing);
        for (const std::string& placement : placements) {
            Eigen::Vector2d offset = Eigen::Vector2d::Zero();
            if (placement == "edge") offset = {0.5 * spacing, 0};
            else if (placement == "face") offset = {0.5 * spacing, 0.5 * spacing};
            else if (placement != "particle") {
                std::fprintf(stderr, "hertz_bench: placement %s: particle, edge or face\n", placement.c_str());
                return 2;
            }
            std::vector<double> d_mm;
            for (double d : depths) d_mm.push_back(d * s.radius);
            const std::vector<Press> rows = press(b, offset, d_mm, s);
            const std::vector<double> lin = linear ? linear_press(b, offset, d_mm, s.radius) : std::vector<double>(d_mm.size(), NAN);
            for (std::size_t q = 0; q < rows.size(); ++q) {
                const Press& r = rows[q];
                Cell& cell = summary[{spacing, depths[q]}];
                cell.hertz = hertz(s.radius, r.depth);
                cell.sneddon = sneddon(s.radius, r.depth);
                cell.label_hertz = hertz(s.radius, r.depth + (s.drawn ? 0.0 : 0.5 * spacing));
                cell.forces.push_back(r.force);
                cell.linear.push_back(lin[q]);
                if (details) {
                    std::printf("| %.3f | %zu | %s | %.2f | %.2f | %.5f | %.5f | %.5f | %zu | %zu | %.0f%s | %.1e | %.5f | %+.1f | %+.1f | %+.1f |",
                                spacing, b.lattice.particles.size(), placement.c_str(), depths[q], r.depth, r.force, r.anchors,
                                r.surface_sum, r.touched, r.on_surface, r.hold_ms, r.settled ? "" : " (not settled)", r.last_change,
                                cell.hertz, 100 * (r.force / cell.hertz - 1), 100 * (r.force / cell.sneddon - 1),
                                100 * (r.force / cell.label_hertz - 1));
                    if (linear) std::printf(" %.5f | %+.1f |", lin[q], 100 * (r.force / lin[q] - 1));
                    std::printf("\n");
                }
                std::fflush(stdout);
            }
        }
        std::fprintf(stderr, "hertz_bench: spacing %.3f mm (%zu particles): %.1f s\n", spacing, b.lattice.particles.size(),
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }

    std::string reference_header, reference_rule;
    for (const auto& entry : reference) {
        char text[160];
        std::snprintf(text, sizeof text, " F FE nu = %g N | error vs FE nu = %g %% (mean) |", entry.first, entry.first);
        reference_header += text;
        reference_rule += "---|---|";
    }
    std::printf("\n| spacing mm | d/R | F measured N (mean; min–max over placements) | F Hertz N | error %% (mean; min–max) | "
                "error vs Sneddon %% | error vs Hertz from the label surface %% |%s%s\n|---|---|---|---|---|---|---|%s%s\n",
                linear ? " linear lattice vs Sneddon % (mean; min–max) | solver vs linear lattice % (mean) |" : "",
                reference_header.c_str(), linear ? "---|---|" : "", reference_rule.c_str());
    for (const double spacing : spacing_values)
        for (const double d : depths) {
            const Cell& c = summary[{spacing, d}];
            double mean = 0, lo = 1e30, hi = -1e30;
            for (double f : c.forces) mean += f / double(c.forces.size()), lo = std::min(lo, f), hi = std::max(hi, f);
            std::printf("| %.3f | %.1f | %.4f; %.4f–%.4f | %.4f | %+.1f; %+.1f to %+.1f | %+.1f | %+.1f |", spacing, d, mean, lo, hi,
                        c.hertz, 100 * (mean / c.hertz - 1), 100 * (lo / c.hertz - 1), 100 * (hi / c.hertz - 1),
                        100 * (mean / c.sneddon - 1), 100 * (mean / c.label_hertz - 1));
            if (linear) {
                double lmean = 0, llo = 1e30, lhi = -1e30, ratio = 0;
                for (std::size_t q = 0; q < c.linear.size(); ++q) {
                    const double f = c.linear[q];
                    lmean += f / double(c.linear.size()), llo = std::min(llo, f), lhi = std::max(lhi, f);
                    ratio += (c.forces[q] / f - 1) / double(c.linear.size());
                }
                std::printf(" %+.1f; %+.1f to %+.1f | %+.1f |", 100 * (lmean / c.sneddon - 1), 100 * (llo / c.sneddon - 1),
                            100 * (lhi / c.sneddon - 1), 100 * ratio);
            }
            for (const auto& entry : reference) {
                double fe = NAN;
                for (const auto& depth_force : entry.second)
                    if (std::abs(depth_force.first - d) < 1e-6) fe = depth_force.second;
                if (std::isnan(fe)) std::printf(" – | – |");
                else std::printf(" %.4f | %+.1f |", fe, 100 * (mean / fe - 1));
            }
            std::printf("\n");
        }
    return 0;
}
