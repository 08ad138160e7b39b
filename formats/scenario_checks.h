/// @file scenario_checks.h
/// @brief The element checks the scenario reader applies to whole datasets, each failure naming the
/// dataset and the entry. Used by scenario*.cpp; not a public header.
#pragma once

#include "formats/hdf5_io.h"
#include "libmodel/plausible.h"

#include <cstdint>
#include <string>
#include <vector>

namespace heartsim {

/// Refuses the first entry of dataset `name` outside its plausible range (libmodel/plausible.h).
template <class T>
void require_plausible(const h5::Reader& r, const std::string& name, const std::vector<T>& values, const plausible::Range& range) {
    for (std::size_t n = 0; n < values.size(); ++n)
        if (!range.contains(double(values[n]))) r.fail(name, plausible::outside("entry " + std::to_string(n), double(values[n]), range));
}

/// Refuses the first entry of dataset `name` outside [0, limit): an index into a table of `limit` rows.
inline void require_indices(const h5::Reader& r, const std::string& name, const std::vector<std::int32_t>& values, std::size_t limit) {
    for (std::size_t n = 0; n < values.size(); ++n)
        if (values[n] < 0 || std::size_t(values[n]) >= limit)
            r.fail(name, "entry " + std::to_string(n) + " is " + std::to_string(values[n]) + ", outside [0, " +
                             std::to_string(limit) + ")");
}

}  // namespace heartsim
