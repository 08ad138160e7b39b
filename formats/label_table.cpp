#include "formats/label_table.h"

#include "libmodel/errors.h"
#include "libmodel/segment_names.h"
#include "libmodel/text.h"

#include <fstream>
#include <sstream>
#include <vector>

namespace heartsim {

namespace {

using text::trim;

std::string unquote(std::string text) {
    text = trim(text);
    if (text.size() >= 2 && text.front() == '"' && text.back() == '"') text = text.substr(1, text.size() - 2);
    return trim(text);
}

}  // namespace

std::map<int, std::string> read_label_table(const std::filesystem::path& path) {
    std::error_code error;
    if (!std::filesystem::is_regular_file(path, error))
        throw InputError(path.string() + ": label table not found (--labels expects a file)");
    // A label table is a few lines; a large file is something else given by mistake.
    if (std::filesystem::file_size(path, error) > 16u * 1024 * 1024)
        throw InputError(path.string() + ": label table larger than 16 MB; expected a text file of label names");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path.string() + ": cannot open label table for reading");
    const std::string expected =
        "; expected 'VALUE NAME R G B A' (3D Slicer colour table), 'VALUE R G B A VIS MSH \"NAME\"' (ITK-SNAP) or "
        "'VALUE,NAME,...' (CSV)";
    std::map<int, std::string> names;
    std::string line;
    bool first_content_line = true;
    for (int number = 1; std::getline(in, line); ++number) {
        const std::string text = trim(line);
        if (text.empty() || text[0] == '#') continue;
        if (text.find('\0') != std::string::npos)
            throw InputError(path.string() + ": line " + std::to_string(number) + " holds a NUL byte; expected a text label table");
        const bool header_line = first_content_line;
        first_content_line = false;
        int label = 0;
        std::string name;
        const auto quote = text.find('"'), comma = text.find(',');
        if (quote != std::string::npos && (comma == std::string::npos || quote < comma)) {  // ITK-SNAP
            std::istringstream fields(text.substr(0, quote));
            std::string value;
            fields >> value;
            if (!parse_label_value(value, label) || text.find('"', quote + 1) == std::string::npos)
                throw InputError(path.string() + ": line " + std::to_string(number) + " '" + text.substr(0, 60) + "'" + expected);
            name = unquote(text.substr(quote));
        } else if (comma != std::string::npos) {  // CSV, whose names may be quoted
            const std::string value = text.substr(0, comma);
            if (!parse_label_value(value, label)) {
                if (header_line) continue;  // "LabelValue,Name,Color_R,…"
                throw InputError(path.string() + ": line " + std::to_string(number) + " '" + text.substr(0, 60) + "'" + expected);
            }
            const std::string rest = text.substr(comma + 1);
            name = unquote(rest.substr(0, rest.find(',')));
        } else {  // 3D Slicer colour table
            std::istringstream fields(text);
            std::string value;
            fields >> value >> name;
            if (!parse_label_value(value, label) || name.empty())
                throw InputError(path.string() + ": line " + std::to_string(number) + " '" + text.substr(0, 60) + "'" + expected);
            for (char& c : name)
                if (c == '_') c = ' ';
        }
        if (name.empty())
            throw InputError(path.string() + ": line " + std::to_string(number) + ": label " + std::to_string(label) +
                             " has an empty name" + expected);
        if (!names.emplace(label, name).second)
            throw InputError(path.string() + ": line " + std::to_string(number) + ": label " + std::to_string(label) +
                             " is named twice ('" + names[label] + "' and '" + name + "'); expected one name per label");
    }
    if (names.empty()) throw InputError(path.string() + ": label table names no labels" + expected);
    return names;
}

}  // namespace heartsim
