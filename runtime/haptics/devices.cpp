// The scripted, simulated and window haptic devices (devices.h).
#include "runtime/haptics/devices.h"

#include "formats/csv.h"

#include "libmodel/errors.h"
#include "libmodel/plausible.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace heartsim::haptics {

namespace {

/// Rows of numbers from CSV text: `#` comments, blank lines and one header line (no numbers in
/// it) skipped; every row must have between min_columns and max_columns numbers.
std::vector<std::vector<double>> parse_rows(const std::string& text, const std::string& name, std::size_t min_columns,
                                            std::size_t max_columns) {
    std::vector<std::vector<double>> rows;
    std::istringstream in(text);
    std::string line;
    int number = 0;
    bool header_allowed = true;
    while (std::getline(in, line)) {
        ++number;
        if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
        if (line.find_first_not_of(" \t\r,") == std::string::npos) continue;
        std::vector<double> row;
        bool numeric = true, any_number = false;
        int column = 0;
        std::string bad;
        std::vector<std::string> fields = csv_fields(line);
        if (fields.size() > 1 && fields.back().empty()) fields.pop_back();  // a trailing comma adds no column
        for (const std::string& f : fields) {
            ++column;
            char* end = nullptr;
            const double v = std::strtod(f.c_str(), &end);
            if (f.empty() || *end != '\0' || !std::isfinite(v)) {
                numeric = false;
                if (bad.empty()) bad = "column " + std::to_string(column) + " ('" + f + "')";
                continue;
            }
            row.push_back(v);
            any_number = true;
        }
        if (!numeric) {
            // A header has no numbers; a first row with a typo in one field is an error, not a header.
            if (header_allowed && rows.empty() && !any_number) {
                header_allowed = false;
                continue;
            }
            throw InputError(name + ":" + std::to_string(number) + ": not a finite number in " + bad);
        }
        header_allowed = false;
        if (row.size() < min_columns || row.size() > max_columns)
            throw InputError(name + ":" + std::to_string(number) + ": expected " + std::to_string(min_columns) +
                             (min_columns == max_columns ? "" : " to " + std::to_string(max_columns)) + " columns, found " +
                             std::to_string(row.size()));
        if (!rows.empty() && row[0] < rows.back()[0])
            throw InputError(name + ":" + std::to_string(number) + ": time goes backwards");
        rows.push_back(std::move(row));
    }
    if (rows.empty()) throw InputError(name + ": no rows");
    return rows;
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// scripted

std::vector<PoseKeyframe> parse_pose_script(const std::string& text, const std::string& name) {
    std::vector<PoseKeyframe> keyframes;
    int row_number = 0;
    for (const auto& row : parse_rows(text, name, 8, 9)) {
        ++row_number;
        PoseKeyframe k;
        k.time_ms = row[0];
        k.pose.position_mm = Eigen::Vector3d(row[1], row[2], row[3]);
        for (int a = 0; a < 3; ++a)
            plausible::require(row[std::size_t(1 + a)], plausible::coordinate_mm, std::string(1, "xyz"[a]), name + ": row " + std::to_string(row_number));
        Eigen::Quaterniond q(row[4], row[5], row[6], row[7]);
        if (q.norm() < 1e-9) throw InputError(name + ": row " + std::to_string(row_number) + ": zero orientation quaternion");
        // 1e300 overflowed the length to infinity: the pose read, then every step dropped it.
        if (!std::isfinite(q.norm()))
            throw InputError(name + ": row " + std::to_string(row_number) + ": the orientation quaternion is too large to normalise (its length overflows)");
        k.pose.orientation = q.normalized();
        if (row.size() > 8) {
            // Bits of a 32-bit word: a larger number cannot be converted (fuzz_pose_script found 1e49).
            if (row[8] < 0 || row[8] != std::floor(row[8]) || row[8] > 4294967295.0)
                throw InputError(name + ": row " + std::to_string(row_number) + ": buttons must be an integer from 0 to 4294967295 (32 button bits)");
            k.pose.buttons = std::uint32_t(row[8]);
        }
        keyframes.push_back(k);
    }
    return keyframes;
}

std::vector<PoseKeyframe> read_pose_script(const std::filesystem::path& path) { return parse_pose_script(read_csv_file(path), path.string()); }

ScriptedDevice::ScriptedDevice(std::vector<PoseKeyframe> keyframes, DeviceLimits limits)
    : keyframes_(std::move(keyframes)), limits_(limits) {
    if (keyframes_.empty()) throw InputError("scripted device: no keyframes");
    std::uint64_t presses = 0;
    for (std::size_t k = 0; k < keyframes_.size(); ++k) {
        const bool down = keyframes_[k].pose.buttons & 1u, was = k > 0 && (keyframes_[k - 1].pose.buttons & 1u);
        presses += down && !was;
        presses_.push_back(presses);
    }
}

DevicePose ScriptedDevice::pose_at(double t) const {
    if (t <= keyframes_.front().time_ms) {
        DevicePose p = keyframes_.front().pose;
        p.presses = presses_.front();
        return p;
    }
    if (t >= keyframes_.back().time_ms) {
        DevicePose p = keyframes_.back().pose;
        p.presses = presses_.back();
        return p;
    }
    const auto next = std::upper_bound(keyframes_.begin(), keyframes_.end(), t,
                                       [](double time, const PoseKeyframe& k) { return time < k.time_ms; });
    const PoseKeyframe& b = *next;
    const PoseKeyframe& a = *(next - 1);
    const double span = b.time_ms - a.time_ms;
    const double u = span > 0 ? (t - a.time_ms) / span : 1.0;
    DevicePose p;
    p.position_mm = a.pose.position_mm + u * (b.pose.position_mm - a.pose.position_mm);
    p.orientation = a.pose.orientation.slerp(u, b.pose.orientation);
    p.buttons = a.pose.buttons;
    p.presses = presses_[std::size_t(next - keyframes_.begin()) - 1];
    return p;
}

DevicePose ScriptedDevice::read_pose(double time_ms) { return pose_at(time_ms); }

// ------------------------------------------------------------------------------------------------
// hand force

HandForce parse_hand_force(const std::string& text, const std::string& name) {
    auto rows = parse_rows(text, name, 4, 4);
    return [rows = std::move(rows)](double t) -> Eigen::Vector3d {
        auto at = [](const std::vector<double>& r) { return Eigen::Vector3d(r[1], r[2], r[3]); };
        if (t <= rows.front()[0]) return at(rows.front());
        if (t >= rows.back()[0]) return at(rows.back());
        const auto next = std::upper_bound(rows.begin(), rows.end(), t, [](double time, const std::vector<double>& r) { return time < r[0]; });
        const auto& b = *next;
        const auto& a = *(next - 1);
        const double span = b[0] - a[0];
        const double u = span > 0 ? (t - a[0]) / span : 1.0;
        return at(a) + u * (at(b) - at(a));
    };
}

HandForce read_hand_force(const std::filesystem::path& path) { return parse_hand_force(read_csv_file(path), path.string()); }

// ------------------------------------------------------------------------------------------------
// simulated

SimulatedDevice::SimulatedDevice(SimulatedDeviceSettings settings) : settings_(std::move(settings)), x_(settings_.start_mm) {
    if (!(settings_.mass_g > 0.0) || !(settings_.damping_n_ms_per_mm >= 0.0))
        throw InputError("simulated device: mass must be positive and damping non-negative");
    settings_.limits.damping_n_ms_per_mm = settings_.damping_n_ms_per_mm;
}

void SimulatedDevice::advance(double to_ms) {
    if (!started_) {
        started_ = true;
        time_ms_ = to_ms;
        return;
    }
    const double dt = to_ms - time_ms_;
    if (!(dt > 0.0)) return;
    const double m = settings_.mass_g, b = settings_.damping_n_ms_per_mm;
    const Eigen::Vector3d hand = settings_.hand_force ? settings_.hand_force(time_ms_ + 0.5 * dt) : Eigen::Vector3d::Zero();
    const Eigen::Vector3d f = hand + force_;
    // Exact for a constant force over the interval: v → f/b with time constant m/b.
    Eigen::Vector3d dx, v_new;
    if (b > 0.0) {
        const double tau = m / b, decay = std::exp(-dt / tau);
        const Eigen::Vector3d v_inf = f / b;
        v_new = v_inf + (v_ - v_inf) * decay;
        dx = v_inf * dt + (v_ - v_inf) * tau * (1.0 - decay);
    } else {
        v_new = v_ + f / m * dt;
        dx = (v_ + 0.5 * f / m * dt) * dt;
    }
    Eigen::Vector3d x_new = x_ + dx;
    const Eigen::AlignedBox3d& box = settings_.limits.workspace_mm;
    if (!box.isEmpty()) {
        for (int a = 0; a < 3; ++a) {
            if (x_new[a] < box.min()[a]) x_new[a] = box.min()[a], v_new[a] = 0.0;
            if (x_new[a] > box.max()[a]) x_new[a] = box.max()[a], v_new[a] = 0.0;
        }
    }
    const Eigen::Vector3d moved = x_new - x_;
    rendered_work_mj_ += force_.dot(moved);
    hand_work_mj_ += hand.dot(moved);
    x_ = x_new;
    v_ = v_new;
    time_ms_ = to_ms;
}

DevicePose SimulatedDevice::read_pose(double time_ms) {
    advance(time_ms);
    DevicePose p;
    p.position_mm = x_;
    return p;
}

void SimulatedDevice::send_force(const Eigen::Vector3d& force_n, double time_ms) {
    advance(time_ms);
    force_ = force_n;
}

}  // namespace heartsim::haptics
