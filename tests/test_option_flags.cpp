// libmodel names an option by its meaning ({LayoutOptions::occupancy}); the programs spell it as
// their flag (cli/option_flags.h). Checked against libmodel's own sources: every meaning it names
// in a message has a heartprep flag, so no user ever reads braces.
#include "cli/option_flags.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>

namespace heartsim::cli {
namespace {

constexpr OptionFlag table[] = {{"LayoutOptions::occupancy", "--occupancy"}, {"rest_state", "--rest-state"}};

TEST(OptionFlags, SpellsEachMeaningAsItsFlag) {
    EXPECT_EQ(spell_options("{LayoutOptions::occupancy} must be in (0, 1]", table), "--occupancy must be in (0, 1]");
    EXPECT_EQ(spell_options("use {rest_state} imaged or lower {LayoutOptions::occupancy}", table),
              "use --rest-state imaged or lower --occupancy");
    EXPECT_EQ(spell_options("no option here", table), "no option here");
    EXPECT_EQ(spell_options("", table), "");
}

TEST(OptionFlags, BracesThatNameNoOptionOfTheTableStayAsTheyAre) {
    EXPECT_EQ(spell_options("{SolverOptions::dt_ms} too long", table), "{SolverOptions::dt_ms} too long");
    EXPECT_EQ(spell_options("case{1}.nii.gz: {LayoutOptions::occupancy} too low", table), "case{1}.nii.gz: --occupancy too low");
    EXPECT_EQ(spell_options("an open { brace stays", table), "an open { brace stays");
    EXPECT_EQ(spell_options("{}", table), "{}");
}

/// The meanings libmodel's string literals name: {Struct::field} or {plain_name}.
std::set<std::string> meanings_named_in_libmodel() {
    std::set<std::string> found;
    const std::regex literal(R"("(?:[^"\\\n]|\\.)*")");
    const std::regex meaning(R"(\{([A-Za-z_][A-Za-z_0-9]*(?:::[A-Za-z_][A-Za-z_0-9]*)?)\})");
    for (const auto& entry : std::filesystem::directory_iterator(std::filesystem::path(HEARTSIM_SOURCE_DIR) / "libmodel")) {
        if (entry.path().extension() != ".cpp") continue;
        std::ifstream in(entry.path());
        std::stringstream text;
        text << in.rdbuf();
        const std::string source = text.str();
        for (std::sregex_iterator s(source.begin(), source.end(), literal), end; s != end; ++s) {
            const std::string string = s->str();
            for (std::sregex_iterator m(string.begin(), string.end(), meaning); m != end; ++m) found.insert((*m)[1].str());
        }
    }
    return found;
}

TEST(OptionFlags, HeartprepSpellsEveryOptionLibmodelNames) {
    const std::set<std::string> named = meanings_named_in_libmodel();
    EXPECT_GE(named.size(), 20u) << "libmodel's messages name its options by their meaning";
    for (const std::string& option : named) {
        bool spelled = false;
        for (const OptionFlag& f : heartprep_flags) spelled = spelled || f.option == option;
        EXPECT_TRUE(spelled) << "{" << option << "} has no heartprep flag in cli/option_flags.h";
    }
    for (const OptionFlag& f : heartprep_flags) EXPECT_TRUE(f.flag.starts_with("--")) << f.option;
}

}  // namespace
}  // namespace heartsim::cli
