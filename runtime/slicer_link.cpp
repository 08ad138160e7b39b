// The live link to 3D Slicer (slicer_link.h). OpenIGTLink encodes the messages; the sockets are
// our own (POSIX, non-blocking, MSG_NOSIGNAL): the library's sockets block on send, raise SIGPIPE
// on a vanished client and have no connect timeout, which a simulation that must never wait on
// the network cannot use.
#include "runtime/slicer_link.h"

#include "cli/command_errors.h"

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
    throw UsageError("--igtl: this heartsim was built without OpenIGTLink, so it cannot stream to 3D Slicer (install "
                     "libopenigtlink-dev, e.g. with scripts/install-deps.sh, and build again with the CMake option "
                     "HEARTSIM_WITH_OPENIGTLINK on, its default)");
}

}  // namespace heartsim

#else

#include "libmodel/mapping.h"

#include <igtlPolyDataMessage.h>
#include <igtlStringMessage.h>
#include <igtlTimeStamp.h>
#include <igtlTransformMessage.h>

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
#include <cstring>
#include <deque>
#include <mutex>
#include <thread>

namespace heartsim {

bool slicer_link_available() { return true; }

namespace {

using Clock = std::chrono::steady_clock;
using Bytes = std::shared_ptr<const std::string>;

/// Between two tries to reach a Slicer server, and the longest a connect may wait for an answer.
constexpr auto reconnect_period = std::chrono::seconds(2);

std::chrono::nanoseconds seconds(double s) { return std::chrono::nanoseconds(std::llround(s * 1e9)); }

/// A packed message's bytes (header and body), to be shared by every client's outbox.
Bytes packed(igtl::MessageBase* message) {
    return std::make_shared<const std::string>(static_cast<const char*>(message->GetPackPointer()), std::size_t(message->GetPackSize()));
}

void stamp(igtl::MessageBase* message) {
    igtl::TimeStamp::Pointer now = igtl::TimeStamp::New();
    now->GetTime();
    message->SetTimeStamp(now);
}

Bytes string_message(const char* device, const std::string& text) {
    igtl::StringMessage::Pointer message = igtl::StringMessage::New();
    message->SetDeviceName(device);
    message->SetEncoding(3);  // IANA 3: US-ASCII
    message->SetString(text.c_str());
    stamp(message);
    message->Pack();
    return packed(message);
}

/// The 4×4 tool → world matrix of `pose`, LPS mm.
Bytes transform_message(const char* device, const InstrumentPose& pose) {
    igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
    message->SetDeviceName(device);
    const Eigen::Matrix3d rotation = pose.orientation.normalized().toRotationMatrix();
    igtl::Matrix4x4 matrix;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) matrix[r][c] = float(rotation(r, c));
        matrix[r][3] = float(pose.position[r]);
    }
    matrix[3][0] = matrix[3][1] = matrix[3][2] = 0.0f;
    matrix[3][3] = 1.0f;
    message->SetMatrix(matrix);
    stamp(message);
    message->Pack();
    return packed(message);
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

/// "PORT" or "HOST:PORT"; UsageError otherwise.
struct Endpoint {
    std::string host;  ///< empty: listen
    int port = 0;
};

Endpoint parse_endpoint(const std::string& text) {
    const std::string usage = "--igtl '" + text +
                              "': expected PORT (heartsim listens there, e.g. --igtl 18944) or HOST:PORT (heartsim connects to a "
                              "Slicer server there, e.g. --igtl localhost:18944), the port from 1 to 65535";
    Endpoint endpoint;
    const auto colon = text.rfind(':');
    const std::string port = colon == std::string::npos ? text : text.substr(colon + 1);
    if (colon != std::string::npos) endpoint.host = text.substr(0, colon);
    if (colon != std::string::npos && endpoint.host.empty()) throw UsageError(usage);
    if (port.empty() || port.size() > 5 || !std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; }))
        throw UsageError(usage);
    endpoint.port = std::stoi(port);
    if (endpoint.port < 1 || endpoint.port > 65535) throw UsageError(usage);
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

class IgtlLink final : public SlicerLink {
public:
    IgtlLink(const SlicerLinkOptions& options, Endpoint endpoint) : options_(options), endpoint_(std::move(endpoint)) {
        if (!(options_.pose_rate_hz > 0) || !(options_.mesh_rate_hz > 0))
            throw UsageError("--igtl-mesh-rate: expected a rate above 0 Hz");
        if (endpoint_.host.empty()) listen_now();
    }
    ~IgtlLink() override {
        stop();
        if (listen_fd_ >= 0) ::close(listen_fd_);
    }

    void start(const Scenario& scenario) override {
        prepare_mesh(scenario);
        thread_ = std::thread([this] { run(); });
        const std::string streams = "heartsim-heart (" + std::to_string(triangles_) + " triangles, " + mesh_source_ + ") at up to " +
                                    rate(options_.mesh_rate_hz) + " when it moves, heartsim-hand0/1, -state, -force0/1 at up to " +
                                    rate(options_.pose_rate_hz) + "; LPS mm";
        if (endpoint_.host.empty())
            say("igtl: listening on port %d (every interface) for 3D Slicer (OpenIGTLinkIF, client); %s\n", endpoint_.port, streams.c_str());
        else
            say("igtl: connecting to a 3D Slicer server at %s:%d (OpenIGTLinkIF, server); %s\n", endpoint_.host.c_str(), endpoint_.port,
                streams.c_str());
        if (options_.wait_s > 0) {
            say("igtl: waiting up to %g s for %s before the first step\n", options_.wait_s,
                endpoint_.host.empty() ? "a client" : "the connection");
            const auto until = Clock::now() + seconds(options_.wait_s);
            while (clients_.load() == 0 && Clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(5));
            if (clients_.load() == 0) say("igtl: none after %g s: starting; Slicer can connect at any time\n", options_.wait_s);
        }
    }

    bool due() const override { return clients_.load(std::memory_order_relaxed) > 0 && Clock::now() >= next_pose_; }

    void offer(Backend& backend, long long steps, const SlicerLinkHands& hands, State state) override {
        if (!due()) return;
        const auto now = Clock::now();
        next_pose_ = std::max(next_pose_ + seconds(1.0 / options_.pose_rate_hz), now);
        Frame frame{.time_ms = backend.simulated_time_ms(), .steps = steps, .state = state, .hands = hands, .positions = nullptr, .final = false};
        if (now >= next_mesh_ || mesh_wanted_.exchange(false)) {
            // The only wait the simulation takes (gl: the positions read back), and only while
            // someone is connected, at most mesh_rate_hz times a second.
            frame.positions = std::make_shared<const std::vector<std::array<float, 3>>>(backend.positions());
            next_mesh_ = std::max(next_mesh_ + seconds(1.0 / options_.mesh_rate_hz), now);
        }
        post(std::move(frame));
    }

    void offer(double time_ms, const std::vector<std::array<float, 3>>& positions, long long steps, const SlicerLinkHands& hands,
               State state) override {
        if (!due()) return;
        const auto now = Clock::now();
        next_pose_ = std::max(next_pose_ + seconds(1.0 / options_.pose_rate_hz), now);
        Frame frame{.time_ms = time_ms, .steps = steps, .state = state, .hands = hands, .positions = nullptr, .final = false};
        if (!positions.empty() && (now >= next_mesh_ || mesh_wanted_.exchange(false))) {
            frame.positions = std::make_shared<const std::vector<std::array<float, 3>>>(positions);
            next_mesh_ = std::max(next_mesh_ + seconds(1.0 / options_.mesh_rate_hz), now);
        }
        post(std::move(frame));
    }

    void finish(Backend& backend, long long steps, const SlicerLinkHands& hands) override {
        if (!thread_.joinable()) return;
        if (clients_.load() > 0) {
            Frame frame{.time_ms = backend.simulated_time_ms(), .steps = steps, .state = State::finished, .hands = hands, .positions = nullptr, .final = false};
            frame.positions = std::make_shared<const std::vector<std::array<float, 3>>>(backend.positions());
            frame.final = true;
            finishing_.store(true);
            post(std::move(frame));
            // Until every client has the final state and has closed (or finish_s has passed).
            const auto until = Clock::now() + seconds(options_.finish_s);
            while (clients_.load() > 0 && Clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        stop();
    }

private:
    struct Frame {
        double time_ms = 0.0;
        long long steps = 0;
        State state = State::running;
        SlicerLinkHands hands{};
        std::shared_ptr<const std::vector<std::array<float, 3>>> positions;  ///< null: the mesh is not due
        bool final = false;
    };
    struct Client {
        int fd = -1;
        std::string name;
        std::deque<Bytes> outbox;  ///< at most one frame (two with the final one): newer frames are skipped meanwhile
        std::size_t sent = 0;      ///< bytes of outbox.front() already sent
        Clock::time_point last_progress = Clock::now();
        std::uint64_t mesh_version = 0;  ///< the mesh it has
        bool closing = false;            ///< final state queued: shut down once sent
        bool shut = false;               ///< everything sent and shut down for writing: waiting for its close
        std::string gone;                ///< why it is dropped; empty while connected
    };

    static std::string rate(double hz) {
        char text[32];
        std::snprintf(text, sizeof text, "%g Hz", hz);
        return text;
    }

    void listen_now() {
        const std::string option = "--igtl " + std::to_string(endpoint_.port);
        listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (listen_fd_ < 0) throw UsageError(option + ": cannot open a socket: " + std::strerror(errno));
        // A port a heartsim closed a moment ago (TIME_WAIT) is free to take again; one that a program
        // listens on is not (Linux refuses the bind either way).
        int on = 1;
        ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
        sockaddr_in address{};
        address.sin_family = AF_INET;
        address.sin_addr.s_addr = htonl(INADDR_ANY);
        address.sin_port = htons(std::uint16_t(endpoint_.port));
        if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || ::listen(listen_fd_, 4) != 0) {
            const int error = errno;
            ::close(listen_fd_);
            listen_fd_ = -1;
            if (error == EADDRINUSE)
                throw UsageError(option + ": port " + std::to_string(endpoint_.port) +
                                 " is in use by another program (another heartsim, or a Slicer connector in server mode?); give a "
                                 "free one, e.g. --igtl " + std::to_string(endpoint_.port < 65535 ? endpoint_.port + 1 : 18944));
            if (error == EACCES)
                throw UsageError(option + ": ports below 1024 need privileges; give one from 1024 to 65535 (Slicer's default is 18944)");
            throw UsageError(option + ": cannot listen on port " + std::to_string(endpoint_.port) + ": " + std::strerror(error));
        }
        set_non_blocking(listen_fd_);
    }

    /// The mesh Slicer shows, as the renderer draws it: the detailed mesh through the mapping, or
    /// the simulation surface (its particles only, renumbered).
    void prepare_mesh(const Scenario& scenario) {
        scenario_ = &scenario;
        const std::vector<std::array<std::int32_t, 3>>* triangles = nullptr;
        if (scenario.visual && scenario.mapping && scenario.simulation_surface) {
            triangles = &scenario.visual->triangles;
            mesh_source_ = "the detailed mesh";
        } else if (scenario.simulation_surface) {
            triangles = &scenario.simulation_surface->triangles;
            mesh_source_ = "the simulation surface";
            std::vector<std::int32_t> renumbered(scenario.lattice.particles.rest_position.size(), -1);
            for (const auto& t : *triangles)
                for (std::int32_t i : t)
                    if (renumbered[std::size_t(i)] < 0) renumbered[std::size_t(i)] = std::int32_t(surface_particles_.size()), surface_particles_.push_back(i);
            renumber_ = std::move(renumbered);
        } else {
            mesh_source_ = "no surface in the scenario";
        }
        polydata_ = igtl::PolyDataMessage::New();
        polydata_->SetDeviceName("heartsim-heart");
        points_ = igtl::PolyDataPointArray::New();
        polydata_->SetPoints(points_);
        if (triangles) {
            igtl::PolyDataCellArray::Pointer polygons = igtl::PolyDataCellArray::New();
            for (const auto& t : *triangles) {
                igtlUint32 cell[3];
                for (int k = 0; k < 3; ++k) cell[k] = igtlUint32(renumber_.empty() ? t[std::size_t(k)] : renumber_[std::size_t(t[std::size_t(k)])]);
                polygons->AddCell(3, cell);
            }
            polydata_->SetPolygons(polygons);
            triangles_ = triangles->size();
        }
    }

    /// The POLYDATA of `positions` (packed particles, mm), or null when they did not move.
    Bytes mesh_message(const std::vector<std::array<float, 3>>& positions) {
        if (triangles_ == 0 || positions == last_positions_) return nullptr;
        last_positions_ = positions;
        if (renumber_.empty()) {
            // The detailed mesh as drawn and as --save-state writes /visual/positions.
            const auto visual = apply_mapping(*scenario_->mapping, positions, *scenario_->simulation_surface);
            points_->SetNumberOfPoints(int(visual.size()));
            for (std::size_t v = 0; v < visual.size(); ++v) points_->SetPoint(unsigned(v), visual[v].x(), visual[v].y(), visual[v].z());
        } else {
            points_->SetNumberOfPoints(int(surface_particles_.size()));
            for (std::size_t v = 0; v < surface_particles_.size(); ++v) {
                const auto& p = positions[std::size_t(surface_particles_[v])];
                points_->SetPoint(unsigned(v), p[0], p[1], p[2]);
            }
        }
        stamp(polydata_);
        polydata_->Pack();
        return packed(polydata_);
    }

    void post(Frame frame) {
        std::lock_guard lock(mailbox_mutex_);
        // A final frame is never replaced; otherwise the newest replaces what the sender has not taken.
        if (mailbox_ && mailbox_->final) return;
        if (mailbox_ && !frame.positions) frame.positions = std::move(mailbox_->positions);  // keep a pending mesh
        mailbox_ = std::move(frame);
    }

    void stop() {
        stop_.store(true);
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
        clients_.store(int(clients_list_.size()));
        mesh_wanted_.store(true);  // a newcomer gets the mesh at once, moved or not
    }

    /// The mailbox's frame, if any, into the outbox of every client that has room.
    void take_frame() {
        std::optional<Frame> frame;
        {
            std::lock_guard lock(mailbox_mutex_);
            frame.swap(mailbox_);
        }
        if (!frame) return;
        // The mesh is made (mapping, encoding) only when a client can take it now: a client that
        // is not reading costs no work.
        if (frame->positions) pending_positions_ = std::move(frame->positions);
        const bool someone_ready = std::any_of(clients_list_.begin(), clients_list_.end(), [](const Client& c) {
            return c.gone.empty() && c.outbox.empty() && !c.closing && !c.shut;
        });
        if (pending_positions_ && (someone_ready || frame->final)) {
            if (Bytes mesh = mesh_message(*pending_positions_)) mesh_ = std::move(mesh), ++mesh_version_;
            pending_positions_.reset();
        }
        // state, hands, forces: one buffer shared by the clients
        std::string bytes;
        char text[256];
        std::snprintf(text, sizeof text, "%s time_ms=%.17g steps=%lld", state_name(frame->state), frame->time_ms, frame->steps);
        bytes += *string_message("heartsim-state", text);
        for (int hand = 0; hand < 2; ++hand) {
            const SlicerLinkHand& h = frame->hands[std::size_t(hand)];
            if (!h.used) continue;
            bytes += *transform_message(hand == 0 ? "heartsim-hand0" : "heartsim-hand1", h.pose);
            std::snprintf(text, sizeof text, "force_n=%.6g,%.6g,%.6g magnitude_n=%.6g particles=%zu kind=%s", h.force_n.x(), h.force_n.y(),
                          h.force_n.z(), h.force_n.norm(), h.particles, to_string(h.kind));
            bytes += *string_message(hand == 0 ? "heartsim-force0" : "heartsim-force1", text);
        }
        const Bytes shared = std::make_shared<const std::string>(std::move(bytes));
        for (Client& client : clients_list_) {
            if (!client.gone.empty() || client.closing || client.shut) continue;
            if (!client.outbox.empty() && !frame->final) continue;  // still busy with an older frame: this one is skipped
            if (client.outbox.empty()) client.last_progress = Clock::now();
            client.outbox.push_back(shared);
            if (mesh_ && client.mesh_version < mesh_version_) client.outbox.push_back(mesh_), client.mesh_version = mesh_version_;
            client.closing = frame->final;
        }
    }

    /// One poll of every socket (≤ 5 ms): new clients, bytes out, bytes in (discarded), closes.
    void exchange() {
        std::vector<pollfd> fds;
        if (listen_fd_ >= 0) fds.push_back({listen_fd_, POLLIN, 0});
        const std::size_t first_client = fds.size();
        for (const Client& client : clients_list_) fds.push_back({client.fd, short(POLLIN | (client.outbox.empty() ? 0 : POLLOUT)), 0});
        if (::poll(fds.data(), nfds_t(fds.size()), 5) < 0) return;
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
            while (client.gone.empty() && !client.outbox.empty()) {
                const std::string& front = *client.outbox.front();
                const ssize_t n = ::send(client.fd, front.data() + client.sent, front.size() - client.sent, MSG_NOSIGNAL | MSG_DONTWAIT);
                if (n < 0) {
                    if (errno != EAGAIN && errno != EWOULDBLOCK) client.gone = std::string("dropped: ") + std::strerror(errno);
                    break;
                }
                client.sent += std::size_t(n);
                client.last_progress = Clock::now();
                if (client.sent == front.size()) client.outbox.pop_front(), client.sent = 0;
            }
            if (client.gone.empty() && client.closing && client.outbox.empty()) {
                // All sent: say so with a FIN and wait for the client to close (or finish_s).
                ::shutdown(client.fd, SHUT_WR);
                client.closing = false;
                client.shut = true;
            }
            if (client.gone.empty() && !client.outbox.empty() && Clock::now() - client.last_progress > seconds(options_.stall_s)) {
                char text[96];
                std::snprintf(text, sizeof text, "took nothing for %g s (not reading): dropped, the simulation goes on", options_.stall_s);
                client.gone = text;
            }
        }
        if (listen_fd_ >= 0 && (fds[0].revents & POLLIN))
            for (int fd; (fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC)) >= 0;) {
                add_client(fd, peer_name(fd));
                say("igtl: %s connected\n", clients_list_.back().name.c_str());
            }
    }

    SlicerLinkOptions options_;
    Endpoint endpoint_;
    int listen_fd_ = -1;
    std::thread thread_;
    std::atomic<bool> stop_{false};
    std::atomic<int> clients_{0};
    std::atomic<bool> mesh_wanted_{false};
    std::atomic<bool> finishing_{false};  ///< the final state is on its way: no new connection
    // the thread that steps
    Clock::time_point next_pose_{}, next_mesh_{};
    // the mailbox: one slot
    std::mutex mailbox_mutex_;
    std::optional<Frame> mailbox_;
    // the sender thread
    std::vector<Client> clients_list_;
    const Scenario* scenario_ = nullptr;
    std::string mesh_source_;
    std::size_t triangles_ = 0;
    std::vector<std::int32_t> renumber_, surface_particles_;
    igtl::PolyDataMessage::Pointer polydata_;
    igtl::PolyDataPointArray::Pointer points_;
    std::vector<std::array<float, 3>> last_positions_;
    std::shared_ptr<const std::vector<std::array<float, 3>>> pending_positions_;  ///< offered, not yet made into a mesh
    Bytes mesh_;
    std::uint64_t mesh_version_ = 0;
};

}  // namespace

std::unique_ptr<SlicerLink> SlicerLink::open(const SlicerLinkOptions& options) {
    return std::make_unique<IgtlLink>(options, parse_endpoint(options.endpoint));
}

}  // namespace heartsim

#endif
