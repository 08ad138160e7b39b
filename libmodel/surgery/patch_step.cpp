// One step of a laid patch (PatchModel::step, patch.h): extended position-based dynamics
// (Macklin, Müller and Chentanez, "XPBD", MIG 2016) with the tissue held where it is, its stitches
// drawn by a smoothstep, a one-sided contact with friction, the instruments as obstacles, and the
// opposite of every force on the patch left as a load on the tissue.
#include "libmodel/surgery/patch.h"

#include "libmodel/ellipsoid.h"
#include "libmodel/errors.h"
#include "libmodel/surgery/patch_internal.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace heartsim {

using patch_internal::barycentric;

/// The stitches within one step(): each anchor held where the tissue is at the start of the step
/// and yielding by its carriers' inverse mass (its predicted offset), each stitch's length to
/// draw to, and its multiplier and direction as the iterations leave them.
struct PatchModel::StitchPull {
    std::vector<Eigen::Vector3d> anchor, anchor_offset, direction;
    std::vector<double> target, lambda, anchor_inverse_mass;
};

/// The contact within one step(): per patch vertex, the surface triangle's barycentric weights
/// under it (under_ holds which triangle), the tissue's generalised inverse mass there and its
/// predicted yield, how far the tissue under it moved since the last step, and the contact's
/// displacement of it.
struct PatchModel::StepContact {
    std::vector<Eigen::Vector3d> under_at, carried, pushed;
    std::vector<double> under_inverse_mass, surface_offset;
};

void PatchModel::drift(double dt_ms) {
    const double keep = std::max(0.0, 1.0 - spec_.damping_per_ms * dt_ms);
    for (std::size_t i = 0; i < x_.size(); ++i) {
        if (inverse_mass_[i] == 0) continue;
        Eigen::Vector3d acceleration = spec_.gravity * (1.0 - spec_.blood_density / spec_.material.density);  // afloat in blood
        if (pressure_ > 0) {  // over the opening the blood pushes the patch off the wall
            Eigen::Vector3d bary;
            double depth = 0;
            if (triangle_under(x_[i], bary, depth) < 0) acceleration -= pressure_ * area_[i] * inverse_mass_[i] * facing_;
        }
        v_[i] = keep * (v_[i] + acceleration * dt_ms);
        x_[i] += v_[i] * dt_ms;
    }
}

PatchModel::StitchPull PatchModel::stitch_pull(const ParticlePositions& positions, double dt_ms, double time_ms) const {
    StitchPull pull;
    pull.anchor.resize(stitches_.size());
    pull.target.resize(stitches_.size());
    pull.lambda.assign(stitches_.size(), 0.0);
    pull.direction.assign(stitches_.size(), Eigen::Vector3d::Zero());
    const double end_length = 0.5 * spec_.thickness_mm;  // tied: the patch on the tissue
    for (std::size_t s = 0; s < stitches_.size(); ++s) {
        pull.anchor[s] = where(stitches_[s].anchor, positions);
        const double tau = std::clamp((time_ms + dt_ms - stitches_[s].tied_ms) / spec_.tie_ms, 0.0, 1.0);
        const double drawn = tau * tau * (3.0 - 2.0 * tau);  // smoothstep: no jump in pull at either end
        pull.target[s] = std::max(end_length, stitches_[s].start_length + (end_length - stitches_[s].start_length) * drawn);
    }
    pull.anchor_inverse_mass.resize(stitches_.size());
    pull.anchor_offset.assign(stitches_.size(), Eigen::Vector3d::Zero());
    for (std::size_t s = 0; s < stitches_.size(); ++s) pull.anchor_inverse_mass[s] = inverse_mass_of(stitches_[s].anchor);
    return pull;
}

void PatchModel::update_compliance(double dt_ms, double dt2) {
    if (alpha_dt_ == dt_ms && alpha_.size() == distances_.size()) return;
    alpha_.resize(distances_.size());
    denominator_.resize(distances_.size());
    for (std::size_t k = 0; k < distances_.size(); ++k) {
        const Distance& d = distances_[k];
        alpha_[k] = d.compliance / dt2;
        const double sum = inverse_mass_[std::size_t(d.a)] + inverse_mass_[std::size_t(d.b)];
        denominator_[k] = sum == 0 ? 0.0 : 1.0 / (sum + alpha_[k]);
    }
    alpha_dt_ = dt_ms;
}

PatchModel::StepContact PatchModel::step_contact() {
    const std::size_t n = x_.size();
    StepContact contact;
    contact.pushed.assign(n, Eigen::Vector3d::Zero());
    contact.surface_offset.assign(n, 0.0);
    contact.under_inverse_mass.assign(n, 0.0);
    // The surface triangle under each vertex for this step (where it was predicted to go).
    std::vector<int>& under = under_;
    under.resize(n, -1);
    contact.under_at.assign(n, Eigen::Vector3d::Zero());
    searched_at_.resize(n, Eigen::Vector3d::Zero());
    searched_shift_.resize(n, Eigen::Vector3d::Zero());
    searched_travel_.resize(n, std::numeric_limits<double>::quiet_NaN());
    for (std::size_t i = 0; i < n; ++i) {
        if (inverse_mass_[i] == 0) continue;
        // What a vertex found under it last time stands while it still holds (the triangle still
        // under it, within the search's depth range; or none, over the opening) and, unless the
        // vertex touches that triangle, until it has moved against the tissue's shift, or the
        // tissue deformed, by search_again() since it looked.
        const bool still = (x_[i] - searched_at_[i] - (tissue_shift_ - searched_shift_[i])).norm() + (tissue_travel_ - searched_travel_[i]) <
                           search_again();
        if (const int t = under[i]; t >= 0) {
            const auto& [a, b, c] = surface_.triangles[std::size_t(t)];
            const Eigen::Vector3d& pa = sx(std::size_t(a));
            const double d = (x_[i] - pa).dot(sn(std::size_t(t)));
            const Eigen::Vector3d w = barycentric(x_[i], pa, sx(std::size_t(b)), sx(std::size_t(c)));
            if (w.minCoeff() >= 0 && (std::abs(d) < 0.5 * spec_.thickness_mm + 0.5 || (still && d >= -2.0 && d <= 3.0 + spec_.thickness_mm))) {
                contact.under_at[i] = w;
                continue;
            }
        } else if (still) {
            continue;
        }
        double depth = 0;
        under[i] = triangle_under(x_[i], contact.under_at[i], depth);
        searched_at_[i] = x_[i];
        searched_shift_[i] = tissue_shift_;
        searched_travel_[i] = tissue_travel_;
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (under[i] < 0) continue;
        double w = 0;
        for (int corner = 0; corner < 3; ++corner)
            w += contact.under_at[i][corner] * contact.under_at[i][corner] *
                 vertex_inverse_mass(std::size_t(surface_.triangles[std::size_t(under[i])][corner]));
        contact.under_inverse_mass[i] = w;
    }
    // How far the tissue under each vertex moved since the patch last stepped: friction holds the
    // patch against its slip on the tissue, not against its motion in space.
    contact.carried.assign(n, Eigen::Vector3d::Zero());
    if (stepped_slot_x_.size() == slot_x_.size()) {
        for (std::size_t i = 0; i < n; ++i) {
            if (under[i] < 0) continue;
            for (int corner = 0; corner < 3; ++corner) {
                const std::size_t v = std::size_t(surface_.triangles[std::size_t(under[i])][corner]);
                for (std::size_t k = vertex_first_[v]; k < vertex_first_[v + 1]; ++k) {
                    const std::size_t slot = std::size_t(slot_of_surface_[k]);
                    contact.carried[i] += contact.under_at[i][corner] * surface_weight_[k] * (slot_x_[slot] - stepped_slot_x_[slot]);
                }
            }
        }
    }
    stepped_slot_x_ = slot_x_;
    return contact;
}

void PatchModel::project_stitches(StitchPull& pull, double dt2) {
    for (std::size_t s = 0; s < stitches_.size(); ++s) {
        // Two bodies: the patch vertex and the tissue point, which yields by its carriers' inverse
        // mass as the tissue's next step will move it under the load (within the step its
        // yielding is predicted, not applied: the anchor's offset).
        const std::size_t i = std::size_t(stitches_[s].vertex);
        const double w = inverse_mass_[i], wt = pull.anchor_inverse_mass[s];
        Eigen::Vector3d delta = x_[i] - (pull.anchor[s] + pull.anchor_offset[s]);
        const double length = delta.norm();
        if (!(length > pull.target[s]) || !(length > 1e-12)) continue;  // a suture pulls, never pushes
        delta /= length;
        const double alpha = 1.0 / (spec_.stitch_stiffness * dt2);
        const double dl = (-(length - pull.target[s]) - alpha * pull.lambda[s]) / (w + wt + alpha);
        pull.lambda[s] += dl;
        pull.direction[s] = delta;
        x_[i] += w * dl * delta;
        pull.anchor_offset[s] -= wt * dl * delta;
    }
}

void PatchModel::project_distances(std::vector<double>& lambda) {
    for (std::size_t k = 0; k < distances_.size(); ++k) {
        const Distance& d = distances_[k];
        const double wa = inverse_mass_[std::size_t(d.a)], wb = inverse_mass_[std::size_t(d.b)];
        Eigen::Vector3d delta = x_[std::size_t(d.a)] - x_[std::size_t(d.b)];
        const double length2 = delta.squaredNorm();
        if (!(length2 > 1e-24) || denominator_[k] == 0) continue;
        const double inverse = 1.0 / std::sqrt(length2), length = length2 * inverse;
        const double dl = (-(length - d.rest) - alpha_[k] * lambda[k]) * denominator_[k];
        lambda[k] += dl;
        delta *= dl * inverse;
        x_[std::size_t(d.a)] += wa * delta;
        x_[std::size_t(d.b)] -= wb * delta;
    }
}

void PatchModel::project_contact(StepContact& contact, const std::vector<Eigen::Vector3d>& previous) {
    const double half = 0.5 * spec_.thickness_mm, friction = spec_.friction;
    for (std::size_t i = 0; i < x_.size(); ++i) {
        const int t = under_[i];
        if (t < 0) continue;
        const Eigen::Vector3d& normal = surface_normal_[std::size_t(t)];
        const double depth = (x_[i] - surface_x_[std::size_t(surface_.triangles[std::size_t(t)][0])]).dot(normal) - contact.surface_offset[i];
        if (!(depth < half)) continue;
        // Two bodies again: the patch moves its share, the tissue under it (predicted) the rest.
        const double share = inverse_mass_[i] / (inverse_mass_[i] + contact.under_inverse_mass[i]);
        const Eigen::Vector3d push = share * (half - depth) * normal;
        contact.surface_offset[i] -= (1.0 - share) * (half - depth);
        x_[i] += push;
        contact.pushed[i] += push;
        // Friction (Coulomb, as position-based dynamics takes it): the slip along the surface in
        // this step, relative to the tissue under it, is undone up to μ times the push.
        Eigen::Vector3d slip = x_[i] - previous[i] - contact.carried[i];
        slip -= slip.dot(normal) * normal;
        const double length = slip.norm(), hold = friction * (half - depth);
        const Eigen::Vector3d undo = length <= hold ? slip : Eigen::Vector3d(slip * (hold / length));
        x_[i] -= undo;
        contact.pushed[i] -= undo;
    }
}

void PatchModel::project_obstacles(double dt2) {
    const double half = 0.5 * spec_.thickness_mm;
    for (std::size_t o = 0; o < obstacles_.size(); ++o) {
        const PatchObstacle& obstacle = obstacles_[o];
        const Eigen::Matrix3d rotation = obstacle.pose.orientation.normalized().toRotationMatrix();
        const Eigen::Vector3d axes = obstacle.semi_axes + Eigen::Vector3d::Constant(half);
        for (std::size_t i = 0; i < x_.size(); ++i) {
            if (inverse_mass_[i] == 0) continue;
            const Eigen::Vector3d local = rotation.transpose() * (x_[i] - obstacle.pose.position);
            if (!(local.cwiseQuotient(axes).squaredNorm() < 1.0)) continue;
            const Eigen::Vector3d push = rotation * (nearest_point_on_ellipsoid(local, axes) - local);
            x_[i] += push;
            obstacle_force_[o] -= push / (inverse_mass_[i] * dt2);
        }
    }
}

void PatchModel::load_tissue(const StitchPull& pull, const StepContact& contact, double dt2) {
    // Forces: a stitch's pull on the patch is λ·n/dt²; the contact's, m·Δx/dt². The tissue takes
    // the opposite of each at its point.
    for (std::size_t s = 0; s < stitches_.size(); ++s) {
        stitches_[s].force_n = pull.lambda[s] * pull.direction[s] / dt2;
        add_load(stitches_[s].anchor, -stitches_[s].force_n);
    }
    // The contact's forces on the surface vertices under the patch, then each vertex's on its carriers.
    vertex_force_.resize(surface_.vertices.size(), Eigen::Vector3d::Zero());
    loaded_vertices_.clear();
    for (std::size_t i = 0; i < x_.size(); ++i) {
        if (under_[i] < 0 || inverse_mass_[i] == 0 || contact.pushed[i].isZero()) continue;
        const Eigen::Vector3d force = contact.pushed[i] / (inverse_mass_[i] * dt2);
        contact_force_ += force;
        for (int corner = 0; corner < 3; ++corner) {
            const std::size_t v = std::size_t(surface_.triangles[std::size_t(under_[i])][corner]);
            if (vertex_force_[v].isZero()) loaded_vertices_.push_back(std::int32_t(v));
            vertex_force_[v] -= contact.under_at[i][corner] * force;
        }
    }
    for (std::int32_t v : loaded_vertices_) {
        const Eigen::Vector3d force = vertex_force_[std::size_t(v)];
        vertex_force_[std::size_t(v)].setZero();
        for (std::size_t k = vertex_first_[std::size_t(v)]; k < vertex_first_[std::size_t(v) + 1]; ++k)
            add_load(std::size_t(slot_of_surface_[k]), surface_weight_[k] * force);
    }
}

void PatchModel::step(const ParticlePositions& positions, double dt_ms, double time_ms) {
    obstacle_force_.assign(obstacles_.size(), Eigen::Vector3d::Zero());
    if (!laid()) {
        clear_loads();
        contact_force_.setZero();
        return;
    }
    if (!(dt_ms > 0) || !std::isfinite(dt_ms)) throw InputError("patch: the step must be positive, ms");
    if (held_) {  // laid and not sewn: held in front of the defect
        clear_loads();
        contact_force_.setZero();
        return;
    }
    // A patch at rest on tissue at rest stays so: it sleeps, its loads as they were, until either
    // moves or a stitch is drawing.
    if (at_rest(positions, time_ms)) return;
    asleep_positions_ = positions;
    clear_loads();
    contact_force_.setZero();
    begin_surface(positions);  // each surface vertex and normal computed as the step first reads it
    if (surface_moved()) {     // the grid rebuilt where every triangle now lies and faces
        deform_surface(positions);
        build_surface_grid();
    }
    const double dt2 = dt_ms * dt_ms;
    const std::vector<Eigen::Vector3d> previous = x_;
    drift(dt_ms);
    StitchPull pull = stitch_pull(positions, dt_ms, time_ms);
    std::vector<double> lambda(distances_.size(), 0.0);
    update_compliance(dt_ms, dt2);
    StepContact contact = step_contact();
    // Each iteration, in this order: the stitches, the patch's own distances, the tissue's contact
    // with friction, and last the instruments, which push a vertex inside one (grown by half the
    // thickness) all the way to its surface (the hand moves the instrument, not the patch).
    for (int iteration = 0; iteration < spec_.iterations; ++iteration) {
        project_stitches(pull, dt2);
        project_distances(lambda);
        project_contact(contact, previous);
        project_obstacles(dt2);
    }
    for (std::size_t i = 0; i < x_.size(); ++i)
        if (inverse_mass_[i] > 0) v_[i] = (x_[i] - previous[i]) / dt_ms;
    load_tissue(pull, contact, dt2);
}

}  // namespace heartsim
