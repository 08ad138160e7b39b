/// @file volume_io.cpp
/// @brief Label-map reading and writing through ITK's image I/O, with the checks ITK leaves out:
/// integer component type, sane geometry, voxel data actually present, memory estimated first.
/// One file of about 800 lines on purpose: it is the only translation unit that compiles ITK's
/// headers (about a minute each on the build machines), so reading, checking and writing stay
/// together rather than paying that cost twice.
#include "formats/volume_io.h"

#include "formats/atomic_file.h"

#include "libmodel/errors.h"
#include "libmodel/segment_names.h"
#include "libmodel/text.h"
#include "libmodel/plausible.h"

// Debian's ITK 5.2 ships the compiler detection header generated for GCC, which stops any other
// compiler with "#error Unsupported compiler". clang (the sanitize preset) speaks GCC's dialect:
// it reads that header once here posing as GCC 12, and the include guard makes ITK's own include
// of it a no-op.
#if defined(__clang__)
#pragma push_macro("__clang__")
#pragma push_macro("__GNUC__")
#pragma push_macro("__GNUC_MINOR__")
#undef __clang__
#undef __GNUC__
#undef __GNUC_MINOR__
#define __GNUC__ 12
#define __GNUC_MINOR__ 2
#include <itk_compiler_detection.h>
#pragma pop_macro("__GNUC_MINOR__")
#pragma pop_macro("__GNUC__")
#pragma pop_macro("__clang__")
#endif

// ITK 5.2 bundles an older Eigen (itkeigen/) and its headers include modules of it through
// itkImageIOBase.h; over the system Eigen 3.4 that libmodel uses they do not compile
// (EIGEN_USING_STD_MATH is gone in 3.4). Including the system modules first makes ITK's copies
// no-ops through the shared include guards, so this file sees one Eigen.
#include <Eigen/Eigenvalues>

#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkMetaDataObject.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <limits>
#include <mutex>
#include <numbers>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>

namespace heartsim {
namespace {

namespace fs = std::filesystem;

/// Extensions we read and write, longest first so ".seg.nrrd" wins over ".nrrd".
constexpr std::array<const char*, 6> supported_extensions = {".seg.nrrd", ".nii.gz", ".nii", ".nrrd", ".mha", ".mhd"};
constexpr const char* supported_list = ".nii, .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd";

using text::lowercase;
using text::trim;  // the header lines come from getline: no line feed inside

/// The supported extension `path` ends with (lower case), or empty.
std::string volume_extension(const fs::path& path) {
    const std::string name = lowercase(path.filename().string());
    for (const char* extension : supported_extensions) {
        const std::string ext = extension;
        if (name.size() > ext.size() && name.compare(name.size() - ext.size(), ext.size(), ext) == 0) return ext;
    }
    return {};
}

/// Without these, ImageIOFactory finds nothing at run time: we do not include ITK_USE_FILE, whose
/// generated registration code is what normally does this.
void register_io_factories() {
    static std::once_flag once;
    std::call_once(once, [] {
        itk::NiftiImageIOFactory::RegisterOneFactory();
        itk::NrrdImageIOFactory::RegisterOneFactory();
        itk::MetaImageIOFactory::RegisterOneFactory();
    });
}

std::string describe_bytes(double bytes) {
    std::ostringstream text;
    text.precision(3);
    if (bytes >= 1024.0 * 1024.0 * 1024.0) text << bytes / (1024.0 * 1024.0 * 1024.0) << " GiB";
    else if (bytes >= 1024.0 * 1024.0) text << bytes / (1024.0 * 1024.0) << " MiB";
    else text << bytes << " bytes";
    return text.str();
}

/// ITK's exception description (without the source-file location ITK's what() adds), as one line
/// a user can act on. ITK prefixes "ITK ERROR: NrrdImageIO(0x55…): " (an object's address) and
/// may end with "Reason: <strerror(errno)>", where errno is stale (the file exists: it was opened
/// before ITK saw it); both go. NrrdIO's description is a chain, outermost first ("[nrrd] nrrdLoad:
/// trouble reading …", …, "[nrrd] _nrrdReadNrrdParse_sizes: parsed 2 values, but dimension is 3"):
/// the links that only say that reading failed go, and the function names with them. `captured` is what the
/// reader printed on std::cerr meanwhile (MetaIO explains itself there, not in the exception):
/// its first line leads.
std::string itk_reason(const itk::ExceptionObject& error, const std::string& captured = {}) {
    static const std::regex prefix(R"((ITK ERROR|itk::ERROR|itk::ExceptionObject)?:?\s*[A-Za-z]+\(0x[0-9a-fA-F]+\):\s*)");
    static const std::regex nrrd_link(R"(^\[nrrd\] [A-Za-z_0-9]+: ?)");
    std::vector<std::string> parts;
    auto add = [&](std::string part) {
        while (!part.empty() && (part.back() == '\r' || part.back() == ' ' || part.back() == ':' || part.back() == ';' || part.back() == '.'))
            part.pop_back();
        while (!part.empty() && part.front() == ' ') part.erase(part.begin());
        // Links that only say that reading failed, or name the file again.
        for (const char* generic : {"trouble reading", "ReadImageInformation: Error reading", "File cannot be read"})
            if (part.rfind(generic, 0) == 0) return;
        if (part.empty() || part == "trouble" || part == "finished reading header, but there were problems") return;
        if (std::find(parts.begin(), parts.end(), part) == parts.end()) parts.push_back(part);
    };
    if (const auto end = captured.find('\n'); !captured.empty()) add("MetaIO: " + captured.substr(0, end));
    std::string description = std::regex_replace(error.GetDescription(), prefix, "");
    if (const auto reason = description.find("Reason: "); reason != std::string::npos) description.erase(reason);
    // NrrdIO joins its links with "; " or line breaks: split on both.
    std::string link;
    auto flush = [&] {
        add(std::regex_replace(link, nrrd_link, ""));
        link.clear();
    };
    for (std::size_t i = 0; i < description.size(); ++i) {
        const char c = description[i];
        if (c == '\n' || (c == ';' && i + 1 < description.size() && description[i + 1] == ' ')) flush();
        else link += c;
    }
    flush();
    std::string text;
    for (const std::string& part : parts) text += (text.empty() ? "" : "; ") + part;
    return text.empty() ? std::string("ITK gave no reason") : text;
}

/// Runs `read` with std::cerr captured into `printed` (MetaIO prints its parse errors there), also
/// when `read` throws. Volume headers are read on one thread (heartprep batch runs each case in its
/// own process).
template <class Read>
void with_cerr_captured(std::string& printed, Read&& read) {
    std::ostringstream captured;
    std::streambuf* const original = std::cerr.rdbuf(captured.rdbuf());
    try {
        read();
    } catch (...) {
        std::cerr.rdbuf(original);
        printed = captured.str();
        throw;
    }
    std::cerr.rdbuf(original);
    printed = captured.str();
}

// ---------------------------------------------------------------------------------------------
// Where the voxel data lies, from our own reading of the raw header: ITK does not tell, and it
// reads truncated files silently (DESIGN.md).

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

/// Reads "key<separator>value" header lines of NRRD or MetaImage text headers.
struct TextHeader {
    std::map<std::string, std::string> fields;  ///< lower-case key -> value
    std::uint64_t end_offset = 0;               ///< byte after the header
};

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

// ---------------------------------------------------------------------------------------------
// Probing: ITK's header reading plus our own raw-header facts.

struct Probe {
    VolumeHeader header;
    itk::ImageIOBase::Pointer io;
    unsigned itk_dimensions = 0;
    std::vector<std::uint64_t> itk_sizes;
    std::optional<NiftiFields> nifti;
    DataLocation location;
    bool segmentation_file = false;
    int max_segment_layer = 0;
};

bool is_integer_component(itk::IOComponentEnum type) {
    using C = itk::IOComponentEnum;
    switch (type) {
    case C::UCHAR: case C::CHAR: case C::USHORT: case C::SHORT: case C::UINT: case C::INT:
    case C::ULONG: case C::LONG: case C::ULONGLONG: case C::LONGLONG:
        return true;
    default:
        return false;
    }
}

/// Segment<N>_LabelValue / _Name / _Layer key/values of a 3D Slicer .seg.nrrd.
void read_segment_metadata(Probe& probe) {
    static const std::regex key_pattern(R"(Segment(\d+)_(LabelValue|Name|Layer))");
    std::map<int, std::string> names, label_values;
    const itk::MetaDataDictionary& dictionary = probe.io->GetMetaDataDictionary();
    for (const std::string& key : dictionary.GetKeys()) {
        std::smatch match;
        std::string value;
        if (!std::regex_match(key, match, key_pattern) || !itk::ExposeMetaData<std::string>(dictionary, key, value))
            continue;
        // Numbers out of int's range are refused, not thrown as std::out_of_range (fuzz_volume_nrrd).
        int segment = 0;
        if (!parse_label_value(match[1].str(), segment))
            throw InputError(probe.header.format + " file: " + key.substr(0, 60) + ": the segment number is out of range");
        if (match[2] == "Name") {
            names[segment] = value;
        } else if (match[2] == "LabelValue") {
            label_values[segment] = value;
        } else {
            int layer = 0;
            if (!parse_label_value(value, layer) || layer < 0)
                throw InputError(probe.header.format + " file: " + key + " is '" + value.substr(0, 40) +
                                 "'; expected a layer number (0, 1, …)");
            probe.max_segment_layer = std::max(probe.max_segment_layer, layer);
        }
    }
    for (const auto& [segment, text] : label_values) {
        int label = 0;
        if (!parse_label_value(text, label))
            throw InputError(probe.header.format + " file: Segment" + std::to_string(segment) + "_LabelValue is '" +
                             text.substr(0, 40) + "'; expected an integer");
        auto name = names.find(segment);
        probe.header.segment_names[label] = name != names.end() ? name->second : "Segment" + std::to_string(segment);
    }
}

/// Whether a header's numeric field holds a NaN or an infinity: ITK replaces such a spacing by 1 mm
/// without a word (the NIfTI reader checks pixdim itself).
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
/// with one in it hid a 1,248-character field line from this check (fuzz_volume_nrrd, CI of
/// 2026-11-25). And its data file (refuse_multi_file_data). Returns whether the header gives the
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

Probe probe_volume(const fs::path& path) {
    const std::string extension = volume_extension(path);
    if (extension.empty())
        throw InputError(path.string() + ": unsupported file type '" + path.extension().string() +
                         "'; expected one of " + supported_list);
    std::error_code error;
    if (!fs::exists(path, error)) throw InputError(path.string() + ": file not found");
    if (fs::is_directory(path, error)) throw InputError(path.string() + ": is a folder; expected a volume file");
    // A FIFO or a device would block or never end: only regular files are read.
    if (!fs::is_regular_file(path, error)) throw InputError(path.string() + ": not a regular file; expected a volume file");
    if (!std::ifstream(path, std::ios::binary)) throw InputError(path.string() + ": cannot open for reading");
    bool spacing_given = true;  // a NIfTI header always holds pixdim
    if (extension == ".mha" || extension == ".mhd") spacing_given = check_metaimage_header_before_itk(path);
    if (extension == ".nrrd" || extension == ".seg.nrrd") spacing_given = check_nrrd_header_before_itk(path);

    register_io_factories();
    Probe probe;
    probe.io = itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::ImageIOFactory::ReadMode);
    if (!probe.io)
        throw InputError(path.string() + ": not a readable " + extension +
                         " file (no ITK image reader recognises its contents)");
    const std::string io_class = probe.io->GetNameOfClass();
    const bool nifti = io_class == "NiftiImageIO", nrrd = io_class == "NrrdImageIO", meta = io_class == "MetaImageIO";
    if (!nifti && !nrrd && !meta)
        throw InputError(path.string() + ": read by ITK's " + io_class + ", not a supported format; expected " +
                         supported_list);
    probe.header.format = nifti ? "NIfTI" : nrrd ? "NRRD" : "MetaImage";
    probe.segmentation_file = extension == ".seg.nrrd";

    // Our own header reading comes first: it explains damage more precisely than ITK does.
    if (nifti) probe.nifti = read_nifti_fields(path);

    probe.io->SetFileName(path.string());
    std::string printed;
    try {
        with_cerr_captured(printed, [&] { probe.io->ReadImageInformation(); });
    } catch (const itk::ExceptionObject& itk_error) {
        throw InputError(path.string() + ": cannot read the " + probe.header.format + " header: " + itk_reason(itk_error, meta ? printed : ""));
    }

    VolumeHeader& header = probe.header;
    if (const auto end = printed.find('\n'); !printed.empty())
        header.warnings.push_back(path.string() + ": the " + header.format + " reader said: " + printed.substr(0, end));
    // Both formats then default to 1 mm voxels, which for an MRI is often wrong by half or more:
    // the lattice and every length in the scenario would be off by that factor.
    if (!spacing_given)
        header.warnings.push_back(path.string() + ": the " + header.format + " header gives no voxel size (" +
                                  (meta ? "ElementSpacing" : "spacings or space directions") +
                                  "): 1 mm voxels assumed, the format's default; if the scan's voxels are not 1 mm, add the field");
    // ITK's size queries throw through a noexcept function (std::terminate) on an unknown element
    // type (fuzz_volume_mha: "ElementType = MET_" followed by zeros).
    if (probe.io->GetComponentType() == itk::IOComponentEnum::UNKNOWNCOMPONENTTYPE)
        throw InputError(path.string() + ": the " + probe.header.format + " header names no element type ITK knows; expected an integer type");
    header.component_type = itk::ImageIOBase::GetComponentTypeAsString(probe.io->GetComponentType());
    header.components = int(probe.io->GetNumberOfComponents());
    probe.itk_dimensions = probe.io->GetNumberOfDimensions();
    for (unsigned d = 0; d < probe.itk_dimensions; ++d) probe.itk_sizes.push_back(probe.io->GetDimensions(d));
    for (unsigned d = 0; d < std::min(3u, probe.itk_dimensions); ++d) {
        header.geometry.dims[d] = int(std::min<std::uint64_t>(probe.itk_sizes[d], std::numeric_limits<int>::max()));
        header.geometry.spacing[d] = probe.io->GetSpacing(d);
        header.geometry.origin[d] = probe.io->GetOrigin(d);
        const std::vector<double> axis = probe.io->GetDirection(d);
        for (unsigned row = 0; row < 3; ++row) header.geometry.direction(row, d) = row < axis.size() ? axis[row] : 0.0;
    }
    if (nrrd) read_segment_metadata(probe);

    if (nifti) {
        probe.header.data_bytes = nifti_data_bytes(path, *probe.nifti);
        probe.location.file = path;
        // vox_offset counts bytes of the uncompressed file: for .nii.gz the whole file is one stream.
        const auto voxel_offset = std::uint64_t(std::max(0.0, probe.nifti->vox_offset));
        probe.location.compressed = extension == ".nii.gz";
        (probe.location.compressed ? probe.location.skip_after_inflate : probe.location.offset) = voxel_offset;
    } else {
        probe.header.data_bytes = probe.io->GetImageSizeInBytes();
        probe.location = nrrd ? nrrd_data_location(path) : metaimage_data_location(path);
    }
    return probe;
}

/// Values (voxels × components) the header declares.
std::uint64_t value_count(const Probe& probe) {
    return probe.header.data_bytes / std::max<std::uint64_t>(1, probe.io->GetComponentSize());
}

const char* axis_name(int axis) { return axis == 0 ? "i" : axis == 1 ? "j" : "k"; }

std::string number(double value) {
    std::ostringstream text;
    text.precision(9);
    text << value;
    return text.str();
}

/// Dimension 3 (or 4 with one volume), positive finite spacing, finite origin and direction,
/// direction not singular.
void check_geometry(const fs::path& path, const Probe& probe) {
    const std::string file = path.string() + ": ";
    const unsigned dimensions = probe.itk_dimensions;
    if (dimensions < 3 || dimensions > 4 || (dimensions == 4 && probe.itk_sizes[3] != 1)) {
        std::string sizes;
        for (auto size : probe.itk_sizes) sizes += (sizes.empty() ? "" : "×") + std::to_string(size);
        throw InputError(file + "image is " + std::to_string(dimensions) + "-dimensional (" + sizes +
                         "); expected a 3D volume (or 4D with one time point)");
    }
    if (probe.nifti) {
        // Raw pixdim: niftilib/ITK would report 1 for a zero or negative value.
        for (int axis = 0; axis < 3; ++axis) {
            const double value = probe.nifti->pixdim[axis + 1];
            if (!std::isfinite(value) || value <= 0)
                throw InputError(file + "invalid voxel spacing along " + axis_name(axis) + ": NIfTI pixdim[" +
                                 std::to_string(axis + 1) + "] is " + number(value) +
                                 "; expected a finite positive size in mm");
        }
    }
    const VolumeGeometry& geometry = probe.header.geometry;
    for (int axis = 0; axis < 3; ++axis) {
        if (probe.itk_sizes[axis] > std::uint64_t(std::numeric_limits<int>::max()))
            throw InputError(file + "size along " + axis_name(axis) + " is " + std::to_string(probe.itk_sizes[axis]) +
                             "; expected at most " + std::to_string(std::numeric_limits<int>::max()) + " voxels");
        if (geometry.dims[axis] < 1)
            throw InputError(file + "size along " + axis_name(axis) + " is " + std::to_string(geometry.dims[axis]) +
                             "; expected at least one voxel");
        const double value = geometry.spacing[axis];
        if (!std::isfinite(value) || value <= 0)
            throw InputError(file + "invalid voxel spacing along " + axis_name(axis) + ": " + number(value) +
                             "; expected a finite positive size in mm");
        // A voxel in metres read as millimetres, or 1e-6 mm (whose lattice would not fit in memory).
        if (!plausible::voxel_spacing_mm.contains(value))
            throw InputError(file + plausible::outside(std::string("voxel spacing along ") + axis_name(axis), value, plausible::voxel_spacing_mm) +
                             " (check the header's spacing and units)");
    }
    if (!geometry.origin.allFinite())
        throw InputError(file + "origin is not finite (" + number(geometry.origin.x()) + ", " +
                         number(geometry.origin.y()) + ", " + number(geometry.origin.z()) + ")");
    if (!geometry.direction.allFinite()) throw InputError(file + "direction matrix has non-finite entries");
    const double determinant = geometry.direction.determinant();
    if (!(std::abs(determinant) > 1e-6))
        throw InputError(file + "direction matrix is singular (determinant " + number(determinant) +
                         "); expected independent axes");
}

// ---------------------------------------------------------------------------------------------
// NIfTI qform and sform: both may be set, and they may disagree. ITK's NiftiImageIO picks one
// (itkNiftiImageIO.cxx, SetImageIOOrientationFromNIfTI: the ITK 5.2 we build with, measured by
// test_volume_io, and the newer ITK inside 3D Slicer 5): the sform when its columns are a rotation times a
// scaling and either the qform code is 0 or the sform code is 1 (scanner anatomy) or the two
// agree within 1e-4; otherwise the qform. heartprep keeps ITK's choice, so a label map lands where
// 3D Slicer shows it, and says so when the two disagree: a file that two tools read differently
// (nibabel takes the sform whenever its code is set) is worth a look.

/// Where a NIfTI transform puts the grid, as ITK uses it: LPS origin and unit axes (the spacing
/// comes from pixdim either way).
struct NiftiPlacement {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();               ///< LPS mm
    Eigen::Matrix3d direction = Eigen::Matrix3d::Identity();        ///< unit columns, LPS
    bool rotation = true;  ///< the columns, normalised, are orthonormal (within ITK's 1e-4)
};

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

/// The qform: NIfTI-1's quaternion (nifti1.h, "METHOD 2"), qfac = pixdim[0]'s sign.
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

/// The sform: rows srow_x, srow_y, srow_z ("METHOD 3"), its columns normalised as ITK does.
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

/// How far apart two placements put the grid: at the first voxel, in orientation, and at worst
/// over the volume's eight corner voxels.
struct PlacementDifference {
    double origin_mm = 0.0;
    double angle_degrees = 0.0;
    double largest_mm = 0.0;
    bool mirrored = false;  ///< one is the other's mirror image (opposite handedness)
};

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

std::string fixed(double value, int decimals) {
    std::ostringstream text;
    text.setf(std::ios::fixed);
    text.precision(decimals);
    text << value;
    return text.str();
}

/// Warns (probe.header.warnings) when both codes are set and the qform and sform disagree by
/// more than 0.01 mm anywhere in the volume or 0.01° in orientation.
void check_nifti_orientation(const fs::path& path, Probe& probe) {
    if (!probe.nifti) return;
    const NiftiFields& fields = *probe.nifti;
    if (fields.qform_code <= 0 || fields.sform_code <= 0) return;
    const VolumeGeometry& geometry = probe.header.geometry;
    const NiftiPlacement qform = qform_placement(fields), sform = sform_placement(fields);
    const PlacementDifference apart = compare_placements(qform, sform, geometry);
    if (apart.largest_mm <= 0.01 && apart.angle_degrees <= 0.01 && !apart.mirrored) return;

    // The one ITK used: the one its origin and axes match.
    auto distance = [&](const NiftiPlacement& placement) {
        return (placement.origin - geometry.origin).norm() + 100.0 * (placement.direction - geometry.direction).norm();
    };
    const bool used_sform = distance(sform) < distance(qform);
    std::string why;
    if (used_sform && fields.sform_code == 1)
        why = "as ITK and 3D Slicer do when the sform's code is 1 (scanner anatomy) and it has no shear";
    else if (used_sform)
        why = "as ITK's NIfTI reader chose";
    else if (!sform.rotation)
        why = "as ITK and 3D Slicer do when the sform holds shear (its columns are not orthogonal)";
    else
        why = "as ITK and 3D Slicer do when the two disagree and the sform's code is not 1 (scanner anatomy); nibabel "
              "would use the sform";
    std::string how_far = apart.mirrored ? "one is the mirror image of the other"
                                         : fixed(apart.angle_degrees, 2) + "° apart in orientation";
    how_far = fixed(apart.origin_mm, 2) + " mm apart at the first voxel, " + how_far + ", up to " +
              fixed(apart.largest_mm, 2) + " mm apart across the volume";
    probe.header.warnings.push_back(path.string() + ": the NIfTI qform (code " + xform_code_name(fields.qform_code) +
                                    ") and sform (code " + xform_code_name(fields.sform_code) + ") disagree: " + how_far +
                                    "; heartprep uses the " + (used_sform ? "sform" : "qform") + ", " + why +
                                    "; check that the label map lies on its image");
}

/// Multi-layer .seg.nrrd files hold overlapping segments in separate layers: no single label map.
void check_single_layer(const fs::path& path, const Probe& probe) {
    if (!probe.segmentation_file) return;
    const bool extra_axis = probe.itk_dimensions == 4 && probe.itk_sizes[3] > 1;
    if (probe.header.components > 1 || extra_axis || probe.max_segment_layer > 0) {
        const int layers = std::max({probe.header.components, probe.max_segment_layer + 1,
                                     extra_axis ? int(probe.itk_sizes[3]) : 1});
        throw InputError(path.string() + ": multi-layer 3D Slicer segmentation (" + std::to_string(layers) +
                         " layers); expected a single layer: in 3D Slicer export it as a labelmap volume, or "
                         "save the segmentation with overlapping segments collapsed into a single layer");
    }
}

void check_component_type(const fs::path& path, const Probe& probe) {
    const itk::IOComponentEnum type = probe.io->GetComponentType();
    if (!is_integer_component(type)) {
        const std::string kind = type == itk::IOComponentEnum::FLOAT ? "float" : type == itk::IOComponentEnum::DOUBLE
                                                                               ? "double"
                                                                               : probe.header.component_type;
        throw InputError(path.string() + ": is a " + kind + " image; expected an integer label map" +
                         (probe.nifti ? " (NIfTI datatype " + std::to_string(probe.nifti->datatype) +
                                            ", or integer data rescaled by scl_slope/scl_inter)"
                                      : std::string()));
    }
    if (probe.header.components != 1)
        throw InputError(path.string() + ": has " + std::to_string(probe.header.components) +
                         " components per voxel; expected one label per voxel");
}

/// MemAvailable from /proc/meminfo, bytes; 0 when unknown.
std::uint64_t available_memory_bytes() {
    std::ifstream meminfo("/proc/meminfo");
    std::string key;
    std::uint64_t kilobytes = 0;
    std::string unit;
    while (meminfo >> key >> kilobytes >> unit)
        if (key == "MemAvailable:") return kilobytes * 1024;
    return 0;
}

void check_memory(const fs::path& path, const Probe& probe, const VolumeReadOptions& options) {
    long double voxels = 1;
    for (auto size : probe.itk_sizes) voxels *= size;
    const long double needed = voxels * options.working_bytes_per_voxel;
    const bool from_machine = options.memory_limit_bytes == 0;
    const std::uint64_t limit = from_machine ? available_memory_bytes() : options.memory_limit_bytes;
    if (limit != 0 && needed > (long double)limit) {
        std::string sizes;
        for (auto size : probe.itk_sizes) sizes += (sizes.empty() ? "" : "×") + std::to_string(size);
        throw InputError(path.string() + ": volume too large: " + sizes + " voxels need about " +
                         describe_bytes(double(needed)) + " of working memory (" +
                         number(options.working_bytes_per_voxel) + " bytes per voxel), more than the " +
                         describe_bytes(double(limit)) +
                         (from_machine ? " available on this machine (MemAvailable)" : " allowed (memory limit)") +
                         "; crop or resample the volume");
    }
}

/// Converts ITK's native buffer to int32, refusing values int32 cannot hold.
template <class T>
void convert_labels(const fs::path& path, const std::vector<char>& buffer, std::vector<std::int32_t>& labels) {
    const std::size_t count = labels.size();
    const T* values = reinterpret_cast<const T*>(buffer.data());
    for (std::size_t index = 0; index < count; ++index) {
        const T value = values[index];
        if constexpr (sizeof(T) >= sizeof(std::int32_t)) {
            // std::in_range compares across signedness without conversion surprises.
            if (!std::in_range<std::int32_t>(value))
                throw InputError(path.string() + ": label " + std::to_string(value) + " at voxel " +
                                 std::to_string(index) + " is outside the 32-bit signed range labels are kept in");
        }
        labels[index] = std::int32_t(value);
    }
}

LabelVolume read_voxels(const fs::path& path, Probe& probe) {
    LabelVolume volume;
    volume.geometry = probe.header.geometry;
    const std::size_t voxel_count = volume.geometry.voxel_count();
    itk::ImageIORegion region(probe.itk_dimensions);
    for (unsigned d = 0; d < probe.itk_dimensions; ++d) {
        region.SetIndex(d, 0);
        region.SetSize(d, probe.itk_sizes[d]);
    }
    probe.io->SetIORegion(region);
    std::vector<char> buffer(voxel_count * probe.io->GetComponentSize());
    try {
        probe.io->Read(buffer.data());
    } catch (const itk::ExceptionObject& itk_error) {
        throw InputError(path.string() + ": cannot read voxel data: " + itk_reason(itk_error));
    }
    volume.labels.resize(voxel_count);
    using C = itk::IOComponentEnum;
    switch (probe.io->GetComponentType()) {
    case C::UCHAR: convert_labels<unsigned char>(path, buffer, volume.labels); break;
    case C::CHAR: convert_labels<signed char>(path, buffer, volume.labels); break;
    case C::USHORT: convert_labels<unsigned short>(path, buffer, volume.labels); break;
    case C::SHORT: convert_labels<short>(path, buffer, volume.labels); break;
    case C::UINT: convert_labels<unsigned int>(path, buffer, volume.labels); break;
    case C::INT: convert_labels<int>(path, buffer, volume.labels); break;
    case C::ULONG: convert_labels<unsigned long>(path, buffer, volume.labels); break;
    case C::LONG: convert_labels<long>(path, buffer, volume.labels); break;
    case C::ULONGLONG: convert_labels<unsigned long long>(path, buffer, volume.labels); break;
    case C::LONGLONG: convert_labels<long long>(path, buffer, volume.labels); break;
    default: throw InputError(path.string() + ": unexpected component type " + probe.header.component_type);
    }
    return volume;
}

// ---------------------------------------------------------------------------------------------
// Writing.

template <class Pixel>
void write_with_itk(const fs::path& path, const LabelVolume& volume, bool compress,
                    const std::map<int, std::string>* segment_names) {
    using Image = itk::Image<Pixel, 3>;
    const VolumeGeometry& geometry = volume.geometry;
    auto image = Image::New();
    typename Image::RegionType region;
    typename Image::SpacingType spacing;
    typename Image::PointType origin;
    typename Image::DirectionType direction;
    for (unsigned d = 0; d < 3; ++d) {
        region.SetIndex(d, 0);
        region.SetSize(d, itk::SizeValueType(geometry.dims[d]));
        spacing[d] = geometry.spacing[d];
        origin[d] = geometry.origin[d];
        for (unsigned column = 0; column < 3; ++column) direction(d, column) = geometry.direction(d, column);
    }
    image->SetRegions(region);
    image->SetSpacing(spacing);
    image->SetOrigin(origin);
    image->SetDirection(direction);
    image->Allocate();
    Pixel* pixels = image->GetBufferPointer();
    std::transform(volume.labels.begin(), volume.labels.end(), pixels, [](std::int32_t label) { return Pixel(label); });

    if (segment_names) {
        // 3D Slicer's segmentation keys: one segment per label, all in layer 0.
        itk::MetaDataDictionary& dictionary = image->GetMetaDataDictionary();
        int segment = 0;
        for (const auto& [label, name] : *segment_names) {
            const std::string prefix = "Segment" + std::to_string(segment++) + "_";
            itk::EncapsulateMetaData<std::string>(dictionary, prefix + "ID", "Segment_" + std::to_string(label));
            itk::EncapsulateMetaData<std::string>(dictionary, prefix + "Name", name);
            itk::EncapsulateMetaData<std::string>(dictionary, prefix + "LabelValue", std::to_string(label));
            itk::EncapsulateMetaData<std::string>(dictionary, prefix + "Layer", "0");
        }
    }
    auto writer = itk::ImageFileWriter<Image>::New();
    writer->SetFileName(path.string());
    writer->SetInput(image);
    writer->SetUseCompression(compress);
    writer->Update();
}

/// MetaImage .mhd headers name their data file (.raw/.zraw) after themselves, so a renamed
/// temporary header would point at the wrong file: write both inside a temporary folder under
/// their final names, then move the data file first and the header last.
void write_label_volume_impl(const fs::path& path, const LabelVolume& volume,
                             const std::map<int, std::string>* segment_names) {
    const std::string extension = volume_extension(path);
    if (extension.empty()) throw OutputError(label_volume_path_problem(path));
    if (volume.labels.size() != volume.geometry.voxel_count())
        throw OutputError(path.string() + ": label count " + std::to_string(volume.labels.size()) +
                          " does not match the geometry's " + std::to_string(volume.geometry.voxel_count()) +
                          " voxels");
    // Before ITK: niftilib reports an output it cannot open on stderr only, in two lines of its own.
    check_destination(path);
    register_io_factories();
    const auto [lowest, highest] = std::minmax_element(volume.labels.begin(), volume.labels.end());
    const bool fits_uint16 = volume.labels.empty() || (*lowest >= 0 && *highest <= 65535);
    const bool compress = extension != ".nii" && extension != ".mhd";
    std::map<int, std::string> default_names;
    if (extension == ".seg.nrrd" && !segment_names) {
        for (std::int32_t label : volume.labels)
            if (label != 0 && !default_names.count(label)) default_names[label] = "Label " + std::to_string(label);
        segment_names = &default_names;
    }
    if (extension != ".seg.nrrd") segment_names = nullptr;

    const bool detached = extension == ".mhd";
    // The temporary keeps the whole extension, so ITK picks the same writer.
    sweep_stale_temporaries(path);
    const fs::path staging = temporary_beside(path, detached ? "" : extension);
    const fs::path written = detached ? staging / path.filename() : staging;
    std::error_code ignored;
    try {
        if (detached && !fs::create_directory(staging))
            throw OutputError(path.string() + ": cannot create temporary folder " + staging.string());
        if (fits_uint16) write_with_itk<std::uint16_t>(written, volume, compress, segment_names);
        else write_with_itk<std::int32_t>(written, volume, compress, segment_names);
        // Some ITK writers (niftilib) report failure only on stderr: confirm the result is complete.
        if (!fs::exists(written)) throw OutputError(path.string() + ": ITK wrote no file");
        Probe check = probe_volume(written);
        check_data_present(written, check.location, check.header.data_bytes, value_count(check));
        if (detached) {
            for (const auto& entry : fs::directory_iterator(staging))
                if (entry.path() != written) fs::rename(entry.path(), path.parent_path() / entry.path().filename());
        }
        fs::rename(written, path);
        if (detached) fs::remove_all(staging, ignored);
    } catch (const itk::ExceptionObject& itk_error) {
        fs::remove_all(staging, ignored);
        throw OutputError(path.string() + ": cannot write: " + itk_reason(itk_error));
    } catch (const OutputError&) {
        fs::remove_all(staging, ignored);
        throw;
    } catch (const std::bad_alloc&) {  // out of memory, not a write that failed: the caller says so
        fs::remove_all(staging, ignored);
        throw;
    } catch (const std::exception& error) {
        fs::remove_all(staging, ignored);
        throw OutputError(path.string() + ": cannot write: " + error.what());
    }
}

}  // namespace

VolumeHeader read_volume_header(const std::filesystem::path& path) {
    Probe probe = probe_volume(path);
    check_single_layer(path, probe);
    check_geometry(path, probe);
    check_nifti_orientation(path, probe);
    return probe.header;
}

LabelVolume read_label_volume(const std::filesystem::path& path, const VolumeReadOptions& options,
                              VolumeHeader* header) {
    Probe probe = probe_volume(path);
    check_single_layer(path, probe);
    check_component_type(path, probe);
    check_geometry(path, probe);
    check_nifti_orientation(path, probe);
    check_memory(path, probe, options);
    check_data_present(path, probe.location, probe.header.data_bytes, value_count(probe));
    LabelVolume volume = read_voxels(path, probe);
    if (header) *header = probe.header;
    return volume;
}

std::string label_volume_path_problem(const std::filesystem::path& path) {
    if (!volume_extension(path).empty()) return {};
    return path.string() + ": unsupported file type '" + path.extension().string() + "'; expected one of " + supported_list;
}

void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume) {
    write_label_volume_impl(path, volume, nullptr);
}

void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume,
                        const std::map<int, std::string>& segment_names) {
    write_label_volume_impl(path, volume, &segment_names);
}

}  // namespace heartsim
