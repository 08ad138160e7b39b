#include "runtime_test_support.h"

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

}  // namespace heartsim::test
