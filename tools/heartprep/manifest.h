/// @file manifest.h
/// @brief `heartprep batch`'s list of cases: a CSV manifest of lines `input[,case_id[,options]]`
/// or a folder of label maps. Apart from command_batch.cpp so that it can be read without
/// running a batch (tests/fuzz/fuzz_batch_manifest.cpp).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace heartsim::cli {

struct BatchCase {
    std::string id;                ///< names the output file DIR/<id>.h5: letters, digits, '.', '_', '-'
    std::filesystem::path input;   ///< label map; a relative manifest path is taken from the manifest's folder
    std::string options;           ///< build options for this case (replace the batch's --options)
    int line = 0;                  ///< manifest line, for messages (0 for a folder)
};

/// The cases of `manifest`, a CSV file (a header line starting with `input` and lines starting
/// with # ignored; quote options that contain commas) or a folder (its label maps in name order,
/// each with `default_options`; with a `pattern`, only the files whose name matches that shell
/// pattern, e.g. `*-label.nii.gz`, so an intensity image beside the labels is left out). Throws
/// InputError naming the manifest and the line for: a missing or unreadable manifest, a line of
/// more than three fields or without an input, no cases, a case id with other characters, a
/// duplicate case id (two files of one folder with one stem), unbalanced quotes in options.
std::vector<BatchCase> read_manifest(const std::filesystem::path& manifest, const std::string& default_options,
                                     const std::string& pattern = "");

/// Splits build options as a shell would for plain words and quotes ("a b", 'a b'); no expansion.
/// Throws InputError on an unbalanced quote.
std::vector<std::string> split_words(const std::string& text);

}  // namespace heartsim::cli
