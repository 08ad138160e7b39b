/// @file surface.h
/// @brief The visual surface of a tissue mask: marching cubes at full voxel resolution,
/// non-shrinking windowed-sinc smoothing (3D Slicer's default pipeline), optional decimation.
#pragma once

#include "libmodel/mesh.h"
#include "libmodel/progress.h"
#include "libmodel/volume.h"

#include <string>
#include <vector>

namespace heartsim {

struct SurfaceOptions {
    /// Smoothing strength in [0, 1] as 3D Slicer's "smoothing factor": windowed-sinc pass band
    /// 10^(−4·factor). 0 turns smoothing off. Slicer's default is 0.5.
    double smoothing_factor = 0.5;
    /// Windowed-sinc iterations (degree of the Chebyshev filter); Slicer uses 20.
    int smoothing_iterations = 20;
    /// Fraction of triangles to remove by edge-collapse decimation (CGAL), in [0, 1). 0 = none.
    double decimation = 0.0;
};

struct SurfaceReport {
    std::size_t marching_cubes_triangles = 0;
    std::size_t triangles = 0;
    std::size_t vertices = 0;
    double seconds_marching_cubes = 0.0;
    double seconds_smoothing = 0.0;
    double seconds_decimation = 0.0;
    std::vector<std::string> warnings;
};

/// Marching cubes on `mask` at iso-level 0.5, vertices at edge midpoints, in world coordinates.
/// The mask is treated as padded with zeros, so the surface is closed even where the mask
/// touches the volume border. Ambiguous faces are resolved by a rule that depends on the face's
/// four corners alone, so neighbouring cells agree and the result is a closed, oriented
/// 2-manifold (triangles counter-clockwise seen from outside the mask). Empty mask -> empty mesh.
TriangleMesh marching_cubes(const Mask& mask, Progress& progress = null_progress());

/// Windowed-sinc low-pass filter of the vertex positions (Taubin et al. 1996; the filter of
/// vtkWindowedSincPolyDataFilter): `iterations` Chebyshev terms, Hamming window, pass band in
/// (0, 2). Does not shrink: constants and the mean are preserved. Topology unchanged.
void smooth_windowed_sinc(TriangleMesh& mesh, int iterations, double pass_band,
                          Progress& progress = null_progress());

/// Removes about `fraction` of the triangles by edge collapse with Garland–Heckbert quadrics
/// (CGAL), keeping the mesh closed and 2-manifold. Throws InputError if the mesh is not a closed
/// 2-manifold to begin with.
void decimate(TriangleMesh& mesh, double fraction, Progress& progress = null_progress());

/// The whole stage: marching cubes, smoothing, decimation, vertex normals.
TriangleMesh extract_surface(const Mask& mask, const SurfaceOptions& options = {},
                             Progress& progress = null_progress(), SurfaceReport* report = nullptr);

}  // namespace heartsim
