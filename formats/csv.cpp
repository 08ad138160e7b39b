// The CSV line splitter (csv.h).
#include "csv.h"

#include "libmodel/errors.h"

#include <algorithm>
#include <fstream>
#include <sstream>

namespace heartsim {

std::vector<std::string> csv_fields(const std::string& line) {
    std::vector<std::string> fields(1);
    bool quoted = false;
    for (std::size_t i = 0; i < line.size(); ++i) {
        const char c = line[i];
        if (quoted) {
            if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') fields.back() += '"', ++i;
            else if (c == '"') quoted = false;
            else fields.back() += c;
        } else if (c == '"') quoted = true;
        else if (c == ',') fields.emplace_back();
        else if (c != '\r') fields.back() += c;
    }
    for (auto& f : fields) {
        f.erase(0, f.find_first_not_of(" \t"));
        f.erase(f.find_last_not_of(" \t") + 1);
    }
    return fields;
}

std::string read_csv_file(const std::filesystem::path& path) {
    namespace fs = std::filesystem;
    std::error_code error;
    const fs::file_status status = fs::status(path, error);
    if (!fs::exists(status)) throw InputError(path.string() + ": file not found");
    if (fs::is_directory(status)) throw InputError(path.string() + ": is a folder; expected a CSV file");
    if (!fs::is_regular_file(status)) throw InputError(path.string() + ": not a regular file; expected a CSV file");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot be opened for reading");
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) throw InputError(path.string() + ": cannot be read");
    // Spreadsheets' "CSV UTF-8" begins with a byte order mark, which would make the header's
    // first name "\xEF\xBB\xBFtime_ms".
    std::string contents = text.str();
    if (contents.rfind("\xEF\xBB\xBF", 0) == 0) contents.erase(0, 3);
    // No text holds a NUL: a label map or a recording given where a CSV belongs read as "line 7 has
    // 5 fields", and a NUL inside a field cut the message that quoted it.
    if (const auto nul = contents.find('\0'); nul != std::string::npos)
        throw InputError(path.string() + ": holds binary data (a NUL byte on line " +
                         std::to_string(1 + std::count(contents.begin(), contents.begin() + std::ptrdiff_t(nul), '\n')) +
                         "); expected a CSV text file" +
                         (contents.rfind("\x1f\x8b", 0) == 0 ? " (this one is gzip-compressed: a .nii.gz label map?)" : ""));
    return contents;
}

}  // namespace heartsim
