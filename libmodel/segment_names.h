/// @file segment_names.h
/// @brief Segment names of a label map (3D Slicer's .seg.nrrd, or a label table beside a NIfTI):
/// choosing labels by name, telling heart muscle from blood pool by name, naming materials.
///
/// A name is judged by words in it (lower case, as substrings), non-muscle words first:
///   not muscle: blood, cavity, pool, lumen, chamber, aort, arter, vein, venous, vena, cava,
///               vessel, valve, fat, fluid, pericard, background
///   muscle:     myo (myocardium, myocardial, "LV myo"), muscle, muscul, wall, septum, septal
/// so "LV cavity", "blood pool", "aortic wall" and "vessel wall" are not heart muscle, and
/// "Myocardium", "LV wall" and "septum" are. "Left ventricle" and "atrium" say neither: in most
/// label sets they name the blood cavity, in some the whole chamber.
#pragma once

#include <map>
#include <string>
#include <vector>

namespace heartsim {

/// Label value -> segment name; empty when the volume names nothing.
using SegmentNames = std::map<int, std::string>;

enum class SegmentKind {
    heart_muscle,  ///< the name holds a muscle word and no non-muscle word
    not_muscle,    ///< the name holds a non-muscle word (blood, cavity, vessel, …)
    unnamed,       ///< no name, or a placeholder: "Segment_3", "Segment 3", "Label 3", "3"
    unclear,       ///< a name that says neither ("heart", "left ventricle")
};

/// What `name` says about its segment (the word lists above; case-insensitive).
SegmentKind classify_segment_name(const std::string& name);

/// A label value: an integer and nothing else (surrounding blanks allowed), in int's range. False
/// (and `value` untouched) otherwise. How a tissue choice tells a number from a name, and how a label
/// table's values are read.
bool parse_label_value(const std::string& text, int& value);

/// The word of `name` that made classify_segment_name call it not heart muscle ("blood",
/// "cavity", …), or empty.
std::string non_muscle_word(const std::string& name);

/// Labels given on the command line, each a label number or a segment name, in the order given
/// (duplicates dropped). A number is a label value even where a segment is named like it; a name
/// is matched against `names` case-insensitively, an underscore matching a blank, surrounding
/// blanks ignored. Two segments of the same name: the lower label.
/// Throws InputError "`option` 'X' names no segment; segments: 1 'blood pool', 2 'myocardium'"
/// (or, when `names` is empty, that the volume names no segments).
std::vector<int> resolve_label_choice(const std::vector<std::string>& given, const SegmentNames& names,
                                      const std::string& option);

/// The tissue labels when none are chosen: label 1 (HVSMR: 1 = myocardium), unless the
/// volume names its segments, some are named as heart muscle, and label 1 is not (a non-muscle
/// name, a placeholder name, or no segment 1 at all): then those segments, and `note` says so.
/// Label maps without names (HVSMR) always get label 1.
std::vector<int> default_tissue_labels(const SegmentNames& names, std::string* note = nullptr);

/// Warnings about a tissue choice: one for each chosen label whose segment name is not heart
/// muscle or says neither, naming the segments that are heart muscle, if any; a placeholder name
/// ("Segment_1") warns only when another segment is named as heart muscle. Labels without a
/// name give none.
std::vector<std::string> tissue_name_warnings(const std::vector<int>& tissue_labels, const SegmentNames& names);

/// The material name of a tissue label: its segment name; without one, `myocardium` for
/// label 1 (the HVSMR convention) and `label_<n>` otherwise.
std::string material_name(int label, const SegmentNames& names);

/// "2 'myocardium'" for label 2 named myocardium, "2" for an unnamed one.
std::string describe_label(int label, const SegmentNames& names);

}  // namespace heartsim
