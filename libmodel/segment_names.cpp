#include "libmodel/segment_names.h"

#include "libmodel/errors.h"
#include "libmodel/text.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <limits>
#include <regex>

namespace heartsim {

namespace {

using text::lowercase;
using text::trim;

// The word lists of segment_names.h; substrings of the lower-case name.
constexpr std::array<const char*, 17> non_muscle_words = {"blood", "cavity", "pool",  "lumen",  "chamber",  "aort",
                                                          "arter", "vein",   "venous", "vena",  "cava",     "vessel",
                                                          "valve", "fat",    "fluid",  "pericard", "background"};
constexpr std::array<const char*, 6> muscle_words = {"myo", "muscle", "muscul", "wall", "septum", "septal"};

/// A name as matched: lower case, an underscore as a blank (colour tables write "blood_pool"),
/// surrounding blanks ignored.
std::string comparable(const std::string& name) {
    std::string text = lowercase(trim(name));
    std::replace(text.begin(), text.end(), '_', ' ');
    return text;
}

std::vector<int> muscle_labels(const SegmentNames& names) {
    std::vector<int> labels;
    for (const auto& [label, name] : names)
        if (classify_segment_name(name) == SegmentKind::heart_muscle) labels.push_back(label);
    return labels;
}

std::string describe_labels(const std::vector<int>& labels, const SegmentNames& names) {
    std::string text;
    for (int label : labels) text += (text.empty() ? "" : ", ") + describe_label(label, names);
    return text;
}

std::string list_segments(const SegmentNames& names) {
    std::vector<int> labels;
    for (const auto& entry : names) labels.push_back(entry.first);
    return describe_labels(labels, names);
}

}  // namespace

bool parse_label_value(const std::string& text, int& value) {
    const std::string t = trim(text);
    if (t.empty()) return false;
    std::size_t used = 0;
    try {
        const long long parsed = std::stoll(t, &used);
        if (used != t.size() || parsed < std::numeric_limits<int>::min() || parsed > std::numeric_limits<int>::max()) return false;
        value = int(parsed);
        return true;
    } catch (const std::exception&) {
        return false;
    }
}

std::string non_muscle_word(const std::string& name) {
    const std::string lower = lowercase(name);
    for (const char* word : non_muscle_words)
        if (lower.find(word) != std::string::npos) return word;
    return {};
}

SegmentKind classify_segment_name(const std::string& name) {
    const std::string lower = lowercase(trim(name));
    // 3D Slicer names new segments "Segment_1", "Segment_2"; heartprep's writer "Label 1" when given none.
    static const std::regex placeholder(R"(((segment|label)[ _-]*)?\d+)");
    if (lower.empty() || std::regex_match(lower, placeholder)) return SegmentKind::unnamed;
    if (!non_muscle_word(lower).empty()) return SegmentKind::not_muscle;
    for (const char* word : muscle_words)
        if (lower.find(word) != std::string::npos) return SegmentKind::heart_muscle;
    return SegmentKind::unclear;
}

std::string describe_label(int label, const SegmentNames& names) {
    auto found = names.find(label);
    return found == names.end() ? std::to_string(label) : std::to_string(label) + " '" + found->second + "'";
}

std::vector<int> resolve_label_choice(const std::vector<std::string>& given, const SegmentNames& names,
                                      const std::string& option) {
    std::vector<int> labels;
    for (const std::string& text : given) {
        int label = 0;
        if (!parse_label_value(text, label)) {
            const std::string wanted = comparable(text);
            auto found = std::find_if(names.begin(), names.end(),
                                      [&](const auto& entry) { return comparable(entry.second) == wanted; });
            if (found == names.end()) {
                if (names.empty())
                    throw InputError(option + " '" + text +
                                     "' is not a label number, and the volume names no segments (a 3D Slicer .seg.nrrd "
                                     "names them; for another format give a label table with {label_table})");
                throw InputError(option + " '" + text + "' names no segment; segments: " + list_segments(names));
            }
            label = found->first;
        }
        if (std::find(labels.begin(), labels.end(), label) == labels.end()) labels.push_back(label);
    }
    return labels;
}

std::vector<int> default_tissue_labels(const SegmentNames& names, std::string* note) {
    auto first = names.find(1);
    const SegmentKind first_kind = first == names.end() ? SegmentKind::unnamed : classify_segment_name(first->second);
    const std::vector<int> muscle = muscle_labels(names);
    // A name that says neither ("heart") is trusted as label 1 (with a warning, tissue_name_warnings).
    if (names.empty() || first_kind == SegmentKind::heart_muscle || first_kind == SegmentKind::unclear || muscle.empty())
        return {1};
    if (note)
        *note = "no {SelectionOptions::tissue_labels} given: label " +
                (first == names.end() ? std::string("1 is no segment")
                                      : describe_label(1, names) + (first_kind == SegmentKind::not_muscle ? " is not heart muscle"
                                                                                                          : " has no name")) +
                "; built the segment(s) named as heart muscle instead: " + describe_labels(muscle, names) +
                " (give {SelectionOptions::tissue_labels} to choose)";
    return muscle;
}

std::vector<std::string> tissue_name_warnings(const std::vector<int>& tissue_labels, const SegmentNames& names) {
    std::vector<std::string> warnings;
    std::vector<int> muscle = muscle_labels(names);
    std::string elsewhere;
    std::vector<int> others;
    for (int label : muscle)
        if (std::find(tissue_labels.begin(), tissue_labels.end(), label) == tissue_labels.end()) others.push_back(label);
    if (!others.empty()) elsewhere = "; the heart muscle is segment " + describe_labels(others, names);
    for (int label : tissue_labels) {
        auto found = names.find(label);
        if (found == names.end()) continue;
        switch (classify_segment_name(found->second)) {
        case SegmentKind::not_muscle:
            warnings.push_back("tissue label " + describe_label(label, names) + " is not heart muscle by its name ('" +
                               non_muscle_word(found->second) + "'): it is simulated as tissue all the same" + elsewhere);
            break;
        case SegmentKind::unclear:
            warnings.push_back("tissue label " + describe_label(label, names) +
                               " does not name heart muscle (no word such as myocardium, muscle, wall or septum); check "
                               "that {SelectionOptions::tissue_labels} chose the myocardium" + elsewhere);
            break;
        case SegmentKind::unnamed:
            if (!others.empty())
                warnings.push_back("tissue label " + describe_label(label, names) + " has no name that says what it is" + elsewhere);
            break;
        default: break;
        }
    }
    return warnings;
}

std::string material_name(int label, const SegmentNames& names) {
    auto found = names.find(label);
    if (found != names.end() && classify_segment_name(found->second) != SegmentKind::unnamed) return trim(found->second);
    return label == 1 ? "myocardium" : "label_" + std::to_string(label);
}

}  // namespace heartsim
