// Run time against error on real hearts (docs/benchmarks.md "Run time against error"), driven by
// tests/bench/run_accuracy_bench.sh. Three commands:
//   accuracy_bench gesture SCENARIO OUT.csv [--hands press|grab|both]
//       A scripted gesture placed from the scenario's detailed (visual) mesh, which is the same
//       at every particle count: a 3 mm probe pressing the most anterior vertex 6 mm posterior
//       over 100 ms, and/or a 3 mm grabber holding the most inferior vertex and pulling it 10 mm
//       inferior over 100 ms; both then hold still.
//   accuracy_bench table RUNS.csv OUT.csv OUT.md
//       RUNS.csv rows: case,label,particles,state,wall_s,simulated_s. Per case, the run with
//       the most particles is the reference; every run's /visual/positions (the deformed detailed
//       mesh written by heartsim --save-state) is compared vertex by vertex with it: mean and max
//       distance, mm. Writes the table as CSV and Markdown; tests/bench/plot_benchmarks.py
//       accuracy draws the CSV (matplotlib).
// Not a test: it asserts nothing.
#include "formats/scenario.h"
#include "formats/state.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace heartsim;

namespace {

int gesture(int argc, char** argv) {
    if (argc < 4) throw std::runtime_error("usage: accuracy_bench gesture SCENARIO OUT.csv [--hands press|grab|both]");
    std::string hands = "both";
    for (int i = 4; i + 1 < argc; ++i)
        if (std::string(argv[i]) == "--hands") hands = argv[i + 1];
    if (hands != "press" && hands != "grab" && hands != "both") throw std::runtime_error("--hands must be press, grab or both");
    const Scenario scenario = read_scenario(argv[2]);
    if (!scenario.visual || scenario.visual->positions.empty()) throw std::runtime_error(std::string(argv[2]) + ": no /visual mesh");
    const auto& visual = scenario.visual->positions;
    std::size_t anterior = 0, inferior = 0;
    for (std::size_t v = 0; v < visual.size(); ++v) {
        if (visual[v][1] < visual[anterior][1]) anterior = v;
        if (visual[v][2] < visual[inferior][2]) inferior = v;
    }
    const auto& a = visual[anterior];
    const auto& b = visual[inferior];
    std::ofstream out(argv[3]);
    out << "# accuracy_bench gesture from " << argv[2] << " (LPS mm, ms)\n"
        << "# hand 0: 3 mm probe from 5 mm in front of the most anterior visual vertex to 6 mm into the wall\n"
        << "# hand 1: 3 mm grabber at the most inferior visual vertex (2 mm inside), pulled 10 mm inferior\n"
        << "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n";
    if (hands != "grab")
        out << "0,0,probe," << a[0] << "," << a[1] - 8.0 << "," << a[2] << ",1,0,0,0,3,3,3,0\n"
            << "100,0,probe," << a[0] << "," << a[1] + 3.0 << "," << a[2] << ",1,0,0,0,3,3,3,0\n";
    if (hands != "press")
        out << "0,1,grabber," << b[0] << "," << b[1] << "," << b[2] + 2.0 << ",1,0,0,0,3,3,3,1\n"
            << "100,1,grabber," << b[0] << "," << b[1] << "," << b[2] - 8.0 << ",1,0,0,0,3,3,3,1\n";
    if (!out) throw std::runtime_error(std::string("cannot write ") + argv[3]);
    return 0;
}

struct Run {
    std::string case_name, label, state;
    std::size_t particles = 0;
    double wall_s = 0, simulated_s = 0;
    double mean_mm = 0, max_mm = 0, moved_mm = 0;  // against the case's reference; moved: largest motion of the reference mesh
    bool reference = false;
};

std::vector<std::string> split(const std::string& line) {
    std::vector<std::string> fields;
    std::stringstream s(line);
    for (std::string f; std::getline(s, f, ',');) fields.push_back(f);
    return fields;
}

int table(int argc, char** argv) {
    if (argc < 5) throw std::runtime_error("usage: accuracy_bench table RUNS.csv OUT.csv OUT.md");
    std::ifstream in(argv[2]);
    if (!in) throw std::runtime_error(std::string("cannot read ") + argv[2]);
    std::vector<Run> runs;
    for (std::string line; std::getline(in, line);) {
        if (line.empty() || line[0] == '#' || line.rfind("case,", 0) == 0) continue;
        const auto f = split(line);
        if (f.size() != 6) throw std::runtime_error(std::string(argv[2]) + ": expected 6 fields in '" + line + "'");
        Run r;
        r.case_name = f[0], r.label = f[1], r.particles = std::stoul(f[2]), r.state = f[3];
        r.wall_s = std::stod(f[4]), r.simulated_s = std::stod(f[5]);
        runs.push_back(r);
    }
    std::map<std::string, std::size_t> reference;
    for (std::size_t i = 0; i < runs.size(); ++i) {
        auto [it, inserted] = reference.emplace(runs[i].case_name, i);
        if (!inserted && runs[i].particles > runs[it->second].particles) it->second = i;
    }
    std::map<std::string, std::vector<std::array<float, 3>>> reference_mesh, rest_mesh;
    for (const auto& [name, index] : reference) {
        runs[index].reference = true;
        reference_mesh[name] = read_state(runs[index].state).visual_positions;
    }
    for (Run& r : runs) {
        const auto mesh = read_state(r.state).visual_positions;
        const auto& ref = reference_mesh[r.case_name];
        if (mesh.size() != ref.size() || mesh.empty())
            throw std::runtime_error(r.state + ": " + std::to_string(mesh.size()) + " visual vertices, the reference has " +
                                     std::to_string(ref.size()));
        double sum = 0;
        for (std::size_t v = 0; v < mesh.size(); ++v) {
            const double d = std::sqrt(double((mesh[v][0] - ref[v][0]) * (mesh[v][0] - ref[v][0]) + (mesh[v][1] - ref[v][1]) * (mesh[v][1] - ref[v][1]) +
                                              (mesh[v][2] - ref[v][2]) * (mesh[v][2] - ref[v][2])));
            sum += d;
            r.max_mm = std::max(r.max_mm, d);
        }
        r.mean_mm = sum / double(mesh.size());
    }
    std::ofstream csv(argv[3]), md(argv[4]);
    csv << "case,label,particles,wall_s,simulated_s,wall_s_per_simulated_s,mean_error_mm,max_error_mm\n";
    md << "| case | build | particles | wall s per simulated s | mean error, mm | max error, mm |\n|---|---|---|---|---|---|\n";
    for (const Run& r : runs) {
        char line[512];
        std::snprintf(line, sizeof line, "%s,%s,%zu,%.3f,%.3f,%.3f,%.4f,%.4f\n", r.case_name.c_str(), r.label.c_str(), r.particles,
                      r.wall_s, r.simulated_s, r.wall_s / r.simulated_s, r.mean_mm, r.max_mm);
        csv << line;
        std::snprintf(line, sizeof line, "| %s | %s | %zu | %.2f | %s | %s |\n", r.case_name.c_str(), r.label.c_str(), r.particles,
                      r.wall_s / r.simulated_s, r.reference ? "(reference)" : (std::to_string(r.mean_mm).substr(0, 6)).c_str(),
                      r.reference ? "(reference)" : (std::to_string(r.max_mm).substr(0, 6)).c_str());
        md << line;
        std::fputs(line, stdout);
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const std::string command = argc > 1 ? argv[1] : "";
        if (command == "gesture") return gesture(argc, argv);
        if (command == "table") return table(argc, argv);
        std::fprintf(stderr, "usage: accuracy_bench gesture SCENARIO OUT.csv [--hands press|grab|both]\n"
                             "       accuracy_bench table RUNS.csv OUT.csv OUT.md\n");
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "accuracy_bench: %s\n", e.what());
        return 1;
    }
}
