// The gl backend (runtime/gl/backend_gl_impl.h) built from the scenario: its compute programs,
// the packed tables and buffers of libmodel/sim/solver.cpp's constructor made the same way, and the
// constants that depend on the substep and the mass scale.
#include "runtime/gl/backend_gl_impl.h"
#include "runtime/gl/gl_context.h"

#include "libmodel/errors.h"
#include "libmodel/packing.h"
#include "libmodel/stability.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>

namespace heartsim {
namespace gl_backend {

namespace {

/// Compiles sh::common followed by `parts` into one compute program.
void build(Program& program, const char* name, std::initializer_list<const char*> parts) {
    const std::string what = std::string("gl backend: the ") + name + " compute shader";
    std::vector<const char*> sources{sh::common};
    sources.insert(sources.end(), parts.begin(), parts.end());
    program.id = link_program({compile_shader(GL_COMPUTE_SHADER, sources, what, "run with --backend cpu")}, what, "run with --backend cpu");
}

}  // namespace

GlBackend::GlBackend(const Scenario& scenario, const SolverOptions& options) : options_(options) {
    // The CPU solver validates the scenario exactly as the cpu backend would and decides
    // the substeps (critical step, damping): both backends then share h and the constants.
    {
        Solver reference(scenario.lattice, scenario.packing->neighbours, options);
        // The contact skin as the cpu solver takes it: checked by set_contact_skin, each particle's
        // reach computed by reach_beyond, in double (build_buffers uploads it).
        reference.set_contact_skin(scenario_contact_skin(scenario));
        reach_beyond_.resize(reference.size());
        for (std::size_t i = 0; i < reference.size(); ++i) {
            reach_beyond_[i] = reference.reach_beyond(i);
            max_reach_beyond_ = std::max(max_reach_beyond_, reach_beyond_[i]);
        }
        load_report_ = reference.load_report();
        dt_ms_ = reference.time_step_ms();
        h_ = reference.substep_ms();
        substeps_ = reference.substeps_per_step();
        lattice_frame_ = reference.lattice_frame();  // the scalpel's area per spring, as the cpu solver's
        cell_corner_host_ = reference.volume_cell_corners();  // the volume term's cells, constants and springs, as it steps them
        cell_spring_slot_host_ = reference.volume_cell_spring_slots();
        for (std::size_t c = 0; c < cell_corner_host_.size(); ++c)
            cell_constants_host_.insert(cell_constants_host_.end(), {reference.volume_cell_k12()[c], reference.volume_cell_rest12()[c]});
    }
    build_buffers(scenario);
    surface_ = scenario.simulation_surface;  // for the picking / search contact passes, built on demand
    lattice_spacing_ = scenario.lattice.spacing;
    build(step_program_, "step", {sh::springs, sh::geometry, sh::step});
    build(after_program_, "after-step", {sh::after_step});
    build(capture_program_, "grab", {sh::capture});
    build(release_program_, "release", {sh::release});
    build(force_program_, "force", {sh::springs, sh::force_pass});
    build(strain_program_, "strain", {sh::springs, sh::strain_pass});
    build(cut_program_, "cut", {sh::cut_pass});
    build(blade_program_, "blade", {sh::blade_pass});
    build(scatter_program_, "load scatter", {sh::load_scatter});
    build(gather_program_, "gather", {sh::gather});
    build(cell_program_, "volume cell", {sh::cell_pass});
    for (const Program* p : {&step_program_, &after_program_, &capture_program_, &release_program_, &force_program_, &strain_program_,
                             &cut_program_, &scatter_program_, &gather_program_, &cell_program_}) {
        glProgramUniform1ui(p->id, p->at("particle_count"), GLuint(n_));
        glProgramUniform1ui(p->id, p->at("padded_count"), GLuint(n_pad_));
    }
    glProgramUniform1f(step_program_.id, step_program_.at("keep"), keep());
    glProgramUniform3f(step_program_.id, step_program_.at("gravity"), float(options_.gravity.x()), float(options_.gravity.y()),
                       float(options_.gravity.z()));
    glProgramUniform1i(step_program_.id, step_program_.at("damped"), damped_);
    for (const Program* p : {&step_program_, &force_program_})
        glProgramUniform1i(p->id, p->at("supported"), supported_);
    glProgramUniform1i(force_program_.id, force_program_.at("damped"), damped_);
    glProgramUniform1f(after_program_.id, after_program_.at("slip_strain"), float(options_.grab_slip_strain));
    glProgramUniform1d(step_program_.id, step_program_.at("pierce_strain"), options_.probe_pierce_strain);
    glProgramUniform1ui(cell_program_.id, cell_program_.at("cell_count"), GLuint(cell_count_));
    glProgramUniform1i(force_program_.id, force_program_.at("volume_term"), cell_count_ > 0);
    glProgramUniform1i(step_program_.id, step_program_.at("volume_term"), cell_count_ > 0);
    update_loaded();
    check("setting up the gl backend");
}

GlBackend::~GlBackend() {
    if (ring_.id()) glUnmapNamedBuffer(ring_.id());
    if (status_ring_.id()) glUnmapNamedBuffer(status_ring_.id());
}

void GlBackend::set_mass_scale(double mass_scale) {
    const ScaledStep step = scaled_step(load_report_, options_, mass_scale);  // Solver::set_mass_scale's rule; throws first
    const double old_h = h_;
    options_.mass_scale = mass_scale;
    dt_ms_ = step.dt_ms;
    substeps_ = step.substeps;
    h_ = dt_ms_ / substeps_;
    load_report_.mass_scale = mass_scale;
    load_report_.critical_dt_ms = step.critical_dt_ms;
    load_report_.damped_critical_dt_ms = step.damped_critical_dt_ms;
    load_report_.substeps = substeps_;
    load_report_.substep_ms = h_;
    upload_step_constants();
    glProgramUniform1f(step_program_.id, step_program_.at("keep"), keep());
    if (old_h != h_) {  // velocities kept: u = v·h, scaled in float as the cpu solver does
        const float ratio = float(h_ / old_h);
        std::vector<float> motion(4 * n_pad_);
        glGetNamedBufferSubData(motion_[current_].id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
        for (std::size_t i = 0; i < n_pad_; ++i)
            for (int c = 0; c < 3; ++c) motion[4 * i + std::size_t(c)] = motion[4 * i + std::size_t(c)] * ratio;
        glNamedBufferSubData(motion_[current_].id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
    }
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    check("set_mass_scale");
}

void GlBackend::upload_step_constants() {
    std::vector<ParticleConstants> constants = particle_host_;
    for (std::size_t i = 0; i < n_; ++i) {
        ParticleConstants& p = constants[i];
        p.inverse_mass_h2 = p.movable ? float(h_ * h_ / (double(p.mass) * options_.mass_scale)) : 0.0f;
        p.support_point[3] = p.support_stiffness > 0.0f ? float(support_damping_host_[i] / h_) : 0.0f;
    }
    std::vector<float> dashpot_over_h(dashpot_host_.size());
    for (std::size_t t = 0; t < dashpot_host_.size(); ++t) dashpot_over_h[t] = float(double(dashpot_host_[t]) / h_);
    // Solver::reset(): at rest the springs and supports balance `balanced_gravity`, so the
    // motion starts with acceleration (g − g_balanced)/S: u₀ = x₀ − x₋₁ = −½·a·h².
    const Eigen::Vector3d rest_acceleration = (options_.gravity - options_.balanced_gravity) / options_.mass_scale;
    std::vector<float> motion(4 * n_pad_, 0.0f);
    for (std::size_t i = 0; i < n_; ++i)
        if (constants[i].movable)
            for (int c = 0; c < 3; ++c) motion[4 * i + std::size_t(c)] = float(-0.5 * rest_acceleration[c] * h_ * h_);
    if (!particle_.id()) {
        storage(particle_, constants, GL_DYNAMIC_STORAGE_BIT);
        storage(dashpot_, dashpot_over_h, GL_DYNAMIC_STORAGE_BIT);
        storage(rest_motion_, motion, GL_DYNAMIC_STORAGE_BIT);
        storage(motion_[0], motion, GL_DYNAMIC_STORAGE_BIT);
        storage(motion_[1], motion, GL_DYNAMIC_STORAGE_BIT);
        return;
    }
    glNamedBufferSubData(particle_.id(), 0, GLsizeiptr(constants.size() * sizeof(ParticleConstants)), constants.data());
    glNamedBufferSubData(dashpot_.id(), 0, GLsizeiptr(dashpot_over_h.size() * sizeof(float)), dashpot_over_h.data());
    glNamedBufferSubData(rest_motion_.id(), 0, GLsizeiptr(motion.size() * sizeof(float)), motion.data());
}

void GlBackend::build_buffers(const Scenario& scenario) {
    const Particles& particles = scenario.lattice.particles;
    const Springs& springs = scenario.lattice.springs;
    const auto& table = scenario.packing->neighbours;
    n_ = particles.size();
    n_pad_ = (n_ + lane_count - 1) / lane_count * lane_count;
    const std::vector<double> damping_ratio =
        options_.damping_ratio.empty() ? damping_ratios(scenario.lattice.materials) : options_.damping_ratio;
    const std::vector<std::int32_t> slot_spring = spring_of_slot(table, springs);  // throws for non-neighbours
    const std::size_t entries = n_pad_ * slot_count;
    std::vector<std::int32_t> neighbour(entries);
    std::vector<float> rest(entries, 0.0f), stiff(entries, 0.0f);
    dashpot_host_.assign(entries, 0.0f);
    min_rest_length_ = std::numeric_limits<float>::infinity();
    damped_ = false;
    for (std::size_t i = 0; i < n_pad_; ++i)
        for (int s = 0; s < slot_count; ++s) {
            const std::size_t t = table_entry(i, s);
            neighbour[t] = std::int32_t(i);
            if (i >= n_) continue;
            const std::int32_t q = slot_spring[i * slot_count + std::size_t(s)];
            if (q < 0) continue;
            const auto [a, b] = springs.pairs[std::size_t(q)];
            const std::size_t j = std::size_t(a) == i ? std::size_t(b) : std::size_t(a);
            neighbour[t] = std::int32_t(j);
            rest[t] = springs.rest_length[std::size_t(q)];
            stiff[t] = springs.stiffness[std::size_t(q)];
            const float c = float(spring_dashpot(particles, damping_ratio, double(springs.stiffness[std::size_t(q)]), i, j));
            damped_ = damped_ || c != 0.0f;
            dashpot_host_[t] = c;
            min_rest_length_ = std::min(min_rest_length_, rest[t]);
            max_rest_length_ = std::max(max_rest_length_, rest[t]);
        }
    std::vector<ParticleConstants>& constants = particle_host_;
    constants.assign(n_pad_, {1.0f, 0.0f, 0, 0.0f, {0.0f, 0.0f, 0.0f, 0.0f}});
    support_damping_host_.assign(n_, 0.0);
    std::vector<float> current(4 * n_pad_, 0.0f);
    supported_ = false;
    for (std::size_t i = 0; i < n_; ++i) {
        const bool movable = !particles.anchored[i];
        constants[i].mass = particles.mass[i];
        constants[i].movable = movable;
        const std::array<float, 3>& y = particles.supported() ? particles.support_point[i] : particles.rest_position[i];
        for (int c = 0; c < 3; ++c) constants[i].support_point[c] = y[std::size_t(c)];
        if (movable && particles.supported() && particles.support_stiffness[i] > 0.0f) {
            constants[i].support_stiffness = particles.support_stiffness[i];
            // Solver::build_step_constants(): c/h rounded from double (upload_step_constants).
            if (!particles.support_damping.empty()) support_damping_host_[i] = double(particles.support_damping[i]);
            supported_ = true;
        }
        for (int c = 0; c < 3; ++c) current[4 * i + std::size_t(c)] = particles.rest_position[i][std::size_t(c)];
    }
    storage(position_[0], current, 0);
    storage(position_[1], current, 0);
    storage(rest_current_, current, 0);    // the start state again, for reset_tissue()
    upload_step_constants();               // particle constants, dashpots c/h, the start motion (both buffers)
    storage(neighbour_, neighbour, GL_DYNAMIC_STORAGE_BIT);  // the cut pass and reset_tissue rewrite it
    uncut_neighbour_ = std::move(neighbour);
    storage(rest_length_, rest);
    storage(stiffness_, stiff);
    storage(held_by_, std::vector<std::int32_t>(n_pad_, -1));
    storage(counters_, std::vector<std::uint32_t>(sh::counter_words, 0u), GL_DYNAMIC_STORAGE_BIT);
    storage(touched_, std::size_t(hands) * n_ * 4, 0);
    storage(held_, std::size_t(hands) * n_ * 4, GL_DYNAMIC_STORAGE_BIT);              // begin_grab rewrites it
    storage(held_local_, std::size_t(hands) * n_ * 3 * 8, GL_DYNAMIC_STORAGE_BIT);
    storage(load_, std::vector<float>(4 * n_pad_, 0.0f), 0);  // set_loads's scatter pass writes it
    // The volume term's cells (the reference solver's), their springs' slots as entries of this
    // table's layout, and each particle's 8 force slots. Buffers of one element where there are none.
    cell_count_ = cell_corner_host_.size();
    {
        std::vector<std::int32_t> corners, entries;
        for (std::size_t c = 0; c < cell_count_; ++c) {
            const auto& corner = cell_corner_host_[c];
            for (int r = 0; r < 8; ++r) corners.push_back(corner[std::size_t(r)]);
            for (std::size_t q = 0; q < cell_springs.size(); ++q)
                entries.push_back(std::int32_t(table_entry(std::size_t(corner[std::size_t(cell_springs[q][0])]), cell_spring_slot_host_[c][q])));
        }
        if (cell_count_ == 0) corners.assign(8, 0), entries.assign(24, 0), cell_constants_host_.assign(2, 0.0f);
        storage(cell_corner_, corners);
        storage(cell_constants_, cell_constants_host_);
        storage(cell_spring_, entries);
        storage(cell_force_, std::vector<float>(cell_count_ > 0 ? 24 * n_pad_ : 24, 0.0f), 0);  // zero where no cell writes
    }
    reach_beyond_.resize(n_pad_, 0.0);
    storage(skin_, reach_beyond_, 0);
    rest_position_.resize(3 * n_);  // begin_grab's piece of tissue (keep_one_piece)
    for (std::size_t i = 0; i < n_; ++i)
        for (int c = 0; c < 3; ++c) rest_position_[3 * i + std::size_t(c)] = particles.rest_position[i][std::size_t(c)];
    const GLbitfield ring_flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
    storage(ring_, std::size_t(ring_slots) * ring_stride, ring_flags);
    ring_map_ = glMapNamedBufferRange(ring_.id(), 0, ring_slots * ring_stride, ring_flags);
    if (!ring_map_) throw GlUnavailable("gl backend: cannot map the force readback buffer persistently; run with --backend cpu");
    storage(good_position_, current, 0);       // the watchdog's restore point, verified clean
    storage(candidate_position_, current, 0);  // the next restore point, while its status is in flight
    const GLbitfield status_flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
    storage(status_ring_, std::size_t(status_slots) * 8, status_flags);  // per slot: status, candidate stretch
    status_map_ = glMapNamedBufferRange(status_ring_.id(), 0, status_slots * 8, status_flags);
    if (!status_map_) throw GlUnavailable("gl backend: cannot map the status readback buffer persistently; run with --backend cpu");
    memory_bytes_ = estimate_gl_memory_bytes(scenario);
}

}  // namespace gl_backend

namespace {
bool volume_term(const Scenario& scenario) {
    for (const Material& m : scenario.lattice.materials)
        if (m.poisson_ratio > 0.25) return true;
    return false;
}
}  // namespace

std::size_t estimate_gl_memory_bytes(const Scenario& scenario) {
    const std::size_t n = scenario.lattice.particles.size(), n_pad = (n + 7) / 8 * 8;
    return 8 * n_pad * 16            // positions and motions: two float4 buffers each, the start state of both, two restore points
           + n_pad * 18 * 4 * 4      // neighbour, rest length, stiffness, dashpot c/h
           + n_pad * 32 + n_pad * 4  // particle constants (with the support spring), held-by
           + n_pad * 16              // external loads
           + (volume_term(scenario) ? n_pad * 96 + n * (8 * 4 + 8 + 24 * 4) : 0)  // the volume term: each particle's slots; at
                                                                                // most a cell per particle: corners, constants, springs
           + n_pad * 8               // each particle's reach beyond it (the contact skin)
           + n * (2 * 4 + 2 * 4 + 2 * 24)  // touched lists, held lists and their local coordinates
           + gl_backend::ring_slots * gl_backend::ring_stride + gl_backend::status_slots * 8 + gl_backend::sh::counter_words * 4;
}

}  // namespace heartsim
