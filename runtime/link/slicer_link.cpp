// The live link to 3D Slicer (slicer_link.h). OpenIGTLink encodes the poses and the text; the
// meshes are encoded from the protocol's layout (igtl_messages.h), because the library rebuilds a
// mesh's triangles from linked lists at every message (a 190,000-triangle heart: tens of ms each)
// where a mesh's triangles change only when an incision opens it. The sockets are our own (POSIX,
// non-blocking, MSG_NOSIGNAL): the library's sockets block on send, raise SIGPIPE on a vanished
// client and have no connect timeout, which a simulation that must never wait on the network
// cannot use.
#include "runtime/link/slicer_link.h"

#include "libmodel/errors.h"

#include <cstdio>

namespace heartsim {

SlicerLinkHands link_hands(const Trajectory& trajectory, double time_ms, const std::optional<InstrumentForces>& forces) {
    SlicerLinkHands hands;
    for (int hand = 0; hand < 2; ++hand) {
        if (!trajectory.uses_hand(hand)) continue;
        const InstrumentKeyframe k = trajectory.at(hand, time_ms);
        SlicerLinkHand& h = hands[std::size_t(hand)];
        h.used = true;
        h.kind = k.kind;
        h.pose = k.pose;
        if (forces) h.force_n = forces->hand[std::size_t(hand)].force_n, h.particles = forces->hand[std::size_t(hand)].particles;
    }
    return hands;
}

SlicerLinkHands link_hands(const std::vector<InstrumentShape>& shapes, const InstrumentForces& forces) {
    SlicerLinkHands hands;
    for (const InstrumentShape& shape : shapes) {
        if (shape.hand < 0 || shape.hand > 1) continue;
        SlicerLinkHand& h = hands[std::size_t(shape.hand)];
        h.used = true;
        h.kind = shape.kind;
        h.pose = shape.pose;
        h.force_n = forces.hand[std::size_t(shape.hand)].force_n;
        h.particles = forces.hand[std::size_t(shape.hand)].particles;
    }
    return hands;
}

}  // namespace heartsim

#ifndef HEARTSIM_HAVE_OPENIGTLINK

namespace heartsim {

bool slicer_link_available() { return false; }

std::unique_ptr<SlicerLink> SlicerLink::open(const SlicerLinkOptions&) {
    throw OptionError("{SlicerLinkOptions::endpoint}: this heartsim was built without OpenIGTLink, so it cannot stream to 3D Slicer (install "
                     "libopenigtlink-dev, e.g. with scripts/install-deps.sh, and build again with the CMake option "
                     "HEARTSIM_WITH_OPENIGTLINK on, its default)");
}

}  // namespace heartsim

#else

#include "libmodel/mapping.h"
#include "runtime/link/igtl_messages.h"

#include <tbb/task_arena.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <ctime>
#include <mutex>
#include <thread>

namespace heartsim {

bool slicer_link_available() { return true; }

namespace {

using Clock = std::chrono::steady_clock;
using igtl_messages::Bytes;
using igtl_messages::cell_section;
using igtl_messages::polydata_message;
using igtl_messages::ras_signs;
using igtl_messages::string_message;
using igtl_messages::transform_message;

/// Between two tries to reach a Slicer server, and the longest a connect may wait for an answer.
constexpr auto reconnect_period = std::chrono::seconds(2);
/// The most of one core's time the meshes take (mapping, encoding, sending) while a run goes on.
constexpr double mesh_share = 0.05;

std::chrono::nanoseconds seconds(double s) { return std::chrono::nanoseconds(std::llround(s * 1e9)); }

/// The processor time the calling thread has taken, ns.
std::int64_t thread_cpu_ns() {
    timespec t{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return std::int64_t(t.tv_sec) * 1000000000 + t.tv_nsec;
}

const char* state_name(SlicerLink::State state) {
    switch (state) {
    case SlicerLink::State::running: return "running";
    case SlicerLink::State::paused: return "paused";
    case SlicerLink::State::emergency_stop: return "e-stop";
    case SlicerLink::State::finished: return "finished";
    }
    return "running";
}

/// "PORT" or "HOST:PORT"; OptionError naming {SlicerLinkOptions::endpoint} otherwise.
struct Endpoint {
    std::string host;  ///< empty: listen
    int port = 0;
};

Endpoint parse_endpoint(const std::string& text) {
    const std::string usage = "{SlicerLinkOptions::endpoint} '" + text +
                              "': expected PORT (heartsim listens there, e.g. {SlicerLinkOptions::endpoint} 18944) or HOST:PORT (heartsim "
                              "connects to a Slicer server there, e.g. {SlicerLinkOptions::endpoint} localhost:18944), the port from 1 to 65535";
    Endpoint endpoint;
    const auto colon = text.rfind(':');
    const std::string port = colon == std::string::npos ? text : text.substr(colon + 1);
    if (colon != std::string::npos) endpoint.host = text.substr(0, colon);
    if (colon != std::string::npos && endpoint.host.empty()) throw OptionError(usage);
    if (port.empty() || port.size() > 5 || !std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; }))
        throw OptionError(usage);
    endpoint.port = std::stoi(port);
    if (endpoint.port < 1 || endpoint.port > 65535) throw OptionError(usage);
    return endpoint;
}

void set_non_blocking(int fd) { ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL, 0) | O_NONBLOCK); }

void set_no_delay(int fd) {
    int on = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &on, sizeof on);
}

/// "ADDRESS:PORT" of a connected peer.
std::string peer_name(int fd) {
    sockaddr_storage address{};
    socklen_t size = sizeof address;
    if (::getpeername(fd, reinterpret_cast<sockaddr*>(&address), &size) != 0) return "a client";
    char host[NI_MAXHOST] = "", port[NI_MAXSERV] = "";
    if (::getnameinfo(reinterpret_cast<sockaddr*>(&address), size, host, sizeof host, port, sizeof port, NI_NUMERICHOST | NI_NUMERICSERV) != 0)
        return "a client";
    return std::string(host) + ":" + port;
}

/// One line on stdout, whole (printf locks the stream per call).
template <class... Args>
void say(const char* format, Args... args) {
    std::printf(format, args...);
    std::fflush(stdout);
}

/// The mesh Slicer shows, as the renderer draws it, from one change of its triangles to the next.
struct DrawnMesh {
    std::uint64_t version = 0;
    std::vector<std::array<std::int32_t, 3>> triangles;  ///< indices into the points sent
    std::optional<VisualMapping> mapping;                ///< the detailed mesh: its vertices through the mapping
    std::vector<std::int32_t> particles;                 ///< else the simulation surface: its particles, renumbered
};

/// What a mesh message is made of: the particles, the mesh drawn, the repair.
struct MeshJob {
    std::shared_ptr<const std::vector<std::array<float, 3>>> positions;
    std::shared_ptr<const DrawnMesh> mesh;
    DrawnPatch patch;
    bool forced = false;  ///< sent whether it changed or not (a client connected)
};

/// A message with the device it updates: a newer one replaces one not yet begun.
using Named = std::pair<std::string, Bytes>;

class IgtlLink final : public SlicerLink {
public:
    IgtlLink(const SlicerLinkOptions& options, Endpoint endpoint) : options_(options), endpoint_(std::move(endpoint)) {
        if (!(options_.pose_rate_hz > 0) || !(options_.mesh_rate_hz > 0))
            throw OptionError("{SlicerLinkOptions::mesh_rate_hz}: expected a rate above 0 Hz");
        if (::pipe2(wake_, O_CLOEXEC | O_NONBLOCK) != 0) throw OptionError(std::string("{SlicerLinkOptions::endpoint}: cannot make a pipe: ") + std::strerror(errno));
        if (endpoint_.host.empty()) listen_now();
    }
    ~IgtlLink() override {
        stop_encoder();
        stop();
        if (listen_fd_ >= 0) ::close(listen_fd_);
        ::close(wake_[0]), ::close(wake_[1]);
    }

    void start(const Scenario& scenario) override {
        prepare_mesh(scenario);
        thread_ = std::thread([this] { run(); });
        encoder_ = std::thread([this] { encode_loop(); });
        const std::string streams = "heartsim-heart (" + std::to_string(mesh_->triangles.size()) + " triangles, " + mesh_source_ + ") at up to " +
                                    rate(options_.mesh_rate_hz) + " when it moves, heartsim-patch and -stitches once a patch is laid, "
                                    "heartsim-hand0/1, -state, -force0/1 at up to " + rate(options_.pose_rate_hz) + "; " + frame_name() + " mm";
        if (!endpoint_.host.empty())
            say("igtl: connecting to a 3D Slicer server at %s:%d (OpenIGTLinkIF, server); %s\n", endpoint_.host.c_str(), endpoint_.port,
                streams.c_str());
        else if (options_.bind == "127.0.0.1")
            say("igtl: listening on 127.0.0.1:%d (this machine only; --igtl-bind 0.0.0.0 for every interface) for 3D Slicer "
                "(OpenIGTLinkIF, client); %s\n", endpoint_.port, streams.c_str());
        else
            say("igtl: listening on %s:%d (%s) for 3D Slicer (OpenIGTLinkIF, client); %s\n", options_.bind.c_str(), endpoint_.port,
                options_.bind == "0.0.0.0" ? "every interface" : "that interface", streams.c_str());
        if (options_.wait_s > 0) {
            say("igtl: waiting up to %g s for %s before the first step\n", options_.wait_s,
                endpoint_.host.empty() ? "a client" : "the connection");
            const auto until = Clock::now() + seconds(options_.wait_s);
            while (clients_.load() == 0 && Clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(5));
            if (clients_.load() == 0) say("igtl: none after %g s: starting; Slicer can connect at any time\n", options_.wait_s);
        }
    }

    void set_drawn_mesh(const std::vector<std::array<std::int32_t, 3>>& triangles, const VisualMapping& mapping) override {
        if (!mesh_ || !mesh_->mapping) return;  // the simulation surface is sent: no detailed mesh to open
        auto mesh = std::make_shared<DrawnMesh>();
        mesh->version = mesh_->version + 1;
        mesh->triangles = triangles;
        mesh->mapping = mapping;
        mesh_ = std::move(mesh);
    }

    bool due() const override { return clients_.load(std::memory_order_relaxed) > 0 && Clock::now() >= next_pose_; }

    void offer(Backend& backend, long long steps, const SlicerLinkHands& hands, State state, const PatchSource& patch) override {
        if (!due()) return;
        const auto now = Clock::now();
        next_pose_ = std::max(next_pose_ + seconds(1.0 / options_.pose_rate_hz), now);
        // The only wait the simulation takes (gl: the positions read back), and only while a client
        // can take a mesh and the mesh thread is free for it, at most mesh_rate_hz times a second.
        if (mesh_due(now)) submit(std::make_shared<const std::vector<std::array<float, 3>>>(backend.positions()), patch);
        post(Frame{.time_ms = backend.simulated_time_ms(), .steps = steps, .state = state, .hands = hands, .final = false, .meshes = {}});
    }

    void offer(double time_ms, const std::vector<std::array<float, 3>>& positions, long long steps, const SlicerLinkHands& hands,
               State state, const PatchSource& patch) override {
        if (!due()) return;
        const auto now = Clock::now();
        next_pose_ = std::max(next_pose_ + seconds(1.0 / options_.pose_rate_hz), now);
        if (!positions.empty() && mesh_due(now)) submit(std::make_shared<const std::vector<std::array<float, 3>>>(positions), patch);
        post(Frame{.time_ms = time_ms, .steps = steps, .state = state, .hands = hands, .final = false, .meshes = {}});
    }

    void finish(Backend& backend, long long steps, const SlicerLinkHands& hands, const PatchSource& patch) override {
        if (!thread_.joinable()) return;
        stop_encoder();  // the final mesh is made here, after any the mesh thread was making
        if (clients_.load() > 0) {
            Frame frame{.time_ms = backend.simulated_time_ms(), .steps = steps, .state = State::finished, .hands = hands, .final = true, .meshes = {}};
            MeshJob job{.positions = std::make_shared<const std::vector<std::array<float, 3>>>(backend.positions()),
                        .mesh = mesh_,
                        .patch = patch ? patch() : DrawnPatch{},
                        .forced = true};
            frame.meshes = encode(job);
            if (const long long made = meshes_made_.load(); made > 0)
                say("igtl: %lld meshes made and sent during the run, %.3g ms of processor time each (at most %g %% of one core)\n", made, 1e-6 * double(mesh_ns_.load()) / double(made),
                    100 * mesh_share);
            finishing_.store(true);
            post(std::move(frame));
            // Until every client has the final state and has closed (or finish_s has passed).
            const auto until = Clock::now() + seconds(options_.finish_s);
            while (clients_.load() > 0 && Clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        if (connections_.load() == 0) {
            if (!endpoint_.host.empty())
                say("igtl: the Slicer server at %s:%d was never reached during the run: nothing was sent\n", endpoint_.host.c_str(), endpoint_.port);
            else
                say("igtl: no client connected to %s:%d during the run: nothing was sent\n", options_.bind.c_str(), endpoint_.port);
        }
        stop();
    }

private:
    struct Frame {
        double time_ms = 0.0;
        long long steps = 0;
        State state = State::running;
        SlicerLinkHands hands{};
        bool final = false;
        std::vector<Named> meshes;  ///< the final frame's meshes
    };
    struct Client {
        int fd = -1;
        std::string name;
        Bytes current;              ///< the message on the wire: sent whole before any other
        std::size_t sent = 0;       ///< bytes of `current` already sent
        bool current_is_mesh = false;
        Bytes frame;                ///< the newest frame not yet begun (state, poses, forces): goes first
        std::vector<Named> meshes;  ///< the newest meshes not yet begun, one per device
        Clock::time_point last_progress = Clock::now();
        bool closing = false;       ///< final state queued: shut down once sent
        bool shut = false;          ///< everything sent and shut down for writing: waiting for its close
        std::string gone;           ///< why it is dropped; empty while connected
        bool pending() const { return current || frame || !meshes.empty(); }
        bool open() const { return gone.empty() && !closing && !shut; }
    };

    static std::string rate(double hz) {
        char text[32];
        std::snprintf(text, sizeof text, "%g Hz", hz);
        return text;
    }
    const char* frame_name() const { return options_.ras ? "RAS" : "LPS"; }

    void listen_now() {
        const std::string option = "{SlicerLinkOptions::endpoint} " + std::to_string(endpoint_.port);
        sockaddr_in address{};
        address.sin_family = AF_INET;
        address.sin_port = htons(std::uint16_t(endpoint_.port));
        if (::inet_pton(AF_INET, options_.bind.c_str(), &address.sin_addr) != 1)
            throw OptionError("{SlicerLinkOptions::bind} '" + options_.bind + "': expected an IPv4 address of this machine to listen on: 127.0.0.1 (this "
                             "machine only, the default), 0.0.0.0 (every interface) or one interface's, e.g. 192.168.1.20");
        listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (listen_fd_ < 0) throw OptionError(option + ": cannot open a socket: " + std::strerror(errno));
        // A port a heartsim closed a moment ago (TIME_WAIT) is free to take again; one that a program
        // listens on is not (Linux refuses the bind either way).
        int on = 1;
        ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
        if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || ::listen(listen_fd_, 4) != 0) {
            const int error = errno;
            ::close(listen_fd_);
            listen_fd_ = -1;
            if (error == EADDRINUSE)
                throw OptionError(option + ": port " + std::to_string(endpoint_.port) +
                                  " is in use by another program (another heartsim, or a Slicer connector in server mode?); give a "
                                  "free one, e.g. {SlicerLinkOptions::endpoint} " + std::to_string(endpoint_.port < 65535 ? endpoint_.port + 1 : 18944));
            if (error == EACCES)
                throw OptionError(option + ": ports below 1024 need privileges; give one from 1024 to 65535 (Slicer's default is 18944)");
            if (error == EADDRNOTAVAIL)
                throw OptionError("{SlicerLinkOptions::bind} " + options_.bind + ": not an address of this machine; give one of its "
                                  "interfaces', 127.0.0.1 or 0.0.0.0");
            throw OptionError(option + ": cannot listen on port " + std::to_string(endpoint_.port) + ": " + std::strerror(error));
        }
        set_non_blocking(listen_fd_);
    }

    /// The mesh Slicer shows, as the renderer draws it: the detailed mesh through the mapping, or
    /// the simulation surface (its particles only, renumbered).
    void prepare_mesh(const Scenario& scenario) {
        scenario_ = &scenario;
        auto mesh = std::make_shared<DrawnMesh>();
        if (scenario.visual && scenario.mapping && scenario.simulation_surface) {
            mesh->triangles = scenario.visual->triangles;
            mesh->mapping = *scenario.mapping;
            mesh_source_ = "the detailed mesh";
        } else if (scenario.simulation_surface) {
            mesh_source_ = "the simulation surface";
            std::vector<std::int32_t> renumbered(scenario.lattice.particles.rest_position.size(), -1);
            for (const auto& t : scenario.simulation_surface->triangles) {
                std::array<std::int32_t, 3> cell{};
                for (int k = 0; k < 3; ++k) {
                    std::int32_t& r = renumbered[std::size_t(t[std::size_t(k)])];
                    if (r < 0) r = std::int32_t(mesh->particles.size()), mesh->particles.push_back(t[std::size_t(k)]);
                    cell[std::size_t(k)] = r;
                }
                mesh->triangles.push_back(cell);
            }
        } else {
            mesh_source_ = "no surface in the scenario";
        }
        mesh_ = std::move(mesh);
    }

    // ---- the thread that steps ----

    /// A mesh is due: its time has come (or a client has just connected), a client has room for
    /// it and the mesh thread is free.
    bool mesh_due(Clock::time_point now) {
        if (!(now >= next_mesh_ || mesh_wanted_.load()) || !mesh_room_.load() || encoding_.load() ||
            now.time_since_epoch().count() < mesh_not_before_.load())
            return false;
        next_mesh_ = std::max(next_mesh_ + seconds(1.0 / options_.mesh_rate_hz), now);
        return true;
    }

    void submit(std::shared_ptr<const std::vector<std::array<float, 3>>> positions, const PatchSource& patch) {
        MeshJob job{.positions = std::move(positions), .mesh = mesh_, .patch = patch ? patch() : DrawnPatch{}, .forced = mesh_wanted_.exchange(false)};
        {
            std::lock_guard lock(job_mutex_);
            job_ = std::move(job);
            encoding_.store(true);
        }
        job_ready_.notify_one();
    }

    void post(Frame frame) {
        std::lock_guard lock(mailbox_mutex_);
        // A final frame is never replaced; otherwise the newest replaces what the sender has not taken.
        if (mailbox_ && mailbox_->final) return;
        mailbox_ = std::move(frame);
        wake();
    }

    /// The sender thread out of its poll: a frame or meshes for it, or the end.
    void wake() {
        const char byte = 1;
        [[maybe_unused]] const ssize_t n = ::write(wake_[1], &byte, 1);  // a full pipe has woken it already
    }

    // ---- the mesh thread ----

    void encode_loop() {
        while (true) {
            MeshJob job;
            {
                std::unique_lock lock(job_mutex_);
                job_ready_.wait(lock, [this] { return job_ || stop_encoder_; });
                if (stop_encoder_) return;
                job = std::move(*job_);
                job_.reset();
            }
            const std::int64_t began = thread_cpu_ns();
            std::vector<Named> meshes = encode(job);
            // The next mesh waits (1 − share)/share times the processor time this one took: the
            // meshes take at most mesh_share of one core, whatever they cost and however loaded
            // the machine is.
            // What sending the meshes before it took the sender thread counts too.
            const std::int64_t took = thread_cpu_ns() - began + mesh_send_ns_.exchange(0);
            mesh_not_before_.store((Clock::now() + std::chrono::nanoseconds(std::llround(double(took) * (1.0 - mesh_share) / mesh_share)))
                                       .time_since_epoch()
                                       .count());
            meshes_made_.fetch_add(1), mesh_ns_.fetch_add(took);
            if (!meshes.empty()) {
                std::lock_guard lock(meshes_mutex_);
                for (Named& m : meshes) replace(meshes_out_, std::move(m));
            }
            wake();
            encoding_.store(false);
        }
    }

    void stop_encoder() {
        {
            std::lock_guard lock(job_mutex_);
            stop_encoder_ = true;
        }
        job_ready_.notify_one();
        if (encoder_.joinable()) encoder_.join();
    }

    /// `m` in place of the message for its device in `queue`, or after the others.
    static void replace(std::vector<Named>& queue, Named m) {
        for (Named& q : queue)
            if (q.first == m.first) return void(q.second = std::move(m.second));
        queue.push_back(std::move(m));
    }

    /// The messages for what changed since the last ones (everything when forced): the heart, the
    /// patch and its stitches (empty once a patch is gone, so that Slicer's go too).
    std::vector<Named> encode(const MeshJob& job) {
        std::vector<Named> out;
        const DrawnMesh& mesh = *job.mesh;
        const auto& positions = *job.positions;
        const float sx = options_.ras ? ras_signs[0] : 1.0f, sy = options_.ras ? ras_signs[1] : 1.0f;
        if (!mesh.triangles.empty() && (job.forced || mesh.version != sent_version_ || positions != sent_positions_)) {
            std::vector<std::array<float, 3>> points;
            if (mesh.mapping) {
                // The detailed mesh as drawn and as --save-state writes /visual/positions; on this
                // thread alone (not the simulation's workers).
                std::vector<Eigen::Vector3f> visual;
                tbb::task_arena(1).execute([&] { visual = apply_mapping(*mesh.mapping, positions, *scenario_->simulation_surface); });
                points.reserve(visual.size());
                for (const auto& v : visual) points.push_back({sx * v.x(), sy * v.y(), v.z()});
            } else {
                points.reserve(mesh.particles.size());
                for (std::int32_t i : mesh.particles) {
                    const auto& p = positions[std::size_t(i)];
                    points.push_back({sx * p[0], sy * p[1], p[2]});
                }
            }
            if (polygons_version_ != mesh.version || polygons_.empty()) polygons_ = cell_section(mesh.triangles), polygons_version_ = mesh.version;
            out.emplace_back("heartsim-heart", polydata_message("heartsim-heart", points, polygons_, mesh.triangles.size(), {}, 0));
            sent_version_ = mesh.version;
            sent_positions_ = positions;
        }
        const DrawnPatch& patch = job.patch;
        const bool has_patch = !patch.triangles.empty();
        if ((has_patch || patch_sent_) &&
            (job.forced || patch.positions != sent_patch_.positions || patch.triangles != sent_patch_.triangles ||
             patch.stitch_from != sent_patch_.stitch_from || patch.stitch_to != sent_patch_.stitch_to)) {
            auto frame = [&](const std::array<float, 3>& p) { return std::array<float, 3>{sx * p[0], sy * p[1], p[2]}; };
            std::vector<std::array<float, 3>> points, ends;
            for (const auto& p : patch.positions) points.push_back(frame(p));
            std::vector<std::array<std::int32_t, 2>> lines;
            for (std::size_t k = 0; k < patch.stitch_from.size() && k < patch.stitch_to.size(); ++k) {
                lines.push_back({std::int32_t(ends.size()), std::int32_t(ends.size() + 1)});
                ends.push_back(frame(patch.stitch_from[k]));
                ends.push_back(frame(patch.stitch_to[k]));
            }
            out.emplace_back("heartsim-patch", polydata_message("heartsim-patch", points, cell_section(patch.triangles), patch.triangles.size(), {}, 0));
            out.emplace_back("heartsim-stitches", polydata_message("heartsim-stitches", ends, {}, 0, cell_section(lines), lines.size()));
            sent_patch_ = patch;
            patch_sent_ = has_patch;
        }
        return out;
    }

    void stop() {
        stop_.store(true);
        wake();
        if (thread_.joinable()) thread_.join();
    }

    // ---- the sender thread ----

    void run() {
        auto next_connect = Clock::now();
        std::string last_failure;
        while (!stop_.load()) {
            if (!endpoint_.host.empty() && clients_list_.empty() && !finishing_.load() && Clock::now() >= next_connect) {
                const std::string failure = connect_now();
                if (!failure.empty()) {
                    if (failure != last_failure)
                        say("igtl: cannot reach %s:%d (%s); trying again every 2 s\n", endpoint_.host.c_str(), endpoint_.port, failure.c_str());
                    last_failure = failure;
                    next_connect = Clock::now() + reconnect_period;
                } else {
                    last_failure.clear();
                }
            }
            take_meshes();
            take_frame();
            exchange();
            for (auto it = clients_list_.begin(); it != clients_list_.end();) {
                if (it->gone.empty()) {
                    ++it;
                    continue;
                }
                if (it->gone != "finished") {
                    say("igtl: %s %s%s\n", it->name.c_str(), it->gone.c_str(),
                        finishing_.load() ? "" : endpoint_.host.empty() ? "; it can connect again" : "; trying again every 2 s");
                    if (!endpoint_.host.empty()) next_connect = Clock::now() + reconnect_period, last_failure = "closed";
                }
                ::close(it->fd);
                it = clients_list_.erase(it);
                clients_.store(int(clients_list_.size()));
            }
            mesh_room_.store(std::any_of(clients_list_.begin(), clients_list_.end(), [](const Client& c) { return c.open() && c.meshes.empty(); }));
        }
        for (Client& client : clients_list_) ::close(client.fd);
        clients_list_.clear();
        clients_.store(0);
    }

    /// One try to reach HOST:PORT, within 2 s; empty on success, else why not.
    std::string connect_now() {
        addrinfo hints{};
        hints.ai_family = AF_UNSPEC;
        hints.ai_socktype = SOCK_STREAM;
        addrinfo* found = nullptr;
        const std::string port = std::to_string(endpoint_.port);
        if (const int error = ::getaddrinfo(endpoint_.host.c_str(), port.c_str(), &hints, &found); error != 0)
            return std::string("unknown host: ") + ::gai_strerror(error);
        std::string failure = "no address";
        for (addrinfo* a = found; a; a = a->ai_next) {
            const int fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
            if (fd < 0) continue;
            int result = ::connect(fd, a->ai_addr, a->ai_addrlen);
            if (result != 0 && errno == EINPROGRESS) {
                const auto until = Clock::now() + reconnect_period;
                result = -1;
                errno = ETIMEDOUT;
                while (!stop_.load() && Clock::now() < until) {
                    pollfd p{fd, POLLOUT, 0};
                    if (::poll(&p, 1, 50) > 0) {
                        int error = 0;
                        socklen_t size = sizeof error;
                        ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &size);
                        result = error == 0 ? 0 : -1;
                        errno = error;
                        break;
                    }
                }
            }
            if (result == 0) {
                ::freeaddrinfo(found);
                add_client(fd, endpoint_.host + ":" + port);
                say("igtl: connected to the Slicer server at %s\n", clients_list_.back().name.c_str());
                return "";
            }
            failure = errno == ETIMEDOUT ? "no answer within 2 s" : std::strerror(errno);
            ::close(fd);
        }
        ::freeaddrinfo(found);
        return failure;
    }

    void add_client(int fd, std::string name) {
        set_non_blocking(fd);
        set_no_delay(fd);
        Client client;
        client.fd = fd;
        client.name = std::move(name);
        clients_list_.push_back(std::move(client));
        connections_.fetch_add(1);
        clients_.store(int(clients_list_.size()));
        mesh_room_.store(true);
        mesh_wanted_.store(true);  // a newcomer gets the mesh at once, moved or not
    }

    /// The mesh thread's newest messages into every open client's queue, each in place of its
    /// device's message not yet begun.
    void take_meshes() {
        std::vector<Named> meshes;
        {
            std::lock_guard lock(meshes_mutex_);
            meshes.swap(meshes_out_);
        }
        for (const Named& m : meshes)
            for (Client& client : clients_list_) {
                if (!client.open()) continue;
                if (!client.pending()) client.last_progress = Clock::now();
                replace(client.meshes, m);
            }
    }

    /// The mailbox's frame, if any, to every open client, in place of the frame it has not begun.
    void take_frame() {
        std::optional<Frame> frame;
        {
            std::lock_guard lock(mailbox_mutex_);
            frame.swap(mailbox_);
        }
        if (!frame) return;
        // state, hands, forces: one buffer shared by the clients
        std::string bytes;
        char text[256];
        std::snprintf(text, sizeof text, "%s time_ms=%.17g steps=%lld frame=%s", state_name(frame->state), frame->time_ms, frame->steps,
                      frame_name());
        bytes += *string_message("heartsim-state", text);
        const double sx = options_.ras ? ras_signs[0] : 1.0, sy = options_.ras ? ras_signs[1] : 1.0;
        for (int hand = 0; hand < 2; ++hand) {
            const SlicerLinkHand& h = frame->hands[std::size_t(hand)];
            if (!h.used) continue;
            bytes += *transform_message(hand == 0 ? "heartsim-hand0" : "heartsim-hand1", h.pose, options_.ras);
            std::snprintf(text, sizeof text, "force_n=%.6g,%.6g,%.6g magnitude_n=%.6g particles=%zu kind=%s", sx * h.force_n.x(),
                          sy * h.force_n.y(), h.force_n.z(), h.force_n.norm(), h.particles, to_string(h.kind));
            bytes += *string_message(hand == 0 ? "heartsim-force0" : "heartsim-force1", text);
        }
        const Bytes shared = std::make_shared<const std::string>(std::move(bytes));
        for (Client& client : clients_list_) {
            if (!client.open()) continue;
            if (!client.pending()) client.last_progress = Clock::now();
            client.frame = shared;
            if (frame->final) client.meshes = frame->meshes, client.closing = true;
        }
    }

    /// One poll of every socket until something happens (a client, bytes that can go, a frame or
    /// meshes to send: the wake pipe) or 50 ms pass (the stall and reconnect clocks): new clients,
    /// bytes out (a frame before any mesh not yet begun), bytes in (discarded), closes. Between
    /// frames the thread sleeps: it takes no processor time from the simulation.
    void exchange() {
        std::vector<pollfd> fds;
        fds.push_back({wake_[0], POLLIN, 0});
        if (listen_fd_ >= 0) fds.push_back({listen_fd_, POLLIN, 0});
        const std::size_t first_client = fds.size();
        for (const Client& client : clients_list_) fds.push_back({client.fd, short(POLLIN | (client.pending() ? POLLOUT : 0)), 0});
        if (::poll(fds.data(), nfds_t(fds.size()), 50) < 0) return;
        if (fds[0].revents & POLLIN)
            for (char drain[64]; ::read(wake_[0], drain, sizeof drain) > 0;) {
            }
        for (std::size_t i = 0; i < clients_list_.size(); ++i) {
            Client& client = clients_list_[i];
            const short events = fds[first_client + i].revents;
            if (events & POLLIN) {
                char discard[4096];
                const ssize_t n = ::recv(client.fd, discard, sizeof discard, MSG_DONTWAIT);
                if (n == 0) client.gone = client.shut ? "finished" : "closed the connection";
                else if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) client.gone = std::string("dropped: ") + std::strerror(errno);
            } else if (events & (POLLERR | POLLHUP)) {
                client.gone = "closed the connection";
            }
            while (client.gone.empty()) {
                if (!client.current) {
                    client.current_is_mesh = !client.frame;
                    if (client.frame) client.current = std::move(client.frame), client.frame.reset();
                    else if (!client.meshes.empty()) client.current = std::move(client.meshes.front().second), client.meshes.erase(client.meshes.begin());
                    else break;
                    client.sent = 0;
                }
                const std::string& front = *client.current;
                const std::int64_t began = client.current_is_mesh ? thread_cpu_ns() : 0;
                const ssize_t n = ::send(client.fd, front.data() + client.sent, front.size() - client.sent, MSG_NOSIGNAL | MSG_DONTWAIT);
                if (client.current_is_mesh) mesh_send_ns_.fetch_add(thread_cpu_ns() - began);
                if (n < 0) {
                    if (errno != EAGAIN && errno != EWOULDBLOCK) client.gone = std::string("dropped: ") + std::strerror(errno);
                    break;
                }
                client.sent += std::size_t(n);
                client.last_progress = Clock::now();
                if (client.sent == front.size()) client.current.reset(), client.sent = 0;
            }
            if (client.gone.empty() && client.closing && !client.pending()) {
                // All sent: say so with a FIN and wait for the client to close (or finish_s).
                ::shutdown(client.fd, SHUT_WR);
                client.closing = false;
                client.shut = true;
            }
            if (client.gone.empty() && client.pending() && Clock::now() - client.last_progress > seconds(options_.stall_s)) {
                char text[96];
                std::snprintf(text, sizeof text, "took nothing for %g s (not reading): dropped, the simulation goes on", options_.stall_s);
                client.gone = text;
            }
        }
        if (listen_fd_ >= 0 && (fds[1].revents & POLLIN))
            for (int fd; (fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC)) >= 0;) {
                add_client(fd, peer_name(fd));
                say("igtl: %s connected\n", clients_list_.back().name.c_str());
            }
    }

    SlicerLinkOptions options_;
    Endpoint endpoint_;
    int listen_fd_ = -1;
    int wake_[2] = {-1, -1};  ///< the sender thread's wake pipe: read end, write end
    std::thread thread_, encoder_;
    std::atomic<bool> stop_{false};
    std::atomic<int> clients_{0};
    std::atomic<long long> connections_{0};  ///< clients that connected during the run
    std::atomic<bool> mesh_wanted_{false};
    std::atomic<bool> mesh_room_{false};  ///< a client has no mesh waiting (the sender's word)
    std::atomic<bool> encoding_{false};   ///< the mesh thread has a job
    std::atomic<Clock::rep> mesh_not_before_{0};  ///< the mesh thread's share: no mesh before this (Clock's count)
    std::atomic<long long> meshes_made_{0}, mesh_ns_{0};  ///< by the mesh thread, and the time they took (sending them included)
    std::atomic<std::int64_t> mesh_send_ns_{0};  ///< the sender thread's processor time on meshes since the mesh thread last counted it
    std::atomic<bool> finishing_{false};  ///< the final state is on its way: no new connection
    const Scenario* scenario_ = nullptr;
    std::string mesh_source_;
    // the thread that steps
    Clock::time_point next_pose_{}, next_mesh_{};
    std::shared_ptr<const DrawnMesh> mesh_;  ///< the mesh drawn now
    // the mailbox: one slot
    std::mutex mailbox_mutex_;
    std::optional<Frame> mailbox_;
    // the mesh thread: its job, its messages out
    std::mutex job_mutex_;
    std::condition_variable job_ready_;
    std::optional<MeshJob> job_;
    bool stop_encoder_ = false;
    std::mutex meshes_mutex_;
    std::vector<Named> meshes_out_;
    // the mesh thread's own (finish()'s once it has stopped): what was sent last
    std::uint64_t sent_version_ = ~std::uint64_t(0), polygons_version_ = ~std::uint64_t(0);
    std::vector<std::array<float, 3>> sent_positions_;
    std::string polygons_;
    DrawnPatch sent_patch_;
    bool patch_sent_ = false;
    // the sender thread
    std::vector<Client> clients_list_;
};

}  // namespace

std::unique_ptr<SlicerLink> SlicerLink::open(const SlicerLinkOptions& options) {
    return std::make_unique<IgtlLink>(options, parse_endpoint(options.endpoint));
}

}  // namespace heartsim

#endif
