// libFuzzer target: the label-map reader (formats/volume_io.h) on one file format, chosen at
// build time by HEARTSIM_FUZZ_FORMAT (tests/fuzz/CMakeLists.txt builds this file once per format):
//   nii     the input as a .nii file
//   nii_gz  the input as a .nii.gz file: gzip-compressed here first, unless it already starts with
//           the gzip magic (then as is, so damaged streams are read too)
//   nrrd    the input as a .nrrd file (.seg.nrrd when it mentions "Segment": 3D Slicer's keys)
//   mha     the input as a .mha file (MetaImage, header and data in one file)
#include "fuzz_support.h"

#include "formats/volume_io.h"

#include <zlib.h>

#include <cmath>
#include <cstring>
#include <string_view>
#include <vector>

namespace {

std::vector<std::uint8_t> gzip(const std::uint8_t* data, std::size_t size) {
    z_stream stream{};
    if (deflateInit2(&stream, 1, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK) heartsim::fuzz::broken("deflateInit2");
    std::vector<std::uint8_t> out(deflateBound(&stream, uLong(size)) + 32);
    stream.next_in = const_cast<Bytef*>(data);
    stream.avail_in = uInt(size);
    stream.next_out = out.data();
    stream.avail_out = uInt(out.size());
    if (deflate(&stream, Z_FINISH) != Z_STREAM_END) heartsim::fuzz::broken("deflate");
    out.resize(stream.total_out);
    deflateEnd(&stream);
    return out;
}

std::filesystem::path input_file(const std::uint8_t* data, std::size_t size) {
    using heartsim::fuzz::write_input;
    const std::string_view format = HEARTSIM_FUZZ_FORMAT;
    if (format == "nii") return write_input(data, size, "input.nii");
    if (format == "nii_gz") {
        if (size >= 2 && data[0] == 0x1f && data[1] == 0x8b) return write_input(data, size, "input.nii.gz");
        const auto compressed = gzip(data, size);
        return write_input(compressed.data(), compressed.size(), "input.nii.gz");
    }
    if (format == "nrrd") {
        const std::string_view text(reinterpret_cast<const char*>(data), size);
        return write_input(data, size, text.find("Segment") != std::string_view::npos ? "input.seg.nrrd" : "input.nrrd");
    }
    if (format == "mha") return write_input(data, size, "input.mha");
    heartsim::fuzz::broken("unknown HEARTSIM_FUZZ_FORMAT");
}

void check_geometry(const heartsim::VolumeGeometry& g) {
    for (int a = 0; a < 3; ++a)
        if (g.dims[a] < 1 || !(g.spacing[a] > 0) || !std::isfinite(g.spacing[a]))
            heartsim::fuzz::broken("read a volume with a non-positive size or spacing");
    if (!g.origin.allFinite() || !g.direction.allFinite()) heartsim::fuzz::broken("read a volume with a non-finite geometry");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = input_file(data, size);
    heartsim::fuzz::expect_refusal_or_success([&] { check_geometry(heartsim::read_volume_header(path).geometry); });
    heartsim::fuzz::expect_refusal_or_success([&] {
        const heartsim::LabelVolume volume = heartsim::read_label_volume(path);
        check_geometry(volume.geometry);
        if (volume.labels.size() != volume.geometry.voxel_count())
            heartsim::fuzz::broken("read " + std::to_string(volume.labels.size()) + " labels for " +
                                   std::to_string(volume.geometry.voxel_count()) + " voxels");
    });
    return 0;
}
