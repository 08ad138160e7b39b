// A headless run's progress lines (runtime/app/run_progress.h; docs/runtime.md "Progress of a headless
// run"): the cadence as a function of the steps, the simulated time and the wall time the caller
// gives, and the lines `heartsim run --headless` prints on stderr over a run of 40,000 steps.
#include "runtime/app/run_progress.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

using namespace heartsim;
using test::quoted;

namespace {

/// One progress line, read back.
struct Line {
    int percent = 0;
    double simulated_ms = 0, total_ms = 0, wall_s = 0, left_s = -1;
    bool closing = false;
};

/// The progress lines of `text`, in order; any other line that starts "heartsim: run:" fails the test.
std::vector<Line> progress_lines(const std::string& text) {
    const std::regex going(R"(heartsim: run: ([0-9]+)% \(([0-9]+) of ([0-9]+) ms simulated\) after ([0-9.]+) s, about ([0-9.]+) s left)");
    const std::regex closing(R"(heartsim: run: 100% \(([0-9]+) ms simulated\) in ([0-9.]+) s)");
    std::vector<Line> lines;
    std::istringstream in(text);
    for (std::string row; std::getline(in, row);) {
        if (row.rfind("heartsim: run:", 0) != 0) continue;
        std::smatch m;
        if (std::regex_match(row, m, going))
            lines.push_back({std::stoi(m[1]), std::stod(m[2]), std::stod(m[3]), std::stod(m[4]), std::stod(m[5]), false});
        else if (std::regex_match(row, m, closing))
            lines.push_back({100, std::stod(m[1]), std::stod(m[1]), std::stod(m[2]), -1, true});
        else
            ADD_FAILURE() << "not a progress line: " << row;
    }
    return lines;
}

/// What a RunProgress said, driven step by step: step k (1-based) ends at k·step_ms of simulated
/// time and `wall_per_step` · k seconds of wall time.
std::string drive(int steps, double end_ms, double step_ms, double wall_per_step, int* said = nullptr) {
    std::FILE* file = std::tmpfile();
    RunProgress progress(steps, end_ms, file);
    int k = 0;
    for (; k < steps && (end_ms <= 0 || k * step_ms < end_ms); ++k) progress.after_step(k + 1, (k + 1) * step_ms, step_ms, wall_per_step * (k + 1));
    progress.finish(k * step_ms, wall_per_step * k);
    if (said) *said = progress.lines();
    std::rewind(file);
    std::string text;
    for (int c; (c = std::fgetc(file)) != EOF;) text += char(c);
    std::fclose(file);
    return text;
}

}  // namespace

// A run shorter than 5 s of wall time and of fewer than 40,000 steps says nothing, not even the
// closing line.
TEST(RunProgress, AShortRunSaysNothing) {
    int said = -1;
    EXPECT_EQ(drive(39999, 0.0, 0.5, 4.99 / 39999, &said), "");
    EXPECT_EQ(said, 0);
}

// 1,000 steps over 12 s of wall time: a line at the first step past 5 s and past 10 s, then the
// closing line; each line's estimate is the rest at the pace so far, wall · (1 − f) / f.
TEST(RunProgress, ALongRunSaysAFrameEveryFiveSecondsOfWallTime) {
    const std::vector<Line> lines = progress_lines(drive(1000, 0.0, 0.5, 0.012));
    ASSERT_EQ(lines.size(), 3u);
    // Step 417 is the first past 5 s (417 × 0.012 = 5.004 s), step 834 the first 5 s after it.
    EXPECT_EQ(lines[0].percent, 41);
    EXPECT_NEAR(lines[0].simulated_ms, 208.5, 0.5);  // 417 × 0.5 ms, printed to the ms
    EXPECT_DOUBLE_EQ(lines[0].total_ms, 500.0);
    EXPECT_NEAR(lines[0].wall_s, 5.0, 0.05);
    EXPECT_NEAR(lines[0].left_s, 5.004 * (1000 - 417) / 417.0, 0.05);
    EXPECT_EQ(lines[1].percent, 83);
    EXPECT_NEAR(lines[1].wall_s, 10.0, 0.05);
    EXPECT_TRUE(lines[2].closing);
    EXPECT_DOUBLE_EQ(lines[2].simulated_ms, 500.0);
    EXPECT_NEAR(lines[2].wall_s, 12.0, 0.05);
}

// 40,000 steps or more: 25, 50 and 75 % are said as they pass whatever the wall clock (here
// none passes), then the closing line. With --seconds the fraction is the simulated time's.
TEST(RunProgress, ARunOfFortyThousandStepsSaysItsQuarters) {
    for (const double end_ms : {0.0, 12000.0}) {
        SCOPED_TRACE(end_ms);
        const std::vector<Line> lines = progress_lines(drive(48000, end_ms, 0.25, 0.0));
        ASSERT_EQ(lines.size(), 4u);
        for (int q = 0; q < 3; ++q) {
            EXPECT_EQ(lines[std::size_t(q)].percent, 25 * (q + 1));
            EXPECT_NEAR(lines[std::size_t(q)].simulated_ms, 3000.0 * (q + 1), 1.0);
            EXPECT_DOUBLE_EQ(lines[std::size_t(q)].total_ms, 12000.0);
        }
        EXPECT_TRUE(lines[3].closing);
        EXPECT_DOUBLE_EQ(lines[3].simulated_ms, 12000.0);
    }
}

// The command: `heartsim run --headless --steps 40000` on a small phantom says its quarters on
// stderr (stdout apart), in order, of the total the run reports, and closes at 100 % with the
// simulated time of its "ran … ms simulated" line; a --seconds run the same by simulated time.
TEST(RunProgress, HeadlessRunsPrintTheirProgressOnStderr) {
    const auto& phantom = test::built_phantom("--particles 500");
    test::TempDir dir;
    for (const std::string& length : {std::string("--steps 40000"), std::string("--seconds 40")}) {
        SCOPED_TRACE(length);
        const auto err = dir / "stderr.txt";
        // stderr to its file inside the subshell; run_command takes stdout (and the subshell's stderr).
        std::string command = quoted(HEARTSIM_EXE);
        command += " run " + quoted(phantom) + " --headless --backend cpu " + length + " 2>" + quoted(err);
        const auto run = test::run_command("(" + command + ")");
        ASSERT_EQ(run.exit_code, 0) << run.output;
        EXPECT_EQ(run.output.find("heartsim: run:"), std::string::npos) << "progress on stdout:\n" << run.output;
        std::ifstream in(err);
        const std::string text((std::istreambuf_iterator<char>(in)), {});
        const std::vector<Line> lines = progress_lines(text);
        ASSERT_GE(lines.size(), 4u) << text;
        std::smatch m;
        ASSERT_TRUE(std::regex_search(run.output, m, std::regex(R"(ran [0-9]+ steps \([0-9]+ substeps\), ([0-9.e+]+) ms simulated)")))
            << run.output;
        const double simulated = std::stod(m[1]);
        std::vector<int> quarters;
        for (std::size_t k = 0; k + 1 < lines.size(); ++k) {
            EXPECT_FALSE(lines[k].closing) << text;
            EXPECT_NEAR(lines[k].total_ms, simulated, 1.0 + 1e-3 * simulated) << text;
            EXPECT_NEAR(lines[k].percent, 100.0 * lines[k].simulated_ms / lines[k].total_ms, 1.0) << text;
            if (k > 0) {
                EXPECT_GE(lines[k].percent, lines[k - 1].percent) << text;
                EXPECT_GT(lines[k].simulated_ms, lines[k - 1].simulated_ms) << text;
                EXPECT_GE(lines[k].wall_s, lines[k - 1].wall_s) << text;
            }
            if (lines[k].percent % 25 == 0) quarters.push_back(lines[k].percent);
        }
        EXPECT_EQ(quarters, (std::vector<int>{25, 50, 75})) << text;
        EXPECT_TRUE(lines.back().closing) << text;
        EXPECT_NEAR(lines.back().simulated_ms, simulated, 1.0 + 1e-3 * simulated) << text;
    }
}

// A headless haptic session follows the wall clock, so one of 6 s runs at least 5 s of it and
// says a line there, of its 6 s, then closes at 100 %.
TEST(RunProgress, AHapticSessionSaysItsProgressByTheWallClock) {
    const auto& phantom = test::built_phantom("--particles 500");
    test::TempDir dir;
    const auto err = dir / "stderr.txt";
    const std::string device = std::string(" --device simulated:") + quoted(std::filesystem::path(HEARTSIM_SOURCE_DIR) / "samples/haptics/press_phantom.csv");
    std::string command = quoted(HEARTSIM_EXE);
    command += " run " + quoted(phantom) + " --headless --backend cpu --seconds 6" + device + " 2>" + quoted(err);
    const auto run = test::run_command("(" + command + ")");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    std::ifstream in(err);
    const std::string text((std::istreambuf_iterator<char>(in)), {});
    const std::vector<Line> lines = progress_lines(text);
    ASSERT_GE(lines.size(), 2u) << text;
    EXPECT_FALSE(lines.front().closing) << text;
    EXPECT_GE(lines.front().wall_s, 5.0) << text;
    EXPECT_DOUBLE_EQ(lines.front().total_ms, 6000.0) << text;
    EXPECT_TRUE(lines.back().closing) << text;
    EXPECT_GT(lines.back().simulated_ms, lines.front().simulated_ms) << text;
}
