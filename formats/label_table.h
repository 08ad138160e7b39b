/// @file label_table.h
/// @brief Segment names for a label map that cannot carry them itself (NIfTI, MetaImage, plain
/// NRRD): a label table file, `heartprep build --labels FILE`. Three common layouts, told apart
/// line by line:
///   3D Slicer colour table (.ctbl, .txt):  `VALUE NAME R G B A`           e.g. `2 blood_pool 0 0 255 255`
///   ITK-SNAP label descriptions (.txt):    `VALUE R G B A VIS MSH "NAME"` e.g. `2 0 0 255 1 1 1 "blood pool"`
///   CSV (3D Slicer 5's .csv colour table): `VALUE,NAME,…` after an optional header line
/// Blank lines and lines starting with '#' are skipped. In a colour table, whose names hold no
/// blanks, an underscore stands for a blank: `blood_pool` is read as "blood pool".
#pragma once

#include <filesystem>
#include <map>
#include <string>

namespace heartsim {

/// Reads a label table: label value -> name. Throws InputError naming the file and line for an
/// unreadable file, a line that is none of the layouts above, a label given twice, or a table
/// with no entries.
std::map<int, std::string> read_label_table(const std::filesystem::path& path);

}  // namespace heartsim
