/// @file picking.h
/// @brief Probe contact search for the force pass (Sørensen & Mosegaard, MMVR 2006, §1.2.2; docs/runtime.md "Probe contacts"): which
/// particles a probe touches, three ways, selectable, all feeding the same force pass.
///
/// * `direct` (default, the CPU reference's definition): the particles the step pass projected
///   out of the probe in the last substep (the step tests every particle, fused, no extra pass).
/// * `picking` (Sørensen & Mosegaard): the simulation surface (/simsurface over the current positions) is
///   rendered from the probe's base along its axis into an offscreen integer target holding,
///   per pixel, the nearest particle of the visible triangle and the distance of the surface
///   point to the probe; a compute pass projects sampling points on the probe's boundary into
///   it and keeps the picked particles within `tolerance_mm` of the probe. Rendered every
///   `picking_refresh` (K) force requests; in between the stale image is used with the current
///   pose and current particle positions (Sørensen & Mosegaard's choice).
/// * `search`: a compute pass testing every simulation-surface particle with the same
///   tolerance: what the picking buffer approximates (for measuring it).
///
/// Camera: the probe points along its tool-frame +z axis; its base is centre − R·(0,0,c) (c the
/// z semi-axis). Orthographic, looking from the base along +z, window ±(1.02·max(a,b) + tol)
/// mm, depth from the base to 3c + one lattice spacing beyond the centre. docs/runtime.md.
#pragma once

#include "runtime/backend/contact.h"

#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/sim/solver.h"

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

/// Device memory the picking pass allocates for `scenario` at `settings` (both hands), bytes.
std::size_t estimate_picking_memory_bytes(const Scenario& scenario, const ContactSettings& settings);

/// The GL passes behind `picking` and `search` (needs a current GL 4.3+ context). Owned by the
/// GL backend; it writes hand h's contact list to picked_buffer()[h·N ...] and its count to word
/// picked0 + h of the backend's counter buffer (shaders/bindings.h `Counter`).
class PickingPass {
public:
    /// `surface`: the scenario's /simsurface, `particles` N, `spacing_mm` the lattice spacing.
    /// Throws InputError when there is no surface, GlUnavailable when a shader fails.
    PickingPass(const std::optional<SimulationSurface>& surface, std::size_t particles, double spacing_mm,
                const ContactSettings& settings);
    ~PickingPass();
    PickingPass(const PickingPass&) = delete;
    PickingPass& operator=(const PickingPass&) = delete;

    void set_settings(const ContactSettings& settings);
    const ContactSettings& settings() const { return settings_; }
    double tolerance_mm() const { return tolerance_; }
    std::size_t surface_particles() const { return surface_count_; }

    /// The picking buffer of `hand` is out of date (instrument changed): rendered on next use.
    void invalidate(int hand);
    /// picking: renders hand's buffer if due (K), then collects the contacts of the probe at
    /// `pose` from `positions` (an SSBO of float4). search: tests every surface particle. A
    /// particle is in contact within the tolerance of the probe grown by its entry of `skin_buffer`
    /// (a double per particle, mm: Solver::reach_beyond), as the step meets it.
    void collect(int hand, const Instrument& instrument, const InstrumentPose& pose, unsigned positions_buffer,
                 unsigned counters_buffer, unsigned skin_buffer);
    unsigned picked_buffer() const;
    long long renders() const { return renders_; }
    std::size_t memory_bytes() const { return memory_bytes_; }

    struct Gl;
private:
    void render(int hand, const Instrument& instrument, const InstrumentPose& pose, unsigned positions_buffer);

    ContactSettings settings_;
    double tolerance_ = 0.0, spacing_ = 1.0;
    std::size_t n_ = 0, triangle_count_ = 0, surface_count_ = 0, sample_count_ = 0, memory_bytes_ = 0;
    long long renders_ = 0;
    std::uint32_t epoch_ = 0;
    std::unique_ptr<Gl> gl_;
};

}  // namespace heartsim
