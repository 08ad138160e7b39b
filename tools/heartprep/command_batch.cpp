// `heartprep batch`: many cases at once. Each case runs as its own `heartprep build` process, so a
// crash or an out-of-memory in one case cannot take the others down; a case whose input bytes,
// options and heartprep version are unchanged since its scenario was written is reused. The
// summary is rewritten (atomically) as each case ends, and a batch stopped by a signal stops its
// builds, waits for them and writes the summary before it ends by the same signal; its builds also
// end when it is killed outright (SIGKILL), through the parent-death signal.
//
// Each build leaves a record beside its log, DIR/logs/<id>.build.json: who built the scenario (this
// batch or a job of workflow/Snakefile, which writes the same record through
// workflow/build_case.py), how long the build took and when it ended, or why it failed. The summary
// takes each case's build time from it, so a reused case shows the time of the build that made its
// file, and the workflow's summary (`--no-build --workflow-run RUN`) tells the cases its own jobs
// built in this run from those it found done.
#include "commands.h"
#include "manifest.h"
#include "pipeline.h"
#include "terminal_progress.h"

#include "formats/atomic_file.h"
#include "formats/scenario.h"
#include "formats/xdmf.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "libmodel/supports.h"
#include "cli/exit_codes.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
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
    /// pending (not finished yet), built (by this batch), built by the workflow (by a job of the
    /// workflow run given with --workflow-run), reused (up to date, skipped), failed, interrupted
    /// (its build was stopped with the batch), not started (the batch was stopped first; with
    /// --no-build: no build ran for the case's current key)
    std::string status = "pending";
    std::size_t particles = 0, springs = 0, triangles = 0;
    /// Particles that do not move / on surface supports (count_surface_supported: the elastic
    /// foundation under every free particle is not counted), as build and inspect count them.
    std::size_t anchored = 0, supported = 0;
    /// The tissue's volume: the label map's tissue voxels (/source tissue_volume_mm3), the figure
    /// build and inspect give; none for a file from before it was stored (inspect: null).
    std::optional<double> tissue_volume_ml;
    std::string heart;  ///< what the heart is made of (pipeline.h heart_contents): labelled and grown walls
    double spacing_mm = 0.0, dt_ms = 0.0;     ///< the lattice spacing and the scenario's time step
    /// The build's wall time, s: of the build that made the scenario (a reused case: from its build
    /// record; unknown for a scenario without one), or until the case failed or was stopped.
    std::optional<double> seconds;
    std::string built_by;  ///< "batch" or "workflow", from the build record; empty when unknown
    std::string built_at;  ///< when that build ended, UTC (ISO 8601); empty when unknown
    std::vector<std::string> warnings;
    std::string message;
    std::string preview;       ///< previews/<id>.png, relative to the batch folder; empty when there is none
    std::string preview_note;  ///< why there is none (or "" when it was not asked for)
};

/// Where a case's scenario goes.
fs::path output_of(const BatchCase& c, const fs::path& folder) { return folder / (c.id + ".h5"); }

/// Whether a case with this status has a scenario that its summary row describes.
bool has_scenario(const std::string& status) { return status == "built" || status == "built by the workflow" || status == "reused"; }

// ------------------------------------------------------------------------------------------------
// Build records: DIR/logs/<id>.build.json, one per case, rewritten (atomically) by each build of it.

/// What one build of a case left: written by the batch for its builds and by the workflow's build
/// jobs (workflow/build_case.py writes the same fields).
struct BuildRecord {
    std::string key{};                               ///< the content key the build was given (`--batch-key`)
    std::string built_by{};                          ///< "batch" or "workflow"
    std::string run{};                               ///< a workflow build's run (DIR/logs/workflow-run); empty for a batch
    std::string status{};                            ///< "built", "failed", or "running" (a build that never reported its end)
    std::optional<double> seconds{};                 ///< the build's wall time, s
    std::string finished{};                          ///< when it ended, UTC, ISO 8601
    std::optional<std::uintmax_t> scenario_bytes{};  ///< the size of the scenario it wrote, bytes
    std::string message{};                           ///< why it failed
};

fs::path record_of(const BatchCase& c, const fs::path& folder) { return folder / "logs" / (c.id + ".build.json"); }

/// The record at `path`; none when there is none or it cannot be read (a record is a report, never
/// a reason to fail the batch).
std::optional<BuildRecord> read_record(const fs::path& path) {
    std::ifstream in(path);
    if (!in) return std::nullopt;
    const auto json = nlohmann::json::parse(in, nullptr, false);
    if (!json.is_object()) return std::nullopt;
    auto text = [&](const char* name) { return json.contains(name) && json[name].is_string() ? json[name].get<std::string>() : std::string(); };
    BuildRecord record{.key = text("key"), .built_by = text("built_by"), .run = text("run"), .status = text("status"),
                       .finished = text("finished"), .message = text("message")};
    if (json.contains("seconds") && json["seconds"].is_number()) record.seconds = json["seconds"].get<double>();
    if (json.contains("scenario_bytes") && json["scenario_bytes"].is_number_unsigned())
        record.scenario_bytes = json["scenario_bytes"].get<std::uintmax_t>();
    return record;
}

std::string utc_now() {
    const std::time_t now = std::time(nullptr);
    std::tm parts{};
    ::gmtime_r(&now, &parts);
    char text[32];
    std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &parts);
    return text;
}

/// Writes the record of a build of this batch; a record that cannot be written costs the summary
/// its build time, never the case (a warning says so).
void write_record(const BatchCase& c, const fs::path& folder, const BuildRecord& record) {
    nlohmann::ordered_json json{{"case_id", c.id}, {"key", record.key}, {"built_by", record.built_by}, {"status", record.status}};
    json["seconds"] = record.seconds ? nlohmann::ordered_json(*record.seconds) : nlohmann::ordered_json();
    json["finished"] = record.finished;
    if (record.scenario_bytes) json["scenario_bytes"] = *record.scenario_bytes;
    json["message"] = record.message;
    const std::string text = json.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) + "\n";
    try {
        write_bytes_atomically(record_of(c, folder), text.data(), text.size(), "the build record");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "heartprep: warning: %s\n", e.what());
    }
}

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
ChildStatus run_process(const std::vector<std::string>& arguments, const fs::path& log, std::atomic<pid_t>& slot,
                        bool append = false) {
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
        const int out = ::open(log.c_str(), O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0644);
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

void fill_figures(const Scenario& s, Outcome& outcome) {
    const auto& p = s.lattice.particles;
    outcome.particles = p.size();
    outcome.springs = s.lattice.springs.size();
    outcome.triangles = s.visual ? s.visual->triangles.size() : 0;
    outcome.anchored = std::size_t(std::count_if(p.anchored.begin(), p.anchored.end(), [](auto a) { return a != 0; }));
    outcome.supported = count_surface_supported(s.lattice);
    outcome.tissue_volume_ml.reset();
    if (s.source.tissue_volume_mm3 > 0) outcome.tissue_volume_ml = s.source.tissue_volume_mm3 / 1000.0;
    outcome.heart = heart_contents(s);
    outcome.spacing_mm = s.lattice.spacing;
    outcome.dt_ms = s.solver.dt_ms;
}

/// The content key of a case: SHA-256 of its input's content (label_map_sha256: a detached
/// header's data file too), its build options and the heartprep
/// version with the scenario format and the build's defaults (a build of a newer format, or one whose
/// defaults make something else, is not skipped as up to date).
/// `heartprep build --batch-key` stores it in the scenario; batch and the Snakemake workflow
/// (workflow/Snakefile, through `batch --plan`) skip a case whose scenario carries it.
std::string content_key(const BatchCase& c) {
    std::string content;
    try {
        content = label_map_sha256(c.input);
    } catch (const InputError&) {
        content = sha256_file(c.input);  // a header the reader refuses: its build fails and says why
    }
    return sha256_text(content + "\n" + c.options + "\nheartprep " + HEARTSIM_VERSION + " format " +
                       std::to_string(scenario_format_version) + " defaults " + std::to_string(build_defaults_revision));
}

/// Whether the scenario at `output` was built from `key` (and kept its build's warnings, so the
/// summary can report them); fills `outcome` from it when it was.
bool up_to_date(const fs::path& output, const std::string& key, Outcome* outcome) {
    if (!fs::exists(output)) return false;
    try {
        const Scenario existing = read_scenario(output);
        if (existing.batch_key != key || !existing.build_warnings) return false;
        if (outcome) {
            // A scenario built before its ParaView description was written gets one.
            if (!fs::exists(xdmf_beside(output))) write_scenario_xdmf(output, existing);
            fill_figures(existing, *outcome);
            outcome->warnings = *existing.build_warnings;
        }
        return true;
    } catch (const InputError&) {
        return false;  // a damaged or foreign file: build the case again
    }
}

/// heartsim, for the previews: beside heartprep (an install), in the build tree's runtime/ folder,
/// or on PATH; empty when there is none.
fs::path find_heartsim(const fs::path& heartprep) {
    std::vector<fs::path> candidates{heartprep.parent_path() / "heartsim", heartprep.parent_path().parent_path() / "runtime" / "heartsim"};
    if (const char* path = std::getenv("PATH")) {
        std::istringstream folders(path);
        for (std::string folder; std::getline(folders, folder, ':');) candidates.push_back(fs::path(folder.empty() ? "." : folder) / "heartsim");
    }
    std::error_code error;
    for (const fs::path& candidate : candidates)
        if (fs::is_regular_file(candidate, error) && ::access(candidate.c_str(), X_OK) == 0) return candidate;
    return {};
}

/// What the batch was asked to do beyond building.
struct BatchSettings {
    int threads = 1;          ///< --threads of each build
    fs::path heartsim;        ///< renders the previews; empty: no previews
    std::string no_preview;   ///< why there are none, when `heartsim` is empty
    bool force = false;       ///< --force: build every case, up to date or not
    bool no_build = false;    ///< --no-build: report the folder as it stands (the workflow's summary)
    std::string workflow_run; ///< --workflow-run: the run whose builds are `built by the workflow`
};

/// Fills a case whose scenario is up to date from its build record: `reused`, or `built by the
/// workflow` when a job of this workflow run built it, with that build's time. A record that is
/// not about this scenario (another key, another size: a file replaced since) gives no time.
void describe_existing_build(const BatchCase& c, const fs::path& folder, const std::string& key, const BatchSettings& settings,
                             Outcome& outcome) {
    outcome.status = "reused";
    const auto record = read_record(record_of(c, folder));
    if (!record || record->status != "built" || record->key != key) return;
    std::error_code error;
    const auto bytes = fs::file_size(output_of(c, folder), error);
    if (record->scenario_bytes && (error || bytes != *record->scenario_bytes)) return;
    outcome.seconds = record->seconds;
    outcome.built_by = record->built_by;
    outcome.built_at = record->finished;
    if (!settings.workflow_run.empty() && record->built_by == "workflow" && record->run == settings.workflow_run)
        outcome.status = "built by the workflow";
}

/// --no-build: what became of a case whose scenario is not up to date, from its build record.
void describe_missing_build(const BatchCase& c, const fs::path& folder, const std::string& key, Outcome& outcome) {
    const auto record = read_record(record_of(c, folder));
    const std::string log = (folder / "logs" / (c.id + ".log")).string();
    if (!record || record->key != key || (record->status != "failed" && record->status != "running")) {
        outcome.status = "not started";
        outcome.message = "not built: no build of its current input and options has run (the workflow stopped before it?)";
        return;
    }
    outcome.status = "failed";
    outcome.seconds = record->seconds;
    outcome.built_by = record->built_by;
    outcome.built_at = record->finished;
    outcome.message = record->status == "running"
                          ? "its build began but never reported an end: stopped, or killed by the cluster (out of time or memory?); see " + log
                          : (record->message.empty() ? "see " + log : record->message);
}

/// The picture of a case at rest, previews/<id>.png, rendered headless by heartsim (its output is
/// appended to the case's log). Kept while newer than the scenario.
void make_preview(const BatchCase& c, const fs::path& folder, const BatchSettings& settings, std::atomic<pid_t>& slot,
                  Outcome& outcome) {
    if (settings.heartsim.empty()) {
        outcome.preview_note = settings.no_preview;
        return;
    }
    const fs::path output = output_of(c, folder);
    const std::string relative = "previews/" + c.id + ".png";
    const fs::path picture = folder / relative;
    std::error_code error;
    if (fs::exists(picture, error) && fs::last_write_time(picture, error) >= fs::last_write_time(output, error) && !error) {
        outcome.preview = relative;
        return;
    }
    fs::remove(picture, error);  // an old picture of an older scenario
    if (stop_signal.load()) return;
    const ChildStatus status = run_process({settings.heartsim.string(), "run", output.string(), "--headless", "--backend", "cpu",
                                            "--steps", "0", "--screenshot", picture.string(), "--size", "320x240"},
                                           folder / "logs" / (c.id + ".log"), slot, true);
    if (status.exit_code == 0 && !status.signal && !status.fork_error && fs::exists(picture, error)) {
        outcome.preview = relative;
    } else {
        outcome.preview_note = status.exit_code == exit_status(ExitCode::no_opengl) ? "no preview: no usable OpenGL (see logs/" + c.id + ".log)"
                                                     : "no preview: heartsim failed (see logs/" + c.id + ".log)";
    }
}

Outcome run_case(const BatchCase& c, const fs::path& folder, const fs::path& executable, const BatchSettings& settings,
                 std::atomic<pid_t>& slot) {
    Outcome outcome;
    outcome.status = "failed";
    const auto start = std::chrono::steady_clock::now();
    auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); };
    const fs::path output = output_of(c, folder);
    const fs::path log = folder / "logs" / (c.id + ".log");
    std::string key;
    try {
        // Temporaries of builds killed in an earlier run (their process is gone). Not with
        // --no-build: on a cluster, the process of a temporary may live on another machine.
        if (!settings.no_build) {
            sweep_stale_temporaries(output);
            sweep_stale_temporaries(xdmf_beside(output));
        }
        if (!fs::exists(c.input)) throw InputError(c.input.string() + ": file not found");
        key = content_key(c);
        if (!settings.force && fs::exists(output)) {
            // A file from before scenarios kept their build's warnings is built again, so the
            // summary can report them.
            if (up_to_date(output, key, &outcome)) {
                describe_existing_build(c, folder, key, settings, outcome);
                make_preview(c, folder, settings, slot, outcome);
                return outcome;
            }
        }
        if (settings.no_build) {
            describe_missing_build(c, folder, key, outcome);
            return outcome;
        }
        if (stop_signal.load()) {  // stopped while the existing scenario was being checked
            outcome.status = "not started";
            outcome.message = "the batch was stopped by " + signal_name(stop_signal.load()) + " first";
            return outcome;
        }
        std::vector<std::string> arguments{executable.string(), "build",   c.input.string(), "-o", output.string(), "--batch-key",
                                           key,                 "--threads", std::to_string(settings.threads)};
        const auto words = split_words(c.options);
        if (std::find(words.begin(), words.end(), "--threads") != words.end()) arguments.resize(arguments.size() - 2);  // theirs
        for (const auto& word : words) arguments.push_back(word);
        const auto build_start = std::chrono::steady_clock::now();
        const ChildStatus status = run_process(arguments, log, slot);
        const double build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - build_start).count();
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
        } else if (status.exit_code == exit_status(ExitCode::usage)) {
            // The build refused its command line: the batch passed it a bad option, from --options or
            // the case's options in the manifest (the build checks them; the batch does not).
            outcome.message = "heartprep build refused the options (" + (c.options.empty() ? std::string("none") : c.options) +
                              "; from --options or the manifest): " + (outcome.message.empty() ? "see " + log.string() : outcome.message);
        } else if (status.signal || status.exit_code != 0) {
            if (outcome.message.empty())
                outcome.message = status.signal ? "killed by " + signal_name(status.signal) + " (see " + log.string() + ")"
                                                : "exit status " + std::to_string(status.exit_code) + " (see " + log.string() + ")";
        } else {
            const Scenario built = read_scenario(output);
            fill_figures(built, outcome);
            outcome.warnings = built.build_warnings ? *built.build_warnings : logged_warnings;
            outcome.status = "built";
            outcome.seconds = build_seconds;
            outcome.built_by = "batch";
            outcome.built_at = utc_now();
            std::error_code error;
            const auto bytes = fs::file_size(output, error);
            write_record(c, folder, {.key = key, .built_by = "batch", .status = "built", .seconds = build_seconds,
                                     .finished = outcome.built_at,
                                     .scenario_bytes = error ? std::nullopt : std::optional<std::uintmax_t>(bytes)});
            make_preview(c, folder, settings, slot, outcome);
            return outcome;
        }
    } catch (const std::exception& e) {
        outcome.message = e.what();
    }
    outcome.seconds = elapsed();
    if (outcome.status == "failed" && !key.empty() && !settings.no_build) {
        outcome.built_by = "batch";
        outcome.built_at = utc_now();
        write_record(c, folder, {.key = key, .built_by = "batch", .status = "failed", .seconds = outcome.seconds,
                                 .finished = outcome.built_at, .message = outcome.message});
    }
    return outcome;
}

std::string csv_quote(const std::string& text) {
    std::string out = "\"";
    for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
    return out + "\"";
}

/// Writes `text` to `path` atomically.
void write_text(const fs::path& path, const std::string& text) { write_bytes_atomically(path, text.data(), text.size(), "the table"); }

std::string fixed(double value, int digits) {
    char text[64];
    std::snprintf(text, sizeof text, "%.*f", digits, value);
    return text;
}

/// The batch as JSON: summary.json, `--json`.
nlohmann::ordered_json summary_json(const fs::path& folder, const std::vector<BatchCase>& cases, const std::vector<Outcome>& outcomes,
                                    const std::string& state) {
    auto list = nlohmann::ordered_json::array();
    for (std::size_t i = 0; i < cases.size(); ++i) {
        const auto& c = cases[i];
        const auto& o = outcomes[i];
        const bool ended_well = has_scenario(o.status);
        nlohmann::ordered_json entry{{"case_id", c.id}, {"input", c.input.string()}, {"output", output_of(c, folder).string()},
                                     {"status", o.status}};
        if (ended_well) {
            entry["particles"] = o.particles;
            entry["springs"] = o.springs;
            entry["triangles"] = o.triangles;
            entry["anchored"] = o.anchored;
            entry["supported"] = o.supported;
            entry["tissue_volume_ml"] = o.tissue_volume_ml ? nlohmann::ordered_json(*o.tissue_volume_ml) : nlohmann::ordered_json();
            entry["spacing_mm"] = o.spacing_mm;
            entry["dt_ms"] = o.dt_ms;
            entry["heart"] = o.heart;
        }
        entry["seconds"] = o.seconds ? nlohmann::ordered_json(*o.seconds) : nlohmann::ordered_json();
        entry["built_by"] = o.built_by.empty() ? nlohmann::ordered_json() : nlohmann::ordered_json(o.built_by);
        entry["built_at"] = o.built_at.empty() ? nlohmann::ordered_json() : nlohmann::ordered_json(o.built_at);
        entry["warnings"] = o.warnings;
        entry["message"] = o.message;
        entry["preview"] = o.preview.empty() ? nlohmann::ordered_json() : nlohmann::ordered_json(o.preview);
        if (!o.preview_note.empty()) entry["preview_note"] = o.preview_note;
        list.push_back(std::move(entry));
    }
    return {{"folder", folder.string()}, {"state", state}, {"cases", std::move(list)}};
}

/// One JSON text: NaN and infinities as null (nlohmann's rule), bytes that are not UTF-8 replaced.
std::string dump(const nlohmann::ordered_json& json) { return json.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) + "\n"; }

/// summary.csv, summary.md and summary.json for every case of the manifest as the batch stands;
/// returns the markdown table. `state`: the line under the table that says whether the batch is
/// running, finished or stopped; `workflow`: the summary of a workflow run (--no-build), whose
/// count line leads with the cases its jobs built.
std::string write_summaries(const fs::path& folder, const std::vector<BatchCase>& cases, const std::vector<Outcome>& outcomes,
                            const std::string& state, bool workflow) {
    std::ostringstream csv, markdown;
    // The first nine columns as before the QC columns were added, so readers by position still work;
    // new columns go at the end.
    csv << "case_id,input,status,particles,springs,triangles,seconds,warnings,message,"
           "output,anchored,supported,tissue_volume_ml,spacing_mm,dt_ms,preview,built_by,built_at\n";
    markdown << "| case | status | particles | anchored | supported | tissue (mL) | spacing (mm) | dt (ms) | build time (s) | warnings | "
                "preview |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|\n";
    std::map<std::string, std::size_t> counts;
    for (std::size_t i = 0; i < cases.size(); ++i) {
        const auto& c = cases[i];
        const auto& o = outcomes[i];
        ++counts[o.status];
        const bool ended_well = has_scenario(o.status);
        std::string warnings;
        for (const auto& w : o.warnings) warnings += (warnings.empty() ? "" : "; ") + w;
        const std::string seconds = o.seconds ? fixed(*o.seconds, 2) : std::string();
        // A case without a scenario measured nothing: its figures are blank, not zero.
        auto figure = [&](const std::string& text) { return ended_well ? text : std::string(); };
        const std::string tissue_csv = o.tissue_volume_ml ? fixed(*o.tissue_volume_ml, 3) : "",
                          tissue_md = o.tissue_volume_ml ? fixed(*o.tissue_volume_ml, 1) : "";
        csv << csv_quote(c.id) << "," << csv_quote(c.input.string()) << "," << o.status << "," << figure(std::to_string(o.particles)) << ","
            << figure(std::to_string(o.springs)) << "," << figure(std::to_string(o.triangles)) << "," << seconds << "," << csv_quote(warnings)
            << "," << csv_quote(o.message) << "," << csv_quote(output_of(c, folder).string()) << "," << figure(std::to_string(o.anchored))
            << "," << figure(std::to_string(o.supported)) << "," << figure(tissue_csv) << "," << figure(fixed(o.spacing_mm, 4)) << ","
            << figure(fixed(o.dt_ms, 5)) << "," << csv_quote(o.preview) << "," << o.built_by << "," << o.built_at << "\n";
        std::string cell = ended_well ? warnings : o.message;
        std::replace(cell.begin(), cell.end(), '|', '/');
        if (ended_well && cell.size() > 100)  // the CSV and the log keep the full text
            cell = std::to_string(o.warnings.size()) + " warning(s): " + cell.substr(0, 80) + "… (see logs/" + c.id + ".log)";
        std::string picture = o.preview.empty() ? o.preview_note : "![" + c.id + "](" + o.preview + ")";
        std::replace(picture.begin(), picture.end(), '|', '/');
        markdown << "| " << c.id << " | " << o.status << " | " << figure(std::to_string(o.particles)) << " | " << figure(std::to_string(o.anchored))
                 << " | " << figure(std::to_string(o.supported)) << " | " << figure(tissue_md) << " | " << figure(fixed(o.spacing_mm, 2)) << " | "
                 << figure(fixed(o.dt_ms, 4)) << " | "
                 << (seconds.empty() && ended_well ? "unknown" : seconds) << " | " << cell << " | " << picture << " |\n";
    }
    // Always the statuses of this kind of run, then any other that occurs.
    const std::vector<std::string> always = workflow ? std::vector<std::string>{"built by the workflow", "reused", "failed"}
                                                     : std::vector<std::string>{"built", "reused", "failed"};
    markdown << "\n" << cases.size() << " cases: ";
    bool first = true;
    for (const char* status : {"built by the workflow", "built", "reused", "failed", "interrupted", "not started", "pending"}) {
        if (!counts[status] && std::find(always.begin(), always.end(), status) == always.end()) continue;
        markdown << (first ? "" : ", ") << counts[status] << " " << status;
        first = false;
    }
    markdown << ". " << state << "\n";
    const char* gap = "\n";  // then what each heart is made of: the labels' walls, and those grown
    for (std::size_t i = 0; i < cases.size(); ++i)
        if (has_scenario(outcomes[i].status) && !outcomes[i].heart.empty()) markdown << std::exchange(gap, "") << "- " << cases[i].id << ": " << outcomes[i].heart << "\n";
    write_text(folder / "summary.csv", csv.str());
    write_text(folder / "summary.md", markdown.str());
    write_text(folder / "summary.json", dump(summary_json(folder, cases, outcomes, state)));
    return markdown.str();
}

/// `heartprep batch --plan`: each case's id, input, output, options, content key and whether its
/// scenario is up to date, as JSON on stdout.
void print_batch_plan(const std::vector<BatchCase>& cases, const fs::path& folder) {
    auto list = nlohmann::ordered_json::array();
    for (const auto& c : cases) {
        const std::string key = fs::exists(c.input) ? content_key(c) : std::string();
        list.push_back({{"case_id", c.id}, {"input", fs::absolute(c.input).lexically_normal().string()},
                        {"output", fs::absolute(output_of(c, folder)).lexically_normal().string()}, {"options", c.options},
                        {"options_words", split_words(c.options)}, {"key", key},
                        {"up_to_date", !key.empty() && up_to_date(output_of(c, folder), key, nullptr)}});
    }
    std::fputs(dump(nlohmann::ordered_json{{"cases", std::move(list)}}).c_str(), stdout);
}

/// Builds `cases` on `jobs` workers, each by run_case, the summary rewritten as each ends (and
/// once before any starts); where stderr is not a terminal, a line every progress interval says
/// which cases are running. A stop signal leaves the cases not begun `not started`.
std::vector<Outcome> build_cases(const std::vector<BatchCase>& cases, const fs::path& folder, const fs::path& executable,
                                 const BatchSettings& settings, int jobs, bool no_build, std::chrono::steady_clock::time_point start) {
    std::vector<Outcome> outcomes(cases.size());
    std::atomic<std::size_t> next{0};
    std::size_t done = 0;
    std::mutex print;  // the progress lines, `outcomes`, `running` and the summary files
    std::condition_variable ended;  // a case ended
    std::vector<std::pair<std::size_t, std::chrono::steady_clock::time_point>> running(std::size_t(jobs), {cases.size(), {}});
    TerminalProgress progress(false);
    const int workers_count = std::min<int>(jobs, int(cases.size()));
    auto running_state = [&] {
        return "The batch is running: " + std::to_string(done) + " of " + std::to_string(cases.size()) +
               " cases finished (this table is rewritten as each case ends).";
    };
    catch_stop_signals();
    // Before any build starts: a summary left by an earlier run no longer describes the folder.
    write_summaries(folder, cases, outcomes, running_state(), no_build);
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
                {
                    std::lock_guard lock(print);
                    running[std::size_t(w)] = {i, std::chrono::steady_clock::now()};
                }
                Outcome outcome = run_case(cases[i], folder, executable, settings, running_children[std::size_t(w)]);
                std::lock_guard lock(print);
                running[std::size_t(w)].first = cases.size();
                outcomes[i] = std::move(outcome);
                const auto& o = outcomes[i];
                const bool ended_well = has_scenario(o.status);
                std::fprintf(stderr, "\r[%zu/%zu] %s: %s%s%s\n", ++done, cases.size(), cases[i].id.c_str(), o.status.c_str(),
                             ended_well ? "" : ": ", ended_well ? "" : o.message.c_str());
                stage.update(done);
                try {
                    write_summaries(folder, cases, outcomes, running_state(), no_build);
                } catch (const std::exception& e) {
                    std::fprintf(stderr, "heartprep: warning: %s\n", e.what());  // the final write reports it as an error
                }
                ended.notify_all();
            }
        };
        std::vector<std::thread> workers;
        for (int w = 0; w < workers_count; ++w) workers.emplace_back(worker, w);
        // In a log or a pipe, nothing else shows that a long case is still going: a line now and then.
        const double interval = progress_interval_seconds();
        if (!isatty(fileno(stderr)) && interval > 0.0) {
            std::unique_lock lock(print);
            while (done < cases.size() && !stop_signal.load()) {
                if (ended.wait_for(lock, std::chrono::duration<double>(interval)) != std::cv_status::timeout) continue;
                if (done >= cases.size()) break;
                const auto now = std::chrono::steady_clock::now();
                std::string names;
                for (const auto& [i, since] : running)
                    if (i < cases.size())
                        names += (names.empty() ? "" : ", ") + cases[i].id + " (" +
                                 fixed(std::chrono::duration<double>(now - since).count(), 0) + " s)";
                std::fprintf(stderr, "heartprep: batch: %zu of %zu cases finished after %.0f s; running: %s\n", done, cases.size(),
                             std::chrono::duration<double>(now - start).count(), names.empty() ? "none" : names.c_str());
                std::fflush(stderr);
            }
        }
        for (auto& w : workers) w.join();
    }
    return outcomes;
}

}  // namespace

void add_batch_command(CLI::App& app) {
    auto* command = app.add_subcommand("batch", "Build many cases in parallel: resumable, with a summary table and a picture per case");
    command->footer(
        "\nMANIFEST is a CSV file of lines `input[,case_id[,options]]` (a header line starting with `input` and\n"
        "lines starting with # are ignored; relative paths are relative to the manifest), or a folder of label maps\n"
        "(all of them, or those whose name matches --pattern; the case id is the file name without its extension).\n"
        "Each case is written to DIR/<case_id>.h5 by its own `heartprep build --threads T` process, its output to\n"
        "DIR/logs/<case_id>.log, and pictured at rest in DIR/previews/<case_id>.png by `heartsim run --headless`\n"
        "(found beside heartprep or on PATH). Per-case options replace --options. A case whose input bytes,\n"
        "options and heartprep version are unchanged since its scenario was written is `reused` (its build's\n"
        "warnings, kept in the scenario, are reported again). One failing case does not stop the others; the exit\n"
        "status is non-zero if any case failed. Summary: DIR/summary.md (with the pictures), DIR/summary.csv and\n"
        "DIR/summary.json, rewritten as each case ends (cases not finished yet are `pending`): per case `built`,\n"
        "`built by the workflow`, `reused` or `failed`, with the time of the build that made its scenario (each\n"
        "build's record: DIR/logs/<case_id>.build.json). When stderr is not a terminal, a line every 10 s says\n"
        "which cases are running (HEARTPREP_PROGRESS_SECONDS sets the interval).\n"
        "SIGINT (Ctrl-C), SIGTERM or SIGHUP stop the running builds (`interrupted`) and the cases not begun\n"
        "(`not started`), write the summary, and end the batch by the same signal (a shell reports 128 + its\n"
        "number: 130, 143, 129); run the command again to finish. On a cluster, workflow/Snakefile runs one case\n"
        "per job with the same reuse (docs/user-guide.md, \"Batch on a cluster\").\n"
        "Examples:\n  heartprep batch cases.csv -o scenarios/ -j 2 --options \"--cavity 2 --anchor-border\"\n"
        "  heartprep batch mri/ --pattern '*-label.nii.gz' -o scenarios/ -j 4 --threads 2");
    auto manifest = std::make_shared<fs::path>();
    auto folder = std::make_shared<fs::path>();
    auto jobs = std::make_shared<int>(1);
    auto threads = std::make_shared<int>(0);
    auto options = std::make_shared<std::string>();
    auto pattern = std::make_shared<std::string>();
    auto json = std::make_shared<bool>(false);
    auto plan = std::make_shared<bool>(false);
    auto no_preview = std::make_shared<bool>(false);
    auto no_build = std::make_shared<bool>(false);
    auto force = std::make_shared<bool>(false);
    auto workflow_run = std::make_shared<std::string>();
    command->add_option("manifest", *manifest, "CSV manifest or folder of label maps")->required();
    command->add_option("-o,--output", *folder, "Folder for the scenarios, logs, previews and summary (created if needed)")->required();
    command->add_option("-j,--jobs", *jobs, "Cases built at the same time")->check(CLI::Range(1, max_jobs))->capture_default_str();
    command->add_option("--threads", *threads, "Threads of each case's build (default: the cores divided by --jobs, at least 1)")
        ->check(CLI::Range(1, 4096));
    command->add_option("--options", *options, "heartprep build options for every case, e.g. \"--cavity 2 --anchor-border\"");
    command->add_option("--pattern", *pattern, "With a folder: only the files whose name matches this shell pattern, e.g. '*-label.nii.gz'");
    command->add_flag("--json", *json, "Print the summary as JSON (as DIR/summary.json) instead of the table");
    command->add_flag("--plan", *plan,
                      "Build nothing: print each case's id, input, output, options, content key and whether it is up to date, as JSON");
    command->add_flag("--no-preview", *no_preview, "No pictures (previews need heartsim and OpenGL, e.g. Mesa's llvmpipe)");
    command->add_flag("--force", *force, "Build every case again, also those whose scenario is up to date");
    command->add_flag("--no-build", *no_build,
                      "Build nothing: write the summary of the folder as it stands (a case not up to date is `failed` or `not "
                      "started`, from its build record); the workflow's summary");
    command->add_option("--workflow-run", *workflow_run,
                        "With --no-build: the workflow run (DIR/logs/workflow-run) whose builds are `built by the workflow`; other "
                        "up-to-date cases are `reused`")
        ->needs(command->get_option("--no-build"));
    command->get_option("--no-build")->excludes(command->get_option("--force"));
    command->callback([=] {
        if (!pattern->empty() && !fs::is_directory(*manifest))
            throw UsageError("--pattern chooses files of a folder; " + manifest->string() + " is not a folder");
        const auto cases = read_manifest(*manifest, *options, *pattern);
        if (*plan) {
            print_batch_plan(cases, *folder);
            return;
        }
        std::error_code error;
        fs::create_directories(*folder / "logs", error);
        if (!error && !*no_preview) fs::create_directories(*folder / "previews", error);
        if (error) throw OutputError(folder->string() + ": cannot create the output folder: " + error.message());
        const fs::path executable = self_executable();
        BatchSettings settings;
        settings.no_build = *no_build;
        settings.force = *force;
        settings.workflow_run = *workflow_run;
        const int cores = int(std::max(1u, std::thread::hardware_concurrency()));
        settings.threads = *threads > 0 ? *threads : std::max(1, cores / *jobs);
        if (!*no_preview) {
            settings.heartsim = find_heartsim(executable);
            if (settings.heartsim.empty()) {
                settings.no_preview = "no preview: heartsim is neither beside heartprep nor on PATH";
                std::fprintf(stderr, "heartprep: warning: %s\n", settings.no_preview.c_str());
            }
        }

        const auto start = std::chrono::steady_clock::now();
        const std::vector<Outcome> outcomes = build_cases(cases, *folder, executable, settings, *jobs, *no_build, start);
        const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        const int stopped_by = stop_signal.load();
        std::ostringstream state;
        if (*no_build)
            state << "The folder as it stands" << (workflow_run->empty() ? "" : " after workflow run " + *workflow_run)
                  << " (heartprep batch --no-build, which builds nothing), in " << std::fixed << std::setprecision(1) << total << " s.";
        else
            state << "In " << std::fixed << std::setprecision(1) << total << " s with -j " << *jobs << " --threads " << settings.threads << ".";
        if (stopped_by) state << " Stopped by " << signal_name(stopped_by) << ": run the same command again to finish.";
        const std::string table = write_summaries(*folder, cases, outcomes, state.str(), *no_build);
        std::fputs(*json ? dump(summary_json(*folder, cases, outcomes, state.str())).c_str() : table.c_str(), stdout);
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
