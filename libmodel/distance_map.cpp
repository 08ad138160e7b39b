// The exact Euclidean distance map of landmarks.h (distance_map): the square root of walls.h's
// feature transform, which finds the squared distances one grid axis at a time with that axis'
// spacing.
#include "libmodel/landmarks.h"
#include "libmodel/walls.h"

#include <cmath>

namespace heartsim {

std::vector<float> distance_map(const VolumeGeometry& geometry, const std::vector<std::uint8_t>& inside) {
    std::vector<float> distance;
    std::vector<std::int32_t> nearest;
    feature_transform(geometry.dims, geometry.spacing, inside, distance, nearest);
    for (float& d : distance) d = std::sqrt(d);  // +infinity stays +infinity where nothing is inside
    return distance;
}

}  // namespace heartsim
