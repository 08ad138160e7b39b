// Where a NIfTI file's qform and sform put the grid (nifti_placement.h).
#include "formats/nifti_placement.h"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace heartsim::volume_header_checks {
namespace {

const Eigen::Matrix3d& ras_to_lps() {
    static const Eigen::Matrix3d flip = Eigen::Vector3d(-1.0, -1.0, 1.0).asDiagonal();
    return flip;
}

/// Normalises the columns of `axes` and says whether they are orthonormal within `tolerance`.
bool normalise_columns(Eigen::Matrix3d& axes, double tolerance) {
    for (int column = 0; column < 3; ++column) {
        const double length = axes.col(column).norm();
        if (!(length > 0.0)) return false;
        axes.col(column) /= length;
    }
    return (axes * axes.transpose()).isIdentity(tolerance);
}

}  // namespace

NiftiPlacement qform_placement(const NiftiFields& fields) {
    double b = fields.orientation[0], c = fields.orientation[1], d = fields.orientation[2];
    double a = 1.0 - (b * b + c * c + d * d);
    if (a < 1e-7) {  // niftilib: a 180° rotation; renormalise (b, c, d)
        a = 1.0 / std::sqrt(b * b + c * c + d * d);
        b *= a, c *= a, d *= a;
        a = 0.0;
    } else {
        a = std::sqrt(a);
    }
    Eigen::Matrix3d rotation;
    rotation << a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c),
                2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b),
                2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - c * c - b * b;
    if (fields.pixdim[0] < 0) rotation.col(2) *= -1.0;
    NiftiPlacement placement;
    placement.rotation = normalise_columns(rotation, 1e-4);
    placement.direction = ras_to_lps() * rotation;
    placement.origin = ras_to_lps() * Eigen::Vector3d(fields.orientation[3], fields.orientation[4], fields.orientation[5]);
    return placement;
}

NiftiPlacement sform_placement(const NiftiFields& fields) {
    Eigen::Matrix3d axes;
    Eigen::Vector3d offset;
    for (int row = 0; row < 3; ++row) {
        for (int column = 0; column < 3; ++column) axes(row, column) = fields.orientation[std::size_t(6 + 4 * row + column)];
        offset[row] = fields.orientation[std::size_t(6 + 4 * row + 3)];
    }
    NiftiPlacement placement;
    placement.rotation = normalise_columns(axes, 1e-4);
    placement.direction = ras_to_lps() * axes;
    placement.origin = ras_to_lps() * offset;
    return placement;
}

std::string xform_code_name(int code) {
    switch (code) {
    case 1: return "1, scanner anatomy";
    case 2: return "2, aligned anatomy";
    case 3: return "3, Talairach";
    case 4: return "4, MNI 152";
    case 5: return "5, template";
    default: return std::to_string(code);
    }
}


PlacementDifference compare_placements(const NiftiPlacement& first, const NiftiPlacement& second, const VolumeGeometry& grid) {
    PlacementDifference difference;
    difference.origin_mm = (first.origin - second.origin).norm();
    const Eigen::Matrix3d relative = first.direction.transpose() * second.direction;
    difference.mirrored = relative.determinant() < 0.0;
    difference.angle_degrees = std::acos(std::clamp((relative.trace() - 1.0) / 2.0, -1.0, 1.0)) * 180.0 / std::numbers::pi;
    for (int corner = 0; corner < 8; ++corner) {
        const Eigen::Vector3d ijk((corner & 1) ? grid.dims[0] - 1 : 0, (corner & 2) ? grid.dims[1] - 1 : 0,
                                  (corner & 4) ? grid.dims[2] - 1 : 0);
        const Eigen::Vector3d step = grid.spacing.cwiseProduct(ijk);
        const Eigen::Vector3d a = first.origin + first.direction * step, b = second.origin + second.direction * step;
        difference.largest_mm = std::max(difference.largest_mm, (a - b).norm());
    }
    return difference;
}

}  // namespace heartsim::volume_header_checks
