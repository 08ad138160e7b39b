#include "libmodel/select.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <sstream>
#include <map>

namespace heartsim {

namespace {

/// "1,2,5"; past 24 values the first 12 and the count: a volume of every byte value (not a label
/// map: an image, or a data file that is not the header's) gets one line, not hundreds of numbers.
std::string join(const std::vector<int>& values) {
    constexpr std::size_t most = 24, shown = 12;
    std::ostringstream out;
    const std::size_t count = values.size() > most ? shown : values.size();
    for (std::size_t n = 0; n < count; ++n) out << (n ? "," : "") << values[n];
    if (count < values.size()) out << ", ... (" << values.size() << " different values: is this a label map?)";
    return out.str();
}

/// Labels the 6-connected components of `mask`: returns per-voxel component ids (−1 outside) and
/// appends one Island per component. Breadth-first with an explicit queue: no recursion depth to blow.
std::vector<std::int32_t> label_components(const Mask& mask, std::vector<Island>& islands) {
    const auto& g = mask.geometry;
    std::vector<std::int32_t> component(g.voxel_count(), -1);
    std::vector<std::size_t> queue;
    const std::ptrdiff_t stride_j = g.dims[0], stride_k = std::ptrdiff_t(g.dims[0]) * g.dims[1];
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                std::size_t seed = g.linear(i, j, k);
                if (!mask.values[seed] || component[seed] >= 0) continue;
                const auto id = std::int32_t(islands.size());
                Island island;
                island.first_voxel = {i, j, k};
                queue.assign(1, seed);
                component[seed] = id;
                for (std::size_t head = 0; head < queue.size(); ++head) {
                    const std::size_t v = queue[head];
                    const int vi = int(v % g.dims[0]);
                    const int vj = int((v / g.dims[0]) % g.dims[1]);
                    const int vk = int(v / stride_k);
                    auto visit = [&](bool inside, std::ptrdiff_t offset) {
                        if (!inside) return;
                        std::size_t w = std::size_t(std::ptrdiff_t(v) + offset);
                        if (mask.values[w] && component[w] < 0) {
                            component[w] = id;
                            queue.push_back(w);
                        }
                    };
                    visit(vi > 0, -1);
                    visit(vi + 1 < g.dims[0], 1);
                    visit(vj > 0, -stride_j);
                    visit(vj + 1 < g.dims[1], stride_j);
                    visit(vk > 0, -stride_k);
                    visit(vk + 1 < g.dims[2], stride_k);
                }
                island.voxels = queue.size();
                islands.push_back(island);
            }
    return component;
}

}  // namespace

Selection select_tissue(const LabelVolume& volume, const SelectionOptions& options, Progress& progress,
                        SelectionReport* report_out) {
    const auto& g = volume.geometry;
    if (options.tissue_labels.empty()) throw OptionError("no tissue labels given ({SelectionOptions::tissue_labels})");
    for (int label : options.tissue_labels)
        if (std::find(options.cavity_labels.begin(), options.cavity_labels.end(), label) != options.cavity_labels.end())
            throw OptionError("label " + std::to_string(label) + " is given both as tissue and as cavity");
    // Label 0 is the background of every label map (HVSMR, 3D Slicer, ITK-SNAP): as tissue it
    // would simulate the air around the heart, as a cavity fill everything outside it.
    for (const auto* labels : {&options.tissue_labels, &options.cavity_labels})
        if (std::find(labels->begin(), labels->end(), 0) != labels->end())
            throw OptionError(std::string(labels == &options.tissue_labels ? "{SelectionOptions::tissue_labels}" : "{SelectionOptions::cavity_labels}") +
                             ": label 0 is the background of a label map, not a structure; give the labels of the heart");
    ProgressStage stage(progress, "select tissue", 3);
    // Roles per label through a lookup table for the usual label range (label maps are 8- or
    // 16-bit), a search only for labels outside it: one pass over a 57-million-voxel volume
    // must not hash every voxel.
    constexpr std::int32_t table_size = 65536;
    enum Role : std::uint8_t { tissue_role = 1, cavity_role = 2, anchor_role = 4 };
    std::vector<std::uint8_t> role_table(table_size, 0);
    for (int label : options.tissue_labels) if (label >= 0 && label < table_size) role_table[std::size_t(label)] |= tissue_role;
    for (int label : options.cavity_labels) if (label >= 0 && label < table_size) role_table[std::size_t(label)] |= cavity_role;
    for (int label : options.anchor_labels) if (label >= 0 && label < table_size) role_table[std::size_t(label)] |= anchor_role;
    auto role_of = [&](std::int32_t value) -> std::uint8_t {
        if (value >= 0 && value < table_size) return role_table[std::size_t(value)];
        auto in = [&](const std::vector<int>& labels) { return std::find(labels.begin(), labels.end(), value) != labels.end(); };
        return std::uint8_t((in(options.tissue_labels) ? tissue_role : 0) | (in(options.cavity_labels) ? cavity_role : 0) |
                            (in(options.anchor_labels) ? anchor_role : 0));
    };

    std::vector<std::size_t> histogram(table_size, 0);
    std::map<std::int32_t, std::size_t> other_labels;
    for (std::int32_t label : volume.labels) {
        if (label >= 0 && label < table_size) ++histogram[std::size_t(label)];
        else ++other_labels[label];
    }
    auto occurs = [&](int label) {
        return label >= 0 && label < table_size ? histogram[std::size_t(label)] > 0 : other_labels.count(label) > 0;
    };
    auto require_present = [&](const std::vector<int>& labels, const char* role) {
        for (int label : labels) {
            if (occurs(label)) continue;
            std::vector<int> present;
            for (std::int32_t value = 0; value < table_size; ++value)
                if (histogram[std::size_t(value)]) present.push_back(value);
            for (const auto& [value, count] : other_labels) present.push_back(value);
            std::sort(present.begin(), present.end());
            throw InputError(std::string(role) + " label " + std::to_string(label) +
                             " does not occur in the volume (labels present: " + join(present) + ")");
        }
    };
    require_present(options.tissue_labels, "tissue");
    require_present(options.cavity_labels, "cavity");
    require_present(options.anchor_labels, "anchor");

    Selection selection;
    selection.tissue.geometry = g;
    selection.tissue.values.resize(g.voxel_count());
    SelectionReport report;
    for (std::size_t v = 0; v < volume.labels.size(); ++v) {
        const std::uint8_t role = role_of(volume.labels[v]);
        selection.tissue.values[v] = (role & tissue_role) ? 1 : 0;
        report.cavity_voxels += (role & cavity_role) ? 1 : 0;
    }
    stage.update(1);
    if (progress.cancelled()) throw Cancelled();

    // Islands: drop the small ones, report all.
    auto component = label_components(selection.tissue, report.islands);
    const double voxel_volume = g.voxel_volume();
    std::vector<std::uint8_t> keep(report.islands.size(), 1);
    for (std::size_t c = 0; c < report.islands.size(); ++c) {
        auto& island = report.islands[c];
        island.volume_mm3 = double(island.voxels) * voxel_volume;
        island.kept = island.volume_mm3 >= options.min_island_mm3;
        keep[c] = island.kept;
        if (!island.kept) {
            ++report.islands_dropped;
            report.voxels_dropped += island.voxels;
        }
    }
    for (std::size_t v = 0; v < component.size(); ++v)
        if (component[v] >= 0 && !keep[std::size_t(component[v])]) selection.tissue.values[v] = 0;
    std::stable_sort(report.islands.begin(), report.islands.end(),
                     [](const Island& a, const Island& b) { return a.voxels > b.voxels; });
    stage.update(2);

    report.tissue_voxels = selection.tissue.count();
    if (report.tissue_voxels == 0) {
        std::ostringstream message;
        message << "empty selection: tissue labels " << join(options.tissue_labels) << " have "
                << report.voxels_dropped << " voxels, all in islands smaller than {SelectionOptions::min_island_mm3} "
                << options.min_island_mm3 << " mm³";
        throw InputError(message.str());
    }
    report.tissue_volume_mm3 = double(report.tissue_voxels) * voxel_volume;
    report.cavity_volume_mm3 = double(report.cavity_voxels) * voxel_volume;

    // Whether each kept island is held (anchors, supports) is decided on the lattice, where
    // pieces are what moves: libmodel/supports.h drop_free_pieces.

    // Anchors: voxels of anchor labels, and tissue voxels on the volume border.
    selection.anchors.geometry = g;
    selection.anchors.values.assign(g.voxel_count(), 0);
    for (int k = 0; k < g.dims[2]; ++k)
        for (int j = 0; j < g.dims[1]; ++j)
            for (int i = 0; i < g.dims[0]; ++i) {
                const std::size_t v = g.linear(i, j, k);
                const bool on_border = i == 0 || j == 0 || k == 0 || i + 1 == g.dims[0] ||
                                       j + 1 == g.dims[1] || k + 1 == g.dims[2];
                if ((role_of(volume.labels[v]) & anchor_role) || (options.anchor_border && on_border && selection.tissue.values[v]))
                    selection.anchors.values[v] = 1;
            }
    report.anchor_voxels = selection.anchors.count();
    if (options.anchor_border && report.anchor_voxels == 0 && options.anchor_labels.empty())
        report.warnings.push_back("{SelectionOptions::anchor_border}: the tissue does not touch the volume border; nothing is anchored");
    stage.update(3);

    if (report_out) *report_out = std::move(report);
    return selection;
}

}  // namespace heartsim
