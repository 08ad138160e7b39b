/// @file png.h
/// @brief A minimal PNG writer and reader for the runtime's screenshots and the golden-image
/// tests: 8-bit greyscale, RGB or RGBA, non-interlaced (PNG 1.2 / ISO 15948). The encoder writes
/// IHDR, one IDAT (zlib, per-row filter chosen by the minimum-sum-of-absolute-differences rule)
/// and IEND, each with its CRC-32; the file appears atomically (a temporary file beside it, then
/// rename). The reader accepts what the writer writes (any of the five row filters), which is
/// all the tests need; it rejects palette, 16-bit and interlaced images with a clear message.
///
///     Image image{256, 256, 3, pixels};          // rows top to bottom, RGB
///     write_png("shot.png", image);
///     Image back = read_png("shot.png");
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace heartsim {

struct Image {
    int width = 0, height = 0;
    int channels = 3;                    ///< 1 grey, 3 RGB, 4 RGBA
    std::vector<std::uint8_t> pixels;    ///< width·height·channels bytes, rows top to bottom
};

/// The PNG file's bytes for `image`. Throws std::invalid_argument for a bad size or channel count.
std::vector<std::uint8_t> encode_png(const Image& image);

/// Writes `image` to `path` atomically. Throws OutputError naming the file.
void write_png(const std::filesystem::path& path, const Image& image);

/// Decodes PNG bytes (8-bit grey, grey+alpha, RGB or RGBA, not interlaced). Throws InputError
/// (`name` in the message) for anything else or a damaged file (bad CRC, truncated data).
Image decode_png(const std::vector<std::uint8_t>& bytes, const std::string& name = "PNG");

/// Reads and decodes a PNG file. Throws InputError naming the file.
Image read_png(const std::filesystem::path& path);

}  // namespace heartsim
