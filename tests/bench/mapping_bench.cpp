// Mapping benchmark (not a test): how well a coarse simulation drives the detailed visual mesh.
// For lattice spacings h = 1, 1.5, 2, 3, 4 mm (and the default 30 000-particle budget) on the
// heart phantom (make_phantom defaults) and on the real cases, it builds the pipeline's pieces
// (extract_surface with default smoothing, layout_particles at spacing h, build_simulation_surface,
// map_visual_mesh), moves the particles' rest positions by a reference smooth displacement field
// u(x), evaluates apply_mapping (float32, the shader's order), and compares the mapped visual
// vertices with u applied directly to the rest visual vertices: mean, RMS, 99th percentile and
// max error in mm, against the particle count and the time of the simulation surface and the
// mapping. Prints Markdown tables; writes mapping_bench.csv. Asserts nothing.
//
//   mapping_bench [--real DIR_OR_FILE]... [--no-real] [--no-phantom] [--out DIR] [--amplitude MM]
//                 [--threads N]
//
// --real defaults to every */ *-label.nii.gz under HEARTSIM_REAL_DATA (skipped with a message if
// absent). Results and the exact commands: docs/benchmarks.md, "heartprep: packing, simulation surface and mapping".
//
// Reference field (world LPS mm). c = centre of the visual mesh's bounding box, L = half its
// extent along z (the long axis of the phantom, the axial direction of the HVSMR crops),
// (x, y, z) = position − c, s = z / L in [−1, 1], A = amplitude (default 3 mm):
//   twist about the z axis through c, angle θ(s) = (A / 30 mm) · s rad (A at a 30 mm radius at
//   the ends):      u_twist = (x cos θ − y sin θ − x,  x sin θ + y cos θ − y,  0)
//   bending in the x–z plane (Euler–Bernoulli: plane sections stay plane and normal to the
//   bent axis):     u_bend  = (A · s²,  0,  −2 A · s · x / L)
//   u = u_twist + u_bend.
// It is smooth (polynomial and trigonometric), rotates the surface locally (so the mapping's
// normals and offsets matter, not only its barycentric weights) and has displacements of a few mm.
#include "formats/volume_io.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"
#include "libmodel/mesh.h"
#include "libmodel/phantom.h"
#include "libmodel/select.h"
#include "libmodel/simulation_surface.h"
#include "libmodel/surface.h"

#include <sys/resource.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

using namespace heartsim;
using Clock = std::chrono::steady_clock;

namespace {

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// CPU seconds (user + system) of this process, all threads: less disturbed than wall time by
/// other jobs on a shared machine (they take cores away, not cycles of work).
double cpu_seconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return double(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) + 1e-6 * double(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

struct Field {
    Eigen::Vector3d centre;
    double half_length = 1.0;  ///< L, mm
    double amplitude = 3.0;    ///< A, mm

    Eigen::Vector3d operator()(const Eigen::Vector3d& p) const {
        const Eigen::Vector3d q = p - centre;
        const double s = q.z() / half_length;
        const double theta = amplitude / 30.0 * s;
        const double c = std::cos(theta), sn = std::sin(theta);
        Eigen::Vector3d u(q.x() * c - q.y() * sn - q.x(), q.x() * sn + q.y() * c - q.y(), 0.0);
        u += Eigen::Vector3d(amplitude * s * s, 0.0, -2.0 * amplitude * s * q.x() / half_length);
        return u;
    }
};

struct Input {
    std::string name;
    LabelVolume volume;
};

struct Row {
    std::string name;
    std::string spacing_label;   ///< "1", "1.5", ... or "default (1.42)"
    double spacing = 0;
    std::size_t particles = 0;
    std::size_t simsurface_triangles = 0;
    std::size_t boundary_particles = 0;
    std::size_t visual_vertices = 0;
    double layout_s = 0, simsurface_s = 0, map_s = 0;
    double simsurface_cpu_s = 0, map_cpu_s = 0;  ///< CPU seconds, all threads
    double mean_u = 0, max_u = 0;
    double mean = 0, rms = 0, p99 = 0, max = 0;
    std::size_t over_1mm = 0;   ///< visual vertices with error above 1 mm
    double rest_max = 0;        ///< max rest error of the mapping (report), mm
    double mean_offset = 0, max_offset = 0;
    std::size_t outside = 0, unsolved = 0, unstable = 0;
    std::size_t warnings = 0;
};

std::vector<std::filesystem::path> find_real(const std::filesystem::path& root) {
    std::vector<std::filesystem::path> found;
    if (std::filesystem::is_regular_file(root)) return {root};
    if (!std::filesystem::is_directory(root)) return found;
    for (const auto& dir : std::filesystem::recursive_directory_iterator(root)) {
        const std::string name = dir.path().filename().string();
        if (dir.is_regular_file() && name.size() > 16 && name.ends_with("-label.nii.gz")) found.push_back(dir.path());
    }
    std::sort(found.begin(), found.end());
    return found;
}

std::string case_name(const std::filesystem::path& path) {
    std::string name = path.filename().string();
    name = name.substr(0, name.size() - std::string("-label.nii.gz").size());
    const auto pat = name.rfind("pat");
    return pat == std::string::npos ? name : name.substr(pat);
}

/// One spacing on one case. `spacing` 0 = the default budget of 30 000 particles.
Row run_one(const std::string& name, const LabelVolume& volume, const Selection& selection, const std::vector<Eigen::Vector3d>& visual,
            const Field& field, double spacing) {
    Row row;
    row.name = name;
    LayoutOptions layout;
    layout.spacing_mm = spacing;
    auto t0 = Clock::now();
    LayoutReport layout_report;
    const Lattice lattice = layout_particles(selection, {1}, volume, layout, null_progress(), &layout_report);
    row.layout_s = seconds_since(t0);
    row.spacing = lattice.spacing;
    char label[64];
    if (spacing > 0) std::snprintf(label, sizeof label, "%g", spacing);
    else std::snprintf(label, sizeof label, "default (%.2f)", lattice.spacing);
    row.spacing_label = label;
    row.particles = lattice.particles.size();

    t0 = Clock::now();
    double cpu0 = cpu_seconds();
    SimulationSurfaceReport surface_report;
    const SimulationSurface surface = build_simulation_surface(lattice, null_progress(), &surface_report);
    row.simsurface_s = seconds_since(t0);
    row.simsurface_cpu_s = cpu_seconds() - cpu0;
    row.simsurface_triangles = surface.size();
    row.boundary_particles = surface_report.boundary_particles;

    MappingOptions options;
    options.lattice_spacing_mm = lattice.spacing;
    MappingReport report;
    t0 = Clock::now();
    cpu0 = cpu_seconds();
    const VisualMapping mapping = map_visual_mesh(visual, lattice.particles.rest_position, surface, options, null_progress(), &report);
    row.map_s = seconds_since(t0);
    row.map_cpu_s = cpu_seconds() - cpu0;
    row.rest_max = report.max_rest_error_mm;
    row.mean_offset = report.mean_offset_mm;
    row.max_offset = report.max_offset_mm;
    row.outside = report.outside_triangle;
    row.unsolved = report.unsolved;
    row.unstable = report.unstable_normal;
    row.warnings = report.warnings.size() + surface_report.warnings.size();
    row.visual_vertices = visual.size();

    // Deform the particles by u and map; compare with u on the visual vertices.
    std::vector<std::array<float, 3>> moved = lattice.particles.rest_position;
    for (auto& p : moved) {
        const Eigen::Vector3d x(p[0], p[1], p[2]);
        const Eigen::Vector3d y = x + field(x);
        p = {float(y.x()), float(y.y()), float(y.z())};
    }
    const std::vector<Eigen::Vector3f> mapped = apply_mapping(mapping, moved, surface);
    std::vector<double> errors(visual.size());
    double sum = 0, sum2 = 0, sum_u = 0;
    for (std::size_t v = 0; v < visual.size(); ++v) {
        const Eigen::Vector3d u = field(visual[v]);
        const Eigen::Vector3d truth = visual[v] + u;
        const double e = (mapped[v].cast<double>() - truth).norm();
        errors[v] = e;
        if (e > 1.0) ++row.over_1mm;
        sum += e;
        sum2 += e * e;
        sum_u += u.norm();
        row.max_u = std::max(row.max_u, u.norm());
    }
    const double n = double(visual.size());
    row.mean = sum / n;
    row.rms = std::sqrt(sum2 / n);
    row.mean_u = sum_u / n;
    std::vector<double> sorted = errors;
    const std::size_t k99 = std::min(sorted.size() - 1, std::size_t(std::ceil(0.99 * n)) - 1);
    std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(k99), sorted.end());
    row.p99 = sorted[k99];
    row.max = *std::max_element(errors.begin(), errors.end());
    return row;
}

void print_header() {
    std::printf("| case | spacing mm | particles | simsurface triangles | visual vertices | mean error mm | RMS error mm | p99 error mm "
                "| max error mm | vertices > 1 mm | mean abs(u) mm | max abs(u) mm | mean error / mean abs(u) | layout s | simsurface s | map s | map CPU s | mean abs(offset) mm | max abs(offset) mm "
                "| extrapolated | unstable normal | unsolved |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
}

void print_row(const Row& r) {
    std::printf("| %s | %s | %zu | %zu | %zu | %.3f | %.3f | %.3f | %.3f | %zu | %.2f | %.2f | %.1f %% | %.3f | %.3f | %.3f | %.3f | %.2f | %.2f | %zu | %zu | %zu |\n",
                r.name.c_str(), r.spacing_label.c_str(), r.particles, r.simsurface_triangles, r.visual_vertices, r.mean, r.rms, r.p99,
                r.max, r.over_1mm, r.mean_u, r.max_u, 100 * r.mean / r.mean_u, r.layout_s, r.simsurface_s, r.map_s, r.map_cpu_s, r.mean_offset, r.max_offset, r.outside,
                r.unstable, r.unsolved);
    std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::filesystem::path> real_args;
    bool use_real = true, use_phantom = true;
    std::filesystem::path out = "/tmp/heartsim-bench";
    double amplitude = 3.0;
    int threads = 2;
    for (int a = 1; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--real" && a + 1 < argc) real_args.emplace_back(argv[++a]);
        else if (arg == "--no-real") use_real = false;
        else if (arg == "--no-phantom") use_phantom = false;
        else if (arg == "--out" && a + 1 < argc) out = argv[++a];
        else if (arg == "--amplitude" && a + 1 < argc) amplitude = std::stod(argv[++a]);
        else if (arg == "--threads" && a + 1 < argc) threads = std::stoi(argv[++a]);
        else {
            std::cerr << "usage: mapping_bench [--real DIR_OR_FILE]... [--no-real] [--no-phantom] [--out DIR] [--amplitude MM] [--threads N]\n";
            return 2;
        }
    }
    tbb::global_control control(tbb::global_control::max_allowed_parallelism, std::size_t(threads));

    std::vector<std::filesystem::path> real;
    if (use_real) {
        if (real_args.empty()) real_args.emplace_back(HEARTSIM_REAL_DATA);
        for (const auto& r : real_args) {
            const auto found = find_real(r);
            if (found.empty()) std::printf("real cases: nothing (*-label.nii.gz) at %s, skipped\n", r.string().c_str());
            real.insert(real.end(), found.begin(), found.end());
        }
    }

    std::filesystem::create_directories(out);
    const std::filesystem::path csv_path = out / "mapping_bench.csv";
    std::ofstream csv(csv_path);
    csv << "case,spacing_mm,spacing_label,particles,simsurface_triangles,boundary_particles,visual_vertices,mean_u_mm,max_u_mm,"
           "mean_error_mm,rms_error_mm,p99_error_mm,max_error_mm,vertices_over_1mm,rest_max_error_mm,layout_s,simsurface_s,map_s,simsurface_cpu_s,map_cpu_s,mean_abs_offset_mm,"
           "max_abs_offset_mm,extrapolated,unstable_normal,unsolved,warnings\n";

    std::printf("## Mapping error against particle spacing\n\n");
    std::printf("threads (TBB): %d; amplitude A = %g mm (twist %g rad at the ends, bending %g mm at the ends)\n\n", threads, amplitude,
                amplitude / 30.0, amplitude);

    std::vector<std::pair<std::string, std::optional<std::filesystem::path>>> cases;
    if (use_phantom) cases.emplace_back("phantom", std::nullopt);
    for (const auto& r : real) cases.emplace_back(case_name(r), r);

    std::vector<Row> rows;
    for (const auto& [name, path] : cases) {
        LabelVolume volume = path ? read_label_volume(*path) : make_phantom(PhantomOptions{});
        const Selection selection = select_tissue(volume, {});
        const auto t0 = Clock::now();
        const TriangleMesh mesh = extract_surface(selection.tissue, {});
        const double surface_s = seconds_since(t0);
        // The scenario stores the visual mesh in float32: map those positions, as heartprep does.
        std::vector<Eigen::Vector3d> visual;
        visual.reserve(mesh.positions.size());
        for (const auto& p : mesh.positions) visual.push_back(p.cast<float>().cast<double>());
        const auto box = bounds(mesh);
        Field field;
        field.centre = (box[0] + box[1]) / 2;
        field.half_length = (box[1].z() - box[0].z()) / 2;
        field.amplitude = amplitude;
        std::printf("%s: %zu visual vertices, %zu triangles (surface %.2f s); z half-extent L = %.1f mm, centre (%.1f, %.1f, %.1f) LPS mm\n",
                    name.c_str(), visual.size(), mesh.triangles.size(), surface_s, field.half_length, field.centre.x(), field.centre.y(),
                    field.centre.z());
        for (double spacing : {1.0, 1.5, 2.0, 3.0, 4.0, 0.0}) {
            Row r;
            try {
                r = run_one(name, volume, selection, visual, field, spacing);
            } catch (const std::exception& e) {
                std::printf("%s at spacing %g: failed: %s\n", name.c_str(), spacing, e.what());
                continue;
            }
            std::fprintf(stderr, "  %s spacing %s: %zu particles, mean error %.3f mm, map %.2f s\n", r.name.c_str(), r.spacing_label.c_str(),
                         r.particles, r.mean, r.map_s);
            rows.push_back(r);
            csv << r.name << "," << r.spacing << "," << r.spacing_label << "," << r.particles << "," << r.simsurface_triangles << ","
                << r.boundary_particles << "," << r.visual_vertices << "," << r.mean_u << "," << r.max_u << "," << r.mean << "," << r.rms
                << "," << r.p99 << "," << r.max << "," << r.over_1mm << "," << r.rest_max << "," << r.layout_s << "," << r.simsurface_s << "," << r.map_s << "," << r.simsurface_cpu_s << "," << r.map_cpu_s << ","
                << r.mean_offset << "," << r.max_offset << "," << r.outside << "," << r.unstable << "," << r.unsolved << "," << r.warnings
                << "\n";
        }
    }
    std::printf("\n");
    print_header();
    for (const Row& r : rows) print_row(r);
    std::printf("\nwrote %s\n", csv_path.string().c_str());
    return 0;
}
