/// @file incision_state.h
/// @brief The detailed mesh of a run as the scalpel opens it: each finished stroke is mapped into
/// the rest shape, the mesh is split and capped along it (incision.h), and every vertex beside the
/// cut is embedded again in the particles of its own side, so no vertex is pulled across the cut
/// and no triangle bridges it (docs/architecture.md "Incision").
///
///     IncisionState incisions(scenario.lattice, visual.positions, visual.normals, visual.triangles, mapping, surface);
///     if (incisions.update(backend.strokes(), backend.positions(), false).opened) renderer.set_visual(...);
#pragma once

#include "libmodel/sim/cutting.h"
#include "libmodel/surgery/incision.h"
#include "libmodel/lattice.h"
#include "libmodel/mapping.h"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// The rest-space surfaces one stroke swept: its poses thinned to those where the blade's path
/// bends (within a twentieth of the lattice spacing), split where it turns back (a sawing blade
/// sweeps the same surface twice), each blade point taken into the rest shape by the displacement
/// of the particles around it (the tissue's current positions `positions`, packed order, against
/// its rest positions: a Gaussian of the lattice spacing's width over the particles within two
/// spacings, or the nearest particle beyond).
std::vector<CutSurface> stroke_surfaces(const BladeStroke& stroke, const std::vector<std::array<float, 3>>& positions,
                                        const Lattice& lattice);

struct IncisionUpdate {
    bool opened = false;               ///< the mesh changed
    std::size_t strokes = 0;           ///< strokes opened in this update
    std::size_t reembedded = 0;        ///< vertices embedded again (new ones included)
    std::size_t remeshed = 0;          ///< the mesh's triangles the strokes' corefinements took in (IncisionResult::patch_triangles)
    std::size_t cut_faces = 0;         ///< the strips' triangles added to the cut
    /// Carriers (vertex–particle segments) of the vertices beside the strips tested for crossing
    /// the cut, and the segment–face tests that took: each segment meets each face once at most,
    /// and only the faces cut since its vertex was last found clear.
    std::size_t carriers_tested = 0;
    std::size_t face_tests = 0;
    std::vector<std::string> failures; ///< strokes the mesh could not be opened along, and why
    double seconds = 0.0;
};

class IncisionState {
public:
    /// The uncut detailed mesh (rest positions, normals V or empty, triangles) with its mapping on
    /// `lattice`'s particles (packed order, as a scenario stores them); `surface` gives the
    /// carriers of a mapping that stores none (mapping_carriers). Keeps a reference to `lattice`.
    IncisionState(const Lattice& lattice, const std::vector<std::array<float, 3>>& positions,
                  const std::vector<std::array<float, 3>>& normals, const std::vector<std::array<std::int32_t, 3>>& triangles,
                  const VisualMapping& mapping, const SimulationSurface& surface);
    ~IncisionState();
    IncisionState(const IncisionState&) = delete;
    IncisionState& operator=(const IncisionState&) = delete;

    /// Opens the mesh along every stroke of `log` whose blade was lifted and that is not opened
    /// yet, and, with `finish`, along the strokes still under way too (the end of a run: they are
    /// then taken as finished). `positions`: the particles' current positions (packed order).
    /// A log that was cleared (the tissue reset, its cuts healed) restores the uncut mesh. Where
    /// the split along a stroke does not close up (open_along), the strip moved 0.05, 0.1, 0.2 and
    /// 0.3 spacing each way along its normal is tried, then the strip with both its ends drawn in
    /// along the stroke by 0.1, 0.2 and 0.3 spacing, before that stroke leaves the mesh closed.
    IncisionUpdate update(const StrokeLog& log, const std::vector<std::array<float, 3>>& positions, bool finish);
    /// Whether update() would do anything for `log` (cheap: no positions needed).
    bool pending(const StrokeLog& log, bool finish) const;
    /// While a stroke is under way: the mesh as if its blade lifted now, drawn until the next
    /// update() or preview() (which start again from the strokes that did lift); nothing when no
    /// stroke is under way. For a window, a few times a second: the incision opens as the blade
    /// moves. update() alone gives the same mesh whatever previews came before.
    IncisionUpdate preview(const StrokeLog& log, const std::vector<std::array<float, 3>>& positions);
    bool previewing() const { return committed_.has_value(); }

    bool cut() const { return mesh_.triangles.size() != uncut_triangles_; }  ///< opened along at least one stroke
    const IncisionMesh& mesh() const { return mesh_; }
    const VisualMapping& mapping() const { return mapping_; }
    /// The triangles to draw: the tissue's surface first, then the caps from cap_first() on.
    const std::vector<std::array<std::int32_t, 3>>& drawn_triangles() const { return drawn_; }
    std::size_t cap_first() const { return cap_first_; }
    /// Rest positions and normals in float (the file's and the renderer's precision).
    std::vector<std::array<float, 3>> rest_positions() const;
    std::vector<std::array<float, 3>> rest_normals() const;

private:
    void restore();
    void apply(const BladeStroke& stroke, const std::vector<std::array<float, 3>>& positions, IncisionUpdate& update);
    bool end_preview();  ///< back to the strokes that lifted; true when a preview was shown
    std::size_t reembed(const IncisionResult& result, const Eigen::AlignedBox3d& region, IncisionUpdate& update);
    void order_for_drawing();

    const Lattice& lattice_;
    std::vector<Eigen::Vector3d> particle_rest_;
    struct Impl;
    std::unique_ptr<Impl> impl_;
    IncisionMesh uncut_;
    VisualMapping uncut_mapping_;
    std::size_t uncut_triangles_ = 0;
    IncisionMesh mesh_;
    VisualMapping mapping_;
    std::vector<std::array<std::int32_t, 3>> drawn_;
    /// What the cuts so far settled about a vertex's carriers, so that a lift looks only at what
    /// its own stroke changed (reembed).
    struct Settled {
        std::uint32_t clear_of = 0;  ///< its carriers reach across none of the first so many cut faces
        /// 1: no particles on its side can carry it, and fewer cannot either (CellEmbedder's search
        /// found fewer than 8 within reach): its carriers are the nearest any side's until it moves;
        /// 2: the same, and none carry it (its carriers kept).
        std::uint8_t stranded = 0;
    };
    std::vector<Settled> settled_;
    std::size_t cap_first_ = 0;
    struct Committed {
        IncisionMesh mesh;
        VisualMapping mapping;
        std::size_t cut_faces = 0;
        std::vector<Settled> settled;
    };
    std::optional<Committed> committed_;  ///< while a preview is drawn: the strokes that lifted
    std::vector<std::uint8_t> applied_;  ///< per stroke row of the log
    std::uint64_t generation_ = 0;       ///< the log's clears() seen
};

}  // namespace heartsim
