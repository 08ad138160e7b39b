/// @file csv.h
/// @brief The one CSV line splitter behind trajectories, device pose files and batch manifests,
/// and the one way those files are read.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace heartsim {

/// One CSV line into fields: RFC 4180 quoting ("a ""quoted"" field", commas inside quotes kept),
/// unquoted carriage returns dropped, spaces and tabs around each field trimmed. A trailing comma
/// gives an empty last field; an empty line gives one empty field.
std::vector<std::string> csv_fields(const std::string& line);

/// The whole text of a CSV file. Throws InputError naming the file when it does not exist, is a
/// folder, is not a regular file (a FIFO or a device would block or never end), or cannot be read.
/// A UTF-8 byte order mark at its start (a spreadsheet's "CSV UTF-8") is dropped; a file holding a
/// NUL byte (binary data: a label map given as a manifest) is refused naming the line.
std::string read_csv_file(const std::filesystem::path& path);

}  // namespace heartsim
