// The OpenIGTLink messages the live link sends, encoded (igtl_messages.h).
#include "runtime/link/igtl_messages.h"

#include <igtlStringMessage.h>
#include <igtlTimeStamp.h>
#include <igtlTransformMessage.h>

#include <algorithm>
#include <chrono>
#include <cstring>

namespace heartsim::igtl_messages {

namespace {

/// A packed message's bytes (header and body), to be shared by every client's outbox.
Bytes packed(igtl::MessageBase* message) {
    return std::make_shared<const std::string>(static_cast<const char*>(message->GetPackPointer()), std::size_t(message->GetPackSize()));
}

void stamp(igtl::MessageBase* message) {
    igtl::TimeStamp::Pointer now = igtl::TimeStamp::New();
    now->GetTime();
    message->SetTimeStamp(now);
}

// ---- POLYDATA, from the protocol's layout (OpenIGTLink v1 header, big-endian throughout) ----

void put_u16(char*& out, std::uint16_t v) {
    v = __builtin_bswap16(v);
    std::memcpy(out, &v, 2), out += 2;
}
void put_u32(char*& out, std::uint32_t v) {
    v = __builtin_bswap32(v);
    std::memcpy(out, &v, 4), out += 4;
}
void put_u64(char*& out, std::uint64_t v) {
    v = __builtin_bswap64(v);
    std::memcpy(out, &v, 8), out += 8;
}
void put_f32(char*& out, float f) {
    std::uint32_t v;
    std::memcpy(&v, &f, 4);
    put_u32(out, v);
}

constexpr std::size_t header_bytes = 58;      ///< version, type, device name, time stamp, body size, CRC64
constexpr std::size_t polydata_counts = 40;   ///< the POLYDATA body's ten u32 counts

template <std::size_t N>
std::string cells_of(const std::vector<std::array<std::int32_t, N>>& cells) {
    std::string bytes((1 + N) * 4 * cells.size(), '\0');
    char* out = bytes.data();
    for (const auto& cell : cells) {
        put_u32(out, std::uint32_t(N));
        for (std::int32_t i : cell) put_u32(out, std::uint32_t(i));
    }
    return bytes;
}

}  // namespace

// Eight bytes at a time: a mesh's megabytes in a few ms.
std::uint64_t crc64_of(const char* data, std::size_t size) {
    static const auto tables = [] {
        std::array<std::array<std::uint64_t, 256>, 8> t{};
        for (std::uint64_t i = 0; i < 256; ++i) {
            std::uint64_t c = i << 56;
            for (int k = 0; k < 8; ++k) c = (c >> 63) ? (c << 1) ^ 0x42F0E1EBA9EA3693ull : c << 1;
            t[0][i] = c;
        }
        for (std::size_t k = 1; k < 8; ++k)
            for (std::size_t i = 0; i < 256; ++i) t[k][i] = t[0][t[k - 1][i] >> 56] ^ (t[k - 1][i] << 8);
        return t;
    }();
    const auto* p = reinterpret_cast<const std::uint8_t*>(data);
    std::uint64_t crc = 0;
    for (; size >= 8; size -= 8, p += 8) {
        std::uint64_t word;
        std::memcpy(&word, p, 8);
        crc ^= __builtin_bswap64(word);  // the next eight bytes, first byte highest
        crc = tables[7][crc >> 56] ^ tables[6][(crc >> 48) & 0xff] ^ tables[5][(crc >> 40) & 0xff] ^ tables[4][(crc >> 32) & 0xff] ^
              tables[3][(crc >> 24) & 0xff] ^ tables[2][(crc >> 16) & 0xff] ^ tables[1][(crc >> 8) & 0xff] ^ tables[0][crc & 0xff];
    }
    for (; size > 0; --size, ++p) crc = tables[0][(crc >> 56) ^ *p] ^ (crc << 8);
    return crc;
}

Bytes string_message(const char* device, const std::string& text) {
    igtl::StringMessage::Pointer message = igtl::StringMessage::New();
    message->SetDeviceName(device);
    message->SetEncoding(3);  // IANA 3: US-ASCII
    message->SetString(text.c_str());
    stamp(message);
    message->Pack();
    return packed(message);
}

Bytes transform_message(const char* device, const InstrumentPose& pose, bool ras) {
    igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
    message->SetDeviceName(device);
    const Eigen::Matrix3d rotation = pose.orientation.normalized().toRotationMatrix();
    igtl::Matrix4x4 matrix;
    for (int r = 0; r < 3; ++r) {
        const float sign = ras ? ras_signs[std::size_t(r)] : 1.0f;
        for (int c = 0; c < 3; ++c) matrix[r][c] = sign * float(rotation(r, c));
        matrix[r][3] = sign * float(pose.position[r]);
    }
    matrix[3][0] = matrix[3][1] = matrix[3][2] = 0.0f;
    matrix[3][3] = 1.0f;
    message->SetMatrix(matrix);
    stamp(message);
    message->Pack();
    return packed(message);
}

std::string cell_section(const std::vector<std::array<std::int32_t, 3>>& triangles) { return cells_of(triangles); }
std::string cell_section(const std::vector<std::array<std::int32_t, 2>>& lines) { return cells_of(lines); }

Bytes polydata_message(const char* device, const std::vector<std::array<float, 3>>& points, const std::string& polygons, std::size_t npolygons,
                       const std::string& lines, std::size_t nlines) {
    const std::size_t body = polydata_counts + 12 * points.size() + lines.size() + polygons.size();
    auto message = std::make_shared<std::string>(header_bytes + body, '\0');
    char* out = message->data() + header_bytes;
    for (std::uint32_t count : {std::uint32_t(points.size()), 0u, 0u, std::uint32_t(nlines), std::uint32_t(lines.size()),
                                std::uint32_t(npolygons), std::uint32_t(polygons.size()), 0u, 0u, 0u})
        put_u32(out, count);
    for (const auto& p : points)
        for (float x : p) put_f32(out, x);
    out = std::copy(lines.begin(), lines.end(), out);
    std::copy(polygons.begin(), polygons.end(), out);
    // The header: version 1, "POLYDATA", the device, the wall clock (s since 1970, 2^-32 s), the body's size and CRC64.
    char* h = message->data();
    put_u16(h, 1);
    char type[12] = "POLYDATA", name[20] = {};
    std::memcpy(name, device, std::min(std::strlen(device), sizeof name));
    std::memcpy(h, type, 12), h += 12;
    std::memcpy(h, name, 20), h += 20;
    const auto since_epoch = std::chrono::system_clock::now().time_since_epoch();
    const auto whole = std::chrono::duration_cast<std::chrono::seconds>(since_epoch);
    const double fraction = std::chrono::duration<double>(since_epoch - whole).count();
    put_u64(h, (std::uint64_t(whole.count()) << 32) | std::uint64_t(std::min(fraction * 4294967296.0, 4294967295.0)));
    put_u64(h, body);
    put_u64(h, crc64_of(message->data() + header_bytes, body));
    return message;
}

}  // namespace heartsim::igtl_messages
