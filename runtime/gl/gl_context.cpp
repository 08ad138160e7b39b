// The GL context: headless EGL (a GPU's EGL device, else Mesa's surfaceless platform) or a GLFW window. docs/runtime.md.
#include "runtime/gl/gl_context.h"

#include <epoxy/egl.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <cstdlib>
#include <cstring>
#include <sstream>
#include <vector>

#ifndef EGL_PLATFORM_SURFACELESS_MESA
#define EGL_PLATFORM_SURFACELESS_MESA 0x31DD
#endif
#ifndef EGL_PLATFORM_DEVICE_EXT
#define EGL_PLATFORM_DEVICE_EXT 0x313F
#endif

namespace heartsim {

struct GlContext::State {
    EGLDisplay display = EGL_NO_DISPLAY;
    EGLContext context = EGL_NO_CONTEXT;
    GLFWwindow* window = nullptr;
    std::string platform;

    ~State() {
        if (context != EGL_NO_CONTEXT) {
            eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
            eglDestroyContext(display, context);
        }
        if (display != EGL_NO_DISPLAY) eglTerminate(display);
        if (window) {
            glfwDestroyWindow(window);
            glfwTerminate();
        }
    }
};

namespace {

std::string egl_error(const char* what) {
    std::ostringstream s;
    s << what << " failed (EGL error 0x" << std::hex << eglGetError() << ")";
    return s.str();
}

bool has_word(const char* list, const char* word) {
    if (!list) return false;
    const std::size_t n = std::strlen(word);
    for (const char* p = list; (p = std::strstr(p, word)); p += n)
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
    return false;
}

const char* gl_string(GLenum name) {
    const auto* s = reinterpret_cast<const char*>(glGetString(name));
    return s ? s : "";
}

}  // namespace

GlContext::GlContext(std::unique_ptr<State> state) : state_(std::move(state)) {}
GlContext::GlContext(GlContext&&) noexcept = default;
GlContext& GlContext::operator=(GlContext&&) noexcept = default;
GlContext::~GlContext() = default;

namespace {

// Which EGL platforms to try, in order. HEARTSIM_EGL=device|surfaceless picks one alone (a test,
// or a machine where the default order picks the wrong one).
struct HeadlessDisplay {
    EGLDisplay display = EGL_NO_DISPLAY;
    std::string platform;
};

// EGL_EXT_platform_device: one display per GPU, the way into NVIDIA's driver on a machine with no
// display server. `hardware` false also takes Mesa's software device (EGL_MESA_device_software).
HeadlessDisplay device_display(bool hardware, std::string& tried) {
    EGLint count = 0;
    if (!eglQueryDevicesEXT(0, nullptr, &count) || count <= 0) {
        tried += "; EGL device platform: no devices";
        return {};
    }
    std::vector<EGLDeviceEXT> devices(static_cast<std::size_t>(count));
    if (!eglQueryDevicesEXT(count, devices.data(), &count)) return {};
    for (EGLint i = 0; i < count; ++i) {
        const char* extensions = eglQueryDeviceStringEXT(devices[std::size_t(i)], EGL_EXTENSIONS);
        const bool software = has_word(extensions, "EGL_MESA_device_software");
        if (hardware && software) continue;
        EGLDisplay display = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[std::size_t(i)], nullptr);
        if (display == EGL_NO_DISPLAY) continue;
        EGLint major = 0, minor = 0;
        if (!eglInitialize(display, &major, &minor)) {
            tried += "; EGL device " + std::to_string(i) + ": " + egl_error("eglInitialize");
            continue;
        }
        return {display, "EGL device " + std::to_string(i) + " of " + std::to_string(count) + (software ? " (software)" : "")};
    }
    if (hardware) tried += "; EGL device platform: no hardware device among " + std::to_string(count);
    return {};
}

HeadlessDisplay surfaceless_display(std::string& tried) {
    EGLDisplay display = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (display == EGL_NO_DISPLAY) {
        tried += "; " + egl_error("eglGetPlatformDisplayEXT(surfaceless)");
        return {};
    }
    EGLint major = 0, minor = 0;
    if (!eglInitialize(display, &major, &minor)) {
        tried += "; surfaceless: " + egl_error("eglInitialize");
        return {};
    }
    return {display, "EGL surfaceless"};
}

// A GPU's own device first (NVIDIA headless, or Mesa on a machine with a DRM device), then Mesa's
// surfaceless platform (its hardware driver where there is one, else llvmpipe), then any device.
HeadlessDisplay open_headless_display() {
    const char* client_extensions = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    const std::string offered = client_extensions && *client_extensions
                                    ? client_extensions
                                    : "nothing (no GPU driver's EGL library: NVIDIA's libEGL_nvidia or Mesa's libEGL_mesa)";
    const bool platform_base = has_word(client_extensions, "EGL_EXT_platform_base");
    const bool device = platform_base && has_word(client_extensions, "EGL_EXT_platform_device") &&
                        (has_word(client_extensions, "EGL_EXT_device_enumeration") || has_word(client_extensions, "EGL_EXT_device_base"));
    const bool surfaceless = platform_base && has_word(client_extensions, "EGL_MESA_platform_surfaceless");
    const char* forced = std::getenv("HEARTSIM_EGL");
    const std::string only = forced ? forced : "";
    if (!only.empty() && only != "device" && only != "surfaceless")
        throw GlUnavailable("HEARTSIM_EGL=" + only + " is not an EGL platform heartsim knows: device or surfaceless (or unset: both, device first)");
    std::string tried;
    if (device && only != "surfaceless")
        if (auto d = device_display(true, tried); d.display != EGL_NO_DISPLAY) return d;
    if (surfaceless && only != "device")
        if (auto d = surfaceless_display(tried); d.display != EGL_NO_DISPLAY) return d;
    if (device && only != "surfaceless")
        if (auto d = device_display(false, tried); d.display != EGL_NO_DISPLAY) return d;
    if (!device && !surfaceless)
        throw GlUnavailable("headless OpenGL needs EGL with EGL_EXT_platform_device (a GPU driver, e.g. NVIDIA's) or "
                            "EGL_MESA_platform_surfaceless (Mesa's libegl-mesa0); this machine's EGL offers: " + offered +
                            "; run with --backend cpu");
    throw GlUnavailable("no headless EGL display" + (only.empty() ? std::string() : " (HEARTSIM_EGL=" + only + ")") + tried +
                        "; run with --backend cpu");
}

}  // namespace

GlContext GlContext::create_headless() {
    auto state = std::make_unique<State>();
    HeadlessDisplay opened = open_headless_display();
    state->display = opened.display;
    state->platform = opened.platform;
    if (!eglBindAPI(EGL_OPENGL_API)) throw GlUnavailable(egl_error("eglBindAPI(OpenGL)") + "; run with --backend cpu");
    const char* display_extensions = eglQueryString(state->display, EGL_EXTENSIONS);
    EGLConfig config = nullptr;  // EGL_NO_CONFIG_KHR where the driver allows it
    if (!has_word(display_extensions, "EGL_KHR_no_config_context")) {
        const EGLint attributes[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_NONE};
        EGLint count = 0;
        if (!eglChooseConfig(state->display, attributes, &config, 1, &count) || count < 1)
            throw GlUnavailable("EGL offers no OpenGL configuration; run with --backend cpu");
    }
    for (const auto& [want_major, want_minor] : {std::pair{4, 6}, {4, 5}, {4, 3}}) {
        const EGLint attributes[] = {EGL_CONTEXT_MAJOR_VERSION, want_major, EGL_CONTEXT_MINOR_VERSION, want_minor,
                                     EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
        state->context = eglCreateContext(state->display, config, EGL_NO_CONTEXT, attributes);
        if (state->context != EGL_NO_CONTEXT) break;
    }
    if (state->context == EGL_NO_CONTEXT) {
        // Report what the machine does offer: any context at all, for its version string.
        const EGLint any[] = {EGL_NONE};
        EGLContext fallback = eglCreateContext(state->display, config, EGL_NO_CONTEXT, any);
        std::string offered = "no OpenGL context at all";
        if (fallback != EGL_NO_CONTEXT && eglMakeCurrent(state->display, EGL_NO_SURFACE, EGL_NO_SURFACE, fallback)) {
            offered = std::string("OpenGL ") + gl_string(GL_VERSION) + " on " + gl_string(GL_RENDERER);
            eglMakeCurrent(state->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        }
        if (fallback != EGL_NO_CONTEXT) eglDestroyContext(state->display, fallback);
        throw GlUnavailable("OpenGL 4.3 with compute shaders is needed; this machine offers " + offered + "; run with --backend cpu");
    }
    if (!eglMakeCurrent(state->display, EGL_NO_SURFACE, EGL_NO_SURFACE, state->context))
        throw GlUnavailable(egl_error("eglMakeCurrent without a surface") + "; run with --backend cpu");
    GlContext context(std::move(state));
    require_compute(context.info());
    return context;
}

GlContext GlContext::create_window(int width, int height, const std::string& title) {
    if (!glfwInit()) {
        const char* description = nullptr;
        glfwGetError(&description);
        throw GlUnavailable(std::string("cannot open a window: ") + (description ? description : "GLFW failed to start") +
                            " (no display? run with --headless)");
    }
    auto state = std::make_unique<State>();
    state->platform = "GLFW window";
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    state->window = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
    if (!state->window) {
        const char* description = nullptr;
        glfwGetError(&description);
        glfwTerminate();
        throw GlUnavailable(std::string("OpenGL 4.3 with compute shaders is needed; the window system refused a 4.3 core context (") +
                            (description ? description : "unknown reason") + "); run with --backend cpu");
    }
    glfwMakeContextCurrent(state->window);
    GlContext context(std::move(state));
    require_compute(context.info());
    return context;
}

void GlContext::make_current() {
    if (state_->window) glfwMakeContextCurrent(state_->window);
    else eglMakeCurrent(state_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, state_->context);
}

void* GlContext::window() const { return state_->window; }

GlInfo GlContext::info() const {
    GlInfo info;
    info.platform = state_->platform;
    info.vendor = gl_string(GL_VENDOR);
    info.renderer = gl_string(GL_RENDERER);
    info.version = gl_string(GL_VERSION);
    info.shading_language = gl_string(GL_SHADING_LANGUAGE_VERSION);
    glGetIntegerv(GL_MAJOR_VERSION, &info.major);
    glGetIntegerv(GL_MINOR_VERSION, &info.minor);
    if (info.major > 4 || (info.major == 4 && info.minor >= 3)) {
        GLint64 ssbo = 0;
        glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &ssbo);
        info.max_ssbo_bytes = ssbo;
        glGetIntegerv(GL_MAX_SHADER_STORAGE_BUFFER_BINDINGS, &info.max_ssbo_bindings);
        for (GLuint a = 0; a < 3; ++a) {
            glGetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_COUNT, a, &info.max_work_group_count[a]);
            glGetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_SIZE, a, &info.max_work_group_size[a]);
        }
        glGetIntegerv(GL_MAX_COMPUTE_WORK_GROUP_INVOCATIONS, &info.max_work_group_invocations);
        glGetIntegerv(GL_MAX_COMPUTE_SHARED_MEMORY_SIZE, &info.max_shared_memory_bytes);
        glGetQueryiv(GL_TIMESTAMP, GL_QUERY_COUNTER_BITS, &info.timer_query_bits);
    }
    glGetIntegerv(GL_MAX_TEXTURE_SIZE, &info.max_texture_size);
    info.persistent_mapping = (info.major > 4 || (info.major == 4 && info.minor >= 4)) || epoxy_has_gl_extension("GL_ARB_buffer_storage");
    while (glGetError() != GL_NO_ERROR) {}
    return info;
}

void require_compute(const GlInfo& info) {
    if (info.major > 4 || (info.major == 4 && info.minor >= 3)) {
        if (!info.persistent_mapping)
            throw GlUnavailable("OpenGL 4.4 buffer storage (or ARB_buffer_storage) is needed for the force readback; this machine offers OpenGL " +
                                info.version + " on " + info.renderer + "; run with --backend cpu");
        return;
    }
    throw GlUnavailable("OpenGL 4.3 with compute shaders is needed; this machine offers OpenGL " +
                        (info.version.empty() ? std::string("(none)") : info.version) + " on " +
                        (info.renderer.empty() ? std::string("(unknown renderer)") : info.renderer) + "; run with --backend cpu");
}

std::string describe(const GlInfo& info) {
    std::ostringstream s;
    s << "platform        " << info.platform << "\n"
      << "vendor          " << info.vendor << "\n"
      << "renderer        " << info.renderer << "\n"
      << "version         " << info.version << " (core " << info.major << "." << info.minor << ")\n"
      << "GLSL            " << info.shading_language << "\n"
      << "max SSBO size   " << info.max_ssbo_bytes << " bytes (" << info.max_ssbo_bytes / (1024 * 1024) << " MiB)\n"
      << "SSBO bindings   " << info.max_ssbo_bindings << "\n"
      << "work groups     count " << info.max_work_group_count[0] << " x " << info.max_work_group_count[1] << " x "
      << info.max_work_group_count[2] << ", size " << info.max_work_group_size[0] << " x " << info.max_work_group_size[1] << " x "
      << info.max_work_group_size[2] << ", " << info.max_work_group_invocations << " invocations\n"
      << "shared memory   " << info.max_shared_memory_bytes << " bytes per work group\n"
      << "texture size    " << info.max_texture_size << " texels per side\n"
      << "timer queries   " << (info.timer_query_bits ? std::to_string(info.timer_query_bits) + " bits" : std::string("none")) << "\n"
      << "persistent map  " << (info.persistent_mapping ? "yes" : "no") << "\n";
    return s.str();
}

bool is_software_rasteriser(const GlInfo& info) {
    for (const char* name : {"llvmpipe", "softpipe", "swrast"})
        if (info.renderer.find(name) != std::string::npos) return true;
    return false;
}

}  // namespace heartsim
