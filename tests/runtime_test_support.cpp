#include "runtime_test_support.h"

#include "runtime/gl/renderer.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <optional>

namespace heartsim::test {

GlContext* shared_gl_context(std::string* reason) {
    static std::optional<GlContext> context;
    static std::string why;
    static bool tried = false;
    if (!tried) {
        tried = true;
        try {
            context.emplace(GlContext::create_headless());
            require_compute(context->info());
        } catch (const std::exception& e) {
            context.reset();
            why = e.what();
        }
    }
    if (reason) *reason = why;
    return context ? &*context : nullptr;
}

ImageDifference compare_images(const Image& a, const Image& b, int threshold, Image* diff) {
    ImageDifference d;
    const std::size_t pixels = std::size_t(a.width) * std::size_t(a.height);
    if (diff) *diff = Image{a.width, a.height, 3, std::vector<std::uint8_t>(pixels * 3, 0)};
    double sum = 0;
    std::size_t over = 0;
    for (std::size_t p = 0; p < pixels; ++p) {
        int largest = 0;
        for (int c = 0; c < 3; ++c) {
            const int delta = std::abs(int(a.pixels[p * 3 + std::size_t(c)]) - int(b.pixels[p * 3 + std::size_t(c)]));
            sum += delta;
            largest = std::max(largest, delta);
            if (diff) diff->pixels[p * 3 + std::size_t(c)] = std::uint8_t(std::min(255, 4 * delta));
        }
        if (largest > threshold) ++over;
    }
    d.mean_abs = sum / double(3 * pixels);
    d.fraction_over = double(over) / double(pixels);
    return d;
}

Image crop(const Image& image, int x0, int y0, int x1, int y1) {
    Image out{x1 - x0, y1 - y0, 3, {}};
    out.pixels.reserve(std::size_t(out.width) * std::size_t(out.height) * 3);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            for (int c = 0; c < 3; ++c) out.pixels.push_back(image.pixels[(std::size_t(y) * std::size_t(image.width) + std::size_t(x)) * 3 + std::size_t(c)]);
    return out;
}

std::optional<Image> golden_reference(const std::filesystem::path& golden, const Image& image, bool may_update) {
    if (may_update && std::getenv("HEARTSIM_UPDATE_GOLDEN")) {
        std::filesystem::create_directories(golden.parent_path());
        write_png(golden, image);
        std::printf("  updated the golden image %s\n", golden.c_str());
    }
    if (!std::filesystem::exists(golden)) return std::nullopt;
    return read_png(golden);
}

void write_golden_failure(const std::string& name, const Image& diff, const Image& image) {
    const std::filesystem::path out = std::filesystem::current_path() / (name + ".diff.png");
    const std::filesystem::path actual = std::filesystem::current_path() / (name + ".actual.png");
    write_png(out, diff);
    write_png(actual, image);
    std::printf("  wrote the difference image (4x amplified) %s and the screenshot %s\n", out.c_str(), actual.c_str());
}

bool cut_colour(const Image& image, int x, int y) {
    const std::size_t p = (std::size_t(y) * std::size_t(image.width) + std::size_t(x)) * std::size_t(image.channels);
    for (std::size_t c = 0; c < 3; ++c)
        if (std::abs(int(image.pixels[p + c]) - section_cut_rgb[c]) > 2) return false;
    return true;
}

std::size_t cut_pixels(const Image& image) {
    std::size_t n = 0;
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x) n += cut_colour(image, x, y);
    return n;
}

}  // namespace heartsim::test
