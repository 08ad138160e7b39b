// `heartsim run … --igtl`: the live link to 3D Slicer (runtime/link/slicer_link.h), end to end on the
// loopback interface. Two clients receive what Slicer's OpenIGTLinkIF would: one built with the
// OpenIGTLink library, and one written here from the protocol's specification (the 58-byte
// header, CRC64, the TRANSFORM, STRING and POLYDATA bodies), which shares no code with heartsim's
// encoder. The tests check what arrives against the truth: the mesh against the state file the
// same run wrote (opened by an incision, with a repair's patch and stitches), the triangles
// against the scenario, the instruments' poses against the trajectory's keyframes interpolated
// here, in RAS by default. Then what must not disturb a session: a client that never reads, a
// reconnect, a port in use, a server that is not there, an interface that was not asked for.
#include "defect_block_scenario.h"
#include "incision_gesture.h"
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/state.h"
#include "runtime/link/slicer_link.h"

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <future>
#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <thread>

#ifdef HEARTSIM_HAVE_OPENIGTLINK
#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>
#include <igtlPolyDataMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>
#endif

using namespace heartsim;
using test::quoted;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

test::CommandResult run_heartsim(const std::string& arguments) { return test::run_command(std::string(quoted(HEARTSIM_EXE)) + " " + arguments); }

/// The phantom the haptics tests use: 12,000 particles, base anchored, no gravity; the
/// samples' gestures are written for it (--cavity 2).
const fs::path& phantom() { return test::built_phantom("--cavity 2 --anchor-border --gravity 0 0 0 --particles 12000"); }

fs::path sample(const std::string& name) { return fs::path(HEARTSIM_SOURCE_DIR) / "samples" / name; }

/// A TCP port nobody listens on now (the kernel's pick for 127.0.0.1:0).
int free_port() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = 0;
    socklen_t size = sizeof address;
    if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 ||
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &size) != 0)
        throw std::runtime_error("no free port");
    ::close(fd);
    return ntohs(address.sin_port);
}

/// Steps of a run's summary line "ran N steps".
long long steps_ran(const std::string& output) {
    std::smatch m;
    return std::regex_search(output, m, std::regex("ran (\\d+) steps")) ? std::stoll(m[1]) : -1;
}

}  // namespace

// ---- A client from the OpenIGTLink specification (protocol v1/v2), sharing no code with heartsim ----
namespace spec {

/// CRC-64 of the protocol: the ECMA-182 polynomial 0x42F0E1EBA9EA3693, most significant bit first,
/// starting from 0, not inverted.
std::uint64_t crc64(const char* data, std::size_t size) {
    static const std::array<std::uint64_t, 256> table = [] {
        std::array<std::uint64_t, 256> t{};
        for (std::uint64_t i = 0; i < 256; ++i) {
            std::uint64_t c = i << 56;
            for (int k = 0; k < 8; ++k) c = (c >> 63) ? (c << 1) ^ 0x42F0E1EBA9EA3693ull : c << 1;
            t[i] = c;
        }
        return t;
    }();
    std::uint64_t crc = 0;
    for (std::size_t i = 0; i < size; ++i) crc = table[((crc >> 56) ^ std::uint8_t(data[i])) & 0xff] ^ (crc << 8);
    return crc;
}

/// Big-endian fields, read in order; `ok` false once a read would pass the end.
struct Reader {
    const std::string& bytes;
    std::size_t at = 0;
    bool ok = true;
    std::uint64_t uint(int size) {
        if (at + std::size_t(size) > bytes.size()) return ok = false, 0;
        std::uint64_t v = 0;
        for (int k = 0; k < size; ++k) v = (v << 8) | std::uint8_t(bytes[at++]);
        return v;
    }
    float f32() {
        const std::uint32_t v = std::uint32_t(uint(4));
        float f;
        std::memcpy(&f, &v, 4);
        return f;
    }
};

struct Message {
    int version = 0;
    std::string type, device, content;  ///< content: the body without a v2 extended header and metadata
    bool crc_ok = false;
};

/// Reads exactly `size` bytes, waiting at most 60 s for each; false at the end of the stream.
bool read_exactly(int fd, char* out, std::size_t size) {
    while (size > 0) {
        pollfd p{fd, POLLIN, 0};
        if (::poll(&p, 1, 60000) <= 0) return false;
        const ssize_t n = ::recv(fd, out, size, 0);
        if (n <= 0) return false;
        out += n, size -= std::size_t(n);
    }
    return true;
}

/// The next message: the 58-byte header (version u16, type char[12], device name char[20], time
/// stamp u64, body size u64, CRC64 u64), then the body it announces.
std::optional<Message> next(int fd) {
    std::string header(58, '\0');
    if (!read_exactly(fd, header.data(), header.size())) return std::nullopt;
    Reader h{header};
    Message m;
    m.version = int(h.uint(2));
    auto text = [&](std::size_t at, std::size_t size) {
        const std::string field = header.substr(at, size);
        return field.substr(0, field.find('\0'));
    };
    m.type = text(2, 12), m.device = text(14, 20);
    h.at = 42;
    const std::uint64_t body_size = h.uint(8), crc = h.uint(8);
    if (body_size > (1u << 30)) return std::nullopt;
    std::string body(body_size, '\0');
    if (!read_exactly(fd, body.data(), body.size())) return std::nullopt;
    m.crc_ok = crc64(body.data(), body.size()) == crc;
    m.content = body;
    if (m.version == 2) {  // extended header: its size u16, metadata header size u16, metadata size u32, message id u32
        Reader e{body};
        const std::size_t extended = e.uint(2), meta_header = e.uint(2), meta = e.uint(4);
        if (e.ok && extended + meta_header + meta <= body.size()) m.content = body.substr(extended, body.size() - extended - meta_header - meta);
    }
    return m;
}

struct PolyData {
    std::vector<std::array<float, 3>> points;
    std::vector<std::vector<std::uint32_t>> vertices, lines, polygons, strips;
    bool ok = false;  ///< every count and size agreed with the bytes
};

/// POLYDATA: the counts (points; vertices, lines, polygons, strips: each cells and bytes;
/// attributes), the points (float32 × 3), then each cell array as (N, i1 … iN) in u32.
PolyData polydata(const std::string& body) {
    Reader r{body};
    PolyData d;
    const std::uint64_t npoints = r.uint(4);
    std::array<std::uint64_t, 4> cells{}, sizes{};
    for (int k = 0; k < 4; ++k) cells[std::size_t(k)] = r.uint(4), sizes[std::size_t(k)] = r.uint(4);
    r.uint(4);  // attributes: none expected (read past)
    if (!r.ok || 40 + 12 * npoints > body.size()) return d;
    d.points.resize(npoints);
    for (auto& p : d.points)
        for (float& x : p) x = r.f32();
    std::array<std::vector<std::vector<std::uint32_t>>*, 4> arrays = {&d.vertices, &d.lines, &d.polygons, &d.strips};
    bool ok = true;
    for (int k = 0; k < 4; ++k) {
        const std::size_t end = r.at + sizes[std::size_t(k)];
        for (std::uint64_t c = 0; c < cells[std::size_t(k)]; ++c) {
            const std::uint64_t n = r.uint(4);
            std::vector<std::uint32_t> cell;
            for (std::uint64_t i = 0; i < n && r.ok; ++i) {
                cell.push_back(std::uint32_t(r.uint(4)));
                ok = ok && cell.back() < npoints;
            }
            arrays[std::size_t(k)]->push_back(std::move(cell));
        }
        ok = ok && r.at == end;
    }
    d.ok = ok && r.ok;
    return d;
}

/// TRANSFORM: R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ (float32): the 4×4 matrix, row major.
std::optional<std::array<std::array<double, 4>, 4>> transform(const std::string& body) {
    if (body.size() != 48) return std::nullopt;
    Reader r{body};
    std::array<std::array<double, 4>, 4> m{};
    for (int c = 0; c < 4; ++c)
        for (int row = 0; row < 3; ++row) m[std::size_t(row)][std::size_t(c)] = r.f32();
    m[3] = {0, 0, 0, 1};
    return m;
}

/// STRING: encoding u16, length u16, the bytes.
std::string string(const std::string& body) {
    Reader r{body};
    r.uint(2);
    const std::size_t length = r.uint(2);
    return r.ok && 4 + length <= body.size() ? body.substr(4, length) : std::string();
}

/// What a client received: the last POLYDATA of each device, counts, states and poses in order.
struct Stream {
    struct Pose {
        double time_ms;  ///< the simulated time of the heartsim-state before it
        int hand;
        std::array<std::array<double, 4>, 4> matrix;
    };
    std::vector<std::string> states;
    std::vector<Pose> poses;
    std::map<std::string, PolyData> last;
    std::map<std::string, std::size_t> polydata_count;
    std::size_t bad_crc = 0, malformed = 0;
    bool ended = false;
};

/// Receives until the server closes (or `enough`), from a socket connected to heartsim.
void receive(int fd, Stream& s, const std::function<bool(const Stream&)>& enough = {}) {
    double time_ms = -1.0;
    while (!(enough && enough(s))) {
        const std::optional<Message> m = next(fd);
        if (!m) return void(s.ended = true);
        if (!m->crc_ok) {
            ++s.bad_crc;
            continue;
        }
        if (m->type == "STRING" && m->device == "heartsim-state") {
            s.states.push_back(string(m->content));
            std::smatch match;
            if (std::regex_search(s.states.back(), match, std::regex("time_ms=([^ ]+)"))) time_ms = std::stod(match[1]);
        } else if (m->type == "TRANSFORM") {
            const auto matrix = transform(m->content);
            if (!matrix) ++s.malformed;
            else s.poses.push_back({time_ms, m->device == "heartsim-hand1" ? 1 : 0, *matrix});
        } else if (m->type == "POLYDATA") {
            PolyData d = polydata(m->content);
            if (!d.ok) ++s.malformed;
            ++s.polydata_count[m->device];
            s.last[m->device] = std::move(d);
        }
    }
}

/// A socket connected to 127.0.0.1:`port`, trying for up to 60 s (heartsim is starting); -1 if none.
int connect_to(int port, const char* address = "127.0.0.1") {
    for (const auto until = Clock::now() + std::chrono::seconds(60); Clock::now() < until;) {
        const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(std::uint16_t(port));
        ::inet_pton(AF_INET, address, &a.sin_addr);
        if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0) return fd;
        ::close(fd);
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return -1;
}

/// Runs `command` (heartsim with --igtl PORT --igtl-wait) beside this client, to the stream's end.
Stream received_from(const std::string& command, int port, test::CommandResult& result) {
    auto run = std::async(std::launch::async, [&] { return test::run_command(command); });
    Stream s;
    const int fd = connect_to(port);
    if (fd >= 0) receive(fd, s), ::close(fd);
    result = run.get();
    EXPECT_GE(fd, 0) << "no connection to port " << port << "\n" << result.output;
    return s;
}

/// heartsim's LPS point in RAS: x and y negated.
std::array<float, 3> ras(const std::array<float, 3>& p) { return {-p[0], -p[1], p[2]}; }

}  // namespace spec

TEST(Igtl, WithoutTheLibraryTheOptionIsRefused) {
    if (slicer_link_available()) GTEST_SKIP() << "built with OpenIGTLink: the option is accepted (the other tests)";
    const auto run = run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --steps 1 --igtl 18944");
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("built without OpenIGTLink"), std::string::npos) << run.output;
}

#ifdef HEARTSIM_HAVE_OPENIGTLINK

namespace {

/// What a client received, in order.
struct Received {
    struct Pose {
        double time_ms;  ///< the simulated time of the heartsim-state before it
        int hand;
        igtl::Matrix4x4 matrix;
    };
    std::vector<Pose> poses;
    std::vector<std::string> states, forces;
    std::size_t meshes = 0;
    std::vector<std::array<float, 3>> mesh_points;             ///< the last POLYDATA's points
    std::vector<std::array<std::uint32_t, 3>> mesh_triangles;  ///< and its polygons (each checked to be a triangle)
    std::size_t non_triangles = 0, lines = 0, bad_crc = 0;
    bool ended = false;  ///< the server closed the connection
};

/// Connects to 127.0.0.1:`port`, trying for up to 60 s (heartsim is starting).
igtl::ClientSocket::Pointer connect_to(int port) {
    const auto until = Clock::now() + std::chrono::seconds(60);
    while (Clock::now() < until) {
        igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
        if (socket->ConnectToServer("127.0.0.1", port) == 0) {
            socket->SetReceiveTimeout(60000);  // a test that waits, waits in bounded time
            return socket;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(100));  // the library says each failure on stderr
    }
    return nullptr;
}

/// Reads messages until the server closes, or until `enough` says so.
void receive(igtl::Socket* socket, Received& r, const std::function<bool(const Received&)>& enough = {}) {
    double time_ms = -1.0;
    while (!(enough && enough(r))) {
        igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
        header->InitPack();
        if (socket->Receive(header->GetPackPointer(), header->GetPackSize()) != header->GetPackSize()) {
            r.ended = true;
            return;
        }
        header->Unpack();
        const std::string type = header->GetDeviceType(), name = header->GetDeviceName();
        igtl::MessageBase::Pointer body;
        igtl::TransformMessage::Pointer transform;
        igtl::StringMessage::Pointer text;
        igtl::PolyDataMessage::Pointer poly;
        if (type == "TRANSFORM") body = transform = igtl::TransformMessage::New();
        else if (type == "STRING") body = text = igtl::StringMessage::New();
        else if (type == "POLYDATA") body = poly = igtl::PolyDataMessage::New();
        if (!body) {
            ADD_FAILURE() << "unexpected message type " << type << " (" << name << ")";
            socket->Skip(int(header->GetBodySizeToRead()), 0);
            continue;
        }
        body->SetMessageHeader(header);
        body->AllocatePack();
        if (socket->Receive(body->GetPackBodyPointer(), body->GetPackBodySize()) != body->GetPackBodySize()) {
            r.ended = true;
            return;
        }
        if (!(body->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
            ++r.bad_crc;
            continue;
        }
        if (text && name == "heartsim-state") {
            r.states.push_back(text->GetString());
            std::smatch m;
            if (std::regex_search(r.states.back(), m, std::regex("time_ms=([^ ]+)"))) time_ms = std::stod(m[1]);
        } else if (text) {
            r.forces.push_back(name + " " + text->GetString());
        } else if (transform) {
            Received::Pose pose{time_ms, name == "heartsim-hand1" ? 1 : 0, {}};
            transform->GetMatrix(pose.matrix);
            EXPECT_TRUE(name == "heartsim-hand0" || name == "heartsim-hand1") << name;
            r.poses.push_back(pose);
        } else if (poly) {
            EXPECT_EQ(name, "heartsim-heart");
            ++r.meshes;
            igtl::PolyDataPointArray::Pointer points = poly->GetPoints();
            r.mesh_points.resize(std::size_t(points->GetNumberOfPoints()));
            for (std::size_t i = 0; i < r.mesh_points.size(); ++i) points->GetPoint(unsigned(i), r.mesh_points[i].data());
            r.mesh_triangles.clear();
            igtl::PolyDataCellArray::Pointer polygons = poly->GetPolygons();
            const unsigned cells = polygons.IsNotNull() ? polygons->GetNumberOfCells() : 0;
            for (unsigned c = 0; c < cells; ++c) {
                if (polygons->GetCellSize(c) != 3) {
                    ++r.non_triangles;
                    continue;
                }
                std::array<std::uint32_t, 3> t{};
                polygons->GetCell(c, t.data());
                r.mesh_triangles.push_back(t);
            }
            if (poly->GetLines()) r.lines += poly->GetLines()->GetNumberOfCells();
        }
    }
}

/// The trajectory CSV's keyframes per hand (time, position), read here independently of heartsim.
std::map<int, std::vector<std::pair<double, Eigen::Vector3d>>> keyframes(const fs::path& csv) {
    std::map<int, std::vector<std::pair<double, Eigen::Vector3d>>> hands;
    std::ifstream in(csv);
    for (std::string line; std::getline(in, line);) {
        if (line.empty() || line[0] == '#' || line.rfind("time_ms", 0) == 0) continue;
        std::stringstream fields(line);
        std::vector<std::string> f;
        for (std::string field; std::getline(fields, field, ',');) f.push_back(field);
        hands[std::stoi(f[1])].push_back({std::stod(f[0]), {std::stod(f[3]), std::stod(f[4]), std::stod(f[5])}});
    }
    return hands;
}

/// Linear between keyframes, held outside them.
Eigen::Vector3d position_at(const std::vector<std::pair<double, Eigen::Vector3d>>& k, double t) {
    if (t <= k.front().first) return k.front().second;
    for (std::size_t i = 1; i < k.size(); ++i)
        if (t <= k[i].first) return k[i - 1].second + (t - k[i - 1].first) / (k[i].first - k[i - 1].first) * (k[i].second - k[i - 1].second);
    return k.back().second;
}

}  // namespace

/// Runs `command` (a shell command line starting heartsim with --igtl PORT --igtl-wait) beside a
/// client that connects to `port` and receives until the stream ends; `result` is the run's.
Received received_from(const std::string& command, int port, test::CommandResult& result) {
    auto run = std::async(std::launch::async, [&] { return test::run_command(command); });
    Received r;
    igtl::ClientSocket::Pointer socket = connect_to(port);
    if (socket) {
        receive(socket, r);
        socket->CloseSocket();
    }
    result = run.get();
    EXPECT_TRUE(socket) << "no connection to port " << port << "\n" << result.output;
    return r;
}

// In LPS on request (--igtl-frame lps), read with the OpenIGTLink library as Slicer reads it.
TEST(Igtl, LoopbackRoundTripMatchesTheSavedStateAndTheTrajectory) {
    test::TempDir dir;
    const int port = free_port();
    const fs::path trajectory = sample("probe_and_grab_phantom.csv");
    // --igtl-wait: the run starts when this client is connected, so it sees the run from its start.
    test::CommandResult result;
    const Received r = received_from(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                         " --headless --backend cpu --seconds 0.5 --trajectory " + quoted(trajectory) + " --igtl " +
                                         std::to_string(port) + " --igtl-frame lps --igtl-wait 60 --save-state " + quoted(dir / "s.h5"),
                                     port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("igtl: 127.0.0.1:"), std::string::npos) << result.output;
    EXPECT_EQ(result.output.find("nothing was sent"), std::string::npos) << result.output;
    EXPECT_TRUE(r.ended);
    EXPECT_EQ(r.bad_crc, 0u);

    // The state: running, then finished at the run's last step.
    const SimulationState state = read_state(dir / "s.h5");
    ASSERT_FALSE(r.states.empty());
    EXPECT_EQ(r.states.front().rfind("running ", 0), 0u) << r.states.front();
    EXPECT_EQ(r.states.back().rfind("finished ", 0), 0u) << r.states.back();
    EXPECT_NE(r.states.back().find("steps=" + std::to_string(state.steps) + " frame=LPS"), std::string::npos) << r.states.back();
    std::printf("received %zu states, %zu poses, %zu meshes, %zu force lines; last state '%s'\n", r.states.size(), r.poses.size(), r.meshes,
                r.forces.size(), r.states.back().c_str());

    // The mesh: the detailed mesh with the scenario's triangles, real polygons, at the final
    // positions exactly as --save-state wrote /visual/positions.
    const Scenario scenario = read_scenario(phantom());
    ASSERT_TRUE(scenario.visual);
    ASSERT_GE(r.meshes, 1u);
    EXPECT_EQ(r.non_triangles, 0u);
    EXPECT_EQ(r.lines, 0u);
    ASSERT_EQ(r.mesh_triangles.size(), scenario.visual->triangles.size());
    for (std::size_t t = 0; t < r.mesh_triangles.size(); ++t)
        for (int k = 0; k < 3; ++k) ASSERT_EQ(r.mesh_triangles[t][k], std::uint32_t(scenario.visual->triangles[t][k])) << "triangle " << t;
    ASSERT_EQ(r.mesh_points.size(), state.visual_positions.size());
    double error = 0.0, moved = 0.0;
    for (std::size_t v = 0; v < r.mesh_points.size(); ++v)
        for (int k = 0; k < 3; ++k) {
            error = std::max(error, double(std::abs(r.mesh_points[v][k] - state.visual_positions[v][k])));
            moved = std::max(moved, double(std::abs(r.mesh_points[v][k] - scenario.visual->positions[v][k])));
        }
    std::printf("last mesh against /visual/positions: max %.3g mm (the mesh moved up to %.3f mm)\n", error, moved);
    EXPECT_LE(error, 1e-5);
    EXPECT_GT(moved, 1.0);

    // The poses: the trajectory's at the simulated time of each frame (float32, mm), both hands.
    const auto expected = keyframes(trajectory);
    std::size_t per_hand[2] = {0, 0};
    double pose_error = 0.0, rotation_error = 0.0;
    for (const auto& pose : r.poses) {
        ASSERT_GE(pose.time_ms, 0.0);
        ++per_hand[pose.hand];
        const Eigen::Vector3d want = position_at(expected.at(pose.hand), pose.time_ms);
        for (int k = 0; k < 3; ++k) {
            pose_error = std::max(pose_error, std::abs(double(pose.matrix[k][3]) - want[k]));
            for (int c = 0; c < 3; ++c) rotation_error = std::max(rotation_error, std::abs(double(pose.matrix[k][c]) - (k == c ? 1.0 : 0.0)));
        }
        EXPECT_EQ(pose.matrix[3][3], 1.0f);
    }
    std::printf("%zu + %zu poses against the trajectory: max %.3g mm, rotation %.3g\n", per_hand[0], per_hand[1], pose_error, rotation_error);
    EXPECT_GE(per_hand[0], 2u);
    EXPECT_GE(per_hand[1], 2u);
    EXPECT_LT(pose_error, 1e-4);
    EXPECT_LT(rotation_error, 1e-6);
    // The grabber moves 8 mm over the gesture: the poses sent cover it.
    EXPECT_FALSE(r.forces.empty());
}

TEST(Igtl, AClientThatNeverReadsDoesNotChangeTheRun) {
    test::TempDir dir;
    const std::string common = "run " + quoted(phantom()) + " --headless --backend cpu --seconds 0.5 --trajectory " +
                               quoted(sample("probe_and_grab_phantom.csv"));
    const auto alone = run_heartsim(common + " --save-state " + quoted(dir / "alone.h5"));
    ASSERT_EQ(alone.exit_code, 0) << alone.output;

    const int port = free_port();
    auto run = std::async(std::launch::async, [&] {
        return run_heartsim(common + " --igtl " + std::to_string(port) + " --igtl-wait 60 --save-state " + quoted(dir / "linked.h5"));
    });
    // A client with a tiny receive buffer that never reads a byte.
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    int small = 4096;
    ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons(std::uint16_t(port));
    bool connected = false;
    for (const auto until = Clock::now() + std::chrono::seconds(60); !connected && Clock::now() < until;) {
        connected = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
        if (!connected) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    const auto linked = run.get();
    ::close(fd);
    ASSERT_TRUE(connected) << linked.output;
    ASSERT_EQ(linked.exit_code, 0) << linked.output;
    EXPECT_NE(linked.output.find("connected"), std::string::npos) << linked.output;
    // The same steps over the same simulated time, to the same state bit for bit.
    EXPECT_EQ(steps_ran(linked.output), steps_ran(alone.output)) << linked.output;
    const SimulationState a = read_state(dir / "alone.h5"), b = read_state(dir / "linked.h5");
    EXPECT_EQ(a.steps, b.steps);
    EXPECT_EQ(a.positions, b.positions);
    EXPECT_EQ(a.force_n, b.force_n);
}

TEST(Igtl, AClientThatReconnectsReceivesTheStreamAgain) {
    // A haptic session follows the wall clock: 3 s, whatever the machine's speed.
    const int port = free_port();
    auto run = std::async(std::launch::async, [&] {
        return run_heartsim("run " + quoted(phantom()) + " --headless --backend cpu --device simulated:" +
                            quoted(sample("haptics/press_phantom.csv")) + " --seconds 3 --igtl " + std::to_string(port) + " --igtl-wait 60");
    });
    auto has_mesh_and_pose = [](const Received& r) { return r.meshes >= 1 && !r.poses.empty() && !r.states.empty(); };
    Received first, second;
    {
        igtl::ClientSocket::Pointer socket = connect_to(port);
        ASSERT_TRUE(socket) << run.get().output;
        receive(socket, first, has_mesh_and_pose);
        socket->CloseSocket();  // gone mid-stream
    }
    {
        igtl::ClientSocket::Pointer socket = connect_to(port);
        ASSERT_TRUE(socket) << run.get().output;
        receive(socket, second);  // to the end of the session
        socket->CloseSocket();
    }
    const auto result = run.get();
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_TRUE(has_mesh_and_pose(first));
    EXPECT_TRUE(has_mesh_and_pose(second)) << result.output;
    EXPECT_TRUE(second.ended);
    ASSERT_FALSE(second.states.empty());
    EXPECT_EQ(second.states.back().rfind("finished ", 0), 0u) << second.states.back();
    EXPECT_EQ(second.mesh_triangles.size(), read_scenario(phantom()).visual->triangles.size());
    // Each event one line: two connections, one close, and the session ran to its end.
    std::size_t connects = 0;
    for (std::size_t at = 0; (at = result.output.find(" connected\n", at)) != std::string::npos; ++at) ++connects;
    EXPECT_EQ(connects, 2u) << result.output;
    EXPECT_NE(result.output.find("closed the connection; it can connect again"), std::string::npos) << result.output;
    EXPECT_GT(steps_ran(result.output), 0) << result.output;
}

TEST(Igtl, APortInUseIsOneClearLineAndExit2) {
    const int port = free_port();
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_ANY);
    address.sin_port = htons(std::uint16_t(port));
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
    ASSERT_EQ(::listen(fd, 1), 0);
    // stderr alone: the one line.
    const auto run = test::run_command("(" + std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                       " --headless --backend cpu --steps 1 --igtl " + std::to_string(port) + " 2>&1 >/dev/null)");
    ::close(fd);
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_EQ(run.output, "heartsim: error: --igtl " + std::to_string(port) + ": port " + std::to_string(port) +
                              " is in use by another program (another heartsim, or a Slicer connector in server mode?); give a free "
                              "one, e.g. --igtl " + std::to_string(port + 1) + "\n");
}

TEST(Igtl, AServerThatIsNotThereCostsTheSessionNothing) {
    test::TempDir dir;
    const std::string common = "run " + quoted(phantom()) + " --headless --backend cpu --steps 40 --trajectory " +
                               quoted(sample("probe_and_grab_phantom.csv"));
    const auto alone = run_heartsim(common + " --save-state " + quoted(dir / "alone.h5"));
    const int port = free_port();  // nothing listens there
    const auto linked = run_heartsim(common + " --igtl 127.0.0.1:" + std::to_string(port) + " --save-state " + quoted(dir / "linked.h5"));
    ASSERT_EQ(alone.exit_code, 0) << alone.output;
    ASSERT_EQ(linked.exit_code, 0) << linked.output;
    EXPECT_NE(linked.output.find("igtl: cannot reach 127.0.0.1:" + std::to_string(port) + " (Connection refused); trying again every 2 s"),
              std::string::npos)
        << linked.output;
    // The run's end says that nothing reached Slicer, as does a server no client connected to.
    EXPECT_NE(linked.output.find("igtl: the Slicer server at 127.0.0.1:" + std::to_string(port) + " was never reached during the run: nothing was sent"),
              std::string::npos)
        << linked.output;
    const int listen_port = free_port();
    const auto unheard = run_heartsim(common + " --igtl " + std::to_string(listen_port));
    ASSERT_EQ(unheard.exit_code, 0) << unheard.output;
    EXPECT_NE(unheard.output.find("igtl: no client connected to 127.0.0.1:" + std::to_string(listen_port) + " during the run: nothing was sent"),
              std::string::npos)
        << unheard.output;
    EXPECT_EQ(read_state(dir / "alone.h5").positions, read_state(dir / "linked.h5").positions);
    // A command line that names no endpoint, and --igtl-wait without --igtl: usage errors.
    const auto bad = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl localhost:99999");
    EXPECT_EQ(bad.exit_code, 2) << bad.output;
    EXPECT_NE(bad.output.find("expected PORT"), std::string::npos) << bad.output;
    const auto lone = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl-wait 5");
    EXPECT_EQ(lone.exit_code, 2) << lone.output;
    EXPECT_NE(lone.output.find("it needs --igtl PORT"), std::string::npos) << lone.output;
}

// The scalpel's incision through the phantom's anterior wall (incision_gesture.h), streamed to the
// client written from the specification: the last heart it receives is the opened mesh the run's
// state file holds (its triangles, caps included, and its points), not the uncut one; everything
// in RAS by default: each point is the state's LPS point with x and y negated, each pose is
// diag(−1, −1, 1) times the trajectory's, and the state message says so.
TEST(Igtl, AfterAnIncisionTheLastMeshIsTheOpenedMeshOfTheSavedStateInRas) {
    test::TempDir dir;
    const Scenario scenario = read_scenario(phantom());
    const test::Incision plan = test::anterior_incision(scenario, {.length_mm = 16, .retract = false});
    test::write_trajectory_csv(plan.trajectory, dir / "cut.csv");
    const int port = free_port();
    char seconds[32];
    std::snprintf(seconds, sizeof seconds, "%.3f", 1e-3 * (plan.cut_end_ms + 100.0));
    test::CommandResult result;
    const spec::Stream s = spec::received_from(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                                   " --headless --backend cpu --seconds " + seconds + " --trajectory " + quoted(dir / "cut.csv") +
                                                   " --igtl " + std::to_string(port) + " --igtl-wait 60 --save-state " + quoted(dir / "s.h5"),
                                               port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("incision: the detailed mesh opened"), std::string::npos) << result.output;
    EXPECT_TRUE(s.ended);
    EXPECT_EQ(s.bad_crc, 0u);
    EXPECT_EQ(s.malformed, 0u);
    const SimulationState state = read_state(dir / "s.h5");
    ASSERT_FALSE(state.visual_triangles.empty()) << "the run's mesh did not open";
    ASSERT_GT(state.visual_triangles.size(), scenario.visual->triangles.size());

    ASSERT_TRUE(s.last.count("heartsim-heart"));
    const spec::PolyData& heart = s.last.at("heartsim-heart");
    std::printf("the last of %zu meshes: %zu points, %zu triangles; the saved state's %zu, %zu (uncut %zu, %zu)\n",
                s.polydata_count.at("heartsim-heart"), heart.points.size(), heart.polygons.size(), state.visual_positions.size(),
                state.visual_triangles.size(), scenario.visual->positions.size(), scenario.visual->triangles.size());
    ASSERT_EQ(heart.polygons.size(), state.visual_triangles.size());
    for (std::size_t t = 0; t < heart.polygons.size(); ++t) {
        ASSERT_EQ(heart.polygons[t].size(), 3u) << "polygon " << t;
        for (int k = 0; k < 3; ++k) ASSERT_EQ(heart.polygons[t][std::size_t(k)], std::uint32_t(state.visual_triangles[t][std::size_t(k)])) << "triangle " << t;
    }
    EXPECT_TRUE(heart.lines.empty() && heart.vertices.empty() && heart.strips.empty());
    ASSERT_EQ(heart.points.size(), state.visual_positions.size());
    std::size_t mismatched = 0;
    for (std::size_t v = 0; v < heart.points.size(); ++v) mismatched += heart.points[v] != spec::ras(state.visual_positions[v]);
    EXPECT_EQ(mismatched, 0u) << "points that are not the saved state's with x and y negated";

    ASSERT_FALSE(s.states.empty());
    for (const std::string& line : s.states) EXPECT_NE(line.find(" frame=RAS"), std::string::npos) << line;
    EXPECT_EQ(s.states.back().rfind("finished ", 0), 0u) << s.states.back();
    // The poses: the trajectory's, turned into RAS (positions' x and y negated, rotations' rows too).
    const Trajectory trajectory = read_trajectory(dir / "cut.csv");
    ASSERT_FALSE(s.poses.empty());
    double error = 0.0;
    for (const auto& pose : s.poses) {
        const InstrumentKeyframe k = trajectory.at(pose.hand, pose.time_ms);
        const Eigen::Matrix3d rotation = k.pose.orientation.normalized().toRotationMatrix();
        const double sign[3] = {-1.0, -1.0, 1.0};
        for (int r = 0; r < 3; ++r) {
            error = std::max(error, std::abs(pose.matrix[std::size_t(r)][3] - sign[r] * k.pose.position[r]));
            for (int c = 0; c < 3; ++c) error = std::max(error, std::abs(pose.matrix[std::size_t(r)][std::size_t(c)] - sign[r] * rotation(r, c)));
        }
    }
    std::printf("%zu poses against diag(-1, -1, 1) times the trajectory's: max %.3g\n", s.poses.size(), error);
    EXPECT_LT(error, 1e-4);
}

// plan-repair's closure of the block's VSD (4 stitches) streamed to the client written from the
// specification: the patch arrives as its own POLYDATA (heartsim-patch) and ends as the state file
// holds it (its triangles, its points in RAS), and its stitches (heartsim-stitches) as one line each
// from the stitch's patch vertex to its tissue point, the state's anchors.
TEST(Igtl, ARepairsPatchAndStitchesArriveAsTheStateHoldsThem) {
    test::TempDir dir;
    const fs::path scenario = dir / "vsd.h5", plan = dir / "repair.csv";
    test::defect_block::build_block_scenario(test::defect_block::make_block(), dir / "block.nrrd", scenario, "vsd", 3000);
    const auto planned = run_heartsim("plan-repair " + quoted(scenario) + " -o " + quoted(plan) + " --stitches=4");
    ASSERT_EQ(planned.exit_code, 0) << planned.output;
    double end_ms = 0.0;
    for (const InstrumentKeyframe& k : read_trajectory(plan).keyframes) end_ms = std::max(end_ms, k.time_ms);
    char seconds[32];
    std::snprintf(seconds, sizeof seconds, "%.3f", 1e-3 * end_ms);
    const int port = free_port();
    test::CommandResult result;
    const spec::Stream s = spec::received_from(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(scenario) +
                                                   " --headless --backend cpu --seconds " + seconds + " --trajectory " + quoted(plan) +
                                                   " --igtl " + std::to_string(port) + " --igtl-wait 60 --save-state " + quoted(dir / "s.h5"),
                                               port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_TRUE(s.ended);
    EXPECT_EQ(s.bad_crc, 0u);
    EXPECT_EQ(s.malformed, 0u);
    const SimulationState state = read_state(dir / "s.h5");
    ASSERT_TRUE(state.patch.has_value()) << result.output;
    const PatchState& patch = *state.patch;
    ASSERT_EQ(patch.stitch_vertex.size(), 4u);
    ASSERT_TRUE(s.last.count("heartsim-patch") && s.last.count("heartsim-stitches")) << "no patch or no stitches received";
    const spec::PolyData &sheet = s.last.at("heartsim-patch"), &stitches = s.last.at("heartsim-stitches");
    std::printf("patch: %zu messages, the last %zu points and %zu triangles (the state's %zu, %zu); stitches: %zu lines\n",
                s.polydata_count.at("heartsim-patch"), sheet.points.size(), sheet.polygons.size(), patch.positions.size(),
                patch.triangles.size(), stitches.lines.size());
    ASSERT_EQ(sheet.polygons.size(), patch.triangles.size());
    for (std::size_t t = 0; t < sheet.polygons.size(); ++t)
        EXPECT_EQ(sheet.polygons[t], (std::vector<std::uint32_t>{std::uint32_t(patch.triangles[t][0]), std::uint32_t(patch.triangles[t][1]),
                                                                  std::uint32_t(patch.triangles[t][2])}))
            << "triangle " << t;
    ASSERT_EQ(sheet.points.size(), patch.positions.size());
    for (std::size_t v = 0; v < sheet.points.size(); ++v) EXPECT_EQ(sheet.points[v], spec::ras(patch.positions[v])) << "patch vertex " << v;
    ASSERT_EQ(stitches.lines.size(), patch.stitch_vertex.size());
    for (std::size_t k = 0; k < stitches.lines.size(); ++k) {
        ASSERT_EQ(stitches.lines[k].size(), 2u);
        EXPECT_EQ(stitches.points[stitches.lines[k][0]], spec::ras(patch.positions[std::size_t(patch.stitch_vertex[k])])) << "stitch " << k;
        EXPECT_EQ(stitches.points[stitches.lines[k][1]], spec::ras(patch.stitch_anchor[k])) << "stitch " << k;
    }
    // The heart came too, uncut: the scenario's triangles.
    ASSERT_TRUE(s.last.count("heartsim-heart"));
    EXPECT_EQ(s.last.at("heartsim-heart").polygons.size(), read_scenario(scenario).visual->triangles.size());
}

// Poses go at their rate whatever the meshes cost: the meshes are made on a thread of their own
// and a client's poses go before any mesh not yet begun. At the default rates (poses 60 a second,
// meshes at most 20: three poses a mesh) a client receives at least two poses of a hand for each
// mesh (where meshes held the poses back, one came with each); the counts are what the client
// received over the whole run, not a time.
TEST(Igtl, PosesAreNotHeldBackByTheMeshes) {
    test::TempDir dir;
    const int port = free_port();
    test::CommandResult result;
    const spec::Stream s = spec::received_from(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                                   " --headless --backend cpu --seconds 1 --trajectory " +
                                                   quoted(sample("probe_and_grab_phantom.csv")) + " --igtl " + std::to_string(port) +
                                                   " --igtl-wait 60",
                                               port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_EQ(s.bad_crc, 0u);
    std::size_t hand0 = 0;
    for (const auto& pose : s.poses) hand0 += pose.hand == 0;
    const std::size_t meshes = s.polydata_count.count("heartsim-heart") ? s.polydata_count.at("heartsim-heart") : 0;
    std::printf("%zu poses of hand 0, %zu meshes, %zu states over %lld steps\n", hand0, meshes, s.states.size(), steps_ran(result.output));
    ASSERT_GE(meshes, 2u);
    EXPECT_GE(double(hand0), 2.0 * double(meshes));
}

// heartsim listens on 127.0.0.1 unless --igtl-bind says otherwise: a client on another of this
// machine's addresses (127.0.0.2: the whole 127.0.0.0/8 range is this machine's, and no traffic
// leaves it) is refused while one on 127.0.0.1 is streamed to; with --igtl-bind 0.0.0.0 the other
// address is served too. An address that is not this machine's, or not an address, is refused
// before the run (exit 2), naming the option.
TEST(Igtl, ListensOnLoopbackUnlessAsked) {
    const std::string other = "127.0.0.2";
    const std::string common = " run " + quoted(phantom()) + " --headless --backend cpu --seconds 0.3 --trajectory " +
                               quoted(sample("probe_and_grab_phantom.csv")) + " --igtl-wait 60";
    for (const std::string bind : {"", "0.0.0.0"}) {
        const int port = free_port();
        auto run = std::async(std::launch::async, [&] {
            return test::run_command(std::string(quoted(HEARTSIM_EXE)) + common + " --igtl " + std::to_string(port) +
                                     (bind.empty() ? "" : " --igtl-bind " + bind));
        });
        spec::Stream s;
        const int fd = spec::connect_to(port);
        bool other_served = false;
        if (fd >= 0) {
            spec::receive(fd, s, [](const spec::Stream& r) { return !r.states.empty(); });
            // heartsim is listening (it streams to this client) while the other address is tried.
            const int probe = ::socket(AF_INET, SOCK_STREAM, 0);
            sockaddr_in a{};
            a.sin_family = AF_INET;
            a.sin_port = htons(std::uint16_t(port));
            ::inet_pton(AF_INET, other.c_str(), &a.sin_addr);
            other_served = ::connect(probe, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
            ::close(probe);
            spec::receive(fd, s);
            ::close(fd);
        }
        const auto result = run.get();
        ASSERT_GE(fd, 0) << result.output;
        ASSERT_EQ(result.exit_code, 0) << result.output;
        ASSERT_FALSE(s.states.empty());
        EXPECT_EQ(s.states.back().rfind("finished ", 0), 0u) << "the stream went on after the other address was tried";
        if (bind.empty()) {
            EXPECT_NE(result.output.find("igtl: listening on 127.0.0.1:" + std::to_string(port) + " (this machine only"), std::string::npos)
                << result.output;
            EXPECT_FALSE(other_served) << "a client on " << other << " was let in";
        } else {
            EXPECT_NE(result.output.find("igtl: listening on 0.0.0.0:" + std::to_string(port) + " (every interface)"), std::string::npos)
                << result.output;
            EXPECT_TRUE(other_served) << "a client on " << other << " was refused";
        }
    }
    for (const std::string bind : {"192.0.2.254", "127.0.0", "every"}) {
        const auto bad = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl " + std::to_string(free_port()) + " --igtl-bind " + bind);
        EXPECT_EQ(bad.exit_code, 2) << bad.output;
        EXPECT_NE(bad.output.find("--igtl-bind"), std::string::npos) << bad.output;
    }
    const auto connecting = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl localhost:18944 --igtl-bind 0.0.0.0");
    EXPECT_EQ(connecting.exit_code, 2) << connecting.output;
    EXPECT_NE(connecting.output.find("--igtl-bind sets where heartsim listens"), std::string::npos) << connecting.output;
    for (const std::string option : {"--igtl-bind 0.0.0.0", "--igtl-frame lps"}) {
        const auto alone = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 " + option);
        EXPECT_EQ(alone.exit_code, 2) << alone.output;
        EXPECT_NE(alone.output.find("it needs --igtl PORT"), std::string::npos) << alone.output;
    }
}

#endif

// The window streams too: a scripted window run under Xvfb (cpu backend: the simulation on its
// own thread, the frames offered from the window's latest state) sends the state, the poses and
// the mesh, and its last mesh is the saved state's.
TEST(Igtl, TheWindowStreamsWhatItShows) {
    if (std::system("command -v xvfb-run >/dev/null 2>&1") != 0) GTEST_SKIP() << "xvfb-run absent: no X server for a window";
    test::TempDir dir;
    const int port = free_port();
    const fs::path trajectory = sample("probe_and_grab_phantom.csv");
    test::CommandResult result;
    const Received r = received_from("xvfb-run -a " + std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                         " --backend cpu --size 320x240 --seconds 0.5 --trajectory " + quoted(trajectory) + " --igtl " +
                                         std::to_string(port) + " --igtl-frame lps --igtl-wait 60 --save-state " + quoted(dir / "s.h5") + " 2>&1",
                                     port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_TRUE(r.ended);
    ASSERT_FALSE(r.states.empty());
    EXPECT_EQ(r.states.back().rfind("finished ", 0), 0u) << r.states.back();
    EXPECT_FALSE(r.poses.empty());
    ASSERT_GE(r.meshes, 1u);
    const SimulationState state = read_state(dir / "s.h5");
    ASSERT_EQ(r.mesh_points.size(), state.visual_positions.size());
    double error = 0.0;
    for (std::size_t v = 0; v < r.mesh_points.size(); ++v)
        for (int k = 0; k < 3; ++k) error = std::max(error, double(std::abs(r.mesh_points[v][k] - state.visual_positions[v][k])));
    EXPECT_LE(error, 1e-5) << "the last mesh sent is the saved state's";
}
