/// @file picking_shaders.h
/// @brief GLSL 4.30 shaders of the probe contact passes (picking.cpp), after the preamble
/// compile_shader puts first (bindings.h): the picking buffer's render program, and the collect
/// (picking) and search programs, each `contact_common` and its body.
#pragma once

namespace heartsim::gl_shaders {

inline constexpr const char* picking_vertex_shader = R"(
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_PICKING_TRIANGLES) readonly buffer TriangleBuffer { int triangle[]; };
uniform vec3 centre;          // probe centre at render time, world mm
uniform mat3 to_tool;         // Rᵀ: world → tool frame
uniform vec4 window;          // half width W, near, far, unused (tool-frame z)
flat out ivec3 corner_particle;
out vec3 bary;
out vec3 local;
void main() {
    int t = gl_VertexID / 3, c = gl_VertexID - 3 * (gl_VertexID / 3);
    ivec3 ids = ivec3(triangle[3 * t], triangle[3 * t + 1], triangle[3 * t + 2]);
    corner_particle = ids;
    bary = vec3(c == 0 ? 1.0 : 0.0, c == 1 ? 1.0 : 0.0, c == 2 ? 1.0 : 0.0);
    local = to_tool * (x[ids[c]].xyz - centre);
    gl_Position = vec4(local.x / window.x, local.y / window.x, 2.0 * (local.z - window.y) / (window.z - window.y) - 1.0, 1.0);
}
)";

inline constexpr const char* picking_fragment_shader = R"(
flat in ivec3 corner_particle;
in vec3 bary;
in vec3 local;
uniform vec3 semi_axes;
layout(location = 0) out int picked;
layout(location = 1) out float distance_mm;
void main() {
    // The triangle's corner with the largest barycentric weight: a Voronoi-like diagram.
    int k = (bary.x >= bary.y && bary.x >= bary.z) ? 0 : (bary.y >= bary.z ? 1 : 2);
    picked = corner_particle[k];
    // Radial distance of the surface point to the ellipsoid (the solver's projection direction).
    float rho = length(local / semi_axes);
    distance_mm = rho > 0.0 ? length(local) * (1.0 - 1.0 / rho) : -min(semi_axes.x, min(semi_axes.y, semi_axes.z));
}
)";

// Shared by the collect and search passes: the exact contact test in double, and the
// deduplicated append (mark[i] holds the epoch of the last pass that appended i).
inline constexpr const char* contact_common = R"(
#extension GL_ARB_gpu_shader_fp64 : enable
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer CurrentBuffer { vec4 x[]; };
layout(std430, binding = BINDING_COUNTERS) buffer CounterBuffer { uint counter[]; };
layout(std430, binding = BINDING_PICKING_MARKS) buffer MarkBuffer { uint mark[]; };
layout(std430, binding = BINDING_PICKED) writeonly buffer PickedBuffer { int picked[]; };
layout(std430, binding = BINDING_SKIN) readonly buffer SkinBuffer { double reach_beyond[]; };  // Solver::reach_beyond, mm
uniform uint particle_count;
uniform int hand;
uniform uint epoch;
uniform dvec3 centre;         // current pose
uniform dmat3 rotation;       // tool → world
uniform dvec3 semi_axes;
uniform double tolerance;
bool in_contact(uint i) {
    dvec3 v = dvec3(x[i].xyz) - centre;
    dvec3 local = transpose(rotation) * v;
    dvec3 q = local / max(semi_axes + dvec3(reach_beyond[i]), 0.5lf * semi_axes);  // the probe as the step meets particle i (Solver::met_axes)
    double rho = sqrt(dot(q, q));
    double d = rho > 0.0lf ? sqrt(dot(local, local)) * (1.0lf - 1.0lf / rho) : -1.0lf;
    return d <= tolerance;
}
void append(uint i) {
    if (atomicExchange(mark[i], epoch) == epoch) return;
    uint slot = atomicAdd(counter[COUNTER_PICKED0 + hand], 1u);
    picked[uint(hand) * particle_count + slot] = int(i);
}
)";

inline constexpr const char* collect_body = R"(
layout(std430, binding = BINDING_PICKING_SAMPLES) readonly buffer SampleBuffer { vec4 sample_unit[]; };
layout(binding = BINDING_PICKING_INDEX_IMAGE) uniform isampler2D index_image;
uniform uint sample_count;
uniform int resolution;
uniform dvec3 render_centre;  // the camera of the (possibly stale) picking buffer
uniform dmat3 render_to_tool;
uniform double render_half_width;
void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= sample_count) return;
    dvec3 s = centre + rotation * (semi_axes * dvec3(sample_unit[k].xyz));   // boundary point, current pose
    dvec3 p = render_to_tool * (s - render_centre);                          // into the buffer's camera
    dvec2 uv = (p.xy / render_half_width) * 0.5lf + 0.5lf;
    ivec2 pixel = ivec2(floor(uv * double(resolution)));
    if (any(lessThan(pixel, ivec2(0))) || any(greaterThanEqual(pixel, ivec2(resolution)))) return;
    int i = texelFetch(index_image, pixel, 0).r;
    if (i < 0 || uint(i) >= particle_count) return;
    if (in_contact(uint(i))) append(uint(i));
}
)";

inline constexpr const char* search_body = R"(
layout(std430, binding = BINDING_PICKING_SURFACE) readonly buffer SurfaceBuffer { int surface[]; };
uniform uint surface_count;
void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= surface_count) return;
    uint i = uint(surface[k]);
    if (in_contact(i)) append(i);
}
)";

}  // namespace heartsim::gl_shaders
