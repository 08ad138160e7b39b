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
layout(location = 9) in vec3 rest_position;     // the visual vertex at rest, world mm
layout(location = 10) in float grown;           // its carriers' share of grown wall (0: labelled tissue)
uniform mat4 view_projection;
out vec3 world_position;
out vec3 shading_normal;
out vec3 rest_point;                            // where the surface detail is looked up
out vec3 rest_shading_normal;                   // the detail's tangent plane at rest
out vec4 rest_turn;                             // (k, c): the turn from rest to now (Rodrigues)
out float grown_share;
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
    rest_turn = vec4(0.0, 0.0, 0.0, 1.0);
    if (len > 0.0 && dot(rest_frame_normal, rest_frame_normal) > 0.5) {
        vec3 b = m / len, a = rest_frame_normal;
        float c = dot(a, b);
        vec3 k = cross(a, b);
        s = c > -0.99 ? s * c + cross(k, s) + k * (dot(k, s) / (1.0 + c)) : b;
        if (c > -0.99) rest_turn = vec4(k, c);
    }
    shading_normal = s;
    rest_point = rest_position;
    rest_shading_normal = rest_normal;
    grown_share = grown;
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
///
/// With SURFACE_DETAIL defined (the mapped detailed mesh only), the coronary arteries: the field
/// of libmodel/coronary_field.h (r: distance to the nearest course in that artery's radii; gba:
/// the unit direction away from it) looked up at the fragment's rest position. The artery is a
/// half-cylinder of its radius standing 0.6 radii proud of a ridge of epicardial fat that falls
/// off over 2.6 radii; the heights' gradient tilts the rest normal in its tangent plane, and the
/// vertex's turn from rest to now carries the tilted normal along: the detail follows every
/// deformation without more geometry. Coloured as seen through the fat: the artery red, the fat
/// around it yellow. Elsewhere on the muscle, its fibres' fine ridges (fibre_phase), carried the
/// same way. In the section view, the cut through a wall heartprep grew (the vertex's carrying
/// particles mostly of a grown material) is flat in grown_cut_color beside the labelled
/// myocardium's cut_color.
inline constexpr const char* fragment_shader = R"(
layout(std430, binding = BINDING_SHEET_TRIANGLES) readonly buffer SheetBuffer { uint sheet[]; };
in vec3 world_position;
in vec3 shading_normal;
#ifdef SURFACE_DETAIL
in vec3 rest_point;
in vec3 rest_shading_normal;
in vec4 rest_turn;
in float grown_share;
uniform vec3 grown_cut_color;  // the section's cut through a wall heartprep grew
uniform bool coronaries_on;
uniform sampler3D coronary_field;
uniform vec3 field_origin;     // the first node, mm
uniform float field_spacing;   // mm
uniform vec3 field_nodes;      // nodes along x, y, z
uniform vec3 artery_color;
uniform vec3 fat_color;
uniform bool fibres_on;
uniform vec3 heart_axis;       // unit: the left ventricle's long axis, base to apex
uniform vec3 heart_base;       // the mitral ring's centre, mm
/// The ventricles' epicardial fibres: fine ridges 1.2 mm apart along helices about the left
/// ventricle's long axis (from the mitral ring's centre towards the apex) at the epicardial helix
/// angle of 60 degrees, 120 around: phase = 120 θ + (2π / 1.2 mm) cos 60° h, θ the angle about
/// the axis and h the height along it, below the atrioventricular plane (h > 0) only. Returns the
/// phase; `gradient` its gradient at rest (mm⁻¹), `pixel` how much it changes across a pixel.
float fibre_phase(out vec3 gradient, out float pixel) {
    vec3 r = rest_point - heart_base;
    float h = dot(r, heart_axis);
    vec3 radial = r - h * heart_axis;
    float rho2 = max(dot(radial, radial), 1.0);
    vec3 e1 = normalize(abs(heart_axis.x) < 0.9 ? cross(heart_axis, vec3(1.0, 0.0, 0.0)) : cross(heart_axis, vec3(0.0, 1.0, 0.0)));
    vec3 e2 = cross(heart_axis, e1);
    float theta = atan(dot(radial, e2), dot(radial, e1));
    const float around = 120.0, along = 2.6179939;  // (2π / 1.2) cos 60°
    vec3 dtheta = cross(heart_axis, radial) / rho2;
    gradient = around * dtheta + along * heart_axis;
    pixel = around * (abs(dot(dtheta, dFdx(rest_point))) + abs(dot(dtheta, dFdy(rest_point)))) +
            along * (abs(dot(heart_axis, dFdx(rest_point))) + abs(dot(heart_axis, dFdy(rest_point))));
    return around * theta + along * h;
}
/// The rest normal tilted across the fibres' ridges (0.02 mm high, `fade` of it), turned to now.
void fibre_detail(inout vec3 nrm, float phase, vec3 gradient, float fade) {
    vec3 n0 = normalize(rest_shading_normal);
    vec3 g = (0.02 * fade * cos(phase)) * gradient;
    g -= dot(g, n0) * n0;
    vec3 tilted = normalize(n0 - g);
    vec3 k = rest_turn.xyz;
    float c = rest_turn.w;
    nrm = tilted * c + cross(k, tilted) + k * (dot(k, tilted) / (1.0 + c));
}
/// The rest normal tilted by the arteries' and the fat's heights, turned to now; the colour under them.
void coronary_detail(inout vec3 nrm, inout vec3 surface_color) {
    vec4 f = texture(coronary_field, ((rest_point - field_origin) / field_spacing + 0.5) / field_nodes);
    float u = f.r;
    if (u >= 2.6) return;
    // d(height)/d(distance), both in radii: the artery's half-cylinder sqrt(1 - u²) (its slope
    // held finite at the flank) and the fat's smoothstep fall from 1 to 2.6 radii.
    float w = min(u, 0.96);
    float slope = u < 1.0 ? -0.6 * w / sqrt(1.0 - w * w) : 0.0;
    float t = clamp((u - 1.0) / 1.6, 0.0, 1.0);
    slope += -0.35 * 6.0 * t * (1.0 - t) / 1.6;
    vec3 n0 = rest_shading_normal;
    if (dot(n0, n0) < 1e-12) return;
    n0 = normalize(n0);
    vec3 g = slope * f.gba;
    g -= dot(g, n0) * n0;
    vec3 tilted = normalize(n0 - g);
    vec3 k = rest_turn.xyz;
    float c = rest_turn.w;
    nrm = tilted * c + cross(k, tilted) + k * (dot(k, tilted) / (1.0 + c));
    float fat = 1.0 - smoothstep(1.5, 2.6, u);
    float artery = 1.0 - smoothstep(0.85, 1.05, u);
    surface_color = mix(mix(surface_color, fat_color, 0.85 * fat), artery_color, artery);
}
#endif
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
#ifdef SURFACE_DETAIL
    // The fibres' ridges fade where they would be finer than two pixels, so they never alias.
    vec3 fibre_gradient = vec3(0.0);
    float fibre_pixel = 0.0;
    float phase = fibres_on ? fibre_phase(fibre_gradient, fibre_pixel) : 0.0;
    float fibre_fade = fibres_on ? clamp(1.0 - fibre_pixel / 3.1415927, 0.0, 1.0) *
                                       smoothstep(0.0, 6.0, dot(rest_point - heart_base, heart_axis)) : 0.0;
#endif
    if (section_on) {
        if (dot(section_plane.xyz, world_position) + section_plane.w > 0.0) discard;
        if (!gl_FrontFacing && sheet[gl_PrimitiveID] == 0u) {
            colour = vec4(cut_color, 1.0);
#ifdef SURFACE_DETAIL
            if (grown_share > 0.5) colour = vec4(grown_cut_color, 1.0);
#endif
            return;
        }
    }
    bool cap = cap_first >= 0 && gl_PrimitiveID >= cap_first;
    vec3 nrm = cap ? vec3(0.0) : shading_normal;
    vec3 surface_color = cap ? cap_color : base_color;
#ifdef SURFACE_DETAIL
    if (fibre_fade > 0.0 && !cap && dot(nrm, nrm) >= 1e-12 && dot(rest_shading_normal, rest_shading_normal) >= 1e-12)
        fibre_detail(nrm, phase, fibre_gradient, fibre_fade);
    if (coronaries_on && !cap && dot(nrm, nrm) >= 1e-12) coronary_detail(nrm, surface_color);
#endif
    if (dot(nrm, nrm) < 1e-12) nrm = face_normal;
    vec3 v = normalize(eye - world_position);
    nrm = dot(nrm, nrm) > 1e-20 ? normalize(nrm) : v;
    if (dot(nrm, v) < 0.0) nrm = -nrm;
    float diffuse = 0.62 * max(dot(nrm, key_light), 0.0) + 0.28 * max(dot(nrm, fill_light), 0.0);
    vec3 h = normalize(key_light + v);
    float shine = specular * pow(max(dot(nrm, h), 0.0), 32.0);
    colour = vec4(min(surface_color * (0.16 + diffuse) + vec3(shine), vec3(1.0)), opacity);
}
)";

}  // namespace heartsim::gl_shaders
