// The simulation state file (state.h): its schema over the HDF5 layer (hdf5_io.h).
#include "state.h"

#include "hdf5_io.h"
#include "xdmf.h"

#include "libmodel/errors.h"
#include "libmodel/stability.h"

#include <string>

namespace heartsim {

void write_state(const std::filesystem::path& path, const SimulationState& state) {
    const std::string xdmf = state_xdmf(path.filename().string(), state, path.parent_path());
    check_xdmf_destination(path);
    h5::write_file(path, [&](h5::Writer& w) {
        w.header("heartsim.state", 1, "mm g ms");
        w.attribute("/", "backend", state.backend);
        w.attribute("/", "scenario", state.scenario);
        w.attribute("/", "time_ms", state.time_ms);
        w.attribute("/", "steps", std::int64_t(state.steps));
        w.attribute("/", "mass_scale", state.mass_scale);
        w.dataset("positions", state.positions, {state.positions.size(), 3});
        w.dataset("instrument_forces", state.force_n.data()->data(), {2, 3});
        w.dataset("instrument_particles", state.particles.data(), {2});
        w.dataset("instrument_kind", state.kind.data(), {2});
        if (!state.cut_springs.empty()) w.dataset("cut_springs", state.cut_springs, {state.cut_springs.size(), 2});
        if (!state.visual_positions.empty()) {
            w.group("visual");
            w.dataset("visual/positions", state.visual_positions, {state.visual_positions.size(), 3});
            if (!state.visual_triangles.empty()) {
                w.dataset("visual/triangles", state.visual_triangles, {state.visual_triangles.size(), 3});
                w.attribute("visual/triangles", "cap_first", std::int64_t(state.visual_cap_first));
            }
        }
        if (state.patch) {
            const PatchState& patch = *state.patch;
            w.group("patch");
            w.attribute("patch", "material", patch.material);
            w.attribute("patch", "thickness_mm", patch.thickness_mm);
            w.attribute("patch", "youngs_modulus_mpa", patch.youngs_modulus_mpa);
            if (patch.has_defect) {
                w.attribute("patch", "defect_centre", patch.defect_centre.data(), {3});
                w.attribute("patch", "defect_axis", patch.defect_axis.data(), {3});
                w.attribute("patch", "defect_diameter_mm", patch.defect_diameter_mm);
                w.attribute("patch", "closed", std::int64_t(patch.closed ? 1 : 0));
                w.attribute("patch", "largest_rim_gap_mm", patch.largest_rim_gap_mm);
                w.attribute("patch", "leak_test_mmhg", patch.leak_test_mmhg);
                w.attribute("patch", "rim_offset_mm", patch.rim_offset_mm);
                w.attribute("patch", "margin_mm", patch.margin_mm);
                if (patch.leak_mm) w.attribute("patch", "leak_mm", patch.leak_mm->data(), {3});
            }
            w.dataset("patch/positions", patch.positions, {patch.positions.size(), 3});
            if (!patch.leak_test_positions.empty())
                w.dataset("patch/leak_test_positions", patch.leak_test_positions, {patch.leak_test_positions.size(), 3});
            w.dataset("patch/triangles", patch.triangles, {patch.triangles.size(), 3});
            const std::size_t stitches = patch.stitch_vertex.size();
            w.dataset("patch/stitch_vertex", patch.stitch_vertex.data(), {stitches});
            w.dataset("patch/stitch_anchor", patch.stitch_anchor, {stitches, 3});
            w.dataset("patch/stitch_force", patch.stitch_force, {stitches, 3});
            w.dataset("patch/stitch_tied_ms", patch.stitch_tied_ms.data(), {stitches});
        }
    }, {}, {xdmf_file_beside(path, xdmf)});
}

SimulationState read_state(const std::filesystem::path& path) {
    const h5::Reader r(path);
    r.header("heartsim.state", 1, 1, "mm g ms");
    SimulationState state;
    state.backend = r.string_attribute("/", "backend");
    state.scenario = r.string_attribute("/", "scenario");
    state.time_ms = r.number<double>("/", "time_ms");
    state.steps = r.number<std::int64_t>("/", "steps");
    if (r.has_attribute("/", "mass_scale")) {
        state.mass_scale = r.number<double>("/", "mass_scale");
        if (!valid_mass_scale(state.mass_scale))
            r.fail("/", "attribute mass_scale must lie in [1, 1024], not " + std::to_string(state.mass_scale));
    }
    const auto positions = r.dataset<float>("positions", {-1, 3});
    r.require_finite("positions", positions);
    state.positions = h5::rows_of<3>(positions);
    const auto forces = r.dataset<double>("instrument_forces", {2, 3});
    for (int h = 0; h < 2; ++h)
        for (int c = 0; c < 3; ++c) state.force_n[h][c] = forces[std::size_t(3 * h + c)];
    const auto particles = r.dataset<std::int32_t>("instrument_particles", {2});
    const auto kind = r.dataset<std::int32_t>("instrument_kind", {2});
    for (int h = 0; h < 2; ++h) {
        state.particles[h] = particles[h], state.kind[h] = kind[h];
        if (kind[h] < 0 || kind[h] > 6) r.fail("instrument_kind", "hand " + std::to_string(h) + " is " + std::to_string(kind[h]) + ", expected 0 to 6");
    }
    if (r.exists("cut_springs")) {
        const auto cuts = r.dataset<std::int32_t>("cut_springs", {-1, 2});
        state.cut_springs = h5::rows_of<2>(cuts);
        for (std::size_t k = 0; k < state.cut_springs.size(); ++k) {
            const auto& [a, b] = state.cut_springs[k];
            if (a < 0 || b <= a || std::size_t(b) >= state.positions.size())
                r.fail("cut_springs", "pair (" + std::to_string(a) + ", " + std::to_string(b) + ") is not two particle indices, lower first");
            if (k > 0 && !(state.cut_springs[k - 1] < state.cut_springs[k]))
                r.fail("cut_springs", "row " + std::to_string(k) + " (" + std::to_string(a) + ", " + std::to_string(b) +
                                          ") is not after the row before it: the list is sorted, each spring once");
        }
    }
    if (r.exists("visual")) {
        const auto visual = r.dataset<float>("visual/positions", {-1, 3});
        r.require_finite("visual/positions", visual);
        state.visual_positions = h5::rows_of<3>(visual);
        if (r.exists("visual/triangles")) {
            state.visual_triangles = h5::rows_of<3>(r.dataset<std::int32_t>("visual/triangles", {-1, 3}));
            for (const auto& t : state.visual_triangles)
                for (std::int32_t v : t)
                    if (v < 0 || std::size_t(v) >= state.visual_positions.size())
                        r.fail("visual/triangles", "vertex index " + std::to_string(v) + " outside /visual/positions (" +
                                                       std::to_string(state.visual_positions.size()) + " rows)");
            const std::int64_t first = r.number<std::int64_t>("visual/triangles", "cap_first");
            if (first < 0 || std::size_t(first) > state.visual_triangles.size())
                r.fail("visual/triangles", "attribute cap_first " + std::to_string(first) + " outside [0, " +
                                               std::to_string(state.visual_triangles.size()) + "]");
            state.visual_cap_first = std::size_t(first);
        }
    }
    if (r.exists("patch")) {
        PatchState patch;
        patch.material = r.string_attribute("patch", "material");
        patch.thickness_mm = r.number<double>("patch", "thickness_mm");
        patch.youngs_modulus_mpa = r.number<double>("patch", "youngs_modulus_mpa");
        const auto positions = r.dataset<float>("patch/positions", {-1, 3});
        r.require_finite("patch/positions", positions);
        patch.positions = h5::rows_of<3>(positions);
        if (r.exists("patch/leak_test_positions")) {
            const auto tested = r.dataset<float>("patch/leak_test_positions", {long(patch.positions.size()), 3});
            r.require_finite("patch/leak_test_positions", tested);
            patch.leak_test_positions = h5::rows_of<3>(tested);
        }
        patch.triangles = h5::rows_of<3>(r.dataset<std::int32_t>("patch/triangles", {-1, 3}));
        for (const auto& t : patch.triangles)
            for (std::int32_t v : t)
                if (v < 0 || std::size_t(v) >= patch.positions.size())
                    r.fail("patch/triangles", "vertex index " + std::to_string(v) + " outside /patch/positions (" +
                                                  std::to_string(patch.positions.size()) + " rows)");
        patch.stitch_vertex = r.dataset<std::int32_t>("patch/stitch_vertex", {-1});
        const std::int64_t stitches = std::int64_t(patch.stitch_vertex.size());
        for (std::int32_t v : patch.stitch_vertex)
            if (v < 0 || std::size_t(v) >= patch.positions.size())
                r.fail("patch/stitch_vertex", "vertex index " + std::to_string(v) + " outside /patch/positions");
        const auto anchors = r.dataset<float>("patch/stitch_anchor", {stitches, 3});
        r.require_finite("patch/stitch_anchor", anchors);
        patch.stitch_anchor = h5::rows_of<3>(anchors);
        const auto force = r.dataset<double>("patch/stitch_force", {stitches, 3});
        r.require_finite("patch/stitch_force", force);
        patch.stitch_force = h5::rows_of<3>(force);
        patch.stitch_tied_ms = r.dataset<double>("patch/stitch_tied_ms", {stitches});
        if (r.has_attribute("patch", "defect_centre")) {
            patch.has_defect = true;
            const auto centre = r.numbers<double>("patch", "defect_centre", 3), axis = r.numbers<double>("patch", "defect_axis", 3);
            for (int c = 0; c < 3; ++c) patch.defect_centre[c] = centre[c], patch.defect_axis[c] = axis[c];
            patch.defect_diameter_mm = r.number<double>("patch", "defect_diameter_mm");
            patch.closed = r.number<std::int64_t>("patch", "closed") != 0;
            patch.largest_rim_gap_mm = r.number<double>("patch", "largest_rim_gap_mm");
            patch.leak_test_mmhg = r.number<double>("patch", "leak_test_mmhg");
            patch.rim_offset_mm = r.number<double>("patch", "rim_offset_mm");
            patch.margin_mm = r.number<double>("patch", "margin_mm");
            if (r.has_attribute("patch", "leak_mm")) {
                if (patch.closed) r.fail("patch", "attribute leak_mm (where it leaks) is there, but closed says the defect is closed");
                const auto leak = r.numbers<double>("patch", "leak_mm", 3);  // finite, or refused
                patch.leak_mm = std::array<double, 3>{leak[0], leak[1], leak[2]};
            }
        }
        state.patch = std::move(patch);
    }
    return state;
}

bool is_state_file(const std::filesystem::path& path) {
    try {
        const h5::Reader r(path);
        return r.has_attribute("/", "format") && r.string_attribute("/", "format") == "heartsim.state";
    } catch (const InputError&) {
        return false;
    }
}

}  // namespace heartsim
