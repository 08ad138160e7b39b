// `heartsim run … --igtl`: the live link to 3D Slicer (runtime/slicer_link.h), end to end on the
// loopback interface. A client built with the same OpenIGTLink library as heartsim receives what
// Slicer's OpenIGTLinkIF would, and the test checks it against the truth: the mesh against the
// state file the same run wrote, the triangles against the scenario, the instruments' poses
// against the trajectory's keyframes interpolated here. Then what must not disturb a session: a
// client that never reads, a reconnect, a port in use, a server that is not there.
#include "test_support.h"

#include "formats/scenario.h"
#include "formats/state.h"
#include "runtime/slicer_link.h"

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <fstream>
#include <future>
#include <map>
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

TEST(Igtl, LoopbackRoundTripMatchesTheSavedStateAndTheTrajectory) {
    test::TempDir dir;
    const int port = free_port();
    const fs::path trajectory = sample("probe_and_grab_phantom.csv");
    // --igtl-wait: the run starts when this client is connected, so it sees the run from its start.
    test::CommandResult result;
    const Received r = received_from(std::string(quoted(HEARTSIM_EXE)) + " run " + quoted(phantom()) +
                                         " --headless --backend cpu --seconds 0.5 --trajectory " + quoted(trajectory) + " --igtl " +
                                         std::to_string(port) + " --igtl-wait 60 --save-state " + quoted(dir / "s.h5"),
                                     port, result);
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("igtl: 127.0.0.1:"), std::string::npos) << result.output;
    EXPECT_TRUE(r.ended);
    EXPECT_EQ(r.bad_crc, 0u);

    // The state: running, then finished at the run's last step.
    const SimulationState state = read_state(dir / "s.h5");
    ASSERT_FALSE(r.states.empty());
    EXPECT_EQ(r.states.front().rfind("running ", 0), 0u) << r.states.front();
    EXPECT_EQ(r.states.back().rfind("finished ", 0), 0u) << r.states.back();
    EXPECT_NE(r.states.back().find("steps=" + std::to_string(state.steps)), std::string::npos) << r.states.back();
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
    EXPECT_EQ(read_state(dir / "alone.h5").positions, read_state(dir / "linked.h5").positions);
    // A command line that names no endpoint, and --igtl-wait without --igtl: usage errors.
    const auto bad = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl localhost:99999");
    EXPECT_EQ(bad.exit_code, 2) << bad.output;
    EXPECT_NE(bad.output.find("expected PORT"), std::string::npos) << bad.output;
    const auto lone = run_heartsim("run " + quoted(phantom()) + " --headless --steps 1 --igtl-wait 5");
    EXPECT_EQ(lone.exit_code, 2) << lone.output;
    EXPECT_NE(lone.output.find("it needs --igtl PORT"), std::string::npos) << lone.output;
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
                                         std::to_string(port) + " --igtl-wait 60 --save-state " + quoted(dir / "s.h5") + " 2>&1",
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
