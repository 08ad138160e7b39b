/// @file igtl_messages.h
/// @brief The OpenIGTLink messages the live link to 3D Slicer sends (slicer_link.h), encoded:
/// STRING and TRANSFORM through the library, POLYDATA from the protocol's layout (OpenIGTLink v1
/// header, big-endian throughout), since the library rebuilds a mesh's triangles from linked lists
/// at every message. Each message is its packed bytes, header and body, shared by every client's
/// outbox. Built with OpenIGTLink only (runtime/CMakeLists.txt); private to the runtime.
#pragma once

#include "libmodel/instrument_pose.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace heartsim::igtl_messages {

/// A packed message's bytes (header and body).
using Bytes = std::shared_ptr<const std::string>;

/// LPS → RAS: x and y negated (a half turn about z, so a triangle keeps its winding).
constexpr std::array<float, 3> ras_signs = {-1.0f, -1.0f, 1.0f};

/// The protocol's CRC-64 (ECMA-182, most significant bit first, from 0, not inverted: the
/// library's crc64()) of `size` bytes at `data`.
std::uint64_t crc64_of(const char* data, std::size_t size);

/// A STRING message to `device`: `text`, US-ASCII, stamped with the wall clock.
Bytes string_message(const char* device, const std::string& text);

/// A TRANSFORM message to `device`: the 4×4 tool → world matrix of `pose` (LPS mm); in RAS
/// diag(−1, −1, 1)·T (rows x and y negated) when `ras`.
Bytes transform_message(const char* device, const InstrumentPose& pose, bool ras);

/// A cell array's bytes as POLYDATA holds them: each cell its size (u32) then its indices (u32).
std::string cell_section(const std::vector<std::array<std::int32_t, 3>>& triangles);
std::string cell_section(const std::vector<std::array<std::int32_t, 2>>& lines);

/// One POLYDATA message to `device`: `points` (mm, in the frame already) with the polygons
/// `polygons` (a cell_section of `npolygons` cells) or the lines `lines` (`nlines` cells); no
/// vertices, strips or attributes.
Bytes polydata_message(const char* device, const std::vector<std::array<float, 3>>& points, const std::string& polygons, std::size_t npolygons,
                       const std::string& lines, std::size_t nlines);

}  // namespace heartsim::igtl_messages
