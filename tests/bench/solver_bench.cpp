// Solver benchmark (not a test): steps per second at ~30k (a real heart), 300k and 1M particles
// (phantoms), achieved memory bandwidth against a STREAM-style copy measured in the same run,
// Bullet's soft body on the same lattice, run time against error for the policy step and
// dt = critical/2 … /32
// in float and double, and the slices vs bricks packings. Prints tables; writes CSV.
//
//   solver_bench [--real PATH] [--out DIR] [--quick] [--threads N] [--stress STEPS] [--safety F]
//                [--phantoms N,N,...]   phantom sizes (default 300000,1000000 in a full run, none with --quick)
//                [--seeds N,N,...]      the stress gesture's random seeds, one run each (default 5)
//                [--stress-only]        with --stress: no rate, peer or accuracy tables
//
// Results and the exact commands: docs/benchmarks-solver.md.
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/packing.h"
#include "libmodel/phantom.h"
#include "libmodel/select.h"
#include "libmodel/sim/solver.h"
#include "libmodel/stability.h"
#include "tests/stress_gesture.h"

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#ifdef HEARTSIM_HAVE_BULLET
#include <BulletSoftBody/btSoftBody.h>
#include <BulletSoftBody/btSoftBodyHelpers.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>
#include <BulletSoftBody/btSoftRigidDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>
#endif

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

using namespace heartsim;
using Clock = std::chrono::steady_clock;

namespace {

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

struct Case {
    std::string name;
    Lattice lattice;
    Packing packing;
};

Case real_case(const std::filesystem::path& path, PackingScheme scheme) {
    const LabelVolume volume = read_label_volume(path);
    const Selection selection = select_tissue(volume, {});
    Case c{path.parent_path().filename().string() + "/" + to_string(scheme), layout_particles(selection, {1}, volume, {}), {}};
    c.packing = pack_particles(c.lattice, {.scheme = scheme});
    return c;
}

Case phantom_case(std::size_t budget) {
    PhantomOptions options;
    options.shape = PhantomShape::heart;
    options.voxel_mm = budget > 500000 ? 0.35 : 0.6;
    const LabelVolume volume = make_phantom(options);
    const Selection selection = select_tissue(volume, {});
    Case c{"phantom_" + std::to_string(budget / 1000) + "k", layout_particles(selection, {1}, volume, {.particle_budget = budget}), {}};
    c.packing = pack_particles(c.lattice);
    return c;
}

/// STREAM "copy" (a[i] = b[i]) over `bytes` per array on the current TBB arena, GB/s counting
/// read + write bytes as STREAM does. Best of `repeats`.
double stream_copy_gbs(std::size_t bytes, int repeats = 10) {
    const std::size_t n = bytes / sizeof(float);
    std::vector<float> a(n, 1.0f), b(n, 2.0f);
    const std::size_t block = 1 << 16;
    double best = 0;
    for (int r = 0; r < repeats; ++r) {
        const auto t0 = Clock::now();
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, (n + block - 1) / block), [&](const tbb::blocked_range<std::size_t>& range) {
            for (std::size_t k = range.begin(); k != range.end(); ++k) {
                const std::size_t first = k * block, count = std::min(block, n - first);
                std::memcpy(a.data() + first, b.data() + first, count * sizeof(float));
            }
        });
        best = std::max(best, 2.0 * double(bytes) / seconds_since(t0) / 1e9);
    }
    if (a[n / 2] != 2.0f) std::cerr << "copy check failed\n";
    return best;
}

/// Bytes a substep must move at least: read the positions and the motions of the last substep
/// (16 B each), write the next of both (16 B each), the 18-slot tables (neighbour, rest length,
/// stiffness, and dashpot if damped, 4 B each), mass and h²/m (4 B each).
double bytes_per_particle(bool damped, bool uniform_slots) {
    return 64.0 + 18.0 * 4.0 * ((damped ? 2.0 : 1.0) + (uniform_slots ? 0.0 : 2.0)) + 8.0;
}

struct Timing {
    double steps_per_second = 0;
    double seconds = 0;
    long long steps = 0;
};

/// Runs `solver` in three windows of `min_seconds` / 3 (after a short warm-up) and returns the
/// best window's substeps/s: the machine is shared, the best window is the least disturbed.
Timing time_steps(Solver& solver, double min_seconds) {
    solver.step(20);
    Timing best;
    for (int window = 0; window < 3; ++window) {
        Timing t;
        const auto t0 = Clock::now();
        int batch = 10;
        while (true) {
            const StepReport report = solver.step(batch);
            if (report.diverged) std::cerr << report.message << "\n";
            t.steps += batch;
            t.seconds = seconds_since(t0);
            if (t.seconds >= min_seconds / 3) break;
            batch = std::min(batch * 2, 2000);
        }
        t.steps_per_second = double(t.steps) * solver.substeps_per_step() / t.seconds;
        if (t.steps_per_second > best.steps_per_second) best = t;
    }
    return best;
}

/// --safety: the step as a fraction of the damped critical step (SolverOptions default otherwise).
double safety_factor = SolverOptions{}.safety_factor;

SolverOptions scenario_options() {
    SolverOptions o;  // as a scenario gives them: dt = safety × the damped critical step, ζ from the material (0.1)
    o.safety_factor = safety_factor;
    // Gravity off: the benchmark hearts have no anchors and would fall freely until the speed
    // bound stops them; the cost of a step does not depend on it.
    o.gravity.setZero();
    return o;
}

#ifdef HEARTSIM_HAVE_BULLET
/// Bullet's soft body with the same nodes, masses, links and time step; single-threaded as
/// Bullet's soft bodies are. Link stiffness is Bullet's [0,1] position-constraint factor kLST
/// (1 = stiffest), one solver iteration (Bullet's default), collisions off.
double bullet_steps_per_second(const Case& c, double dt_ms, double min_seconds) {
    btSoftBodyRigidBodyCollisionConfiguration configuration;
    btCollisionDispatcher dispatcher(&configuration);
    btDbvtBroadphase broadphase;
    btSequentialImpulseConstraintSolver solver;
    btSoftRigidDynamicsWorld world(&dispatcher, &broadphase, &solver, &configuration);
    world.setGravity(btVector3(0, 9.81, 0));
    btSoftBodyWorldInfo& info = world.getWorldInfo();
    info.m_gravity = btVector3(0, 9.81, 0);
    info.m_sparsesdf.Initialize();
    const auto& p = c.lattice.particles;
    std::vector<btVector3> x(p.size());
    std::vector<btScalar> m(p.size());
    for (std::size_t i = 0; i < p.size(); ++i) {
        x[i] = btVector3(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        m[i] = p.anchored[i] ? 0 : p.mass[i];
    }
    auto* body = new btSoftBody(&info, int(p.size()), x.data(), m.data());
    btSoftBody::Material* material = body->appendMaterial();
    material->m_kLST = 1.0;
    for (const auto& pair : c.lattice.springs.pairs) body->appendLink(pair[0], pair[1], material, false);
    body->m_cfg.piterations = 1;
    body->m_cfg.collisions = 0;
    body->m_cfg.kDP = 0.0;
    world.addSoftBody(body);
    const btScalar dt = btScalar(dt_ms * 1e-3);  // Bullet works in seconds
    for (int i = 0; i < 5; ++i) world.stepSimulation(dt, 0, dt);
    long long steps = 0;
    const auto t0 = Clock::now();
    while (seconds_since(t0) < min_seconds) {
        for (int i = 0; i < 5; ++i) world.stepSimulation(dt, 0, dt);
        steps += 5;
    }
    const double rate = double(steps) / seconds_since(t0);
    world.removeSoftBody(body);
    delete body;
    return rate;
}
#endif

/// Error at a fixed simulated time against a converged double reference, and wall time per
/// simulated ms, for dt = critical/divisor, float and double.
void accuracy_table(const Case& c, std::ostream& csv, bool quick, double damping_ratio) {
    SolverOptions base;
    base.gravity = Eigen::Vector3d(0, 9.81e-3, 0);
    base.damping_ratio = {damping_ratio};
    base.subdivide = false;
    base.critical_dt_ms = estimate_critical_time_step(c.lattice.particles, c.lattice.springs).critical_dt_ms;
    const double end_time = 20 * base.critical_dt_ms;
    // A smooth initial deformation: the heart squeezed by 5% along x about its centre.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (const auto& r : c.lattice.particles.rest_position) centre += Eigen::Vector3d(r[0], r[1], r[2]);
    centre /= double(c.lattice.particles.size());
    std::vector<Eigen::Vector3d> x0, v0(c.lattice.particles.size(), Eigen::Vector3d::Zero());
    for (const auto& r : c.lattice.particles.rest_position) {
        Eigen::Vector3d x(r[0], r[1], r[2]);
        x.x() = centre.x() + 0.95 * (x.x() - centre.x());
        x0.push_back(x);
    }
    auto run = [&](auto& solver, double& wall) {
        solver.set_state(x0, v0);
        const auto t0 = Clock::now();
        solver.step(int(std::lround(end_time / solver.time_step_ms())));
        wall = seconds_since(t0);
        std::vector<Eigen::Vector3d> x(solver.size());
        for (std::size_t i = 0; i < x.size(); ++i) x[i] = solver.position(i);
        return x;
    };
    SolverOptions reference_options = base;
    const int reference_divisor = quick ? 64 : 256;
    reference_options.dt_ms = base.critical_dt_ms / reference_divisor;
    ReferenceSolver reference_solver(c.lattice, c.packing.neighbours, reference_options);
    double reference_wall = 0;
    const auto reference = run(reference_solver, reference_wall);
    std::cout << "\nRun time against error (" << c.name << ", " << c.lattice.particles.size() << " particles, dashpots ζ = " << damping_ratio
              << ", gravity, 5% squeeze; t = "
              << end_time << " ms; reference: double at critical/" << reference_divisor << ")\n";
    std::cout << "  precision  dt          max error (mm)  rms error (mm)  wall s per simulated ms\n";
    // The step the runtime takes on this heart: the safety factor × the damped critical step with
    // the material's dashpots (ζ = 0.1), as the solver computes it, run here with the table's ζ
    // like the other rows. (Rounded so that a whole number of steps ends at end_time, as the
    // divisors do.)
    const double policy_step =
        scenario_options().safety_factor *
        stable_step_ms(4.0 / (base.critical_dt_ms * base.critical_dt_ms),
                       estimate_damping_eigenvalue(c.lattice.particles, c.lattice.springs, damping_ratios(c.lattice.materials), 0.0));
    const double policy_dt = end_time / std::ceil(end_time / policy_step);
    std::vector<std::pair<std::string, double>> steps{{"policy " + std::to_string(policy_dt / base.critical_dt_ms).substr(0, 5), policy_dt}};
    for (int divisor : {2, 4, 8, 16, 32}) steps.emplace_back("crit/" + std::to_string(divisor), base.critical_dt_ms / divisor);
    for (const char* precision : {"float", "double"}) {
        for (const auto& [label, dt] : steps) {
            SolverOptions o = base;
            o.dt_ms = dt;
            double wall = 0;
            std::vector<Eigen::Vector3d> x;
            if (std::string(precision) == "float") {
                Solver s(c.lattice, c.packing.neighbours, o);
                x = run(s, wall);
            } else {
                ReferenceSolver s(c.lattice, c.packing.neighbours, o);
                x = run(s, wall);
            }
            double max_error = 0, sum2 = 0;
            for (std::size_t i = 0; i < x.size(); ++i) {
                const double e = (x[i] - reference[i]).norm();
                max_error = std::max(max_error, e);
                sum2 += e * e;
            }
            const double rms = std::sqrt(sum2 / double(x.size()));
            std::cout << "  " << std::setw(9) << precision << "  " << std::left << std::setw(12) << label << std::right << std::setw(14) << max_error
                      << "  " << std::setw(14) << rms << "  " << std::setw(10) << wall / end_time << "\n";
            csv << "accuracy," << c.name << "," << damping_ratio << "," << precision << "," << label << "," << max_error << "," << rms << "," << wall / end_time << "\n";
        }
    }
}

// The two-handed stress gesture (tests/stress_gesture.h) for `steps` steps from one seed: prints
// one line, adds one CSV row, returns the watchdog events.
std::size_t stress_run(const Case& c, long long steps, unsigned seed, std::ostream& csv) {
    SolverOptions o = scenario_options();
    o.damping = 0.01;
    Solver solver(c.lattice, c.packing.neighbours, o);
    std::size_t events = 0, largest_grab = 0;
    std::array<std::size_t, 4> reasons{};
    double largest_force = 0;
    const auto t0 = Clock::now();
    test::StressGesture gesture(solver, c.lattice.particles, seed);  // tests/stress_gesture.h
    for (long long s = 0; s < steps; ++s) {
        gesture.before_step(solver, s);
        largest_grab = std::max(largest_grab, solver.contact_particles(1).size());
        const StepReport report = solver.step();
        events += report.diverged;
        if (report.diverged) ++reasons[int(report.reason)];
        const auto f = solver.instrument_forces();
        largest_force = std::max({largest_force, f.hand[0].force_n.norm(), f.hand[1].force_n.norm()});
    }
    bool finite = true;
    for (std::size_t i = 0; i < solver.size(); ++i) finite = finite && solver.position(i).allFinite();
    std::cout << "  seed " << std::setw(3) << seed << ": " << seconds_since(t0) << " s, positions " << (finite ? "finite" : "NOT FINITE") << ", watchdog events "
              << events << " (non-finite " << reasons[1] << ", speed " << reasons[2] << ", energy " << reasons[3] << "), largest grab " << largest_grab
              << " particles, slipped " << solver.slipped_particles() << ", pierced " << solver.pierced_particles() << ", largest instrument force "
              << largest_force << " N\n";
    csv << "stress," << c.name << "," << seed << "," << events << "," << largest_grab << "," << solver.pierced_particles() << "," << largest_force << "\n";
    return events;
}

}  // namespace

int main(int argc, char** argv) {
    std::filesystem::path real = std::filesystem::path(HEARTSIM_REAL_DATA) / "hvsmr16_pat1";
    std::filesystem::path out = ".";
    bool quick = false;
    int threads = 2;
    long long stress_steps = 0;
    std::vector<unsigned> seeds{5};
    bool stress_only = false;
    std::vector<std::size_t> phantom_sizes{300000, 1000000};
    bool phantoms_given = false;  // --phantoms: also with --quick
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--real" && a + 1 < argc) real = argv[++a];
        else if (arg == "--out" && a + 1 < argc) out = argv[++a];
        else if (arg == "--quick") quick = true;
        else if (arg == "--threads" && a + 1 < argc) threads = std::stoi(argv[++a]);
        else if (arg == "--stress" && a + 1 < argc) stress_steps = std::stoll(argv[++a]);
        else if (arg == "--safety" && a + 1 < argc) safety_factor = std::stod(argv[++a]);
        else if (arg == "--stress-only") stress_only = true;
        else if (arg == "--seeds" && a + 1 < argc) {
            seeds.clear();
            std::stringstream list(argv[++a]);
            for (std::string item; std::getline(list, item, ',');) seeds.push_back(unsigned(std::stoul(item)));
        }
        else if (arg == "--phantoms" && a + 1 < argc) {
            phantom_sizes.clear();
            phantoms_given = true;
            std::stringstream list(argv[++a]);
            for (std::string item; std::getline(list, item, ',');) phantom_sizes.push_back(std::size_t(std::stoull(item)));
        }
        else {
            std::cerr << "usage: solver_bench [--real DIR_OR_FILE] [--out DIR] [--quick] [--threads N] [--stress STEPS] [--safety F] [--phantoms N,N,...] [--seeds N,N,...] [--stress-only]\n";
            return 2;
        }
    }
    if (std::filesystem::is_directory(real)) {
        // A case folder holds the label map (…-label.nii.gz) beside the MRI itself: take the labels.
        std::filesystem::path labels;
        for (const auto& entry : std::filesystem::directory_iterator(real))
            if (entry.path().filename().string().find("label") != std::string::npos) labels = entry.path();
        if (labels.empty()) {
            std::cerr << "solver_bench: " << real << " holds no label map (a file with 'label' in its name)\n";
            return 1;
        }
        real = labels;
    }
    tbb::global_control control(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    const double min_seconds = quick ? 0.5 : 2.0;
    std::ofstream csv(out / "solver_bench.csv");
    csv << "table,case,a,b,c,d,e\n";

    std::cout << "heartsim solver benchmark, " << threads << " threads (TBB)\n";
    double copy_gbs = 0;
    if (!stress_only) {
        copy_gbs = stream_copy_gbs(std::size_t(256) << 20);
        std::cout << "STREAM-style copy (2 × 256 MiB arrays, read + write counted): " << copy_gbs << " GB/s\n";
        csv << "copy,," << copy_gbs << ",,,,\n";
    }

    // ~30k: the real heart at the default budget, both packings.
    std::vector<Case> cases;
    const auto t_layout = Clock::now();
    cases.push_back(real_case(real, PackingScheme::bricks));
    if (!stress_only) cases.push_back(real_case(real, PackingScheme::slices));  // the rate tables compare the packings
    std::cout << "real case " << real << ": " << cases[0].lattice.particles.size() << " particles, " << cases[0].lattice.springs.size()
              << " springs (layout " << seconds_since(t_layout) << " s)\n";
    if ((!quick || phantoms_given) && stress_steps == 0 && !stress_only) {
        for (std::size_t budget : phantom_sizes) {
            if (budget == 0) continue;
            const auto t0 = Clock::now();
            cases.push_back(phantom_case(budget));
            std::cout << cases.back().name << ": " << cases.back().lattice.particles.size() << " particles (layout " << seconds_since(t0) << " s)\n";
        }
    }

    double rate_30k = 0;
    if (!stress_only) {
        std::cout << "\nSteps per second (float, dt = " << safety_factor << " × the damped critical step, ζ = 0.1 dashpots, gravity off; substeps counted)\n";
        std::cout << "  case                 particles  kernel    steps/s    ns/particle  GB/s moved  fraction of copy  (bytes/particle/step: "
                  << bytes_per_particle(true, true) << " with per-slot constants, " << bytes_per_particle(true, false) << " with per-entry tables)\n";
        for (const Case& c : cases) {
            for (SolverKernel kernel : {SolverKernel::avx512, SolverKernel::avx2, SolverKernel::sse2, SolverKernel::portable}) {
                if (c.lattice.particles.size() > 100000 && kernel == SolverKernel::portable) continue;
                SolverOptions o = scenario_options();
                o.kernel = kernel;
                Solver solver(c.lattice, c.packing.neighbours, o);
                const Timing t = time_steps(solver, min_seconds);
                const double n = double(c.lattice.particles.size());
                const double gbs = t.steps_per_second * n * bytes_per_particle(true, solver.load_report().uniform_slots) / 1e9;
                const char* kernel_name = to_string(solver.load_report().kernel);
                if (kernel == SolverKernel::avx2) std::cout << "  (" << c.name << ": per-slot constants " << (solver.load_report().uniform_slots ? "yes" : "no") << ")\n";
                std::cout << "  " << std::left << std::setw(20) << c.name << std::right << std::setw(10) << std::size_t(n) << "  " << std::setw(8) << kernel_name
                          << std::setw(11) << std::fixed << std::setprecision(0) << t.steps_per_second << std::setw(13) << std::setprecision(2)
                          << 1e9 / (t.steps_per_second * n) << std::setw(12) << gbs << std::setw(12) << gbs / copy_gbs << std::defaultfloat
                          << std::setprecision(6) << "\n";
                csv << "steps," << c.name << "," << std::size_t(n) << "," << kernel_name << "," << t.steps_per_second << "," << gbs << "," << gbs / copy_gbs << "\n";
                if (&c == &cases[0] && kernel == SolverKernel::avx512) rate_30k = t.steps_per_second;
            }
        }

        // Undamped (no dashpot gathers) on the real case, for the record.
        {
            SolverOptions o = scenario_options();
            o.damping_ratio = {0.0};
            Solver solver(cases[0].lattice, cases[0].packing.neighbours, o);
            const Timing t = time_steps(solver, min_seconds);
            std::cout << "  " << cases[0].name << " without dashpots (ζ = 0): " << std::fixed << std::setprecision(0) << t.steps_per_second << std::defaultfloat
                      << std::setprecision(6) << " steps/s\n";
            csv << "steps_undamped," << cases[0].name << ",," << t.steps_per_second << ",,,\n";
        }

#ifdef HEARTSIM_HAVE_BULLET
        {
            const Case& c = cases[0];
            Solver solver(c.lattice, c.packing.neighbours, scenario_options());
            const double bullet = bullet_steps_per_second(c, solver.substep_ms(), min_seconds);
            std::cout << "\nPeer: Bullet 3.24 btSoftBody on the same lattice (" << c.lattice.particles.size() << " nodes, " << c.lattice.springs.size()
                      << " links, same masses, dt = " << solver.substep_ms() << " ms, 1 iteration, collisions off, 1 thread)\n";
            std::cout << "  Bullet: " << bullet << " steps/s; heartsim: " << rate_30k << " steps/s; ratio " << rate_30k / bullet << "x\n";
            csv << "bullet," << c.name << "," << bullet << "," << rate_30k << "," << rate_30k / bullet << ",,\n";
        }
#else
        std::cout << "\nPeer: Bullet not built in (configure with libbullet-dev; HEARTSIM_HAVE_BULLET)\n";
#endif

        for (double zeta : {0.0, 0.1}) accuracy_table(cases[0], csv, quick, zeta);
    }

    if (stress_steps > 0) {
        std::cout << "\nStress: " << stress_steps << " steps of two instruments chasing random targets at 2 mm/ms (tests/stress_gesture.h), "
                  << cases[0].lattice.particles.size() << " particles\n";
        std::size_t events = 0;
        for (unsigned seed : seeds) events += stress_run(cases[0], stress_steps, seed, csv);
        std::cout << "  watchdog events over " << seeds.size() << " seed(s): " << events << "\n";
    }

    if (!stress_only)
        std::cout << "\nTargets: >= 4000 steps/s at ~30k on 2 cores: " << (rate_30k >= 4000 ? "met" : "MISSED") << " (" << rate_30k << ")\n";
    std::cout << "CSV: " << (out / "solver_bench.csv") << "\n";
    return 0;
}
