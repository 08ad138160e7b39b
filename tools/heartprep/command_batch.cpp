// `heartprep batch`: many cases at once. Each case runs as its own `heartprep build` process, so a
// crash or an out-of-memory in one case cannot take the others down; a case whose input bytes,
// options and heartprep version are unchanged since its scenario was written is skipped. The
// summary is rewritten (atomically) as each case ends, and a batch stopped by a signal stops its
// builds, waits for them and writes the summary before it ends by the same signal; its builds also
// end when it is killed outright (SIGKILL), through the parent-death signal.
#include "commands.h"
#include "manifest.h"
#include "terminal_progress.h"

#include "formats/atomic_file.h"
#include "formats/scenario.h"
#include "formats/xdmf.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <thread>

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

namespace heartsim::cli {

namespace {

namespace fs = std::filesystem;

struct Outcome {
    /// pending (not finished yet), built, skipped, failed, interrupted (its build was stopped with
    /// the batch), not started (the batch was stopped first)
    std::string status = "pending";
    std::size_t particles = 0, springs = 0, triangles = 0;
    double seconds = 0.0;
    std::vector<std::string> warnings;
    std::string message;
};

fs::path self_executable() {
    std::error_code error;
    auto path = fs::read_symlink("/proc/self/exe", error);
    if (error) throw OutputError("cannot locate the heartprep executable (/proc/self/exe)");
    return path;
}

// ------------------------------------------------------------------------------------------------
// Stopping: a signal handler may only touch lock-free atomics and call async-signal-safe functions
// (kill), so each worker publishes its running child's pid in its own slot.

constexpr int max_jobs = 256;  ///< --jobs' upper bound: one slot per worker
std::array<std::atomic<pid_t>, max_jobs> running_children{};
std::atomic<int> stop_signal{0};  ///< the first SIGINT, SIGTERM or SIGHUP received; 0 = none
static_assert(std::atomic<pid_t>::is_always_lock_free && std::atomic<int>::is_always_lock_free);

extern "C" void on_stop_signal(int signal) {
    int none = 0;
    stop_signal.compare_exchange_strong(none, signal);
    // SIGTERM whatever the batch received: a build ends on it (it has no handler), even where the
    // batch was started with SIGINT ignored, which its builds would inherit.
    for (auto& slot : running_children)
        if (const pid_t pid = slot.load(); pid > 0) ::kill(pid, SIGTERM);
}

/// SIGINT, SIGTERM and SIGHUP stop the batch; a signal the batch was started with ignored (nohup)
/// stays ignored.
void catch_stop_signals() {
    for (int signal : {SIGINT, SIGTERM, SIGHUP}) {
        struct sigaction old {};
        if (::sigaction(signal, nullptr, &old) == 0 && old.sa_handler == SIG_IGN) continue;
        struct sigaction action {};
        action.sa_handler = on_stop_signal;
        sigemptyset(&action.sa_mask);
        action.sa_flags = SA_RESTART;
        ::sigaction(signal, &action, nullptr);
    }
}

std::string signal_name(int signal) {
    switch (signal) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    case SIGHUP: return "SIGHUP";
    case SIGKILL: return "SIGKILL";
    default: return "signal " + std::to_string(signal);
    }
}

/// How a child ended: its exit status, or the signal that killed it.
struct ChildStatus {
    int exit_code = 0;  ///< when it exited
    int signal = 0;     ///< when a signal ended it
    int fork_error = 0; ///< errno when no process could be started
};

/// Runs `arguments` with stdout and stderr into `log`, its pid in `slot` while it runs.
/// fork + exec rather than posix_spawn, for the parent-death signal: the child asks for SIGTERM
/// when the thread that forked it ends, which a SIGKILL of the batch does, so no build outlives
/// the batch. The thread that forks also waits for the child, so the signal never fires early.
ChildStatus run_process(const std::vector<std::string>& arguments, const fs::path& log, std::atomic<pid_t>& slot) {
    std::vector<char*> argv;
    for (const auto& a : arguments) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid < 0) return {.exit_code = 127, .fork_error = errno};
    if (pid == 0) {
        // Only async-signal-safe calls between fork and exec.
        ::prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (::getppid() != parent) ::_exit(127);  // the batch died before the request took effect
        for (int signal : {SIGINT, SIGTERM, SIGHUP}) ::signal(signal, SIG_DFL);
        sigset_t none;
        sigemptyset(&none);
        ::sigprocmask(SIG_SETMASK, &none, nullptr);
        const int out = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (out < 0 || ::dup2(out, STDOUT_FILENO) < 0 || ::dup2(out, STDERR_FILENO) < 0) ::_exit(127);
        if (out > STDERR_FILENO) ::close(out);
        const int null = ::open("/dev/null", O_RDONLY);
        if (null >= 0 && null != STDIN_FILENO) ::dup2(null, STDIN_FILENO), ::close(null);
        ::execv(argv[0], argv.data());
        ::_exit(127);
    }
    slot.store(pid);
    // A stop that came between the check before this case and the slot being set: the handler did
    // not see this child, so stop it here.
    if (stop_signal.load()) ::kill(pid, SIGTERM);
    int status = 0;
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    slot.store(0);
    if (WIFSIGNALED(status)) return {.signal = WTERMSIG(status)};
    return {.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 127};
}

void fill_counts(const Scenario& s, Outcome& outcome) {
    outcome.particles = s.lattice.particles.size();
    outcome.springs = s.lattice.springs.size();
    outcome.triangles = s.visual ? s.visual->triangles.size() : 0;
}

Outcome run_case(const BatchCase& c, const fs::path& folder, const fs::path& executable, std::atomic<pid_t>& slot) {
    Outcome outcome;
    outcome.status = "failed";
    const auto start = std::chrono::steady_clock::now();
    const fs::path output = folder / (c.id + ".h5");
    const fs::path log = folder / "logs" / (c.id + ".log");
    try {
        // Temporaries of builds killed in an earlier run (their process is gone).
        sweep_stale_temporaries(output);
        sweep_stale_temporaries(xdmf_beside(output));
        if (!fs::exists(c.input)) throw InputError(c.input.string() + ": file not found");
        // The format version is in the key: a build of a newer format is not skipped as up to date.
        const std::string key = sha256_text(sha256_file(c.input) + "\n" + c.options + "\nheartprep " + HEARTSIM_VERSION +
                                            " format " + std::to_string(scenario_format_version));
        if (fs::exists(output)) {
            try {
                const Scenario existing = read_scenario(output);
                // A file from before scenarios kept their build's warnings is built again, so the
                // summary can report them.
                if (existing.batch_key == key && existing.build_warnings) {
                    // A scenario built before .xdmf files were written gets its description.
                    if (!fs::exists(xdmf_beside(output))) write_scenario_xdmf(output, existing);
                    outcome.status = "skipped";
                    fill_counts(existing, outcome);
                    outcome.warnings = *existing.build_warnings;
                    return outcome;
                }
            } catch (const InputError&) {
                // A damaged or foreign file: build the case again.
            }
        }
        if (stop_signal.load()) {  // stopped while the existing scenario was being checked
            outcome.status = "not started";
            outcome.message = "the batch was stopped by " + signal_name(stop_signal.load()) + " first";
            return outcome;
        }
        std::vector<std::string> arguments{executable.string(), "build", c.input.string(), "-o", output.string(), "--batch-key", key};
        for (auto& word : split_words(c.options)) arguments.push_back(word);
        const ChildStatus status = run_process(arguments, log, slot);
        sweep_stale_temporaries(output);  // what a killed build left beside its output
        sweep_stale_temporaries(xdmf_beside(output));
        std::vector<std::string> logged_warnings;
        {
            std::ifstream in(log);
            std::string line;
            while (std::getline(in, line)) {
                if (line.rfind("heartprep: warning: ", 0) == 0) logged_warnings.push_back(line.substr(20));
                if (line.rfind("heartprep: error: ", 0) == 0) outcome.message = line.substr(18);
            }
        }
        if (status.signal && stop_signal.load()) {
            outcome.status = "interrupted";
            outcome.message = "stopped by " + signal_name(stop_signal.load()) + " to the batch";
        } else if (status.fork_error) {
            outcome.message = "cannot start " + executable.string() + ": " + std::strerror(status.fork_error);
        } else if (status.signal || status.exit_code != 0) {
            if (outcome.message.empty())
                outcome.message = status.signal ? "killed by " + signal_name(status.signal) + " (see " + log.string() + ")"
                                                : "exit status " + std::to_string(status.exit_code) + " (see " + log.string() + ")";
        } else {
            const Scenario built = read_scenario(output);
            fill_counts(built, outcome);
            outcome.warnings = built.build_warnings ? *built.build_warnings : logged_warnings;
            outcome.status = "built";
        }
    } catch (const std::exception& e) {
        outcome.message = e.what();
    }
    outcome.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return outcome;
}

std::string csv_quote(const std::string& text) {
    std::string out = "\"";
    for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
    return out + "\"";
}

/// Writes `text` to `path` atomically.
void write_text(const fs::path& path, const std::string& text) { write_bytes_atomically(path, text.data(), text.size(), "the table"); }

/// summary.csv and summary.md for every case of the manifest as the batch stands; returns the table.
/// `state`: the line under the table that says whether the batch is running, finished or stopped.
std::string write_summaries(const fs::path& folder, const std::vector<BatchCase>& cases, const std::vector<Outcome>& outcomes,
                            const std::string& state) {
    std::ostringstream csv, markdown;
    csv << "case_id,input,status,particles,springs,triangles,seconds,warnings,message\n";
    markdown << "| case | status | particles | springs | triangles | time (s) | warnings |\n|---|---|---:|---:|---:|---:|---|\n";
    std::map<std::string, std::size_t> counts;
    for (std::size_t i = 0; i < cases.size(); ++i) {
        const auto& c = cases[i];
        const auto& o = outcomes[i];
        ++counts[o.status];
        std::string warnings;
        for (const auto& w : o.warnings) warnings += (warnings.empty() ? "" : "; ") + w;
        char seconds[32];
        std::snprintf(seconds, sizeof seconds, "%.2f", o.seconds);
        csv << csv_quote(c.id) << "," << csv_quote(c.input.string()) << "," << o.status << "," << o.particles << "," << o.springs
            << "," << o.triangles << "," << seconds << "," << csv_quote(warnings) << "," << csv_quote(o.message) << "\n";
        const bool ended_well = o.status == "built" || o.status == "skipped";
        std::string cell = ended_well ? warnings : o.message;
        std::replace(cell.begin(), cell.end(), '|', '/');
        if (ended_well && cell.size() > 100)  // the CSV and the log keep the full text
            cell = std::to_string(o.warnings.size()) + " warning(s): " + cell.substr(0, 80) + "… (see logs/" + c.id + ".log)";
        markdown << "| " << c.id << " | " << o.status << " | " << o.particles << " | " << o.springs << " | " << o.triangles << " | "
                 << seconds << " | " << cell << " |\n";
    }
    markdown << "\n" << cases.size() << " cases: " << counts["built"] << " built, " << counts["skipped"] << " skipped, "
             << counts["failed"] << " failed";
    for (const char* status : {"interrupted", "not started", "pending"})
        if (counts[status]) markdown << ", " << counts[status] << " " << status;
    markdown << ". " << state << "\n";
    write_text(folder / "summary.csv", csv.str());
    write_text(folder / "summary.md", markdown.str());
    return markdown.str();
}

}  // namespace

void add_batch_command(CLI::App& app) {
    auto* command = app.add_subcommand("batch", "Build many cases in parallel: resumable, with a summary table");
    command->footer(
        "\nMANIFEST is a CSV file of lines `input[,case_id[,options]]` (a header line starting with `input` and\n"
        "lines starting with # are ignored; relative paths are relative to the manifest), or a folder of label maps.\n"
        "Each case is written to DIR/<case_id>.h5 by its own `heartprep build` process, its output to\n"
        "DIR/logs/<case_id>.log. Per-case options replace --options. A case whose input bytes, options and\n"
        "heartprep version are unchanged since its scenario was written is skipped (its build's warnings,\n"
        "kept in the scenario, are reported again). One failing case does not stop the others; the exit status\n"
        "is non-zero if any case failed. Summary: DIR/summary.csv, DIR/summary.md, rewritten as each case ends\n"
        "(cases not finished yet are `pending`). SIGINT (Ctrl-C), SIGTERM or SIGHUP stop the running builds\n"
        "(`interrupted`) and the cases not begun (`not started`), write the summary, and end the batch by the\n"
        "same signal (a shell reports 128 + its number: 130, 143, 129); run the command again to finish.\n"
        "Example:\n  heartprep batch cases.csv -o scenarios/ -j 2 --options \"--cavity 2 --anchor-border\"");
    auto manifest = std::make_shared<fs::path>();
    auto folder = std::make_shared<fs::path>();
    auto jobs = std::make_shared<int>(1);
    auto options = std::make_shared<std::string>();
    command->add_option("manifest", *manifest, "CSV manifest or folder of label maps")->required();
    command->add_option("-o,--output", *folder, "Folder for the scenarios, logs and summary (created if needed)")->required();
    command->add_option("-j,--jobs", *jobs, "Cases built at the same time")->check(CLI::Range(1, max_jobs))->capture_default_str();
    command->add_option("--options", *options, "heartprep build options for every case, e.g. \"--cavity 2 --anchor-border\"");
    command->callback([=] {
        const auto cases = read_manifest(*manifest, *options);
        std::error_code error;
        fs::create_directories(*folder / "logs", error);
        if (error) throw OutputError(folder->string() + ": cannot create the output folder: " + error.message());
        const fs::path executable = self_executable();

        std::vector<Outcome> outcomes(cases.size());
        std::atomic<std::size_t> next{0};
        std::size_t done = 0;
        std::mutex print;  // the progress lines, `outcomes` and the summary files
        TerminalProgress progress(false);
        const auto start = std::chrono::steady_clock::now();
        const int workers_count = std::min<int>(*jobs, int(cases.size()));
        auto running_state = [&] {
            return "The batch is running: " + std::to_string(done) + " of " + std::to_string(cases.size()) +
                   " cases finished (this table is rewritten as each case ends).";
        };
        catch_stop_signals();
        // Before any build starts: a summary left by an earlier run no longer describes the folder.
        write_summaries(*folder, cases, outcomes, running_state());
        {
            ProgressStage stage(progress, "batch", cases.size());
            auto worker = [&](int w) {
                for (std::size_t i; (i = next++) < cases.size();) {
                    if (stop_signal.load()) {
                        std::lock_guard lock(print);
                        outcomes[i].status = "not started";
                        outcomes[i].message = "the batch was stopped by " + signal_name(stop_signal.load()) + " first";
                        continue;
                    }
                    Outcome outcome = run_case(cases[i], *folder, executable, running_children[std::size_t(w)]);
                    std::lock_guard lock(print);
                    outcomes[i] = std::move(outcome);
                    const auto& o = outcomes[i];
                    const bool ended_well = o.status == "built" || o.status == "skipped";
                    std::fprintf(stderr, "\r[%zu/%zu] %s: %s%s%s\n", ++done, cases.size(), cases[i].id.c_str(), o.status.c_str(),
                                 ended_well ? "" : ": ", ended_well ? "" : o.message.c_str());
                    stage.update(done);
                    try {
                        write_summaries(*folder, cases, outcomes, running_state());
                    } catch (const std::exception& e) {
                        std::fprintf(stderr, "heartprep: warning: %s\n", e.what());  // the final write reports it as an error
                    }
                }
            };
            std::vector<std::thread> workers;
            for (int w = 0; w < workers_count; ++w) workers.emplace_back(worker, w);
            for (auto& w : workers) w.join();
        }
        const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        const int stopped_by = stop_signal.load();
        std::ostringstream state;
        state << "In " << std::fixed << std::setprecision(1) << total << " s with -j " << *jobs << ".";
        if (stopped_by) state << " Stopped by " << signal_name(stopped_by) << ": run the same command again to finish.";
        const std::string table = write_summaries(*folder, cases, outcomes, state.str());
        std::fputs(table.c_str(), stdout);
        std::fflush(stdout);
        if (stopped_by) {
            std::fprintf(stderr, "heartprep: batch stopped by %s; the summary is %s\n", signal_name(stopped_by).c_str(),
                         (*folder / "summary.md").c_str());
            // End by the same signal, so a calling shell or script stops too.
            std::signal(stopped_by, SIG_DFL);
            std::raise(stopped_by);
        }
        const auto failed = std::count_if(outcomes.begin(), outcomes.end(), [](const Outcome& o) { return o.status == "failed"; });
        if (failed) throw InputError(std::to_string(failed) + " of " + std::to_string(cases.size()) + " cases failed (see " +
                                     (*folder / "summary.md").string() + ")");
    });
}

}  // namespace heartsim::cli
