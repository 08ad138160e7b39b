/// @file gl_context.h
/// @brief An OpenGL 4.3+ core context for the runtime: headless (EGL with no X and no display: a
/// GPU's EGL device, as NVIDIA's driver offers, else Mesa's surfaceless platform) or a GLFW window. Both give the same
/// GL: compute shaders on shader storage buffers, timer queries, persistent mapped buffers.
///
///     GlContext gl = GlContext::create_headless();   // throws GlUnavailable with the reason
///     GlInfo info = gl.info();                       // renderer, version, limits
#pragma once

#include <memory>
#include <stdexcept>
#include <string>

namespace heartsim {

/// No usable OpenGL: no EGL display, no 4.3 core context, no compute shaders. The message says
/// what the machine offers and suggests `--backend cpu`.
class GlUnavailable : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// What `heartsim info` prints.
struct GlInfo;
/// Whether the device is a software rasteriser (Mesa's llvmpipe, softpipe, swrast): its compute
/// shaders run on the CPU cores, slower than the cpu backend.
bool is_software_rasteriser(const GlInfo& info);

struct GlInfo {
    std::string vendor, renderer, version, shading_language;
    std::string platform;                   ///< "EGL device 0 of 1", "EGL surfaceless" or "GLFW window"
    int major = 0, minor = 0;
    long long max_ssbo_bytes = 0;           ///< GL_MAX_SHADER_STORAGE_BLOCK_SIZE
    int max_ssbo_bindings = 0;              ///< GL_MAX_SHADER_STORAGE_BUFFER_BINDINGS
    int max_work_group_count[3] = {0, 0, 0};
    int max_work_group_size[3] = {0, 0, 0};
    int max_work_group_invocations = 0;
    int max_shared_memory_bytes = 0;        ///< GL_MAX_COMPUTE_SHARED_MEMORY_SIZE
    int max_texture_size = 0;               ///< texels per side
    int timer_query_bits = 0;               ///< GL_QUERY_COUNTER_BITS of GL_TIMESTAMP (0 = no timer)
    bool persistent_mapping = false;        ///< GL 4.4 or ARB_buffer_storage
};

/// Owns a GL context and keeps it current on the creating thread. Move-only.
class GlContext {
public:
    /// Headless: a 4.6, 4.5 (else 4.3) core context with no surface on the first EGL display of:
    /// a hardware EGL device (EGL_EXT_platform_device), Mesa's surfaceless platform, any EGL device
    /// (Mesa's software one). HEARTSIM_EGL=device or surfaceless tries that platform alone.
    /// Throws GlUnavailable naming what failed.
    static GlContext create_headless();
    /// A window of `width`×`height` pixels through GLFW (needs a display). Throws GlUnavailable.
    static GlContext create_window(int width, int height, const std::string& title);

    GlContext(GlContext&&) noexcept;
    GlContext& operator=(GlContext&&) noexcept;
    ~GlContext();

    /// Makes the context current on the calling thread.
    void make_current();
    GlInfo info() const;
    /// The GLFW window (GLFWwindow*) in window mode, null when headless.
    void* window() const;

private:
    struct State;
    explicit GlContext(std::unique_ptr<State> state);
    std::unique_ptr<State> state_;
};

/// Throws GlUnavailable unless the current context is OpenGL 4.3+ core with compute shaders:
/// "OpenGL 4.3 with compute shaders is needed; this machine offers <version, renderer>; run
/// with --backend cpu".
void require_compute(const GlInfo& info);

/// The lines `heartsim info` prints: renderer, version and the limits above.
std::string describe(const GlInfo& info);

}  // namespace heartsim
