// The window driven as training staff drive it: real X input events (xdotool, XTEST) into
// heartsim's GLFW window under Xvfb, its stdout event lines and its P-key screenshots as the
// observables (docs/runtime.md "Window mode"). Every wait is for an event the window says (a
// line on stdout, a screenshot written after the frame that took an input in), polled with a
// generous limit; nothing asserts how long anything took, and no outcome hangs on a time passing
// (the mouse device's inputs are waited for until the simulation has them: wait_in_place). Also:
// the key table in docs/runtime.md is the code's (runtime/view/window_keys.h), and `heartsim run --help`
// prints it.
#include "defect_block_scenario.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/recording.h"
#include "formats/scenario.h"
#include "formats/state.h"
#include "libmodel/surgery/incision.h"
#include "runtime/view/png.h"
#include "runtime/gl/hud.h"
#include "runtime/view/window_keys.h"
#include "runtime/app/window_run.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <thread>

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

extern char** environ;

using namespace heartsim;
using test::quoted;
using test::cut_pixels;
namespace fs = std::filesystem;

namespace {

const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border"); }

pid_t spawn_shell(const std::string& command) {
    pid_t pid = -1;
    const char* argv[] = {"/bin/sh", "-c", command.c_str(), nullptr};
    if (posix_spawn(&pid, "/bin/sh", nullptr, nullptr, const_cast<char**>(argv), environ) != 0) return -1;
    return pid;
}

/// Ends `pid` (TERM, then KILL after 10 s) and reaps it; returns its exit status or -1.
int end_process(pid_t pid) {
    int status = 0;
    if (waitpid(pid, &status, WNOHANG) == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    kill(pid, SIGTERM);
    for (int i = 0; i < 100; ++i) {
        if (waitpid(pid, &status, WNOHANG) == pid) return -1;
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
    return -1;
}

/// An Xvfb server of its own (640×480×24, or `screen`) on the first free display it finds (-displayfd).
class XServer {
public:
    explicit XServer(const fs::path& dir, const std::string& screen = "640x480x24") {
        const fs::path number = dir / "display";
        pid_ = spawn_shell("exec Xvfb -displayfd 3 -screen 0 " + screen + " -nolisten tcp 3>" + quoted(number) + " 2>" + quoted(dir / "xvfb.log"));
        for (int i = 0; i < 300 && display_.empty(); ++i) {
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
            std::ifstream in(number);
            std::string n;
            if (std::getline(in, n) && !n.empty()) display_ = ":" + n;
        }
    }
    ~XServer() {
        if (pid_ > 0) end_process(pid_);
    }
    const std::string& display() const { return display_; }

private:
    pid_t pid_ = -1;
    std::string display_;
};

/// heartsim in a window on `display`, its stdout and stderr in a file.
class Window {
public:
    /// `environment`: more NAME=VALUE words for its environment.
    Window(const XServer& x, const fs::path& dir, const std::string& arguments, const std::string& environment = "")
        : display_(x.display()), log_(dir / "heartsim.log") {
        pid_ = spawn_shell("ASAN_OPTIONS=\"${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0\" DISPLAY=" + display_ + " " + environment + " exec timeout 600 " +
                           quoted(HEARTSIM_EXE) + " run " + arguments + " >" + quoted(log_) + " 2>&1");
    }
    ~Window() {
        if (pid_ > 0) end_process(pid_);
    }
    std::string output() const {
        std::ifstream in(log_);
        std::stringstream text;
        text << in.rdbuf();
        return text.str();
    }
    /// Polls the output for `text` at or after `from` (at most `seconds`); its position or npos.
    std::size_t wait_for(const std::string& text, std::size_t from = 0, double seconds = 180) {
        const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
        while (std::chrono::steady_clock::now() < until) {
            const std::string out = output();
            if (const auto at = out.find(text, from); at != std::string::npos) return at;
            if (exited()) return output().find(text, from);
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        return std::string::npos;
    }
    /// xdotool with this display; its exit status.
    int xdotool(const std::string& arguments) const {
        return test::run_command("DISPLAY=" + display_ + " timeout 120 xdotool " + arguments).exit_code;
    }
    /// The window's X id (decimal), or "" when it does not show within 60 s.
    std::string id() const {
        const auto r = test::run_command("DISPLAY=" + display_ + " timeout 60 xdotool search --sync --onlyvisible --name heartsim");
        const auto end = r.output.find('\n');
        return r.exit_code == 0 ? r.output.substr(0, end) : "";
    }
    /// Waits for the window and gives it the keyboard focus (no window manager: XSetInputFocus).
    bool focus() const { return xdotool("search --sync --onlyvisible --name heartsim windowfocus --sync %1") == 0; }
    bool exited() {
        if (exit_code_ >= -1 && reaped_) return true;
        int status = 0;
        if (waitpid(pid_, &status, WNOHANG) == pid_) {
            reaped_ = true, pid_ = -1;
            exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
            return true;
        }
        return false;
    }
    /// Waits for the process to end (at most `seconds`); its exit status, -2 if it did not end.
    int wait_exit(double seconds = 180) {
        const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
        while (std::chrono::steady_clock::now() < until) {
            if (exited()) return exit_code_;
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
        return -2;
    }

private:
    std::string display_;
    fs::path log_;
    pid_t pid_ = -1;
    bool reaped_ = false;
    int exit_code_ = -2;
};

/// The number after `prefix` in `text` at or after `from` (NaN if absent).
double number_after(const std::string& text, const std::string& prefix, std::size_t from = 0) {
    const auto at = text.find(prefix, from);
    if (at == std::string::npos) return std::nan("");
    return std::strtod(text.c_str() + at + prefix.size(), nullptr);
}

/// The path in "screenshot: wrote PATH (WxH)" at or after `from`.
fs::path screenshot_path(const std::string& text, std::size_t from) {
    const std::string prefix = "screenshot: wrote ";
    const auto at = text.find(prefix, from);
    if (at == std::string::npos) return {};
    const auto end = text.find(" (", at);
    return text.substr(at + prefix.size(), end - at - prefix.size());
}

/// Presses P and returns the screenshot it wrote (read back), or an empty image.
Image screenshot(Window& window, std::string* path_out = nullptr) {
    const std::size_t from = window.output().size();
    if (window.xdotool("key p") != 0) return {};
    const auto at = window.wait_for("screenshot: wrote ", from);
    if (at == std::string::npos) return {};
    if (window.wait_for(")\n", at) == std::string::npos) return {};
    const fs::path path = screenshot_path(window.output(), at);
    if (path_out) *path_out = path.string();
    return read_png(path);
}

/// The fraction of pixels in [x0, x1)×[y0, y1) whose colour differs by more than 24 in a channel.
double changed(const Image& a, const Image& b, int x0, int y0, int x1, int y1) {
    if (a.width != b.width || a.height != b.height) return 1.0;
    if (x1 <= x0 || y1 <= y0) return 0.0;
    return test::compare_images(test::crop(a, x0, y0, x1, y1), test::crop(b, x0, y0, x1, y1), 24, nullptr).fraction_over;
}

/// The HUD panel's height, pixels: the rows from its top (y = 8) down in which it covers the whole
/// strip x = 12..40 (every pixel differs from the same frame without the HUD: the panel darkens
/// what lies behind it).
int panel_height(const Image& with_hud, const Image& without_hud) {
    int rows = 0;
    for (int y = 8; y < with_hud.height; ++y, ++rows) {
        bool covered = true;
        for (int x = 12; x < 40 && covered; ++x) {
            const std::size_t p = (std::size_t(y) * std::size_t(with_hud.width) + std::size_t(x)) * 3;
            int largest = 0;
            for (int c = 0; c < 3; ++c) largest = std::max(largest, std::abs(int(with_hud.pixels[p + c]) - int(without_hud.pixels[p + c])));
            covered = largest > 3;
        }
        if (!covered) break;
    }
    return rows;
}

/// Waits until the simulation has the mouse device where the inputs sent so far put it (its place
/// and its button 1): for that event, not for a time. X hands a client its events in order, and `[`
/// with the section view off only says so: once that line shows, the window has taken in every
/// input sent before it. The window says "moving" (or "button 1 …") when an input changes where the
/// device should be, and "in place" once the simulation has stepped it there: the first "in place"
/// after the last of those is the one. Returns where that line starts in the output, or npos.
std::size_t wait_in_place(Window& window) {
    const std::size_t from = window.output().size();
    if (window.xdotool("key bracketleft") != 0) return std::string::npos;
    const auto said = window.wait_for("section view: off; C turns it on", from);
    if (said == std::string::npos) return std::string::npos;
    const std::string out = window.output();
    std::size_t moved = 0;
    for (const char* line : {"mouse device: moving", "mouse device: button 1 "})
        if (const auto at = out.rfind(line, said); at != std::string::npos) moved = std::max(moved, at);
    return window.wait_for("mouse device: in place at ", moved);
}

bool have_window_tools(std::string* why) {
    if (test::run_command("command -v Xvfb && command -v xdotool").exit_code != 0) {
        *why = "Xvfb or xdotool is not installed (Debian: xvfb xdotool; scripts/install-deps.sh)";
        return false;
    }
    return true;
}

#define REQUIRE_WINDOW_TOOLS()                                   \
    do {                                                         \
        std::string why_;                                        \
        if (!have_window_tools(&why_)) GTEST_SKIP() << why_;     \
    } while (0)

}  // namespace

TEST(WindowKeys, TheDocumentsKeyTableIsTheCodes) {
    // README.md and docs/runtime.md hold the table between two markers; each must be
    // window_keys_markdown() byte for byte (regenerate it from the expected text below when a key changes).
    for (const char* name : {"README.md", "docs/runtime.md"}) {
        std::ifstream in(fs::path(HEARTSIM_SOURCE_DIR) / name);
        std::stringstream text;
        text << in.rdbuf();
        const std::string doc = text.str(), begin = "<!-- window-keys: begin (runtime/view/window_keys.cpp; a test checks) -->\n",
                          end = "<!-- window-keys: end -->";
        const auto b = doc.find(begin), e = doc.find(end);
        ASSERT_NE(b, std::string::npos) << name << " has no '" << begin << "'";
        ASSERT_NE(e, std::string::npos) << name;
        EXPECT_EQ(doc.substr(b + begin.size(), e - b - begin.size()), window_keys_markdown()) << name << ", expected:\n"
                                                                                             << window_keys_markdown();
    }
}

TEST(WindowKeys, RunHelpPrintsEveryKey) {
    const auto help = test::run_command(quoted(HEARTSIM_EXE) + " run --help");
    ASSERT_EQ(help.exit_code, 0) << help.output;
    EXPECT_FALSE(window_keys().empty());
    for (const WindowKey& k : window_keys()) {
        EXPECT_NE(help.output.find(k.input), std::string::npos) << k.input;
        EXPECT_NE(help.output.find(std::string(k.action) + ": " + k.description), std::string::npos) << k.action;
    }
}

/// Space, N and T in a window on `backend` (cpu: the simulation's own thread; gl: between frames).
void pause_step_and_reset(const std::string& backend) {
    SCOPED_TRACE(backend + " backend");
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    // --real-time off: N advances by the scenario's step whatever the machine's speed (with auto
    // a loaded machine scales the mass and lengthens the step before the pause).
    const double dt = read_scenario(phantom()).solver.dt_ms;
    Window window(x, dir.path(), quoted(phantom()) + " --backend " + backend + " --size 400x300 --real-time off");
    ASSERT_TRUE(window.focus()) << window.output();
    ASSERT_EQ(window.xdotool("key space"), 0);
    auto at = window.wait_for("paused at ");
    ASSERT_NE(at, std::string::npos) << window.output();
    const double paused = number_after(window.output(), "paused at ", at);
    // Frames go by while paused (a screenshot is one), and the simulated time stands still:
    // only N moves it, by exactly one time step each.
    ASSERT_FALSE(screenshot(window).pixels.empty()) << window.output();
    std::this_thread::sleep_for(std::chrono::seconds(1));
    double before = paused;
    for (int n = 0; n < 2; ++n) {
        const std::size_t from = window.output().size();
        ASSERT_EQ(window.xdotool("key n"), 0);
        at = window.wait_for("one step: ", from);
        ASSERT_NE(at, std::string::npos) << window.output();
        const double after = number_after(window.output(), "one step: ", at);
        EXPECT_NEAR(after - before, dt, 1e-6 * std::max(1.0, after)) << window.output();
        before = after;
    }
    // T puts the tissue back to rest; the simulated time goes on from where it stood.
    const std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key t"), 0);
    ASSERT_NE(window.wait_for("tissue reset to its rest state", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key space"), 0);
    at = window.wait_for("resumed at ", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    EXPECT_NEAR(number_after(window.output(), "resumed at ", at), before, 1e-6 * std::max(1.0, before)) << window.output();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
}

TEST(WindowInput, SpacePausesTheSimulatedTimeAndNStepsOnceOnTheCpuBackend) {
    REQUIRE_WINDOW_TOOLS();
    pause_step_and_reset("cpu");
}

TEST(WindowInput, SpacePausesTheSimulatedTimeAndNStepsOnceOnTheGlBackend) {
    REQUIRE_WINDOW_TOOLS();
    REQUIRE_GL();
    pause_step_and_reset("gl");
}

TEST(WindowInput, ScreenshotHelpHudOrbitAndZoomChangeWhatIsSeen) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    // The scenario in this test's folder: P writes beside it.
    fs::copy_file(phantom(), dir / "case.h5");
    Window window(x, dir.path(), quoted(dir / "case.h5") + " --backend cpu --size 400x300");
    ASSERT_TRUE(window.focus()) << window.output();
    ASSERT_EQ(window.xdotool("key space"), 0);  // paused: the tissue stands still between pictures
    ASSERT_NE(window.wait_for("paused at "), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key F5"), 0);  // no device: nothing to record, and it says so
    ASSERT_NE(window.wait_for("recording: needs a haptic session"), std::string::npos) << window.output();

    std::string path;
    const Image hud = screenshot(window, &path);
    ASSERT_EQ(hud.width, 400) << window.output();
    ASSERT_EQ(hud.height, 300);
    const fs::path written = path;
    EXPECT_EQ(fs::absolute(written).parent_path(), fs::absolute(dir.path())) << path;
    const std::string name = written.filename().string();  // case-YYYYmmdd-HHMMSS.png
    EXPECT_EQ(name.size(), std::string("case-20260101-000000.png").size()) << name;
    EXPECT_EQ(name.rfind("case-", 0), 0u) << name;
    EXPECT_EQ(written.extension(), ".png");

    ASSERT_EQ(window.xdotool("key h"), 0);
    const Image help = screenshot(window);
    ASSERT_EQ(help.width, 400) << window.output();
    EXPECT_GT(changed(hud, help, 100, 75, 300, 225), 0.2) << "the help should cover the middle of the window";

    ASSERT_EQ(window.xdotool("key h F2"), 0);  // help and HUD off
    const Image bare = screenshot(window);
    ASSERT_EQ(bare.width, 400) << window.output();
    EXPECT_GT(changed(hud, bare, 8, 8, 150, 50), 0.1) << "F2 should hide the HUD panel (top left)";
    // Below the panel the scene alone, as before (paused: it stands still). The panel's height is
    // measured: it has a line more where the real-time governor scaled the mass before the pause
    // (a loaded machine), or where a force pass has run.
    const int panel = panel_height(hud, bare), below = 8 + panel + 4;
    std::printf("  HUD panel: %d pixels high\n", panel);
    EXPECT_GT(panel, 40) << "the HUD panel, top left";
    ASSERT_LT(below, 200) << "the HUD panel should leave the scene below it in sight";
    EXPECT_LT(changed(hud, bare, 100, below, 300, 225), 0.02) << "the scene alone, as before, below the HUD panel (from row " << below << ")";
    // I adds the figures (real time, fps and steps/s, particles and backend: three lines at least)
    // below what the panel showed, which stays.
    ASSERT_EQ(window.xdotool("key F2 i"), 0);
    const Image figures = screenshot(window);
    ASSERT_EQ(figures.width, 400) << window.output();
    EXPECT_GT(changed(hud, figures, 12, below, 150, below + 3 * 13), 0.1) << "I should add the figures' lines below the panel";
    EXPECT_LT(changed(hud, figures, 8, 8, 150, 8 + panel - 20), 0.02) << "the panel's first lines stay";
    ASSERT_EQ(window.xdotool("key i F2"), 0);  // figures and HUD off again

    // Orbit: a left drag across the middle; zoom: the wheel. Each changes the picture.
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 mousedown 1"), 0);
    for (int k = 1; k <= 8; ++k) ASSERT_EQ(window.xdotool("mousemove --window " + id + " " + std::to_string(200 + 10 * k) + " 150"), 0);
    ASSERT_EQ(window.xdotool("mouseup 1"), 0);
    const Image orbited = screenshot(window);
    ASSERT_EQ(orbited.width, 400) << window.output();
    EXPECT_GT(changed(bare, orbited, 0, 0, 400, 300), 0.03) << "the orbit should turn the model";
    ASSERT_EQ(window.xdotool("click --repeat 5 --delay 50 5"), 0);  // wheel down: farther away
    const Image zoomed = screenshot(window);
    ASSERT_EQ(zoomed.width, 400) << window.output();
    EXPECT_GT(changed(orbited, zoomed, 0, 0, 400, 300), 0.03) << "the zoom should shrink the model";
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
}

TEST(WindowInput, TheMouseDeviceTouchesTheTissueTheEmergencyStopZeroesItsForceTIsRefusedWhileRecording) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(phantom()) + " --backend cpu --size 400x300 --device mouse --record " + quoted(dir / "session.h5"));
    ASSERT_TRUE(window.focus()) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());

    // Ctrl + left drag to the right: the device moves along the camera's right axis only (the
    // anterior view: +x, the patient's left), as the recording of its poses shows below.
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 keydown ctrl mousedown 1"), 0);
    for (int k = 1; k <= 4; ++k) ASSERT_EQ(window.xdotool("mousemove --window " + id + " " + std::to_string(200 + 5 * k) + " 150"), 0);
    ASSERT_EQ(window.xdotool("mouseup 1 keyup ctrl"), 0);

    // Ctrl + wheel up, a notch at a time, each stepped there by the simulation, until the device
    // reaches the tissue and feels it.
    std::size_t touching = std::string::npos;
    for (int notch = 0; notch < 80 && touching == std::string::npos; ++notch) {
        ASSERT_EQ(window.xdotool("keydown ctrl click 4 keyup ctrl"), 0);
        ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
        touching = window.output().find("mouse device: touching the tissue");
    }
    ASSERT_NE(touching, std::string::npos) << "the probe should reach the phantom within 80 notches\n" << window.output();
    EXPECT_GT(number_after(window.output(), "mouse device: touching the tissue, ", touching), 0.01);

    // E latches the emergency stop: the force sent drops to zero (free) while the probe stays in
    // the tissue; E again releases it and the force comes back.
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key e"), 0);
    auto at = window.wait_for("emergency stop latched", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    ASSERT_NE(window.wait_for("mouse device: free", at), std::string::npos) << window.output();
    // … and a red banner across the middle of the window says so.
    const Image banner = screenshot(window);
    ASSERT_EQ(banner.width, 400) << window.output();
    int red_rows = 0;
    for (int y = 0; y < banner.height; ++y) {
        int red = 0;
        for (int x = 0; x < banner.width; ++x) {
            const std::uint8_t* px = &banner.pixels[(std::size_t(y) * banner.width + x) * 3];
            red += px[0] > 150 && px[1] < 30 && px[2] < 30;  // the banner: (200, 0, 0) at 92 %
        }
        red_rows += red > banner.width / 2;
    }
    EXPECT_GE(red_rows, 15) << "rows more than half red (the banner)";
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key e"), 0);
    at = window.wait_for("emergency stop released", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    EXPECT_NE(window.wait_for("mouse device: touching the tissue", at), std::string::npos) << window.output();

    // --record records the whole session: F5 is refused (the session's recording goes on).
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key F5"), 0);
    ASSERT_NE(window.wait_for("records the whole session already; F5 is off", from), std::string::npos) << window.output();

    // T is refused while --record records: a reset is no input a replay could repeat, so the
    // session's recording would no longer replay. The tissue stays pressed in.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key space"), 0);
    ASSERT_NE(window.wait_for("paused at ", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key t"), 0);
    ASSERT_NE(window.wait_for("T: not while --record records the session", from), std::string::npos) << window.output();

    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();
    const std::string out = window.output();
    EXPECT_GT(number_after(out, "mouse device: largest force sent "), 0.01) << out;
    EXPECT_EQ(out.find("tissue reset to its rest state"), std::string::npos) << out;
    EXPECT_GT(number_after(out, "displacement from rest: max "), 0.0) << out;

    const Recording r = read_recording(dir / "session.h5");
    ASSERT_EQ(r.hands[0].device_name, "mouse");
    double max_sent = 0;
    for (const auto& f : r.hands[0].force_n) max_sent = std::max(max_sent, std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]));
    EXPECT_GT(max_sent, 0.01) << "the session sent the device a force";
    bool latched = false, released = false;
    for (const auto& e : r.events) latched |= e.what == "emergency_stop", released |= latched && e.what == "emergency_stop_released";
    EXPECT_TRUE(latched && released) << "the session saw the stop latched, then released";
    // The drag: x grew, y stayed; the wheel moved z only (into the screen: -y is anterior, so the
    // device moved towards +y, posterior). Poses in the device frame = world for the mouse.
    const auto& p = r.hands[0].position_mm;
    ASSERT_FALSE(p.empty());
    EXPECT_GT(p.back()[0], p.front()[0] + 0.1) << "Ctrl + drag to the right moves the device towards the patient's left";
    const double travel = std::abs(p.back()[0] - p.front()[0]) + std::abs(p.back()[1] - p.front()[1]);
    // (the camera's axes are float: a move of T mm strays by ~1e-7·T off them)
    EXPECT_NEAR(p.back()[2], p.front()[2], 1e-5 * travel) << "neither the drag nor the wheel moves it up or down";
    EXPECT_GT(p.back()[1], p.front()[1]) << "the wheel moved it into the screen (posterior in the anterior view)";
}

// G: the mouse device's button 1 with a grabber instrument. Pressed inside the tissue, the grabber
// takes hold of it; drawn back out, it pulls the tissue along (a force on the device); G again lets
// go. The recording says when the grabber held.
TEST(WindowInput, GGrabsTheTissueWithTheMouseDeviceAndLetsGoAgain) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(phantom()) + " --backend cpu --size 400x300 --device mouse --instrument grabber --record " +
                                     quoted(dir / "grab.h5"));
    ASSERT_TRUE(window.focus()) << window.output();
    // Ctrl + wheel up into the phantom's wall: the probe of the test above touches its surface
    // after about 20 notches of 2 % of the model radius; a few more put the grabber in the wall.
    for (int k = 0; k < 24; ++k) ASSERT_EQ(window.xdotool("keydown ctrl click 4 keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // the simulation has the device there
    ASSERT_EQ(window.xdotool("key g"), 0);  // button 1 on: the grabber takes hold
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // at the step that read the button
    // Back out a notch at a time until the held tissue pulls on the device.
    std::size_t pulling = std::string::npos;
    for (int notch = 0; notch < 15 && pulling == std::string::npos; ++notch) {
        ASSERT_EQ(window.xdotool("keydown ctrl click 5 keyup ctrl"), 0);
        ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
        pulling = window.output().find("mouse device: touching the tissue");
    }
    ASSERT_NE(pulling, std::string::npos) << "the held tissue should pull on the device\n" << window.output();
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key g"), 0);  // let go
    ASSERT_NE(window.wait_for("mouse device: free", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();

    const Recording r = read_recording(dir / "grab.h5");
    ASSERT_EQ(r.hands[0].instrument, "grabber");
    std::size_t held = 0, last_held = 0;
    for (std::size_t step = 0; step < r.steps.grab.size(); ++step)
        if (r.steps.grab[step][0]) ++held, last_held = step;
    EXPECT_GT(held, 0u) << "the grabber held tissue for some steps";
    EXPECT_LT(last_held + 1, r.steps.grab.size()) << "and let go before the end";
    bool grabbed = false, released = false;
    for (const auto& e : r.events) grabbed |= e.what == "grab", released |= grabbed && e.what == "release";
    EXPECT_TRUE(grabbed && released) << "the session saw the grab, then the release";
    double max_sent = 0;
    for (const auto& f : r.hands[0].force_n) max_sent = std::max(max_sent, std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]));
    EXPECT_GT(max_sent, 0.01) << "the held tissue pulled on the device";
}

// K makes the mouse device's probe a scalpel (its blade along the tool's +z, superior); G lowers
// the blade; pushed into the phantom's anterior wall with Ctrl + wheel (perpendicular to the blade:
// it sweeps a surface) and drawn sideways with Ctrl + left drag, it cuts: the state file written at
// Esc names the scalpel and lists the springs cut. K while recording is refused.
TEST(WindowInput, KMakesTheMouseDevicesInstrumentAScalpelThatCutsWhileGLowersIt) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(phantom()) + " --backend cpu --size 400x300 --device mouse --save-state " + quoted(dir / "state.h5"));
    ASSERT_TRUE(window.focus()) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());
    ASSERT_EQ(window.xdotool("key k"), 0);
    ASSERT_NE(window.wait_for("instrument 0: scalpel"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key g"), 0);  // button 1: the blade lowered
    for (int k = 0; k < 30; ++k) ASSERT_EQ(window.xdotool("keydown ctrl click 4 keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // the blade down, in the wall
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 keydown ctrl mousedown 1"), 0);
    for (int k = 1; k <= 8; ++k) ASSERT_EQ(window.xdotool("mousemove --window " + id + " " + std::to_string(200 + 8 * k) + " 150"), 0);
    ASSERT_EQ(window.xdotool("mouseup 1 keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // swept through it
    // G again lifts the blade: the window opens the detailed mesh along the stroke.
    ASSERT_EQ(window.xdotool("key g"), 0);
    EXPECT_NE(window.wait_for("incision: the detailed mesh opened along 1 stroke"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();
    const SimulationState state = read_state(dir / "state.h5");
    EXPECT_EQ(state.kind[0], 3);
    std::printf("  %zu springs cut; the saved mesh has %zu triangles, %zu of them cut faces\n", state.cut_springs.size(),
                state.visual_triangles.size(), state.visual_triangles.size() - state.visual_cap_first);
    EXPECT_GT(state.cut_springs.size(), 10u) << window.output();
    EXPECT_GT(state.visual_triangles.size(), state.visual_cap_first) << "the saved mesh has caps";
    std::string why;
    EXPECT_TRUE(closed_manifold(state.visual_triangles, &why)) << why;

    // While --record records the session, K switches all the same: the recording starts with
    // the probe and holds the scalpel from the step K took effect. The simulation steps the probe
    // where it starts before K, and the scalpel a notch further in after it.
    Window recording(x, dir.path(), quoted(phantom()) + " --backend cpu --size 400x300 --device mouse --record " + quoted(dir / "r.h5"));
    ASSERT_TRUE(recording.focus()) << recording.output();
    ASSERT_NE(wait_in_place(recording), std::string::npos) << recording.output();
    ASSERT_EQ(recording.xdotool("key k"), 0);
    EXPECT_NE(recording.wait_for("instrument 0: scalpel"), std::string::npos) << recording.output();
    ASSERT_EQ(recording.xdotool("keydown ctrl click 4 keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(recording), std::string::npos) << recording.output();
    ASSERT_EQ(recording.xdotool("key Escape"), 0);
    ASSERT_EQ(recording.wait_exit(), 0) << recording.output();
    const Recording r = read_recording(dir / "r.h5");
    EXPECT_EQ(r.hands[0].instrument, "probe");
    EXPECT_EQ(r.instrument_at(0, 0).kind, InstrumentKind::probe);
    EXPECT_EQ(r.instrument_at(r.steps.size() - 1, 0).kind, InstrumentKind::scalpel);
    EXPECT_EQ(r.instrument_at(r.steps.size() - 1, 0).semi_axes, default_blade_semi_axes_mm);
}


/// Pixels in a pericardium patch's colour (renderer.h patch_rgb, lit: green 0.96 and blue 0.82 of
/// red); the phantom's lit red keeps green under 0.55 of red, the HUD's grey panel blue above red.
std::size_t patch_pixels(const Image& image) {
    std::size_t count = 0;
    for (std::size_t p = 0; p < std::size_t(image.width) * std::size_t(image.height); ++p) {
        const double r = image.pixels[3 * p], g = image.pixels[3 * p + 1], b = image.pixels[3 * p + 2];
        count += r > 50 && std::abs(g / r - 0.957) < 0.04 && b / r > 0.78 && b / r < 0.95 && b < g;
    }
    return count;
}

// Shift + P makes the mouse device's probe a patch: put on the phantom's surface (Ctrl + Shift +
// click) and G, it is laid there, and the window draws it in its colour (the HUD off). Shift + N makes it a
// needle: G ties a stitch to the patch. Shift + N again gives the probe back. The state file
// written at Esc holds the patch with its stitch. The whole repair is recorded (--record): the
// recording holds probe, patch, needle, probe in that order, and replays bit for bit, laying the
// patch and tying the stitch again.
TEST(WindowInput, ShiftPLaysAPatchWithTheMouseDeviceAndShiftNTiesAStitchToIt) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(phantom()) + " --backend cpu --size 400x300 --device mouse --save-state " + quoted(dir / "state.h5") +
                                     " --record " + quoted(dir / "repair.h5"));
    ASSERT_TRUE(window.focus()) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());
    ASSERT_EQ(window.xdotool("key Tab"), 0);  // the HUD off: its panel would shade the patch
    const Image before = screenshot(window);
    ASSERT_GT(before.width, 0) << window.output();
    EXPECT_EQ(patch_pixels(before), 0u);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // steps with the probe first
    ASSERT_EQ(window.xdotool("key shift+p"), 0);
    ASSERT_NE(window.wait_for("instrument 0: patch"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 keydown ctrl keydown shift click 1 keyup shift keyup ctrl"), 0);
    ASSERT_NE(window.wait_for("mouse device: on the surface at"), std::string::npos) << window.output();
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // the simulation has the device there
    ASSERT_EQ(window.xdotool("key g"), 0);    // button 1: the patch laid
    ASSERT_NE(window.wait_for("repair: pericardium patch laid"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key g"), 0);    // button 1 off: the hand lets go of it
    // A frame draws the state the simulation published for it: a frame or two after the patch was laid, it shows.
    Image laid;
    for (int shot = 0; shot < 5 && patch_pixels(laid) <= 50; ++shot) laid = screenshot(window);
    std::printf("  %zu pixels in the patch's colour once laid\n", patch_pixels(laid));
    EXPECT_GT(patch_pixels(laid), 50u) << "the laid patch is drawn (the last frame: window_patch.png)\n" << window.output();
    if (HasFailure()) write_png("window_patch.png", laid);

    ASSERT_EQ(window.xdotool("key shift+n"), 0);
    ASSERT_NE(window.wait_for("instrument 0: needle"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 keydown ctrl keydown shift click 1 keyup shift keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key g"), 0);    // button 1: a stitch tied at the needle's tip
    EXPECT_NE(window.wait_for("repair: stitch 1 tied"), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key g"), 0);    // the knot thrown
    ASSERT_EQ(window.xdotool("key shift+n"), 0);
    EXPECT_NE(window.wait_for("instrument 0: probe"), std::string::npos) << window.output();
    // A step with the probe again: a notch out of the screen, stepped there.
    ASSERT_EQ(window.xdotool("keydown ctrl click 5 keyup ctrl"), 0);
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();
    const SimulationState state = read_state(dir / "state.h5");
    ASSERT_TRUE(state.patch.has_value()) << window.output();
    EXPECT_EQ(state.patch->material, "pericardium");
    EXPECT_EQ(state.patch->stitch_vertex.size(), 1u);

    const Recording r = read_recording(dir / "repair.h5");
    std::vector<InstrumentKind> held;
    for (std::size_t k = 0; k < r.steps.size(); ++k)
        if (held.empty() || r.instrument_at(k, 0).kind != held.back()) held.push_back(r.instrument_at(k, 0).kind);
    EXPECT_EQ(held, (std::vector<InstrumentKind>{InstrumentKind::probe, InstrumentKind::patch, InstrumentKind::needle, InstrumentKind::probe}));
    const auto replay = test::run_command(quoted(HEARTSIM_EXE) + " run " + quoted(phantom()) + " --headless --replay " + quoted(dir / "repair.h5"));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("hand 0 probe, then patch, needle, probe)"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("repair: pericardium patch laid"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("repair: stitch 1 tied"), std::string::npos) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
}

// The section view driven by keys: C cuts the heart open through its centre, facing the view (the
// cut wall in its flat colour, the HUD panel a few lines taller saying where the plane is); ] moves
// it deeper, a millimetre a press, and Shift + [ back five at a time, to the same picture; after an
// orbit V turns it to face the new view at the depth it had; C again shows the whole heart.
TEST(WindowInput, CCutsTheHeartOpenBracketsMoveTheSectionAndVAimsIt) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    fs::copy_file(phantom(), dir / "case.h5");  // P writes beside it
    Window window(x, dir.path(), quoted(dir / "case.h5") + " --backend cpu --size 400x300");
    ASSERT_TRUE(window.focus()) << window.output();
    ASSERT_EQ(window.xdotool("key space"), 0);  // paused: only the keys change the picture
    ASSERT_NE(window.wait_for("paused at "), std::string::npos) << window.output();
    // Keys that move a section that is not there say so.
    ASSERT_EQ(window.xdotool("key bracketright"), 0);
    ASSERT_NE(window.wait_for("section view: off; C turns it on"), std::string::npos) << window.output();

    const Image hud_whole = screenshot(window);
    ASSERT_EQ(window.xdotool("key F2"), 0);  // HUD off: the scene alone
    const Image whole = screenshot(window);
    ASSERT_EQ(whole.width, 400) << window.output();
    EXPECT_EQ(cut_pixels(whole), 0u) << "no cut colour without the section view";

    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key c"), 0);
    auto at = window.wait_for("section view: on, the plane ", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    EXPECT_EQ(number_after(window.output(), "section view: on, the plane ", at), 0.0) << "through the heart's centre";
    EXPECT_NE(window.output().find("normal (0.0000, -1.0000, 0.0000)", at), std::string::npos) << "facing the anterior view\n" << window.output();
    const Image centre = screenshot(window);
    ASSERT_EQ(centre.width, 400) << window.output();
    const std::size_t centre_cut = cut_pixels(centre);
    std::printf("  cut pixels: %zu through the centre\n", centre_cut);
    EXPECT_GT(centre_cut, 400u * 300u / 50) << "the cut wall should show";
    ASSERT_EQ(window.xdotool("key F2"), 0);  // the HUD again: a taller panel, saying where the plane is
    const Image hud_section = screenshot(window);
    ASSERT_EQ(hud_section.width, 400) << window.output();
    const int before = panel_height(hud_whole, whole), after = panel_height(hud_section, centre);
    std::printf("  HUD panel: %d pixels high, %d with the section view\n", before, after);
    EXPECT_GE(after, before + 30) << "the HUD should give the section's lines";
    ASSERT_EQ(window.xdotool("key F2"), 0);

    // ] ten times: 10 mm deeper, a millimetre a press, the terminal following.
    from = window.output().size();
    for (int k = 0; k < 10; ++k) ASSERT_EQ(window.xdotool("key bracketright"), 0);
    at = window.wait_for("section view: the plane 10.00 mm beyond the heart's centre", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    for (int mm = 1; mm <= 10; ++mm) {
        char line[80];
        std::snprintf(line, sizeof line, "section view: the plane %d.00 mm beyond", mm);
        EXPECT_NE(window.output().find(line, from), std::string::npos) << line;
    }
    const Image deeper = screenshot(window);
    ASSERT_EQ(deeper.width, 400) << window.output();
    const std::size_t deeper_cut = cut_pixels(deeper);
    const double moved = changed(centre, deeper, 0, 0, 400, 300);
    std::printf("  cut pixels: %zu 10 mm deeper; %.1f %% of the window changed\n", deeper_cut, 100 * moved);
    EXPECT_GT(moved, 0.02) << "a deeper cut shows another section";
    EXPECT_GT(deeper_cut, 400u * 300u / 50);

    // Shift + [ twice: 5 mm back a press, to the centre again and the same picture.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key shift+bracketleft shift+bracketleft"), 0);
    ASSERT_NE(window.wait_for("section view: the plane 5.00 mm beyond", from), std::string::npos) << window.output();
    ASSERT_NE(window.wait_for("section view: the plane 0.00 mm beyond", from), std::string::npos) << window.output();
    const Image back = screenshot(window);
    ASSERT_EQ(back.width, 400) << window.output();
    EXPECT_LT(changed(centre, back, 0, 0, 400, 300), 0.002) << "back at the centre: the centre's picture";

    // An orbit turns the view, not the plane; V turns the plane to face the view at the depth it had.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key bracketright bracketright bracketright"), 0);
    ASSERT_NE(window.wait_for("section view: the plane 3.00 mm beyond", from), std::string::npos) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 mousedown 1"), 0);
    for (int k = 1; k <= 8; ++k) ASSERT_EQ(window.xdotool("mousemove --window " + id + " " + std::to_string(200 + 10 * k) + " 150"), 0);
    ASSERT_EQ(window.xdotool("mouseup 1"), 0);
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key v"), 0);
    at = window.wait_for("section view: aimed at the view, the plane ", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    EXPECT_NEAR(number_after(window.output(), "section view: aimed at the view, the plane ", at), 3.0, 1e-9) << window.output();
    const double nx = number_after(window.output(), "normal (", at);
    EXPECT_GT(std::abs(nx), 0.1) << "the orbit turned the view about the superior axis: the normal too\n" << window.output();
    EXPECT_GT(cut_pixels(screenshot(window)), 400u * 300u / 50) << "the new section shows";

    // C again: the whole heart.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key c"), 0);
    ASSERT_NE(window.wait_for("section view: off", from), std::string::npos) << window.output();
    const Image off = screenshot(window);
    ASSERT_EQ(off.width, 400) << window.output();
    EXPECT_EQ(cut_pixels(off), 0u);
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
}

/// The path in "recording: wrote PATH (N steps)" at or after `from`, and N.
fs::path recording_path(const std::string& text, std::size_t from, long long* steps = nullptr) {
    const std::string prefix = "recording: wrote ";
    const auto at = text.find(prefix, from);
    if (at == std::string::npos) return {};
    const auto end = text.find(" (", at);
    if (end == std::string::npos) return {};
    if (steps) *steps = std::atoll(text.c_str() + end + 2);
    return text.substr(at + prefix.size(), end - at - prefix.size());
}

/// F5 and F5 again: the path written and its steps (empty path on failure).
fs::path record_from_window(Window& window, int notches, long long* steps) {
    std::size_t from = window.output().size();
    if (window.xdotool("key F5") != 0) return {};
    const auto started = window.wait_for("recording: started at ", from);
    if (started == std::string::npos || window.wait_for("\n", started) == std::string::npos) return {};
    // The device moves while recording: a few Ctrl + wheel notches into the tissue and back,
    // stepped by the simulation (the recording placed it afresh: "in place" needs a step of it).
    for (int k = 0; k < notches; ++k) window.xdotool("keydown ctrl click 4 keyup ctrl");
    for (int k = 0; k < notches; ++k) window.xdotool("keydown ctrl click 5 keyup ctrl");
    if (wait_in_place(window) == std::string::npos) return {};
    from = window.output().size();
    if (window.xdotool("key F5") != 0) return {};
    const auto wrote = window.wait_for("recording: wrote ", from);
    if (wrote == std::string::npos || window.wait_for(" steps)\n", wrote) == std::string::npos) return {};
    return recording_path(window.output(), wrote, steps);
}

TEST(WindowInput, F5RecordsFromTheRestStateAndTheRecordingReplaysBitForBit) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    fs::copy_file(phantom(), dir / "case.h5");  // the recordings go beside the scenario
    Window window(x, dir.path(), quoted(dir / "case.h5") + " --backend cpu --size 400x300 --device mouse");
    ASSERT_TRUE(window.focus()) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());

    // The probe pressed into the tissue before the recording starts: the tissue is deformed, so
    // only a recording that starts from the rest state (F5 resets it) replays bit for bit.
    std::size_t touching = std::string::npos;
    for (int notch = 0; notch < 80 && touching == std::string::npos; ++notch) {
        ASSERT_EQ(window.xdotool("keydown ctrl click 4 keyup ctrl"), 0);
        ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
        touching = window.output().find("mouse device: touching the tissue");
    }
    ASSERT_NE(touching, std::string::npos) << "the probe should reach the phantom within 80 notches\n" << window.output();
    ASSERT_EQ(window.xdotool("keydown ctrl click 4 click 4 keyup ctrl"), 0);  // deeper in
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();

    long long steps1 = 0, steps2 = 0;
    const fs::path first = record_from_window(window, 2, &steps1);
    ASSERT_FALSE(first.empty()) << window.output();
    const fs::path second = record_from_window(window, 1, &steps2);
    ASSERT_FALSE(second.empty()) << window.output();
    // T is refused while recording (a reset could not be replayed): start a third, press T, close
    // the window while it records: it is written too.
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key F5"), 0);
    ASSERT_NE(window.wait_for("recording: started at ", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key t"), 0);
    ASSERT_NE(window.wait_for("T: not while recording", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("keydown ctrl click 4 keyup ctrl"), 0);  // steps recorded: a notch in, stepped there
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();
    long long steps3 = 0;
    const fs::path third = recording_path(window.output(), from, &steps3);
    ASSERT_FALSE(third.empty()) << "closing the window writes the recording that is on\n" << window.output();

    const std::vector<fs::path> paths = {first, second, third};
    const std::vector<long long> steps = {steps1, steps2, steps3};
    EXPECT_NE(first, second);
    EXPECT_NE(second, third);
    EXPECT_NE(first, third);
    for (std::size_t k = 0; k < paths.size(); ++k) {
        SCOPED_TRACE(paths[k].string());
        const std::string name = paths[k].filename().string();  // case-YYYYmmdd-HHMMSS[-N].rec.h5
        EXPECT_EQ(fs::absolute(paths[k]).parent_path(), fs::absolute(dir.path()));
        EXPECT_EQ(name.rfind("case-", 0), 0u) << name;
        EXPECT_EQ(name.substr(name.size() - 7), ".rec.h5") << name;
        EXPECT_TRUE(fs::exists(fs::path(paths[k]).replace_extension(".xmf2"))) << "the .xmf2 beside it";
        EXPECT_FALSE(fs::exists(paths[k].string() + ".journal")) << "the journal is deleted once written";
        const Recording r = read_recording(paths[k]);
        ASSERT_EQ(r.hands[0].device_name, "mouse");
        EXPECT_EQ((long long)r.steps.size(), steps[k]);
        ASSERT_GT(r.steps.size(), 0u);
        double largest = 0;
        for (const auto& f : r.steps.force_n) largest = std::max(largest, std::sqrt(f[0][0] * f[0][0] + f[0][1] * f[0][1] + f[0][2] * f[0][2]));
        EXPECT_GT(largest, 0.01) << "the probe pressed in the tissue while recording";
        const auto replay = test::run_command(quoted(HEARTSIM_EXE) + " run " + quoted(dir / "case.h5") + " --headless --replay " + quoted(paths[k]));
        EXPECT_EQ(replay.exit_code, 0) << replay.output;
        EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
    }
}

TEST(WindowHud, TheScaleBarIsTheOneTwoFiveLengthNearestTheTarget) {
    // For every scale, the bar is 1, 2 or 5 × 10^k mm and on screen within a factor √2.5 of the
    // target (the series' widest step is 2 → 5: the nearest value in log scale is within √2.5).
    for (const double mm_per_pixel : {0.001, 0.0137, 0.1, 0.25, 0.9, 3.3, 12.0, 70.0}) {
        const double target = 96.0, bar = scale_bar_mm(mm_per_pixel, target);
        const double mantissa = bar / std::pow(10.0, std::floor(std::log10(bar) + 1e-9));
        EXPECT_TRUE(std::abs(mantissa - 1) < 1e-9 || std::abs(mantissa - 2) < 1e-9 || std::abs(mantissa - 5) < 1e-9) << bar;
        const double pixels = bar / mm_per_pixel;
        EXPECT_LE(std::abs(std::log(pixels / target)), std::log(std::sqrt(2.5)) + 1e-9) << mm_per_pixel << " mm/px: " << bar << " mm";
    }
}

TEST(WindowHud, TheHudMatchesItsGoldenImage) {
    // The window as seen (P), HUD included: the phantom at rest (paused, one step, then T), the
    // keyboard's probe, the HUD panel with its figures (I), the LPS axes and the scale bar. HEARTSIM_HUD_FIXED shows
    // the figures that depend on the machine's speed (real-time factor, fps, steps/s, simulated
    // time) as fixed values, and --real-time off keeps the mass scale (and its HUD line) from
    // following the machine's speed; everything else is what the window draws. Regenerate (after an
    // intended change of the picture) with
    // HEARTSIM_UPDATE_GOLDEN=1 ./test_runtime_window --gtest_filter='*Golden*'; look at it first.
    REQUIRE_WINDOW_TOOLS();
    const fs::path golden = fs::path(HEARTSIM_SOURCE_DIR) / "tests/data/golden/window_hud.png";
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    fs::copy_file(phantom(), dir / "case.h5");
    Window window(x, dir.path(), quoted(dir / "case.h5") + " --backend cpu --size 400x300 --real-time off", "HEARTSIM_HUD_FIXED=1");
    ASSERT_TRUE(window.focus()) << window.output();
    // Paused, then one step (N): the HUD shows the force pass's result, not "not known".
    ASSERT_EQ(window.xdotool("key space"), 0);
    ASSERT_NE(window.wait_for("paused at "), std::string::npos) << window.output();
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("key n"), 0);
    ASSERT_NE(window.wait_for("one step: ", from), std::string::npos) << window.output();
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key t"), 0);  // the rest state exactly
    ASSERT_NE(window.wait_for("tissue reset to its rest state", from), std::string::npos) << window.output();
    ASSERT_EQ(window.xdotool("key i"), 0);  // the figures too (X hands the window i before the P that follows)
    const Image image = screenshot(window);
    ASSERT_EQ(image.width, 400) << window.output();
    ASSERT_EQ(image.height, 300);
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();

    const std::optional<Image> golden_image = test::golden_reference(golden, image);
    if (!golden_image) GTEST_SKIP() << "no golden image " << golden << " (HEARTSIM_UPDATE_GOLDEN=1 writes it)";
    const Image& reference = *golden_image;
    ASSERT_EQ(reference.width, image.width);
    ASSERT_EQ(reference.height, image.height);
    ASSERT_EQ(reference.channels, 3);
    Image diff;
    const test::ImageDifference whole = test::compare_images(image, reference, 16, &diff);
    // The HUD panel (top left, where its text is) on its own: a changed word or figure moves a few
    // dozen of its pixels, lost in the whole picture's share.
    const int px1 = 360, py1 = 150;
    const test::ImageDifference panel = test::compare_images(test::crop(image, 0, 0, px1, py1), test::crop(reference, 0, 0, px1, py1), 16, nullptr);
    const long long panel_pixels = (long long)std::llround(panel.fraction_over * px1 * py1);
    std::printf("  whole window: mean |difference| %.4f / 255, %.4f %% of pixels differ by more than 16 / 255; HUD panel: %lld pixels\n",
                whole.mean_abs, 100 * whole.fraction_over, panel_pixels);
    // Tolerance: the scene as the render test's (llvmpipe on another CPU or Mesa may round edges
    // and shading differently); the HUD's text is drawn from ImGui's own font atlas and differs
    // by a handful of pixels at most, where one changed character moves dozens.
    const bool pass = whole.mean_abs < 2.0 && whole.fraction_over < 0.01 && panel_pixels <= 12;
    if (!pass) test::write_golden_failure("window_hud", diff, image);
    EXPECT_TRUE(pass) << "mean " << whole.mean_abs << ", fraction " << whole.fraction_over << ", HUD panel pixels " << panel_pixels;
}

/// The point (x, y, z) after `prefix` in `text` at or after `from`, and where the line starts (npos: absent).
std::size_t point_after(const std::string& text, const std::string& prefix, std::size_t from, Eigen::Vector3d& point) {
    const auto at = text.find(prefix, from);
    if (at == std::string::npos) return at;
    const char* p = text.c_str() + at + prefix.size();
    for (int k = 0; k < 3; ++k) {
        while (*p == ' ' || *p == '(' || *p == ',') ++p;
        char* end = nullptr;
        point[k] = std::strtod(p, &end);
        p = end;
    }
    return at;
}

/// The model radius the window's camera fits: half the diagonal of the detailed mesh's bounding box.
double model_radius(const Scenario& scenario) {
    Eigen::AlignedBox3d box;
    for (const auto& p : scenario.visual->positions) box.extend(Eigen::Vector3d(p[0], p[1], p[2]));
    return 0.5 * box.diagonal().norm();
}

// The keyboard's instrument moves 0.25 model radius per second a movement key is held, by the wall
// clock, however slowly the window draws (llvmpipe at 1280×800: about a frame a second), and every
// press counts, a tap as 0.1 s held, taps between two frames too. The held time is the one the
// window logs from the key events as they reached it (a loaded machine may stretch the 2 s this
// test holds the key); the distance is between the places the window says the simulation stepped
// the instrument at.
TEST(WindowInput, TheKeyboardsInstrumentMovesByTheTimeAKeyIsHeldWhateverTheFrameRate) {
    REQUIRE_WINDOW_TOOLS();
    test::TempDir dir;
    XServer x(dir.path(), "1280x800x24");
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    const Scenario scenario = read_scenario(phantom());
    ASSERT_TRUE(scenario.visual.has_value()) << "the phantom has a detailed mesh";
    const double speed = 0.25 * model_radius(scenario);
    Window window(x, dir.path(), quoted(phantom()) + " --size 1280x800");
    ASSERT_TRUE(window.focus()) << window.output();
    Eigen::Vector3d start;
    ASSERT_NE(window.wait_for("keyboard: instrument 0 (probe) at "), std::string::npos) << window.output();
    ASSERT_NE(point_after(window.output(), "keyboard: instrument 0 (probe) at ", 0, start), std::string::npos);
    EXPECT_NEAR(number_after(window.output(), "PgUp / PgDn in depth, "), speed, 0.005 * speed) << "the speed said, mm/s";

    // Up held for 2 s.
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("keydown Up"), 0);
    std::this_thread::sleep_for(std::chrono::seconds(2));
    ASSERT_EQ(window.xdotool("keyup Up"), 0);
    auto at = window.wait_for("keyboard: Up held ", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    const double held_s = number_after(window.output(), "keyboard: Up held ", at);
    at = window.wait_for("keyboard: instrument 0 in place at ", at);
    ASSERT_NE(at, std::string::npos) << window.output();
    Eigen::Vector3d after_hold;
    point_after(window.output(), "keyboard: instrument 0 in place at ", at, after_hold);
    const double expected = speed * std::max(held_s, 0.1);
    std::printf("  Up held %.3f s: moved %.2f mm, %.2f mm expected\n", held_s, (after_hold - start).norm(), expected);
    EXPECT_NEAR((after_hold - start).norm(), expected, 0.1 * expected) << window.output();

    // Five taps of → in 0.1 s (within a frame or two here): each moves the instrument.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("key --delay 20 Right Right Right Right Right"), 0);
    double taps_s = 0;
    std::size_t last = from;
    for (int k = 0; k < 5; ++k) {
        last = window.wait_for("keyboard: Right held ", last);
        ASSERT_NE(last, std::string::npos) << "tap " << k << "\n" << window.output();
        taps_s += std::max(number_after(window.output(), "keyboard: Right held ", last), 0.1);
        ++last;
    }
    at = window.wait_for("keyboard: instrument 0 in place at ", last);
    ASSERT_NE(at, std::string::npos) << window.output();
    Eigen::Vector3d after_taps;
    point_after(window.output(), "keyboard: instrument 0 in place at ", at, after_taps);
    std::printf("  five taps of Right (%.3f s counted): moved %.2f mm, %.2f mm expected\n", taps_s, (after_taps - after_hold).norm(),
                speed * taps_s);
    EXPECT_NEAR((after_taps - after_hold).norm(), speed * taps_s, 0.1 * speed * taps_s) << window.output();
    // Up and Right move in the view plane, at right angles.
    EXPECT_LT(std::abs((after_hold - start).normalized().dot((after_taps - after_hold).normalized())), 0.05);
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
}

// The key help (H) fits a 1280×800 window, its last row inside it, and lists the keys that work in
// the session: a keyboard session has none of a haptic device's, a mouse-device session has them
// all but N (the one only without a device). The layout is the one the window says it drew.
TEST(WindowHud, TheHelpFitsA1280x800WindowAndListsTheSessionsKeys) {
    REQUIRE_WINDOW_TOOLS();
    for (const std::string device : {"", "mouse"}) {
        SCOPED_TRACE(device.empty() ? "keyboard session" : "--device " + device);
        test::TempDir dir;
        XServer x(dir.path(), "1280x800x24");
        ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
        Window window(x, dir.path(), quoted(phantom()) + " --size 1280x800" + (device.empty() ? "" : " --device " + device));
        ASSERT_TRUE(window.focus()) << window.output();
        ASSERT_EQ(window.xdotool("key h"), 0);
        const auto at = window.wait_for("help: ");
        ASSERT_NE(at, std::string::npos) << window.output();
        const std::string out = window.output();
        const std::string line = out.substr(at, out.find('\n', at) - at);
        const double rows = number_after(line, "help: "), top = number_after(line, "from y "), bottom = number_after(line, " to "),
                     last_row = number_after(line, "last row ends at "), height = number_after(line, ") of ");
        EXPECT_EQ(height, 800) << line;
        EXPECT_GE(top, 0) << line;
        EXPECT_LE(last_row, bottom) << "the last row is inside the help window: " << line;
        EXPECT_LE(bottom, height) << "the help window is inside the window: " << line;
        EXPECT_EQ(line.find("actions only"), std::string::npos) << "the details fit too: " << line;
        // The keys of the session, from the table's own words.
        std::size_t expected = 0;
        for (const WindowKey& k : window_keys()) {
            const std::string d = k.description;
            const bool device_only = d.starts_with("with --device");
            const bool needs_moving = std::string(k.input) == "arrows" || std::string(k.input) == "PgUp / PgDn";
            const bool without_device = d.find("(not with --device)") != std::string::npos;
            expected += device.empty() ? !device_only : !without_device && (!needs_moving || device == "mouse");
        }
        EXPECT_EQ(rows, double(expected)) << line;
        ASSERT_EQ(window.xdotool("key Escape"), 0);
        EXPECT_EQ(window.wait_exit(), 0) << window.output();
    }
}

// The HUD leads with the case, its septal defect (the scenario's /source defect and diameter) and
// the procedure; the window says the same lines at the start. The figures (real time, fps, …)
// are behind I (WindowInput.ScreenshotHelpHudOrbitAndZoomChangeWhatIsSeen).
TEST(WindowHud, TheHudLeadsWithTheCaseItsDefectAndTheProcedure) {
    REQUIRE_WINDOW_TOOLS();
    using namespace test::defect_block;
    test::TempDir dir;
    build_block_scenario(make_block(), dir / "block.nrrd", dir / "vsd.h5", "vsd", 4000);
    const Scenario scenario = read_scenario(dir / "vsd.h5");
    ASSERT_EQ(scenario.source.defect, "vsd");
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(dir / "vsd.h5") + " --size 400x300");
    ASSERT_TRUE(window.focus()) << window.output();
    ASSERT_NE(window.wait_for("keyboard: instrument 0"), std::string::npos) << window.output();
    char across[32];
    std::snprintf(across, sizeof across, ", %.3g mm across", scenario.source.defect_diameter_mm);
    EXPECT_NE(window.output().find(std::string("window: vsd, ventricular septal defect (VSD)") + across +
                                   "; exploring with the keyboard's probe\n"),
              std::string::npos)
        << window.output();
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
}

TEST(WindowKeys, AKeyboardSessionsHelpHasNoDeviceKeys) {
    const WindowKeySession keyboard{.keyboard_instrument = true};
    std::size_t listed = 0;
    for (const WindowKey& k : window_keys()) {
        if (!key_works(k, keyboard)) continue;
        ++listed;
        EXPECT_FALSE(std::string(k.description).starts_with("with --device")) << k.input;
    }
    EXPECT_GT(listed, 10u);
    // Every key works in some session.
    for (const WindowKey& k : window_keys())
        EXPECT_TRUE(key_works(k, keyboard) || key_works(k, {.device = true, .mouse_device = true})) << k.input;
}

TEST(WindowScreenshot, TheNameCarriesTheLocalTimeAndNeverReplacesAFile) {
    test::TempDir dir;
    std::tm t{};
    t.tm_year = 2026 - 1900, t.tm_mon = 10, t.tm_mday = 24, t.tm_hour = 5, t.tm_min = 7, t.tm_sec = 9;
    const std::string scenario = (dir / "pat1.h5").string();
    const fs::path first = timestamped_screenshot(scenario, t);
    EXPECT_EQ(first, dir / "pat1-20261124-050709.png");
    std::ofstream(first) << "x";
    const fs::path second = timestamped_screenshot(scenario, t);
    EXPECT_EQ(second, dir / "pat1-20261124-050709-2.png");
    std::ofstream(second) << "x";
    EXPECT_EQ(fs::path(timestamped_screenshot(scenario, t)), dir / "pat1-20261124-050709-3.png");
    // F5's recordings: a name whose journal exists (a recording under way, or a killed one) is taken too.
    const fs::path recording = timestamped_path(scenario, t, ".rec.h5");
    EXPECT_EQ(recording, dir / "pat1-20261124-050709.rec.h5");
    std::ofstream(recording.string() + ".journal") << "x";
    EXPECT_EQ(fs::path(timestamped_path(scenario, t, ".rec.h5")), dir / "pat1-20261124-050709-2.rec.h5");
}

// `heartsim scenario.h5` with no option, on a machine whose OpenGL is a software rasteriser
// (Mesa's llvmpipe here): the window simulates on the cpu backend, faster here, and draws with
// OpenGL; it says so on the terminal and in the HUD. On a hardware device it keeps gl.
TEST(WindowInput, WithoutAGpuTheWindowSimulatesOnTheCpuBackendAndSaysSo) {
    REQUIRE_WINDOW_TOOLS();
    REQUIRE_GL();
    const auto info = test::run_command(quoted(HEARTSIM_EXE) + " info");
    const bool software = info.output.find("llvmpipe") != std::string::npos || info.output.find("softpipe") != std::string::npos;
    test::TempDir dir;
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(phantom()) + " --size 400x300");
    ASSERT_TRUE(window.focus()) << window.output();
    if (software) {
        EXPECT_NE(window.wait_for("a software rasteriser: simulating with the cpu backend"), std::string::npos) << window.output();
        ASSERT_FALSE(screenshot(window).pixels.empty()) << window.output();  // it draws, with OpenGL
    } else {
        EXPECT_EQ(window.output().find("software rasteriser"), std::string::npos) << window.output();
    }
    ASSERT_EQ(window.xdotool("key Escape"), 0);
    EXPECT_EQ(window.wait_exit(), 0) << window.output();
    // The run's end report names the backend that simulated.
    EXPECT_NE(window.output().find(software ? "cpu" : "gl"), std::string::npos) << window.output();
}

// Ctrl + Shift + click on a real heart puts the mouse device (a probe) on the tissue's surface
// under the cursor, touching it; a drag slides it along the surface; Ctrl + right click is its
// button 1; a click beside the heart leaves it where it is. The recording shows the touch: the
// probe pressed a quarter of its size in rests against the tissue with a few mN, below the
// 0.01 N of the window's "touching" line (only the moment it lands crosses that, by more or less
// with the machine's load), so the forces the simulation computed there are read from it instead.
TEST(WindowInput, CtrlShiftClickPutsTheMouseDeviceOnARealHeartsSurfaceAndADragSlidesItAlong) {
    REQUIRE_WINDOW_TOOLS();
    const fs::path label_map = test::real_case("hvsmr16_pat1");
    if (label_map.empty()) GTEST_SKIP() << "real case hvsmr16_pat1 absent";
    test::TempDir dir;
    const auto built = test::run_command(quoted(HEARTPREP_EXE) + " build " + quoted(label_map) + " -q -o " + quoted(dir / "pat1.h5"));
    ASSERT_EQ(built.exit_code, 0) << built.output;
    const Scenario scenario = read_scenario(dir / "pat1.h5");
    ASSERT_TRUE(scenario.visual.has_value());
    // How far a point lies from the detailed mesh at rest (its nearest vertex: edges are ~1 mm).
    auto from_surface = [&](const Eigen::Vector3d& p) {
        double best = 1e30;
        for (const auto& v : scenario.visual->positions) best = std::min(best, (Eigen::Vector3d(v[0], v[1], v[2]) - p).norm());
        return best;
    };
    XServer x(dir.path());
    ASSERT_FALSE(x.display().empty()) << "Xvfb did not start";
    Window window(x, dir.path(), quoted(dir / "pat1.h5") + " --backend cpu --size 400x300 --device mouse --record " + quoted(dir / "slide.h5"));
    ASSERT_TRUE(window.focus()) << window.output();
    const std::string id = window.id();
    ASSERT_FALSE(id.empty());
    auto point_after = [&](const std::string& words, std::size_t at) {
        Eigen::Vector3d p;
        const auto found = window.output().find(words, at);
        EXPECT_NE(found, std::string::npos) << window.output();
        if (found == std::string::npos) return p;
        EXPECT_EQ(std::sscanf(window.output().c_str() + found + words.size(), "(%lf, %lf, %lf)", &p[0], &p[1], &p[2]), 3) << window.output();
        return p;
    };

    // The middle of the window shows the heart (once a frame is drawn: P writes one): the device
    // goes onto its surface, and touches it.
    ASSERT_FALSE(screenshot(window).pixels.empty()) << window.output();
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 200 150 keydown ctrl keydown shift click 1 keyup shift keyup ctrl"), 0);
    auto at = window.wait_for("mouse device: on the surface at ");
    ASSERT_NE(at, std::string::npos) << window.output();
    const Eigen::Vector3d first = point_after("mouse device: on the surface at ", at);
    EXPECT_LT(from_surface(first), 3.0) << first.transpose();
    ASSERT_NE(wait_in_place(window), std::string::npos) << window.output();  // the simulation has it there

    // Dragged, it slides along the surface: its new place is on the surface too, further along.
    std::size_t from = window.output().size();
    ASSERT_EQ(window.xdotool("keydown ctrl keydown shift mousedown 1"), 0);
    for (int k = 1; k <= 6; ++k) ASSERT_EQ(window.xdotool("mousemove --window " + id + " " + std::to_string(200 + 4 * k) + " 150"), 0);
    ASSERT_EQ(window.xdotool("mouseup 1 keyup shift keyup ctrl"), 0);
    at = window.wait_for("mouse device: slid along the surface to ", from);
    ASSERT_NE(at, std::string::npos) << window.output();
    const Eigen::Vector3d second = point_after("mouse device: slid along the surface to ", at);
    EXPECT_LT(from_surface(second), 3.0) << second.transpose();
    EXPECT_GT((second - first).norm(), 2.0) << "24 pixels along, a few mm on the heart";

    // Ctrl + right click: the device's button 1, as G (a grabber would close on the tissue).
    from = window.output().size();
    ASSERT_EQ(window.xdotool("keydown ctrl click 3 keyup ctrl"), 0);
    ASSERT_NE(window.wait_for("mouse device: button 1 pressed", from), std::string::npos) << window.output();

    // Beside the heart: nothing under the cursor, the device stays.
    from = window.output().size();
    ASSERT_EQ(window.xdotool("mousemove --window " + id + " 3 3 keydown ctrl keydown shift click 1 keyup shift keyup ctrl"), 0);
    ASSERT_NE(window.wait_for("mouse device: no tissue under the cursor", from), std::string::npos) << window.output();

    ASSERT_EQ(window.xdotool("key Escape"), 0);
    ASSERT_EQ(window.wait_exit(), 0) << window.output();

    // The session's ticks: free where the device started, then (it glides to where the click
    // put it, at the mouse device's speed) there (the tick's pose is the one said, to the 0.01 mm
    // printed). The simulation's steps with the device there (the window said "in place" before
    // the drag): the tissue pushed it back. Steps, not ticks: a tick sends the force of the last
    // step published, which lags the device's place by as much as the machine's load makes it.
    const Recording r = read_recording(dir / "slide.h5");
    const auto& p = r.hands[0].position_mm;
    const auto& f = r.hands[0].force_n;
    ASSERT_EQ(p.size(), f.size());
    auto norm = [](const auto& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); };
    auto there = [&](const std::array<double, 3>& x) { return (Eigen::Vector3d(x[0], x[1], x[2]) - first).norm() < 0.01; };
    bool arrived = false;
    double before = 0.0;
    for (std::size_t i = 0; i < p.size(); ++i) {
        if (p[i] == p.front()) before = std::max(before, norm(f[i]));
        arrived = arrived || there(p[i]);
    }
    EXPECT_TRUE(arrived) << "the recording has the device where the click put it";
    EXPECT_EQ(before, 0.0) << "free before the click";
    std::size_t steps_there = 0;
    double resting = 0.0;
    for (std::size_t k = 0; k < r.steps.size(); ++k)
        if (there(r.steps.tool_position_mm[k][0])) ++steps_there, resting = std::max(resting, norm(r.steps.force_n[k][0]));
    ASSERT_GT(steps_there, 0u) << "the simulation stepped the device where the click put it";
    std::printf("  resting where the click put it (%zu steps), the tissue pushed the device back with up to %.3g N\n", steps_there, resting);
    EXPECT_GT(resting, 1e-3) << "a click on the heart touches it: the tissue pushes the device back";
}
