// `heartprep inspect`: what a scenario file holds, for people (table) and scripts (--json).
#include "commands.h"
#include "pipeline.h"

#include "formats/scenario.h"
#include "libmodel/mapping.h"
#include "libmodel/sim/solver.h"
#include "libmodel/supports.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>

namespace heartsim::cli {

namespace {

struct Summary {
    std::size_t particles = 0, anchored = 0, springs = 0, face_springs = 0, edge_springs = 0;
    std::size_t visual_vertices = 0, visual_triangles = 0;
    std::size_t simsurface_triangles = 0;
    double texture_occupancy = 0.0;
    double mapping_rest_error_mm = -1.0;  ///< max |mapped rest position − visual vertex|; −1 without a mapping
    std::size_t embedded = 0, tangent = 0;  ///< visual vertices embedded in lattice cells, and in tangent space
    std::array<double, 3> weight_sum{};   ///< Σ|w| (the embedding's sensitivity) over vertices: median, 99th percentile, max
    std::array<double, 3> reach{};        ///< distance from a visual vertex to its nearest carrier, mm: median, 99th pct, max
    std::array<double, 3> offset{};       ///< |d| over tangent-space vertices, mm: median, 99th percentile, max
    std::size_t thin_particles = 0;       ///< particles one particle thick along some lattice axis
    double thin_volume_share = 0.0;       ///< their share of the tissue volume (mass / density)
    double total_mass = 0.0;
    /// Σ m/ρ: the tissue the particles carry, mm³ (their cells' tissue, as the layout weighed it;
    /// not the label map's tissue volume, /source tissue_volume_mm3).
    double particle_volume = 0.0;
    std::size_t supported = 0;            ///< particles with a support spring
    /// Of those, the ones on surface supports (posterior or boundary) rather than the elastic
    /// foundation alone (count_surface_supported: the figure build and batch give).
    std::size_t surface_supported = 0;
    double support_stiffness = 0.0;       ///< Σ k_s, N/mm
    std::size_t pieces = 0, free_pieces = 0;
    double max_prestrain = 0.0;           ///< max |L₀ − |x_b − x_a|| / |x_b − x_a| over springs at rest
    RestResidual residual;                ///< force at rest under /solver gravity (zero when balanced)
    Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d high = -low;
};

/// Median, 99th percentile and maximum of `values` (zeros when empty).
std::array<double, 3> spread(std::vector<double> values) {
    if (values.empty()) return {0.0, 0.0, 0.0};
    std::sort(values.begin(), values.end());
    auto at = [&](double q) { return values[std::size_t(q * double(values.size() - 1) + 0.5)]; };
    return {at(0.5), at(0.99), values.back()};
}

Summary summarise(const Scenario& s) {
    Summary summary;
    const auto& p = s.lattice.particles;
    summary.particles = p.size();
    for (std::size_t i = 0; i < p.size(); ++i) {
        summary.anchored += p.anchored[i];
        summary.total_mass += p.mass[i];
        const auto row = std::size_t(p.material[i]);
        summary.particle_volume += double(p.mass[i]) / (row < s.lattice.materials.size() ? s.lattice.materials[row].density : Material{}.density);
        const Eigen::Vector3d x(p.rest_position[i][0], p.rest_position[i][1], p.rest_position[i][2]);
        summary.low = summary.low.cwiseMin(x);
        summary.high = summary.high.cwiseMax(x);
    }
    const auto& sp = s.lattice.springs;
    summary.springs = sp.size();
    if (p.supported())
        for (std::size_t i = 0; i < p.size(); ++i) {
            const float k = p.support_stiffness[i];
            summary.supported += k > 0;
            summary.support_stiffness += k;
        }
    summary.surface_supported = count_surface_supported(s.lattice);
    const Pieces pieces = find_pieces(p, sp);
    summary.pieces = pieces.size.size();
    for (bool held : pieces.held) summary.free_pieces += !held;
    for (std::size_t q = 0; q < sp.size(); ++q) {
        const auto& a = p.rest_position[std::size_t(sp.pairs[q][0])];
        const auto& b = p.rest_position[std::size_t(sp.pairs[q][1])];
        const double distance = Eigen::Vector3d(double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]).norm();
        summary.max_prestrain = std::max(summary.max_prestrain, std::abs(distance - double(sp.rest_length[q])) / distance);
    }
    summary.residual = rest_force_residual(s.lattice, s.solver.gravity);
    // A face spring is one lattice step long; an edge spring √2 steps.
    for (float length : sp.rest_length) (length < 1.2 * s.lattice.spacing ? summary.face_springs : summary.edge_springs)++;
    if (s.visual) {
        summary.visual_vertices = s.visual->positions.size();
        summary.visual_triangles = s.visual->triangles.size();
    }
    if (s.packing) summary.texture_occupancy = double(p.size()) / (double(s.packing->width) * s.packing->height);
    if (s.simulation_surface) summary.simsurface_triangles = s.simulation_surface->size();
    if (s.mapping && s.simulation_surface && s.visual) {
        // Evaluate the mapping at rest, as the runtime will, and compare with the stored mesh.
        const auto mapped = apply_mapping(*s.mapping, p.rest_position, *s.simulation_surface);
        summary.mapping_rest_error_mm = 0.0;
        std::vector<double> weight_sum, reach, offset;
        std::array<std::int32_t, 8> carriers;
        std::array<float, 8> weights;
        for (std::size_t v = 0; v < mapped.size(); ++v) {
            const auto& x = s.visual->positions[v];
            const Eigen::Vector3f xv(x[0], x[1], x[2]);
            const double error = (mapped[v] - xv).norm();
            summary.mapping_rest_error_mm = std::max(summary.mapping_rest_error_mm, error);
            mapping_carriers(*s.mapping, *s.simulation_surface, v, carriers, weights);
            double sum = 0.0, nearest = std::numeric_limits<double>::infinity();
            for (std::size_t k = 0; k < 8; ++k) {
                sum += std::abs(double(weights[k]));
                const auto& c = p.rest_position[std::size_t(carriers[k])];
                if (weights[k] != 0.0f) nearest = std::min(nearest, double((Eigen::Vector3f(c[0], c[1], c[2]) - xv).norm()));
            }
            weight_sum.push_back(sum);
            reach.push_back(nearest);
            // Tangent space: the carriers are the frame triangle's corners with weights λ alone.
            const auto& frame = s.simulation_surface->triangles[std::size_t(s.mapping->triangle[v])];
            bool tangent = carriers[0] == frame[0] && carriers[1] == frame[1] && carriers[2] == frame[2];
            for (std::size_t k = 3; k < 8; ++k) tangent = tangent && weights[k] == 0.0f;
            if (tangent) {
                ++summary.tangent;
                offset.push_back(std::abs(double(s.mapping->offset[v])));
            } else {
                ++summary.embedded;
            }
        }
        summary.weight_sum = spread(weight_sum);
        summary.reach = spread(reach);
        summary.offset = spread(offset);
    }
    const ThinWallSummary thin = summarise_thin_walls(s.lattice);
    summary.thin_particles = thin.particles;
    summary.thin_volume_share = thin.volume_share;
    return summary;
}

/// The substeps heartsim's solver takes per step of dt (libmodel/sim/solver.cpp set_time_step): the
/// fewest within safety_factor × the damped critical step, that step no longer than the critical
/// one. Nothing when the file stores no damped step (the solver estimates it at load), and more
/// than Solver::max_substeps where heartsim refuses the step. /solver substeps is not this number.
std::optional<long long> runtime_substeps(const SolverSettings& solver) {
    const double damped = std::min(solver.damped_critical_dt_ms, solver.critical_dt_ms);
    const double limit = solver.safety_factor * damped;
    if (!(solver.damped_critical_dt_ms > 0) || !(limit > 0) || !std::isfinite(limit) || !(solver.dt_ms > 0)) return std::nullopt;
    const double needed = std::max(1.0, std::ceil(solver.dt_ms / limit * (1 - 1e-12)));
    return needed <= double(Solver::max_substeps) ? std::llround(needed) : Solver::max_substeps + 1LL;
}

std::string substeps_text(const SolverSettings& solver) {
    const auto n = runtime_substeps(solver);
    if (!n) return "substeps as the stable step needs";
    if (*n > Solver::max_substeps)
        return "a step heartsim refuses (over " + std::to_string(Solver::max_substeps) + " substeps of the stable step)";
    return std::to_string(*n) + (*n == 1 ? " substep" : " substeps");
}

/// /landmarks for --json: each found landmark's figures (not its points) and each missing one's reason.
nlohmann::ordered_json landmarks_json(const Scenario& s) {
    using json = nlohmann::ordered_json;
    if (!s.landmarks) return json();
    auto vector = [](const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); };
    json found = json::array(), missing = json::array();
    for (const Landmark& l : s.landmarks->found) {
        json o{{"name", l.name}, {"kind", to_string(l.kind)}, {"between", l.between}, {"points", l.points.size()},
               {"length_mm", l.length_mm}, {"surface_distance_mm", l.surface_distance_mm}, {"coverage", l.coverage}};
        if (l.kind == LandmarkKind::ring) {
            o["diameter_mm"] = l.diameter_mm;
            o["centre"] = vector(l.centre);
            o["normal"] = vector(l.normal);
        }
        found.push_back(o);
    }
    for (const MissingLandmark& m : s.landmarks->missing) missing.push_back({{"name", m.name}, {"reason", m.reason}});
    return json{{"found", found}, {"missing", missing}};
}

/// /landmarks for the table: one line a landmark.
void print_landmarks(const Scenario& s) {
    if (!s.landmarks) {
        std::printf("landmarks   none stored (a file from before heartprep found them)\n");
        return;
    }
    const char* head = "landmarks  ";
    for (const Landmark& l : s.landmarks->found) {
        std::printf("%s %s: %zu points", head, l.name.c_str(), l.points.size());
        if (l.kind == LandmarkKind::course) std::printf(", %.1f mm long", l.length_mm);
        if (l.kind == LandmarkKind::ring) std::printf(", %.1f mm across, perimeter %.1f mm", l.diameter_mm, l.length_mm);
        if (l.coverage < 1.0) std::printf(", %.0f%% of it on the surface", 100.0 * l.coverage);
        std::printf(" (%s)\n", l.between.c_str());
        head = "           ";
    }
    for (const MissingLandmark& m : s.landmarks->missing) {
        std::printf("%s %s: missing: %s\n", head, m.name.c_str(), m.reason.c_str());
        head = "           ";
    }
}

void print_json(const std::filesystem::path& path, const Scenario& s, const Summary& m) {
    using json = nlohmann::ordered_json;
    auto vector = [](const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); };
    const auto& g = s.source.geometry;
    json o{{"file", path.string()},
           {"file_bytes", std::filesystem::file_size(path)},
           {"format_version", scenario_format_version},
           {"generator", s.generator},
           {"source", {{"file_name", s.source.file_name}, {"sha256", s.source.sha256}, {"dims", {g.dims[0], g.dims[1], g.dims[2]}},
                       {"spacing", vector(g.spacing)}}},
           {"lattice", {{"spacing", s.lattice.spacing}, {"dims", {s.lattice.dims[0], s.lattice.dims[1], s.lattice.dims[2]}}}},
           {"tissue_volume_ml", s.source.tissue_volume_mm3 > 0 ? json(s.source.tissue_volume_mm3 / 1000.0) : json()},
           {"heart", heart_contents(s)},
           {"defect", s.source.defect.empty() ? json(nullptr)
                                              : json{{"type", s.source.defect},
                                                     {"centre", vector(s.source.defect_centre)},
                                                     {"axis", vector(s.source.defect_axis)},
                                                     {"diameter_mm", s.source.defect_diameter_mm}}},
           {"particles", m.particles},
           {"anchored", m.anchored},
           {"springs", m.springs},
           {"face_springs", m.face_springs},
           {"edge_springs", m.edge_springs},
           {"total_mass_g", m.total_mass},
           {"particle_volume_ml", m.particle_volume / 1000.0},
           {"bounds", {{"min", vector(m.low)}, {"max", vector(m.high)}}},
           {"visual", s.visual ? json{{"vertices", m.visual_vertices}, {"triangles", m.visual_triangles}} : json()},
           {"packing", s.packing ? json{{"scheme", to_string(s.packing->scheme)},
                                        {"width", s.packing->width},
                                        {"height", s.packing->height},
                                        {"occupancy", m.texture_occupancy}}
                                 : json()},
           {"simsurface_triangles", m.simsurface_triangles},
           {"mapping_rest_error_mm", s.mapping ? json(m.mapping_rest_error_mm) : json()}};
    if (s.mapping)
        o["mapping"] = {{"embedded", m.embedded},
                        {"tangent", m.tangent},
                        {"weight_sum_median_p99_max", m.weight_sum},
                        {"nearest_carrier_mm_median_p99_max", m.reach},
                        {"offset_mm_median_p99_max", m.offset}};
    o["thin_walls"] = {{"particles", m.thin_particles}, {"volume_share", m.thin_volume_share}};
    json materials = json::array();
    for (std::size_t k = 0; k < s.lattice.materials.size(); ++k) {
        const Material& mat = s.lattice.materials[k];
        const TissueOrigin origin = k < s.tissue_origin.size() ? s.tissue_origin[k] : TissueOrigin{};
        materials.push_back({{"label", mat.label},
                             {"name", mat.name},
                             {"density_g_per_mm3", mat.density},
                             {"youngs_modulus_kpa", mat.youngs_modulus_kpa},
                             {"poisson_ratio", mat.poisson_ratio},
                             {"face_spring_stiffness_n_per_mm", spring_stiffness(mat.youngs_modulus_kpa, s.lattice.spacing, mat.poisson_ratio)},
                             {"added_lame_modulus_kpa", 1e3 * added_lame_modulus(mat.youngs_modulus_kpa, mat.poisson_ratio)},
                             {"damping_ratio", mat.damping_ratio},
                             {"origin", origin.grown ? "grown" : "labelled"},
                             {"wall_thickness_mm", origin.thickness_mm},
                             {"tissue_volume_ml", origin.volume_mm3 > 0 ? json(origin.volume_mm3 / 1000.0) : json()}});
    }
    o["materials"] = std::move(materials);
    const auto substeps = runtime_substeps(s.solver);
    o["solver"] = {{"dt_ms", s.solver.dt_ms},
                   {"substeps", substeps ? nlohmann::json(*substeps) : nlohmann::json()},
                   {"damping", s.solver.damping},
                   {"gravity", vector(s.solver.gravity)},
                   {"balanced_gravity", vector(s.solver.balanced_gravity)},
                   {"critical_dt_ms", s.solver.critical_dt_ms},
                   {"critical_dt_bound_ms", s.solver.critical_dt_bound_ms},
                   {"damped_critical_dt_ms", s.solver.damped_critical_dt_ms}};
    o["holding"] = {{"supported_particles", m.supported},
                    {"surface_supported_particles", m.surface_supported},
                    {"support_stiffness_n_per_mm", m.support_stiffness},
                    {"pieces", m.pieces},
                    {"free_pieces", m.free_pieces},
                    {"max_prestrain", m.max_prestrain},
                    {"rest_residual_max_particle_n", m.residual.max_particle_n},
                    {"rest_residual_total_n", m.residual.total.norm()}};
    o["landmarks"] = landmarks_json(s);
    o["build_warnings"] = s.build_warnings ? json(*s.build_warnings) : json();
    // nlohmann writes NaN and infinities as null and replaces bytes that are not UTF-8: always valid JSON.
    std::fputs((o.dump(2, ' ', false, json::error_handler_t::replace) + "\n").c_str(), stdout);
}

/// One line a material: labelled or grown (with its thickness), its volume and its particles.
void print_tissues(const Scenario& s) {
    std::vector<std::size_t> particles(s.lattice.materials.size(), 0);
    for (auto row : s.lattice.particles.material) ++particles[std::size_t(row)];
    const char* head = "tissues    ";
    for (std::size_t k = 0; k < s.lattice.materials.size(); ++k) {
        const Material& material = s.lattice.materials[k];
        const TissueOrigin origin = k < s.tissue_origin.size() ? s.tissue_origin[k] : TissueOrigin{};
        std::printf("%s %s (label %d): ", head, material.name.c_str(), material.label);
        if (origin.grown) std::printf("grown %g mm around label %d", origin.thickness_mm, origin.grown_from);
        else std::printf("as labelled");
        if (origin.volume_mm3 > 0) std::printf(", %.1f mL", origin.volume_mm3 / 1000.0);
        std::printf(", %zu particles\n", particles[k]);
        head = "           ";
    }
}

void print_table(const std::filesystem::path& path, const Scenario& s, const Summary& m) {
    std::printf("file        %s (%.2f MB), %s\n", path.c_str(), double(std::filesystem::file_size(path)) / 1e6, s.generator.c_str());
    const auto& g = s.source.geometry;
    std::printf("source      %s, %d x %d x %d voxels of %.3f x %.3f x %.3f mm, sha256 %.12s…\n", s.source.file_name.c_str(),
                g.dims[0], g.dims[1], g.dims[2], g.spacing[0], g.spacing[1], g.spacing[2], s.source.sha256.c_str());
    if (s.source.tissue_volume_mm3 > 0) std::printf("tissue      %.1f mL (the label map's tissue voxels)\n", s.source.tissue_volume_mm3 / 1000.0);
    std::printf("heart       %s\n", heart_contents(s).c_str());
    print_tissues(s);
    if (!s.source.defect.empty())
        std::printf("defect      %s, %.1f mm, centre %.1f, %.1f, %.1f (LPS mm), axis %.2f, %.2f, %.2f\n", s.source.defect.c_str(),
                    s.source.defect_diameter_mm, s.source.defect_centre.x(), s.source.defect_centre.y(), s.source.defect_centre.z(),
                    s.source.defect_axis.x(), s.source.defect_axis.y(), s.source.defect_axis.z());
    std::printf("lattice     spacing %.3f mm, %d x %d x %d cells\n", s.lattice.spacing, s.lattice.dims[0], s.lattice.dims[1],
                s.lattice.dims[2]);
    // The particles' mass is their cells' tissue at its density: not the label map's volume above.
    char density[48] = "";
    if (s.lattice.materials.size() == 1) std::snprintf(density, sizeof density, " at %.3g g/cm³", s.lattice.materials.front().density * 1e3);
    std::printf("particles   %zu (%zu anchored), %.3f g: the tissue of their cells, %.1f mL%s\n", m.particles, m.anchored, m.total_mass,
                m.particle_volume / 1000.0, density);
    std::printf("springs     %zu (%zu face, %zu edge)\n", m.springs, m.face_springs, m.edge_springs);
    std::printf("thin walls  %zu particles one particle thick along some axis, %.2f%% of the tissue volume\n", m.thin_particles,
                100 * m.thin_volume_share);
    std::printf("bounds      LPS mm [%.1f, %.1f] x [%.1f, %.1f] x [%.1f, %.1f]\n", m.low.x(), m.high.x(), m.low.y(), m.high.y(),
                m.low.z(), m.high.z());
    if (s.visual)
        std::printf("visual      %zu vertices, %zu triangles\n", m.visual_vertices, m.visual_triangles);
    else
        std::printf("visual      none (the runtime draws the simulation surface)\n");
    if (s.packing)
        std::printf("packing     %s, %d x %d texture, %.1f%% occupied\n", to_string(s.packing->scheme), s.packing->width,
                    s.packing->height, 100 * m.texture_occupancy);
    else
        std::printf("packing     none (run `heartprep pack`)\n");
    if (s.simulation_surface)
        std::printf("simsurface  %zu triangles\n", m.simsurface_triangles);
    else
        std::printf("simsurface  none (run `heartprep simsurface`)\n");
    if (s.mapping) {
        std::printf("mapping     %zu visual vertices; at rest the mapping reproduces them within %.2g mm\n", m.visual_vertices,
                    m.mapping_rest_error_mm);
        std::printf("            %zu embedded in lattice cells, %zu in tangent space (|d| median %.2f, 99%% %.2f, max "
                    "%.2f mm)\n",
                    m.embedded, m.tangent, m.offset[0], m.offset[1], m.offset[2]);
        std::printf("            sum |w| median %.2f, 99%% %.2f, max %.2f; nearest carrier median %.2f, 99%% %.2f, max %.2f mm\n",
                    m.weight_sum[0], m.weight_sum[1], m.weight_sum[2], m.reach[0], m.reach[1], m.reach[2]);
    }
    else if (s.visual)
        std::printf("mapping     none (run `heartprep map`)\n");
    for (const auto& mat : s.lattice.materials) {
        char volume[64] = ", springs alone";
        if (mat.poisson_ratio > 0.25)
            std::snprintf(volume, sizeof volume, ", volume term Δλ %.3g kPa", 1e3 * added_lame_modulus(mat.youngs_modulus_kpa, mat.poisson_ratio));
        std::printf("material    %d %s: density %.3g g/cm³, E %.3g kPa, Poisson's ratio %.3g (spring %.4g N/mm%s), damping ratio %.3g\n",
                    mat.label, mat.name.c_str(), mat.density * 1e3, mat.youngs_modulus_kpa, mat.poisson_ratio,
                    spring_stiffness(mat.youngs_modulus_kpa, s.lattice.spacing, mat.poisson_ratio), volume, mat.damping_ratio);
    }
    const std::string substeps = substeps_text(s.solver);
    std::printf("solver      dt %.4g ms (critical %.4g ms, proven bound %.4g ms, damped %s ms), %s, drag %.3g /ms, "
                "gravity (%.3g, %.3g, %.3g) mm/ms²\n",
                s.solver.dt_ms, s.solver.critical_dt_ms, s.solver.critical_dt_bound_ms,
                s.solver.damped_critical_dt_ms > 0 ? std::to_string(s.solver.damped_critical_dt_ms).c_str() : "not stored", substeps.c_str(),
                s.solver.damping,
                s.solver.gravity.x(), s.solver.gravity.y(), s.solver.gravity.z());
    std::printf("holding     %zu anchored; %zu particles on surface supports%s; %.3g N/mm in all; %zu piece(s), %zu held by nothing\n",
                m.anchored, m.surface_supported,
                m.supported > m.surface_supported ? (", an elastic foundation under all " + std::to_string(m.supported) + " free particles").c_str() : "",
                m.support_stiffness, m.pieces, m.free_pieces);
    const Eigen::Vector3d& b = s.solver.balanced_gravity;
    std::printf("rest state  %s; pre-strain max %.2g%%; force at rest under gravity: max %.3g N on a particle, %.3g N in all\n",
                b.norm() > 0 ? "balanced under gravity (pre-stressed)" : "unstressed (imaged shape, no pre-stress)", 100 * m.max_prestrain,
                m.residual.max_particle_n, m.residual.total.norm());
    print_landmarks(s);
    if (!s.build_warnings)
        std::printf("warnings    not stored (a file from before heartprep kept its build's warnings)\n");
    else if (s.build_warnings->empty())
        std::printf("warnings    none from the build\n");
    else
        for (std::size_t i = 0; i < s.build_warnings->size(); ++i)
            std::printf("%s %s\n", i ? "           " : "warnings   ", (*s.build_warnings)[i].c_str());
}

}  // namespace

void add_inspect_command(CLI::App& app) {
    auto* command = app.add_subcommand("inspect", "Summarise a scenario file: counts, bounds, materials, mass, time step, size");
    auto path = std::make_shared<std::filesystem::path>();
    auto json = std::make_shared<bool>(false);
    command->add_option("file", *path, "Scenario file (.h5)")->required();
    command->add_flag("--json", *json, "Print JSON instead of a table");
    command->callback([=] {
        const Scenario scenario = read_scenario(*path);  // validates everything
        const Summary summary = summarise(scenario);
        if (*json)
            print_json(*path, scenario, summary);
        else
            print_table(*path, scenario, summary);
    });
}

}  // namespace heartsim::cli
