// Run time against error on real hearts (docs/benchmarks.md "Run time against error"), driven by
// tests/bench/run_accuracy_bench.sh. Three commands:
//   accuracy_bench gesture SCENARIO OUT.csv [--hands press|grab|both]
//       A scripted gesture placed from the scenario's detailed (visual) mesh, which is the same
//       at every particle count: a 3 mm probe pressing the most anterior vertex 6 mm posterior
//       over 100 ms, and/or a 3 mm grabber holding the most inferior vertex and pulling it 10 mm
//       inferior over 100 ms; both then hold still.
//   accuracy_bench table RUNS.csv OUT.csv OUT.md OUT.png
//       RUNS.csv rows: case,label,particles,state,wall_s,simulated_s. Per case, the run with
//       the most particles is the reference; every run's /visual/positions (the deformed detailed
//       mesh written by heartsim --save-state) is compared vertex by vertex with it: mean and max
//       distance, mm. Writes the table as CSV and Markdown, and a log-log plot of mean error
//       against wall time per simulated second (PNG, our own encoder).
// Not a test: it asserts nothing.
#include "formats/scenario.h"
#include "formats/state.h"
#include "runtime/png.h"

#include <algorithm>
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

// ---- a small log-log plot ------------------------------------------------------------------

/// 3×5 glyphs for the tick labels: bit 14 is the top-left pixel, rows of three.
int glyph(char c) {
    switch (c) {
    case '0': return 0b111101101101111;
    case '1': return 0b010110010010111;
    case '2': return 0b111001111100111;
    case '3': return 0b111001111001111;
    case '4': return 0b101101111001001;
    case '5': return 0b111100111001111;
    case '6': return 0b111100111101111;
    case '7': return 0b111001001001001;
    case '8': return 0b111101111101111;
    case '9': return 0b111101111001111;
    case '.': return 0b000000000000010;
    default: return 0;
    }
}

struct Canvas {
    Image image;
    Canvas(int w, int h) {
        image.width = w;
        image.height = h;
        image.channels = 3;
        image.pixels.assign(std::size_t(w) * std::size_t(h) * 3, 255);
    }
    void dot(int x, int y, std::array<std::uint8_t, 3> c) {
        if (x < 0 || y < 0 || x >= image.width || y >= image.height) return;
        std::uint8_t* p = &image.pixels[(std::size_t(y) * std::size_t(image.width) + std::size_t(x)) * 3];
        p[0] = c[0], p[1] = c[1], p[2] = c[2];
    }
    void line(double x0, double y0, double x1, double y1, std::array<std::uint8_t, 3> c, int width = 1) {
        const int steps = int(std::max(std::abs(x1 - x0), std::abs(y1 - y0))) + 1;
        for (int s = 0; s <= steps; ++s) {
            const double t = double(s) / steps;
            for (int dx = 0; dx < width; ++dx)
                for (int dy = 0; dy < width; ++dy) dot(int(std::lround(x0 + t * (x1 - x0))) + dx, int(std::lround(y0 + t * (y1 - y0))) + dy, c);
        }
    }
    void text(int x, int y, const std::string& s, int scale = 2) {
        for (char ch : s) {
            const int g = glyph(ch);
            for (int r = 0; r < 5; ++r)
                for (int col = 0; col < 3; ++col)
                    if (g & (1 << (14 - (r * 3 + col))))
                        for (int a = 0; a < scale; ++a)
                            for (int b = 0; b < scale; ++b) dot(x + col * scale + a, y + r * scale + b, {0, 0, 0});
            x += 4 * scale;
        }
    }
};

std::string decade(int e) {
    std::ostringstream s;
    s << std::pow(10.0, e);
    return s.str();
}

/// Mean error (mm, y) against wall time per simulated second (s, x), both log scale; one colour
/// per case, runs joined in particle order; the reference runs (error 0) are left out.
void plot(const std::vector<Run>& runs, const std::string& path) {
    const int w = 900, h = 600, left = 90, right = 30, top = 30, bottom = 70;
    double x_low = 1e30, x_high = -1e30, y_low = 1e30, y_high = -1e30;
    for (const Run& r : runs) {
        if (r.reference || r.mean_mm <= 0) continue;
        const double x = r.wall_s / r.simulated_s;
        x_low = std::min(x_low, x), x_high = std::max(x_high, x);
        y_low = std::min(y_low, r.mean_mm), y_high = std::max(y_high, r.mean_mm);
    }
    if (x_low > x_high) return;
    const int ex0 = int(std::floor(std::log10(x_low))), ex1 = int(std::ceil(std::log10(x_high)));
    const int ey0 = int(std::floor(std::log10(y_low))), ey1 = int(std::ceil(std::log10(y_high)));
    auto px = [&](double x) { return left + (std::log10(x) - ex0) / std::max(1, ex1 - ex0) * (w - left - right); };
    auto py = [&](double y) { return h - bottom - (std::log10(y) - ey0) / std::max(1, ey1 - ey0) * (h - top - bottom); };
    Canvas c(w, h);
    const std::array<std::uint8_t, 3> grey{200, 200, 200}, black{0, 0, 0};
    for (int e = ex0; e <= ex1; ++e) {
        c.line(px(std::pow(10.0, e)), top, px(std::pow(10.0, e)), h - bottom, grey);
        c.text(int(px(std::pow(10.0, e))) - 10, h - bottom + 12, decade(e));
    }
    for (int e = ey0; e <= ey1; ++e) {
        c.line(left, py(std::pow(10.0, e)), w - right, py(std::pow(10.0, e)), grey);
        c.text(8, int(py(std::pow(10.0, e))) - 5, decade(e));
    }
    c.line(left, h - bottom, w - right, h - bottom, black, 2);
    c.line(left, top, left, h - bottom, black, 2);
    const std::array<std::array<std::uint8_t, 3>, 6> colours{
        {{31, 119, 180}, {214, 39, 40}, {44, 160, 44}, {148, 103, 189}, {255, 127, 14}, {23, 190, 207}}};
    std::map<std::string, std::size_t> colour_of;
    for (const Run& r : runs) colour_of.emplace(r.case_name, colour_of.size());
    for (const auto& [name, index] : colour_of) {
        const auto colour = colours[index % colours.size()];
        std::vector<const Run*> series;
        for (const Run& r : runs)
            if (r.case_name == name && !r.reference && r.mean_mm > 0 && r.label == "defaults") series.push_back(&r);
        std::sort(series.begin(), series.end(), [](const Run* a, const Run* b) { return a->particles < b->particles; });
        for (std::size_t k = 0; k + 1 < series.size(); ++k)
            c.line(px(series[k]->wall_s / series[k]->simulated_s), py(series[k]->mean_mm), px(series[k + 1]->wall_s / series[k + 1]->simulated_s),
                   py(series[k + 1]->mean_mm), colour, 2);
        for (const Run& r : runs) {
            if (r.case_name != name || r.reference || r.mean_mm <= 0) continue;
            const double x = px(r.wall_s / r.simulated_s), y = py(r.mean_mm);
            const bool before = r.label != "defaults";  // the keep + tangent build: hollow
            for (int dx = -5; dx <= 5; ++dx)
                for (int dy = -5; dy <= 5; ++dy)
                    if (!before || std::abs(dx) == 5 || std::abs(dy) == 5) c.dot(int(x) + dx, int(y) + dy, colour);
        }
    }
    write_png(path, c.image);
}

int table(int argc, char** argv) {
    if (argc < 6) throw std::runtime_error("usage: accuracy_bench table RUNS.csv OUT.csv OUT.md OUT.png");
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
    plot(runs, argv[5]);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const std::string command = argc > 1 ? argv[1] : "";
        if (command == "gesture") return gesture(argc, argv);
        if (command == "table") return table(argc, argv);
        std::fprintf(stderr, "usage: accuracy_bench gesture SCENARIO OUT.csv [--hands press|grab|both]\n"
                             "       accuracy_bench table RUNS.csv OUT.csv OUT.md OUT.png\n");
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "accuracy_bench: %s\n", e.what());
        return 1;
    }
}
