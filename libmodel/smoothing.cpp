/// @file smoothing.cpp
/// @brief Windowed-sinc smoothing (Taubin, Zhang & Golub 1996, "Optimal surface smoothing as
/// filter design"), the filter of vtkWindowedSincPolyDataFilter that 3D Slicer applies.
#include "libmodel/errors.h"
#include "libmodel/surface.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

namespace heartsim {

namespace {

/// Edge neighbours of every vertex, compressed rows (sorted, without repeats).
struct VertexNeighbours {
    std::vector<std::size_t> first;  ///< #V + 1 offsets into `ids`
    std::vector<std::int32_t> ids;
};

VertexNeighbours edge_neighbours(const TriangleMesh& mesh) {
    const std::size_t vertex_count = mesh.positions.size();
    VertexNeighbours neighbours;
    neighbours.first.assign(vertex_count + 1, 0);
    for (const auto& t : mesh.triangles)
        for (int c = 0; c < 3; ++c) neighbours.first[std::size_t(t[c]) + 1] += 2;
    for (std::size_t v = 0; v < vertex_count; ++v) neighbours.first[v + 1] += neighbours.first[v];
    std::vector<std::int32_t> candidates(neighbours.first.back());
    std::vector<std::size_t> fill(neighbours.first.begin(), neighbours.first.end() - 1);
    for (const auto& t : mesh.triangles)
        for (int c = 0; c < 3; ++c) {
            candidates[fill[std::size_t(t[c])]++] = t[(c + 1) % 3];
            candidates[fill[std::size_t(t[c])]++] = t[(c + 2) % 3];
        }
    // Each edge of a closed mesh appears twice around a vertex; keep it once.
    neighbours.ids.reserve(candidates.size() / 2);
    std::vector<std::size_t> unique_first(vertex_count + 1, 0);
    for (std::size_t v = 0; v < vertex_count; ++v) {
        auto begin = candidates.begin() + std::ptrdiff_t(neighbours.first[v]);
        auto end = candidates.begin() + std::ptrdiff_t(neighbours.first[v + 1]);
        std::sort(begin, end);
        end = std::unique(begin, end);
        for (auto it = begin; it != end; ++it)
            if (*it != std::int32_t(v)) neighbours.ids.push_back(*it);
        unique_first[v + 1] = neighbours.ids.size();
    }
    neighbours.first = std::move(unique_first);
    return neighbours;
}

/// Filter weights f_i = w_i·c_i(θ_PB + σ) of Σ f_i T_i(1 − k/2), k the frequency (eigenvalue of
/// −Δ, in [0, 2]): Chebyshev coefficients of the ideal low-pass filter with cut-off θ
/// (c_0 = θ/π, c_i = 2 sin(iθ)/(iπ), θ_PB = acos(1 − k_PB/2)) times the Hamming window
/// w_i = 0.54 + 0.46 cos(iπ/(N+1)).
///
/// As vtkWindowedSincPolyDataFilter does, the cut-off is shifted by σ (Newton's method) until the
/// filter passes the pass-band edge k_PB with gain 1. Without that shift a 20-term filter cannot
/// resolve a pass band as narrow as Slicer's 0.01 (θ_PB ≈ 0.1 rad, narrower than the window's
/// main lobe) and attenuates even the lowest modes: a sphere of radius 20 voxels lost 9% of its
/// volume. Finally the weights are scaled to sum to 1, so the filter passes constants exactly
/// (translation invariance; VTK leaves a gain of about 1.001 there).
std::vector<double> filter_weights(int iterations, double pass_band) {
    const double pi = std::numbers::pi;
    const double theta = std::acos(1.0 - 0.5 * pass_band);
    std::vector<double> window(std::size_t(iterations) + 1), weights(std::size_t(iterations) + 1);
    for (int i = 0; i <= iterations; ++i) window[std::size_t(i)] = 0.54 + 0.46 * std::cos(i * pi / (iterations + 1));
    auto set_weights = [&](double cutoff) {
        for (int i = 0; i <= iterations; ++i)
            weights[std::size_t(i)] = window[std::size_t(i)] * (i == 0 ? cutoff / pi : 2.0 * std::sin(i * cutoff) / (i * pi));
    };

    // Newton's method on gain(σ) = Σ f_i(σ) cos(iθ_PB) = 1; VTK's tolerance and iteration cap.
    double sigma = 0.0;
    set_weights(theta);
    for (int step = 0; iterations > 1 && step < 500; ++step) {
        double gain = 0.0, gain_derivative = 0.0;
        for (int i = 0; i <= iterations; ++i) {
            gain += weights[std::size_t(i)] * std::cos(i * theta);
            const double coefficient_derivative = i == 0 ? 1.0 / pi : 2.0 * std::cos(i * (theta + sigma)) / pi;
            gain_derivative += window[std::size_t(i)] * coefficient_derivative * std::cos(i * theta);
        }
        if (std::abs(gain - 1.0) < 1e-3 || gain_derivative == 0.0) break;
        sigma -= (gain - 1.0) / gain_derivative;
        set_weights(theta + sigma);
    }

    double sum = 0.0;
    for (double weight : weights) sum += weight;
    for (double& weight : weights) weight /= sum;
    return weights;
}

}  // namespace

void smooth_windowed_sinc(TriangleMesh& mesh, int iterations, double pass_band, Progress& progress) {
    if (iterations < 1) throw InputError("windowed-sinc smoothing: iterations must be at least 1, got " + std::to_string(iterations));
    if (!(pass_band > 0.0 && pass_band < 2.0))
        throw InputError("windowed-sinc smoothing: pass band must lie in (0, 2), got " + std::to_string(pass_band));
    const std::size_t vertex_count = mesh.positions.size();
    if (vertex_count == 0 || mesh.triangles.empty()) return;

    ProgressStage stage(progress, "smoothing", std::uint64_t(iterations));
    const VertexNeighbours neighbours = edge_neighbours(mesh);
    const std::vector<double> weights = filter_weights(iterations, pass_band);

    // Work in a unit box about the centre (VTK's NormalizeCoordinates): the filter is linear and
    // commutes with this affine map, but sums of far-off, large coordinates lose digits.
    const auto box = bounds(mesh);
    const Eigen::Vector3d centre = 0.5 * (box[0] + box[1]);
    const double extent = (box[1] - box[0]).maxCoeff();
    const double scale = extent > 0.0 ? 1.0 / extent : 1.0;

    std::vector<Eigen::Vector3d> previous(vertex_count), current(vertex_count), next(vertex_count), result(vertex_count);
    auto for_vertices = [&](auto&& body) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, vertex_count, 4096),
                          [&](const tbb::blocked_range<std::size_t>& range) {
                              for (std::size_t v = range.begin(); v != range.end(); ++v) body(v);
                          });
    };
    // Umbrella operator Δx_v = mean of the neighbours − x_v; eigenvalues of −Δ lie in [0, 2].
    auto umbrella = [&](const std::vector<Eigen::Vector3d>& x, std::size_t v) {
        const std::size_t begin = neighbours.first[v], end = neighbours.first[v + 1];
        if (begin == end) return Eigen::Vector3d(Eigen::Vector3d::Zero());
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (std::size_t n = begin; n < end; ++n) sum += x[std::size_t(neighbours.ids[n])];
        return Eigen::Vector3d(sum / double(end - begin) - x[v]);
    };

    // Chebyshev recursion of T_i(I + Δ/2): x_0 = x, x_1 = x_0 + ½Δx_0,
    // x_{n+1} = 2x_n + Δx_n − x_{n−1}; the output is Σ f_i x_i.
    for_vertices([&](std::size_t v) { previous[v] = (mesh.positions[v] - centre) * scale; });
    for_vertices([&](std::size_t v) {
        current[v] = previous[v] + 0.5 * umbrella(previous, v);
        result[v] = weights[0] * previous[v] + weights[1] * current[v];
    });
    stage.update(1);
    for (int i = 2; i <= iterations; ++i) {
        if (progress.cancelled()) throw Cancelled();
        const double weight = weights[std::size_t(i)];
        for_vertices([&](std::size_t v) {
            next[v] = 2.0 * current[v] + umbrella(current, v) - previous[v];
            result[v] += weight * next[v];
        });
        std::swap(previous, current);
        std::swap(current, next);
        stage.update(std::uint64_t(i));
    }
    for_vertices([&](std::size_t v) { mesh.positions[v] = result[v] / scale + centre; });
    if (!mesh.normals.empty()) compute_vertex_normals(mesh);
}

}  // namespace heartsim
