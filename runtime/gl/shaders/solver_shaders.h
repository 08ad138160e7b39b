/// @file solver_shaders.h
/// @brief GLSL 4.30 compute shaders of the GL backend (backend_gl.cpp): each program is `common`
/// and one pass, after the preamble compile_shader puts first (bindings.h). Every arithmetic
/// expression mirrors libmodel/sim/solver.cpp operation for operation (same order, `precise` so that
/// no multiply-add is fused except the five fma() of a spring slot, where the CPU kernels fuse
/// them too), so the GPU step is the CPU step: float for the springs and integration, double
/// for the instrument geometry (probe projection, grab capture and follow, forces), as on the CPU.
#pragma once

namespace heartsim::gl_shaders {

inline constexpr const char* common = R"(
#extension GL_ARB_gpu_shader_fp64 : enable
// support_stiffness (N/mm), support_point.xyz (mm) and support_point.w (its dashpot c/h, N/mm):
// the particle's support (libmodel/supports.h), stiffness 0 where it has none.
struct Particle { float mass; float inverse_mass_h2; int movable; float support_stiffness; vec4 support_point; };
layout(std430, binding = BINDING_PARTICLE) readonly buffer ParticleBuffer { Particle particle[]; };
layout(std430, binding = BINDING_HELD_BY) buffer HeldByBuffer { int held_by[]; };
layout(std430, binding = BINDING_COUNTERS) buffer CounterBuffer { uint counter[]; };
uniform uint particle_count;   // real particles N
uniform uint padded_count;     // N rounded up to 8
uniform bool supported;        // any particle has a support spring
)";

/// The positions, motion and springs that the step and force passes both read.
inline constexpr const char* springs = R"(
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_MOTION) readonly buffer MotionBuffer { vec4 u[]; };
layout(std430, binding = BINDING_NEIGHBOUR) readonly buffer NeighbourBuffer { int neighbour[]; };
layout(std430, binding = BINDING_REST_LENGTH) readonly buffer RestBuffer { float rest_length[]; };
layout(std430, binding = BINDING_STIFFNESS) readonly buffer StiffnessBuffer { float stiffness[]; };
layout(std430, binding = BINDING_DASHPOT) readonly buffer DashpotBuffer { float dashpot[]; };
)";

/// Instrument geometry in double that the step and the patch's pass share: rotations in Eigen's
/// order, dot products, and the nearest point of an ellipsoid.
inline constexpr const char* geometry = R"(
dvec3 rotate(dmat3 r, dvec3 v) {          // r · v, Eigen's order
    precise double a = r[0][0] * v.x + r[1][0] * v.y; a = a + r[2][0] * v.z;
    precise double b = r[0][1] * v.x + r[1][1] * v.y; b = b + r[2][1] * v.z;
    precise double c = r[0][2] * v.x + r[1][2] * v.y; c = c + r[2][2] * v.z;
    return dvec3(a, b, c);
}
dvec3 rotate_back(dmat3 r, dvec3 v) {     // rᵀ · v
    precise double a = r[0][0] * v.x + r[0][1] * v.y; a = a + r[0][2] * v.z;
    precise double b = r[1][0] * v.x + r[1][1] * v.y; b = b + r[1][2] * v.z;
    precise double c = r[2][0] * v.x + r[2][1] * v.y; c = c + r[2][2] * v.z;
    return dvec3(a, b, c);
}
double squared_norm(dvec3 v) { precise double s = v.x * v.x + v.y * v.y; s = s + v.z * v.z; return s; }
double dot3(dvec3 a, dvec3 b) { precise double s = a.x * b.x + a.y * b.y; s = s + a.z * b.z; return s; }

// The nearest surface point of the ellipsoid with semi-axes a from y inside it, in its frame:
// libmodel/ellipsoid.cpp nearest_point_on_ellipsoid, the same steps in double. Components by a
// loop index go through double[3] arrays: NVIDIA's GLSL compiler cannot write a dvec3 component
// by a variable index (it fails to link with "can't find __setVectorIndex").
dvec3 ellipsoid_nearest(dvec3 y_in, dvec3 a_in) {
    double a[3] = double[3](a_in.x, a_in.y, a_in.z);
    double y[3] = double[3](y_in.x, y_in.y, y_in.z);
    double a2[3] = double[3](a[0] * a[0], a[1] * a[1], a[2] * a[2]);
    double m = min(min(a2[0], a2[1]), a2[2]);
    bool shortest[3];
    precise double w2 = 0.0lf, g = 0.0lf;
    for (int i = 0; i < 3; ++i) {
        shortest[i] = a2[i] <= m * (1.0lf + 1e-12lf);
        if (shortest[i]) w2 = w2 + y[i] * y[i];
        else { precise double q = a[i] * y[i] / (a2[i] - m); g = g + q * q; }
    }
    double x[3];
    if (g <= 1.0lf && w2 <= 1e-18lf * m) {
        double w = sqrt(w2);
        int fallback = shortest[2] ? 2 : (shortest[0] ? 0 : 1);
        double along = sqrt(m * (1.0lf - g));
        for (int i = 0; i < 3; ++i) {
            if (!shortest[i]) x[i] = a2[i] * y[i] / (a2[i] - m);
            else if (w > 0.0lf) x[i] = along * y[i] / w;
            else x[i] = i == fallback ? along : 0.0lf;
        }
        return dvec3(x[0], x[1], x[2]);
    }
    // F(t) > 0 without a division (ellipsoid.cpp): Σ p_i Π_{j≠i} d_j > Π d_j, d_i = (a_i² + t)².
    precise dvec3 p = (a_in * y_in) * (a_in * y_in);
    double low = -m, high = 0.0lf;
    for (int iteration = 0; iteration < 80; ++iteration) {
        precise double middle = 0.5lf * (low + high);
        if (middle <= low || middle >= high) break;
        precise double d0 = (a2[0] + middle) * (a2[0] + middle), d1 = (a2[1] + middle) * (a2[1] + middle), d2 = (a2[2] + middle) * (a2[2] + middle);
        precise double n = p.x * d1 * d2 + p.y * d0 * d2;
        n = n + p.z * d0 * d1;
        if (n > d0 * d1 * d2) low = middle; else high = middle;
    }
    for (int i = 0; i < 3; ++i) x[i] = a2[i] * y[i] / (a2[i] + high);
    return dvec3(x[0], x[1], x[2]);
}
)";

/// One substep: gather the 18 slots, integrate, check the displacement, add the external loads,
/// project out of probes. Positions x and the motion of the last substep u = x_n − x_{n−1} are
/// kept apart, as on the CPU.
inline constexpr const char* step = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_NEXT) writeonly buffer NextBuffer { vec4 xn[]; };
layout(std430, binding = BINDING_NEXT_MOTION) writeonly buffer NextMotionBuffer { vec4 un[]; };
layout(std430, binding = BINDING_TOUCHED) writeonly buffer TouchedBuffer { int touched[]; };
layout(std430, binding = BINDING_LOAD) readonly buffer LoadBuffer { vec4 load[]; };  // N, zero where none
layout(std430, binding = BINDING_SKIN) readonly buffer SkinBuffer { double reach_beyond[]; };  // Solver::reach_beyond, mm
layout(std430, binding = BINDING_CELL_FORCE) readonly buffer CellForceBuffer { float cell_force[]; };  // 8 slots of 3 per particle (cell_pass)

uniform float keep;             // 1 − γh
uniform vec3 gravity;           // mm/ms²
uniform float max_displacement2;
uniform bool damped;
uniform int probe_count;
uniform int probe_hand[2];
uniform dvec3 probe_centre[2];
uniform dmat3 probe_rotation[2];
uniform dvec3 probe_previous_centre[2];
uniform dmat3 probe_previous_rotation[2];
uniform dvec3 probe_semi_axes[2];
uniform float probe_bound2[2];
uniform double pierce_strain;   // SolverOptions::probe_pierce_strain; ≤ 0: never pierces
uniform bool loaded;            // some particle has a load (set_loads), or the volume term: read them
uniform bool volume_term;       // the cells' forces (cell_pass) in `cell_force`'s slots
uniform bool external_loads;    // with volume_term: some particle has a load in `load`

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= padded_count) return;
    uint group = i / 8u, lane = i % 8u;
    vec4 own = x[i], own_motion = u[i];
    precise float xi = own.x, yi = own.y, zi = own.z;
    precise float uxi = own_motion.x, uyi = own_motion.y, uzi = own_motion.z;
    precise float fx = 0.0, fy = 0.0, fz = 0.0;
    uint table = group * 18u * 8u + lane;
    for (uint s = 0u; s < 18u; ++s) {
        uint t = table + s * 8u;
        uint j = uint(neighbour[t]);
        vec4 pj = x[j];
        precise float dx = pj.x - xi, dy = pj.y - yi, dz = pj.z - zi;
        precise float length2 = fma(dy, dy, dx * dx);
        length2 = fma(dz, dz, length2);
        precise float len = sqrt(length2 > 1e-30 ? length2 : 1e-30);
        precise float inverse = 1.0 / len;
        precise float scale = (stiffness[t] * (len - rest_length[t])) * inverse;
        if (damped) {
            vec4 qj = u[j];
            precise float dux = qj.x - uxi, duy = qj.y - uyi, duz = qj.z - uzi;
            precise float along = fma(duy, dy, dux * dx);
            along = fma(duz, dz, along) * inverse;
            along = along * inverse;
            scale = fma(dashpot[t], along, scale);
        }
        fx = fma(scale, dx, fx);
        fy = fma(scale, dy, fy);
        fz = fma(scale, dz, fz);
    }
    Particle p = particle[i];
    if (supported) {  // zero-rest-length support spring, after the 18 slots (solver.cpp order)
        fx = fx + (p.support_stiffness * (p.support_point.x - xi) - p.support_point.w * uxi);
        fy = fy + (p.support_stiffness * (p.support_point.y - yi) - p.support_point.w * uyi);
        fz = fz + (p.support_stiffness * (p.support_point.z - zi) - p.support_point.w * uzi);
    }
    precise float ex = keep * uxi + (fx + p.mass * gravity.x) * p.inverse_mass_h2;
    precise float ey = keep * uyi + (fy + p.mass * gravity.y) * p.inverse_mass_h2;
    precise float ez = keep * uzi + (fz + p.mass * gravity.z) * p.inverse_mass_h2;
    precise float nx = xi + ex, ny = yi + ey, nz = zi + ez;
    precise float d2 = ex * ex + ey * ey;
    d2 = d2 + ez * ez;
    if (!(d2 <= max_displacement2)) atomicOr(counter[COUNTER_STATUS], 1u);
    // External loads (Solver::substep, after the kernel): h²F/(S·m) more position and motion on a
    // movable particle that no grabber holds, rounded apart as on the CPU.
    if (loaded && p.movable != 0 && held_by[i] < 0) {
        vec4 f;
        if (volume_term) {  // the particle's 8 slots in order, then its load: Solver's load_and_project sum
            precise vec3 sum = vec3(0.0);
            for (uint r = 0u; r < 8u; ++r) {
                uint at = 24u * i + 3u * r;
                sum = vec3(sum.x + cell_force[at], sum.y + cell_force[at + 1u], sum.z + cell_force[at + 2u]);
            }
            if (external_loads) {
                vec4 l = load[i];
                sum = vec3(sum.x + l.x, sum.y + l.y, sum.z + l.z);
            }
            f = vec4(sum, 0.0);
        } else
            f = load[i];
        precise float lx = p.inverse_mass_h2 * f.x, ly = p.inverse_mass_h2 * f.y, lz = p.inverse_mass_h2 * f.z;
        nx = nx + lx; ny = ny + ly; nz = nz + lz;
        ex = ex + lx; ey = ey + ly; ez = ez + lz;
    }
    vec4 motion = vec4(ex, ey, ez, 0.0);

    // Probes (libmodel/sim/solver.cpp `project`): exact test and projection in double.
    if (i < particle_count && p.movable != 0 && held_by[i] < 0) {
        for (int q = 0; q < probe_count; ++q) {
            precise float cx = float(probe_centre[q].x), cy = float(probe_centre[q].y), cz = float(probe_centre[q].z);
            precise float bx = nx - cx, by = ny - cy, bz = nz - cz;
            precise float b2 = bx * bx + by * by;
            b2 = b2 + bz * bz;
            if (!(b2 < probe_bound2[q])) continue;
            dmat3 r = probe_rotation[q];
            precise dvec3 semi = max(probe_semi_axes[q] + dvec3(reach_beyond[i]), 0.5lf * probe_semi_axes[q]);  // Solver::met_axes
            dvec3 world = dvec3(double(nx), double(ny), double(nz));
            precise dvec3 local = rotate_back(r, world - probe_centre[q]);
            precise double r2 = squared_norm(local / semi);
            if (!(r2 < 1.0lf)) continue;
            local = ellipsoid_nearest(local, semi);
            precise double factor = 1.0lf + 1e-6lf;
            dvec3 stored = world;  // the loop below sets it at its first attempt
            for (int attempt = 0; attempt < 60; ++attempt) {
                precise dvec3 out_position = probe_centre[q] + rotate(r, local * factor);
                nx = float(out_position.x); ny = float(out_position.y); nz = float(out_position.z);
                stored = dvec3(double(nx), double(ny), double(nz));
                if (squared_norm(rotate_back(r, stored - probe_centre[q]) / semi) >= 1.0lf + 1e-6lf) break;
                factor = factor * (1.0lf + 1e-6lf * double(1 << min(attempt, 20)));
            }
            if (pierce_strain > 0.0lf) {  // Solver's `project`: strain_at against the current positions
                precise float worst = 0.0;
                uint table = group * 18u * 8u + lane;
                for (uint s = 0u; s < 18u; ++s) {
                    uint t = table + s * 8u;
                    uint j = uint(neighbour[t]);
                    if (j == i) continue;
                    vec4 other = x[j];
                    precise float dx = nx - other.x, dy = ny - other.y, dz = nz - other.z;
                    precise float length2 = dx * dx + dy * dy;
                    length2 = length2 + dz * dz;
                    precise float strain = abs(sqrt(length2) / rest_length[t] - 1.0);
                    worst = max(worst, strain);
                }
                if (double(worst) > pierce_strain) {  // pierced: back where the integration put it
                    nx = float(world.x); ny = float(world.y); nz = float(world.z);
                    continue;
                }
            }
            precise dvec3 normal = rotate(r, local / (semi * semi));
            normal = normal / sqrt(squared_norm(normal));
            precise dvec3 surface_motion = stored - (probe_previous_centre[q] + rotate(probe_previous_rotation[q], local * factor));
            precise dvec3 contact = world - dvec3(double(xi), double(yi), double(zi));
            contact = contact + max(0.0lf, dot3(surface_motion - contact, normal)) * normal;
            motion = vec4(vec3(contact), 0.0);
            uint slot = atomicAdd(counter[COUNTER_TOUCHED0 + probe_hand[q]], 1u);
            touched[uint(probe_hand[q]) * particle_count + slot] = int(i);
        }
    }
    xn[i] = vec4(nx, ny, nz, 0.0);
    un[i] = motion;
}
)";

/// After a substep (one work group): grabbed particles follow their grabber; their motion is
/// the step from their current position (double, rounded once, as Solver::substep). A held
/// particle whose springs would pass the slip strain at its target slips out and keeps the
/// position the integration gave it, x + u. Three passes between barriers, as the cpu solver
/// runs them: every held particle moves to its target; each measures its springs (held
/// neighbours at their targets, free ones where the integration put them) and marks itself
/// slipping (held_by −2); the slipping ones go back and are free. Only when one slipped does
/// one invocation compact the held lists, in order.
inline constexpr const char* after_step = R"(
layout(local_size_x = 256) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_NEXT) buffer NextBuffer { vec4 xn[]; };
layout(std430, binding = BINDING_NEXT_MOTION) buffer NextMotionBuffer { vec4 un[]; };
layout(std430, binding = BINDING_HELD) buffer HeldBuffer { int held[]; };
layout(std430, binding = BINDING_HELD_LOCAL) buffer HeldLocalBuffer { double held_local[]; };
layout(std430, binding = BINDING_NEIGHBOUR) readonly buffer NeighbourBuffer { int neighbour[]; };
layout(std430, binding = BINDING_REST_LENGTH) readonly buffer RestBuffer { float rest_length[]; };
uniform bool grabbing[2];
uniform dvec3 grab_centre[2];
uniform dmat3 grab_rotation[2];
uniform float slip_strain;      // ≤ 0: never slips
shared bool slipped_any;

dvec3 target_of(int hand, uint e) {
    dmat3 r = grab_rotation[hand];
    dvec3 v = dvec3(held_local[3u * e], held_local[3u * e + 1u], held_local[3u * e + 2u]);
    precise double a = r[0][0] * v.x + r[1][0] * v.y; a = a + r[2][0] * v.z;
    precise double b = r[0][1] * v.x + r[1][1] * v.y; b = b + r[2][1] * v.z;
    precise double c = r[0][2] * v.x + r[1][2] * v.y; c = c + r[2][2] * v.z;
    precise dvec3 world = grab_centre[hand] + dvec3(a, b, c);
    return world;
}

float strain_at(uint i) {       // Solver::strain_at: the largest |L/L0 − 1| of i's springs
    precise float worst = 0.0;
    vec4 own = xn[i];
    uint table = (i / 8u) * 18u * 8u + i % 8u;
    for (uint s = 0u; s < 18u; ++s) {
        uint t = table + s * 8u;
        uint j = uint(neighbour[t]);
        if (j == i) continue;
        vec4 other = xn[j];
        precise float dx = own.x - other.x, dy = own.y - other.y, dz = own.z - other.z;
        precise float length2 = dx * dx + dy * dy;
        length2 = length2 + dz * dz;
        precise float strain = abs(sqrt(length2) / rest_length[t] - 1.0);
        worst = max(worst, strain);
    }
    return worst;
}

void main() {
    uint lid = gl_LocalInvocationID.x;
    if (lid == 0u) slipped_any = false;
    for (int hand = 0; hand < 2; ++hand) {
        if (!grabbing[hand]) continue;
        uint count = counter[COUNTER_HELD0 + hand];
        for (uint k = lid; k < count; k += 256u) {
            uint e = uint(hand) * particle_count + k;
            xn[uint(held[e])] = vec4(vec3(target_of(hand, e)), 0.0);
        }
    }
    memoryBarrierBuffer();
    barrier();
    if (slip_strain > 0.0) {
        for (int hand = 0; hand < 2; ++hand) {
            if (!grabbing[hand]) continue;
            uint count = counter[COUNTER_HELD0 + hand];
            for (uint k = lid; k < count; k += 256u) {
                uint i = uint(held[uint(hand) * particle_count + k]);
                if (strain_at(i) > slip_strain) { held_by[i] = -2; slipped_any = true; }
            }
        }
    }
    memoryBarrierBuffer();
    memoryBarrierShared();
    barrier();
    for (int hand = 0; hand < 2; ++hand) {
        if (!grabbing[hand]) continue;
        uint count = counter[COUNTER_HELD0 + hand];
        for (uint k = lid; k < count; k += 256u) {
            uint e = uint(hand) * particle_count + k;
            uint i = uint(held[e]);
            if (held_by[i] == -2) {
                precise vec3 integrated = x[i].xyz + un[i].xyz;
                xn[i] = vec4(integrated, 0.0);
                continue;
            }
            precise dvec3 step_motion = target_of(hand, e) - dvec3(x[i].xyz);
            un[i] = vec4(vec3(step_motion), 0.0);
        }
    }
    memoryBarrierBuffer();
    barrier();
    if (lid != 0u || !slipped_any) return;
    for (int hand = 0; hand < 2; ++hand) {
        if (!grabbing[hand]) continue;
        uint count = counter[COUNTER_HELD0 + hand], kept = 0u;
        for (uint k = 0u; k < count; ++k) {
            uint e = uint(hand) * particle_count + k;
            int i = held[e];
            if (held_by[i] == -2) { held_by[i] = -1; continue; }
            uint f = uint(hand) * particle_count + kept;
            held[f] = i;
            held_local[3u * f] = held_local[3u * e];
            held_local[3u * f + 1u] = held_local[3u * e + 1u];
            held_local[3u * f + 2u] = held_local[3u * e + 2u];
            ++kept;
        }
        counter[COUNTER_HELD0 + hand] = kept;
    }
}
)";

/// The restore-point check (after `springs`): the largest spring stretch L/L0 − 1 of the state
/// in `current`, as SolverEnergy::max_strain, into the counter word `strain` as float bits (a
/// stretch here is ≥ 0, so its bits order as its value, and a NaN's above every finite one).
inline constexpr const char* strain_pass = R"(
layout(local_size_x = 64) in;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= particle_count) return;
    vec4 own = x[i];
    uint table = (i / 8u) * 18u * 8u + i % 8u;
    precise float worst = 0.0;
    for (uint s = 0u; s < 18u; ++s) {
        uint t = table + s * 8u;
        uint j = uint(neighbour[t]);
        if (j == i || !(rest_length[t] > 0.0)) continue;
        vec4 other = x[j];
        precise float dx = other.x - own.x, dy = other.y - own.y, dz = other.z - own.z;
        precise float length2 = dx * dx + dy * dy;
        length2 = length2 + dz * dz;
        precise float stretch = sqrt(length2) / rest_length[t] - 1.0;
        if (!(stretch <= worst)) {
            worst = stretch;
            if (isnan(stretch)) break;
        }
    }
    atomicMax(counter[COUNTER_STRAIN], floatBitsToUint(worst));
}
)";

/// set_loads: each listed particle's load (N) into `load`; the host lists the previous loads'
/// particles that the new list drops with a zero force, so every particle is listed at most once.
inline constexpr const char* load_scatter = R"(
layout(local_size_x = 64) in;
struct LoadEntry { int particle; float fx; float fy; float fz; };
layout(std430, binding = BINDING_LOAD_LIST) readonly buffer LoadListBuffer { LoadEntry entry[]; };
layout(std430, binding = BINDING_LOAD) writeonly buffer LoadBuffer { vec4 load[]; };
uniform uint entry_count;
void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= entry_count) return;
    LoadEntry l = entry[e];
    load[uint(l.particle)] = vec4(l.fx, l.fy, l.fz, 0.0);
}
)";

/// The volume term (libmodel/volume_cells.h): each cell's forces on its eight corners at the
/// current positions, as the cpu solver's cell_pass makes them (cell_forces: twelfths, the same
/// float operations in the same order, none fused). A cell one of whose 24 springs is cut (its
/// table entry no longer holds the other corner) has none; `any_cut` is false while the tissue
/// is whole, and the check is skipped. The step pass adds a particle's 8 slots to its load.
inline constexpr const char* cell_pass = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_NEIGHBOUR) readonly buffer NeighbourBuffer { int neighbour[]; };
layout(std430, binding = BINDING_CELL_CORNER) readonly buffer CellCornerBuffer { int cell_corner[]; };   // 8 per cell
layout(std430, binding = BINDING_CELL_CONSTANTS) readonly buffer CellConstantsBuffer { vec2 cell_constants[]; };  // k12, 12·V0
layout(std430, binding = BINDING_CELL_SPRING) readonly buffer CellSpringBuffer { int cell_spring[]; };   // 24 table entries per cell
layout(std430, binding = BINDING_CELL_FORCE) writeonly buffer CellForceBuffer { float cell_force[]; };  // 8 slots of 3 per particle, N
uniform uint cell_count;
uniform bool any_cut;
const int face[24] = int[24](0, 4, 6, 2, 1, 3, 7, 5, 0, 1, 5, 4, 2, 6, 7, 3, 0, 2, 3, 1, 4, 5, 7, 6);
const int spring_end[24] = int[24](1, 2, 3, 4, 5, 6, 2, 3, 4, 5, 7, 3, 4, 6, 7, 5, 6, 7, 5, 6, 7, 6, 7, 7);  // volume_cells.cpp cell_springs
void main() {
    uint c = gl_GlobalInvocationID.x;
    if (c >= cell_count) return;
    int corner[8];
    for (int q = 0; q < 8; ++q) corner[q] = cell_corner[8u * c + uint(q)];
    bool whole = true;
    if (any_cut)
        for (int q = 0; q < 24; ++q)
            if (neighbour[cell_spring[24u * c + uint(q)]] != corner[spring_end[q]]) whole = false;
    if (!whole) {  // its corners' slots hold zero
        for (int q = 0; q < 8; ++q)
            for (int k = 0; k < 3; ++k) cell_force[24u * uint(corner[q]) + uint(3 * q + k)] = 0.0;
        return;
    }
    vec3 x0 = x[corner[0]].xyz;
    precise vec3 p[8];
    for (int q = 0; q < 8; ++q) {
        vec3 xq = x[corner[q]].xyz;
        p[q] = vec3(xq.x - x0.x, xq.y - x0.y, xq.z - x0.z);
    }
    precise float volume = 0.0;
    precise vec3 g[8];
    for (int q = 0; q < 8; ++q) g[q] = vec3(0.0);
    for (int f = 0; f < 6; ++f) {
        int i0 = face[4 * f], i1 = face[4 * f + 1], i2 = face[4 * f + 2], i3 = face[4 * f + 3];
        vec3 p0 = p[i0], p1 = p[i1], p2 = p[i2], p3 = p[i3];
        precise vec3 c01 = vec3(p0.y * p1.z - p0.z * p1.y, p0.z * p1.x - p0.x * p1.z, p0.x * p1.y - p0.y * p1.x);
        precise vec3 c02 = vec3(p0.y * p2.z - p0.z * p2.y, p0.z * p2.x - p0.x * p2.z, p0.x * p2.y - p0.y * p2.x);
        precise vec3 c03 = vec3(p0.y * p3.z - p0.z * p3.y, p0.z * p3.x - p0.x * p3.z, p0.x * p3.y - p0.y * p3.x);
        precise vec3 c12 = vec3(p1.y * p2.z - p1.z * p2.y, p1.z * p2.x - p1.x * p2.z, p1.x * p2.y - p1.y * p2.x);
        precise vec3 c13 = vec3(p1.y * p3.z - p1.z * p3.y, p1.z * p3.x - p1.x * p3.z, p1.x * p3.y - p1.y * p3.x);
        precise vec3 c23 = vec3(p2.y * p3.z - p2.z * p3.y, p2.z * p3.x - p2.x * p3.z, p2.x * p3.y - p2.y * p3.x);
        for (int k = 0; k < 3; ++k) volume = volume + (p0[k] * (c12[k] + c23[k]) + p1[k] * (c23[k] - c03[k]));
        for (int k = 0; k < 3; ++k) {
            g[i0][k] = g[i0][k] + ((c12[k] + c23[k]) + c13[k]);
            g[i1][k] = g[i1][k] + ((c23[k] - c02[k]) - c03[k]);
            g[i2][k] = g[i2][k] + ((c01[k] - c03[k]) - c13[k]);
            g[i3][k] = g[i3][k] + ((c02[k] + c12[k]) + c01[k]);
        }
    }
    vec2 constants = cell_constants[c];
    precise float pressure = -(constants.x * (volume - constants.y));
    for (int q = 0; q < 8; ++q)  // corner q's force into slot q of its particle
        for (int k = 0; k < 3; ++k) cell_force[24u * uint(corner[q]) + uint(3 * q + k)] = pressure * g[q][k];
}
)";

/// positions_of: the current positions of the listed particles (checked in range by the host), in
/// the list's order.
inline constexpr const char* gather = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_GATHER_INDEX) readonly buffer GatherIndexBuffer { int gather_index[]; };
layout(std430, binding = BINDING_GATHERED) writeonly buffer GatheredBuffer { vec4 gathered[]; };
uniform uint gather_count;
void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= gather_count) return;
    gathered[e] = x[uint(gather_index[e])];
}
)";

/// begin_grab: free particles inside the grabber at its pose join the hand's held list.
inline constexpr const char* capture = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_HELD) writeonly buffer HeldBuffer { int held[]; };
layout(std430, binding = BINDING_HELD_LOCAL) writeonly buffer HeldLocalBuffer { double held_local[]; };
layout(std430, binding = BINDING_SKIN) readonly buffer SkinBuffer { double reach_beyond[]; };  // Solver::reach_beyond, mm
uniform int hand;
uniform dvec3 centre;
uniform dmat3 rotation;
uniform dvec3 semi_axes;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= particle_count || particle[i].movable == 0 || held_by[i] >= 0) return;
    dmat3 r = rotation;
    dvec3 v = dvec3(x[i].xyz) - centre;
    precise double a = r[0][0] * v.x + r[0][1] * v.y; a = a + r[0][2] * v.z;
    precise double b = r[1][0] * v.x + r[1][1] * v.y; b = b + r[1][2] * v.z;
    precise double c = r[2][0] * v.x + r[2][1] * v.y; c = c + r[2][2] * v.z;
    precise dvec3 reach = max(semi_axes + dvec3(reach_beyond[i]), 0.5lf * semi_axes);  // Solver::met_axes
    dvec3 q = dvec3(a, b, c) / reach;
    precise double r2 = q.x * q.x + q.y * q.y; r2 = r2 + q.z * q.z;
    if (r2 > 1.0) return;
    held_by[i] = hand;
    uint slot = atomicAdd(counter[COUNTER_HELD0 + hand], 1u);
    uint e = uint(hand) * particle_count + slot;
    held[e] = int(i);
    held_local[3u * e] = a; held_local[3u * e + 1u] = b; held_local[3u * e + 2u] = c;
}
)";

/// release: the hand's held particles are free again.
inline constexpr const char* release = R"(
layout(local_size_x = 256) in;
layout(std430, binding = BINDING_HELD) readonly buffer HeldBuffer { int held[]; };
uniform int hand;
void main() {
    uint count = counter[COUNTER_HELD0 + hand];
    for (uint k = gl_LocalInvocationID.x; k < count; k += 256u) held_by[held[uint(hand) * particle_count + k]] = -1;
    barrier();
    if (gl_LocalInvocationID.x == 0u) counter[COUNTER_HELD0 + hand] = 0u;
}
)";

/// A lowered scalpel's cut (Solver::cut, libmodel/sim/cutting.cpp operation for operation): every
/// entry whose spring crosses the blade's swept quad (two triangles, `corner`) at the current
/// positions points at its own particle from now on, an empty slot. One invocation per particle
/// writes only its own entries; both ends of a spring test it with the end of lower index first,
/// so they decide alike. The end of lower index counts the spring into the hand's cut counter
/// (the blade pass's count, read back with the forces).
inline constexpr const char* cut_pass = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_NEIGHBOUR) buffer NeighbourBuffer { int neighbour[]; };
uniform vec3 corner[4];         // tip_A, end_A, end_B, tip_B
uniform vec3 low;               // the corners' bounding box
uniform vec3 high;
uniform vec3 near_low;          // the box grown by the search margin (BladeSweep, cutting.h)
uniform vec3 near_high;
uniform int hand;               // whose counter counts the springs cut

float orient(vec3 a, vec3 b, vec3 c, vec3 d) {   // (b − a) · ((c − a) × (d − a))
    precise float bx = b.x - a.x, by = b.y - a.y, bz = b.z - a.z;
    precise float cx = c.x - a.x, cy = c.y - a.y, cz = c.z - a.z;
    precise float dx = d.x - a.x, dy = d.y - a.y, dz = d.z - a.z;
    precise float nx = cy * dz - cz * dy;
    precise float ny = cz * dx - cx * dz;
    precise float nz = cx * dy - cy * dx;
    precise float v = bx * nx + by * ny;
    v = v + bz * nz;
    return v;
}

bool crosses_triangle(vec3 t0, vec3 t1, vec3 t2, vec3 p, vec3 q) {
    float sp = orient(t0, t1, t2, p), sq = orient(t0, t1, t2, q);
    if ((sp >= 0.0) == (sq >= 0.0)) return false;   // a point on the plane is on its positive side
    float e0 = orient(p, q, t0, t1), e1 = orient(p, q, t1, t2), e2 = orient(p, q, t2, t0);
    return (e0 >= 0.0 && e1 >= 0.0 && e2 >= 0.0) || (e0 <= 0.0 && e1 <= 0.0 && e2 <= 0.0);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= particle_count) return;
    uint table = (i / 8u) * 18u * 8u + i % 8u;
    for (uint s = 0u; s < 18u; ++s) {
        uint t = table + s * 8u;
        uint j = uint(neighbour[t]);
        if (j == i) continue;
        vec3 p = x[min(i, j)].xyz, q = x[max(i, j)].xyz;
        if (any(lessThan(p, near_low)) || any(greaterThan(p, near_high))) continue;
        if (any(lessThan(max(p, q), low)) || any(greaterThan(min(p, q), high))) continue;
        if (crosses_triangle(corner[0], corner[1], corner[2], p, q) || crosses_triangle(corner[0], corner[2], corner[3], p, q)) {
            neighbour[t] = int(i);
            if (i < j) atomicAdd(counter[COUNTER_CUT0 + hand], 1u);
        }
    }
}
)";

/// A cutting scalpel's state after its cut pass (one invocation): libmodel/sim/cutting_force.cpp
/// next_blade_state on the hand's count, with the step's constants from blade_step as uniforms, the
/// same double operations in the same order. The state lives in the counter words from
/// COUNTER_BLADE0 (six doubles per hand as pairs of words), where the force pass copies it into
/// the force ring; the host turns it into the force (blade_force); release clears it.
inline constexpr const char* blade_pass = R"(
layout(local_size_x = 1) in;
uniform int hand;
uniform double energy_per_spring;  // G_c · area per spring, mJ (BladeStep)
uniform double travel;             // the mean travel of the blade's tip and end over the step, mm
uniform double distance_keep;      // exp(−travel/λ)
uniform dvec3 motion_rate;         // the midpoint's velocity over the step, mm/ms
uniform double travel_rate;        // the blade's speed, mm/ms
uniform double keep;               // exp(−Δt/τ)
uniform double alpha;              // 1 − keep

double load(uint word) { return packDouble2x32(uvec2(counter[word], counter[word + 1u])); }
void store(uint word, double value) {
    uvec2 bits = unpackDouble2x32(value);
    counter[word] = bits.x;
    counter[word + 1u] = bits.y;
}

void main() {
    uint base = uint(COUNTER_BLADE0) + 12u * uint(hand);
    precise double energy = double(counter[COUNTER_CUT0 + hand]) * energy_per_spring;
    precise double summed = distance_keep * load(base) + energy;
    precise double travelled = distance_keep * load(base + 2u) + travel;
    store(base, summed);
    store(base + 2u, travelled);
    double step[4] = double[4](motion_rate.x, motion_rate.y, motion_rate.z, travel_rate);
    for (uint v = 0u; v < 4u; ++v) {
        precise double next = keep * load(base + 4u + 2u * v) + alpha * step[v];
        store(base + 4u + 2u * v, next);
    }
}
)";

/// Forces for both hands (one work group per hand): Σ spring + dashpot + support (+ volume) force on the particles
/// held or touched in the last substep, in double as Solver::force_on; into one ring slot, with
/// each hand's particle count, its springs cut in the step and its blade's state (the host
/// computes a scalpel's force from them: libmodel/sim/cutting_force.h blade_force). The count is a
/// uint word of its own, not the force's w lane: NVIDIA's compiler (driver 580, H100) stores
/// dvec4(partial, double(count)) with the count's integer bits in the w lane's low word and the
/// high word unwritten, which the host read as 0 or 10^11 particles.
inline constexpr const char* force_pass = R"(
layout(local_size_x = 256) in;
layout(std430, binding = BINDING_TOUCHED) readonly buffer TouchedBuffer { int touched[]; };
layout(std430, binding = BINDING_HELD) readonly buffer HeldBuffer { int held[]; };
layout(std430, binding = BINDING_FORCES) writeonly buffer ForceBuffer { dvec4 force[2]; uint status; uint sequence; uint cuts[2]; uint counts[2]; double blade[12]; };
layout(std430, binding = BINDING_PICKED) readonly buffer PickedBuffer { int picked[]; };
layout(std430, binding = BINDING_CELL_FORCE) readonly buffer CellForceBuffer { float cell_force[]; };
uniform bool volume_term;       // the scenario has cells with a volume term (libmodel/volume_cells.h)
uniform int hand_kind[2];       // 0 none, 1 probe, 2 grabber holding, 3 probe with the picking/search list
uniform bool damped;
uniform uint sequence_number;
shared dvec3 partial[256];

void main() {
    uint hand = gl_WorkGroupID.x, lid = gl_LocalInvocationID.x;
    int kind = hand_kind[hand];
    uint count = kind == 1 ? counter[COUNTER_TOUCHED0 + hand] : kind == 2 ? counter[COUNTER_HELD0 + hand] : kind == 3 ? counter[COUNTER_PICKED0 + hand] : 0u;
    precise dvec3 sum = dvec3(0.0);
    for (uint k = lid; k < count; k += 256u) {
        uint i = uint(kind == 1 ? touched[hand * particle_count + k] : kind == 3 ? picked[hand * particle_count + k] : held[hand * particle_count + k]);
        vec4 xi = x[i], ui = u[i];
        uint table = (i / 8u) * 18u * 8u + i % 8u;
        precise dvec3 f = dvec3(0.0);
        for (uint s = 0u; s < 18u; ++s) {
            uint t = table + s * 8u;
            uint j = uint(neighbour[t]);
            if (j == i) continue;
            vec4 xj = x[j], uj = u[j];
            precise dvec3 d = dvec3(xj.xyz) - dvec3(xi.xyz);
            precise double len2 = d.x * d.x + d.y * d.y; len2 = len2 + d.z * d.z;
            precise double len = max(sqrt(len2), 1e-15lf);
            precise double scale = double(stiffness[t]) * (len - double(rest_length[t])) / len;
            if (damped) {
                precise dvec3 du = dvec3(uj.xyz) - dvec3(ui.xyz);
                precise double along = du.x * d.x + du.y * d.y; along = along + du.z * d.z;
                scale = scale + double(dashpot[t]) * along / (len * len);
            }
            f = f + scale * d;
        }
        Particle own = particle[i];
        if (supported && own.support_stiffness != 0.0) {
            f = f + double(own.support_stiffness) * (dvec3(own.support_point.xyz) - dvec3(xi.xyz));
            f = f - double(own.support_point.w) * dvec3(ui.xyz);
        }
        if (volume_term)  // the cells' forces at these positions (cell_pass, run before this pass), slot by slot
            for (uint r = 0u; r < 8u; ++r) {
                uint at = 24u * i + 3u * r;
                f = f + dvec3(double(cell_force[at]), double(cell_force[at + 1u]), double(cell_force[at + 2u]));
            }
        sum = sum + f;
    }
    partial[lid] = sum;
    barrier();
    for (uint width = 128u; width > 0u; width >>= 1u) {
        if (lid < width) partial[lid] = partial[lid] + partial[lid + width];
        barrier();
    }
    if (lid == 0u) {
        force[hand] = dvec4(partial[0], 0.0lf);  // a scalpel's: 0 here, from `blade` on the host
        counts[hand] = count;
        cuts[hand] = counter[COUNTER_CUT0 + hand];
        uint base = uint(COUNTER_BLADE0) + 12u * hand;  // the blade pass's state
        for (uint v = 0u; v < 6u; ++v) blade[6u * hand + v] = packDouble2x32(uvec2(counter[base + 2u * v], counter[base + 2u * v + 1u]));
        if (hand == 0u) { status = counter[COUNTER_STATUS]; sequence = sequence_number; }
    }
}
)";

}  // namespace heartsim::gl_shaders
