/// @file renderer.h
/// @brief The visualisation step (docs/runtime.md "Rendering"): the detailed visual mesh deformed in the
/// vertex shader from the particle positions and per-frame particle normals, by the mapping
/// formula of libmodel/mapping.h in the same float32 order, with no per-frame upload on the gl
/// backend. Without /visual (or /mapping) the simulation surface is drawn instead (flat shaded,
/// no normals pass). Instruments are drawn as their ellipsoids. Everything goes into an
/// offscreen framebuffer: read back for screenshots, blitted to the window in window mode.
///
///     Renderer renderer(scenario, {.width = 1024, .height = 768});   // current GL context
///     renderer.render(*backend, instruments);      // gl: positions read in place; cpu: uploaded
///     write_png("shot.png", renderer.read_pixels());
///
/// Passes per frame (each timed with GL_TIMESTAMP queries, harvested without waiting):
///   * normals (compute, visual mesh only): n_i = normalise(Σ area vectors of the counted
///     simulation-surface triangles containing i), one invocation per surface particle gathering
///     over an incidence list built at load, in triangle-row order: the same sum, in the same
///     order, as libmodel's particle_normals; no atomics, deterministic;
///   * visualisation: the mapped mesh (vertex shader: p = (λa·x_a + λb·x_b) + λc·x_c,
///     m = (λa·n_a + λb·n_b) + λc·n_c, p + d·(m/√(m·m)), written with `precise`), lit, then the
///     instruments.
///
/// With a section plane (set_section, section_plane.h) the tissue on the plane's removed side is
/// not drawn, and where the plane cuts through the closed surface the inside of the wall shows as
/// a flat band of section_cut_rgb; the instruments are drawn whole.
///
/// A septal defect's repair (set_patch, runtime/surgery/repair.h) is drawn with the tissue and cut by the
/// same plane: the patch as a closed sheet of its thickness in its material's colour (patch_rgb;
/// where the plane cuts it, its cut face flat in a darker shade), each stitch as a suture from
/// its patch vertex to its tissue point with a knot on the patch (suture_rgb). Once a patch is
/// laid, the patch instrument that laid it is not drawn: the patch is.
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/view/camera.h"
#include "runtime/backend/instrument_shape.h"
#include "runtime/view/png.h"
#include "runtime/view/section_plane.h"

#include "formats/scenario.h"
#include "libmodel/surgery/patch.h"

#include <Eigen/Geometry>

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// The current context's default framebuffer, its back buffer as drawn so far (before the swap),
/// RGB, rows top to bottom: the window as seen, HUD included (the P key).
Image read_window_pixels(int width, int height);

/// The flat colour of cut myocardium in the section view, 8-bit RGB: darker and more saturated than
/// the lit surface (whose green is at least 0.41 of its red), so no lit pixel takes it.
inline constexpr std::array<int, 3> section_cut_rgb = {138, 34, 26};

/// The flat colour of a wall heartprep grew where the labels showed only blood (docs/user-guide.md
/// "Walls"), cut in the section view, 8-bit RGB: an ochre beside the labelled myocardium's
/// section_cut_rgb, so a section shows which wall the image gave and which the build added.
inline constexpr std::array<int, 3> grown_wall_cut_rgb = {184, 112, 44};

/// The base colour of an incision's cut faces (the caps), 8-bit RGB, lit with their face normals:
/// a deeper, darker red than the epicardium's (0.80, 0.33, 0.30).
inline constexpr std::array<int, 3> incision_cap_rgb = {150, 40, 36};

/// A coronary artery's colour as seen through the epicardium, 8-bit RGB: a crimson whose green is
/// under 0.33 of its red (the lit epicardium's is at least 0.41) and whose blue is over 0.4 of it
/// (the cut myocardium's is under 0.25).
inline constexpr std::array<int, 3> coronary_artery_rgb = {168, 50, 76};

/// The epicardial fat along the coronary arteries, 8-bit RGB: yellow.
inline constexpr std::array<int, 3> epicardial_fat_rgb = {236, 204, 122};

/// A patch's colour by its material (PatchMaterial::name), 8-bit RGB: fixed bovine pericardium
/// ivory {232, 222, 190}, expanded PTFE white-grey {214, 218, 222}, woven dacron white
/// {242, 242, 236}; any other name gets pericardium's.
std::array<int, 3> patch_rgb(const std::string& material);

/// The stitches' colour, 8-bit RGB: the blue of polypropylene suture.
inline constexpr std::array<int, 3> suture_rgb = {40, 52, 150};

/// The colour of a leak's marker (DrawnPatch::leak), 8-bit RGB: a cyan none of the tissue, the
/// patches, the suture or the instruments (amber while touching) has.
inline constexpr std::array<int, 3> leak_rgb = {40, 220, 240};

/// A repair as the renderer draws it (world LPS, mm).
struct DrawnPatch {
    std::vector<std::array<float, 3>> positions;            ///< P×3: the patch's mid-surface vertices
    std::vector<std::array<std::int32_t, 3>> triangles;     ///< F×3 indices into positions (consistently wound)
    float thickness_mm = 0.5f;                              ///< the sheet drawn is this thick, half each side
    std::string material = "pericardium";                   ///< PatchMaterial::name, as the HUD says it
    std::array<int, 3> rgb = patch_rgb("pericardium");      ///< its colour, 8-bit
    std::vector<std::array<float, 3>> stitch_from;          ///< S×3: each stitch's patch vertex (its knot)
    std::vector<std::array<float, 3>> stitch_to;            ///< S×3: each stitch's tissue point
    /// Where the closure check found a leak pass the rim (ClosureResult::leak_mm): a ball of
    /// leak_rgb drawn last and over everything, so it shows through the patch and the wall, and
    /// whole in the section view. None: no leak known.
    std::optional<std::array<float, 3>> leak;
    bool operator==(const DrawnPatch&) const = default;
};

/// `patch` as it lies, with its stitches from their patch vertices to `anchors` (the stitches'
/// tissue points now, mm, in stitch order: RepairBackend::stitch_anchors), in its material's colour.
DrawnPatch drawn_patch(const PatchModel& patch, const std::vector<Eigen::Vector3d>& anchors);

struct RenderOptions {
    int width = 1024, height = 768;            ///< offscreen framebuffer, pixels
    ViewDirection view = ViewDirection::anterior;
    /// Draw the coronary arteries along the scenario's courses (/landmarks lad_course, rca_course,
    /// lcx_course) on the detailed mesh; nothing where the scenario has none.
    bool coronaries = true;
    /// Draw the ventricles' epicardial fibres as fine ridges on the detailed mesh, where the
    /// scenario's landmarks give the mitral ring (the left ventricle's long axis and base).
    bool fibres = true;
};

/// Rendering times so far, ms summed (GPU timer queries; the cpu backend's position upload in
/// wall clock).
struct RenderTimes {
    double normals_ms = 0.0;        ///< normals compute pass
    double draw_ms = 0.0;           ///< visualisation step: mapped mesh + instruments
    double upload_ms = 0.0;         ///< cpu backend only: positions() + buffer upload, wall clock
    long long frames = 0;           ///< frames measured
    long long normals_calls = 0;    ///< normals passes measured (0 without a visual mesh)
    long long uploads = 0;
};

class Renderer {
public:
    /// Builds the static buffers (mapping records, triangles, incidence list) and shaders on the
    /// current GL context. Throws InputError when the scenario has neither /visual with /mapping
    /// nor /simsurface (naming the group), GlUnavailable when the GL cannot run it (no shader
    /// storage in the vertex stage, a shader that does not compile).
    Renderer(const Scenario& scenario, const RenderOptions& options);
    ~Renderer();
    Renderer(const Renderer&) = delete;
    Renderer& operator=(const Renderer&) = delete;

    /// Draws from now on the detailed mesh as an incision opened it (libmodel/surgery/incision_state.h):
    /// rest positions and normals (V), triangles in drawing order with the caps from `cap_first`
    /// on (lit flat in incision_cap_rgb), and the mapping (V rows). The buffers are made anew.
    void set_visual(const std::vector<std::array<float, 3>>& positions, const std::vector<std::array<float, 3>>& normals,
                    const std::vector<std::array<std::int32_t, 3>>& triangles, const VisualMapping& mapping, std::size_t cap_first);
    /// True when the mapped visual mesh is drawn, false for the simulation surface.
    bool draws_visual_mesh() const;
    /// Vertices the vertex shader processes: visual vertices, or particles (simulation surface).
    std::size_t vertex_count() const;
    std::size_t triangle_count() const;
    int width() const;
    int height() const;

    Camera& camera();
    /// Back to the fitted default view.
    void reset_camera();
    /// Resizes the offscreen framebuffer (window resized); keeps the camera.
    void resize(int width, int height);
    /// The centre of the drawn model's rest bounding box, world LPS mm: the default view's orbit
    /// centre, and where a section is put through.
    Eigen::Vector3f model_centre() const;

    /// The section view from the next frame on: the tissue on `plane`'s removed side is not drawn
    /// and the cut wall is shaded flat in section_cut_rgb (the surface seen from inside: back
    /// faces, the surfaces being counter-clockwise from outside); nullopt: the whole heart.
    void set_section(const std::optional<SectionPlane>& plane);
    const std::optional<SectionPlane>& section() const;

    /// The tissue's surface point under the window pixel (x, y) (from the top left, in a window
    /// `window_width` × `window_height` showing the last frame), world LPS mm, from the last
    /// frame's depth (instruments write none); nullopt over the background and before the first
    /// frame. Waits for the GPU.
    std::optional<Eigen::Vector3f> surface_point(double x, double y, int window_width, int window_height);
    /// Also draw, faintly, the parts of instruments inside or behind the tissue (the window: a
    /// probe pushed into the wall stays in sight). Off by default (headless pictures).
    void set_show_hidden_instruments(bool show);

    /// Draws from the next frame on the repair `patch` (its buffers made anew only when it
    /// changed). A patch without triangles draws nothing, as clear_patch().
    void set_patch(const DrawnPatch& patch);
    /// No patch and no stitches from the next frame on.
    void clear_patch();
    /// True while a patch is drawn.
    bool draws_patch() const;

    /// Draws one frame of `backend`'s current positions with `instruments` into the offscreen
    /// framebuffer: gl backend, read in place from its position buffer; cpu backend, uploaded.
    void render(Backend& backend, const std::vector<InstrumentShape>& instruments);
    /// The same from positions (N×3, mm, packed order) taken elsewhere: a simulation thread's
    /// latest state (the window with the cpu backend).
    void render(const std::vector<std::array<float, 3>>& positions, const std::vector<InstrumentShape>& instruments);
    /// The last frame, RGB, rows top to bottom. Waits for the GPU.
    Image read_pixels();
    /// Copies the last frame into the current context's default framebuffer (window mode).
    void present(int window_width, int window_height);

    /// The deformed visual vertices (V×3, mm) at `backend`'s current positions, captured from
    /// the drawing vertex shader itself through transform feedback (rasteriser off). Runs the
    /// normals pass first. For tests against libmodel's apply_mapping.
    std::vector<std::array<float, 3>> capture_vertices(Backend& backend);
    /// The particle normals of the last normals pass (N×3; zero off the surface). Waits.
    std::vector<std::array<float, 3>> read_particle_normals();

    /// Timings so far; `wait` waits for outstanding timer queries (end of run).
    RenderTimes times(bool wait);
    /// Device memory the renderer allocated, bytes.
    std::size_t memory_bytes() const;

private:
    void draw(unsigned positions, const std::vector<InstrumentShape>& instruments);
    struct State;
    std::unique_ptr<State> state_;
};

}  // namespace heartsim
