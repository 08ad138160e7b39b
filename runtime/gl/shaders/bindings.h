/// @file bindings.h
/// @brief The binding points and counter words that the runtime's shaders share with the C++
/// that feeds them. The GLSL never spells a number: compile_shader (gl_program.h) puts
/// `#define BINDING_<NAME> <value>` and `#define COUNTER_<NAME> <value>` lines, made from
/// `shader_constants` below, after the `#version` line of every shader, so a binding is written
/// once, here, and the shader and its glBindBufferBase cannot drift apart.
#pragma once

namespace heartsim::gl_shaders {

/// Binding points: shader storage buffers unless marked otherwise.
enum Binding : unsigned {
    // The gl backend's passes (backend_gl.cpp, solver_shaders.h). `current` also carries the
    // positions that picking and the renderer read.
    current = 0, motion = 1, next = 2, neighbour = 3, rest_length = 4, stiffness = 5, dashpot = 6, particle = 7, held_by = 8,
    counters = 9, touched = 10, next_motion = 11, held = 12, held_local = 13, forces = 14,
    picked = 15,  ///< probe contact lists: written by the picking and search passes, read by the force pass
    // The picking and search passes (picking.cpp, picking_shaders.h), beyond current, counters, picked.
    picking_triangles = 16, picking_samples = 17, picking_marks = 18, picking_surface = 19,
    picking_index_image = 6,  ///< texture unit (not a buffer) of the picking buffer's particle index image
    // External loads (backend_gl.cpp set_loads, positions_of).
    load = 20,          ///< per padded particle, vec4: the load's force (N) in xyz, zero where there is none
    load_list = 21,     ///< set_loads's scatter list: particle index and force per entry
    gather_index = 22,  ///< positions_of's particle indices
    gathered = 23,      ///< positions_of's positions, vec4 per index
    // The patch's pass (patch_pass.cpp, patch_shaders.h), beyond current and load.
    patch_ints = 24, patch_constants = 25, patch_state = 26,
    skin = 27,  ///< per padded particle, double: how far an instrument reaches beyond it, mm (Solver::reach_beyond)
    // The volume term (libmodel/volume_cells.h; cell_pass, and the step pass reads cell_force).
    cell_corner = 28,     ///< per cell, 8 particle indices
    cell_constants = 29,  ///< per cell, vec2: k12 and 12·V0
    cell_spring = 30,     ///< per cell, the 24 neighbour-table entries of its springs
    cell_force = 31,      ///< per padded particle, 8 slots of 3 floats: the force of the cell it is corner r of, N
    // The renderer's passes (renderer.cpp, render_shaders.h) bind all their buffers before each
    // use, so they reuse the backend's low slots: with the cpu backend, drawing then needs no
    // more bindings than the few every OpenGL 4.3 driver offers.
    incidence_start = 1, incidence = 2, particle_normals = 3, surface_particles = 4,
    sheet_triangles = 5,  ///< per drawn triangle, 1 where its reverse twin is drawn too (a one-particle-thick wall)
    captured_vertices = 0,  ///< transform feedback buffer (interleaved capture writes buffer 0)
};

/// Counter words in the `counters` buffer.
/// `strain`: the restore-point candidate's largest spring stretch (float bits; strain_pass).
/// `cut0`, `cut1`: the springs each hand's blade cut in the step (cut_pass). From `blade0`, 12 words
/// per hand: the scalpel's state (libmodel/sim/cutting_force.h BladeState: energy, travel, the three
/// components of the velocity, speed), six doubles as pairs of words (low, high; blade_pass).
enum Counter : unsigned {
    touched0 = 0, touched1 = 1, strain = 2, held0 = 3, held1 = 4, status = 5, picked0 = 6, picked1 = 7,
    cut0 = 8, cut1 = 9, blade0 = 10, blade_words = 12, counter_words = blade0 + 2 * blade_words
};

/// The names the shaders see (BINDING_CURRENT, ...): every Binding and Counter word the GLSL
/// uses. A name missing here makes the shaders that use it fail to compile, which every GL test
/// would report.
struct ShaderConstant {
    const char* name;
    unsigned value;
};
inline constexpr ShaderConstant shader_constants[] = {
    {"BINDING_CURRENT", current},
    {"BINDING_MOTION", motion},
    {"BINDING_NEXT", next},
    {"BINDING_NEIGHBOUR", neighbour},
    {"BINDING_REST_LENGTH", rest_length},
    {"BINDING_STIFFNESS", stiffness},
    {"BINDING_DASHPOT", dashpot},
    {"BINDING_PARTICLE", particle},
    {"BINDING_HELD_BY", held_by},
    {"BINDING_COUNTERS", counters},
    {"BINDING_TOUCHED", touched},
    {"BINDING_NEXT_MOTION", next_motion},
    {"BINDING_HELD", held},
    {"BINDING_HELD_LOCAL", held_local},
    {"BINDING_FORCES", forces},
    {"BINDING_PICKED", picked},
    {"BINDING_PICKING_TRIANGLES", picking_triangles},
    {"BINDING_PICKING_SAMPLES", picking_samples},
    {"BINDING_PICKING_MARKS", picking_marks},
    {"BINDING_PICKING_SURFACE", picking_surface},
    {"BINDING_PICKING_INDEX_IMAGE", picking_index_image},
    {"BINDING_LOAD", load},
    {"BINDING_LOAD_LIST", load_list},
    {"BINDING_GATHER_INDEX", gather_index},
    {"BINDING_GATHERED", gathered},
    {"BINDING_PATCH_INTS", patch_ints},
    {"BINDING_PATCH_CONSTANTS", patch_constants},
    {"BINDING_PATCH_STATE", patch_state},
    {"BINDING_SKIN", skin},
    {"BINDING_CELL_CORNER", cell_corner},
    {"BINDING_CELL_CONSTANTS", cell_constants},
    {"BINDING_CELL_SPRING", cell_spring},
    {"BINDING_CELL_FORCE", cell_force},
    {"BINDING_INCIDENCE_START", incidence_start},
    {"BINDING_INCIDENCE", incidence},
    {"BINDING_PARTICLE_NORMALS", particle_normals},
    {"BINDING_SURFACE_PARTICLES", surface_particles},
    {"BINDING_SHEET_TRIANGLES", sheet_triangles},
    {"COUNTER_TOUCHED0", touched0},
    {"COUNTER_HELD0", held0},
    {"COUNTER_STATUS", status},
    {"COUNTER_STRAIN", strain},
    {"COUNTER_PICKED0", picked0},
    {"COUNTER_CUT0", cut0},
    {"COUNTER_BLADE0", blade0},
};

}  // namespace heartsim::gl_shaders
