/// @file volume_io.cpp
/// @brief Label-map reading and writing through ITK's image I/O, with the checks ITK leaves out:
/// integer component type, sane geometry, voxel data actually present, memory estimated first.
/// It is the only translation unit that compiles ITK's headers (about a minute on the build
/// machines); the raw-header checks that never touch ITK are in volume_header_checks.cpp.
#include "formats/volume_io.h"

#include "formats/atomic_file.h"
#include "formats/nifti_placement.h"
#include "formats/volume_header_checks.h"

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
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <limits>
#include <memory>
#include <new>
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

using namespace volume_header_checks;

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

// The raw-header checks ITK leaves out: volume_header_checks.h.

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

/// A detached header's data file (VolumeHeader::data_file); outside the header's folder it is
/// read, as ITK does, with a warning: the technician sees that the voxels come from elsewhere.
void note_data_file(const fs::path& path, Probe& probe) {
    probe.header.data_file = probe.location.file;
    std::error_code error;
    const fs::path folder = fs::weakly_canonical(path.parent_path().empty() ? fs::path(".") : path.parent_path(), error);
    const fs::path data = fs::weakly_canonical(probe.location.file, error);
    const auto [end, ignored] = std::mismatch(folder.begin(), folder.end(), data.begin(), data.end());
    if (error || end != folder.end())
        probe.header.warnings.push_back(path.string() + ": its voxel data file " + probe.location.file.string() +
                                        " lies outside the header's folder; check that it is this image's data");
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
        if (probe.location.file != path) note_data_file(path, probe);
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

// The NIfTI qform and sform, and which of them ITK takes: nifti_placement.h.

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
        // ITK's NIfTI reader loads the voxels into a copy of its own first ("nifti_image_load
        // failed" when it cannot have one): where a block that size cannot be had now, the
        // failure is memory, not the file.
        if (!std::unique_ptr<char[]>(new (std::nothrow) char[buffer.size() + 1])) throw std::bad_alloc();
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

/// The data file ITK's MetaImage writer puts beside an uncompressed `.mhd` header: its name with
/// `.raw` for `.mhd`, in the header's folder.
fs::path metaimage_data_file(const fs::path& header) {
    const std::string name = header.filename().string();
    return header.parent_path() / (name.substr(0, name.size() - std::string(".mhd").size()) + ".raw");
}

/// ITK chooses its writer by the whole extension (".nii.gz"), and a MetaImage `.mhd` header names
/// its data file after itself: the label map is written into a staging folder beside `path` under
/// its final names, confirmed by reading it back, and handed to write_file_atomically, which
/// flushes it and renames it into place (for a `.mhd`, the data file first and the header last).
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
    sweep_stale_temporaries(path);
    const fs::path staging = temporary_beside(path, "");
    const fs::path written = staging / path.filename();
    const fs::path data_file = detached ? metaimage_data_file(path) : fs::path();
    const fs::path written_data = detached ? staging / data_file.filename() : fs::path();
    std::error_code ignored;
    int write_error = 0;  // errno after ITK's writer: disk_full, said as the cause rather than the short file's damage
    std::string printed;  // what MetaIO said on std::cerr
    try {
        if (!fs::create_directory(staging))
            throw OutputError(path.string() + ": cannot create temporary folder " + staging.string());
        try {
            errno = 0;
            with_cerr_captured(printed, [&] {
                if (fits_uint16) write_with_itk<std::uint16_t>(written, volume, compress, segment_names);
                else write_with_itk<std::int32_t>(written, volume, compress, segment_names);
            });
            write_error = errno;
        } catch (...) {
            write_error = errno;
            throw;
        }
        // Some ITK writers (niftilib) report failure only on stderr: confirm the result is complete.
        if (!fs::exists(written)) throw OutputError(path.string() + ": ITK wrote no file");
        Probe check = probe_volume(written);
        check_data_present(written, check.location, check.header.data_bytes, value_count(check));
        auto take = [](const fs::path& staged) {
            return [staged](const fs::path& temporary) {
                std::error_code error;
                fs::rename(staged, temporary, error);
                if (error) throw OutputError(temporary.string() + ": cannot move the written file here: " + error.message());
            };
        };
        if (!detached) {
            write_file_atomically(path, take(written));
        } else {
            if (check.header.data_file != written_data)
                throw OutputError(path.string() + ": ITK put the voxels in " + check.header.data_file.string() + ", expected " +
                                  written_data.string());
            std::ifstream in(written, std::ios::binary);
            const std::string header((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
            if (in.bad()) throw OutputError(path.string() + ": cannot read back the MetaImage header ITK wrote");
            write_file_atomically(data_file, take(written_data), {FileBeside{path, header, "the MetaImage header"}});
        }
        fs::remove_all(staging, ignored);
    } catch (const itk::ExceptionObject& itk_error) {
        fs::remove_all(staging, ignored);
        if (disk_full(write_error)) throw OutputError(path.string() + ": cannot write the label map (" + std::strerror(write_error) + "; disk full?)");
        throw OutputError(path.string() + ": cannot write: " + itk_reason(itk_error, printed));
    } catch (const OutputError&) {
        fs::remove_all(staging, ignored);
        throw;
    } catch (const std::bad_alloc&) {  // out of memory, not a write that failed: the caller says so
        fs::remove_all(staging, ignored);
        throw;
    } catch (const std::exception& error) {
        fs::remove_all(staging, ignored);
        if (disk_full(write_error)) throw OutputError(path.string() + ": cannot write the label map (" + std::strerror(write_error) + "; disk full?)");
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

std::vector<std::filesystem::path> label_volume_files(const std::filesystem::path& path) {
    if (volume_extension(path) == ".mhd") return {path, metaimage_data_file(path)};
    return {path};
}

void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume) {
    write_label_volume_impl(path, volume, nullptr);
}

void write_label_volume(const std::filesystem::path& path, const LabelVolume& volume,
                        const std::map<int, std::string>& segment_names) {
    write_label_volume_impl(path, volume, &segment_names);
}

}  // namespace heartsim
