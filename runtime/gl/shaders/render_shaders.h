/// @file render_shaders.h
/// @brief GLSL 4.30 shaders of the renderer (renderer.cpp), after the preamble compile_shader
/// puts first (bindings.h): the particle-normals compute pass, the mapping vertex shader, the
/// instrument vertex shader and the shared lit fragment shader.
#pragma once

namespace heartsim::gl_shaders {

/// Particle normals (libmodel particle_normals, same float operations in the same order): one
/// invocation per surface particle sums the area vectors of its counted triangles in row order
/// (the incidence list keeps it), then normalises; (x·x) + ... as Eigen's 3-term dot:
/// x·x + (y·y + z·z).
inline constexpr const char* normals_shader = R"(
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_CURRENT) readonly buffer PositionBuffer { vec4 x[]; };
layout(std430, binding = BINDING_INCIDENCE_START) readonly buffer StartBuffer { uint start[]; };
layout(std430, binding = BINDING_INCIDENCE) readonly buffer IncidenceBuffer { ivec4 triangle[]; };
layout(std430, binding = BINDING_PARTICLE_NORMALS) writeonly buffer NormalBuffer { vec4 normal[]; };
layout(std430, binding = BINDING_SURFACE_PARTICLES) readonly buffer SurfaceBuffer { uint surface_particle[]; };
uniform uint surface_count;
void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= surface_count) return;
    precise vec3 sum = vec3(0.0);
    for (uint e = start[k]; e < start[k + 1u]; ++e) {
        ivec4 t = triangle[e];
        vec3 a = x[t.x].xyz, b = x[t.y].xyz, c = x[t.z].xyz;
        precise vec3 u = b - a;
        precise vec3 v = c - a;
        precise vec3 area = vec3(u.y * v.z - u.z * v.y, u.z * v.x - u.x * v.z, u.x * v.y - u.y * v.x);
        sum = sum + area;
    }
    precise float length2 = sum.x * sum.x + (sum.y * sum.y + sum.z * sum.z);
    precise float len = sqrt(length2);
    normal[surface_particle[k]] = len > 0.0 ? vec4(sum / len, 0.0) : vec4(0.0);
}
)";

/// The mapping (libmodel apply_mapping, float32, same order). Its output world_position is what
/// transform feedback captures for the tests.
inline constexpr const char* mesh_vertex_shader = R"(
layout(std430, binding = BINDING_CURRENT) readonly buffer PositionBuffer { vec4 x[]; };
layout(std430, binding = BINDING_PARTICLE_NORMALS) readonly buffer NormalBuffer { vec4 n[]; };
layout(location = 0) in ivec3 particle;         // the simulation-surface triangle's particles a, b, c
layout(location = 1) in vec3 lambda;            // barycentric weights
layout(location = 2) in float offset;           // d, mm
layout(location = 3) in vec3 rest_normal;       // the visual vertex's normal at rest (0: flat shading)
layout(location = 4) in vec3 rest_frame_normal; // normalised interpolated particle normal at rest
layout(location = 5) in ivec4 carrier_lo;       // the carrying particles i_0..i_3
layout(location = 6) in ivec4 carrier_hi;       // i_4..i_7
layout(location = 7) in vec4 weight_lo;         // their weights w_0..w_3
layout(location = 8) in vec4 weight_hi;         // w_4..w_7
uniform mat4 view_projection;
out vec3 world_position;
out vec3 shading_normal;
void main() {
    vec3 na = n[particle.x].xyz, nb = n[particle.y].xyz, nc = n[particle.z].xyz;
    precise vec3 p = weight_lo.x * x[carrier_lo.x].xyz;
    p = p + weight_lo.y * x[carrier_lo.y].xyz;
    p = p + weight_lo.z * x[carrier_lo.z].xyz;
    p = p + weight_lo.w * x[carrier_lo.w].xyz;
    p = p + weight_hi.x * x[carrier_hi.x].xyz;
    p = p + weight_hi.y * x[carrier_hi.y].xyz;
    p = p + weight_hi.z * x[carrier_hi.z].xyz;
    p = p + weight_hi.w * x[carrier_hi.w].xyz;
    precise vec3 m = (lambda.x * na + lambda.y * nb) + lambda.z * nc;
    precise float m2 = m.x * m.x + (m.y * m.y + m.z * m.z);
    precise float len = sqrt(m2);
    if (len > 0.0) p = p + offset * (m / len);
    world_position = p;
    // Shading: the rest normal turned by the rotation taking the rest interpolated normal to
    // the current one (Rodrigues), so the detailed mesh keeps its detail as it deforms.
    vec3 s = rest_normal;
    if (len > 0.0 && dot(rest_frame_normal, rest_frame_normal) > 0.5) {
        vec3 b = m / len, a = rest_frame_normal;
        float c = dot(a, b);
        vec3 k = cross(a, b);
        s = c > -0.99 ? s * c + cross(k, s) + k * (dot(k, s) / (1.0 + c)) : b;
    }
    shading_normal = s;
    gl_Position = view_projection * vec4(p, 1.0);
}
)";

inline constexpr const char* instrument_vertex_shader = R"(
layout(location = 0) in vec3 unit;              // a point of the unit sphere (also its normal)
uniform mat4 view_projection;
uniform mat4 model;                             // translate · rotate · scale(semi-axes)
uniform mat3 normal_matrix;                     // rotate · scale⁻¹
out vec3 world_position;
out vec3 shading_normal;
void main() {
    vec4 w = model * vec4(unit, 1.0);
    world_position = w.xyz;
    shading_normal = normal_matrix * unit;
    gl_Position = view_projection * w;
}
)";

/// Two directional lights fixed to the camera, Blinn-Phong, two-sided; a zero shading normal
/// (the simulation surface) gives the flat face normal from screen-space derivatives.
/// The section view (section_on): nothing on the plane's positive side is drawn; a back face
/// left (the closed surface seen from inside: CCW from outside, scenario-format.md) is where the
/// plane cut the wall, shaded flat so that the wall's cross-section reads as one solid band. A
/// double-sided sheet (a triangle drawn with its reverse twin) encloses no tissue: both its sides
/// are lit. An incision's caps (the triangles from cap_first on) are the cut myocardium: lit with
/// their flat face normal in cap_color.
inline constexpr const char* fragment_shader = R"(
layout(std430, binding = BINDING_SHEET_TRIANGLES) readonly buffer SheetBuffer { uint sheet[]; };
in vec3 world_position;
in vec3 shading_normal;
uniform vec3 eye;
uniform vec3 key_light;
uniform vec3 fill_light;
uniform vec3 base_color;
uniform float specular;
uniform bool section_on;
uniform vec4 section_plane;   // (n, -n·p): removed where n·x + w > 0
uniform vec3 cut_color;
uniform float opacity;        // 1 but for the instruments' ghost (renderer.cpp)
uniform int cap_first;        // the first cap triangle of an incision (lit flat in cap_color); -1: none
uniform vec3 cap_color;
out vec4 colour;
void main() {
    // Derivatives before any discard: they need the whole pixel quad.
    vec3 face_normal = cross(dFdx(world_position), dFdy(world_position));
    if (section_on) {
        if (dot(section_plane.xyz, world_position) + section_plane.w > 0.0) discard;
        if (!gl_FrontFacing && sheet[gl_PrimitiveID] == 0u) {
            colour = vec4(cut_color, 1.0);
            return;
        }
    }
    bool cap = cap_first >= 0 && gl_PrimitiveID >= cap_first;
    vec3 nrm = cap ? vec3(0.0) : shading_normal;
    if (dot(nrm, nrm) < 1e-12) nrm = face_normal;
    vec3 v = normalize(eye - world_position);
    nrm = dot(nrm, nrm) > 1e-20 ? normalize(nrm) : v;
    if (dot(nrm, v) < 0.0) nrm = -nrm;
    float diffuse = 0.62 * max(dot(nrm, key_light), 0.0) + 0.28 * max(dot(nrm, fill_light), 0.0);
    vec3 h = normalize(key_light + v);
    float shine = specular * pow(max(dot(nrm, h), 0.0), 32.0);
    colour = vec4(min((cap ? cap_color : base_color) * (0.16 + diffuse) + vec3(shine), vec3(1.0)), opacity);
}
)";

}  // namespace heartsim::gl_shaders
