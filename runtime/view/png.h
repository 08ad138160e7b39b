/// @file png.h
/// @brief PNG files for the runtime's screenshots and the golden-image tests, through libpng's
/// simplified API: 8-bit grey, RGB or RGBA written; any PNG read (converted to 8-bit grey, RGB or
/// RGBA). The file appears atomically (a temporary file beside it, then rename). A damaged file
/// (bad CRC in a critical chunk, truncated data) is an InputError naming it.
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

/// Decodes PNG bytes: grey stays grey (1 channel), colour becomes RGB (3), anything with alpha
/// RGBA (4), 8 bits each. Throws InputError (`name` in the message) for a damaged or non-PNG file.
Image decode_png(const std::vector<std::uint8_t>& bytes, const std::string& name = "PNG");

/// Reads and decodes a PNG file. Throws InputError naming the file.
Image read_png(const std::filesystem::path& path);

}  // namespace heartsim
