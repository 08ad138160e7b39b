#include "runtime/surgery/repair.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>

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
    if (h.instrument.kind == InstrumentKind::patch) lay(hand);
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

StepReport RepairBackend::step(int steps) {
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
        forces.hand[std::size_t(hand)].force_n.setZero();
        forces.hand[std::size_t(hand)].particles = 0;
        // The suture's tension pulls the hand that holds it as it pulls the patch: toward the tissue.
        if (h.instrument.kind == InstrumentKind::needle && h.grabbing && h.stitch && f.allFinite()) forces.hand[std::size_t(hand)].force_n = f;
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
