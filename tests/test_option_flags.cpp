// libmodel names an option by its meaning ({LayoutOptions::occupancy}); the programs spell it as
// their flag (cli/option_flags.h). Checked against libmodel's own sources: every meaning it names
// in a message has a heartprep flag, and every one the runtime's parts name a heartsim flag, so no
// user ever reads braces.
#include "cli/option_flags.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

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

/// The meanings the string literals of the .cpp files in `folders` (under the source tree) name:
/// {Struct::field} or {plain_name}; files named in `skip` are left out.
std::set<std::string> meanings_named_in(const std::vector<std::string>& folders, const std::set<std::string>& skip = {}) {
    std::set<std::string> found;
    const std::regex literal(R"("(?:[^"\\\n]|\\.)*")");
    const std::regex meaning(R"(\{([A-Za-z_][A-Za-z_0-9]*(?:::[A-Za-z_][A-Za-z_0-9]*)?)\})");
    for (const std::string& folder : folders)
        for (const auto& entry : std::filesystem::directory_iterator(std::filesystem::path(HEARTSIM_SOURCE_DIR) / folder)) {
            if (entry.path().extension() != ".cpp" || skip.count(entry.path().filename().string())) continue;
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

/// The meanings libmodel's string literals name.
std::set<std::string> meanings_named_in_libmodel() { return meanings_named_in({"libmodel", "libmodel/sim", "libmodel/surgery"}); }

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

// The runtime's parts below heartsim's command line name their options by meaning too (the live
// link, the section plane, the plans, the haptic run): heartsim spells every one, and its table
// holds no meaning that no part names.
TEST(OptionFlags, HeartsimSpellsEveryOptionTheRuntimeNames) {
    const std::set<std::string> named = meanings_named_in(
        {"runtime/app", "runtime/core", "runtime/backend", "runtime/surgery", "runtime/link", "runtime/view", "runtime/haptics"},
        {"main.cpp", "run_modes.cpp"});
    EXPECT_GE(named.size(), 10u) << "the runtime's messages name its options by their meaning";
    for (const std::string& option : named) {
        bool spelled = false;
        for (const OptionFlag& f : heartsim_flags) spelled = spelled || f.option == option;
        EXPECT_TRUE(spelled) << "{" << option << "} has no heartsim flag in cli/option_flags.h";
    }
    for (const OptionFlag& f : heartsim_flags) {
        EXPECT_TRUE(f.flag.starts_with("--")) << f.option;
        EXPECT_TRUE(named.count(std::string(f.option))) << f.option << ": named by no runtime part (a flag the table need not spell)";
    }
    EXPECT_EQ(spell_options("{SlicerLinkOptions::endpoint} 18944: port in use; give a free one, e.g. {SlicerLinkOptions::endpoint} 18945",
                            heartsim_flags),
              "--igtl 18944: port in use; give a free one, e.g. --igtl 18945");
}

}  // namespace
}  // namespace heartsim::cli
