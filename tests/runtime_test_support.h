/// @file runtime_test_support.h
/// @brief Shared by the tests that need OpenGL: one headless context per test program.
#pragma once

#include "runtime/gl/gl_context.h"
#include "runtime/view/png.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <optional>
#include <string>

namespace heartsim::test {

/// One headless context for the whole test program (creating EGL displays repeatedly is slow
/// on llvmpipe), checked for OpenGL 4.3 compute; null with the reason when there is none.
GlContext* shared_gl_context(std::string* reason = nullptr);

/// Two images compared for a golden-image test: the mean absolute difference (0–255, over all
/// channels) and the fraction of pixels whose largest channel difference exceeds a threshold.
struct ImageDifference {
    double mean_abs = 0, fraction_over = 0;
};
/// `a` and `b` of the same size, RGB; writes the difference (4× amplified) to `diff` if given.
ImageDifference compare_images(const Image& a, const Image& b, int threshold, Image* diff);

/// The rectangle [x0, x1)×[y0, y1) of an RGB image.
Image crop(const Image& image, int x0, int y0, int x1, int y1);

/// Whether pixel (x, y) of an RGB or RGBA `image` has the section view's flat cut colour
/// (section_cut_rgb, renderer.h) within 2 per channel: no lit surface takes it.
bool cut_colour(const Image& image, int x, int y);
/// The pixels of `image` in the cut colour.
std::size_t cut_pixels(const Image& image);

/// The golden image a test compares `image` with. With HEARTSIM_UPDATE_GOLDEN set and `may_update`,
/// `image` becomes the golden first (the folder made if needed, the path printed). Empty when
/// there is no golden file: the caller skips, saying so.
std::optional<Image> golden_reference(const std::filesystem::path& golden, const Image& image, bool may_update = true);

/// After a failed comparison: NAME.diff.png (the difference, 4× amplified) and NAME.actual.png in
/// the current folder, and a line saying where.
void write_golden_failure(const std::string& name, const Image& diff, const Image& image);

}  // namespace heartsim::test

/// Skips the current test, saying why, when there is no usable headless OpenGL device.
#define REQUIRE_GL()                                                                                       \
    do {                                                                                                   \
        std::string reason_;                                                                               \
        if (!::heartsim::test::shared_gl_context(&reason_)) GTEST_SKIP() << "no headless OpenGL 4.3 device: " << reason_; \
    } while (0)
