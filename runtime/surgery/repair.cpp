#include "runtime/surgery/repair.h"

#include "libmodel/surgery/sight.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numbers>

namespace heartsim {

namespace {

/// The device's pass looks for the surface under each vertex among the triangles within this
/// distance across of it (PatchModel::pass_candidates), found afresh every candidate_refresh of its
/// steps: a vertex that slides by less than this against the tissue in that time misses nothing.
constexpr double candidate_reach_mm = 3.0;
constexpr int candidate_refresh = 64;
constexpr int candidate_lead = 8;  ///< the copy they are found from is asked for this many patch steps before

Eigen::Vector3d vec(const std::array<float, 3>& p) { return {double(p[0]), double(p[1]), double(p[2])}; }

}  // namespace

ContactSurface patch_surface_near(const Scenario& scenario, const Eigen::Vector3d& centre, const Eigen::Vector3d& facing, double radius,
                            double depth) {
    ContactSurface surface;
    const VisualMesh& visual = *scenario.visual;
    std::vector<std::int32_t> index(visual.positions.size(), -1);
    for (const auto& t : visual.triangles) {
        const Eigen::Vector3d a = vec(visual.positions[std::size_t(t[0])]), b = vec(visual.positions[std::size_t(t[1])]),
                              c = vec(visual.positions[std::size_t(t[2])]);
        const Eigen::Vector3d d = (a + b + c) / 3.0 - centre;
        const double along = d.dot(facing);
        if (std::abs(along) > depth || (d - along * facing).squaredNorm() > radius * radius) continue;
        const Eigen::Vector3d n = (b - a).cross(c - a);
        if (!(n.dot(facing) < -0.3 * n.norm())) continue;  // only surface that faces the patch
        std::array<std::int32_t, 3> local{};
        for (int c = 0; c < 3; ++c) {
            const std::size_t v = std::size_t(t[c]);
            if (index[v] < 0) {
                index[v] = std::int32_t(surface.vertices.size());
                CarriedPoint point;
                point.rest = vec(visual.positions[v]);
                std::array<std::int32_t, 8> particles{};
                std::array<float, 8> weights{};
                mapping_carriers(*scenario.mapping, *scenario.simulation_surface, v, particles, weights);
                std::map<std::int32_t, double> merged;
                for (int k = 0; k < 8; ++k) merged[particles[k]] += double(weights[k]);
                for (const auto& [particle, weight] : merged)
                    if (weight != 0) point.carriers.push_back({particle, weight});
                surface.vertices.push_back(std::move(point));
            }
            local[c] = index[v];
        }
        surface.triangles.push_back(local);
    }
    return surface;
}

namespace {

SurgerySupport& surgery_of(Backend& backend) {
    SurgerySupport* surgery = backend.surgery();
    if (!surgery) throw InputError("repair: the " + std::string(to_string(backend.kind())) + " backend offers no surgery support");
    return *surgery;
}

}  // namespace

RepairBackend::RepairBackend(std::unique_ptr<Backend> inner, const Scenario& scenario, const RepairSettings& settings)
    : BackendWrapper(std::move(inner)), tissue_(surgery_of(this->inner())), scenario_(scenario), settings_(settings) {}

void RepairBackend::set_instrument(int hand, const Instrument& instrument) {
    if (hand < 0 || hand > 1) throw InputError("solver: hand must be 0 or 1");
    Hand& h = hands_[std::size_t(hand)];
    if (repair_kind(h.instrument.kind) && h.grabbing) release(hand);
    h.instrument = instrument;
    h.posed = false;
    patch_force_[std::size_t(hand)].setZero();
    h.grabbing = false;
    h.stitch.reset();
    h.laid = false;
    end_intrusion(hand);
    withdrawing_[std::size_t(hand)] = false;
    checked_at_[std::size_t(hand)].reset();
    end_pass(hand);
    near_tip_[std::size_t(hand)].clear();
    gathered_at_[std::size_t(hand)].reset();
    held_repair_instrument_ = held_repair_instrument_ || repair_kind(instrument.kind);
    // The tissue's solver never holds a patch or a needle: that hand touches nothing there.
    inner().set_instrument(hand, repair_kind(instrument.kind) ? Instrument{InstrumentKind::none, instrument.semi_axes} : instrument);
}

void RepairBackend::set_pose(int hand, const InstrumentPose& pose) {
    if (hand < 0 || hand > 1) throw InputError("solver: hand must be 0 or 1");
    hands_[std::size_t(hand)].pose = pose;
    hands_[std::size_t(hand)].posed = true;
    inner().set_pose(hand, pose);
}

std::size_t RepairBackend::begin_grab(int hand) {
    if (hand < 0 || hand > 1) throw InputError("solver: hand must be 0 or 1");
    Hand& h = hands_[std::size_t(hand)];
    if (!repair_kind(h.instrument.kind)) return inner().begin_grab(hand);
    if (h.grabbing) return 0;
    h.grabbing = true;
    if (h.instrument.kind == InstrumentKind::needle) drop_bite(hand);
    end_intrusion(hand);
    checked_at_[std::size_t(hand)].reset();
    wall_force_[std::size_t(hand)].setZero();  // tying: the hand feels the suture instead (its pass through the wall is kept)
    if (h.instrument.kind == InstrumentKind::patch) h.laid = true, lay(hand);
    else tie(hand);
    std::fflush(stdout);  // the repair's lines, read as they happen (a window's log, the tests)
    return 0;
}

void RepairBackend::release(int hand) {
    if (hand < 0 || hand > 1) throw InputError("solver: hand must be 0 or 1");
    Hand& h = hands_[std::size_t(hand)];
    if (!repair_kind(h.instrument.kind)) {
        inner().release(hand);
        return;
    }
    h.grabbing = false;
    h.stitch.reset();  // the knot is thrown: the stitch goes on drawing tight by itself
    withdrawing_[std::size_t(hand)] = h.instrument.kind == InstrumentKind::needle;
}

void RepairBackend::lay(int hand) {
    const Hand& h = hands_[std::size_t(hand)];
    off_device();  // laying again replaces the patch
    if (!can_hold_patch(scenario_)) {
        std::printf("repair: no patch laid: the scenario has no detailed mesh with its mapping to lay it on\n");
        return;
    }
    PatchSpec spec;
    spec.material = settings_.material;
    spec.radius_x_mm = h.instrument.semi_axes.x();
    spec.radius_y_mm = h.instrument.semi_axes.y();
    spec.thickness_mm = 2.0 * h.instrument.semi_axes.z();
    spec.edge_mm = settings_.edge_mm;
    spec.standoff_mm = settings_.standoff_mm;
    spec.tie_ms = settings_.tie_ms;
    spec.stitch_stiffness = settings_.stitch_stiffness;
    spec.iterations = settings_.iterations;
    spec.gravity = Eigen::Vector3d(inner().options().gravity[0], inner().options().gravity[1], inner().options().gravity[2]);
    const double reach = std::max(spec.radius_x_mm, spec.radius_y_mm) + 3.0;
    const Eigen::Vector3d facing = h.pose.orientation.normalized() * Eigen::Vector3d::UnitZ();
    const Particles& particles = scenario_.lattice.particles;
    std::vector<double> inverse_mass(particles.size(), 0.0);
    for (std::size_t i = 0; i < particles.size(); ++i)
        inverse_mass[i] = (i < particles.anchored.size() && particles.anchored[i]) || !(particles.mass[i] > 0) ? 0.0 : 1.0 / double(particles.mass[i]);
    try {
        patch_.emplace(spec, particles.rest_position, patch_surface_near(scenario_, h.pose.position, facing, reach, 8.0), std::move(inverse_mass));
    } catch (const InputError& e) {  // a patch of a size no heart takes: said, and the session goes on
        patch_.reset();
        std::printf("repair: no patch laid: %s\n", e.what());
        return;
    }
    patch_->set_mass_scale(inner().options().mass_scale);
    patch_->lay(h.pose, tissue_.positions_of(patch_->particles()));
    tissue_steps_ = 0;
    const Eigen::Vector3d c = h.pose.position;
    std::printf("repair: %s patch laid at (%.1f, %.1f, %.1f) mm, %.1f × %.1f mm, %.2f mm thick (%.0f MPa), %zu vertices, %.1f mg, "
                "on %zu triangles of the tissue's surface carried by %zu particles; held where it lies until its first stitch\n",
                spec.material.name.c_str(), c.x(), c.y(), c.z(), 2 * spec.radius_x_mm, 2 * spec.radius_y_mm, spec.thickness_mm,
                spec.material.youngs_modulus_mpa, patch_->positions().size(), patch_->mass_g() * 1e3, patch_->surface_triangles(),
                patch_->particles().size());
}

void RepairBackend::tie(int hand) {
    Hand& h = hands_[std::size_t(hand)];
    if (!patch_ || !patch_->laid()) {
        std::printf("repair: no stitch at %.6g ms: no patch is laid\n", inner().simulated_time_ms());
        return;
    }
    std::string why;
    sync_from_device();
    h.stitch = patch_->tie(h.pose.position, inner().simulated_time_ms(), tissue_.positions_of(patch_->particles()), &why);
    if (!h.stitch) {
        std::printf("repair: no stitch at %.6g ms: %s\n", inner().simulated_time_ms(), why.c_str());
        return;
    }
    patch_force_[std::size_t(hand)].setZero();  // the new stitch pulls from its first step on
    h.tied_ms = inner().simulated_time_ms();
    to_device();
    const Stitch& s = patch_->stitches()[*h.stitch];
    std::printf("repair: stitch %zu tied at %.6g ms, patch vertex %d to the tissue %.2f mm from it; it draws tight over %.0f ms\n",
                *h.stitch + 1, inner().simulated_time_ms(), s.vertex, s.start_length, settings_.tie_ms);
}

void RepairBackend::step_patch(int every) {
    const auto start = std::chrono::steady_clock::now();
    patch_->set_mass_scale(inner().options().mass_scale);
    // The probes push the patch as they push the tissue (their hands feel it), and a needle's hand
    // feels the suture it ties: what each hand feels of the patch (PatchPassStep::hand_output).
    std::vector<PatchObstacle> probes;
    std::array<int, 2> output{-1, -1};
    for (int hand = 0; hand < 2; ++hand) {
        const Hand& h = hands_[std::size_t(hand)];
        if (h.instrument.kind == InstrumentKind::probe && h.posed) {
            output[std::size_t(hand)] = int(probes.size());
            probes.push_back({h.pose, h.instrument.semi_axes});
        } else if (h.instrument.kind == InstrumentKind::needle && h.grabbing && h.stitch) {
            output[std::size_t(hand)] = 2 + int(*h.stitch);
        }
    }
    if (device_) {  // on the device, before the tissue's step: nothing read back
        PatchPassStep step;
        step.dt_ms = every * inner().time_step_ms();
        step.time_ms = inner().simulated_time_ms();
        step.mass_scale = inner().options().mass_scale;
        step.obstacles = probes;
        step.hand_output = output;
        patch_->set_obstacles(std::move(probes));
        device_->step(step);
        device_ahead_ = true;
        // The candidates found again where the patch and the tissue are: a copy of both asked for
        // a few steps ahead and taken at a fixed step (done by then, and the same step in a replay).
        ++device_steps_;
        if (device_steps_ % candidate_refresh == candidate_refresh - candidate_lead) device_->request_snapshot();
        if (device_steps_ % candidate_refresh == 0) {
            auto [x, slot_x] = device_->snapshot();
            if (slot_x.empty())  // the pass has not stepped since it was loaded: the tissue now
                for (const auto& p : tissue_.positions_of(patch_->particles())) slot_x.push_back(vec(p));
            patch_->pass_candidates(*device_input_, x, slot_x, candidate_reach_mm);
            device_->load_candidates(*device_input_);
        }
        patch_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        ++patch_steps_;
        return;
    }
    patch_->set_obstacles(std::move(probes));
    patch_->step(tissue_.positions_of(patch_->particles()), every * inner().time_step_ms(), inner().simulated_time_ms());
    tissue_.set_loads(patch_->loads());
    for (int hand = 0; hand < 2; ++hand) {
        const int o = output[std::size_t(hand)];
        patch_force_[std::size_t(hand)] = o < 0 ? Eigen::Vector3d::Zero()
                                          : o < 2 ? patch_->obstacle_forces()[std::size_t(o)]
                                                  : patch_->stitches()[std::size_t(o - 2)].force_n;
    }
    patch_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    ++patch_steps_;
}

int RepairBackend::intrusion_every() const {
    if (!(settings_.intrusion_every_ms > 0)) return 0;
    return std::max(1, int(std::lround(settings_.intrusion_every_ms / inner().time_step_ms())));
}

void RepairBackend::drop_bite(int hand) {
    const Hand& h = hands_[std::size_t(hand)];
    const std::optional<TissueIntrusion>& going = going_[std::size_t(hand)];
    if (!going || (going->entered - h.pose.position).norm() > 2.0 * h.instrument.semi_axes.z()) return;
    if (const int shown = shown_[std::size_t(hand)]; shown >= 0) {
        intrusions_.erase(intrusions_.begin() + shown);
        int& other = shown_[std::size_t(1 - hand)];
        if (other > shown) --other;
    }
    end_intrusion(hand);
}

bool RepairBackend::carried(int hand) const {
    const Hand& h = hands_[std::size_t(hand)];
    if (!h.posed || h.grabbing) return false;
    return (h.instrument.kind == InstrumentKind::patch && !h.laid) || h.instrument.kind == InstrumentKind::needle;
}

void RepairBackend::check_intrusions() {
    const auto start = std::chrono::steady_clock::now();
    // Each carrying hand's working points and its direction of travel.
    struct Point {
        int hand;
        Eigen::Vector3d x;
        std::array<Eigen::Vector3d, 4> ways;  ///< its depth is looked for along these, both ways: the travel, the tool's axes
    };
    std::vector<Point> points;
    Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), high = -low;
    for (int hand = 0; hand < 2; ++hand) {
        if (!carried(hand)) {
            end_intrusion(hand);
            checked_at_[std::size_t(hand)].reset();
            continue;
        }
        const Hand& h = hands_[std::size_t(hand)];
        const Eigen::Matrix3d axes = h.pose.orientation.normalized().toRotationMatrix();
        std::optional<Eigen::Vector3d>& last = checked_at_[std::size_t(hand)];
        const Eigen::Vector3d moved = last ? Eigen::Vector3d(h.pose.position - *last) : Eigen::Vector3d::Zero();
        const Eigen::Vector3d along = moved.norm() > 1e-3 ? Eigen::Vector3d(moved.normalized()) : Eigen::Vector3d(axes.col(2));
        last = h.pose.position;
        const std::array<Eigen::Vector3d, 4> ways{along, axes.col(0), axes.col(1), axes.col(2)};
        points.push_back({hand, h.pose.position, ways});
        if (h.instrument.kind == InstrumentKind::patch)
            for (int k = 0; k < 8; ++k) {
                const double angle = 2.0 * std::numbers::pi * k / 8;
                points.push_back({hand,
                                  h.pose.position + h.instrument.semi_axes.x() * std::cos(angle) * axes.col(0) +
                                      h.instrument.semi_axes.y() * std::sin(angle) * axes.col(1),
                                  ways});
            }
    }
    if (points.empty()) return;
    // The tissue where it is now. Most checks find no point inside: the particles within 0.75
    // spacing of the points are enough to tell. Only for a point inside are the particles along its
    // four lines gathered, to find how deep it is.
    const double h = scenario_.lattice.spacing, reach2 = 0.5625 * h * h, step = 0.25 * h;
    const std::vector<std::array<float, 3>> positions = inner().positions();
    for (const Point& p : points) low = low.cwiseMin(p.x), high = high.cwiseMax(p.x);
    low.array() -= h, high.array() += h;
    std::vector<std::array<float, 3>> near;
    for (const auto& x : positions)
        if (x[0] >= low.x() && x[0] <= high.x() && x[1] >= low.y() && x[1] <= high.y() && x[2] >= low.z() && x[2] <= high.z())
            near.push_back(x);
    std::vector<Point> inside;
    {
        const TissueOccupancy tissue(near, h);
        for (const Point& p : points)
            if (tissue.inside(p.x)) inside.push_back(p);
    }
    const double now = inner().simulated_time_ms();
    std::array<std::optional<std::pair<double, Eigen::Vector3d>>, 2> deepest;
    if (!inside.empty()) {
        near.clear();
        for (const auto& x : positions) {
            const Eigen::Vector3d y(x[0], x[1], x[2]);
            bool taken = false;
            for (const Point& p : inside)
                for (const Eigen::Vector3d& way : p.ways) {
                    const double t = std::clamp((y - p.x).dot(way), -intrusion_reach_mm, intrusion_reach_mm);
                    if (!taken && (y - p.x - t * way).squaredNorm() <= reach2) near.push_back(x), taken = true;
                }
        }
        const TissueOccupancy tissue(near, h);
        for (const Point& p : inside) {
            // The nearest way out along the four lines, each both ways (way_out, each looking only
            // as far as the nearest found so far), half a step back.
            double exit = intrusion_reach_mm;
            for (const Eigen::Vector3d& way : p.ways)
                for (const double sign : {1.0, -1.0}) exit = way_out(tissue, p.x, sign * way, exit).exit;
            const double depth = exit < intrusion_reach_mm ? exit - 0.5 * step : intrusion_reach_mm;
            auto& d = deepest[std::size_t(p.hand)];
            if (!d || depth > d->first) d = std::pair{depth, p.x};
        }
    }
    for (int hand = 0; hand < 2; ++hand) {
        const auto& d = deepest[std::size_t(hand)];
        std::optional<TissueIntrusion>& going = going_[std::size_t(hand)];
        if (!d) {
            withdrawing_[std::size_t(hand)] = false;
            // A stretch ends once its hand has been out of the tissue for intrusion_gap_ms.
            if (going && now - going->to_ms >= intrusion_gap_ms) end_intrusion(hand);
            continue;
        }
        if (withdrawing_[std::size_t(hand)]) continue;  // drawn back out of its own bite
        if (!going) going = TissueIntrusion{.hand = hand, .kind = hands_[std::size_t(hand)].instrument.kind, .where = d->second,
                                            .depth_mm = d->first, .from_ms = now, .to_ms = now, .entered = d->second};
        going->to_ms = now;
        if (d->first > going->depth_mm) going->depth_mm = d->first, going->where = d->second;
        // Reported once a point has been a spacing deep: less is the surface (a stitch tied there).
        int& shown = shown_[std::size_t(hand)];
        if (shown < 0 && going->depth_mm >= h) shown = int(intrusions_.size()), intrusions_.push_back(*going);
        if (shown >= 0) intrusions_[std::size_t(shown)] = *going;
    }
    intrusion_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    ++intrusion_checks_;
}

StepReport RepairBackend::step(int steps) {
    const int every = intrusion_every(), feel = needle_every();
    const bool check = every > 0 && (carried(0) || carried(1)), needles = feel > 0 && (feels_wall(0) || feels_wall(1));
    if (!check) since_check_ = 0;
    if (!needles) since_feel_ = 0;
    if (!check && !needles) return step_tissue(steps);
    StepReport total;
    for (int done = 0; done < steps;) {
        int n = steps - done;
        if (check) n = std::min(n, every - since_check_);
        if (needles) n = std::min(n, feel - since_feel_);
        const StepReport r = step_tissue(n);
        total.steps += r.steps;
        total.substeps += r.substeps;
        if (r.diverged) total.diverged = true, total.reason = r.reason, total.message = r.message;
        total.gave_up = total.gave_up || r.gave_up;
        if (r.gave_up) break;
        done += n;
        if (check && (since_check_ += n) >= every) {
            since_check_ = 0;
            check_intrusions();
        }
        if (needles && (since_feel_ += n) >= feel) {
            since_feel_ = 0;
            feel_needles();
        }
    }
    return total;
}

int RepairBackend::needle_every() const {
    if (!(settings_.needle_every_ms > 0)) return 0;
    return std::max(1, int(std::lround(settings_.needle_every_ms / inner().time_step_ms())));
}

bool RepairBackend::feels_wall(int hand) const {
    const Hand& h = hands_[std::size_t(hand)];
    return h.instrument.kind == InstrumentKind::needle && h.posed && !h.grabbing;
}

void RepairBackend::feel_needles() {
    // The tissue along each carried needle's shaft: the particles whose rest positions lie within
    // `across` of the segment the depth is looked for along (from the tip `reach` up the shaft),
    // gathered again once a point of that segment has moved `regather` since: so every particle
    // within 0.75 spacing of a point looked at is among them while the tissue there has moved
    // less than 1 mm from rest.
    const double h = scenario_.lattice.spacing, regather = 2.0, reach = 12.0, step = 0.25 * h;
    const double length = reach + step, across = 0.75 * h + regather + 1.0;
    const auto& rest = scenario_.lattice.particles.rest_position;
    for (int hand = 0; hand < 2; ++hand) {
        if (!feels_wall(hand)) continue;
        const Hand& held = hands_[std::size_t(hand)];
        const Eigen::Vector3d tip = held.pose.position;
        const Eigen::Vector3d shaft = held.pose.orientation.normalized() * Eigen::Vector3d::UnitZ();
        std::vector<std::int32_t>& near = near_tip_[std::size_t(hand)];
        std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>>& at = gathered_at_[std::size_t(hand)];
        if (!tip.allFinite() || !shaft.allFinite()) {
            end_pass(hand);
            continue;
        }
        if (!at || (tip - at->first).norm() + length * (shaft - at->second).norm() > regather) {
            near.clear();
            for (std::size_t i = 0; i < rest.size(); ++i) {
                const Eigen::Vector3d d = vec(rest[i]) - tip;
                const double t = std::clamp(d.dot(shaft), 0.0, length);
                if ((d - t * shaft).squaredNorm() <= across * across) near.push_back(std::int32_t(i));
            }
            at = std::pair{tip, shaft};
        }
        double depth = 0.0;
        if (!near.empty()) {
            const std::vector<std::array<float, 3>> x = tissue_.positions_of(near);
            const TissueOccupancy tissue(x, h);
            if (tissue.inside(tip)) {
                // Out along the shaft (way_out), then halved between its last sample inside and
                // its exit.
                const WayOut way = way_out(tissue, tip, shaft, reach);
                double in = way.last_inside, out = way.exit;
                if (out < reach) {
                    for (int k = 0; k < 10; ++k) {
                        const double mid = 0.5 * (in + out);
                        (tissue.inside(tip + mid * shaft) ? in : out) = mid;
                    }
                }
                depth = 0.5 * (in + out);
                // Counted from the drawn surface: the occupancy's edge lies 0.75 spacing from the
                // particle the shaft leaves by, the drawn surface that particle's skin from it.
                if (skin_.empty()) skin_ = scenario_contact_skin(scenario_);
                const int last = tissue.particle_at(tip + in * shaft);
                if (last >= 0 && std::size_t(near[std::size_t(last)]) < skin_.size())
                    depth = std::max(0.0, depth - (0.75 * h - double(skin_[std::size_t(near[std::size_t(last)])])));
            }
        }
        wall_force_[std::size_t(hand)] = wall_force_n(settings_.needle, passes_[std::size_t(hand)], depth) * shaft;
    }
}

StepReport RepairBackend::step_tissue(int steps) {
    if (!patch_ || !patch_->laid()) return inner().step(steps);
    StepReport total;
    const int every = std::max(1, settings_.patch_every);
    for (int k = 0; k < steps; ++k) {
        StepReport r;
        if (tissue_steps_++ % every == 0) {
            // The patch's step, with the tissue as this step starts; its loads for this step and
            // the next every − 1 (the cpu backend runs it beside the tissue's spring pass).
            r = tissue_.step_after([this, every] { step_patch(every); });
        } else {
            r = inner().step(1);
        }
        total.steps += r.steps;
        total.substeps += r.substeps;
        if (r.diverged) {
            total.diverged = true, total.reason = r.reason, total.message = r.message;
            // The tissue went back to its last good state: the patch lets go of its motion and its
            // loads, and its stitches draw tight again from where they now are.
            sync_from_device();
            const bool on_device = device_ != nullptr;
            off_device();
            patch_->recover(tissue_.positions_of(patch_->particles()), inner().simulated_time_ms());
            tissue_.set_loads({});
            patch_force_.fill(Eigen::Vector3d::Zero());
            if (on_device) to_device();
        }
        total.gave_up = total.gave_up || r.gave_up;
        if (r.gave_up) break;
    }
    return total;
}

void RepairBackend::add_repair_forces(InstrumentForces& forces) const {
    for (int hand = 0; hand < 2; ++hand) {
        const Hand& h = hands_[std::size_t(hand)];
        const Eigen::Vector3d& f = patch_force_[std::size_t(hand)];
        if (h.instrument.kind == InstrumentKind::probe && f.allFinite()) forces.hand[std::size_t(hand)].force_n += f;  // the patch it presses on
        if (!repair_kind(h.instrument.kind)) continue;
        Eigen::Vector3d& felt = forces.hand[std::size_t(hand)].force_n;
        felt.setZero();
        forces.hand[std::size_t(hand)].particles = 0;
        if (h.instrument.kind != InstrumentKind::needle) continue;
        const Eigen::Vector3d shaft = h.pose.orientation.normalized() * Eigen::Vector3d::UnitZ();
        if (h.grabbing && h.stitch) {
            // The suture, drawn tight through the wall, pulls the hand that holds it along the
            // shaft toward the wall.
            felt = -suture_tension_n(settings_.needle, inner().simulated_time_ms() - h.tied_ms, settings_.tie_ms) * shaft;
        } else if (!h.grabbing) {
            felt = wall_force_[std::size_t(hand)];  // the wall's resistance to the needle's pass
        }
        if (!felt.allFinite()) felt.setZero();
    }
}

void RepairBackend::device_hand_forces(bool wait) {
    if (!device_) return;
    if (const auto f = device_->hand_forces(wait))
        patch_force_ = *f;
}

std::optional<InstrumentForces> RepairBackend::latest_forces() {
    device_hand_forces(false);
    std::optional<InstrumentForces> forces = inner().latest_forces();
    if (forces) add_repair_forces(*forces);
    return forces;
}

InstrumentForces RepairBackend::instrument_forces() {
    device_hand_forces(true);
    InstrumentForces forces = inner().instrument_forces();
    add_repair_forces(forces);
    return forces;
}

void RepairBackend::reset_tissue() {
    off_device();
    patch_.reset();
    patch_force_.fill(Eigen::Vector3d::Zero());
    for (Hand& h : hands_) h.grabbing = false, h.stitch.reset();
    end_intrusion(0), end_intrusion(1);
    withdrawing_ = {false, false};
    end_pass(0), end_pass(1);
    tissue_.set_loads({});
    inner().reset_tissue();
}

void RepairBackend::to_device() {
    if (!patch_ || !patch_->laid() || patch_->held()) return;
    PatchStepper* stepper = tissue_.patch_stepper();
    if (!stepper || !stepper->takes(*patch_)) {
        off_device();
        return;
    }
    device_input_ = patch_->pass_input(tissue_.positions_of(patch_->particles()), candidate_reach_mm);
    stepper->load(*device_input_);
    tissue_.set_loads({});  // the host's loads, if any: the pass puts its own
    device_ = stepper;
    timed_device_ = stepper;
    device_ahead_ = false;
    device_steps_ = 0;
    patch_force_.fill(Eigen::Vector3d::Zero());
}

void RepairBackend::sync_from_device() const {
    if (!device_ || !device_ahead_ || !patch_) return;
    const auto start = std::chrono::steady_clock::now();
    std::vector<Eigen::Vector3d> obstacle_forces(patch_->obstacle_forces().size(), Eigen::Vector3d::Zero());
    const PatchPassState state = device_->state(&obstacle_forces);
    patch_->take_pass_state(state, obstacle_forces);
    device_ahead_ = false;
    patch_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

std::pair<double, long long> RepairBackend::patch_device_time() {
    return timed_device_ ? timed_device_->device_time(true) : std::pair<double, long long>{0.0, 0};
}

void RepairBackend::off_device() {
    if (device_) device_->unload();
    device_ = nullptr;
    device_ahead_ = false;
    device_input_.reset();
    patch_force_.fill(Eigen::Vector3d::Zero());
}

std::vector<Eigen::Vector3d> RepairBackend::stitch_anchors() {
    std::vector<Eigen::Vector3d> out;
    if (!patch()) return out;
    const auto positions = tissue_.positions_of(patch_->particles());
    for (const Stitch& s : patch_->stitches()) out.push_back(patch_->where(s.anchor, positions));
    return out;
}

bool can_hold_patch(const Scenario& scenario) { return scenario.visual && scenario.mapping && scenario.simulation_surface; }

InputError no_patch_surface(const std::string& what) {
    return InputError(what + " lays a patch or ties a stitch, and the scenario has no detailed mesh (/visual with /mapping) for a "
                             "patch to lie on: build the case again with heartprep build, which writes one");
}

std::unique_ptr<Backend> with_repair(std::unique_ptr<Backend> inner, const Scenario& scenario, const RepairSettings& settings) {
    if (!can_hold_patch(scenario) || !inner->surgery()) return inner;
    return std::make_unique<RepairBackend>(std::move(inner), scenario, settings);
}

std::optional<DefectFrame> defect_frame_now(const Scenario& scenario, const std::vector<std::array<float, 3>>& positions,
                                            const PatchModel* patch) {
    const ScenarioSource& source = scenario.source;
    if (source.defect.empty() || !(source.defect_diameter_mm > 0)) return std::nullopt;
    const auto& rest = scenario.lattice.particles.rest_position;
    const double h = scenario.lattice.spacing;
    Eigen::Vector3d moved = Eigen::Vector3d::Zero();
    double total = 0, nearest = std::numeric_limits<double>::infinity();
    Eigen::Vector3d nearest_displacement = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < rest.size() && i < positions.size(); ++i) {
        const Eigen::Vector3d d = vec(rest[i]) - source.defect_centre;
        const double d2 = d.squaredNorm();
        const Eigen::Vector3d displacement = vec(positions[i]) - vec(rest[i]);
        if (d2 < nearest) nearest = d2, nearest_displacement = displacement;
        if (d2 > 4 * h * h) continue;
        const double w = std::exp(-d2 / (2 * h * h));
        moved += w * displacement;
        total += w;
    }
    DefectFrame frame;
    frame.centre = source.defect_centre + (total > 0 ? Eigen::Vector3d(moved / total) : nearest_displacement);
    frame.axis = source.defect_axis.normalized();
    frame.diameter_mm = source.defect_diameter_mm;
    if (patch && patch->laid()) {
        Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
        for (const auto& x : patch->positions()) centroid += x;
        centroid /= double(patch->positions().size());
        if ((centroid - frame.centre).dot(frame.axis) < 0) frame.axis = -frame.axis;
    } else if (frame.axis.dot(Eigen::Vector3d(-1, -1, 0)) < 0) {
        frame.axis = -frame.axis;
    }
    return frame;
}

}  // namespace heartsim
