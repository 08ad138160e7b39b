/// @file text.h
/// @brief The string helpers the readers of names and tables, and the command lines, share.
#pragma once

#include <algorithm>
#include <cctype>
#include <string>
#include <vector>

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

/// `words` joined by `separator`.
inline std::string join(const std::vector<std::string>& words, const std::string& separator = ", ") {
    std::string text;
    for (const std::string& word : words) text += (text.empty() ? "" : separator) + word;
    return text;
}

/// Levenshtein distance: the fewest single-character insertions, deletions and substitutions
/// that turn `a` into `b` (for "did you mean" suggestions).
inline std::size_t edit_distance(const std::string& a, const std::string& b) {
    std::vector<std::size_t> row(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
        std::size_t diagonal = row[0];
        row[0] = i;
        for (std::size_t j = 1; j <= b.size(); ++j) {
            const std::size_t above = row[j];
            row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
            diagonal = above;
        }
    }
    return row[b.size()];
}

/// The word of `words` nearest to `word` within `within` edits, or "" when none is.
inline std::string nearest_word(const std::string& word, const std::vector<std::string>& words, std::size_t within = 2) {
    std::string nearest;
    std::size_t best = within + 1;
    for (const std::string& candidate : words)
        if (const std::size_t d = edit_distance(word, candidate); d < best) best = d, nearest = candidate;
    return nearest;
}

}  // namespace heartsim::text
