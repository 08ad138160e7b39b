// A minimal PNG encoder and decoder (PNG 1.2 / ISO 15948, 8-bit, non-interlaced) on zlib. png.h.
#include "png.h"

#include "formats/atomic_file.h"

#include "libmodel/errors.h"

#include <zlib.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>
#include <system_error>

namespace heartsim {

namespace {

constexpr std::array<std::uint8_t, 8> signature = {137, 80, 78, 71, 13, 10, 26, 10};

void put32(std::vector<std::uint8_t>& out, std::uint32_t v) {
    out.push_back(std::uint8_t(v >> 24));
    out.push_back(std::uint8_t(v >> 16));
    out.push_back(std::uint8_t(v >> 8));
    out.push_back(std::uint8_t(v));
}

std::uint32_t get32(const std::uint8_t* p) {
    return (std::uint32_t(p[0]) << 24) | (std::uint32_t(p[1]) << 16) | (std::uint32_t(p[2]) << 8) | std::uint32_t(p[3]);
}

/// Length, type, data, CRC-32 over type and data.
void chunk(std::vector<std::uint8_t>& out, const char type[4], const std::uint8_t* data, std::size_t size) {
    put32(out, std::uint32_t(size));
    const std::size_t start = out.size();
    out.insert(out.end(), type, type + 4);
    if (size) out.insert(out.end(), data, data + size);
    const uLong crc = crc32(crc32(0L, Z_NULL, 0), out.data() + start, uInt(out.size() - start));
    put32(out, std::uint32_t(crc));
}

int paeth(int a, int b, int c) {
    const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
    if (pa <= pb && pa <= pc) return a;
    return pb <= pc ? b : c;
}

int color_type_of(int channels) {
    switch (channels) {
        case 1: return 0;
        case 2: return 4;
        case 3: return 2;
        case 4: return 6;
        default: return -1;
    }
}

}  // namespace

std::vector<std::uint8_t> encode_png(const Image& image) {
    const int type = color_type_of(image.channels);
    if (image.width <= 0 || image.height <= 0 || type < 0 || image.channels == 2)
        throw std::invalid_argument("encode_png: need a positive size and 1, 3 or 4 channels");
    const std::size_t stride = std::size_t(image.width) * std::size_t(image.channels);
    if (image.pixels.size() != stride * std::size_t(image.height)) throw std::invalid_argument("encode_png: pixel buffer size mismatch");

    // Filtered scan lines: per row the filter with the smallest sum of |signed bytes| (the
    // heuristic of the PNG specification, section 12.8).
    const int bpp = image.channels;
    std::vector<std::uint8_t> filtered;
    filtered.reserve((stride + 1) * std::size_t(image.height));
    std::vector<std::uint8_t> candidate[5];
    for (auto& c : candidate) c.resize(stride);
    const std::vector<std::uint8_t> zero_row(stride, 0);
    for (int y = 0; y < image.height; ++y) {
        const std::uint8_t* row = image.pixels.data() + std::size_t(y) * stride;
        const std::uint8_t* up = y > 0 ? row - stride : zero_row.data();
        long best_sum = -1;
        int best = 0;
        for (int f = 0; f < 5; ++f) {
            long sum = 0;
            for (std::size_t x = 0; x < stride; ++x) {
                const int a = x >= std::size_t(bpp) ? row[x - std::size_t(bpp)] : 0, b = up[x],
                          c = x >= std::size_t(bpp) ? up[x - std::size_t(bpp)] : 0;
                int predicted = 0;
                switch (f) {
                    case 1: predicted = a; break;
                    case 2: predicted = b; break;
                    case 3: predicted = (a + b) / 2; break;
                    case 4: predicted = paeth(a, b, c); break;
                    default: break;
                }
                const auto value = std::uint8_t(row[x] - predicted);
                candidate[f][x] = value;
                sum += std::abs(int(std::int8_t(value)));
            }
            if (best_sum < 0 || sum < best_sum) best_sum = sum, best = f;
        }
        filtered.push_back(std::uint8_t(best));
        filtered.insert(filtered.end(), candidate[best].begin(), candidate[best].end());
    }
    uLongf compressed_size = compressBound(uLong(filtered.size()));
    std::vector<std::uint8_t> compressed(compressed_size);
    if (compress2(compressed.data(), &compressed_size, filtered.data(), uLong(filtered.size()), 9) != Z_OK)
        throw std::runtime_error("encode_png: zlib compression failed");
    compressed.resize(compressed_size);

    std::vector<std::uint8_t> out(signature.begin(), signature.end());
    std::vector<std::uint8_t> header;
    put32(header, std::uint32_t(image.width));
    put32(header, std::uint32_t(image.height));
    header.push_back(8);                    // bit depth
    header.push_back(std::uint8_t(type));   // colour type
    header.push_back(0);                    // compression: deflate
    header.push_back(0);                    // filter method 0
    header.push_back(0);                    // no interlace
    chunk(out, "IHDR", header.data(), header.size());
    chunk(out, "IDAT", compressed.data(), compressed.size());
    chunk(out, "IEND", nullptr, 0);
    return out;
}

void write_png(const std::filesystem::path& path, const Image& image) {
    const std::vector<std::uint8_t> bytes = encode_png(image);
    write_bytes_atomically(path, bytes.data(), bytes.size(), "the screenshot");
}

Image decode_png(const std::vector<std::uint8_t>& bytes, const std::string& name) {
    if (bytes.size() < signature.size() || !std::equal(signature.begin(), signature.end(), bytes.begin()))
        throw InputError(name + ": not a PNG file (bad signature)");
    Image image;
    int bit_depth = 0, color_type = -1, interlace = 0;
    std::vector<std::uint8_t> idat;
    bool ended = false;
    for (std::size_t at = signature.size(); at < bytes.size();) {
        if (bytes.size() - at < 12) throw InputError(name + ": truncated PNG chunk");
        const std::uint32_t length = get32(&bytes[at]);
        if (length > bytes.size() - at - 12) throw InputError(name + ": truncated PNG chunk");
        const std::string type(reinterpret_cast<const char*>(&bytes[at + 4]), 4);
        const std::uint8_t* data = &bytes[at + 8];
        const uLong crc = crc32(crc32(0L, Z_NULL, 0), &bytes[at + 4], uInt(length + 4));
        if (std::uint32_t(crc) != get32(data + length)) throw InputError(name + ": PNG chunk " + type + " has a bad CRC");
        if (type == "IHDR") {
            if (length != 13) throw InputError(name + ": bad IHDR");
            image.width = int(get32(data));
            image.height = int(get32(data + 4));
            bit_depth = data[8];
            color_type = data[9];
            interlace = data[12];
        } else if (type == "IDAT") {
            idat.insert(idat.end(), data, data + length);
        } else if (type == "IEND") {
            ended = true;
            break;
        }
        at += 12 + std::size_t(length);
    }
    if (!ended) throw InputError(name + ": PNG without IEND (truncated)");
    switch (color_type) {
        case 0: image.channels = 1; break;
        case 2: image.channels = 3; break;
        case 4: image.channels = 2; break;
        case 6: image.channels = 4; break;
        default: throw InputError(name + ": only 8-bit grey, RGB and RGBA PNGs are read (colour type " + std::to_string(color_type) + ")");
    }
    if (bit_depth != 8 || interlace != 0) throw InputError(name + ": only 8-bit, non-interlaced PNGs are read");
    if (image.width <= 0 || image.height <= 0 || image.width > 1 << 15 || image.height > 1 << 15)
        throw InputError(name + ": unreasonable PNG size");
    const std::size_t stride = std::size_t(image.width) * std::size_t(image.channels);
    uLongf raw_size = uLongf((stride + 1) * std::size_t(image.height));
    std::vector<std::uint8_t> raw(raw_size);
    if (uncompress(raw.data(), &raw_size, idat.data(), uLong(idat.size())) != Z_OK || raw_size != raw.size())
        throw InputError(name + ": damaged PNG image data");
    image.pixels.resize(stride * std::size_t(image.height));
    const int bpp = image.channels;
    for (int y = 0; y < image.height; ++y) {
        const std::uint8_t filter = raw[std::size_t(y) * (stride + 1)];
        const std::uint8_t* in = &raw[std::size_t(y) * (stride + 1) + 1];
        std::uint8_t* row = image.pixels.data() + std::size_t(y) * stride;
        const std::uint8_t* up = y > 0 ? row - stride : nullptr;
        for (std::size_t x = 0; x < stride; ++x) {
            const int a = x >= std::size_t(bpp) ? row[x - std::size_t(bpp)] : 0, b = up ? up[x] : 0,
                      c = (up && x >= std::size_t(bpp)) ? up[x - std::size_t(bpp)] : 0;
            int predicted = 0;
            switch (filter) {
                case 0: break;
                case 1: predicted = a; break;
                case 2: predicted = b; break;
                case 3: predicted = (a + b) / 2; break;
                case 4: predicted = paeth(a, b, c); break;
                default: throw InputError(name + ": bad PNG row filter " + std::to_string(filter));
            }
            row[x] = std::uint8_t(in[x] + predicted);
        }
    }
    return image;
}

Image read_png(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open the image");
    std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return decode_png(bytes, path.string());
}

}  // namespace heartsim
