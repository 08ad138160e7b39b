#include "libmodel/volume.h"

#include <algorithm>

namespace heartsim {

std::size_t Mask::count() const {
    return std::size_t(std::count_if(values.begin(), values.end(), [](std::uint8_t v) { return v != 0; }));
}

}  // namespace heartsim
