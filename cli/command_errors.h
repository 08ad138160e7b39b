/// @file command_errors.h
/// @brief How heartprep and heartsim tell the user what went wrong: UsageError for a command line
/// that is wrong, and the helpers that make every error one line `PROGRAM: error: FILE: what`
/// (exit_codes.h has the exit status of each kind).
#pragma once

#include "libmodel/errors.h"

#include <string>

namespace heartsim {

/// A command line that is wrong: an option value out of its range or set, options that contradict
/// each other. A kind of OptionError, as libmodel throws for options that are wrong whatever the
/// data: the programs exit 2 for both, as for the command lines their parser refuses, and name no
/// file in them.
class UsageError : public OptionError {
public:
    using OptionError::OptionError;
};

/// Whether `message` already says where it comes from: it begins with `file`, with another file
/// name ("mesh.stl: …", "case.h5:/lattice/…: …", "path.csv line 4: …": a first word that holds a
/// '.' or a '/', alone or followed by " line "), or with an option ("--device …", or libmodel's "{LayoutOptions::occupancy} …").
inline bool names_its_source(const std::string& message, const std::string& file) {
    if (!file.empty() && message.rfind(file, 0) == 0) return true;
    if (message.rfind("-", 0) == 0 || message.rfind("{", 0) == 0) return true;  // a flag, or an option by its meaning
    const auto colon = message.find(':');
    if (colon == std::string::npos || colon == 0) return false;
    const std::string first = message.substr(0, colon);
    const auto space = first.find(' ');
    // "t2.csv line 2 column z: …" names its file too (the trajectory reader's form).
    const std::string word = first.substr(0, space);
    if (space != std::string::npos && first.compare(space, 6, " line ") != 0) return false;
    return word.find_first_of("./") != std::string::npos;
}

/// `error` as an error of `file`, "FILE: what", unless its message names its source already
/// (names_its_source). For the commands: libmodel opens no file, so its errors name none, and the
/// command knows which file it read the data from. An OptionError (a UsageError too) is about the
/// command line, not a file: it is returned as it is.
inline InputError with_file(const std::string& file, const InputError& error) {
    if (file.empty() || dynamic_cast<const OptionError*>(&error) || names_its_source(error.what(), file)) return error;
    return InputError(file + ": " + error.what());
}

/// `text` on one line, as the programs print an error: each line break (with the indentation
/// after it) becomes "; ", or a space after a colon; trailing breaks are dropped.
inline std::string one_line(const std::string& text) {
    std::string out;
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (text[i] != '\n' && text[i] != '\r') {
            out += text[i];
            continue;
        }
        while (i + 1 < text.size() && (text[i + 1] == '\n' || text[i + 1] == '\r' || text[i + 1] == ' ' || text[i + 1] == '\t')) ++i;
        if (i + 1 >= text.size() || out.empty()) continue;
        out += out.back() == ':' || out.back() == ';' ? " " : "; ";
    }
    return out;
}

}  // namespace heartsim
