// `heartprep batch`: many cases at once. Each case runs as its own `heartprep build` process, so a
// crash or an out-of-memory in one case cannot take the others down; a case whose input bytes,
// options and heartprep version are unchanged since its scenario was written is skipped.
#include "commands.h"
#include "manifest.h"
#include "terminal_progress.h"

#include "formats/atomic_file.h"
#include "formats/scenario.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <fcntl.h>
#include <fstream>
#include <iomanip>
#include <memory>
#include <mutex>
#include <spawn.h>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

extern char** environ;

namespace heartsim::cli {

namespace {

namespace fs = std::filesystem;

struct Outcome {
    std::string status = "failed";  ///< built, skipped, failed
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

/// Runs `arguments` with stdout and stderr into `log`; returns the exit status (−signal if killed).
int run_process(const std::vector<std::string>& arguments, const fs::path& log) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
    posix_spawn_file_actions_addclose(&actions, STDIN_FILENO);
    std::vector<char*> argv;
    for (const auto& a : arguments) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    pid_t pid = 0;
    const int spawned = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    if (spawned != 0) return 127;
    int status = 0;
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

void fill_counts(const Scenario& s, Outcome& outcome) {
    outcome.particles = s.lattice.particles.size();
    outcome.springs = s.lattice.springs.size();
    outcome.triangles = s.visual ? s.visual->triangles.size() : 0;
}

Outcome run_case(const BatchCase& c, const fs::path& folder, const fs::path& executable) {
    Outcome outcome;
    const auto start = std::chrono::steady_clock::now();
    const fs::path output = folder / (c.id + ".h5");
    const fs::path log = folder / "logs" / (c.id + ".log");
    try {
        if (!fs::exists(c.input)) throw InputError(c.input.string() + ": file not found");
        // The format version is in the key: a build of a newer format is not skipped as up to date.
        const std::string key = sha256_text(sha256_file(c.input) + "\n" + c.options + "\nheartprep " + HEARTSIM_VERSION +
                                            " format " + std::to_string(scenario_format_version));
        if (fs::exists(output)) {
            try {
                const Scenario existing = read_scenario(output);
                if (existing.batch_key == key) {
                    outcome.status = "skipped";
                    fill_counts(existing, outcome);
                    return outcome;
                }
            } catch (const InputError&) {
                // A damaged or foreign file: build the case again.
            }
        }
        std::vector<std::string> arguments{executable.string(), "build", c.input.string(), "-o", output.string(), "--batch-key", key};
        for (auto& word : split_words(c.options)) arguments.push_back(word);
        const int status = run_process(arguments, log);
        std::ifstream in(log);
        std::string line;
        while (std::getline(in, line)) {
            if (line.rfind("heartprep: warning: ", 0) == 0) outcome.warnings.push_back(line.substr(20));
            if (line.rfind("heartprep: error: ", 0) == 0) outcome.message = line.substr(18);
        }
        if (status != 0) {
            if (outcome.message.empty())
                outcome.message = status < 0 ? "killed by signal " + std::to_string(-status) + " (see " + log.string() + ")"
                                             : "exit status " + std::to_string(status) + " (see " + log.string() + ")";
        } else {
            fill_counts(read_scenario(output), outcome);
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

}  // namespace

void add_batch_command(CLI::App& app) {
    auto* command = app.add_subcommand("batch", "Build many cases in parallel: resumable, with a summary table");
    command->footer(
        "\nMANIFEST is a CSV file of lines `input[,case_id[,options]]` (a header line starting with `input` and\n"
        "lines starting with # are ignored; relative paths are relative to the manifest), or a folder of label maps.\n"
        "Each case is written to DIR/<case_id>.h5 by its own `heartprep build` process, its output to\n"
        "DIR/logs/<case_id>.log. Per-case options replace --options. A case whose input bytes, options and\n"
        "heartprep version are unchanged since its scenario was written is skipped. One failing case does not\n"
        "stop the others; the exit status is non-zero if any case failed. Summary: DIR/summary.csv, DIR/summary.md.\n"
        "Example:\n  heartprep batch cases.csv -o scenarios/ -j 2 --options \"--cavity 2 --anchor-border\"");
    auto manifest = std::make_shared<fs::path>();
    auto folder = std::make_shared<fs::path>();
    auto jobs = std::make_shared<int>(1);
    auto options = std::make_shared<std::string>();
    command->add_option("manifest", *manifest, "CSV manifest or folder of label maps")->required();
    command->add_option("-o,--output", *folder, "Folder for the scenarios, logs and summary (created if needed)")->required();
    command->add_option("-j,--jobs", *jobs, "Cases built at the same time")->check(CLI::Range(1, 256))->capture_default_str();
    command->add_option("--options", *options, "heartprep build options for every case, e.g. \"--cavity 2 --anchor-border\"");
    command->callback([=] {
        const auto cases = read_manifest(*manifest, *options);
        std::error_code error;
        fs::create_directories(*folder / "logs", error);
        if (error) throw OutputError(folder->string() + ": cannot create the output folder: " + error.message());
        const fs::path executable = self_executable();

        std::vector<Outcome> outcomes(cases.size());
        std::atomic<std::size_t> next{0}, done{0};
        std::mutex print;
        TerminalProgress progress(false);
        const auto start = std::chrono::steady_clock::now();
        {
            ProgressStage stage(progress, "batch", cases.size());
            auto worker = [&] {
                for (std::size_t i; (i = next++) < cases.size();) {
                    outcomes[i] = run_case(cases[i], *folder, executable);
                    std::lock_guard lock(print);
                    const auto& o = outcomes[i];
                    std::fprintf(stderr, "\r[%zu/%zu] %s: %s%s%s\n", ++done, cases.size(), cases[i].id.c_str(), o.status.c_str(),
                                 o.status == "failed" ? ": " : "", o.status == "failed" ? o.message.c_str() : "");
                    stage.update(done);
                }
            };
            std::vector<std::thread> workers;
            for (int w = 0; w < std::min<int>(*jobs, int(cases.size())); ++w) workers.emplace_back(worker);
            for (auto& w : workers) w.join();
        }
        const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

        std::ostringstream csv, markdown;
        csv << "case_id,input,status,particles,springs,triangles,seconds,warnings,message\n";
        markdown << "| case | status | particles | springs | triangles | time (s) | warnings |\n|---|---|---:|---:|---:|---:|---|\n";
        std::size_t failed = 0, skipped = 0;
        for (std::size_t i = 0; i < cases.size(); ++i) {
            const auto& c = cases[i];
            const auto& o = outcomes[i];
            failed += o.status == "failed";
            skipped += o.status == "skipped";
            std::string warnings;
            for (const auto& w : o.warnings) warnings += (warnings.empty() ? "" : "; ") + w;
            char seconds[32];
            std::snprintf(seconds, sizeof seconds, "%.2f", o.seconds);
            csv << csv_quote(c.id) << "," << csv_quote(c.input.string()) << "," << o.status << "," << o.particles << "," << o.springs
                << "," << o.triangles << "," << seconds << "," << csv_quote(warnings) << "," << csv_quote(o.message) << "\n";
            std::string cell = o.status == "failed" ? o.message : warnings;
            std::replace(cell.begin(), cell.end(), '|', '/');
            if (o.status != "failed" && cell.size() > 100)  // the CSV and the log keep the full text
                cell = std::to_string(o.warnings.size()) + " warning(s): " + cell.substr(0, 80) + "… (see logs/" + c.id + ".log)";
            markdown << "| " << c.id << " | " << o.status << " | " << o.particles << " | " << o.springs << " | " << o.triangles << " | "
                     << seconds << " | " << cell << " |\n";
        }
        markdown << "\n" << cases.size() << " cases: " << cases.size() - failed - skipped << " built, " << skipped << " skipped, "
                 << failed << " failed, in " << std::fixed << std::setprecision(1) << total << " s with -j " << *jobs << ".\n";
        write_text(*folder / "summary.csv", csv.str());
        write_text(*folder / "summary.md", markdown.str());
        std::fputs(markdown.str().c_str(), stdout);
        if (failed) throw InputError(std::to_string(failed) + " of " + std::to_string(cases.size()) + " cases failed (see " +
                                     (*folder / "summary.md").string() + ")");
    });
}

}  // namespace heartsim::cli
