/// @file csv.h
/// @brief The one CSV line splitter behind trajectories, device pose files and batch manifests.
#pragma once

#include <string>
#include <vector>

namespace heartsim {

/// One CSV line into fields: RFC 4180 quoting ("a ""quoted"" field", commas inside quotes kept),
/// unquoted carriage returns dropped, spaces and tabs around each field trimmed. A trailing comma
/// gives an empty last field; an empty line gives one empty field.
std::vector<std::string> csv_fields(const std::string& line);

}  // namespace heartsim
