/// @file volume_header_checks.cpp
/// @brief The raw-header checks of label maps that ITK leaves out (volume_header_checks.h).
#include "formats/volume_header_checks.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <regex>
#include <sstream>
#include <string_view>

namespace heartsim::volume_header_checks {

using text::lowercase;
using text::trim;  // the header lines come from getline: no line feed inside

// ---------------------------------------------------------------------------------------------
// Where the voxel data lies, from our own reading of the raw header: ITK does not tell, and it
// reads truncated files silently (DESIGN.md).



/// The names of NiftiFields::orientation's entries, for messages.
std::string orientation_field(std::size_t index) {
    static const char* const names[6] = {"quatern_b", "quatern_c", "quatern_d", "qoffset_x", "qoffset_y", "qoffset_z"};
    if (index < 6) return names[index];
    const std::size_t row = (index - 6) / 4, column = (index - 6) % 4;
    return std::string("srow_") + char('x' + row) + "[" + std::to_string(column) + "]";
}

template <class T>
T read_value(const unsigned char* bytes, bool swap) {
    unsigned char copy[sizeof(T)];
    std::memcpy(copy, bytes, sizeof(T));
    if (swap) std::reverse(copy, copy + sizeof(T));
    T value;
    std::memcpy(&value, copy, sizeof(T));
    return value;
}

NiftiFields read_nifti_fields(const fs::path& path) {
    // gzopen reads plain files transparently, so one path serves .nii and .nii.gz.
    gzFile file = gzopen(path.c_str(), "rb");
    if (!file) throw InputError(path.string() + ": cannot open for reading");
    std::array<unsigned char, 540> header{};
    const int got = gzread(file, header.data(), unsigned(header.size()));
    gzclose(file);
    if (got < 348)
        throw InputError(path.string() + ": NIfTI header truncated: expected at least 348 bytes, file holds " +
                         std::to_string(std::max(got, 0)));
    const std::int32_t sizeof_hdr = read_value<std::int32_t>(header.data(), false);
    const std::int32_t swapped = read_value<std::int32_t>(header.data(), true);
    NiftiFields fields;
    bool swap = false;
    if (sizeof_hdr == 348 || swapped == 348) {
        swap = sizeof_hdr != 348;
        for (int d = 0; d < 8; ++d) fields.dim[d] = read_value<std::int16_t>(&header[40 + 2 * d], swap);
        fields.datatype = read_value<std::int16_t>(&header[70], swap);
        fields.bitpix = read_value<std::int16_t>(&header[72], swap);
        for (int d = 0; d < 8; ++d) fields.pixdim[d] = read_value<float>(&header[76 + 4 * d], swap);
        fields.vox_offset = read_value<float>(&header[108], swap);
        for (std::size_t i = 0; i < 18; ++i) fields.orientation[i] = read_value<float>(&header[256 + 4 * i], swap);
        fields.qform_code = read_value<std::int16_t>(&header[252], swap);
        fields.sform_code = read_value<std::int16_t>(&header[254], swap);
    } else if (sizeof_hdr == 540 || swapped == 540) {
        if (got < 540)
            throw InputError(path.string() + ": NIfTI-2 header truncated: expected 540 bytes, file holds " +
                             std::to_string(got));
        swap = sizeof_hdr != 540;
        fields.version = 2;
        fields.datatype = read_value<std::int16_t>(&header[12], swap);
        fields.bitpix = read_value<std::int16_t>(&header[14], swap);
        for (int d = 0; d < 8; ++d) fields.dim[d] = read_value<std::int64_t>(&header[16 + 8 * d], swap);
        for (int d = 0; d < 8; ++d) fields.pixdim[d] = read_value<double>(&header[104 + 8 * d], swap);
        fields.vox_offset = double(read_value<std::int64_t>(&header[168], swap));
        for (std::size_t i = 0; i < 18; ++i) fields.orientation[i] = read_value<double>(&header[352 + 8 * i], swap);
        fields.qform_code = read_value<std::int32_t>(&header[344], swap);
        fields.sform_code = read_value<std::int32_t>(&header[348], swap);
    } else {
        throw InputError(path.string() + ": not a NIfTI file: sizeof_hdr is " + std::to_string(sizeof_hdr) +
                         "; expected 348 (NIfTI-1) or 540 (NIfTI-2)");
    }
    if (fields.dim[0] < 1 || fields.dim[0] > 7)
        throw InputError(path.string() + ": NIfTI dim[0] is " + std::to_string(fields.dim[0]) +
                         "; expected a dimension count from 1 to 7");
    // niftilib refuses other codes with a line of its own on stderr, and ITK then calls the file
    // "not recognized as a NIFTI file".
    static constexpr int datatypes[] = {2, 4, 8, 16, 32, 64, 128, 256, 512, 768, 1024, 1280, 1536, 1792, 2048, 2304};
    if (std::find(std::begin(datatypes), std::end(datatypes), fields.datatype) == std::end(datatypes))
        throw InputError(path.string() + ": NIfTI datatype is " + std::to_string(fields.datatype) +
                         "; expected a NIfTI type code (2 for unsigned 8-bit labels, 4, 8, 256, 512, 768, …)");
    // A float: 1e31 or infinity cannot become a byte offset (fuzz_volume_nii found the cast).
    if (!std::isfinite(fields.vox_offset) || fields.vox_offset > 9.0e15) {
        std::ostringstream value;
        value << fields.vox_offset;
        throw InputError(path.string() + ": NIfTI vox_offset is " + value.str() +
                         "; expected the byte offset of the voxel data (a finite number of bytes)");
    }
    // ITK builds the orientation from these and pixdim and hands it to vnl_svd, which aborts the
    // process on a non-finite entry and never returns on one near the float range's end, such as
    // -1.7e38 (fuzz_volume_nii): they are checked before ITK reads the header. A kilometre is far
    // beyond any voxel or scanner coordinate (plausible.h's coordinate range).
    const plausible::Range& mm = plausible::coordinate_mm;
    for (int axis = 1; axis <= 3; ++axis) {
        const double value = fields.pixdim[std::size_t(axis)];
        if (!std::isfinite(value) || std::abs(value) > mm.high) {
            std::ostringstream text;
            text << value;
            throw InputError(path.string() + ": invalid voxel spacing along " + std::string(1, "ijk"[axis - 1]) + ": NIfTI pixdim[" +
                             std::to_string(axis) + "] is " + text.str() + "; expected a finite positive size in mm");
        }
    }
    for (std::size_t i = 0; i < fields.orientation.size(); ++i)
        if (!std::isfinite(fields.orientation[i]) || std::abs(fields.orientation[i]) > mm.high)
            throw InputError(path.string() + ": NIfTI " + plausible::outside(orientation_field(i), fields.orientation[i], mm));
    return fields;
}

std::uint64_t nifti_data_bytes(const fs::path& path, const NiftiFields& fields) {
    long double voxels = 1;
    for (int d = 1; d <= fields.dim[0]; ++d) {
        if (fields.dim[d] < 1)
            throw InputError(path.string() + ": NIfTI dim[" + std::to_string(d) + "] is " +
                             std::to_string(fields.dim[d]) + "; expected a positive voxel count");
        voxels *= fields.dim[d];
    }
    if (fields.bitpix <= 0 || fields.bitpix % 8 != 0)
        throw InputError(path.string() + ": NIfTI bitpix is " + std::to_string(fields.bitpix) +
                         "; expected a positive multiple of 8");
    const long double bytes = voxels * (fields.bitpix / 8);
    if (bytes > (long double)(std::numeric_limits<std::uint64_t>::max() / 2))
        throw InputError(path.string() + ": NIfTI dims declare an impossible amount of voxel data");
    return std::uint64_t(bytes);
}


/// NRRD: magic line, then "field: value" lines (key/values use ":=") up to a blank line.
TextHeader read_nrrd_header(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open for reading");
    std::string line;
    std::getline(in, line);
    if (line.rfind("NRRD", 0) != 0) throw InputError(path.string() + ": not a NRRD file: first line should start with NRRD");
    TextHeader header;
    for (int number = 2; std::getline(in, line); ++number) {
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty()) break;
        if (line[0] == '#' || line.find(":=") != std::string::npos) continue;
        const auto colon = line.find(": ");
        if (colon == std::string::npos) continue;
        // The NRRD format allows each field once; a second one leaves NrrdIO and this reader
        // disagreeing on what the file declares (fuzz_volume_nrrd: two `encoding` lines).
        const std::string key = lowercase(trim(line.substr(0, colon)));
        if (!header.fields.emplace(key, trim(line.substr(colon + 2))).second)
            throw InputError(path.string() + ": NRRD header line " + std::to_string(number) + " gives the field '" + key.substr(0, 40) +
                             "' a second time; a field may appear once");
    }
    // tellg is -1 at end of file (a header with no data after it).
    const auto position = in.tellg();
    header.end_offset = position < 0 ? fs::file_size(path) : std::uint64_t(position);
    return header;
}

/// MetaImage: "Key = Value" lines; ElementDataFile is the last one.
TextHeader read_metaimage_header(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open for reading");
    TextHeader header;
    std::string line;
    bool found_data_file = false;
    while (std::getline(in, line)) {
        const auto equals = line.find('=');
        if (equals == std::string::npos) continue;
        const std::string key = lowercase(trim(line.substr(0, equals)));
        header.fields[key] = trim(line.substr(equals + 1));
        if (key == "elementdatafile") {
            found_data_file = true;
            break;
        }
    }
    if (!found_data_file) throw InputError(path.string() + ": MetaImage header has no ElementDataFile line");
    const auto position = in.tellg();
    header.end_offset = position < 0 ? fs::file_size(path) : std::uint64_t(position);
    return header;
}

std::string field_or(const TextHeader& header, const std::string& key, const std::string& fallback) {
    auto found = header.fields.find(key);
    return found == header.fields.end() ? fallback : found->second;
}

long long integer_field(const fs::path& path, const TextHeader& header, const std::string& key, long long fallback) {
    const std::string text = field_or(header, key, "");
    if (text.empty()) return fallback;
    try {
        return std::stoll(text);
    } catch (const std::exception&) {
        throw InputError(path.string() + ": header field '" + key + "' is '" + text + "'; expected an integer");
    }
}

/// Data in several files (NRRD `data file: LIST` or `data file: img%03d.raw 1 10 1`, MetaImage
/// `ElementDataFile = LIST` or a pattern): NrrdIO and MetaIO format each name with a printf pattern
/// taken from the header, and the pieces' sizes cannot be verified one by one. 3D Slicer never
/// writes it; it is refused, before ITK reads the header.
void refuse_multi_file_data(const fs::path& path, const std::string& field, const std::string& data_file) {
    if (data_file.rfind("LIST", 0) == 0 || data_file.find('%') != std::string::npos || data_file.find(' ') != std::string::npos)
        throw InputError(path.string() + ": " + field + " '" + data_file +
                         "' spreads the voxels over several files (LIST or a name pattern); expected one data file "
                         "(save the volume again as a single file)");
}

DataLocation nrrd_data_location(const fs::path& path) {
    const TextHeader header = read_nrrd_header(path);
    DataLocation location;
    std::string data_file = field_or(header, "data file", field_or(header, "datafile", ""));
    if (data_file.empty()) {
        location.file = path;
        location.offset = header.end_offset;
    } else {
        refuse_multi_file_data(path, "NRRD data file", data_file);
        location.file = fs::path(data_file).is_absolute() ? fs::path(data_file) : path.parent_path() / data_file;
        location.offset = 0;
    }
    const std::string encoding = lowercase(field_or(header, "encoding", "raw"));
    const long long byte_skip = integer_field(path, header, "byte skip", integer_field(path, header, "byteskip", 0));
    if (encoding == "raw") {
        if (byte_skip == -1) location.at_end_of_file = true;
        else location.offset += std::uint64_t(std::max(0LL, byte_skip));
    } else if (encoding == "gzip" || encoding == "gz") {
        location.compressed = true;
        location.skip_after_inflate = std::uint64_t(std::max(0LL, byte_skip));
    } else if (encoding == "ascii" || encoding == "text" || encoding == "txt") {
        location.text = DataLocation::Text::ascii;
    } else if (encoding == "hex") {
        location.text = DataLocation::Text::hex;
    } else if (encoding == "bzip2" || encoding == "bz2") {
        location.checkable = false;  // ITK's NrrdIO has no bzip2 and refuses it itself
    } else {
        // An encoding this reader cannot check must not reach NrrdIO unchecked (fuzz_volume_nrrd).
        throw InputError(path.string() + ": NRRD encoding '" + encoding.substr(0, 40) + "'; expected raw, gzip, ascii or hex");
    }
    return location;
}

DataLocation metaimage_data_location(const fs::path& path) {
    const TextHeader header = read_metaimage_header(path);
    DataLocation location;
    const std::string data_file = field_or(header, "elementdatafile", "");
    if (lowercase(data_file) == "local") {
        location.file = path;
        location.offset = header.end_offset;
    } else {
        refuse_multi_file_data(path, "MetaImage ElementDataFile", data_file);
        location.file = fs::path(data_file).is_absolute() ? fs::path(data_file) : path.parent_path() / data_file;
    }
    location.compressed = lowercase(field_or(header, "compresseddata", "false")) == "true";
    const long long header_size = integer_field(path, header, "headersize", 0);
    if (!location.compressed) {
        if (header_size == -1) location.at_end_of_file = true;
        else location.offset += std::uint64_t(std::max(0LL, header_size));
    }
    return location;
}

/// Inflates a zlib or gzip stream (windowBits 15+32 detects which) starting at `offset`, counting
/// the bytes it yields. Returns the count; sets `clean_end` when the stream's end marker (and,
/// for gzip, its CRC) was reached; `problem` gets zlib's reason for corrupt data.
std::uint64_t inflate_count(const fs::path& path, std::uint64_t offset, bool& clean_end, std::string& problem) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open voxel data file for reading");
    in.seekg(std::streamoff(offset));
    z_stream stream{};
    if (inflateInit2(&stream, 15 + 32) != Z_OK) throw InputError(path.string() + ": zlib could not start");
    std::vector<unsigned char> input(1 << 16), output(1 << 18);
    std::uint64_t total = 0;
    clean_end = false;
    bool input_done = false;
    for (;;) {
        if (stream.avail_in == 0 && !input_done) {
            in.read(reinterpret_cast<char*>(input.data()), std::streamsize(input.size()));
            stream.next_in = input.data();
            stream.avail_in = unsigned(in.gcount());
            input_done = in.gcount() == 0;
        }
        if (stream.avail_in == 0 && input_done) break;  // input exhausted before the end marker
        stream.next_out = output.data();
        stream.avail_out = unsigned(output.size());
        const int status = inflate(&stream, Z_NO_FLUSH);
        total += output.size() - stream.avail_out;
        if (status == Z_STREAM_END) {
            // gzip allows concatenated members (what `cat a.gz b.gz` makes); continue into the next.
            if (stream.avail_in == 0 && !input_done) {
                in.read(reinterpret_cast<char*>(input.data()), std::streamsize(input.size()));
                stream.next_in = input.data();
                stream.avail_in = unsigned(in.gcount());
                input_done = in.gcount() == 0;
            }
            if (stream.avail_in >= 2 && stream.next_in[0] == 0x1f && stream.next_in[1] == 0x8b) {
                inflateReset(&stream);
                continue;
            }
            clean_end = true;
            break;
        }
        if (status == Z_BUF_ERROR && stream.avail_in == 0) continue;  // needs more input
        if (status != Z_OK) {
            problem = stream.msg ? stream.msg : "zlib error " + std::to_string(status);
            break;
        }
    }
    inflateEnd(&stream);
    return total;
}

/// Throws unless `location` holds at least `bytes` bytes of voxel data (compressed: a stream that
/// ends cleanly and inflates to at least that much).
void check_data_present(const fs::path& path, const DataLocation& location, std::uint64_t bytes, std::uint64_t values) {
    if (!location.checkable) return;
    std::error_code error;
    if (!fs::exists(location.file, error))
        throw InputError(path.string() + ": voxel data file " + location.file.string() + " does not exist");
    // A folder, /dev/zero or a FIFO named as the data file has no size to check (file_size threw
    // std::filesystem::filesystem_error; fuzz_volume_nrrd) and may never end.
    if (!fs::is_regular_file(location.file, error))
        throw InputError(path.string() + ": voxel data file " + location.file.string() + " is not a regular file");
    const std::uint64_t file_size = fs::file_size(location.file);
    const std::string where = location.file == path ? std::string() : " (data file " + location.file.string() + ")";
    if (location.text != DataLocation::Text::none) {
        const bool hex = location.text == DataLocation::Text::hex;
        const long double needed = hex ? 2.0L * bytes : (long double)values;  // ascii: a character per value at least
        if ((long double)file_size < (long double)location.offset + needed)
            throw InputError(path.string() + ": voxel data truncated" + where + ": the header declares " + std::to_string(values) +
                             " values as " + (hex ? "hex" : "text") + ", which need at least " +
                             std::to_string(std::uint64_t(needed)) + " bytes from byte " + std::to_string(location.offset) +
                             ", file has only " + std::to_string(file_size) + " bytes (file is damaged or incomplete)");
        return;
    }
    if (!location.compressed) {
        // Compared without adding: a byte skip near 2^64 would wrap the sum.
        const bool short_file = location.at_end_of_file ? file_size < bytes : file_size < location.offset || file_size - location.offset < bytes;
        if (short_file)
            throw InputError(path.string() + ": voxel data truncated" + where + ": header declares " +
                             std::to_string(bytes) + " bytes from byte " + std::to_string(location.offset) +
                             ", file has only " + std::to_string(file_size) +
                             " bytes (file is damaged or incomplete)");
        return;
    }
    bool clean_end = false;
    std::string problem;
    const std::uint64_t inflated = inflate_count(location.file, location.offset, clean_end, problem);
    const std::uint64_t needed = location.skip_after_inflate + bytes;
    if (!problem.empty())
        throw InputError(path.string() + ": compressed voxel data corrupt" + where + ": " + problem + " after " +
                         std::to_string(inflated) + " of " + std::to_string(needed) +
                         " bytes (file is damaged)");
    const std::string declared = "header declares " + std::to_string(bytes) + " bytes of voxel data" +
                                 (location.skip_after_inflate ? " from byte " + std::to_string(location.skip_after_inflate) +
                                                                    " of the uncompressed stream"
                                                              : std::string());
    if (!clean_end)
        throw InputError(path.string() + ": voxel data truncated" + where + ": " + declared +
                         ", gzip/zlib stream ends after " + std::to_string(inflated) +
                         " uncompressed bytes without its end marker (file is damaged or incomplete)");
    if (inflated < needed)
        throw InputError(path.string() + ": voxel data truncated" + where + ": " + declared +
                         ", compressed stream holds only " + std::to_string(inflated) +
                         " uncompressed bytes (file is damaged or incomplete)");
}


bool holds_non_finite_number(const std::string& value) {
    const std::string text = text::lowercase(value);
    return text.find("nan") != std::string::npos || text.find("inf") != std::string::npos;
}

/// The leading whitespace-separated numbers of a header value ("4 4 x 4" has two).
std::size_t leading_numbers(const std::string& value) {
    std::istringstream tokens(value);
    std::size_t count = 0;
    for (std::string token; tokens >> token; ++count) {
        char* end = nullptr;
        std::strtod(token.c_str(), &end);
        if (end == token.c_str() || *end != '\0') break;
    }
    return count;
}

/// ITK 5.2's MetaIO copies each header field's name into a 255-byte buffer without a bound (strcpy
/// in MET_InitReadField: a longer name overflows it; fuzz_volume_mha found glibc's fortify check
/// aborting there) and reads NDims values per array and NDims² per matrix into 4096-value buffers.
/// So a MetaImage header is checked here before ITK sees it: every line "Key = Value", every field
/// name (MetaIO's: the text before '=' or ':') and value under 255 characters, and NDims from 1 to 4.
/// Returns whether the header gives the voxel size (ElementSpacing or ElementSize).
bool check_metaimage_header_before_itk(const fs::path& path) {
    bool spacing_given = false;
    // MetaIO reads NDims numbers for the per-axis fields (NDims² for the matrices) and, when a line
    // holds fewer, takes the next field's name as the missing value: "DimSize = 10 10" with NDims 3
    // failed as "ElementType required and not defined". Checked after the loop (NDims may follow).
    int ndims = 0;
    struct Counted { int line; std::string name, value; bool matrix; };
    std::vector<Counted> counted;
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open for reading");
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
        // MetaIO compares names as C strings: "NDims\0…" is NDims to it, not to a std::string
        // (fuzz_volume_mha's rerun hid an NDims of millions that way). No header holds a NUL.
        if (line.find('\0') != std::string::npos)
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(number) + " holds a NUL byte (is this a MetaImage file?)");
        const auto separator = line.find_first_of("=:");
        const std::string name = trim(line.substr(0, separator));
        if (name.size() >= 255)
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(number) + " has a field name of " +
                             std::to_string(name.size()) + " characters; expected under 255 (is this a MetaImage file?)");
        // MetaIO looks for a field's value past the end of its line, up to the next '=' or ':'
        // ("NDims" alone, then "x = 99999999" on the next line reads as NDims 99999999 and arrays of
        // that length, for minutes: fuzz_volume_mha's 10-minute run), so every line must be
        // "Key = Value" (blank lines aside), as every MetaImage writer writes them.
        if (separator == std::string::npos) {
            if (name.empty()) continue;
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(number) + " '" + name.substr(0, 40) +
                             "' has no '='; expected Key = Value lines");
        }
        const std::string value = trim(line.substr(separator + 1));
        if (value.empty())
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(number) + ": " + name.substr(0, 40) +
                             " has no value; expected Key = Value lines");
        // And each string field's value (ObjectType, Name, Comment, …) into 255 bytes in
        // MetaObject::M_Read (fuzz_volume_mha's next 10-minute run); no field of a volume's header
        // needs more.
        if (value.size() >= 255)
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(number) + ": " + name.substr(0, 40) +
                             " has a value of " + std::to_string(value.size()) + " characters; expected under 255");
        if (name == "NDims") {
            char* end = nullptr;
            const double dims = std::strtod(value.c_str(), &end);
            if (end == value.c_str() || !(dims >= 1 && dims < 5))
                throw InputError(path.string() + ": MetaImage NDims is '" + value + "'; expected 3 (a 3D volume, or 4 with one time point)");
            ndims = int(dims);
        }
        if (name == "DimSize" || name == "ElementSpacing" || name == "ElementSize" || name == "Offset" || name == "Origin" ||
            name == "Position" || name == "CenterOfRotation")
            counted.push_back({number, name, value, false});
        if (name == "TransformMatrix" || name == "Orientation" || name == "Rotation") counted.push_back({number, name, value, true});
        if (name == "CompressedDataSize") {
            // MetaIO allocates this many bytes before reading the compressed data (fuzz_volume_mha: 1 TB).
            char* end = nullptr;
            const double bytes = std::strtod(value.c_str(), &end);
            std::error_code error;
            const auto file_size = fs::file_size(path, error);
            if (end == value.c_str() || !(bytes >= 0) || bytes > double(file_size))
                throw InputError(path.string() + ": MetaImage CompressedDataSize is '" + value + "'; the file holds only " +
                                 std::to_string(file_size) + " bytes");
        }
        if ((name == "ElementSpacing" || name == "ElementSize" || name == "Offset" || name == "Origin" || name == "Position" ||
             name == "TransformMatrix" || name == "Orientation" || name == "Rotation") &&
            holds_non_finite_number(value))
            throw InputError(path.string() + ": MetaImage " + name + " is '" + value.substr(0, 60) + "'; expected finite numbers");
        if (name == "ElementSpacing" || name == "ElementSize") spacing_given = true;
        if (name == "ElementDataFile") {  // the header's last field; voxel data may follow
            refuse_multi_file_data(path, "MetaImage ElementDataFile", value);
            break;
        }
    }
    for (const Counted& field : counted) {
        const std::size_t needed = field.matrix ? std::size_t(ndims * ndims) : std::size_t(ndims);
        if (const std::size_t found = leading_numbers(field.value); found < needed)
            throw InputError(path.string() + ": MetaImage header line " + std::to_string(field.line) + ": " + field.name + " is '" +
                             field.value.substr(0, 60) + "', " + std::to_string(found) + (found == 1 ? " number" : " numbers") +
                             "; NDims = " + std::to_string(ndims) + " needs " + std::to_string(needed));
    }
    return spacing_given;
}

/// A NRRD header checked before ITK reads it: NrrdIO formats its complaints about a line into a
/// 1025-byte stack buffer with the line in it, so a 1012-character `type:` line smashed its stack
/// (fuzz_volume_nrrd's 10-minute run: glibc's stack protector aborted); field lines (comments
/// aside) are held to 500 characters. NrrdIO ends a line at a line feed, a carriage return or
/// both, so a lone carriage return inside what getline returns starts a new line: a comment line
/// with one in it hid a 1,248-character field line from this check (found by
/// fuzz_volume_nrrd). And its data file (refuse_multi_file_data). Returns whether the header gives the
/// voxel size ('spacings' or 'space directions').
bool check_nrrd_header_before_itk(const fs::path& path) {
    {
        std::ifstream in(path, std::ios::binary);
        std::string text;
        int number = 0;
        bool ended = false;
        while (!ended && std::getline(in, text)) {
            if (!text.empty() && text.back() == '\r') text.pop_back();  // CR LF: one line break
            for (std::size_t start = 0;;) {
                const std::size_t end = std::min(text.find('\r', start), text.size());
                const std::string_view line(text.data() + start, end - start);
                ++number;
                if (line.empty() && number > 1) {  // the blank line that ends the header
                    ended = true;
                    break;
                }
                if (line.size() > 500 && line[0] != '#')
                    throw InputError(path.string() + ": NRRD header line " + std::to_string(number) + " has " + std::to_string(line.size()) +
                                     " characters; expected at most 500");
                if (end == text.size()) break;
                start = end + 1;
            }
        }
    }
    const TextHeader header = read_nrrd_header(path);
    for (const char* field : {"spacings", "space directions", "space origin", "axis mins", "axis maxs", "thicknesses"})
        if (const std::string value = field_or(header, field, ""); holds_non_finite_number(value))
            throw InputError(path.string() + ": NRRD field '" + field + "' is '" + value.substr(0, 60) + "'; expected finite numbers");
    const std::string data_file = field_or(header, "data file", field_or(header, "datafile", ""));
    if (!data_file.empty()) refuse_multi_file_data(path, "NRRD data file", data_file);
    return !field_or(header, "spacings", "").empty() || !field_or(header, "space directions", "").empty();
}

}  // namespace heartsim::volume_header_checks
