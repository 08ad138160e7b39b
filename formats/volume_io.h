/// @file volume_io.h
/// @brief Integer label maps from NIfTI (.nii, .nii.gz), NRRD (.nrrd, single-layer 3D Slicer
/// .seg.nrrd) and MetaImage (.mha, .mhd) through ITK's image I/O; world frame LPS, mm.
///
/// ITK does not protect us from bad files (DESIGN.md): a truncated .nii.gz is read silently with
/// partial data, and a float image is cast silently to integers. So before reading we probe the
/// component type (integers only), check that the file holds all the voxel data its header
/// declares (for compressed data, that the stream ends cleanly), and estimate the memory needed.
#pragma once

#include "libmodel/volume.h"

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace heartsim {

/// What a volume file's header says, read without loading the voxels.
struct VolumeHeader {
    VolumeGeometry geometry;
    std::string format;          ///< "NIfTI", "NRRD", "MetaImage"
    std::string component_type;  ///< ITK's name, e.g. "unsigned_short"
    int components = 1;          ///< values per voxel
    std::uint64_t data_bytes = 0;  ///< bytes of voxel data the header declares
    /// The separate voxel file a detached header names (NRRD `data file`, MetaImage
    /// `ElementDataFile`), as the reader opens it; empty when the voxels are in the file itself.
    /// One outside the header's folder is read, with a warning below.
    std::filesystem::path data_file;
    /// For 3D Slicer .seg.nrrd: label value -> segment name (empty otherwise).
    std::map<int, std::string> segment_names;
    /// What the reader noticed but read anyway, one line each, naming the file: a NIfTI whose
    /// qform and sform disagree (which one is used, why, and how far apart they are).
    std::vector<std::string> warnings;
};

struct VolumeReadOptions {
    /// Refuse volumes whose estimated working memory exceeds this many bytes;
    /// 0 = the machine's available memory (MemAvailable).
    std::uint64_t memory_limit_bytes = 0;
    /// Working bytes heartprep needs per voxel (labels, masks, distances); used for the estimate.
    double working_bytes_per_voxel = 16.0;
};

/// Reads the header only. Throws InputError naming the file and the problem.
VolumeHeader read_volume_header(const std::filesystem::path& path);


/// Reads an integer label map. Throws InputError naming the file and the problem for: a missing
/// or unreadable file, an unsupported format, a non-integer component type, more than one
/// component, a dimension other than 3, non-finite or non-positive spacing, a truncated file or
/// compressed stream, a volume too large for memory (estimated before allocating).
LabelVolume read_label_volume(const std::filesystem::path& path, const VolumeReadOptions& options = {},
                              VolumeHeader* header = nullptr);

/// Empty when `path` ends with an extension the label-map readers and writers know (.nii,
/// .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd); else the reason, "PATH: unsupported file type …",
/// so that a command can refuse an output name before it does any work.
std::string label_volume_path_problem(const std::filesystem::path& path);

/// The files write_label_volume(path, …) writes: `path` and, for a MetaImage `.mhd` header, the
/// data file beside it that takes the voxels (NAME.raw), so that a command can check that none of
/// them is one of its inputs before it writes.
std::vector<std::filesystem::path> label_volume_files(const std::filesystem::path& path);

/// Writes a label map (stored as unsigned 16-bit when every label fits, else signed 32-bit);
/// the format follows the extension. Atomic: temporary file, then rename. Throws OutputError.
void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume);

/// As above, naming the segments of a 3D Slicer .seg.nrrd: `segment_names` maps label value ->
/// segment name, written as Segment<N>_LabelValue / _Name / _ID / _Layer (all layer 0). Other
/// formats ignore the names. (Without names, a .seg.nrrd gets one segment "Label <v>" per label.)
void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume,
                        const std::map<int, std::string>& segment_names);

}  // namespace heartsim
