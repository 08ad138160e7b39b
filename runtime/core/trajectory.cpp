// Scripted instruments and the run loop shared by the CLI and the tests. trajectory.h.
#include "runtime/core/trajectory.h"

#include "formats/atomic_file.h"
#include "formats/csv.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <sstream>

namespace heartsim {

namespace {

double number(const std::string& text, const std::string& where) {
    std::size_t used = 0;
    double value = 0;
    try {
        value = std::stod(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (used == 0 || used != text.size() || !std::isfinite(value))  // a long field is shown by its start
        throw InputError(where + ": '" + (text.size() > 40 ? text.substr(0, 40) + "…" : text) + "' is not a finite number");
    return value;
}

InstrumentKind parse_kind(const std::string& text, const std::string& where) {
    if (text == "grab") return InstrumentKind::grabber;
    if (const auto kind = instrument_kind_named(text)) return *kind;
    throw InputError(where + ": kind '" + text + "': expected probe, grabber, retractor, scalpel, patch, needle or none");
}

/// What follows "# view:" on a line that begins with it (blanks before the '#' and the "view:"
/// allowed), trimmed; nullopt for any other line.
std::optional<std::string> view_line(const std::string& line) {
    const auto hash = line.find_first_not_of(" \t");
    if (hash == std::string::npos || line[hash] != '#') return std::nullopt;
    const auto word = line.find_first_not_of(" \t", hash + 1);
    if (word == std::string::npos || line.compare(word, 5, "view:") != 0) return std::nullopt;
    const auto begin = line.find_first_not_of(" \t", word + 5), end = line.find_last_not_of(" \t\r");
    return begin == std::string::npos || end < begin ? std::string() : line.substr(begin, end - begin + 1);
}

}  // namespace

void Trajectory::add(double time_ms, int hand, InstrumentKind kind, const Eigen::Vector3d& position, const Eigen::Quaterniond& orientation,
                     const Eigen::Vector3d& semi_axes, bool grab) {
    InstrumentKeyframe k;
    k.time_ms = time_ms, k.hand = hand, k.kind = kind, k.semi_axes = semi_axes, k.grab = grab;
    k.pose.position = position, k.pose.orientation = orientation;
    keyframes.push_back(k);
}

void Trajectory::sort_by_time() {
    std::stable_sort(keyframes.begin(), keyframes.end(), [](const InstrumentKeyframe& a, const InstrumentKeyframe& b) { return a.time_ms < b.time_ms; });
}

bool Trajectory::uses_hand(int hand) const {
    return std::any_of(keyframes.begin(), keyframes.end(), [&](const InstrumentKeyframe& k) { return k.hand == hand; });
}

InstrumentKeyframe Trajectory::at(int hand, double time_ms) const {
    const InstrumentKeyframe* before = nullptr;
    const InstrumentKeyframe* after = nullptr;
    for (const auto& k : keyframes) {
        if (k.hand != hand) continue;
        if (k.time_ms <= time_ms) before = &k;
        else if (!after) after = &k;
    }
    if (!before && !after) throw InputError("trajectory: no keyframe for hand " + std::to_string(hand));
    if (!before) return *after;
    InstrumentKeyframe state = *before;
    state.time_ms = time_ms;
    // Toward a keyframe where the hand's instrument changes the pose holds: the instrument does not
    // travel to where the next one is placed (that one is placed there at once, at its keyframe).
    if (after && after->time_ms > before->time_ms && after->kind == before->kind && after->semi_axes == before->semi_axes) {
        const double t = (time_ms - before->time_ms) / (after->time_ms - before->time_ms);
        state.pose.position = before->pose.position + t * (after->pose.position - before->pose.position);
        state.pose.orientation = before->pose.orientation.slerp(t, after->pose.orientation);
    }
    return state;
}

void check_keyframe(const InstrumentKeyframe& k, const std::string& where) {
    if (!std::isfinite(k.time_ms)) throw InputError(where + ": the time is not a finite number");
    for (int a = 0; a < 3; ++a) plausible::require(k.pose.position[a], plausible::coordinate_mm, std::string(1, "xyz"[a]), where);
    if (k.pose.orientation.norm() < 1e-6) throw InputError(where + ": the orientation quaternion is zero");
    if (!std::isfinite(k.pose.orientation.norm()))
        throw InputError(where + ": the orientation quaternion is too large to normalise (its length overflows)");
    if (!(k.semi_axes.minCoeff() > 0)) throw InputError(where + ": semi-axes must be positive, mm");
    for (int a = 0; a < 3; ++a) plausible::require(k.semi_axes[a], plausible::semi_axis_mm, "semi-axis", where);
    if (k.grab && !takes_grab(k.kind))
        throw InputError(where + ": grab is 1 but the kind is probe or none (grab acts on a grabber, retractor, scalpel, patch or needle)");
}

void check_planned_trajectory(const Trajectory& trajectory) {
    for (const InstrumentKeyframe& k : trajectory.keyframes) {
        char where[96];
        std::snprintf(where, sizeof where, "the planned keyframe of hand %d at %.17g ms", k.hand, k.time_ms);
        try {
            check_keyframe(k, where);
        } catch (const InputError& e) {
            throw OptionError(std::string(e.what()) + ": heartsim run would refuse it; the plan's options ask for more than a trajectory holds");
        }
    }
}

Trajectory parse_trajectory(const std::string& text, const std::string& name) {
    Trajectory trajectory;
    std::istringstream in(text);
    std::string line;
    int line_number = 0, view_line_number = 0;
    std::map<std::pair<int, double>, int> line_of;  // (hand, time) → the line that gave it
    while (std::getline(in, line)) {
        ++line_number;
        if (const auto view = view_line(line)) {
            const std::string where = name + " line " + std::to_string(line_number);
            if (trajectory.view)
                throw InputError(where + ": a second '# view:' line (line " + std::to_string(view_line_number) + " gave the view); give one");
            try {
                trajectory.view = parse_view_options(*view);
            } catch (const InputError& e) {
                throw InputError(where + ": the planned view '# view: " + *view + "': " + e.what());
            }
            view_line_number = line_number;
            continue;
        }
        const auto hash = line.find('#');
        if (hash != std::string::npos) line.erase(hash);
        if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
        const auto fields = csv_fields(line);
        const std::string where = name + " line " + std::to_string(line_number);
        if (!fields.empty() && fields[0] == "time_ms") continue;  // header
        if (fields.size() != 14)
            throw InputError(where + ": expected 14 columns (time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab), found " +
                             std::to_string(fields.size()));
        InstrumentKeyframe k;
        k.time_ms = number(fields[0], where + " column time_ms");
        const double hand = number(fields[1], where + " column hand");
        if (hand != 0 && hand != 1) throw InputError(where + " column hand: expected 0 or 1");
        k.hand = int(hand);
        k.kind = parse_kind(fields[2], where + " column kind");
        k.pose.position = {number(fields[3], where + " column x"), number(fields[4], where + " column y"), number(fields[5], where + " column z")};
        k.pose.orientation = Eigen::Quaterniond(number(fields[6], where + " column qw"), number(fields[7], where + " column qx"),
                                                number(fields[8], where + " column qy"), number(fields[9], where + " column qz"));
        k.semi_axes = {number(fields[10], where + " column ax"), number(fields[11], where + " column ay"), number(fields[12], where + " column az")};
        const double grab = number(fields[13], where + " column grab");
        if (grab != 0 && grab != 1) throw InputError(where + " column grab: expected 0 or 1");
        k.grab = grab == 1;
        check_keyframe(k, where);
        k.pose.orientation.normalize();
        // Two poses of one hand at one time would make the instrument jump there in one step (the
        // earlier line only bends the approach): almost always a typing slip, so it is refused.
        if (const auto [it, fresh] = line_of.emplace(std::make_pair(k.hand, k.time_ms), line_number); !fresh)
            throw InputError(where + ": hand " + std::to_string(k.hand) + " already has a keyframe at " + fields[0] + " ms (line " +
                             std::to_string(it->second) + "); give each of a hand's keyframes its own time");
        trajectory.keyframes.push_back(k);
    }
    std::stable_sort(trajectory.keyframes.begin(), trajectory.keyframes.end(),
                     [](const InstrumentKeyframe& a, const InstrumentKeyframe& b) { return a.time_ms < b.time_ms; });
    if (trajectory.keyframes.empty()) throw InputError(name + ": no keyframes");
    return trajectory;
}

Trajectory read_trajectory(const std::filesystem::path& path) { return parse_trajectory(read_csv_file(path), path.string()); }

void write_trajectory_csv(const Trajectory& t, const std::filesystem::path& path, const std::string& comments) {
    std::string text = comments;
    if (t.view) text += "# view: " + view_options(*t.view) + "\n";
    text += "time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n";
    for (const InstrumentKeyframe& k : t.keyframes) {
        const auto& p = k.pose.position;
        const auto& q = k.pose.orientation;
        char row[512];
        std::snprintf(row, sizeof row, "%.17g,%d,%s,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%d\n", k.time_ms, k.hand,
                      to_string(k.kind), p.x(), p.y(), p.z(), q.w(), q.x(), q.y(), q.z(), k.semi_axes.x(), k.semi_axes.y(), k.semi_axes.z(),
                      k.grab ? 1 : 0);
        text += row;
    }
    write_bytes_atomically(path, text.data(), text.size(), "the trajectory");
}

// --probe and --grab are options: a value that is not one is an OptionError naming the option by
// its meaning (heartsim spells it as its flag, cli/option_flags.h; exit 2).
InstrumentKeyframe parse_fixed_instrument(const std::string& text, InstrumentKind kind, int hand) try {
    const auto fields = csv_fields(text);
    const std::string what = kind == InstrumentKind::probe ? "{fixed_probe}" : "{fixed_grabber}";
    if (fields.size() != 6 && !(kind == InstrumentKind::grabber && fields.size() == 9))
        throw InputError(what + " '" + text + "': expected X,Y,Z,AX,AY,AZ" + (kind == InstrumentKind::grabber ? "[,DX,DY,DZ]" : "") + " (mm)");
    std::vector<double> v;
    for (const auto& f : fields) v.push_back(number(f, what));
    InstrumentKeyframe k;
    k.hand = hand;
    k.kind = kind;
    k.pose.position = {v[0], v[1], v[2]};
    for (int a = 0; a < 3; ++a) plausible::require(k.pose.position[a], plausible::coordinate_mm, std::string(1, "XYZ"[a]), what);
    k.semi_axes = {v[3], v[4], v[5]};
    if (!(k.semi_axes.minCoeff() > 0)) throw InputError(what + ": semi-axes must be positive, mm");
    for (int a = 0; a < 3; ++a) plausible::require(k.semi_axes[a], plausible::semi_axis_mm, "semi-axis", what);
    k.grab = kind == InstrumentKind::grabber;
    return k;
} catch (const OptionError&) {
    throw;
} catch (const InputError& e) {
    throw OptionError(e.what());
}

void ScriptedHands::apply(Backend& backend, int hand, double t_ms, double t_next_ms) {
    if (!trajectory_.uses_hand(hand)) return;
    const InstrumentKeyframe now = trajectory_.at(hand, t_ms);
    Applied& a = applied_[hand];
    if (!a.active || a.kind != now.kind || a.semi_axes != now.semi_axes) {
        backend.set_instrument(hand, {.kind = now.kind, .semi_axes = now.semi_axes});
        backend.set_pose(hand, now.pose);  // placed at once at its pose now
        a = {true, now.kind, now.semi_axes, false};
    }
    if (now.grab && !a.grab) backend.begin_grab(hand);
    if (!now.grab && a.grab) backend.release(hand);
    a.grab = now.grab;
    // The instrument changes within the step (at a keyframe after t): this one ends it where it
    // is. Posed at the next instrument's place it would drag what it holds there, and the held
    // tissue would slip out of a retractor before its release could anchor it.
    const InstrumentKeyframe next = trajectory_.at(hand, t_next_ms);
    backend.set_pose(hand, next.kind == now.kind && next.semi_axes == now.semi_axes ? next.pose : now.pose);
}

ScriptedRunResult run_scripted(Backend& backend, const Trajectory& trajectory, const ScriptedRunOptions& options) {
    ScriptedRunResult result;
    ScriptedHands hands(trajectory);
    const bool uses[2] = {trajectory.uses_hand(0), trajectory.uses_hand(1)};
    StepClock clock(backend.time_step_ms());
    const auto start = std::chrono::steady_clock::now();
    for (int step = 0; step < options.steps; ++step) {
        const auto [t, t_next] = clock.at(step, backend.time_step_ms());
        if (options.end_ms > 0 && clock.changed() && t >= options.end_ms * (1 - 1e-12)) break;
        for (int hand = 0; hand < 2; ++hand) {
            if (!uses[hand]) continue;
            hands.apply(backend, hand, t, t_next);
        }
        const StepReport report = backend.step(1);
        result.add(report);
        if (options.forces_every_step && (uses[0] || uses[1])) {
            backend.request_forces();
            if (backend.latest_forces()) ++result.forces_received;
        }
        if (options.on_step) options.on_step(step, report);
        if (report.gave_up) break;
    }
    result.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return result;
}

}  // namespace heartsim
