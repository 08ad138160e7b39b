/// @file select.h
/// @brief Which voxels of a label map become simulated tissue, which are cavities, which
/// anchor the tissue; detached islands below a size are dropped and reported.
#pragma once

#include "libmodel/progress.h"
#include "libmodel/volume.h"

#include <string>
#include <vector>

namespace heartsim {

struct SelectionOptions {
    std::vector<int> tissue_labels{1};  ///< labels that become tissue (HVSMR: 1 = myocardium)
    std::vector<int> cavity_labels;     ///< labels of blood-filled cavities (HVSMR: 2), reported
    std::vector<int> anchor_labels;     ///< tissue touching voxels of these labels is anchored
    /// Anchor tissue where it touches the volume border (vessels cut by the crop).
    bool anchor_border = false;
    /// 6-connected tissue islands smaller than this are dropped, mm³. 0 keeps everything.
    double min_island_mm3 = 100.0;
};

/// A tissue island: one 6-connected component of the selected tissue.
struct Island {
    std::size_t voxels = 0;
    double volume_mm3 = 0.0;
    std::array<int, 3> first_voxel{0, 0, 0};  ///< lowest voxel index (i,j,k) in scan order
    bool kept = true;
};

struct SelectionReport {
    std::vector<Island> islands;        ///< largest first
    std::size_t islands_dropped = 0;
    std::size_t voxels_dropped = 0;
    std::size_t tissue_voxels = 0;      ///< after dropping islands
    std::size_t cavity_voxels = 0;
    std::size_t anchor_voxels = 0;
    double tissue_volume_mm3 = 0.0;
    double cavity_volume_mm3 = 0.0;
    std::vector<std::string> warnings;
};

/// The selection on the label map's grid.
struct Selection {
    Mask tissue;   ///< tissue voxels kept, on the label map's grid
    Mask anchors;  ///< voxels that anchor the tissue particles whose cells contain them
};

/// Selects tissue and anchors. Throws InputError when a requested label does not occur in the
/// volume, when a label is both tissue and cavity, or when nothing is selected after dropping
/// islands (message names the labels and the voxel counts found).
Selection select_tissue(const LabelVolume& volume, const SelectionOptions& options = {},
                        Progress& progress = null_progress(), SelectionReport* report = nullptr);

}  // namespace heartsim
