/// @file surface.cpp
/// @brief The surface stage: marching cubes, windowed-sinc smoothing, decimation, normals.
#include "libmodel/surface.h"

#include "libmodel/errors.h"

#include <chrono>
#include <cmath>
#include <string>

namespace heartsim {

namespace {
double seconds_since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}
}  // namespace

TriangleMesh extract_surface(const Mask& mask, const SurfaceOptions& options, Progress& progress,
                             SurfaceReport* report) {
    if (!(options.smoothing_factor >= 0.0 && options.smoothing_factor <= 1.0))
        throw InputError("surface: smoothing factor must lie in [0, 1], got " + std::to_string(options.smoothing_factor));
    if (!(options.decimation >= 0.0 && options.decimation < 1.0))
        throw InputError("surface: decimation must lie in [0, 1), got " + std::to_string(options.decimation));
    SurfaceReport local_report;
    SurfaceReport& out = report ? *report : local_report;
    out = SurfaceReport{};

    auto start = std::chrono::steady_clock::now();
    TriangleMesh mesh = marching_cubes(mask, progress);
    out.seconds_marching_cubes = seconds_since(start);
    out.marching_cubes_triangles = mesh.triangles.size();
    if (mesh.triangles.empty()) out.warnings.push_back("the mask is empty: no surface");

    if (options.smoothing_factor > 0.0 && options.smoothing_iterations > 0 && !mesh.triangles.empty()) {
        start = std::chrono::steady_clock::now();
        // 3D Slicer's mapping from its smoothing factor to the windowed-sinc pass band.
        const double pass_band = std::pow(10.0, -4.0 * options.smoothing_factor);
        smooth_windowed_sinc(mesh, options.smoothing_iterations, pass_band, progress);
        out.seconds_smoothing = seconds_since(start);
    }
    if (options.decimation > 0.0 && !mesh.triangles.empty()) {
        start = std::chrono::steady_clock::now();
        decimate(mesh, options.decimation, progress);
        out.seconds_decimation = seconds_since(start);
    }
    compute_vertex_normals(mesh);
    out.triangles = mesh.triangles.size();
    out.vertices = mesh.positions.size();
    return mesh;
}

}  // namespace heartsim
