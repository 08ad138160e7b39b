/// @file slicer_link.h
/// @brief `heartsim run … --igtl PORT | HOST:PORT`: a live link to 3D Slicer over OpenIGTLink
/// (docs/runtime.md "Live link to 3D Slicer"). heartsim listens on PORT (Slicer's OpenIGTLinkIF
/// connects as a client) or connects to a Slicer server at HOST:PORT, and streams, in RAS mm
/// (Slicer's scene; LPS, heartsim's world, on request):
///
///   heartsim-hand0, heartsim-hand1   TRANSFORM  each instrument's pose (tool → world), ≤ pose_rate_hz
///   heartsim-heart                   POLYDATA   the deformed detailed mesh as drawn (opened by the scalpel's strokes), ≤ mesh_rate_hz, when it changed
///   heartsim-patch                   POLYDATA   a repair's patch (its mid-surface triangles), with the mesh, once laid
///   heartsim-stitches                POLYDATA   each stitch a line from its patch vertex to its tissue point, with the patch
///   heartsim-state                   STRING     "running time_ms=… steps=… frame=RAS" (paused, e-stop, finished), ≤ pose_rate_hz
///   heartsim-force0, heartsim-force1 STRING     "force_n=FX,FY,FZ magnitude_n=… particles=… kind=…", ≤ pose_rate_hz
///
/// The simulation never waits for the network: the thread that steps offers its state (offer(),
/// a clock read when nothing is due) into a one-slot mailbox that a sender thread empties; the
/// meshes are made on a thread of their own, and making and sending them takes at most 5 % of one
/// core (a mesh that took t of processor time waits 19·t before the next); each client's poses go
/// out before any mesh not yet begun, so a mesh never holds the poses back by more than the one
/// message on the wire. A slow client skips frames, a client that takes nothing for stall_s is
/// dropped, a vanished one is noticed, and a Slicer that is not there yet is tried again every
/// 2 s. Each such event is one line `igtl: …`.
///
///     auto link = SlicerLink::open({.endpoint = "18944"});  // binds 127.0.0.1 now: a port in use is an OptionError
///     link->start(scenario);                                // the threads (and --igtl-wait)
///     … an incision opened the mesh: link->set_drawn_mesh(triangles, mapping);
///     … after each step: link->offer(backend, steps, hands, SlicerLink::State::running, patch);
///     link->finish(backend, steps, hands, patch);           // the final state, sent within 2 s
///
/// Built without OpenIGTLink (no HEARTSIM_HAVE_OPENIGTLINK), open() throws OptionError saying so.
///
/// The errors name the options by their meaning ({SlicerLinkOptions::endpoint}, …: libmodel/errors.h
/// OptionError); heartsim spells them as its flags (--igtl, --igtl-bind, --igtl-mesh-rate).
#pragma once

#include "runtime/backend/backend.h"
#include "runtime/gl/renderer.h"
#include "runtime/backend/instrument_shape.h"
#include "runtime/core/trajectory.h"

#include "formats/scenario.h"

#include <array>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace heartsim {

struct SlicerLinkOptions {
    /// "PORT": listen at PORT (1-65535) on `bind`; "HOST:PORT": connect to a server there.
    std::string endpoint;
    /// Listening: the IPv4 address to listen on; 127.0.0.1 (this machine only), 0.0.0.0 every interface.
    std::string bind = "127.0.0.1";
    /// Coordinates sent in RAS (Slicer's scene: x and y of heartsim's LPS negated); false: LPS.
    bool ras = true;
    double pose_rate_hz = 60.0;   ///< cap on TRANSFORM and STRING messages, Hz
    double mesh_rate_hz = 20.0;   ///< cap on POLYDATA messages, Hz (sent only when the mesh moved)
    /// Before the first step, wait up to this long for a client (listening) or for the connection
    /// (connecting), s; 0: start at once and stream to whoever is connected.
    double wait_s = 0.0;
    double stall_s = 5.0;          ///< a client that takes no byte of a pending message for this long is dropped, s
    double finish_s = 2.0;         ///< at the end, the final state is sent to connected clients within this, s
};

/// One hand as streamed: its pose (LPS mm, tool → world) and the force on it (N, world frame).
struct SlicerLinkHand {
    bool used = false;
    InstrumentKind kind = InstrumentKind::none;
    InstrumentPose pose;
    Eigen::Vector3d force_n = Eigen::Vector3d::Zero();
    std::size_t particles = 0;  ///< particles the force was summed over
};
using SlicerLinkHands = std::array<SlicerLinkHand, 2>;

/// The hands of a scripted run at `time_ms` (the trajectory's poses) with `forces` where known.
SlicerLinkHands link_hands(const Trajectory& trajectory, double time_ms, const std::optional<InstrumentForces>& forces);
/// The hands of a haptic session: the shapes it draws (hand set) and the forces it published.
SlicerLinkHands link_hands(const std::vector<InstrumentShape>& shapes, const InstrumentForces& forces);

/// True when this heartsim was built with OpenIGTLink (the tests skip without it).
bool slicer_link_available();

class SlicerLink {
public:
    enum class State { running, paused, emergency_stop, finished };

    /// Checks the endpoint and, listening, binds the port. Throws OptionError for an endpoint that
    /// is not PORT or HOST:PORT, a port in use or not permitted, and in a build without OpenIGTLink.
    static std::unique_ptr<SlicerLink> open(const SlicerLinkOptions& options);
    virtual ~SlicerLink() = default;

    /// Starts the sender thread for `scenario`'s mesh (the visual mesh through the mapping, or the
    /// simulation surface); prints one line saying where it listens or connects; then waits up to
    /// wait_s for a client. `scenario` must outlive the link.
    virtual void start(const Scenario& scenario) = 0;
    /// The detailed mesh drawn from now on (an incision opened it, a reset closed it again): its
    /// triangles and the mapping that carries its vertices, copied; on the thread that offers.
    virtual void set_drawn_mesh(const std::vector<std::array<std::int32_t, 3>>& triangles, const VisualMapping& mapping) = 0;
    /// The repair as drawn now (no triangles: no patch laid); called only when a mesh is to be sent.
    using PatchSource = std::function<DrawnPatch()>;
    /// Whether offer() would send now (a client is connected and a frame is due): a clock read.
    virtual bool due() const = 0;
    /// After a step, on the thread that steps: when a frame is due and a client is connected,
    /// hands the state (and, when the mesh is due, backend.positions()) to the sender thread.
    /// Never waits on the network; costs a clock read when nothing is due.
    virtual void offer(Backend& backend, long long steps, const SlicerLinkHands& hands, State state, const PatchSource& patch = {}) = 0;
    /// The same from a state taken elsewhere: the window's latest positions (N×3, packed order)
    /// at `time_ms`, copied only when the mesh is due (the cpu backend steps on its own thread).
    virtual void offer(double time_ms, const std::vector<std::array<float, 3>>& positions, long long steps, const SlicerLinkHands& hands,
                       State state, const PatchSource& patch = {}) = 0;
    /// The run is over: the final state (state `finished`, the final mesh and patch) to the
    /// connected clients, waiting at most finish_s; then the connections are closed.
    virtual void finish(Backend& backend, long long steps, const SlicerLinkHands& hands, const PatchSource& patch = {}) = 0;
};

}  // namespace heartsim
