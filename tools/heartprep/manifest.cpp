// `heartprep batch`'s manifest (manifest.h).
#include "manifest.h"

#include "formats/csv.h"
#include "libmodel/errors.h"
#include "libmodel/text.h"

#include <algorithm>
#include <cctype>
#include <cstring>

#include <fnmatch.h>
#include <map>
#include <sstream>

namespace heartsim::cli {

namespace {

namespace fs = std::filesystem;

bool is_volume_file(const fs::path& path) {
    const std::string name = path.filename().string();
    for (const char* extension : {".nii", ".nii.gz", ".nrrd", ".mha", ".mhd"})
        if (name.size() > std::strlen(extension) && name.compare(name.size() - std::strlen(extension), std::string::npos, extension) == 0)
            return true;
    return false;
}

/// File name without its volume extension (".nii.gz" and ".seg.nrrd" count as one).
std::string stem_of(const fs::path& path) {
    std::string name = path.filename().string();
    for (const char* extension : {".seg.nrrd", ".nii.gz", ".nii", ".nrrd", ".mha", ".mhd"}) {
        const std::size_t n = std::strlen(extension);
        if (name.size() > n && name.compare(name.size() - n, n, extension) == 0) return name.substr(0, name.size() - n);
    }
    return path.stem().string();
}

}  // namespace

std::vector<std::string> split_words(const std::string& text) {
    std::vector<std::string> words;
    std::string word;
    bool in_word = false;
    char quote = 0;
    for (char c : text) {
        if (quote) {
            if (c == quote) quote = 0;
            else word += c;
        } else if (c == '"' || c == '\'') quote = c, in_word = true;
        else if (c == ' ' || c == '\t') {
            if (in_word) words.push_back(word), word.clear(), in_word = false;
        } else word += c, in_word = true;
    }
    if (quote) throw InputError("unbalanced quote in build options: " + text);
    if (in_word) words.push_back(word);
    return words;
}

std::vector<BatchCase> read_manifest(const fs::path& manifest, const std::string& default_options, const std::string& pattern) {
    std::vector<BatchCase> cases;
    if (fs::is_directory(manifest)) {
        std::vector<fs::path> files;
        for (const auto& entry : fs::directory_iterator(manifest)) {
            const std::string name = entry.path().filename().string();
            if (entry.is_regular_file() && is_volume_file(entry.path()) &&
                (pattern.empty() || ::fnmatch(pattern.c_str(), name.c_str(), FNM_PERIOD) == 0))
                files.push_back(entry.path());
        }
        std::sort(files.begin(), files.end());
        std::map<std::string, fs::path> by_id;
        for (const auto& file : files) {
            const std::string id = stem_of(file);
            if (const auto [it, added] = by_id.emplace(id, file); !added)
                throw InputError(manifest.string() + ": " + it->second.filename().string() + " and " + file.filename().string() +
                                 " would both be case '" + id + "' (choose one with --pattern, or list the cases in a CSV manifest)");
            cases.push_back({id, file, default_options, 0});
        }
        if (cases.empty())
            throw InputError(manifest.string() + ": folder holds no label maps (.nii, .nii.gz, .nrrd, .mha, .mhd)" +
                             (pattern.empty() ? std::string() : " whose name matches --pattern '" + pattern + "'"));
    } else {
        std::istringstream in(read_csv_file(manifest));
        std::string line;
        int number = 0;
        while (std::getline(in, line)) {
            ++number;
            auto fields = csv_fields(line);
            if (fields.size() == 1 && fields[0].empty()) continue;
            if (fields[0].rfind('#', 0) == 0) continue;
            const std::string first = text::lowercase(fields[0]);
            if (cases.empty() && first == "input") continue;  // header line
            if (fields.size() > 3)
                throw InputError(manifest.string() + ": line " + std::to_string(number) + " has " + std::to_string(fields.size()) +
                                 " fields; expected input[,case_id[,options]] (quote options that contain commas)");
            if (fields[0].empty()) throw InputError(manifest.string() + ": line " + std::to_string(number) + ": no input file");
            fs::path input = fields[0];
            if (input.is_relative()) input = manifest.parent_path() / input;
            BatchCase c{fields.size() > 1 && !fields[1].empty() ? fields[1] : stem_of(input), input,
                        fields.size() > 2 && !fields[2].empty() ? fields[2] : default_options, number};
            cases.push_back(c);
        }
        if (cases.empty()) throw InputError(manifest.string() + ": no cases (expected lines of input[,case_id[,options]])");
    }
    std::map<std::string, const BatchCase*> seen;  // ids by lower case: a.h5 and A.h5 are one file on macOS and Windows
    for (const auto& c : cases) {
        if (c.id.empty() || c.id.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._-") != std::string::npos)
            throw InputError(manifest.string() + ": line " + std::to_string(c.line) + ": case id '" + c.id +
                             "' may only use letters, digits, '.', '_' and '-' (it names the output file)");
        if (c.id.front() == '.')  // "." and ".." wrote "..h5" and "...h5": hidden files
            throw InputError(manifest.string() + ": line " + std::to_string(c.line) + ": case id '" + c.id +
                             "' begins with '.', which would hide its output file; begin it with a letter or digit");
        if (const auto [other, fresh] = seen.emplace(text::lowercase(c.id), &c); !fresh) {
            const BatchCase& first = *other->second;
            if (first.id == c.id)
                throw InputError(manifest.string() + ": duplicate case id '" + c.id + "' on lines " + std::to_string(first.line) + " and " +
                                 std::to_string(c.line));
            auto where = [](const BatchCase& b) { return b.line > 0 ? "line " + std::to_string(b.line) : b.input.filename().string(); };
            throw InputError(manifest.string() + ": case ids '" + first.id + "' (" + where(first) + ") and '" + c.id + "' (" + where(c) +
                             ") differ only in case: their files would be one on macOS and Windows");
        }
        split_words(c.options);  // refuse unbalanced quotes before anything runs
    }
    return cases;
}

}  // namespace heartsim::cli
