// The patch's exchange with a pass that steps it elsewhere (PatchPassInput and PatchPassState,
// patch.h): the patch flattened into arrays, the surface triangles each vertex may meet, and what
// the pass's steps left taken back into the model.
#include "libmodel/surgery/patch.h"

#include "libmodel/errors.h"
#include "libmodel/surgery/patch_internal.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

namespace heartsim {

using patch_internal::vec;

PatchPassInput PatchModel::pass_input(const ParticlePositions& positions, double reach_mm) {
    if (!laid()) throw InputError("patch: no patch is laid to step");
    PatchPassInput in;
    in.x = x_;
    in.v = v_;
    in.inverse_mass = inverse_mass_;
    for (const Distance& d : distances_) {
        in.distance_vertices.push_back({d.a, d.b});
        in.distance_rest_compliance.push_back({d.rest, d.compliance});
    }
    in.colour_first = colour_first_;
    in.particles = particles_;
    in.stepped_slot_x = stepped_slot_x_;
    in.surface_base = surface_base_;
    in.surface_first.assign(vertex_first_.begin(), vertex_first_.end());
    in.surface_slot.assign(slot_of_surface_.begin(), slot_of_surface_.end());
    in.surface_weight = surface_weight_;
    in.surface_inverse_mass.resize(surface_.vertices.size());
    for (std::size_t v = 0; v < surface_.vertices.size(); ++v) in.surface_inverse_mass[v] = vertex_inverse_mass(v) * mass_scale_;
    in.triangles = surface_.triangles;
    in.stitch_first.push_back(0);
    for (const Stitch& s : stitches_) {
        in.stitch_vertex.push_back(s.vertex);
        in.stitch_tied_ms.push_back(s.tied_ms);
        in.stitch_start_length.push_back(s.start_length);
        in.stitch_inverse_mass.push_back(inverse_mass_of(s.anchor) * mass_scale_);
        Eigen::Vector3d base = s.anchor.rest;
        for (const auto& [particle, weight] : s.anchor.carriers) {
            in.stitch_slot.push_back(std::int32_t(slot_of(particle)));
            in.stitch_weight.push_back(weight);
            base -= weight * vec(rest_[std::size_t(particle)]);
        }
        in.stitch_base.push_back(base);
        in.stitch_first.push_back(std::int32_t(in.stitch_slot.size()));
    }
    {  // the stitches coloured greedily in their order: a vertex's stitches take rising colours
        std::vector<int> colour(stitches_.size(), 0);
        std::map<int, int> next;  // per patch vertex: the colour its next stitch takes
        int colours = 0;
        for (std::size_t q = 0; q < stitches_.size(); ++q) {
            colour[q] = next[stitches_[q].vertex]++;
            colours = std::max(colours, colour[q] + 1);
        }
        for (int c = 0; c < colours; ++c) {
            in.stitch_colour_first.push_back(std::int32_t(in.stitch_order.size()));
            for (std::size_t q = 0; q < stitches_.size(); ++q)
                if (colour[q] == c) in.stitch_order.push_back(std::int32_t(q));
        }
        in.stitch_colour_first.push_back(std::int32_t(in.stitch_order.size()));
    }
    // Per slot: its surface vertices and stitches, with their weights (the loads' gather).
    auto invert = [&](const std::vector<std::int32_t>& first, const std::vector<std::int32_t>& slot, const std::vector<double>& weight,
                      std::vector<std::int32_t>& out_first, std::vector<std::int32_t>& out, std::vector<double>& out_weight) {
        out_first.assign(particles_.size() + 1, 0);
        for (std::int32_t s : slot) ++out_first[std::size_t(s) + 1];
        for (std::size_t k = 0; k < particles_.size(); ++k) out_first[k + 1] += out_first[k];
        out.assign(slot.size(), 0);
        out_weight.assign(slot.size(), 0.0);
        std::vector<std::int32_t> fill(out_first.begin(), out_first.end() - 1);
        for (std::size_t owner = 0; owner + 1 < first.size(); ++owner)
            for (std::int32_t k = first[owner]; k < first[owner + 1]; ++k) {
                const std::int32_t at = fill[std::size_t(slot[std::size_t(k)])]++;
                out[std::size_t(at)] = std::int32_t(owner);
                out_weight[std::size_t(at)] = weight[std::size_t(k)];
            }
    };
    invert(in.surface_first, in.surface_slot, in.surface_weight, in.slot_vertex_first, in.slot_vertex, in.slot_vertex_weight);
    invert(in.stitch_first, in.stitch_slot, in.stitch_weight, in.slot_stitch_first, in.slot_stitch, in.slot_stitch_weight);
    in.facing = facing_;
    in.acceleration = spec_.gravity * (1.0 - spec_.blood_density / spec_.material.density);
    in.thickness_mm = spec_.thickness_mm;
    in.friction = spec_.friction;
    in.damping_per_ms = spec_.damping_per_ms;
    in.tie_ms = spec_.tie_ms;
    in.stitch_stiffness = spec_.stitch_stiffness;
    in.iterations = spec_.iterations;
    in.edge_mm = spec_.edge_mm;
    in.search_again_mm = search_again();
    in.grid_margin_mm = grid_margin;
    in.largest_weight_sum = largest_weight_sum_;
    const std::size_t n = x_.size();
    PatchKeptState& kept = in.kept;
    kept.under = std::vector<std::int32_t>(under_.begin(), under_.end());
    kept.under.resize(n, -1);
    kept.searched_at = searched_at_;
    kept.searched_at.resize(n, Eigen::Vector3d::Zero());
    kept.searched_shift = searched_shift_;
    kept.searched_shift.resize(n, Eigen::Vector3d::Zero());
    kept.searched_travel = searched_travel_;
    kept.searched_travel.resize(n, std::numeric_limits<double>::quiet_NaN());
    kept.tissue_shift = tissue_shift_;
    kept.tissue_travel = tissue_travel_;
    kept.slot_x = slot_x_;
    kept.grid_slot_x = grid_slot_x_;
    for (const auto& p : asleep_positions_) kept.asleep_slot_x.push_back(vec(p));
    pass_candidates(in, positions, reach_mm);
    return in;
}

void PatchModel::pass_candidates(PatchPassInput& in, const ParticlePositions& positions, double reach_mm) const {
    if (positions.size() != particles_.size())
        throw InputError("patch: " + std::to_string(positions.size()) + " positions given for " + std::to_string(particles_.size()) + " particles");
    std::vector<Eigen::Vector3d> slot_x(positions.size());
    for (std::size_t k = 0; k < positions.size(); ++k) slot_x[k] = vec(positions[k]);
    pass_candidates(in, x_, slot_x, reach_mm);
}

void PatchModel::pass_candidates(PatchPassInput& in, const std::vector<Eigen::Vector3d>& x, const std::vector<Eigen::Vector3d>& slot_x,
                                 double reach_mm) const {
    if (!laid()) throw InputError("patch: no patch is laid to step");
    if (x.size() != x_.size() || slot_x.size() != particles_.size()) throw InputError("patch: a snapshot does not match the patch");
    // The triangles whose boxes (grid_over: where a point they hold in front of them can be), with
    // the surface where slot_x puts it, come within reach_mm of a vertex, from the cells around it.
    const SurfaceGrid g = grid_at(slot_x);
    const std::size_t n = x.size();
    in.candidate_first.assign(1, 0);
    in.candidate.clear();
    std::vector<std::uint32_t> seen(surface_.triangles.size(), 0);
    const double r = reach_mm;
    for (std::size_t i = 0; i < n; ++i) {
        const double u = x[i].dot(frame_.col(0)), w = x[i].dot(frame_.col(1)), along = x[i].dot(facing_);
        const std::size_t first = in.candidate.size();
        if (!g.cells.empty()) {
            const int i0 = std::clamp(int(std::floor((u - r - g.origin.x()) / grid_cell_)), 0, g.dims.x() - 1);
            const int i1 = std::clamp(int(std::floor((u + r - g.origin.x()) / grid_cell_)), 0, g.dims.x() - 1);
            const int j0 = std::clamp(int(std::floor((w - r - g.origin.y()) / grid_cell_)), 0, g.dims.y() - 1);
            const int j1 = std::clamp(int(std::floor((w + r - g.origin.y()) / grid_cell_)), 0, g.dims.y() - 1);
            for (int j = j0; j <= j1; ++j)
                for (int k = i0; k <= i1; ++k)
                    for (std::int32_t t : g.cells[std::size_t(j * g.dims.x() + k)]) {
                        if (seen[std::size_t(t)] == i + 1) continue;
                        seen[std::size_t(t)] = std::uint32_t(i + 1);
                        const auto& box = g.box[std::size_t(t)];
                        if (u < box[0] - r || w < box[1] - r || u > box[2] + r || w > box[3] + r || along < box[4] - r || along > box[5] + r) continue;
                        in.candidate.push_back(t);
                    }
        }
        std::sort(in.candidate.begin() + std::ptrdiff_t(first), in.candidate.end());
        in.candidate_first.push_back(std::int32_t(in.candidate.size()));
    }
    // Per surface vertex: the patch vertices (ascending) that one of its triangles is a candidate of.
    std::vector<std::vector<std::int32_t>> over(surface_.vertices.size());
    for (std::size_t i = 0; i < n; ++i)
        for (std::int32_t k = in.candidate_first[i]; k < in.candidate_first[i + 1]; ++k)
            for (std::int32_t corner : surface_.triangles[std::size_t(in.candidate[std::size_t(k)])])
                if (over[std::size_t(corner)].empty() || over[std::size_t(corner)].back() != std::int32_t(i))
                    over[std::size_t(corner)].push_back(std::int32_t(i));
    in.over_first.assign(1, 0);
    in.over.clear();
    for (const auto& list : over) {
        in.over.insert(in.over.end(), list.begin(), list.end());
        in.over_first.push_back(std::int32_t(in.over.size()));
    }
}

void PatchModel::take_pass_state(const PatchPassState& state, const std::vector<Eigen::Vector3d>& obstacle_forces) {
    if (state.x.size() != x_.size() || state.v.size() != v_.size() || state.stitch_force.size() != stitches_.size() ||
        (!state.stepped_slot_x.empty() && state.stepped_slot_x.size() != particles_.size()))
        throw InputError("patch: a pass's state does not match the patch");
    const std::size_t n = x_.size();
    const PatchKeptState& kept = state.kept;
    if (kept.under.size() != n || kept.searched_at.size() != n || kept.searched_shift.size() != n || kept.searched_travel.size() != n ||
        (!kept.slot_x.empty() && kept.slot_x.size() != particles_.size()) ||
        (!kept.grid_slot_x.empty() && kept.grid_slot_x.size() != particles_.size()) ||
        (!kept.asleep_slot_x.empty() && kept.asleep_slot_x.size() != particles_.size()))
        throw InputError("patch: a pass's state does not match the patch");
    x_ = state.x;
    v_ = state.v;
    for (std::size_t s = 0; s < stitches_.size(); ++s) stitches_[s].force_n = state.stitch_force[s];
    under_.assign(kept.under.begin(), kept.under.end());
    searched_at_ = kept.searched_at;
    searched_shift_ = kept.searched_shift;
    searched_travel_ = kept.searched_travel;
    tissue_shift_ = kept.tissue_shift;
    tissue_travel_ = kept.tissue_travel;
    if (kept.slot_x.size() != slot_x_.size() || !std::equal(kept.slot_x.begin(), kept.slot_x.end(), slot_x_.begin())) ++stamp_;  // the surface is computed afresh
    slot_x_ = kept.slot_x;
    if (kept.grid_slot_x.empty()) grid_slot_x_.clear();
    else if (kept.grid_slot_x != grid_slot_x_) {  // the pass's surface moved since: the grid where it last was
        grid_ = grid_at(kept.grid_slot_x);
        grid_slot_x_ = kept.grid_slot_x;
    }
    asleep_positions_.clear();
    for (const Eigen::Vector3d& p : kept.asleep_slot_x) asleep_positions_.push_back({float(p.x()), float(p.y()), float(p.z())});
    if (!obstacle_forces.empty() && obstacle_forces.size() != obstacles_.size())
        throw InputError("patch: a pass's obstacle forces do not match the obstacles");
    stepped_slot_x_ = state.stepped_slot_x;
    contact_force_ = state.contact_force;
    obstacle_force_ = obstacle_forces;
    obstacle_force_.resize(obstacles_.size(), Eigen::Vector3d::Zero());
    clear_loads();  // the pass put its loads on the tissue itself
}

}  // namespace heartsim
