/// @file text.h
/// @brief The two string helpers the readers of names and tables share.
#pragma once

#include <algorithm>
#include <cctype>
#include <string>

namespace heartsim::text {

/// `text` without the blanks (spaces, tabs, carriage returns, line feeds) at its ends.
inline std::string trim(const std::string& text) {
    const auto first = text.find_first_not_of(" \t\r\n");
    if (first == std::string::npos) return {};
    return text.substr(first, text.find_last_not_of(" \t\r\n") - first + 1);
}

/// `text` in lower case (ASCII letters only).
inline std::string lowercase(std::string text) {
    std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return text;
}

}  // namespace heartsim::text
