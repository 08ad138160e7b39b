// PNG screenshots and golden images through libpng's simplified API (libpng 1.6). png.h.
#include "runtime/view/png.h"

#include "formats/atomic_file.h"

#include "libmodel/errors.h"

#include <png.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

namespace heartsim {

namespace {

png_uint_32 format_of(int channels) {
    switch (channels) {
    case 1: return PNG_FORMAT_GRAY;
    case 3: return PNG_FORMAT_RGB;
    case 4: return PNG_FORMAT_RGBA;
    default: return ~png_uint_32(0);
    }
}

}  // namespace

std::vector<std::uint8_t> encode_png(const Image& image) {
    const png_uint_32 format = format_of(image.channels);
    if (image.width <= 0 || image.height <= 0 || format == ~png_uint_32(0))
        throw std::invalid_argument("encode_png: need a positive size and 1, 3 or 4 channels");
    const std::size_t stride = std::size_t(image.width) * std::size_t(image.channels);
    if (image.pixels.size() != stride * std::size_t(image.height)) throw std::invalid_argument("encode_png: pixel buffer size mismatch");
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    png.width = png_uint_32(image.width);
    png.height = png_uint_32(image.height);
    png.format = format;
    png_alloc_size_t size = 0;  // first the size, then the bytes
    if (!png_image_write_to_memory(&png, nullptr, &size, 0, image.pixels.data(), 0, nullptr))
        throw std::runtime_error(std::string("encode_png: ") + png.message);
    std::vector<std::uint8_t> bytes(size);
    if (!png_image_write_to_memory(&png, bytes.data(), &size, 0, image.pixels.data(), 0, nullptr))
        throw std::runtime_error(std::string("encode_png: ") + png.message);
    bytes.resize(size);
    return bytes;
}

void write_png(const std::filesystem::path& path, const Image& image) {
    const std::vector<std::uint8_t> bytes = encode_png(image);
    write_bytes_atomically(path, bytes.data(), bytes.size(), "the screenshot");
}

Image decode_png(const std::vector<std::uint8_t>& bytes, const std::string& name) {
    // libpng stops after the image data; a file must still end with its IEND chunk (length 0,
    // "IEND", CRC AE 42 60 82), or it was cut short.
    static constexpr std::uint8_t iend[12] = {0, 0, 0, 0, 'I', 'E', 'N', 'D', 0xAE, 0x42, 0x60, 0x82};
    if (bytes.size() < 12 || !std::equal(std::begin(iend), std::end(iend), bytes.end() - 12))
        throw InputError(name + ": PNG without IEND at its end (truncated)");
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&png, bytes.data(), bytes.size()))
        throw InputError(name + ": not a readable PNG file (" + png.message + ")");
    Image image;
    // Grey stays grey, colour becomes RGB, anything with alpha RGBA, 8 bits per channel.
    const bool alpha = (png.format & PNG_FORMAT_FLAG_ALPHA) != 0, colour = (png.format & PNG_FORMAT_FLAG_COLOR) != 0;
    png.format = alpha ? PNG_FORMAT_RGBA : colour ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
    image.channels = alpha ? 4 : colour ? 3 : 1;
    image.width = int(png.width);
    image.height = int(png.height);
    if (png.width > 65536 || png.height > 65536) {
        png_image_free(&png);
        throw InputError(name + ": unreasonable PNG size");
    }
    image.pixels.resize(PNG_IMAGE_SIZE(png));
    if (!png_image_finish_read(&png, nullptr, image.pixels.data(), 0, nullptr))
        throw InputError(name + ": damaged PNG (" + png.message + ")");
    return image;
}

Image read_png(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open the image");
    std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return decode_png(bytes, path.string());
}

}  // namespace heartsim
