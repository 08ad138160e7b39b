// Haptics benchmark analyser (not a test): reads haptic session recordings
// (`heartsim run … --device … --record REC.h5`, formats/recording.h) and prints one row per
// recording: the device thread's period, the pose → force latency, and the error of the force the
// device thread rendered between simulation updates. tests/bench/run_haptics_bench.sh records the
// sessions; results in docs/benchmarks.md, "Haptics".
//
//   haptics_bench [--format markdown|csv] [--part timing|force|all] [--per-hand] [--no-header]
//                 REC.h5 [REC2.h5 …]
//
// Definitions (also printed as the output's header):
//  * period p50 / p99 / max / mean, periods, overruns: the recording's root attributes (the device
//    thread's own 1 µs histogram, tick start to tick start). "> 1.5 ms" and p99.9: from the
//    recorded tick times of /hand0 (or /hand1) (the same tick starts; every tick is recorded unless
//    the recording has a ticks_dropped event).
//  * latency p50 / p99 / max ms: the recording's attributes: from the tick that read a pose to the
//    first tick that received a force computed from it (device thread, so ≥ one period).
//  * latency steps p50 / p99 / max: from /steps: for each tool sample (a distinct tool_time_ms), j0 =
//    the first step that used it, k = the first step row at or after j0 whose published forces come
//    from a step ≥ j0 (force_step ≥ j0); steps = k − j0 + 1 (1: the forces published right after the
//    step that first used the pose). Tool samples never followed by such forces are not counted.
//  * real-time factor: simulated time over wall time of the steps (/steps/time_ms, /steps/wall_ms);
//    step wall ms: the steps' mean wall time per step.
//  * force error: for each device tick of each used hand, the force before the safety chain
//    (/handN/input_n, device frame; equal to the world frame for scripted and simulated devices)
//    against a reference: the published simulation forces (/steps/force_n at /steps/wall_ms, only
//    rows where force_step changes, i.e. a new sample) linearly interpolated at the tick time. The
//    reference is non-causal: what an ideal zero-delay renderer would show. Counted only over ticks
//    inside the published range (first to last new sample) whose safety gain is 1 (fade-in and
//    fade-out excluded). err rms / max N: over |input − reference| of those ticks (both hands
//    together unless --per-hand); ref rms N: RMS of |reference| over the same ticks; rel = err /
//    ref rms. ref roughness: RMS |second difference| / RMS |first difference| of the published
//    samples (per sample, per component): ≪ 1 when the force is smooth at the sample rate (first
//    order extrapolation then helps), √2 or more when it changes direction from sample to sample
//    (extrapolation then amplifies the change).
#include "formats/recording.h"
#include "libmodel/errors.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

struct ForceError {
    std::size_t ticks = 0;         ///< hand-ticks compared
    std::size_t ticks_total = 0;   ///< hand-ticks recorded
    double err_sq = 0.0, err_max = 0.0, ref_sq = 0.0, ref_max = 0.0;
    double d1_sq = 0.0, d2_sq = 0.0;  ///< published samples: squared first and second differences
    void add(double e, double r) {
        ++ticks;
        err_sq += e * e;
        err_max = std::max(err_max, e);
        ref_sq += r * r;
        ref_max = std::max(ref_max, r);
    }
    void merge(const ForceError& o) {
        ticks += o.ticks;
        ticks_total += o.ticks_total;
        err_sq += o.err_sq;
        err_max = std::max(err_max, o.err_max);
        ref_sq += o.ref_sq;
        ref_max = std::max(ref_max, o.ref_max);
        d1_sq += o.d1_sq;
        d2_sq += o.d2_sq;
    }
    double roughness() const { return d1_sq > 0 ? std::sqrt(d2_sq / d1_sq) : NAN; }
    double err_rms() const { return ticks ? std::sqrt(err_sq / double(ticks)) : NAN; }
    double ref_rms() const { return ticks ? std::sqrt(ref_sq / double(ticks)) : NAN; }
};

struct Analysis {
    std::string name;
    const Recording* r = nullptr;
    // timing
    std::size_t steps = 0, published = 0;
    double real_time_factor = NAN;
    double step_wall_ms = NAN;  ///< mean wall time per step
    double over_1_5 = 0;     ///< recorded periods > 1.5 ms
    std::size_t recorded_periods = 0;
    double p999_ms = NAN;
    std::size_t latency_samples = 0;
    int lat_steps_p50 = 0, lat_steps_p99 = 0, lat_steps_max = 0;
    double publish_latency_p50_ms = NAN, publish_latency_p99_ms = NAN;  ///< pose read → forces published (/steps)
    // force
    std::array<ForceError, 2> hand{};
    ForceError all{};
};

template <typename T>
T percentile(std::vector<T> v, double q) {
    if (v.empty()) return T{};
    std::sort(v.begin(), v.end());
    const std::size_t i = std::min(v.size() - 1, std::size_t(std::max(0.0, std::ceil(q * double(v.size())) - 1.0)));
    return v[i];
}

double norm3(const std::array<double, 3>& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }

Analysis analyse(const std::string& name, const Recording& r) {
    Analysis a;
    a.name = name;
    a.r = &r;
    const RecordedSteps& s = r.steps;
    a.steps = s.size();
    if (s.size() >= 2 && s.wall_ms.back() > s.wall_ms.front()) {
        a.real_time_factor = (s.time_ms.back() - s.time_ms.front()) / (s.wall_ms.back() - s.wall_ms.front());
        a.step_wall_ms = (s.wall_ms.back() - s.wall_ms.front()) / double(s.size() - 1);
    }

    // Periods from the recorded tick starts.
    for (const RecordedHand& h : r.hands) {
        if (!h.used || h.tick_time_ms.size() < 2) continue;
        std::vector<double> periods;
        periods.reserve(h.tick_time_ms.size());
        for (std::size_t k = 1; k < h.tick_time_ms.size(); ++k) periods.push_back(h.tick_time_ms[k] - h.tick_time_ms[k - 1]);
        a.recorded_periods = periods.size();
        a.over_1_5 = double(std::count_if(periods.begin(), periods.end(), [](double p) { return p > 1.5; }));
        a.p999_ms = percentile(periods, 0.999);
        break;
    }

    // New samples: rows where force_step changes (and is ≥ 0).
    std::vector<std::size_t> fresh;
    for (std::size_t k = 0; k < s.size(); ++k)
        if (s.force_step[k] >= 0 && (fresh.empty() || s.force_step[k] != s.force_step[fresh.back()])) fresh.push_back(k);
    a.published = fresh.size();

    // Latency in steps: per distinct tool sample, its first step j0 → first new sample from a step ≥ j0.
    {
        std::vector<int> steps;
        std::vector<double> ms;
        std::size_t f = 0;  // index into fresh
        for (std::size_t j = 0; j < s.size(); ++j) {
            if (s.tool_time_ms[j] < 0) continue;
            if (j > 0 && s.tool_time_ms[j] == s.tool_time_ms[j - 1]) continue;  // not the first step using it
            while (f < fresh.size() && (fresh[f] < j || s.force_step[fresh[f]] < (long long)j)) ++f;
            if (f == fresh.size()) break;
            steps.push_back(int(fresh[f] - j + 1));
            ms.push_back(s.wall_ms[fresh[f]] - s.tool_time_ms[j]);
        }
        a.latency_samples = steps.size();
        if (!steps.empty()) {
            a.lat_steps_p50 = percentile(steps, 0.50);
            a.lat_steps_p99 = percentile(steps, 0.99);
            a.lat_steps_max = *std::max_element(steps.begin(), steps.end());
            a.publish_latency_p50_ms = percentile(ms, 0.50);
            a.publish_latency_p99_ms = percentile(ms, 0.99);
        }
    }

    // Force error against the interpolated published forces.
    if (fresh.size() >= 2) {
        const double t_first = s.wall_ms[fresh.front()], t_last = s.wall_ms[fresh.back()];
        for (int i = 0; i < 2; ++i) {
            const RecordedHand& h = r.hands[i];
            if (!h.used) continue;
            ForceError& e = a.hand[i];
            e.ticks_total = h.tick_time_ms.size();
            // Roughness of the published force: |second differences| / |first differences| (RMS,
            // per sample, ignoring the time between samples): ≪ 1 for a signal smooth at the
            // sample rate, ≈ √2 … 2 for one that changes direction from sample to sample.
            for (std::size_t m = 2; m < fresh.size(); ++m)
                for (int c = 0; c < 3; ++c) {
                    const double f0 = s.force_n[fresh[m - 2]][i][c], f1 = s.force_n[fresh[m - 1]][i][c], f2 = s.force_n[fresh[m]][i][c];
                    e.d1_sq += (f2 - f1) * (f2 - f1);
                    e.d2_sq += (f2 - 2 * f1 + f0) * (f2 - 2 * f1 + f0);
                }
            std::size_t f = 0;
            for (std::size_t k = 0; k < h.tick_time_ms.size(); ++k) {
                const double t = h.tick_time_ms[k];
                if (t < t_first || t > t_last || h.gain[k] != 1.0f) continue;
                while (f + 2 < fresh.size() && s.wall_ms[fresh[f + 1]] <= t) ++f;
                const std::size_t k0 = fresh[f], k1 = fresh[f + 1];
                const double t0 = s.wall_ms[k0], t1 = s.wall_ms[k1];
                const double w = t1 > t0 ? std::clamp((t - t0) / (t1 - t0), 0.0, 1.0) : 1.0;
                std::array<double, 3> ref{}, d{};
                for (int c = 0; c < 3; ++c) {
                    ref[c] = (1.0 - w) * s.force_n[k0][i][c] + w * s.force_n[k1][i][c];
                    d[c] = h.input_n[k][c] - ref[c];
                }
                e.add(norm3(d), norm3(ref));
            }
            a.all.merge(e);
        }
    } else {
        for (int i = 0; i < 2; ++i)
            if (r.hands[i].used) a.hand[i].ticks_total = r.hands[i].tick_time_ms.size(), a.all.ticks_total += a.hand[i].ticks_total;
    }
    return a;
}

struct Options {
    bool csv = false, per_hand = false, header = true;
    bool timing = true, force = true;
};

std::string fmt(const char* f, double v) {
    if (!std::isfinite(v)) return "—";
    char b[64];
    std::snprintf(b, sizeof b, f, v);
    return b;
}

void print_header(const Options& o) {
    const char* p = o.csv ? "# " : "";
    std::printf("%shaptics_bench: one row per recording (heartsim run --device … --record).\n", p);
    if (o.timing) {
        std::printf("%speriod p50/p99/max/mean ms, periods, overruns: the recording's attributes (device thread, tick start to tick start);\n", p);
        std::printf("%s  >1.5ms and p99.9: from the recorded tick times. latency p50/p99/max ms: attributes, pose read → first tick with a force\n", p);
        std::printf("%s  computed from it. lat steps p50/p99/max: steps from the first step using a tool sample to the first published forces\n", p);
        std::printf("%s  from a step at or after it, inclusive (1 = the same step). pub ms p50/p99: pose read → those forces published.\n", p);
        std::printf("%s  RTF: simulated / wall time of the steps; step wall ms: their mean wall time per step.\n", p);
    }
    if (o.force) {
        std::printf("%sforce error: per device tick, |input_n (force before safety, device = world frame for scripted/simulated devices)\n", p);
        std::printf("%s  − reference|, reference = the published simulation forces (/steps/force_n at /steps/wall_ms, rows where force_step\n", p);
        std::printf("%s  changes) linearly interpolated at the tick time (non-causal: an ideal zero-delay renderer); only ticks inside the\n", p);
        std::printf("%s  published range with safety gain 1. rms / max N over those ticks; ref rms = RMS |reference|; rel = error / ref rms.\n", p);
        std::printf("%s  ref roughness: RMS |second difference| / RMS |first difference| of the published samples (≪ 1: smooth at the\n", p);
        std::printf("%s  sample rate, where extrapolation helps; ≳ 1.4: it changes direction from sample to sample, where it amplifies).\n", p);
    }
    if (!o.csv) std::printf("\n");
}

std::vector<std::string> columns(const Options& o) {
    std::vector<std::string> c = {"recording", "hand", "backend", "contact", "interpolation", "particles", "dt ms", "steps", "RTF",
                                  "step wall ms"};
    if (o.timing)
        for (const char* x : {"periods", "period p50 ms", "period p99 ms", "period p99.9 ms", "period max ms", "period mean ms", "periods >1.5 ms",
                              "overruns", "latency p50 ms", "latency p99 ms", "latency max ms", "lat steps p50", "lat steps p99", "lat steps max",
                              "pub ms p50", "pub ms p99"})
            c.push_back(x);
    if (o.force)
        for (const char* x : {"ticks compared", "err rms N", "err max N", "ref rms N", "err rms rel", "err max rel", "ref roughness"})
            c.push_back(x);
    return c;
}

void print_row(const Options& o, const Analysis& a, const std::string& hand, const ForceError& e) {
    const Recording& r = *a.r;
    std::vector<std::string> v = {a.name, hand, r.backend, r.contact, r.interpolation, std::to_string(r.particles), fmt("%.4g", r.dt_ms),
                                  std::to_string(a.steps), fmt("%.3g", a.real_time_factor), fmt("%.3g", a.step_wall_ms)};
    if (o.timing) {
        v.push_back(std::to_string(r.periods));
        v.push_back(fmt("%.3f", r.period_p50_ms));
        v.push_back(fmt("%.3f", r.period_p99_ms));
        v.push_back(fmt("%.3f", a.p999_ms));
        v.push_back(fmt("%.3f", r.period_max_ms));
        v.push_back(fmt("%.4f", r.period_mean_ms));
        v.push_back(fmt("%.0f", a.over_1_5));
        v.push_back(std::to_string(r.overruns));
        v.push_back(fmt("%.3f", r.latency_p50_ms));
        v.push_back(fmt("%.3f", r.latency_p99_ms));
        v.push_back(fmt("%.3f", r.latency_max_ms));
        v.push_back(a.latency_samples ? std::to_string(a.lat_steps_p50) : "—");
        v.push_back(a.latency_samples ? std::to_string(a.lat_steps_p99) : "—");
        v.push_back(a.latency_samples ? std::to_string(a.lat_steps_max) : "—");
        v.push_back(fmt("%.3f", a.publish_latency_p50_ms));
        v.push_back(fmt("%.3f", a.publish_latency_p99_ms));
    }
    if (o.force) {
        v.push_back(std::to_string(e.ticks) + (o.csv ? "" : " / " + std::to_string(e.ticks_total)));
        v.push_back(fmt("%.3g", e.err_rms()));
        v.push_back(fmt("%.3g", e.ticks ? e.err_max : NAN));
        v.push_back(fmt("%.3g", e.ref_rms()));
        v.push_back(fmt("%.3g", e.ticks && e.ref_rms() > 0 ? e.err_rms() / e.ref_rms() : NAN));
        v.push_back(fmt("%.3g", e.ticks && e.ref_rms() > 0 ? e.err_max / e.ref_rms() : NAN));
        v.push_back(fmt("%.3g", e.roughness()));
    }
    if (o.csv) {
        for (std::size_t i = 0; i < v.size(); ++i) {
            std::string cell = v[i] == "—" ? "" : v[i];
            if (cell.find_first_of(",\"") != std::string::npos) {
                std::string q = "\"";
                for (char ch : cell) q += ch == '"' ? std::string("\"\"") : std::string(1, ch);
                cell = q + "\"";
            }
            std::printf("%s%s", i ? "," : "", cell.c_str());
        }
        std::printf("\n");
    } else {
        std::printf("|");
        for (const auto& x : v) std::printf(" %s |", x.c_str());
        std::printf("\n");
    }
}

int usage(FILE* out) {
    std::fprintf(out,
                 "usage: haptics_bench [--format markdown|csv] [--part timing|force|all] [--per-hand] [--no-header] REC.h5 [REC2.h5 ...]\n"
                 "  Analyses haptic session recordings (heartsim run ... --device ... --record REC.h5): one row per recording\n"
                 "  (named by the file's stem): device-thread period, pose -> force latency, and the rendered force's error against\n"
                 "  the published simulation forces interpolated at each tick. The definitions are printed as the header.\n"
                 "  --format     markdown (default) or csv\n"
                 "  --part       timing (period, latency), force (force error) or all (default)\n"
                 "  --per-hand   a row per used hand besides the row of both hands\n"
                 "  --no-header  the table only\n");
    return out == stderr ? 2 : 0;
}

}  // namespace

int main(int argc, char** argv) {
    Options o;
    std::vector<std::string> files;
    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        auto value = [&](const char* option) -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "haptics_bench: %s needs a value\n", option);
                std::exit(usage(stderr));
            }
            return argv[++i];
        };
        if (arg == "-h" || arg == "--help") return usage(stdout);
        if (arg == "--format") {
            const std::string f = value("--format");
            if (f != "csv" && f != "markdown") return std::fprintf(stderr, "haptics_bench: --format %s: expected markdown or csv\n", f.c_str()), 2;
            o.csv = f == "csv";
        } else if (arg == "--csv") {
            o.csv = true;
        } else if (arg == "--part") {
            const std::string p = value("--part");
            if (p != "timing" && p != "force" && p != "all")
                return std::fprintf(stderr, "haptics_bench: --part %s: expected timing, force or all\n", p.c_str()), 2;
            o.timing = p != "force";
            o.force = p != "timing";
        } else if (arg == "--per-hand") {
            o.per_hand = true;
        } else if (arg == "--no-header") {
            o.header = false;
        } else if (!arg.empty() && arg[0] == '-') {
            std::fprintf(stderr, "haptics_bench: unknown option %s\n", arg.c_str());
            return usage(stderr);
        } else {
            files.push_back(arg);
        }
    }
    if (files.empty()) return usage(stderr);

    std::vector<Recording> recordings;
    recordings.reserve(files.size());
    std::vector<Analysis> analyses;
    try {
        for (const auto& f : files) recordings.push_back(read_recording(f));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "haptics_bench: %s\n", e.what());
        return 1;
    }
    for (std::size_t i = 0; i < files.size(); ++i) analyses.push_back(analyse(std::filesystem::path(files[i]).stem().string(), recordings[i]));

    if (o.header) print_header(o);
    const auto cols = columns(o);
    if (o.csv) {
        for (std::size_t i = 0; i < cols.size(); ++i) std::printf("%s%s", i ? "," : "", cols[i].c_str());
        std::printf("\n");
    } else {
        std::printf("|");
        for (const auto& c : cols) std::printf(" %s |", c.c_str());
        std::printf("\n|");
        for (std::size_t i = 0; i < cols.size(); ++i) std::printf("---|");
        std::printf("\n");
    }
    for (const Analysis& a : analyses) {
        const Recording& r = *a.r;
        std::string hands;
        for (int i = 0; i < 2; ++i)
            if (r.hands[i].used) hands += (hands.empty() ? "" : "+") + std::to_string(i);
        print_row(o, a, hands.empty() ? "—" : hands, a.all);
        if (o.per_hand)
            for (int i = 0; i < 2; ++i)
                if (r.hands[i].used) print_row(o, a, std::to_string(i) + " (" + r.hands[i].instrument + ")", a.hand[i]);
    }
    return 0;
}
