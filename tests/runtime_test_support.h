/// @file runtime_test_support.h
/// @brief Shared by the tests that need OpenGL: one headless context per test program.
#pragma once

#include "runtime/gl/gl_context.h"

#include <gtest/gtest.h>

#include <string>

namespace heartsim::test {

/// One headless context for the whole test program (creating EGL displays repeatedly is slow
/// on llvmpipe), checked for OpenGL 4.3 compute; null with the reason when there is none.
GlContext* shared_gl_context(std::string* reason = nullptr);

}  // namespace heartsim::test

/// Skips the current test, saying why, when there is no usable headless OpenGL device.
#define REQUIRE_GL()                                                                                       \
    do {                                                                                                   \
        std::string reason_;                                                                               \
        if (!::heartsim::test::shared_gl_context(&reason_)) GTEST_SKIP() << "no headless OpenGL 4.3 device: " << reason_; \
    } while (0)
