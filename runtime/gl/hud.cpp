// The window's HUD through Dear ImGui (hud.h). ImGui stays in this file.
#include "runtime/gl/hud.h"

#include "runtime/view/window_keys.h"

#include <epoxy/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

namespace {

const ImU32 white = IM_COL32(255, 255, 255, 255), shadow = IM_COL32(0, 0, 0, 200);

/// `world` (mm) on the screen, pixels from the top left; nullopt behind the camera.
std::optional<ImVec2> project(const Camera& camera, const Eigen::Vector3d& world, int width, int height) {
    const Eigen::Vector4f clip = camera.projection(float(width) / float(std::max(height, 1))) * camera.view() *
                                 Eigen::Vector4f(float(world.x()), float(world.y()), float(world.z()), 1.0f);
    if (clip.w() <= 1e-6f) return std::nullopt;
    return ImVec2(0.5f * (clip.x() / clip.w() + 1.0f) * float(width), 0.5f * (1.0f - clip.y() / clip.w()) * float(height));
}

/// A line with an arrow head at `to`.
void arrow(ImDrawList* draw, ImVec2 from, ImVec2 to, ImU32 colour, float thickness) {
    const float dx = to.x - from.x, dy = to.y - from.y, length = std::sqrt(dx * dx + dy * dy);
    draw->AddLine(from, to, colour, thickness);
    if (length < 1.0f) return;
    const float ux = dx / length, uy = dy / length, head = std::min(12.0f, 0.4f * length);
    draw->AddTriangleFilled(to, ImVec2(to.x - head * ux - 0.5f * head * uy, to.y - head * uy + 0.5f * head * ux),
                            ImVec2(to.x - head * ux + 0.5f * head * uy, to.y - head * uy - 0.5f * head * ux), colour);
}

void outlined_text(ImDrawList* draw, ImVec2 at, ImU32 colour, const char* text, float size = 0) {
    if (size <= 0) size = ImGui::GetFontSize();
    draw->AddText(ImGui::GetFont(), size, ImVec2(at.x + 1, at.y + 1), shadow, text);
    draw->AddText(ImGui::GetFont(), size, at, colour, text);
}

/// The world axes (LPS: +x the patient's left, +y posterior, +z superior) as the camera sees them,
/// at `centre`; the negative ends (R, A, I) faint.
void orientation_axes(ImDrawList* draw, const Camera& camera, ImVec2 centre, float length) {
    const Eigen::Matrix3f world_to_camera = camera.orientation.conjugate().toRotationMatrix();
    const char* positive[3] = {"L", "P", "S"};
    const char* negative[3] = {"R", "A", "I"};
    const ImU32 colours[3] = {IM_COL32(230, 80, 80, 255), IM_COL32(80, 200, 80, 255), IM_COL32(90, 140, 255, 255)};
    for (int axis = 0; axis < 3; ++axis) {
        const Eigen::Vector3f d = world_to_camera.col(axis);
        const ImVec2 tip(centre.x + length * d.x(), centre.y - length * d.y());
        const ImVec2 tail(centre.x - 0.6f * length * d.x(), centre.y + 0.6f * length * d.y());
        draw->AddLine(centre, tail, (colours[axis] & 0x00FFFFFF) | 0x70000000, 1.5f);
        arrow(draw, centre, tip, colours[axis], 2.5f);
        outlined_text(draw, ImVec2(tip.x + 3.0f * d.x() - 4, tip.y - 3.0f * d.y() - 7), colours[axis], positive[axis]);
        outlined_text(draw, ImVec2(tail.x - 4, tail.y - 7), (colours[axis] & 0x00FFFFFF) | 0xA0000000, negative[axis]);
    }
    outlined_text(draw, ImVec2(centre.x - length, centre.y + length + 4), white, "LPS: patient's Left, Posterior, Superior");
}

/// The key help, centred: the keys that work in `session`, each with its action and details, or
/// its action only where the details would make the table taller than the window. Its layout.
HudHelpLayout help_window(int width, int height, const WindowKeySession& session) {
    std::vector<const WindowKey*> keys;
    for (const WindowKey& k : window_keys())
        if (key_works(k, session)) keys.push_back(&k);
    const ImGuiStyle& style = ImGui::GetStyle();
    const float window_width = std::min(0.96f * float(width), 1200.0f);
    float input_width = 0;
    for (const WindowKey* k : keys) input_width = std::max(input_width, ImGui::CalcTextSize(k->input).x);
    // The table's height with the details: each row as tall as its wrapped text, and the window's
    // title bar and padding around it.
    const float text_width = window_width - input_width - 2 * style.WindowPadding.x - 4 * style.CellPadding.x - 8;
    float table_height = 0;
    for (const WindowKey* k : keys) {
        const std::string text = std::string(k->action) + ": " + k->description;
        table_height += ImGui::CalcTextSize(text.c_str(), nullptr, false, text_width).y + 2 * style.CellPadding.y;
    }
    const float chrome = ImGui::GetFrameHeight() + 2 * style.WindowPadding.y + 2 * style.ItemSpacing.y;
    HudHelpLayout layout;
    layout.shown = true;
    layout.rows = keys.size();
    layout.details = table_height + chrome <= 0.98f * float(height);

    ImGui::SetNextWindowPos(ImVec2(0.5f * float(width), 0.5f * float(height)), ImGuiCond_Always, ImVec2(0.5f, 0.5f));
    ImGui::SetNextWindowSize(ImVec2(window_width, 0.0f), ImGuiCond_Always);  // height: fitted
    ImGui::SetNextWindowBgAlpha(0.88f);
    ImGui::Begin(layout.details ? "Keys and mouse (H or F1 hides this)" : "Keys and mouse (H or F1 hides this; heartsim run --help has the details)",
                 nullptr,
                 ImGuiWindowFlags_NoInputs | ImGuiWindowFlags_NoCollapse | ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoResize |
                     ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
    if (ImGui::BeginTable("keys", 2, ImGuiTableFlags_RowBg | ImGuiTableFlags_BordersInnerV | ImGuiTableFlags_SizingFixedFit)) {
        ImGui::TableSetupColumn("input", ImGuiTableColumnFlags_WidthFixed);
        ImGui::TableSetupColumn("action", ImGuiTableColumnFlags_WidthStretch);
        for (const WindowKey* k : keys) {
            ImGui::TableNextRow();
            ImGui::TableNextColumn();
            ImGui::TextColored(ImVec4(1.0f, 0.85f, 0.3f, 1.0f), "%s", k->input);
            ImGui::TableNextColumn();
            if (layout.details) ImGui::TextWrapped("%s: %s", k->action, k->description);
            else ImGui::TextUnformatted(k->action);
        }
        ImGui::EndTable();
        layout.last_row_bottom = ImGui::GetItemRectMax().y;
    }
    layout.top = ImGui::GetWindowPos().y;
    layout.bottom = layout.top + ImGui::GetWindowSize().y;
    ImGui::End();
    return layout;
}

}  // namespace

Hud::Hud(void* glfw_window) {
    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGuiIO& io = ImGui::GetIO();
    io.IniFilename = nullptr;  // no imgui.ini beside the scenario
    io.LogFilename = nullptr;
    ImGui::StyleColorsDark();
    ImGui_ImplGlfw_InitForOpenGL(static_cast<GLFWwindow*>(glfw_window), false);  // the window's callbacks stay
    ImGui_ImplOpenGL3_Init("#version 330 core");
}

Hud::~Hud() {
    ImGui_ImplOpenGL3_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
}

double scale_bar_mm(double mm_per_pixel, double target_pixels) {
    double best = 1.0, best_error = 1e300;
    for (double decade = 1e-3; decade <= 1e4; decade *= 10.0)
        for (const double m : {1.0, 2.0, 5.0}) {
            const double error = std::abs(std::log(m * decade / mm_per_pixel / target_pixels));
            if (error < best_error) best = m * decade, best_error = error;
        }
    return best;
}

void Hud::draw(const HudState& s, const Camera& camera, int width, int height) {
    const bool appearing = (s.show_hud && !hud_shown_) || (s.show_help && !help_shown_);
    hud_shown_ = s.show_hud, help_shown_ = s.show_help;
    if (!s.show_help) help_layout_ = {};
    if (!s.show_hud && !s.show_help && !s.emergency_stop) return;
    // ImGui sizes a window from what the frame before put in it (it shows a new window from its
    // second frame), and a table fits its columns in its first frame: the frame drawn now (a
    // screenshot maybe) is laid out unseen first, twice when a window appears, so that it shows
    // every line the state has (I's figures, a REC line) in a window that fits them. ImGui's
    // layout costs a fraction of a millisecond; the drawing is done once.
    for (int k = 0; k < (appearing ? 2 : 1); ++k) frame(s, camera, width, height, false);
    frame(s, camera, width, height, true);
}

void Hud::frame(const HudState& s, const Camera& camera, int width, int height, bool render) {
    ImGui_ImplOpenGL3_NewFrame();
    ImGui_ImplGlfw_NewFrame();
    ImGuiIO& io = ImGui::GetIO();
    io.DisplaySize = ImVec2(float(width), float(height));  // framebuffer pixels: the projection's too
    io.DisplayFramebufferScale = ImVec2(1.0f, 1.0f);
    ImGui::NewFrame();
    ImDrawList* draw = ImGui::GetForegroundDrawList();
    const float w = float(width), h = float(height);

    if (s.show_hud) {
        ImGui::SetNextWindowPos(ImVec2(8, 8));
        ImGui::SetNextWindowBgAlpha(0.6f);
        ImGui::Begin("session", nullptr,
                     ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoInputs | ImGuiWindowFlags_AlwaysAutoResize |
                         ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
        // What a trainer needs first: the case, its defect, the procedure; the figures on I.
        ImGui::TextColored(ImVec4(1.0f, 1.0f, 1.0f, 1), "%s", s.case_name.c_str());
        if (!s.defect.empty()) ImGui::TextColored(ImVec4(0.55f, 0.8f, 1.0f, 1), "%s", s.defect.c_str());
        if (!s.procedure.empty()) ImGui::Text("%s", s.procedure.c_str());
        if (s.paused) ImGui::TextColored(ImVec4(1.0f, 0.85f, 0.3f, 1), "PAUSED (Space resumes, N steps)");
        else if (!s.show_figures && s.real_time_factor < 0.9)
            ImGui::TextColored(ImVec4(1.0f, 0.7f, 0.3f, 1), "slower than real time: %.2fx (I: figures)", s.real_time_factor);
        if (s.recording) ImGui::TextColored(ImVec4(1.0f, 0.25f, 0.25f, 1), "REC (F5 stops and writes it)");
        if (s.section) {
            // Where the plane is: its depth past the heart's centre and the side it removes (float
            // noise below the last digit shown as 0, not "-0.0").
            auto shown = [](double v, double digit) { return std::abs(v) < 0.5 * digit ? 0.0 : v; };
            const Eigen::Vector3d& n = s.section_normal;
            ImGui::TextColored(ImVec4(1.0f, 0.6f, 0.5f, 1), "SECTION %.1f mm beyond the centre", shown(s.section_depth_mm, 0.1));
            ImGui::Text("normal %.2f, %.2f, %.2f (LPS)", shown(n.x(), 0.01), shown(n.y(), 0.01), shown(n.z(), 0.01));
            ImGui::TextDisabled("[ ] move (Shift: 5 mm), V aim, C off");
        }
        if (s.repair.laid) {
            const HudRepair& r = s.repair;
            ImGui::Text("patch: %s, %zu stitch%s", r.material.c_str(), r.stitches, r.stitches == 1 ? "" : "es");
            if (r.defect && !r.checked) ImGui::TextDisabled("defect closed: checking");
            else if (r.defect && !r.known) ImGui::TextDisabled("defect closed: cannot tell");
            else if (r.defect)
                ImGui::TextColored(r.closed ? ImVec4(0.45f, 0.9f, 0.45f, 1) : ImVec4(1.0f, 0.7f, 0.3f, 1), "defect closed: %s, rim gap %.2f mm",
                                   r.closed ? "yes" : "no", r.rim_gap_mm);
            if (r.defect && r.known && !r.leak.empty()) ImGui::TextColored(ImVec4(1.0f, 0.7f, 0.3f, 1), "leaks %s", r.leak.c_str());
        }
        for (int hand = 0; hand < 2; ++hand) {
            const HudHand& hh = s.hands[hand];
            if (!hh.used) continue;
            ImGui::Separator();
            ImGui::Text("hand %d: %s, %s%s", hand, hh.device.c_str(), hh.instrument.c_str(), hh.grabbing ? ", GRAB" : "");
            if (hh.has_force) ImGui::TextDisabled("force %s", hh.force_source.c_str());
            if (!hh.has_force) {
                ImGui::TextDisabled("force not known here");
                continue;
            }
            const double f = hh.force_n.norm();
            char overlay[64];
            if (hh.max_force_n > 0) {
                std::snprintf(overlay, sizeof overlay, "%.2f / %.2f N", f, hh.max_force_n);
                const float fraction = float(std::min(1.0, f / hh.max_force_n));
                ImGui::PushStyleColor(ImGuiCol_PlotHistogram, fraction > 0.9f ? ImVec4(0.9f, 0.2f, 0.2f, 1) : ImVec4(0.3f, 0.7f, 0.3f, 1));
                ImGui::ProgressBar(fraction, ImVec2(220, 0), overlay);
                ImGui::PopStyleColor();
            } else {
                ImGui::Text("force %.3f N", f);
            }
        }
        if (s.show_figures) {
            ImGui::Separator();
            ImGui::Text("%.2fx real time", s.real_time_factor);
            ImGui::Text("%.1f fps, %.0f steps/s, %.1f ms simulated", s.frames_per_s, s.steps_per_s, s.simulated_ms);
            ImGui::Text("%zu particles, %s backend", s.particles, s.backend.c_str());
            if (s.mass_scale != 1.0)
                ImGui::Text("mass scale %g: transients %.2gx slower, forces at rest unchanged", s.mass_scale, std::sqrt(s.mass_scale));
            if (s.haptic_period_p99_ms >= 0) ImGui::Text("haptic period p99 %.3f ms", s.haptic_period_p99_ms);
        }
        ImGui::TextDisabled("H: help   I: figures   F2: HUD off");
        ImGui::End();

        // Orientation axes (bottom left) and the scale bar at the orbit centre's depth (bottom right).
        const float axes = std::min(40.0f, 0.08f * std::min(w, h));
        orientation_axes(draw, camera, ImVec2(axes + 16, h - axes - 34), axes);
        const double mm_per_pixel = camera.mm_per_pixel(height);
        const double bar_mm = scale_bar_mm(mm_per_pixel, 0.15 * w);
        const float bar = float(bar_mm / mm_per_pixel);
        const ImVec2 right(w - 16, h - 24), left(w - 16 - bar, h - 24);
        draw->AddRectFilled(ImVec2(left.x, left.y - 3), ImVec2(right.x, right.y + 3), white);
        draw->AddRect(ImVec2(left.x, left.y - 3), ImVec2(right.x, right.y + 3), shadow);
        char label[64];
        std::snprintf(label, sizeof label, "%g mm (orbit centre)", bar_mm);
        const ImVec2 size = ImGui::CalcTextSize(label);
        outlined_text(draw, ImVec2(right.x - size.x, left.y - 20), white, label);

        // Force arrows: from each instrument, length ∝ N with the scale in the legend: the
        // largest force so far is about a third of the model radius long (a 1-2-5 scale, so
        // it changes seldom; tissue forces are often a few percent of the device's maximum).
        for (const HudHand& hh : s.hands)
            if (hh.used && hh.has_force) largest_force_n_ = std::max(largest_force_n_, hh.force_n.norm());
        const double mm_per_n = largest_force_n_ > 0 ? scale_bar_mm(1.0, camera.radius / 3.0 / largest_force_n_) : 1.0;
        bool any_arrow = false;
        for (const HudHand& hh : s.hands) {
            if (!hh.used || !hh.has_force || hh.force_n.norm() < 1e-4) continue;
            const auto from = project(camera, hh.position_mm, width, height);
            const auto to = project(camera, hh.position_mm + mm_per_n * hh.force_n, width, height);
            if (!from || !to) continue;
            arrow(draw, *from, *to, shadow, 6.0f);
            arrow(draw, *from, *to, IM_COL32(255, 220, 40, 255), 3.0f);
            any_arrow = true;
        }
        if (any_arrow) {
            std::snprintf(label, sizeof label, "force arrows: 1 N = %.3g mm", mm_per_n);
            outlined_text(draw, ImVec2(w - 16 - ImGui::CalcTextSize(label).x, h - 64), IM_COL32(255, 220, 40, 255), label);
        }
    }

    if (s.emergency_stop) {  // shown even with the HUD off: it must never be missed
        const char* text = "EMERGENCY STOP: device forces are zero (E releases)";
        const float size = std::max(20.0f, std::min(40.0f, w / 28.0f));
        const ImVec2 extent = ImGui::GetFont()->CalcTextSizeA(size, 1e9f, 0.0f, text);
        const float top = 0.5f * h - extent.y - 24;
        draw->AddRectFilled(ImVec2(0, top), ImVec2(w, top + extent.y + 24), IM_COL32(200, 0, 0, 235));
        draw->AddText(ImGui::GetFont(), size, ImVec2(std::max(4.0f, 0.5f * (w - extent.x)), top + 12), white, text);
    }
    help_layout_ = s.show_help ? help_window(width, height, s.keys) : HudHelpLayout{};

    ImGui::Render();
    if (!render) return;
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    glViewport(0, 0, width, height);
    ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

}  // namespace heartsim
