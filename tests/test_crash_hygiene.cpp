// Crash hygiene through the real programs, killed at seeded random moments: a `heartprep build`
// killed leaves its old scenario or the whole new one, never a half-written file under the final
// name, and the next write sweeps what it left; a `heartprep batch` stopped by a signal stops its
// builds and writes a summary that matches the folder, and one killed outright takes its builds
// with it; a `heartsim --record` session killed outright keeps all but its last second in its
// journal, which `heartsim recover` turns into a recording that replays bit for bit, a cutting
// session's cuts included. Plus the journal file's own rules, in process.
#include "runtime_test_support.h"
#include "test_support.h"

#include "formats/atomic_file.h"
#include "formats/csv.h"
#include "formats/hdf5_io.h"
#include "formats/recording.h"
#include "formats/recording_journal.h"
#include "formats/scenario.h"
#include "formats/state.h"
#include "incision_gesture.h"
#include "libmodel/errors.h"
#include "runtime/backend/backend.h"
#include "runtime/haptics/haptic_run.h"

#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <thread>

#include <fcntl.h>
#include <spawn.h>
#include <sys/inotify.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

extern char** environ;

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

/// A program started with its stdout and stderr in `log`.
pid_t start(const std::vector<std::string>& arguments, const fs::path& log) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
    posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
    std::vector<char*> argv;
    for (const auto& a : arguments) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    pid_t pid = 0;
    const int error = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    if (error != 0) throw std::runtime_error("cannot start " + arguments[0]);
    return pid;
}

/// Waits for child `pid` for up to `seconds`; its wait status, or −1 when it is still running.
int wait_for(pid_t pid, double seconds) {
    const auto until = Clock::now() + std::chrono::duration<double>(seconds);
    for (;;) {
        int status = 0;
        const pid_t done = waitpid(pid, &status, WNOHANG);
        if (done == pid) return status;
        if (done < 0 && errno != EINTR) return -1;
        if (Clock::now() > until) return -1;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
}

std::string read_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// The /proc/PID/stat fields after the command name: state, then the parent's pid.
bool stat_of(pid_t pid, char& state, pid_t& parent) {
    std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
    std::string text;
    if (!std::getline(in, text)) return false;
    const auto close = text.rfind(')');
    if (close == std::string::npos) return false;
    return std::sscanf(text.c_str() + close + 1, " %c %d", &state, &parent) == 2;
}

/// The living children of `parent` (zombies not counted).
std::set<pid_t> children_of(pid_t parent) {
    std::set<pid_t> children;
    for (const auto& entry : fs::directory_iterator("/proc")) {
        const std::string name = entry.path().filename().string();
        if (name.find_first_not_of("0123456789") != std::string::npos) continue;
        char state = 0;
        pid_t ppid = 0;
        if (stat_of(pid_t(std::stol(name)), state, ppid) && ppid == parent && state != 'Z' && state != 'X') children.insert(pid_t(std::stol(name)));
    }
    return children;
}

/// Whether `pid` is a living `heartprep build` (a reused pid running something else is not).
bool build_alive(pid_t pid) {
    char state = 0;
    pid_t ppid = 0;
    if (!stat_of(pid, state, ppid) || state == 'Z' || state == 'X') return false;
    std::string command = read_text("/proc/" + std::to_string(pid) + "/cmdline");
    std::replace(command.begin(), command.end(), '\0', ' ');
    return command.find("heartprep build") != std::string::npos;
}

/// Hidden temporaries (".NAME.tmp-PID-N…") in `folder`; of the file `of` only, when given.
std::vector<std::string> temporaries_in(const fs::path& folder, const std::string& of = "") {
    std::vector<std::string> found;
    for (const auto& entry : fs::directory_iterator(folder)) {
        const std::string name = entry.path().filename().string();
        if (name[0] == '.' && name.find(".tmp-") != std::string::npos && (of.empty() || name.rfind("." + of + ".tmp-", 0) == 0))
            found.push_back(name);
    }
    return found;
}

/// A small phantom made by `heartprep phantom`, 120 voxels along its longest axis: a build of a
/// few thousand particles takes about a second, long enough to be killed at chosen moments (at 48
/// voxels it takes 0.2 s, mostly the program's start).
fs::path small_phantom(const test::TempDir& dir, const std::string& name, double vsd_mm) {
    const fs::path path = dir / name;
    const auto run = test::heartprep("phantom -o " + quoted(path) + " --size 120 --vsd-diameter " + std::to_string(vsd_mm));
    if (run.exit_code != 0) throw std::runtime_error("heartprep phantom failed: " + run.output);
    return path;
}

/// The rows of a batch summary.csv by case id: status, particles (none where the cell is blank: a
/// case without a scenario measured nothing).
std::map<std::string, std::pair<std::string, std::optional<std::size_t>>> read_summary(const fs::path& csv) {
    std::map<std::string, std::pair<std::string, std::optional<std::size_t>>> rows;
    std::ifstream in(csv);
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
        const auto fields = csv_fields(line);
        if (fields.size() < 4) continue;
        rows[fields[0]] = {fields[2], fields[3].empty() ? std::nullopt : std::optional<std::size_t>(std::stoull(fields[3]))};
    }
    return rows;
}

/// A batch of four small cases, -j 2, into `out`, started; its log beside the folder.
pid_t start_batch(const test::TempDir& dir, const fs::path& out) {
    if (!fs::exists(dir / "in")) {
        fs::create_directory(dir / "in");
        for (int k = 0; k < 4; ++k) small_phantom(dir, "in/case" + std::to_string(k) + ".nii.gz", 4.0 + 2.0 * k);
    }
    return start({HEARTPREP_EXE, "batch", (dir / "in").string(), "-o", out.string(), "-j", "2", "--options",
                  "--particles 2500 --anchor-border"},
                 dir / "batch.log");
}

/// Waits until the batch `pid` has a build running (up to a minute); its children so far.
std::set<pid_t> wait_for_builds(pid_t batch) {
    const auto until = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < until) {
        const auto children = children_of(batch);
        if (!children.empty()) return children;
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    return {};
}

/// Starts `session` (a `heartsim run … --record` of a haptic session) with its output in `log`,
/// waits until it says "Ctrl-C ends the run cleanly", then kills it outright (SIGKILL) `after_s`
/// seconds later and reaps it. The session clock starts before that line is printed (and
/// flushed), so the time from there to the kill, returned in ms, is a lower bound of the
/// session's time at the kill. Throws, with the log, when the session does not get that far.
double kill_session(const std::vector<std::string>& session, const fs::path& log, double after_s) {
    const pid_t pid = start(session, log);
    const auto deadline = Clock::now() + std::chrono::seconds(120);
    while (read_text(log).find("Ctrl-C ends the run cleanly") == std::string::npos) {
        if (Clock::now() > deadline || waitpid(pid, nullptr, WNOHANG) != 0) {
            kill(pid, SIGKILL);
            wait_for(pid, 60);
            throw std::runtime_error("the session never got going or ended early: " + read_text(log));
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    const auto started = Clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(after_s));
    const double killed_at_ms = std::chrono::duration<double, std::milli>(Clock::now() - started).count();
    kill(pid, SIGKILL);
    if (wait_for(pid, 60) == -1) throw std::runtime_error("the killed session was not reaped within a minute");
    return killed_at_ms;
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// heartprep build

TEST(CrashHygiene, AHeartprepBuildKilledAtRandomMomentsLeavesTheOldScenarioOrTheWholeNewOne) {
    test::TempDir dir;
    const fs::path input = small_phantom(dir, "heart.nii.gz", 6.0);
    const fs::path out = dir / "out.h5";
    auto build = [&](const fs::path& output, const char* particles) {
        return std::vector<std::string>{HEARTPREP_EXE, "build", input.string(), "-o", output.string(), "--particles", particles,
                                        "--anchor-border", "-q"};
    };
    // The old scenario (1500 particles), and how long a build of the new one (3000) takes.
    ASSERT_EQ(wait_for(start(build(out, "1500"), dir / "old.log"), 300), 0) << read_text(dir / "old.log");
    const auto timed = Clock::now();
    ASSERT_EQ(wait_for(start(build(dir / "reference.h5", "3000"), dir / "reference.log"), 300), 0) << read_text(dir / "reference.log");
    const double full_s = std::chrono::duration<double>(Clock::now() - timed).count();
    const std::size_t new_particles = read_scenario(dir / "reference.h5").lattice.particles.size();
    const std::size_t old_particles = read_scenario(out).lattice.particles.size();
    ASSERT_NE(new_particles, old_particles);

    std::mt19937 random(15);  // seeded: the same moments on every run
    std::uniform_real_distribution<double> moment(0.0, 1.1 * full_s);
    int killed_while_running = 0;
    // Six attempts, and more (up to twelve) while fewer than three kills have landed during a
    // build: a reference build timed on a loaded machine can put the moments past a later build.
    for (int attempt = 0; attempt < 12 && (attempt < 6 || killed_while_running < 3); ++attempt) {
        // Every other attempt writes a file that did not exist before.
        const bool fresh = attempt % 2 == 1;
        const fs::path target = fresh ? dir / ("fresh" + std::to_string(attempt) + ".h5") : out;
        const std::string before = fresh ? "" : read_text(out);
        const double delay = moment(random);
        const pid_t pid = start(build(target, "3000"), dir / "killed.log");
        std::this_thread::sleep_for(std::chrono::duration<double>(delay));
        kill(pid, SIGKILL);
        const int status = wait_for(pid, 60);
        killed_while_running += WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
        SCOPED_TRACE("attempt " + std::to_string(attempt) + ", killed after " + std::to_string(delay) + " s of a " +
                     std::to_string(full_s) + " s build");
        if (fresh && !fs::exists(target)) continue;  // killed before the rename: nothing under the name
        // Under the final name: the old file untouched, or the whole new one.
        const std::string after = read_text(target);
        if (!fresh && after == before) continue;
        Scenario written;
        ASSERT_NO_THROW(written = read_scenario(target)) << "a half-written file under the final name";
        EXPECT_EQ(written.lattice.particles.size(), new_particles);
    }
    EXPECT_GE(killed_while_running, 3) << "the kills should mostly land while the build runs";

    // A kill while the scenario is being written (the moment its temporary appears, seen through
    // inotify) leaves the temporary and the old file; the next build removes the temporary.
    const std::string before = read_text(out);
    bool left_a_temporary = false;
    // Ten attempts: on a loaded machine a build can finish its write before the kill lands.
    for (int attempt = 0; attempt < 10 && !left_a_temporary; ++attempt) {
        const int watch = inotify_init1(IN_CLOEXEC);
        ASSERT_GE(watch, 0);
        ASSERT_GE(inotify_add_watch(watch, dir.path().c_str(), IN_CREATE), 0);
        const pid_t pid = start(build(out, attempt % 2 ? "2999" : "3001"), dir / "killed.log");
        alignas(inotify_event) char events[4096];
        bool seen = false;
        while (!seen) {
            const ssize_t n = read(watch, events, sizeof events);
            if (n <= 0) break;
            for (char* p = events; p < events + n;) {
                const auto* e = reinterpret_cast<const inotify_event*>(p);
                if (e->len && std::string(e->name).rfind(".out.h5.tmp-", 0) == 0) seen = true;
                p += sizeof(inotify_event) + e->len;
            }
        }
        kill(pid, SIGKILL);
        wait_for(pid, 60);
        close(watch);
        left_a_temporary = !temporaries_in(dir.path(), "out.h5").empty();
        if (left_a_temporary) EXPECT_EQ(read_text(out), before) << "killed while writing, yet the final name changed";
        else EXPECT_NO_THROW(read_scenario(out));
    }
    EXPECT_TRUE(left_a_temporary) << "no kill landed while the scenario was being written";
    // The next write of each file whose build was killed while writing it sweeps its temporaries
    // (out.h5's from the kills above, and any a random kill left beside a fresh file).
    std::set<std::string> targets{"out.h5"};
    for (const std::string& name : temporaries_in(dir.path())) {
        // A kill while the .xmf2 beside a scenario was written: the next build of the scenario sweeps it.
        const fs::path target = name.substr(1, name.find(".tmp-") - 1);
        targets.insert(target.extension() == ".xmf2" ? target.stem().string() + ".h5" : target.string());
    }
    for (const std::string& target : targets) {
        ASSERT_EQ(wait_for(start(build(dir / target, "3000"), dir / "last.log"), 300), 0) << read_text(dir / "last.log");
        EXPECT_EQ(read_scenario(dir / target).lattice.particles.size(), new_particles);
    }
    const auto left = temporaries_in(dir.path());
    EXPECT_TRUE(left.empty()) << "not swept: " << (left.empty() ? "" : left.front());
}

// ------------------------------------------------------------------------------------------------
// heartprep batch

TEST(CrashHygiene, ABatchStoppedBySigtermStopsItsBuildsAndWritesASummaryThatMatchesTheFolder) {
    test::TempDir dir;
    const fs::path out = dir / "out";
    std::mt19937 random(143);
    for (int round = 0; round < 2; ++round) {
        SCOPED_TRACE("round " + std::to_string(round));
        fs::remove_all(out);
        const pid_t batch = start_batch(dir, out);
        std::set<pid_t> builds = wait_for_builds(batch);
        ASSERT_FALSE(builds.empty()) << "the batch started no build: " << read_text(dir / "batch.log");
        // A random moment within the first builds, every build seen until then remembered.
        const auto until = Clock::now() + std::chrono::duration<double>(std::uniform_real_distribution<double>(0.0, 0.8)(random));
        while (Clock::now() < until) {
            for (pid_t pid : children_of(batch)) builds.insert(pid);
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
        for (pid_t pid : children_of(batch)) builds.insert(pid);
        ASSERT_EQ(kill(batch, SIGTERM), 0);
        const int status = wait_for(batch, 120);
        ASSERT_NE(status, -1) << "the batch did not end after SIGTERM";
        EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGTERM) << "status " << status << "\n" << read_text(dir / "batch.log");
        for (pid_t pid : builds) EXPECT_FALSE(build_alive(pid)) << "build " << pid << " outlived the batch";

        // The summary says what the folder holds.
        const auto rows = read_summary(out / "summary.csv");
        ASSERT_EQ(rows.size(), 4u) << read_text(out / "summary.csv");
        std::size_t interrupted = 0;
        for (const auto& [id, row] : rows) {
            const auto& [state, particles] = row;
            const fs::path file = out / (id + ".h5");
            if (state == "built") {
                ASSERT_TRUE(fs::exists(file)) << id;
                ASSERT_TRUE(particles.has_value()) << id;
                EXPECT_EQ(read_scenario(file).lattice.particles.size(), *particles) << id;
            } else {
                EXPECT_TRUE(state == "interrupted" || state == "not started") << id << ": " << state;
                EXPECT_FALSE(particles.has_value()) << id << " is " << state << " and has a particle count";
                EXPECT_FALSE(fs::exists(file)) << id << " is " << state << " but its scenario is there";
                interrupted += state == "interrupted";
            }
        }
        EXPECT_GE(interrupted, 1u) << "a build was running when the batch was stopped";
        EXPECT_TRUE(temporaries_in(out).empty()) << "the stopped builds' temporaries were not swept";
        EXPECT_NE(read_text(out / "summary.md").find("Stopped by SIGTERM"), std::string::npos) << read_text(out / "summary.md");
    }

    // Run again: what was built is reused, the rest built, nothing pending.
    const auto first = read_summary(out / "summary.csv");
    const auto again = test::heartprep("batch " + quoted(dir / "in") + " -o " + quoted(out) + " -j 2 --options '--particles 2500 --anchor-border'");
    ASSERT_EQ(again.exit_code, 0) << again.output;
    for (const auto& [id, row] : read_summary(out / "summary.csv")) {
        EXPECT_EQ(row.first, first.at(id).first == "built" ? "reused" : "built") << id;
        EXPECT_NO_THROW(read_scenario(out / (id + ".h5")));
    }
}

TEST(CrashHygiene, ABatchKilledOutrightTakesItsBuildsWithIt) {
    // Orphaned builds come to this process (a subreaper) instead of init, so the test can wait
    // for them and see what ended them.
    ASSERT_EQ(prctl(PR_SET_CHILD_SUBREAPER, 1), 0);
    test::TempDir dir;
    const fs::path out = dir / "out";
    const pid_t batch = start_batch(dir, out);
    std::set<pid_t> builds = wait_for_builds(batch);
    ASSERT_FALSE(builds.empty()) << read_text(dir / "batch.log");
    std::mt19937 random(9);
    std::this_thread::sleep_for(std::chrono::duration<double>(std::uniform_real_distribution<double>(0.0, 0.5)(random)));
    for (pid_t pid : children_of(batch)) builds.insert(pid);
    ASSERT_EQ(kill(batch, SIGKILL), 0);
    ASSERT_NE(wait_for(batch, 60), -1);
    int ended_by_the_parent_death_signal = 0;
    for (pid_t pid : builds) {
        // Reaped here once orphaned (or already reaped by the batch before it died).
        const int status = wait_for(pid, 60);
        if (status != -1) ended_by_the_parent_death_signal += WIFSIGNALED(status) && WTERMSIG(status) == SIGTERM;
        else EXPECT_FALSE(build_alive(pid)) << "build " << pid << " outlived the batch";
    }
    EXPECT_GE(ended_by_the_parent_death_signal, 1) << "no build was ended by the parent-death signal";
    for (pid_t pid : builds) EXPECT_FALSE(build_alive(pid)) << pid;
    prctl(PR_SET_CHILD_SUBREAPER, 0);

    // The summary written before the kill matches the folder: a case is `built` only if its
    // scenario is there; one not finished is `pending` (its scenario absent, or complete if the
    // kill fell between its rename and the summary).
    const auto rows = read_summary(out / "summary.csv");
    ASSERT_EQ(rows.size(), 4u);
    for (const auto& [id, row] : rows) {
        const fs::path file = out / (id + ".h5");
        EXPECT_TRUE(row.first == "built" || row.first == "pending") << id << ": " << row.first;
        if (row.first == "built") {
            ASSERT_TRUE(row.second.has_value()) << id;
            EXPECT_EQ(read_scenario(file).lattice.particles.size(), *row.second) << id;
        } else if (fs::exists(file)) {
            EXPECT_NO_THROW(read_scenario(file)) << id;
        }
    }
    EXPECT_NE(read_text(out / "summary.md").find("The batch is running"), std::string::npos);

    // The next run finishes and sweeps what the killed builds left.
    const auto again = test::heartprep("batch " + quoted(dir / "in") + " -o " + quoted(out) + " -j 2 --options '--particles 2500 --anchor-border'");
    ASSERT_EQ(again.exit_code, 0) << again.output;
    for (const auto& [id, row] : read_summary(out / "summary.csv")) EXPECT_TRUE(row.first == "built" || row.first == "reused") << id;
    EXPECT_TRUE(temporaries_in(out).empty());
}

// ------------------------------------------------------------------------------------------------
// heartsim --record

TEST(CrashHygiene, AKilledRecordingSessionKeepsAllButItsLastSecondAndRecoversToABitForBitReplay) {
    const fs::path& phantom = test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000");
    const fs::path samples = fs::path(HEARTSIM_SOURCE_DIR) / "samples/haptics";
    test::TempDir dir;
    const fs::path record = dir / "rec.h5";
    const fs::path journal = dir / "rec.h5.journal";
    const std::vector<std::string> session{HEARTSIM_EXE, "run", phantom.string(), "--headless", "--backend", "cpu",
                                           "--device", "simulated:" + (samples / "press_phantom.csv").string(),
                                           "--device", "scripted:" + (samples / "grab_phantom.csv").string(),
                                           "--seconds", "60", "--record", record.string()};
    std::mt19937 random(2);
    const double killed_at_ms = kill_session(session, dir / "session.log", 2.0 + std::uniform_real_distribution<double>(0.0, 0.5)(random));
    EXPECT_FALSE(fs::exists(record)) << "the recording is written only when a session ends";
    ASSERT_TRUE(fs::exists(journal)) << read_text(dir / "session.log");
    const std::string kept = read_text(journal);

    // The sweep of dead writers' temporaries (every atomic write of rec.h5 makes it) leaves the
    // journal alone, and a new session onto the same recording refuses, saying how to recover.
    sweep_stale_temporaries(record);
    ASSERT_TRUE(fs::exists(journal));
    const auto refused = test::run_command(quoted(HEARTSIM_EXE) + " run " + quoted(phantom) + " --headless --backend cpu --device simulated:" +
                                           quoted(samples / "press_phantom.csv") + " --seconds 1 --record " + quoted(record));
    EXPECT_EQ(refused.exit_code, 1) << refused.output;
    EXPECT_NE(refused.output.find("rec.h5.journal holds a session that was killed"), std::string::npos) << refused.output;
    EXPECT_NE(refused.output.find("heartsim recover"), std::string::npos) << refused.output;
    EXPECT_EQ(read_text(journal), kept) << "the refused session touched the journal";

    // A place no file can take (root may write almost anywhere, but not in /proc) is refused before
    // the journal is read, naming the place and no temporary file, and the journal stays.
    const auto nowhere = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(journal) + " -o /proc/rec.h5");
    EXPECT_EQ(nowhere.exit_code, 7) << nowhere.output;
    EXPECT_NE(nowhere.output.find("/proc/rec.h5: cannot create a file in folder /proc"), std::string::npos) << nowhere.output;
    EXPECT_EQ(nowhere.output.find("tmp"), std::string::npos) << nowhere.output;
    EXPECT_EQ(read_text(journal), kept);

    const auto recovered = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(journal));
    ASSERT_EQ(recovered.exit_code, 0) << recovered.output;
    std::printf("%s\n", recovered.output.c_str());
    EXPECT_FALSE(fs::exists(journal)) << "the journal is deleted once its recording is written";
    // ParaView's description lies beside the recording under its final name, and no other.
    std::vector<std::string> descriptions;
    for (const auto& entry : fs::directory_iterator(record.parent_path()))
        if (entry.path().extension() == ".xmf2") descriptions.push_back(entry.path().filename().string());
    EXPECT_EQ(descriptions, std::vector<std::string>{record.stem().string() + ".xmf2"});
    const Recording r = read_recording(record);
    ASSERT_GT(r.steps.size(), 0u);
    ASSERT_TRUE(r.hands[0].used && r.hands[1].used);
    // All but the last second: the last step and the last device tick kept are at most 1 s before
    // the kill on the session clock.
    EXPECT_GE(r.steps.wall_ms.back(), killed_at_ms - 1000.0) << "killed at ≥ " << killed_at_ms << " ms";
    EXPECT_GE(r.hands[0].tick_time_ms.back(), killed_at_ms - 1000.0) << "killed at ≥ " << killed_at_ms << " ms";
    EXPECT_LE(r.hands[0].tick_time_ms.back(), killed_at_ms + 1000.0);  // and nothing from after it
    EXPECT_EQ(r.hands[0].tick_time_ms.size(), r.hands[1].tick_time_ms.size());
    ASSERT_FALSE(r.events.empty());
    EXPECT_EQ(r.events.back().what, "interrupted");
    for (std::size_t k = 0; k < r.steps.size(); ++k) ASSERT_EQ(r.steps.force_step[k], std::int64_t(k)) << "a step row is missing";

    // The steps it holds replay bit for bit on the cpu backend.
    const auto replay = test::run_command(quoted(HEARTSIM_EXE) + " run " + quoted(phantom) + " --headless --replay " + quoted(record));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;
}

// Ctrl-C ends a haptic session cleanly, and a storm of them (one every 2 ms from the moment the
// session runs until the process is gone) never cuts off what it writes at the end: the recording
// and the state are written whole (each reads back, the state with every particle) and said so.
// Once they are, Ctrl-C is the terminal's again: the process may end by it or exit 0.
TEST(CrashHygiene, InterruptsWhileASessionWritesItsOutputsLeaveThemWhole) {
    const fs::path& phantom = test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000");
    const fs::path samples = fs::path(HEARTSIM_SOURCE_DIR) / "samples/haptics";
    test::TempDir dir;
    const fs::path record = dir / "rec.h5", state = dir / "state.h5", log = dir / "session.log";
    const pid_t pid = start({HEARTSIM_EXE, "run", phantom.string(), "--headless", "--backend", "cpu", "--device",
                             "simulated:" + (samples / "press_phantom.csv").string(), "--seconds", "60", "--record", record.string(),
                             "--save-state", state.string()},
                            log);
    const auto deadline = Clock::now() + std::chrono::seconds(120);
    while (read_text(log).find("Ctrl-C ends the run cleanly") == std::string::npos) {
        if (Clock::now() > deadline || waitpid(pid, nullptr, WNOHANG) != 0) {
            kill(pid, SIGKILL);
            wait_for(pid, 60);
            FAIL() << "the session never got going or ended early: " << read_text(log);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    int status = -1;
    for (int sent = 0; sent < 60000; ++sent) {  // two minutes at most
        if (waitpid(pid, &status, WNOHANG) == pid) break;
        kill(pid, SIGINT);
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    if (status == -1) {
        kill(pid, SIGKILL);
        wait_for(pid, 60);
        FAIL() << "the interrupted session did not end: " << read_text(log);
    }
    const std::string said = read_text(log);
    EXPECT_TRUE((WIFEXITED(status) && WEXITSTATUS(status) == 0) || (WIFSIGNALED(status) && WTERMSIG(status) == SIGINT)) << said;
    EXPECT_NE(said.find("interrupted: ending the session"), std::string::npos) << said;
    EXPECT_NE(said.find("wrote " + record.string()), std::string::npos) << said;
    EXPECT_NE(said.find("wrote " + state.string()), std::string::npos) << said;
    const SimulationState written = read_state(state);
    EXPECT_EQ(written.positions.size(), read_scenario(phantom).lattice.particles.size());
    EXPECT_TRUE(read_recording(record).hands[0].used);
}

// A cutting session killed outright at a random moment while it cuts: hand 0 a scalpel on a
// scripted device, its blade lowered 100 ms in and drawn 16 mm through the phantom's anterior wall
// at 10 mm/s (the incision of incision_gesture.h, slowed), hand 1 a grabber on a scripted device
// holding the wall beside the incision's start and pulling it away from the blade's plane, so that
// the force it feels depends on what was cut. `heartsim recover` keeps all but the last second;
// the steps kept include steps with the blade lowered and a grabber holding tissue, and replay bit
// for bit; replayed here, they cut springs, each a spring of the scenario, listed once.
TEST(CrashHygiene, AKilledCuttingSessionRecoversToABitForBitReplayOfItsCuts) {
    const fs::path& phantom = test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000");
    const Scenario scenario = read_scenario(phantom);
    const double length = 16.0;
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = length, .speed_mm_per_ms = 0.01, .retract = false});
    test::TempDir dir;
    auto row = [](std::ofstream& csv, double t, const Eigen::Vector3d& p, const Eigen::Quaterniond& q, bool button) {
        char line[256];
        std::snprintf(line, sizeof line, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", t, p.x(), p.y(), p.z(), q.w(), q.x(), q.y(), q.z(),
                      button ? 1 : 0);
        csv << line;
    };
    {
        std::ofstream csv(dir / "cut.csv");
        csv << "# time_ms, x, y, z, qw, qx, qy, qz, buttons\n";
        for (const InstrumentKeyframe& k : plan.trajectory.keyframes) row(csv, 100 + k.time_ms, k.pose.position, k.pose.orientation, k.grab);
    }
    // The grabber: the most anterior particle 1.5 spacings to the −x side of the blade's plane,
    // 3 mm from the incision's start, held from 100 ms and pulled 3 mm along −x over 2 s.
    const double spacing = scenario.lattice.spacing;
    const int grip = test::most_anterior_near(scenario, plan.centre.x() - 1.5 * spacing, plan.centre.z() - 0.5 * length + 3.0, spacing);
    ASSERT_GE(grip, 0);
    const auto& g = scenario.lattice.particles.rest_position[std::size_t(grip)];
    const Eigen::Vector3d at(g[0], g[1], g[2]);
    {
        std::ofstream csv(dir / "hold.csv");
        csv << "# time_ms, x, y, z, qw, qx, qy, qz, buttons\n";
        const Eigen::Quaterniond none = Eigen::Quaterniond::Identity();
        row(csv, 0, at, none, false);
        row(csv, 100, at, none, true);
        row(csv, 2100, at - Eigen::Vector3d(3.0, 0, 0), none, true);
    }
    const fs::path record = dir / "cut.h5";
    const std::string grabber = "grabber:" + std::to_string(spacing) + "," + std::to_string(spacing) + "," + std::to_string(spacing);
    const std::vector<std::string> session{HEARTSIM_EXE, "run", phantom.string(), "--headless", "--backend", "cpu",
                                           "--device", "scripted:" + (dir / "cut.csv").string(), "--instrument", "scalpel",
                                           "--device", "scripted:" + (dir / "hold.csv").string(), "--instrument", grabber,
                                           "--seconds", "60", "--record", record.string()};
    std::mt19937 random(3);
    const double killed_at_ms = kill_session(session, dir / "session.log", std::uniform_real_distribution<double>(1.5, 3.0)(random));
    EXPECT_FALSE(fs::exists(record));
    ASSERT_TRUE(fs::exists(fs::path(record.string() + ".journal"))) << read_text(dir / "session.log");

    const auto recovered = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(fs::path(record.string() + ".journal")));
    ASSERT_EQ(recovered.exit_code, 0) << recovered.output;
    const Recording r = read_recording(record);
    ASSERT_TRUE(r.hands[0].used && r.hands[1].used);
    EXPECT_EQ(r.hands[0].instrument, "scalpel");
    EXPECT_EQ(r.hands[1].instrument, "grabber");
    ASSERT_GT(r.steps.size(), 0u);
    EXPECT_GE(r.steps.wall_ms.back(), killed_at_ms - 1000.0) << "killed at ≥ " << killed_at_ms << " ms";
    std::size_t lowered = 0, pulled = 0;
    for (std::size_t k = 0; k < r.steps.size(); ++k) {
        lowered += r.steps.grab[k][0] != 0;
        const auto& f = r.steps.force_n[k][1];
        pulled += std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) > 0;
    }
    std::printf("  killed at ≥ %.0f ms; %zu steps kept: %zu with the blade lowered, %zu with a force on the grabber\n", killed_at_ms,
                r.steps.size(), lowered, pulled);
    EXPECT_GT(lowered, 0u) << "the session was killed before it cut";
    EXPECT_GT(pulled, 0u) << "the grabber held nothing";

    const auto replay = test::run_command(quoted(HEARTSIM_EXE) + " run " + quoted(phantom) + " --headless --replay " + quoted(record));
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("match the recording bit for bit"), std::string::npos) << replay.output;

    // The same steps replayed here on the cpu backend: the cuts the recovered session made.
    SolverOptions options = options_from(scenario.solver);
    if (r.rules) static_cast<SolverRules&>(options) = *r.rules;
    options.mass_scale = r.steps.mass_scale_at(0);
    options.arithmetic = r.arithmetic == "fused" ? SlotArithmetic::fused : SlotArithmetic::separate;
    auto cpu = make_cpu_backend(scenario, options);
    const haptics::ReplayResult again = haptics::replay(*cpu, r, record.string());
    EXPECT_EQ(again.identical, again.compared) << "replayed here, the forces differ by up to " << again.max_difference_n << " N";
    const auto cut = cpu->cut_springs();
    std::printf("  the recovered steps cut %zu springs\n", cut.size());
    EXPECT_GT(cut.size(), 0u);
    std::set<std::array<std::int32_t, 2>> springs;
    for (const auto& [i, j] : scenario.lattice.springs.pairs) springs.insert({std::min(i, j), std::max(i, j)});
    const std::set<std::array<std::int32_t, 2>> listed(cut.begin(), cut.end());
    EXPECT_EQ(listed.size(), cut.size()) << "a spring is listed twice";
    for (const auto& spring : listed) EXPECT_TRUE(springs.count(spring)) << spring[0] << "–" << spring[1] << " is no spring";
}

TEST(CrashHygiene, RecoverRefusesWhatIsNotAJournal) {
    test::TempDir dir;
    std::ofstream(dir / "rec.h5.journal") << "not a journal";
    auto run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "rec.h5.journal"));
    EXPECT_EQ(run.exit_code, 1) << run.output;  // input error: the file
    EXPECT_NE(run.output.find("rec.h5.journal: not a heartsim --record journal"), std::string::npos) << run.output;
    EXPECT_FALSE(fs::exists(dir / "rec.h5"));
    run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "other.bin"));
    EXPECT_EQ(run.exit_code, 2) << run.output;  // usage: the command line must say where to write
    EXPECT_NE(run.output.find("not named OUT.h5.journal"), std::string::npos) << run.output;
    run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "absent.h5.journal"));
    EXPECT_EQ(run.exit_code, 1) << run.output;
    EXPECT_NE(run.output.find("absent.h5.journal: file not found"), std::string::npos) << run.output;
    // A journal whose name gives no .h5 recording name: no file named "j3" without an extension.
    std::ofstream(dir / "j3.journal") << "not a journal";
    run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "j3.journal"));
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("not named OUT.h5.journal"), std::string::npos) << run.output;
    EXPECT_FALSE(fs::exists(dir / "j3"));
}

TEST(CrashHygiene, RecoverNeverReplacesAFile) {
    // The recording is a new file: a scenario or anything else already at its name stays as it is,
    // whether the name comes from the journal or from -o.
    test::TempDir dir;
    std::ofstream(dir / "rec.h5.journal") << "not a journal";
    std::ofstream(dir / "rec.h5") << "precious";
    std::ofstream(dir / "scenario.h5") << "precious too";
    auto run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "rec.h5.journal"));
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("rec.h5 exists"), std::string::npos) << run.output;
    run = test::run_command(quoted(HEARTSIM_EXE) + " recover " + quoted(dir / "rec.h5.journal") + " -o " + quoted(dir / "scenario.h5"));
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("scenario.h5 exists"), std::string::npos) << run.output;
    auto text = [](const fs::path& path) {
        std::ifstream in(path);
        return std::string(std::istreambuf_iterator<char>(in), {});
    };
    EXPECT_EQ(text(dir / "rec.h5"), "precious");
    EXPECT_EQ(text(dir / "scenario.h5"), "precious too");
}

// ------------------------------------------------------------------------------------------------
// The journal file (formats/recording_journal.h)

namespace {

/// A session of `steps` steps and `ticks` ticks with distinct values, events included.
Recording sample_recording(std::size_t steps, std::size_t ticks, unsigned seed) {
    std::mt19937 random(seed);
    std::uniform_real_distribution<double> value(-1.0, 1.0);
    Recording r;
    r.scenario = "phantom.h5";
    r.particles = 12000;
    r.dt_ms = 0.2;
    r.substeps = 2;
    r.backend = "cpu";
    r.contact = "direct";
    r.interpolation = "hold";
    r.rate_hz = 1000;
    for (int h : {0, 1}) {
        RecordedHand& hand = r.hands[h];
        hand.used = h == 0 || seed % 2 == 0;
        if (!hand.used) continue;
        hand.device = "simulated:press.csv";
        hand.device_name = "simulated";
        hand.instrument = h ? "grabber" : "probe";
        hand.semi_axes_mm = {2, 2, 2};
        hand.max_force_n = 3.3;
        for (std::size_t t = 0; t < ticks; ++t) {
            hand.tick_time_ms.push_back(double(t));
            hand.position_mm.push_back({value(random), value(random), value(random)});
            hand.orientation.push_back({1, 0, 0, 0});
            hand.buttons.push_back(std::uint32_t(t % 2));
            hand.input_n.push_back({value(random), value(random), value(random)});
            hand.force_n.push_back({value(random), 0, 0});
            hand.gain.push_back(float(t % 3) / 2.0f);
        }
    }
    RecordedSteps& s = r.steps;
    for (std::size_t k = 0; k < steps; ++k) {
        s.time_ms.push_back(0.2 * double(k + 1));
        s.wall_ms.push_back(0.5 * double(k));
        s.tool_time_ms.push_back(0.5 * double(k) - 0.1);
        s.tool_position_mm.push_back({{{value(random), value(random), value(random)}, {value(random), value(random), value(random)}}});
        s.tool_orientation.push_back({{{1, 0, 0, 0}, {1, 0, 0, 0}}});
        s.grab.push_back({0, std::int8_t(r.hands[1].used && k % 5 == 0)});
        s.applied.push_back({1, std::int8_t(r.hands[1].used)});
        s.force_n.push_back({{{value(random), value(random), value(random)}, {0, 0, value(random)}}});
        s.force_step.push_back(std::int64_t(k));
        s.diverged.push_back(std::int8_t(k == 3));
    }
    for (std::size_t e = 0; e < steps / 10; ++e) r.events.push_back({double(e) * 3.0, int(e % 2), e % 2 ? "grab" : "release"});
    return r;
}

/// Rows [s0, s1) of steps, [t0, t1) of ticks and [e0, e1) of events of `r`.
Recording rows_of(const Recording& r, std::size_t s0, std::size_t s1, std::size_t t0, std::size_t t1, std::size_t e0, std::size_t e1) {
    Recording c;
    auto cut = [](auto& to, const auto& from, std::size_t a, std::size_t b) { to.assign(from.begin() + long(a), from.begin() + long(b)); };
    const RecordedSteps& s = r.steps;
    cut(c.steps.time_ms, s.time_ms, s0, s1);
    cut(c.steps.wall_ms, s.wall_ms, s0, s1);
    cut(c.steps.tool_time_ms, s.tool_time_ms, s0, s1);
    cut(c.steps.tool_position_mm, s.tool_position_mm, s0, s1);
    cut(c.steps.tool_orientation, s.tool_orientation, s0, s1);
    cut(c.steps.grab, s.grab, s0, s1);
    cut(c.steps.applied, s.applied, s0, s1);
    cut(c.steps.force_n, s.force_n, s0, s1);
    cut(c.steps.force_step, s.force_step, s0, s1);
    cut(c.steps.diverged, s.diverged, s0, s1);
    if (!s.mass_scale.empty()) cut(c.steps.mass_scale, s.mass_scale, s0, s1);
    if (!s.instrument.empty()) cut(c.steps.instrument, s.instrument, s0, s1), cut(c.steps.semi_axes_mm, s.semi_axes_mm, s0, s1);
    for (int h : {0, 1}) {
        const RecordedHand& from = r.hands[h];
        RecordedHand& to = c.hands[h];
        if (!from.used) continue;
        to = from;  // the hand's attributes; its columns cut below
        cut(to.tick_time_ms, from.tick_time_ms, t0, t1);
        cut(to.position_mm, from.position_mm, t0, t1);
        cut(to.orientation, from.orientation, t0, t1);
        cut(to.buttons, from.buttons, t0, t1);
        cut(to.input_n, from.input_n, t0, t1);
        cut(to.force_n, from.force_n, t0, t1);
        cut(to.gain, from.gain, t0, t1);
    }
    cut(c.events, r.events, e0, e1);
    return c;
}

void expect_same_rows(const Recording& a, const Recording& b) {
    EXPECT_EQ(a.steps.time_ms, b.steps.time_ms);
    EXPECT_EQ(a.steps.wall_ms, b.steps.wall_ms);
    EXPECT_EQ(a.steps.tool_time_ms, b.steps.tool_time_ms);
    EXPECT_EQ(a.steps.tool_position_mm, b.steps.tool_position_mm);
    EXPECT_EQ(a.steps.tool_orientation, b.steps.tool_orientation);
    EXPECT_EQ(a.steps.grab, b.steps.grab);
    EXPECT_EQ(a.steps.applied, b.steps.applied);
    EXPECT_EQ(a.steps.force_n, b.steps.force_n);
    EXPECT_EQ(a.steps.force_step, b.steps.force_step);
    EXPECT_EQ(a.steps.diverged, b.steps.diverged);
    EXPECT_EQ(a.steps.mass_scale, b.steps.mass_scale);
    EXPECT_EQ(a.steps.instrument, b.steps.instrument);
    EXPECT_EQ(a.steps.semi_axes_mm, b.steps.semi_axes_mm);
    for (int h : {0, 1}) {
        EXPECT_EQ(a.hands[h].used, b.hands[h].used);
        EXPECT_EQ(a.hands[h].device, b.hands[h].device);
        EXPECT_EQ(a.hands[h].instrument, b.hands[h].instrument);
        EXPECT_EQ(a.hands[h].semi_axes_mm, b.hands[h].semi_axes_mm);
        EXPECT_EQ(a.hands[h].tick_time_ms, b.hands[h].tick_time_ms);
        EXPECT_EQ(a.hands[h].position_mm, b.hands[h].position_mm);
        EXPECT_EQ(a.hands[h].orientation, b.hands[h].orientation);
        EXPECT_EQ(a.hands[h].buttons, b.hands[h].buttons);
        EXPECT_EQ(a.hands[h].input_n, b.hands[h].input_n);
        EXPECT_EQ(a.hands[h].force_n, b.hands[h].force_n);
        EXPECT_EQ(a.hands[h].gain, b.hands[h].gain);
    }
}

}  // namespace

TEST(RecordingJournal, ACompleteJournalHoldsTheSessionExactly) {
    for (unsigned seed : {1u, 2u}) {  // one hand, two hands
        test::TempDir dir;
        Recording full = sample_recording(40, 90, seed);
        full.period_p99_ms = 1.03;
        full.periods = 90;
        full.latency_max_ms = 4.5;
        full.arithmetic = seed == 1 ? "fused" : "separate";
        if (seed == 1) full.rules = rules_before_recorded();  // seed 2: a session without rules, as before they were kept
        if (seed == 1)  // --real-time auto's mass scale, changed mid-session (seed 2: none, as before heartsim scaled mass)
            for (std::size_t k = 0; k < full.steps.size(); ++k) full.steps.mass_scale.push_back(k < 25 ? 1.0 : 4.0);
        if (seed == 1) full.patch_material = "dacron";
        if (seed == 1)  // K in the window: a scalpel from step 10 (seed 2: no instrument columns, as before)
            for (std::size_t k = 0; k < full.steps.size(); ++k) {
                const bool scalpel = k >= 10;
                full.steps.instrument.push_back({instrument_code(scalpel ? InstrumentKind::scalpel : InstrumentKind::probe), 0});
                full.steps.semi_axes_mm.push_back({{{scalpel ? 2.0 : 1.5, scalpel ? 0.3 : 1.5, scalpel ? 10.0 : 1.5}, {0, 0, 0}}});
            }
        const fs::path path = dir / "rec.h5.journal";
        {
            RecordingJournal journal(path, full, "rec.h5");
            EXPECT_TRUE(journal_in_use(path)) << "a journal being written is locked";
            journal.append(rows_of(full, 0, 15, 0, 30, 0, 1));
            journal.append(rows_of(full, 15, 15, 30, 31, 1, 1));  // a chunk without steps
            journal.append(rows_of(full, 15, 40, 31, 90, 1, full.events.size()));
            journal.end(full);
            EXPECT_EQ(journal.wait(), "");
        }
        EXPECT_FALSE(journal_in_use(path)) << "a closed journal is not locked";
        const JournalContents c = read_recording_journal(path);
        EXPECT_TRUE(c.ended);
        EXPECT_EQ(c.chunks, 3u);
        EXPECT_EQ(c.ignored_bytes, 0u);
        EXPECT_EQ(c.target, "rec.h5");
        EXPECT_EQ(c.pid, std::int64_t(getpid()));
        expect_same_rows(c.recording, full);
        ASSERT_EQ(c.recording.events.size(), full.events.size());
        for (std::size_t e = 0; e < full.events.size(); ++e) EXPECT_EQ(c.recording.events[e].what, full.events[e].what);
        EXPECT_EQ(c.recording.period_p99_ms, 1.03);
        EXPECT_EQ(c.recording.periods, 90);
        EXPECT_EQ(c.recording.latency_max_ms, 4.5);
        EXPECT_EQ(c.recording.dt_ms, 0.2);
        EXPECT_EQ(c.recording.arithmetic, full.arithmetic);
        EXPECT_EQ(c.recording.rules, full.rules);
        EXPECT_EQ(c.recording.patch_material, full.patch_material);
        // What recover writes reads back as a recording.
        write_recording(dir / "rec.h5", c.recording);
        expect_same_rows(read_recording(dir / "rec.h5"), full);
        EXPECT_EQ(read_recording(dir / "rec.h5").arithmetic, full.arithmetic);
        EXPECT_EQ(read_recording(dir / "rec.h5").rules, full.rules);
    }
}

// A journal that a heartsim from before the solver's rules were recorded left behind (version 2:
// no rules byte after the arithmetic, no mass-scale byte in its chunks) still recovers, without
// rules. Made here from a version-6 journal by the file format's own layout (formats/recording_journal.cpp): after the 16-byte file
// magic, a record is magic, kind (u32), payload bytes (u64), lookup3 checksum of kind, bytes and
// payload (u32), then the payload; the session's payload starts with the version (u32).
TEST(RecordingJournal, AVersion2JournalFromBeforeTheRulesWereKeptStillReads) {
    test::TempDir dir;
    Recording full = sample_recording(20, 40, 2);
    full.arithmetic = "fused";
    const fs::path path = dir / "rec.h5.journal";
    {
        RecordingJournal journal(path, full, "rec.h5");
        journal.append(rows_of(full, 0, 20, 0, 40, 0, full.events.size()));
        journal.end(full);
        EXPECT_EQ(journal.wait(), "");
    }
    std::string bytes = read_text(path);
    // Erases one byte of the payload of the record at `record`, and fixes its size and checksum.
    auto erase_in_record = [&](std::size_t record, std::size_t offset) {
        const std::size_t payload_at = record + 20;
        bytes.erase(payload_at + offset, 1);
        std::uint64_t size = 0;
        std::memcpy(&size, bytes.data() + record + 8, 8);
        --size;
        std::memcpy(bytes.data() + record + 8, &size, 8);
        std::string covered(12 + size, '\0');
        std::memcpy(covered.data(), bytes.data() + record + 4, 12);  // kind, then the new size
        std::memcpy(covered.data() + 12, bytes.data() + payload_at, size);
        const std::uint32_t sum = h5::lookup3(reinterpret_cast<const unsigned char*>(covered.data()), covered.size());
        std::memcpy(bytes.data() + record + 16, &sum, 4);
    };
    const std::size_t header = 16, payload = header + 20;
    std::uint32_t version = 0;
    std::memcpy(&version, bytes.data() + payload, 4);
    // Version 6 adds only a rule, and this session keeps no rules: its bytes are version 5's.
    ASSERT_EQ(version, 6u) << "this test turns a version-6 journal into a version-2 one";
    // The chunk after the session record: its step count (u64), the step columns (197 bytes a row:
    // times 3 × 8, tool poses 2 × (24 + 32), grab 2, applied 2, forces 48, force_step 8, diverged 1),
    // then version 4's mass-scale byte, 0: none follows, and version 5's instrument byte, 0: none
    // follows. Erased first (they lie after the session's).
    std::uint64_t session_size = 0, steps = 0;
    std::memcpy(&session_size, bytes.data() + header + 8, 8);
    const std::size_t chunk = payload + session_size;
    std::memcpy(&steps, bytes.data() + chunk + 20, 8);
    ASSERT_EQ(steps, 20u);
    ASSERT_EQ(bytes[chunk + 20 + 8 + 197 * steps], '\0') << "a chunk without a mass-scale column";
    ASSERT_EQ(bytes[chunk + 20 + 8 + 197 * steps + 1], '\0') << "a chunk without the instrument columns";
    erase_in_record(chunk, 8 + 197 * steps);
    erase_in_record(chunk, 8 + 197 * steps);
    // The rules byte follows version, target, pid, scenario, particles, dt, substeps, backend,
    // contact, interpolation and arithmetic (strings: a u64 length, then the bytes).
    std::size_t at = payload + 4;
    auto skip_text = [&] {
        std::uint64_t n = 0;
        std::memcpy(&n, bytes.data() + at, 8);
        at += 8 + n;
    };
    skip_text();       // target
    at += 8;           // pid
    skip_text();       // scenario
    at += 8 + 8 + 4;   // particles, dt_ms, substeps
    for (int text = 0; text < 4; ++text) skip_text();  // backend, contact, interpolation, arithmetic
    ASSERT_EQ(bytes[at], '\0') << "a session without rules";
    // Version 5's patch material ends the session record: a u64 length, then the name.
    const std::string material = "pericardium";
    std::uint64_t end_size = 0, material_length = 0;
    std::memcpy(&end_size, bytes.data() + header + 8, 8);
    std::memcpy(&material_length, bytes.data() + payload + end_size - 8 - material.size(), 8);
    ASSERT_EQ(material_length, material.size());
    ASSERT_EQ(bytes.substr(payload + end_size - material.size(), material.size()), material);
    for (std::size_t k = 0; k < 8 + material.size(); ++k) erase_in_record(header, end_size - 8 - material.size());
    erase_in_record(header, at - payload);
    version = 2;
    std::memcpy(bytes.data() + payload, &version, 4);
    {  // the version changed: the session's checksum again
        std::uint64_t size = 0;
        std::memcpy(&size, bytes.data() + header + 8, 8);
        std::string covered(12 + size, '\0');
        std::memcpy(covered.data(), bytes.data() + header + 4, 12);
        std::memcpy(covered.data() + 12, bytes.data() + payload, size);
        const std::uint32_t sum = h5::lookup3(reinterpret_cast<const unsigned char*>(covered.data()), covered.size());
        std::memcpy(bytes.data() + header + 16, &sum, 4);
    }
    {
        std::ofstream out(path, std::ios::binary | std::ios::trunc);
        out.write(bytes.data(), std::streamsize(bytes.size()));
    }
    const JournalContents c = read_recording_journal(path);
    EXPECT_TRUE(c.ended);
    EXPECT_EQ(c.ignored_bytes, 0u) << "every record reads";
    EXPECT_EQ(c.recording.arithmetic, "fused");
    EXPECT_FALSE(c.recording.rules.has_value());
    expect_same_rows(c.recording, full);
}

TEST(RecordingJournal, ARecordCutShortOrDamagedEndsTheJournalAndWhatPrecedesItIsKept) {
    test::TempDir dir;
    const Recording full = sample_recording(30, 60, 2);
    const fs::path path = dir / "rec.h5.journal";
    {
        RecordingJournal journal(path, full, "rec.h5");
        journal.append(rows_of(full, 0, 10, 0, 20, 0, 1));
        journal.append(rows_of(full, 10, 20, 20, 40, 1, 2));
        EXPECT_EQ(journal.wait(), "");
    }
    const std::string two_chunks = read_text(path);
    std::string complete;
    {  // the same session with a third chunk
        fs::remove(path);
        RecordingJournal journal(path, full, "rec.h5");
        journal.append(rows_of(full, 0, 10, 0, 20, 0, 1));
        journal.append(rows_of(full, 10, 20, 20, 40, 1, 2));
        journal.append(rows_of(full, 20, 30, 40, 60, 2, 3));
        EXPECT_EQ(journal.wait(), "");
    }
    complete = read_text(path);
    ASSERT_GT(complete.size(), two_chunks.size());
    ASSERT_EQ(complete.compare(0, two_chunks.size(), two_chunks), 0) << "chunks are appended";
    const Recording first_two = rows_of(full, 0, 20, 0, 40, 0, 2);
    // Cut anywhere inside the third chunk (a kill while writing it): the first two are kept.
    std::mt19937 random(3);
    for (int cut = 0; cut < 12; ++cut) {
        const std::size_t size = two_chunks.size() + 1 +
                                 std::uniform_int_distribution<std::size_t>(0, complete.size() - two_chunks.size() - 2)(random);
        test::write_bytes(path, std::vector<unsigned char>(complete.begin(), complete.begin() + long(size)));
        const JournalContents c = read_recording_journal(path);
        EXPECT_EQ(c.chunks, 2u) << "cut at " << size;
        EXPECT_EQ(c.ignored_bytes, size - two_chunks.size());
        EXPECT_FALSE(c.ended);
        expect_same_rows(c.recording, first_two);
        ASSERT_FALSE(c.recording.events.empty());
        EXPECT_EQ(c.recording.events.back().what, "interrupted");
        EXPECT_EQ(c.recording.events.back().time_ms, std::max(first_two.steps.wall_ms.back(), first_two.hands[0].tick_time_ms.back()));
    }
    // A flipped bit in the third chunk's payload fails its checksum: the same.
    std::string damaged = complete;
    damaged[two_chunks.size() + 40] ^= 0x10;
    test::write_bytes(path, std::vector<unsigned char>(damaged.begin(), damaged.end()));
    EXPECT_EQ(read_recording_journal(path).chunks, 2u);
    // A flipped bit in the session record: nothing can be recovered, and the error says so.
    damaged = complete;
    damaged[30] ^= 0x10;
    test::write_bytes(path, std::vector<unsigned char>(damaged.begin(), damaged.end()));
    try {
        read_recording_journal(path);
        ADD_FAILURE() << "a damaged session record was accepted";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("rec.h5.journal: its session record is missing or damaged"), std::string::npos) << e.what();
    }
    // Never replaced: a journal that is there is refused by the next writer.
    EXPECT_THROW(RecordingJournal(path, full, "rec.h5"), InputError);
    EXPECT_EQ(read_text(path), damaged);
}
