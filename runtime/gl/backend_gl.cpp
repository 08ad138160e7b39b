// The gl backend (runtime/gl/backend_gl_impl.h): the hands (instruments, poses, grabs), the
// force pass and its ring, loads and a few particles' positions, the contact search, the patch
// pass it makes for a repair; and the functions backend_gl.h declares.
#include "runtime/gl/backend_gl_impl.h"
#include "runtime/gl/gl_context.h"
#include "runtime/gl/patch_pass.h"

#include "libmodel/errors.h"
#include "libmodel/packing.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <sstream>

namespace heartsim {
namespace gl_backend {

void GlBackend::set_instrument(int hand, const Instrument& instrument) {
    check_hand(hand);
    for (int c = 0; c < 3; ++c)
        if (!(instrument.semi_axes[c] > 0) || !std::isfinite(instrument.semi_axes[c]))
            throw InputError("solver: instrument semi-axes must be positive and finite, mm");
    release(hand);
    hand_[hand].instrument = instrument;
    hand_[hand].placed = false;
    if (picking_) picking_->invalidate(hand);
    // A probe's touched list starts empty (the step pass refills it every substep).
    const GLuint zero = 0;
    glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::touched0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
}

void GlBackend::set_pose(int hand, const InstrumentPose& pose) {
    check_hand(hand);
    if (!pose.position.allFinite() || !pose.orientation.coeffs().allFinite() || pose.orientation.norm() < 1e-6)
        throw InputError("solver: an instrument pose must be finite with a non-zero quaternion");
    InstrumentPose p = pose;
    p.orientation.normalize();
    hand_[hand].target = p;
    if (!hand_[hand].placed) hand_[hand].pose = p;
    hand_[hand].placed = true;
}

std::size_t GlBackend::begin_grab(int hand) {
    check_hand(hand);
    HandState& state = hand_[hand];
    if (state.instrument.kind == InstrumentKind::scalpel) {  // lowers the blade (Solver::begin_grab)
        if (!state.cutting) {
            const BladeState lowered = lowered_blade(options_.cutting_resistance, lattice_frame_);
            clear_blade(hand);
            glNamedBufferSubData(counters_.id(), GLintptr((sh::blade0 + sh::blade_words * unsigned(hand) + 2) * 4), 8, &lowered.travel);
            glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        }
        state.cutting = true;
        return 0;
    }
    if (!holds_tissue(state.instrument.kind)) throw InputError("solver: begin_grab on a hand that holds no grabber, retractor or scalpel");
    release(hand);
    state.grabbing = true;
    bind_common();
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
    const GLuint p = capture_program_.id;
    glProgramUniform1i(p, capture_program_.at("hand"), hand);
    glProgramUniform3dv(p, capture_program_.at("centre"), 1, state.pose.position.data());
    const Eigen::Matrix3d rotation = state.pose.orientation.toRotationMatrix();
    glProgramUniformMatrix3dv(p, capture_program_.at("rotation"), 1, GL_FALSE, rotation.data());
    glProgramUniform3dv(p, capture_program_.at("semi_axes"), 1, state.instrument.semi_axes.data());
    glUseProgram(p);
    glDispatchCompute(GLuint((n_ + 63) / 64), 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    GLuint count = 0;
    glGetNamedBufferSubData(counters_.id(), GLintptr((sh::held0 + hand) * 4), 4, &count);
    if (count > 0) count = keep_one_piece(hand, count);
    check("begin_grab");
    return count;
}

GLuint GlBackend::keep_one_piece(int hand, GLuint count) {
    const std::size_t base = std::size_t(hand) * n_;
    std::vector<std::int32_t> index(count);
    std::vector<double> local(3 * std::size_t(count));
    glGetNamedBufferSubData(held_.id(), GLintptr(base * 4), GLsizeiptr(count * 4), index.data());
    glGetNamedBufferSubData(held_local_.id(), GLintptr(base * 3 * 8), GLsizeiptr(std::size_t(count) * 3 * 8), local.data());
    std::vector<std::size_t> order(count);
    for (std::size_t q = 0; q < count; ++q) order[q] = q;
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return index[a] < index[b]; });
    std::vector<Eigen::Vector3d> sorted_local(count), rest(count);
    for (std::size_t q = 0; q < count; ++q) {
        const std::size_t from = order[q], i = std::size_t(index[from]);
        sorted_local[q] = Eigen::Vector3d(local[3 * from], local[3 * from + 1], local[3 * from + 2]);
        for (int c = 0; c < 3; ++c) rest[q][c] = double(rest_position_[3 * i + std::size_t(c)]);
    }
    // Where a cut runs among them, the side of the grabber's centre (the current table: one
    // readback, at the grab only).
    std::vector<std::int32_t> sorted_index(count);
    for (std::size_t q = 0; q < count; ++q) sorted_index[q] = index[order[q]];
    std::vector<std::int32_t> table;
    auto current = [&](std::size_t i, int s) {
        if (table.empty()) {
            table.resize(uncut_neighbour_.size());
            glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
            glGetNamedBufferSubData(neighbour_.id(), 0, GLsizeiptr(table.size() * 4), table.data());
        }
        return table[table_entry(i, s)];
    };
    const std::vector<std::array<std::int32_t, 2>> joined = blade_swept_ ? joined_captured(
        sorted_index, slot_count, current, [&](std::size_t i, int s) { return uncut_neighbour_[table_entry(i, s)]; }) :
        std::vector<std::array<std::int32_t, 2>>{};
    const std::vector<std::uint8_t> keep = grab_piece(sorted_local, rest, hand_[hand].instrument.semi_axes, options_.grab_reach, joined);
    std::vector<std::int32_t> kept, dropped;
    std::vector<double> kept_local;
    for (std::size_t q = 0; q < count; ++q) {
        const std::int32_t i = index[order[q]];
        if (!keep[q]) {
            dropped.push_back(i);
            continue;
        }
        kept.push_back(i);
        for (int c = 0; c < 3; ++c) kept_local.push_back(sorted_local[q][c]);
    }
    auto set_list = [&](const std::vector<std::int32_t>& list) {
        const GLuint size = GLuint(list.size());
        if (size > 0) glNamedBufferSubData(held_.id(), GLintptr(base * 4), GLsizeiptr(size * 4), list.data());
        glNamedBufferSubData(counters_.id(), GLintptr((sh::held0 + hand) * 4), 4, &size);
    };
    if (!dropped.empty()) {  // the release pass frees the hand's listed particles and zeroes its count
        set_list(dropped);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        glProgramUniform1i(release_program_.id, release_program_.at("hand"), hand);
        glUseProgram(release_program_.id);
        glDispatchCompute(1, 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    }
    set_list(kept);
    if (!kept.empty())
        glNamedBufferSubData(held_local_.id(), GLintptr(base * 3 * 8), GLsizeiptr(kept_local.size() * 8), kept_local.data());
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    return GLuint(kept.size());
}

void GlBackend::release(int hand) {
    check_hand(hand);
    release_hand(hand, true);
}

void GlBackend::release_hand(int hand, bool stay) {
    HandState& state = hand_[hand];
    if (state.cutting) strokes_.lift(hand);
    state.cutting = false;
    clear_blade(hand);  // a lifted blade exerts nothing (Solver::release)
    if (!state.grabbing) return;
    if (stay && state.instrument.kind == InstrumentKind::retractor) anchor_held(hand);
    bind_common();
    glProgramUniform1i(release_program_.id, release_program_.at("hand"), hand);
    glUseProgram(release_program_.id);
    glDispatchCompute(1, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    state.grabbing = false;
}

void GlBackend::anchor_held(int hand) {
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);  // the after pass may have dropped slipped particles from the list
    GLuint count = 0;
    glGetNamedBufferSubData(counters_.id(), GLintptr((sh::held0 + hand) * 4), 4, &count);
    std::vector<std::int32_t> held(std::min<std::size_t>(count, n_));
    if (!held.empty()) glGetNamedBufferSubData(held_.id(), GLintptr(std::size_t(hand) * n_ * 4), GLsizeiptr(held.size() * 4), held.data());
    const float zero4[4] = {0, 0, 0, 0};
    for (const std::int32_t q : held) {
        const std::size_t i = std::size_t(q);
        stayed_.push_back(q);
        stayed_constants_.push_back(particle_host_[i]);
        // Solver::release_hand: not movable, h²/m 0, no support spring, zero motion in both buffers.
        ParticleConstants& p = particle_host_[i];
        p.movable = 0;
        p.inverse_mass_h2 = 0.0f;
        p.support_stiffness = 0.0f;
        p.support_point[3] = 0.0f;
        glNamedBufferSubData(particle_.id(), GLintptr(i * sizeof(ParticleConstants)), GLsizeiptr(sizeof(ParticleConstants)), &p);
        for (Buffer& m : motion_) glClearNamedBufferSubData(m.id(), GL_RGBA32F, GLintptr(i * 16), 16, GL_RGBA, GL_FLOAT, zero4);
    }
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    check("anchoring a retractor's tissue");
}

void GlBackend::free_stayed() {
    if (stayed_.empty()) return;
    for (std::size_t q = 0; q < stayed_.size(); ++q) particle_host_[std::size_t(stayed_[q])] = stayed_constants_[q];
    stayed_.clear();
    stayed_constants_.clear();
    upload_step_constants();  // their h²/(S·m), support spring and start motion again
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
}

void GlBackend::request_forces() {
    if (no_instruments()) {  // answered at once; requests still in flight are superseded
        for (auto& fence : fences_) fence.reset();
        latest_ = InstrumentForces{};
        latest_sequence_ = next_sequence_++;
        return;
    }
    const int slot = int(next_sequence_ % ring_slots);
    if (fences_[slot]) {  // ring full: the oldest readback is still in flight (rare: 4 outstanding)
        glClientWaitSync(fences_[slot], GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(10'000'000'000ull));
        fences_[slot].reset();
    }
    run_contact_search();
    Pending timing{};
    gl::generate(timing.queries);
    glQueryCounter(timing.queries[0], GL_TIMESTAMP);
    bind_common();
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::motion, motion_[current_].id());
    glBindBufferRange(GL_SHADER_STORAGE_BUFFER, sh::forces, ring_.id(), GLintptr(slot) * ring_stride, sizeof(ForceSlot));
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::picked, picking_ ? picking_->picked_buffer() : touched_.id());
    int kinds[2];
    for (int hand = 0; hand < hands; ++hand)
        kinds[hand] = hand_[hand].instrument.kind == InstrumentKind::probe ? (listed_contacts() ? 3 : 1) : hand_[hand].grabbing ? 2 : 0;
    glProgramUniform1iv(force_program_.id, force_program_.at("hand_kind"), 2, kinds);
    glProgramUniform1ui(force_program_.id, force_program_.at("sequence_number"), GLuint(next_sequence_));
    if (cell_count_ > 0) run_cell_pass();  // the cells' forces at the current positions (Solver::force_on)
    glUseProgram(force_program_.id);
    glDispatchCompute(hands, 1, 1);
    glMemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
    fences_[slot].reset(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0));
    sequence_of_[slot] = next_sequence_++;
    glQueryCounter(timing.queries[1], GL_TIMESTAMP);
    timing.is_force = true;
    pending_.push_back(std::move(timing));
    glFlush();
    check("request_forces");
}

std::optional<InstrumentForces> GlBackend::latest_forces() {
    // Newest finished slot, without waiting.
    for (int back = 1; back <= ring_slots; ++back) {
        if (next_sequence_ < std::uint64_t(back)) break;
        const std::uint64_t sequence = next_sequence_ - std::uint64_t(back);
        const int slot = int(sequence % ring_slots);
        if (!fences_[slot] || sequence_of_[slot] != sequence) continue;
        const GLenum state = glClientWaitSync(fences_[slot], 0, 0);
        if (state != GL_ALREADY_SIGNALED && state != GL_CONDITION_SATISFIED) continue;  // unfinished (or the wait failed)
        fences_[slot].reset();
        latest_ = read_slot(slot);
        latest_sequence_ = sequence;
        break;
    }
    return latest_;
}

InstrumentForces GlBackend::instrument_forces() {
    request_forces();
    if (no_instruments()) return *latest_;
    const int slot = int((next_sequence_ - 1) % ring_slots);
    glClientWaitSync(fences_[slot], GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(60'000'000'000ull));
    fences_[slot].reset();
    latest_ = read_slot(slot);
    latest_sequence_ = next_sequence_ - 1;
    return *latest_;
}

std::vector<std::array<float, 3>> GlBackend::positions() {
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    std::vector<float> raw(4 * n_pad_);
    glGetNamedBufferSubData(position_[current_].id(), 0, GLsizeiptr(raw.size() * sizeof(float)), raw.data());
    check("reading positions");
    std::vector<std::array<float, 3>> out(n_);
    for (std::size_t i = 0; i < n_; ++i) out[i] = {raw[4 * i], raw[4 * i + 1], raw[4 * i + 2]};
    return out;
}

void GlBackend::set_loads(const std::vector<ParticleLoad>& loads) {
    check_loads(loads, n_);  // Solver::set_loads's rule; throws before anything changes
    // One list for the scatter pass: the new loads, and the previous ones' particles that the
    // new list drops with a zero force; both sorted, so each particle appears once.
    std::vector<LoadEntry> entries;
    entries.reserve(loads.size() + load_particles_.size());
    std::size_t q = 0;
    for (const ParticleLoad& load : loads) {
        for (; q < load_particles_.size() && load_particles_[q] < load.particle; ++q) entries.push_back({load_particles_[q], {0, 0, 0}});
        if (q < load_particles_.size() && load_particles_[q] == load.particle) ++q;
        entries.push_back({load.particle, {float(load.force_n.x()), float(load.force_n.y()), float(load.force_n.z())}});
    }
    for (; q < load_particles_.size(); ++q) entries.push_back({load_particles_[q], {0, 0, 0}});
    if (!entries.empty()) {
        const std::size_t bytes = entries.size() * sizeof(LoadEntry);
        if (bytes > load_list_bytes_) {
            load_list_bytes_ = std::max<std::size_t>(bytes, 2 * load_list_bytes_);
            storage(load_list_, load_list_bytes_, GL_DYNAMIC_STORAGE_BIT);
        }
        glNamedBufferSubData(load_list_.id(), 0, GLsizeiptr(bytes), entries.data());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load_list, load_list_.id());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load, load_.id());
        glProgramUniform1ui(scatter_program_.id, scatter_program_.at("entry_count"), GLuint(entries.size()));
        glUseProgram(scatter_program_.id);
        glDispatchCompute(GLuint((entries.size() + 63) / 64), 1, 1);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    }
    load_particles_.resize(loads.size());
    for (std::size_t k = 0; k < loads.size(); ++k) load_particles_[k] = loads[k].particle;
    update_loaded();
    check("set_loads");
}

std::vector<std::array<float, 3>> GlBackend::positions_of(const std::vector<std::int32_t>& particles) {
    check_particle_indices(particles, n_);
    std::vector<std::array<float, 3>> out(particles.size());
    if (particles.empty()) return out;
    if (particles.size() > gather_capacity_) {
        gather_capacity_ = std::max<std::size_t>(particles.size(), 2 * gather_capacity_);
        storage(gather_index_, gather_capacity_ * 4, GL_DYNAMIC_STORAGE_BIT);
        storage(gathered_, gather_capacity_ * 16, 0);
    }
    glNamedBufferSubData(gather_index_.id(), 0, GLsizeiptr(particles.size() * 4), particles.data());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::current, position_[current_].id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::gather_index, gather_index_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::gathered, gathered_.id());
    glProgramUniform1ui(gather_program_.id, gather_program_.at("gather_count"), GLuint(particles.size()));
    glUseProgram(gather_program_.id);
    glDispatchCompute(GLuint((particles.size() + 63) / 64), 1, 1);
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    std::vector<float> raw(4 * particles.size());
    glGetNamedBufferSubData(gathered_.id(), 0, GLsizeiptr(raw.size() * sizeof(float)), raw.data());
    check("reading positions of particles");
    for (std::size_t q = 0; q < particles.size(); ++q) out[q] = {raw[4 * q], raw[4 * q + 1], raw[4 * q + 2]};
    return out;
}

void GlBackend::set_contact(const ContactSettings& settings) {
    if (settings.mode != ContactMode::direct && !picking_)
        picking_ = std::make_unique<PickingPass>(surface_, n_, lattice_spacing_, settings);
    if (picking_) picking_->set_settings(settings);
    contact_ = settings;
    check("set_contact");
}

std::vector<std::int32_t> GlBackend::contact_particles(int hand) {
    check_hand(hand);
    const HandState& state = hand_[hand];
    if (state.instrument.kind == InstrumentKind::none) return {};
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    const bool listed = state.instrument.kind == InstrumentKind::probe && listed_contacts();
    const GLuint word = listed ? sh::picked0 + hand : state.grabbing ? sh::held0 + hand : sh::touched0 + hand;
    GLuint count = 0;
    glGetNamedBufferSubData(counters_.id(), GLintptr(word * 4), 4, &count);
    std::vector<std::int32_t> out(std::min<std::size_t>(count, n_));
    const GLuint list = listed ? picking_->picked_buffer() : state.grabbing ? held_.id() : touched_.id();
    if (!out.empty()) glGetNamedBufferSubData(list, GLintptr(std::size_t(hand) * n_ * 4), GLsizeiptr(out.size() * 4), out.data());
    check("reading contact particles");
    std::sort(out.begin(), out.end());
    return out;
}

PassTimes GlBackend::pass_times() {
    harvest_queries(true);
    return times_;
}

StepReport GlBackend::step_after(const std::function<void()>& task) {
    task();
    return step(1);
}

PatchStepper* GlBackend::patch_stepper() {
    if (!patch_pass_ && !patch_pass_refused_) {
        try {
            patch_pass_ = make_gl_patch_pass([this] { return unsigned(position_[current_].id()); }, load_.id(),
                                             [this](bool on) {
                                                 patch_loads_ = on;
                                                 update_loaded();
                                             },
                                             n_);
        } catch (const std::runtime_error& e) {  // a driver without what the pass needs (GlUnavailable, an OpenGL error): the host steps the patch
            patch_pass_refused_ = true;
            std::printf("repair: the patch steps on the host: %s\n", e.what());
        }
    }
    return patch_pass_.get();
}

void GlBackend::clear_loads() {
    const float zero4[4] = {0, 0, 0, 0};
    glClearNamedBufferData(load_.id(), GL_RGBA32F, GL_RGBA, GL_FLOAT, zero4);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    load_particles_.clear();
    update_loaded();
}

void GlBackend::update_loaded() {
    // With the volume term the step adds each particle's cells' forces to its load (`external_loads`).
    const bool external = !load_particles_.empty() || patch_loads_;
    glProgramUniform1i(step_program_.id, step_program_.at("loaded"), cell_count_ > 0 || external);
    glProgramUniform1i(step_program_.id, step_program_.at("external_loads"), external);
}

void GlBackend::run_cell_pass() {
    glProgramUniform1i(cell_program_.id, cell_program_.at("any_cut"), blade_swept_);
    glUseProgram(cell_program_.id);
    glDispatchCompute(GLuint((cell_count_ + 63) / 64), 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
}

void GlBackend::run_contact_search() {
    if (!listed_contacts()) return;
    bool any = false;
    const GLuint zero = 0;
    for (int hand = 0; hand < hands; ++hand) {
        const HandState& state = hand_[hand];
        if (state.instrument.kind != InstrumentKind::probe) continue;
        if (state.placed) any = true;
        else glClearNamedBufferSubData(counters_.id(), GL_R32UI, GLintptr((sh::picked0 + hand) * 4), 4, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    }
    if (!any) return;
    Pending timing{};
    timing.is_picking = true;
    gl::generate(timing.queries);
    glQueryCounter(timing.queries[0], GL_TIMESTAMP);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    for (int hand = 0; hand < hands; ++hand) {
        const HandState& state = hand_[hand];
        if (state.instrument.kind != InstrumentKind::probe || !state.placed) continue;
        picking_->collect(hand, state.instrument, state.pose, position_[current_].id(), counters_.id(), skin_.id());
    }
    glQueryCounter(timing.queries[1], GL_TIMESTAMP);
    pending_.push_back(std::move(timing));
    check("the contact search");
}

void GlBackend::set_indexed_matrix(GLuint program, const std::string& name, int index, const double* column_major) {
    glProgramUniformMatrix3dv(program, glGetUniformLocation(program, (name + "[" + std::to_string(index) + "]").c_str()), 1, GL_FALSE,
                              column_major);
}

InstrumentForces GlBackend::read_slot(int slot) {
    const auto* s = reinterpret_cast<const ForceSlot*>(static_cast<const char*>(ring_map_) + slot * ring_stride);
    InstrumentForces forces;
    for (int hand = 0; hand < hands; ++hand) {
        forces.hand[hand].force_n = Eigen::Vector3d(s->force[hand][0], s->force[hand][1], s->force[hand][2]);
        forces.hand[hand].particles = std::min<std::size_t>(s->counts[hand], n_);
        forces.hand[hand].springs_cut = s->cuts[hand];
        // A blade's state is zero but while its hand is a lowered scalpel, which touches and holds
        // nothing: its force is the blade's (Solver::instrument_forces), from the state the step had.
        const BladeState blade{s->blade[hand][0], s->blade[hand][1], Eigen::Vector3d(s->blade[hand][2], s->blade[hand][3], s->blade[hand][4]),
                               s->blade[hand][5]};
        if (blade.energy != 0 || blade.travel != 0 || blade.travel_rate != 0 || blade.motion_rate != Eigen::Vector3d::Zero())
            forces.hand[hand].force_n = blade_force(blade, options_.cutting_resistance, 2.0 * hand_[hand].instrument.semi_axes.z());
        if (!forces.hand[hand].force_n.allFinite()) forces.hand[hand].force_n.setZero();  // never leak a non-finite force
    }
    return forces;
}

void GlBackend::bind_common() {
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::neighbour, neighbour_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::rest_length, rest_length_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::stiffness, stiffness_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::dashpot, dashpot_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::particle, particle_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held_by, held_by_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::counters, counters_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::touched, touched_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held, held_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::held_local, held_local_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::load, load_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::skin, skin_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::cell_corner, cell_corner_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::cell_constants, cell_constants_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::cell_spring, cell_spring_.id());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, sh::cell_force, cell_force_.id());
}

}  // namespace gl_backend

std::unique_ptr<Backend> make_gl_backend(GlContext& context, const Scenario& scenario, const SolverOptions& options) {
    require_runnable(scenario, "scenario");
    context.make_current();
    auto backend = std::make_unique<gl_backend::GlBackend>(scenario, options);
    backend->set_software(is_software_rasteriser(context.info()));
    return backend;
}

unsigned gl_position_buffer(const Backend& backend) {
    // The backend that simulates is a wrapper's inner one (Backend::simulating), never a wrapper:
    // of those, only the gl backend says it is one.
    const Backend& simulating = backend.simulating();
    return simulating.kind() == BackendKind::gl ? static_cast<const gl_backend::GlBackend&>(simulating).position_buffer() : 0;
}

}  // namespace heartsim
