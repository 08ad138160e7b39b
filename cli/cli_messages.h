/// @file cli_messages.h
/// @brief What heartprep and heartsim say about a command line their parser (CLI11) refused: the
/// words it did not expect in the order they were typed, the nearest option for each mistyped
/// one, and the --help of the command that was being parsed. Header-only, for the two programs
/// (libmodel itself does not use CLI11).
#pragma once

#include "libmodel/plausible.h"
#include "libmodel/text.h"

#include <CLI/CLI.hpp>

#include <cmath>
#include <filesystem>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace heartsim::cli_messages {

/// The innermost subcommand of `app` that the parse reached (`app` itself when none).
inline const CLI::App* parsed_command(const CLI::App& app) {
    for (const CLI::App* command : app.get_subcommands())
        if (command->parsed()) return parsed_command(*command);
    return &app;
}

/// "--name" and "-n" spellings of every option of `command` and of the commands around it.
inline std::vector<std::string> option_names(const CLI::App* command) {
    std::vector<std::string> names;
    for (; command != nullptr; command = command->get_parent())
        for (const CLI::Option* option : command->get_options()) {
            for (const std::string& name : option->get_lnames()) names.push_back("--" + name);
            for (const std::string& name : option->get_snames()) names.push_back("-" + name);
        }
    return names;
}

/// CLI11's own wording of a refused value, in the programs' words: "Could not convert: --steps =
/// abc", "--gravity: At Most 3 required but received 4" and "--haptic-rate: Value 99 not in range
/// 100.000000 to 10000.000000" become "--steps: 'abc' is not a whole number it takes", "--gravity
/// takes 3 values, not 4" and "--haptic-rate: 99 is outside [100, 10000]". Other texts unchanged.
inline std::string plain_words(const CLI::App* command, const std::string& text) {
    std::smatch m;
    static const std::regex conversion(R"(^Could not convert: (\S+) = (.*)$)");
    static const std::regex count(R"(^(\S+): At (Most|Least) (\d+) required but received (\d+)$)");
    static const std::regex range(R"(^(\S+): Value (\S+) not in range (\S+) to (\S+)$)");
    auto trimmed = [](std::string number) {  // "100.000000" → "100"
        if (number.find('.') != std::string::npos && number.find_first_of("eE") == std::string::npos) {
            number.erase(number.find_last_not_of('0') + 1);
            if (number.back() == '.') number.pop_back();
        }
        return number;
    };
    if (std::regex_match(text, m, conversion)) {
        std::string kind = "a value";
        for (const CLI::App* c = command; c != nullptr; c = c->get_parent())
            if (const CLI::Option* option = c->get_option_no_throw(m[1].str())) {
                const std::string type = option->get_type_name();
                kind = type.rfind("INT", 0) == 0 || type.rfind("UINT", 0) == 0 ? "a whole number" : type.rfind("FLOAT", 0) == 0 ? "a number" : kind;
                break;
            }
        return m[1].str() + ": '" + m[2].str() + "' is not " + kind + " it takes";
    }
    if (std::regex_match(text, m, count))
        return m[1].str() + " takes " + (m[2] == "Most" ? "at most " : "at least ") + m[3].str() + " value" + (m[3] == "1" ? "" : "s") +
               ", not " + m[4].str();
    if (std::regex_match(text, m, range))
        return m[1].str() + ": " + m[2].str() + " is outside [" + trimmed(m[3].str()) + ", " + trimmed(m[4].str()) + "]";
    return text;
}

/// The message for `error`, thrown by `app.parse(argc, argv)`. For words the parser did not
/// expect: "not expected: --smothing 0.3 (did you mean --smoothing?)", in the order typed (CLI11
/// lists them backwards). Always ends by naming the --help that lists the options, as
/// "(heartprep build --help lists the options)".
inline std::string parse_error_message(const CLI::App& app, const CLI::ParseError& error, int argc, const char* const* argv) {
    const CLI::App* command = parsed_command(app);
    std::string usage;
    for (const CLI::App* c = command; c != nullptr; c = c->get_parent()) usage = c->get_name() + (usage.empty() ? "" : " " + usage);
    const std::string help = " (" + usage + " --help lists the " + (command == &app ? "commands and options" : "options") + ")";
    if (dynamic_cast<const CLI::ExtrasError*>(&error) == nullptr) return plain_words(command, error.what()) + help;

    std::vector<std::string> left = app.remaining(true);  // the whole tree's unexpected words
    std::vector<std::string> typed, suggestions;
    const std::vector<std::string> names = option_names(command);
    for (int a = 1; a < argc; ++a) {
        const std::string word = argv[a];
        const auto found = std::find(left.begin(), left.end(), word);
        if (found == left.end()) continue;
        left.erase(found);
        typed.push_back(word);
        if (word.size() < 2 || word[0] != '-') continue;
        const std::string name = word.substr(0, word.find('='));  // --smothing=0.3
        if (const std::string nearest = text::nearest_word(name, names); !nearest.empty() && nearest != name)
            suggestions.push_back(name + ": did you mean " + nearest + "?");
    }
    if (typed.empty()) return std::string(error.what()) + help;
    return "not expected: " + text::join(typed, " ") + (suggestions.empty() ? "" : " (" + text::join(suggestions, "; ") + ")") + help;
}

/// A validator for an output file's name: it must end in one of `extensions` (lower case, with
/// the dot; any case accepted), since the programs write one format whatever the name says and a
/// scenario named z.stl would mislead whoever opens it next. `what` says what is written and,
/// where useful, which command writes the other formats.
inline CLI::Validator output_extension(std::vector<std::string> extensions, std::string what) {
    return CLI::Validator(
        [extensions, what](std::string& value) -> std::string {
            std::error_code error;
            if (std::filesystem::is_directory(value, error)) return {};  // "is a folder" comes later, from check_destination
            const std::string name = text::lowercase(value);
            for (const std::string& e : extensions)
                if (name.size() > e.size() && name.ends_with(e)) return {};
            return value + ": " + what + ", so the name must end in " + text::join(extensions, " or ");
        },
        "", "output extension");
}

/// A number option's value must be finite: CLI11 reads "nan" and "inf" as numbers, and its Range
/// lets NaN through (every comparison with it is false).
inline CLI::Validator finite_number() {
    return CLI::Validator(
        [](std::string& value) -> std::string {
            double number = 0;
            if (!CLI::detail::lexical_cast(value, number)) return {};  // not a number: the option's own conversion says so
            return std::isfinite(number) ? std::string() : "'" + value + "' is not a finite number";
        },
        "", "finite");
}

/// Adds finite_number() to every option of `app` and of its subcommands that takes a value and
/// is not plain text (CLI11 names a string's type TEXT), so no NaN or infinity reaches a build or
/// a session through an option: a number renamed for its help (MM, S, HZ) is checked as CLI11's
/// FLOAT is, and a lone "nan" given to a point or a plane is refused as not finite.
inline void require_finite_numbers(CLI::App& app) {
    for (CLI::Option* option : app.get_options())
        if (option->get_expected_min() > 0 && option->get_type_name() != "TEXT") option->check(finite_number());
    for (CLI::App* command : app.get_subcommands({})) require_finite_numbers(*command);
}

/// The first option of `command` given with an empty value ("--trajectory \"\"", a script's unset
/// variable), as "--trajectory: the value is empty; …"; "" when none. Such a value read as the
/// option not given, so a run lost its gesture without a word.
inline std::string empty_value_given(const CLI::App& command) {
    for (const CLI::Option* option : command.get_options()) {
        if (option->count() == 0 || option->get_expected_min() == 0) continue;  // not given, or a flag
        for (const std::string& value : option->results())
            if (value.empty())
                return option->nonpositional() ? option->get_name(false, true) + ": the value is empty; give one, or leave the option out"
                                               : "the " + option->get_name() + " given is an empty name; give a file";
    }
    return {};
}

/// A number option's value at or above 0 (`strictly`: above it), said in a few words
/// (CLI::NonNegativeNumber's message prints the largest double in full).
inline CLI::Validator above_zero(bool strictly) {
    return CLI::Validator(
        [strictly](std::string& value) -> std::string {
            double number = 0;
            if (!CLI::detail::lexical_cast(value, number)) return {};  // not a number: the option's own conversion says so
            if (strictly ? number > 0 : number >= 0) return {};
            return std::string(strictly ? "must be more than 0" : "must be 0 or more") + ", not " + value;
        },
        strictly ? "> 0" : "≥ 0", strictly ? "positive" : "non-negative");
}
inline CLI::Validator non_negative() { return above_zero(false); }
inline CLI::Validator positive() { return above_zero(true); }

/// A number option's value within a plausible range (plausible.h): far wider than any heart
/// needs, so what lies outside is a unit mistake or a typo, refused at once instead of after a
/// build that runs out of memory or ends in a NaN.
inline CLI::Validator within(const plausible::Range& range) {
    return CLI::Validator(
        [range](std::string& value) -> std::string {
            double number = 0;
            if (!CLI::detail::lexical_cast(value, number)) return {};  // not a number: the option's own conversion says so
            if (range.contains(number)) return {};
            std::ostringstream text;
            const std::string unit = *range.unit ? std::string(" ") + range.unit : std::string();
            text << "must lie in the plausible range [" << range.low << ", " << range.high << "]" << unit << ", not " << value;
            return text.str();
        },
        "", "plausible");
}

}  // namespace heartsim::cli_messages
