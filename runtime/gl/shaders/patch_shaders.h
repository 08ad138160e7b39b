/// @file patch_shaders.h
/// @brief The patch's step as one compute workgroup (runtime/gl/patch_pass.cpp): libmodel/surgery/patch.cpp
/// PatchModel::step in double, phase by phase, with barriers where the CPU's loops follow one
/// another. The patch is a few hundred vertices: one workgroup of 256 invocations steps it, its
/// positions in shared memory, its distance constraints by colour (those of a colour share no
/// vertex), each vertex's contact and obstacles by the invocation that owns the vertex, the
/// stitches by colour as well (greedy in their order, so where two share a vertex the first goes
/// first, as on the host). Loads are gathered, never scattered, so the
/// pass has no atomics and its result does not depend on scheduling (a replay is bit for bit).
///
/// Differences from the CPU's step, each documented in docs/architecture.md (departure 15): the
/// pass looks for the triangle under every vertex at every step among that vertex's candidates
/// (the CPU keeps what it found while it still holds), and it never sleeps.
#pragma once

namespace heartsim::gl_shaders {

/// Largest patch the pass takes (its positions in shared memory: 24 KiB in double).
inline constexpr int patch_pass_max_vertices = 1024;

/// The out region (PatchLayout::s_out, doubles): each hand's force (3 + 3), the contact's sum (3),
/// each obstacle's push (3 + 3), then each stitch's pull (3 per stitch), N.
inline constexpr int patch_out_fixed = 15;

/// After sh::common and sh::geometry (solver_shaders.h).
inline constexpr const char* patch_step = R"(
#define MAXV 1024
#define GROUP 256u
layout(local_size_x = 256) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 tissue[]; };
layout(std430, binding = BINDING_LOAD) buffer LoadBuffer { vec4 load[]; };
layout(std430, binding = BINDING_PATCH_INTS) coherent buffer PatchInts { int ints[]; };
layout(std430, binding = BINDING_PATCH_CONSTANTS) readonly buffer PatchConstants { double kd[]; };
layout(std430, binding = BINDING_PATCH_STATE) coherent buffer PatchState { double sd[]; };

uniform uint vertex_count, colour_count, slot_count, surface_count, stitch_count, stitch_colour_count;
uniform int iterations;
uniform double dt, time_ms, mass_scale, thickness, friction, keep, tie_ms, stitch_stiffness;
uniform dvec3 acceleration, facing;
uniform int obstacle_count;
uniform dvec3 obstacle_centre[2];
uniform dmat3 obstacle_rotation[2];
uniform dvec3 obstacle_axes[2];   // grown by half the thickness
uniform double obstacle_reach[2]; // the largest semi-axis, half the thickness and an edge: near the patch within it
uniform double search_again, grid_margin, largest_weight_sum;
uniform int hand_output[2];       // −1 nothing, 0/1 an obstacle's push, 2 + s stitch s's pull
// Where each array starts in its buffer (patch_pass.cpp PatchLayout).
uniform uint i_dist, i_colour, i_particle, i_surface_first, i_surface_slot, i_triangle, i_stitch_vertex, i_stitch_first,
             i_stitch_slot, i_stitch_colour, i_stitch_order, i_slot_vertex_first, i_slot_vertex, i_slot_stitch_first, i_slot_stitch, i_candidate_first,
             i_candidate, i_over_first, i_over;
uniform uint k_inverse_mass, k_dist, k_surface_base, k_surface_weight, k_surface_w, k_stitch_tied, k_stitch_start, k_stitch_w,
             k_stitch_base, k_stitch_weight, k_slot_vertex_weight, k_slot_stitch_weight;
uniform uint s_x, s_v, s_stepped, s_slot_x, s_sx, s_previous, s_bary, s_normal, s_point, s_under_w, s_offset, s_pushed,
             s_carried, s_lambda, s_anchor, s_target, s_stitch_lambda, s_stitch_dir, s_anchor_offset, s_obstacle_push, s_force,
             s_surface_force, s_out, s_under, s_searched_at, s_searched_shift, s_searched_travel, s_searched_valid, s_global,
             s_grid, s_asleep;

shared double px[MAXV], py[MAXV], pz[MAXV];
shared double red[3u * GROUP];  // reductions
shared int rest_flag;

dvec3 k3(uint o, uint i) { return dvec3(kd[o + 3u * i], kd[o + 3u * i + 1u], kd[o + 3u * i + 2u]); }
dvec3 s3(uint o, uint i) { return dvec3(sd[o + 3u * i], sd[o + 3u * i + 1u], sd[o + 3u * i + 2u]); }
void put3(uint o, uint i, dvec3 v) { sd[o + 3u * i] = v.x; sd[o + 3u * i + 1u] = v.y; sd[o + 3u * i + 2u] = v.z; }
dvec3 P(uint i) { return dvec3(px[i], py[i], pz[i]); }
void setP(uint i, dvec3 v) { px[i] = v.x; py[i] = v.y; pz[i] = v.z; }
dvec3 cross3(dvec3 a, dvec3 b) {
    precise double x = a.y * b.z - a.z * b.y, y = a.z * b.x - a.x * b.z, z = a.x * b.y - a.y * b.x;
    return dvec3(x, y, z);
}
void sync() { memoryBarrierShared(); memoryBarrierBuffer(); barrier(); }

// patch.cpp barycentric: the weights of p's projection onto (a, b, c).
dvec3 barycentric(dvec3 p, dvec3 a, dvec3 b, dvec3 c) {
    dvec3 v0 = b - a, v1 = c - a, v2 = p - a;
    double d00 = dot3(v0, v0), d01 = dot3(v0, v1), d11 = dot3(v1, v1), d20 = dot3(v2, v0), d21 = dot3(v2, v1);
    precise double denominator = d00 * d11 - d01 * d01;
    if (!(abs(denominator) > 1e-18lf)) return dvec3(-1.0lf);
    precise double v = (d11 * d20 - d01 * d21) / denominator, w = (d00 * d21 - d01 * d20) / denominator;
    return dvec3(1.0lf - v - w, v, w);
}
dvec3 unit_normal(dvec3 a, dvec3 b, dvec3 c) {
    dvec3 n = cross3(b - a, c - a);
    double length = sqrt(dot3(n, n));
    return length > 0.0lf ? n / length : dvec3(0.0lf);
}
dvec3 surface_x(int v) { return s3(s_sx, uint(v)); }
// Sums and largest values over the work group, in a fixed order (a tree): every invocation calls them.
dvec3 reduce_sum3(dvec3 v) {
    uint tid = gl_LocalInvocationID.x;
    red[tid] = v.x; red[GROUP + tid] = v.y; red[2u * GROUP + tid] = v.z;
    sync();
    for (uint stride = GROUP / 2u; stride > 0u; stride >>= 1u) {
        if (tid < stride) {
            red[tid] = red[tid] + red[tid + stride];
            red[GROUP + tid] = red[GROUP + tid] + red[GROUP + tid + stride];
            red[2u * GROUP + tid] = red[2u * GROUP + tid] + red[2u * GROUP + tid + stride];
        }
        sync();
    }
    dvec3 r = dvec3(red[0], red[GROUP], red[2u * GROUP]);
    sync();
    return r;
}
double reduce_max(double v) {
    uint tid = gl_LocalInvocationID.x;
    red[tid] = v;
    sync();
    for (uint stride = GROUP / 2u; stride > 0u; stride >>= 1u) {
        if (tid < stride) red[tid] = max(red[tid], red[tid + stride]);
        sync();
    }
    double r = red[0];
    sync();
    return r;
}
)"
R"(
void main() {
    uint tid = gl_LocalInvocationID.x;
    double dt2 = dt * dt, half_t = 0.5lf * thickness;
    bool has_stepped = sd[s_stepped + 3u * slot_count] != 0.0lf;
    // At rest (PatchModel::at_rest): the patch and the tissue it touches still since it last
    // stepped, no stitch drawing, no obstacle near: it sleeps, its loads as they were.
    if (tid == 0u) rest_flag = sd[s_global + 6u] != 0.0lf ? 1 : 0;
    sync();
    if (rest_flag != 0) {
        for (uint q = 0u; q < stitch_count; ++q)
            if (time_ms < kd[k_stitch_tied + q] + tie_ms) rest_flag = 0;  // benign race: every writer writes 0
        for (uint i = tid; i < vertex_count; i += GROUP) {
            dvec3 v = s3(s_v, i), x = s3(s_x, i);
            if (dot3(v, v) > 1e-10lf) rest_flag = 0;
            for (int o = 0; o < obstacle_count; ++o) {
                dvec3 d = x - obstacle_centre[o];
                if (dot3(d, d) < obstacle_reach[o] * obstacle_reach[o]) rest_flag = 0;
            }
        }
        for (uint k = tid; k < slot_count; k += GROUP) {
            dvec3 d = abs(dvec3(tissue[uint(ints[i_particle + k])].xyz) - s3(s_asleep, k));
            if (d.x > 1e-5lf || d.y > 1e-5lf || d.z > 1e-5lf) rest_flag = 0;
        }
    }
    sync();
    if (rest_flag != 0) return;
    // The tissue's particles it reads, as the step starts: their mean displacement since the last
    // step (the tissue's shift) and the largest departure from it (its deformation), accumulated.
    bool slot_valid = sd[s_global + 4u] != 0.0lf;
    precise dvec3 moved = dvec3(0.0lf);
    for (uint k = tid; k < slot_count; k += GROUP) {
        dvec3 now = dvec3(tissue[uint(ints[i_particle + k])].xyz);
        put3(s_asleep, k, now);
        if (slot_valid) moved = moved + (now - s3(s_slot_x, k));
    }
    dvec3 total = reduce_sum3(moved);
    dvec3 mean = slot_count > 0u && slot_valid ? total / double(slot_count) : dvec3(0.0lf);
    double departed2 = 0.0lf;
    for (uint k = tid; k < slot_count; k += GROUP) {
        dvec3 now = s3(s_asleep, k);
        if (slot_valid) { dvec3 d = now - s3(s_slot_x, k) - mean; departed2 = max(departed2, dot3(d, d)); }
        put3(s_slot_x, k, now);
    }
    departed2 = reduce_max(departed2);
    double drift2 = 0.0lf;
    bool grid_valid = sd[s_global + 5u] != 0.0lf;
    for (uint k = tid; k < slot_count; k += GROUP)
        if (grid_valid) { dvec3 d = s3(s_slot_x, k) - s3(s_grid, k); drift2 = max(drift2, dot3(d, d)); }
    drift2 = reduce_max(drift2);
    double limit = 0.5lf * grid_margin / largest_weight_sum;
    bool regrid = !grid_valid || drift2 > limit * limit;  // the host rebuilds its grid: every vertex looks again
    if (tid == 0u) {
        put3(s_global, 0u, s3(s_global, 0u) + mean);
        sd[s_global + 3u] = sd[s_global + 3u] + largest_weight_sum * sqrt(departed2);
        sd[s_global + 4u] = 1.0lf;
        sd[s_global + 5u] = 1.0lf;
        sd[s_global + 6u] = 1.0lf;  // asleep positions kept
    }
    for (uint k = tid; k < slot_count; k += GROUP)
        if (regrid) put3(s_grid, k, s3(s_slot_x, k));
    for (uint i = tid; i < vertex_count; i += GROUP)
        if (!slot_valid || regrid) sd[s_searched_valid + i] = 0.0lf;
    sync();
    dvec3 shift = s3(s_global, 0u);
    double travel = sd[s_global + 3u];
    for (uint v = tid; v < surface_count; v += GROUP) {
        precise dvec3 x = k3(k_surface_base, v);
        for (int e = ints[i_surface_first + v]; e < ints[i_surface_first + v + 1u]; ++e)
            x = x + kd[k_surface_weight + uint(e)] * s3(s_slot_x, uint(ints[i_surface_slot + uint(e)]));
        put3(s_sx, v, x);
    }
    sync();
    // Each vertex: predicted, the facing triangle under it (what it found last time while that
    // still holds, else looked for among its candidates), how far the tissue there yields and moved.
    for (uint i = tid; i < vertex_count; i += GROUP) {
        double w = kd[k_inverse_mass + i];
        precise dvec3 x = s3(s_x, i), v = s3(s_v, i);
        put3(s_previous, i, x);
        if (w != 0.0lf) {
            v = keep * (v + acceleration * dt);
            x = x + v * dt;
        }
        setP(i, x);
        int best = int(sd[s_under + i]);
        dvec3 bary = dvec3(0.0lf);
        bool look = w != 0.0lf;
        if (look) {
            bool still = sd[s_searched_valid + i] != 0.0lf &&
                         length(x - s3(s_searched_at, i) - (shift - s3(s_searched_shift, i))) + (travel - sd[s_searched_travel + i]) <
                             search_again;
            if (best >= 0) {
                dvec3 pa = surface_x(ints[i_triangle + 3u * uint(best)]), pb = surface_x(ints[i_triangle + 3u * uint(best) + 1u]),
                      pc = surface_x(ints[i_triangle + 3u * uint(best) + 2u]);
                double d = dot3(x - pa, unit_normal(pa, pb, pc));
                dvec3 b = barycentric(x, pa, pb, pc);
                if (min(min(b.x, b.y), b.z) >= 0.0lf && (abs(d) < half_t + 0.5lf || (still && d >= -2.0lf && d <= 3.0lf + thickness))) {
                    bary = b;
                    look = false;
                }
            } else if (still) {
                look = false;
            }
        }
        if (look) {
            best = -1;
            double best_depth = 1e300lf;
            for (int c = ints[i_candidate_first + i]; c < ints[i_candidate_first + i + 1u]; ++c) {
                int t = ints[i_candidate + uint(c)];
                dvec3 pa = surface_x(ints[i_triangle + 3u * uint(t)]), pb = surface_x(ints[i_triangle + 3u * uint(t) + 1u]),
                      pc = surface_x(ints[i_triangle + 3u * uint(t) + 2u]);
                dvec3 n = unit_normal(pa, pb, pc);
                double d = dot3(x - pa, n);
                if (d < -2.0lf || d > 3.0lf + thickness) continue;  // another layer of the tissue
                if (!(dot3(n, facing) < -0.3lf)) continue;
                dvec3 b = barycentric(x, pa, pb, pc);
                if (min(min(b.x, b.y), b.z) < -1e-9lf) continue;
                if (abs(d) < abs(best_depth)) { best = t; best_depth = d; bary = b; }
            }
            put3(s_searched_at, i, x);
            put3(s_searched_shift, i, shift);
            sd[s_searched_travel + i] = travel;
            sd[s_searched_valid + i] = 1.0lf;
        }
        dvec3 normal = dvec3(0.0lf), point = dvec3(0.0lf);
        if (best >= 0) {
            point = surface_x(ints[i_triangle + 3u * uint(best)]);
            normal = unit_normal(point, surface_x(ints[i_triangle + 3u * uint(best) + 1u]), surface_x(ints[i_triangle + 3u * uint(best) + 2u]));
        }
        sd[s_under + i] = double(best);
        put3(s_bary, i, bary);
        put3(s_normal, i, normal);
        put3(s_point, i, point);
        precise double under_w = 0.0lf;
        precise dvec3 carried = dvec3(0.0lf);
        if (best >= 0) {
            for (uint c = 0u; c < 3u; ++c) {
                double bc = c == 0u ? bary.x : (c == 1u ? bary.y : bary.z);
                int sv = ints[i_triangle + 3u * uint(best) + c];
                under_w = under_w + bc * bc * (kd[k_surface_w + uint(sv)] / mass_scale);
                if (has_stepped)
                    for (int e = ints[i_surface_first + uint(sv)]; e < ints[i_surface_first + uint(sv) + 1u]; ++e) {
                        uint slot = uint(ints[i_surface_slot + uint(e)]);
                        carried = carried + bc * kd[k_surface_weight + uint(e)] * (s3(s_slot_x, slot) - s3(s_stepped, slot));
                    }
            }
        }
        sd[s_under_w + i] = under_w;
        sd[s_offset + i] = 0.0lf;
        put3(s_pushed, i, dvec3(0.0lf));
        put3(s_carried, i, carried);
        put3(s_obstacle_push, 2u * i, dvec3(0.0lf));
        put3(s_obstacle_push, 2u * i + 1u, dvec3(0.0lf));
    }
    // The stitches' anchors where the tissue is, and their lengths this step (a smoothstep).
    for (uint q = tid; q < stitch_count; q += GROUP) {
        precise dvec3 a = k3(k_stitch_base, q);
        for (int e = ints[i_stitch_first + q]; e < ints[i_stitch_first + q + 1u]; ++e)
            a = a + kd[k_stitch_weight + uint(e)] * s3(s_slot_x, uint(ints[i_stitch_slot + uint(e)]));
        put3(s_anchor, q, a);
        double tau = clamp((time_ms + dt - kd[k_stitch_tied + q]) / tie_ms, 0.0lf, 1.0lf);
        precise double drawn = tau * tau * (3.0lf - 2.0lf * tau);
        double start = kd[k_stitch_start + q];
        sd[s_target + q] = max(half_t, start + (half_t - start) * drawn);
        sd[s_stitch_lambda + q] = 0.0lf;
        put3(s_stitch_dir, q, dvec3(0.0lf));
        put3(s_anchor_offset, q, dvec3(0.0lf));
    }
    uint distance_end = uint(ints[i_colour + colour_count]);
    for (uint k = tid; k < distance_end; k += GROUP) sd[s_lambda + k] = 0.0lf;
    sync();
)"
R"(
    for (int iteration = 0; iteration < iterations; ++iteration) {
        // The stitches by colour (those of a colour tie different vertices: in parallel, and in the
        // host's order wherever two share one).
        for (uint c = 0u; c < stitch_colour_count; ++c) {
            uint first = uint(ints[i_stitch_colour + c]), end = uint(ints[i_stitch_colour + c + 1u]);
            for (uint e = first + tid; e < end; e += GROUP) {
                uint q = uint(ints[i_stitch_order + e]);
                uint i = uint(ints[i_stitch_vertex + q]);
                double w = kd[k_inverse_mass + i], wt = kd[k_stitch_w + q] / mass_scale;
                dvec3 delta = P(i) - (s3(s_anchor, q) + s3(s_anchor_offset, q));
                double length = sqrt(dot3(delta, delta)), target = sd[s_target + q];
                if (!(length > target) || !(length > 1e-12lf)) continue;  // a suture pulls, never pushes
                delta = delta / length;
                double alpha = 1.0lf / (stitch_stiffness * dt2);
                precise double dl = (-(length - target) - alpha * sd[s_stitch_lambda + q]) / (w + wt + alpha);
                sd[s_stitch_lambda + q] = sd[s_stitch_lambda + q] + dl;
                put3(s_stitch_dir, q, delta);
                setP(i, P(i) + w * dl * delta);
                put3(s_anchor_offset, q, s3(s_anchor_offset, q) - wt * dl * delta);
            }
            sync();
        }
        for (uint c = 0u; c < colour_count; ++c) {
            uint first = uint(ints[i_colour + c]), end = uint(ints[i_colour + c + 1u]);
            for (uint k = first + tid; k < end; k += GROUP) {
                uint a = uint(ints[i_dist + 2u * k]), b = uint(ints[i_dist + 2u * k + 1u]);
                double wa = kd[k_inverse_mass + a], wb = kd[k_inverse_mass + b];
                double rest = kd[k_dist + 2u * k], alpha = kd[k_dist + 2u * k + 1u] / dt2;
                double sum = wa + wb;
                double denominator = sum == 0.0lf ? 0.0lf : 1.0lf / (sum + alpha);
                dvec3 delta = P(a) - P(b);
                double length2 = dot3(delta, delta);
                if (!(length2 > 1e-24lf) || denominator == 0.0lf) continue;
                double inverse = 1.0lf / sqrt(length2);
                precise double length = length2 * inverse;
                precise double dl = (-(length - rest) - alpha * sd[s_lambda + k]) * denominator;
                sd[s_lambda + k] = sd[s_lambda + k] + dl;
                delta = delta * (dl * inverse);
                setP(a, P(a) + wa * delta);
                setP(b, P(b) - wb * delta);
            }
            sync();
        }
        for (uint i = tid; i < vertex_count; i += GROUP) {
            double w = kd[k_inverse_mass + i];
            int t = int(sd[s_under + i]);
            if (t >= 0) {
                // One-sided contact, the tissue under it yielding its share (predicted); friction
                // against the slip relative to the tissue.
                dvec3 normal = s3(s_normal, i);
                double depth = dot3(P(i) - s3(s_point, i), normal) - sd[s_offset + i];
                if (depth < half_t) {
                    double share = w / (w + sd[s_under_w + i]);
                    dvec3 push = share * (half_t - depth) * normal;
                    sd[s_offset + i] = sd[s_offset + i] - (1.0lf - share) * (half_t - depth);
                    setP(i, P(i) + push);
                    dvec3 pushed = s3(s_pushed, i) + push;
                    dvec3 slip = P(i) - s3(s_previous, i) - s3(s_carried, i);
                    slip = slip - dot3(slip, normal) * normal;
                    double length = sqrt(dot3(slip, slip)), hold = friction * (half_t - depth);
                    dvec3 undo = length <= hold ? slip : slip * (hold / length);
                    setP(i, P(i) - undo);
                    put3(s_pushed, i, pushed - undo);
                }
            }
            if (w == 0.0lf) continue;
            for (int o = 0; o < obstacle_count; ++o) {
                dvec3 axes = obstacle_axes[o];
                dvec3 local = rotate_back(obstacle_rotation[o], P(i) - obstacle_centre[o]);
                dvec3 q = local / axes;
                if (!(dot3(q, q) < 1.0lf)) continue;
                dvec3 push = rotate(obstacle_rotation[o], ellipsoid_nearest(local, axes) - local);
                setP(i, P(i) + push);
                put3(s_obstacle_push, 2u * i + uint(o), s3(s_obstacle_push, 2u * i + uint(o)) + push);
            }
        }
        sync();
    }
)"
R"(
    // Velocities and forces: a stitch's pull on the patch λ·n/dt², the contact's m·Δx/dt².
    for (uint i = tid; i < vertex_count; i += GROUP) {
        double w = kd[k_inverse_mass + i];
        dvec3 x = P(i);
        put3(s_x, i, x);
        if (w > 0.0lf) put3(s_v, i, (x - s3(s_previous, i)) / dt);
        dvec3 pushed = s3(s_pushed, i);
        bool pressed = int(sd[s_under + i]) >= 0 && w != 0.0lf && (pushed.x != 0.0lf || pushed.y != 0.0lf || pushed.z != 0.0lf);
        put3(s_force, i, pressed ? pushed / (w * dt2) : dvec3(0.0lf));
    }
    for (uint q = tid; q < stitch_count; q += GROUP) put3(s_out + 15u, q, sd[s_stitch_lambda + q] * s3(s_stitch_dir, q) / dt2);
    sync();
    // The contact's forces on the surface vertices under the patch (gathered from the patch
    // vertices that can lie over each), then every load on the particles.
    for (uint v = tid; v < surface_count; v += GROUP) {
        precise dvec3 f = dvec3(0.0lf);
        for (int e = ints[i_over_first + v]; e < ints[i_over_first + v + 1u]; ++e) {
            uint i = uint(ints[i_over + uint(e)]);
            int t = int(sd[s_under + i]);
            if (t < 0) continue;
            dvec3 bary = s3(s_bary, i);
            for (uint c = 0u; c < 3u; ++c)
                if (ints[i_triangle + 3u * uint(t) + c] == int(v)) f = f - (c == 0u ? bary.x : (c == 1u ? bary.y : bary.z)) * s3(s_force, i);
        }
        put3(s_surface_force, v, f);
    }
    sync();
    for (uint k = tid; k < slot_count; k += GROUP) {
        precise dvec3 f = dvec3(0.0lf);
        for (int e = ints[i_slot_stitch_first + k]; e < ints[i_slot_stitch_first + k + 1u]; ++e)
            f = f - kd[k_slot_stitch_weight + uint(e)] * s3(s_out + 15u, uint(ints[i_slot_stitch + uint(e)]));
        for (int e = ints[i_slot_vertex_first + k]; e < ints[i_slot_vertex_first + k + 1u]; ++e)
            f = f + kd[k_slot_vertex_weight + uint(e)] * s3(s_surface_force, uint(ints[i_slot_vertex + uint(e)]));
        load[uint(ints[i_particle + k])] = vec4(vec3(f), 0.0);
        put3(s_stepped, k, s3(s_slot_x, k));
    }
    // Out: the contact's sum and the obstacles' pushes (each invocation's vertices, then a tree).
    precise dvec3 contact = dvec3(0.0lf), o0 = dvec3(0.0lf), o1 = dvec3(0.0lf);
    for (uint i = tid; i < vertex_count; i += GROUP) {
        contact = contact + s3(s_force, i);
        double w = kd[k_inverse_mass + i];
        if (w == 0.0lf) continue;
        o0 = o0 - s3(s_obstacle_push, 2u * i) / (w * dt2);
        o1 = o1 - s3(s_obstacle_push, 2u * i + 1u) / (w * dt2);
    }
    contact = reduce_sum3(contact);
    o0 = reduce_sum3(o0);
    o1 = reduce_sum3(o1);
    if (tid == 0u) {
        put3(s_out, 2u, contact);
        put3(s_out, 3u, o0);
        put3(s_out, 4u, o1);
        for (int h = 0; h < 2; ++h) {
            int what = hand_output[h];
            dvec3 f = what == 0 ? o0 : (what == 1 ? o1 : (what >= 2 && uint(what - 2) < stitch_count ? s3(s_out + 15u, uint(what - 2)) : dvec3(0.0lf)));
            put3(s_out, h == 0 ? 0u : 1u, f);
        }
        sd[s_stepped + 3u * slot_count] = 1.0lf;
    }
}
)";

}  // namespace heartsim::gl_shaders
