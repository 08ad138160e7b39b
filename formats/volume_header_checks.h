/// @file volume_header_checks.h
/// @brief Private to formats/volume_io.cpp: our own reading of a label map's raw header (NIfTI,
/// NRRD, MetaImage), for what ITK does not check or tell: the header fields ITK's readers trust,
/// where the voxel data lies and whether the file holds all of it (DESIGN.md: ITK reads truncated
/// files silently). Nothing here touches ITK, so volume_io.cpp, the one translation unit that
/// compiles ITK's headers, stays small.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>

namespace heartsim::volume_header_checks {

namespace fs = std::filesystem;

struct DataLocation {
    fs::path file;                 ///< file holding the voxel data
    std::uint64_t offset = 0;      ///< byte where the (possibly compressed) data starts
    bool compressed = false;       ///< zlib or gzip stream
    bool at_end_of_file = false;   ///< raw data is the last `bytes` bytes (NRRD byte skip -1, MetaImage HeaderSize -1)
    std::uint64_t skip_after_inflate = 0;  ///< bytes before the voxels inside a compressed stream
    bool checkable = true;         ///< false for encodings whose size we cannot verify (bzip2)
    /// Text encodings (NRRD ascii, hex): the file must hold at least this many bytes per byte of
    /// voxel data (hex: 2) or per value (ascii: 1 character), so a few bytes cannot declare gigabytes.
    enum class Text { none, ascii, hex } text = Text::none;
};

/// The fields of a NIfTI-1 or NIfTI-2 header we check ourselves: niftilib quietly replaces a zero
/// or negative pixdim by 1 and ITK reports that, so bad spacing must be caught here.
struct NiftiFields {
    int version = 1;
    std::array<std::int64_t, 8> dim{};
    int bitpix = 0;
    int datatype = 0;
    std::array<double, 8> pixdim{};
    double vox_offset = 0;
    /// quatern_b, c, d, qoffset_x, y, z, then srow_x, srow_y, srow_z (4 each): the orientation.
    std::array<double, 18> orientation{};
    int qform_code = 0;  ///< 0 unknown, 1 scanner, 2 aligned, 3 Talairach, 4 MNI 152, 5 other template
    int sform_code = 0;
};

/// Reads "key<separator>value" header lines of NRRD or MetaImage text headers.
struct TextHeader {
    std::map<std::string, std::string> fields;  ///< lower-case key -> value
    std::uint64_t end_offset = 0;               ///< byte after the header
};

/// The names of NiftiFields::orientation's entries, for messages.
std::string orientation_field(std::size_t index);

NiftiFields read_nifti_fields(const fs::path& path);

std::uint64_t nifti_data_bytes(const fs::path& path, const NiftiFields& fields);

/// NRRD: magic line, then "field: value" lines (key/values use ":=") up to a blank line.
TextHeader read_nrrd_header(const fs::path& path);

/// MetaImage: "Key = Value" lines; ElementDataFile is the last one.
TextHeader read_metaimage_header(const fs::path& path);

std::string field_or(const TextHeader& header, const std::string& key, const std::string& fallback);

long long integer_field(const fs::path& path, const TextHeader& header, const std::string& key, long long fallback);

/// Data in several files (NRRD `data file: LIST` or `data file: img%03d.raw 1 10 1`, MetaImage
/// `ElementDataFile = LIST` or a pattern): NrrdIO and MetaIO format each name with a printf pattern
/// taken from the header, and the pieces' sizes cannot be verified one by one. 3D Slicer never
/// writes it; it is refused, before ITK reads the header.
void refuse_multi_file_data(const fs::path& path, const std::string& field, const std::string& data_file);

DataLocation nrrd_data_location(const fs::path& path);

DataLocation metaimage_data_location(const fs::path& path);

/// Inflates a zlib or gzip stream (windowBits 15+32 detects which) starting at `offset`, counting
/// the bytes it yields. Returns the count; sets `clean_end` when the stream's end marker (and,
/// for gzip, its CRC) was reached; `problem` gets zlib's reason for corrupt data.
std::uint64_t inflate_count(const fs::path& path, std::uint64_t offset, bool& clean_end, std::string& problem);

/// Throws unless `location` holds at least `bytes` bytes of voxel data (compressed: a stream that
/// ends cleanly and inflates to at least that much).
void check_data_present(const fs::path& path, const DataLocation& location, std::uint64_t bytes, std::uint64_t values);

bool holds_non_finite_number(const std::string& value);

/// The leading whitespace-separated numbers of a header value ("4 4 x 4" has two).
std::size_t leading_numbers(const std::string& value);

/// ITK 5.2's MetaIO copies each header field's name into a 255-byte buffer without a bound (strcpy
/// in MET_InitReadField: a longer name overflows it; fuzz_volume_mha found glibc's fortify check
/// aborting there) and reads NDims values per array and NDims² per matrix into 4096-value buffers.
/// So a MetaImage header is checked here before ITK sees it: every line "Key = Value", every field
/// name (MetaIO's: the text before '=' or ':') and value under 255 characters, and NDims from 1 to 4.
/// Returns whether the header gives the voxel size (ElementSpacing or ElementSize).
bool check_metaimage_header_before_itk(const fs::path& path);

/// A NRRD header checked before ITK reads it: NrrdIO formats its complaints about a line into a
/// 1025-byte stack buffer with the line in it, so a 1012-character `type:` line smashed its stack
/// (fuzz_volume_nrrd's 10-minute run: glibc's stack protector aborted); field lines (comments
/// aside) are held to 500 characters. NrrdIO ends a line at a line feed, a carriage return or
/// both, so a lone carriage return inside what getline returns starts a new line: a comment line
/// with one in it hid a 1,248-character field line from this check (found by
/// fuzz_volume_nrrd). And its data file (refuse_multi_file_data). Returns whether the header gives the
/// voxel size ('spacings' or 'space directions').
bool check_nrrd_header_before_itk(const fs::path& path);

}  // namespace heartsim::volume_header_checks
