#include "pipeline.h"
#include "landmark_stage.h"
#include "cli/option_flags.h"

#include "formats/label_table.h"
#include "formats/mesh_io.h"
#include "formats/xdmf.h"
#include "libmodel/landmarks.h"
#include "libmodel/errors.h"
#include "libmodel/text.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <set>

namespace heartsim::cli {

namespace {

/// Times a stage into the report.
template <class Work>
auto timed(BuildReport& report, const char* stage, Work&& work) {
    const auto start = std::chrono::steady_clock::now();
    auto finish = [&] {
        report.times.push_back({stage, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()});
    };
    if constexpr (std::is_void_v<decltype(work())>) {
        work();
        finish();
    } else {
        auto result = work();
        finish();
        return result;
    }
}

void append(std::vector<std::string>& to, const std::vector<std::string>& from) { to.insert(to.end(), from.begin(), from.end()); }

// What a segmented heart looks like, for the warnings about an input that is something else.
constexpr std::size_t max_plausible_labels = 64;     ///< distinct non-zero values in a label map
constexpr std::size_t max_plausible_islands = 1000;  ///< 6-connected pieces of the tissue
constexpr double max_tissue_ml = 500.0;              ///< a heart's muscle (an adult's: 100-300 mL)

}  // namespace

LabelVolume read_and_resolve(const std::filesystem::path& input, const LabelChoice& labels, SelectionOptions& options,
                             Progress& progress, BuildReport& report) {
    // A convention by name, or a table file; the table first: a bad --labels file is reported
    // before a long read. A file of that name wins over a convention.
    const LabelConvention* convention = nullptr;
    if (!labels.label_table.empty() && !std::filesystem::exists(labels.label_table))
        convention = find_label_convention(labels.label_table.string());
    if (!labels.label_table.empty() && !convention && !std::filesystem::exists(labels.label_table))
        throw InputError(labels.label_table.string() + ": cannot read the label table: no such file (--labels takes a label table "
                         "file or a convention: " + label_convention_names() + ")");
    const SegmentNames table = convention       ? convention->names
                               : labels.label_table.empty() ? SegmentNames{}
                                                            : read_label_table(labels.label_table);
    LabelVolume volume = timed(report, "read", [&] {
        ProgressStage stage(progress, "read volume", 0);
        return read_label_volume(input, {}, &report.header);
    });
    append(report.warnings, report.header.warnings);
    report.segment_names = report.header.segment_names;
    for (const auto& [label, name] : table) report.segment_names[label] = name;
    if (convention) report.convention = convention->name;
    std::set<int> present;  // the non-zero values
    {
        std::vector<std::uint8_t> seen(65536, 0);
        for (std::int32_t label : volume.labels) {
            if (label >= 0 && label < 65536) {
                if (seen[std::size_t(label)]) continue;
                seen[std::size_t(label)] = 1;
            }
            if (label != 0) present.insert(label);
        }
    }
    // A label map holds a few labels; an intensity image (an MRI or CT, not its segmentation)
    // holds hundreds of values.
    if (present.size() > max_plausible_labels) {
        std::string first;
        int shown = 0;
        for (auto it = present.begin(); it != present.end() && shown < 6; ++it, ++shown) first += std::to_string(*it) + ", ";
        report.warnings.push_back(input.string() + " holds " + std::to_string(present.size()) + " different values (" + first + "… up to " +
                                  std::to_string(*present.rbegin()) + "): a label map holds a few labels; is it an intensity image (the "
                                  "MRI or CT itself) rather than its segmentation?");
    }
    if (report.segment_names.empty()) {
        if (const LabelConvention* match = matching_label_convention(present))
        {
            report.convention_hint = "the labels match " + match->title + ": --labels " + match->name + " names them";
            report.convention_match = match->name;
        }
    }
    try {
        if (labels.tissue.empty()) {
            std::string note;
            options.tissue_labels = convention ? std::vector<int>{convention->myocardium} : default_tissue_labels(report.segment_names, &note);
            if (!note.empty()) report.warnings.push_back(note);
        } else {
            options.tissue_labels = resolve_label_choice(labels.tissue, report.segment_names, "--tissue");
        }
        // A convention knows its blood pools: they are the cavities unless --cavity says otherwise,
        // those the map holds (a map may leave a structure out: a crop without the pulmonary artery).
        if (labels.cavity.empty() && convention) {
            std::string absent;
            for (int label : convention->blood) {
                if (present.count(label)) {
                    options.cavity_labels.push_back(label);
                    continue;
                }
                const auto name = convention->names.find(label);
                absent += (absent.empty() ? "" : ", ") + std::to_string(label) +
                          (name == convention->names.end() ? std::string() : " '" + name->second + "'");
            }
            if (!absent.empty())
                report.warnings.push_back(input.string() + " holds no " + absent + " of " + convention->title +
                                          "'s blood labels: those structures, and their walls, are left out");
        } else {
            options.cavity_labels = resolve_label_choice(labels.cavity, report.segment_names, "--cavity");
        }
        options.anchor_labels = resolve_label_choice(labels.anchor, report.segment_names, "--anchor-label");
    } catch (const InputError& error) {
        throw InputError(input.string() + ": " + error.what());
    }
    append(report.warnings, tissue_name_warnings(options.tissue_labels, report.segment_names));
    // A volume without names whose labels are a convention's: judge the tissue by the names the
    // convention gives (HVSMR 2016's label 2 is the blood pool).
    if (report.segment_names.empty() && !report.convention_match.empty()) {
        const LabelConvention& match = *find_label_convention(report.convention_match);
        for (const std::string& warning : tissue_name_warnings(options.tissue_labels, match.names))
            report.warnings.push_back("by " + match.title + "'s labels, which this volume's match (--labels " + match.name + "): " + warning);
    }
    return volume;
}

SelectedVolume read_and_select(const std::filesystem::path& input, const LabelChoice& labels, SelectionOptions& options,
                               Progress& progress, BuildReport& report, const std::optional<DefectChoice>& defect, const WallChoice& walls) {
    SelectedVolume result;
    result.volume = read_and_resolve(input, labels, options, progress, report);
    if (defect) defect_stage(result.volume, input, *defect, options, progress, report);
    if (walls.grow) timed(report, "walls", [&] { walls_stage(result.volume, walls, options, progress, report); });
    try {
        result.selection = timed(report, "select", [&] { return select_tissue(result.volume, options, progress, &report.selection); });
    } catch (const InputError& error) {
        if (report.convention_hint.empty()) throw;
        throw InputError(std::string(error.what()) + "; " + report.convention_hint);
    }
    append(report.warnings, report.selection.warnings);
    if (report.selection.tissue_volume_mm3 > max_tissue_ml * 1000.0)
        report.warnings.push_back("the tissue is " + std::to_string(int(std::lround(report.selection.tissue_volume_mm3 / 1000.0))) +
                                  " mL, far more than a heart's muscle (an adult's is 100-300 mL): is --tissue a blood pool or a "
                                  "whole-heart mask?");
    if (report.selection.islands.size() > max_plausible_islands)
        report.warnings.push_back("the tissue falls into " + std::to_string(report.selection.islands.size()) + " separate pieces (" +
                                  std::to_string(report.selection.islands_dropped) +
                                  " dropped as smaller than --min-island): a heart's myocardium is one piece and a few specks; is the "
                                  "input an intensity image, or --tissue the wrong label?");
    return result;
}

void walls_stage(LabelVolume& volume, const WallChoice& choice, SelectionOptions& options, Progress& progress, BuildReport& report) {
    WallsReport& walls = report.walls;
    walls.asked = choice.grow;
    if (!choice.grow) return;
    const std::string& name = report.convention.empty() ? report.convention_match : report.convention;
    const LabelConvention* convention = name.empty() ? nullptr : find_label_convention(name);
    // The walls' labels: above every label the volume holds, the build names (--tissue, --cavity,
    // --anchor-label) or the convention knows, so that a map without some of a convention's labels
    // (an MM-WHS map with no pulmonary artery) gives no wall a label the build reads as blood.
    std::set<int> named(volume.labels.begin(), volume.labels.end());
    for (const std::vector<int>* list : {&options.tissue_labels, &options.cavity_labels, &options.anchor_labels}) named.insert(list->begin(), list->end());
    if (convention)
        for (const auto& [label, segment] : convention->names) named.insert(label);
    const int first_label = std::max(1, named.empty() ? 1 : *named.rbegin() + 1);
    std::vector<WallStructure> structures;
    if (convention && options.tissue_labels == std::vector<int>{convention->myocardium}) {
        walls.convention = convention->title;
        structures = convention_walls(*convention, choice.thickness, first_label);
    } else if (!options.cavity_labels.empty()) {
        structures.push_back({"blood pool wall (grown)", options.cavity_labels, choice.thickness.blood_pool, first_label});
    } else {
        walls.none_because = convention ? "the tissue is not " + convention->title + "'s myocardium (--tissue), so its blood's walls are not known"
                                        : "no label names blood (--labels names a convention, --cavity the blood)";
        return;
    }
    // A label the build anchors (--anchor-label) holds the tissue, whatever a convention calls it:
    // no wall grows around it.
    for (WallStructure& s : structures)
        std::erase_if(s.blood_labels, [&](int label) {
            return std::find(options.anchor_labels.begin(), options.anchor_labels.end(), label) != options.anchor_labels.end();
        });
    std::erase_if(structures, [](const WallStructure& s) { return s.blood_labels.empty(); });
    if (structures.empty()) {
        walls.none_because = "the only blood label is anchored (--anchor-label): no wall grows around it";
        return;
    }
    const WallGrowthReport grown = grow_walls(volume, structures, progress);
    for (std::size_t k = 0; k < structures.size(); ++k) {
        if (grown.walls[k].voxels == 0) {
            walls.bare.push_back({structures[k], grown.walls[k]});
            continue;
        }
        walls.grown.push_back({structures[k], grown.walls[k]});
        options.tissue_labels.push_back(structures[k].wall_label);
        report.segment_names[structures[k].wall_label] = structures[k].name;
    }
    if (walls.grown.empty()) walls.none_because = "no blood faces background: every blood surface has its labelled wall";
}

void defect_stage(LabelVolume& volume, const std::filesystem::path& input, const DefectChoice& choice, const SelectionOptions& options,
                  Progress& progress, BuildReport& report) {
    DefectOptions o;
    o.type = choice.type;
    o.diameter_mm = choice.diameter_mm;
    o.at = choice.at;
    o.site = choice.site;
    o.max_wall_mm = choice.max_wall_mm;
    o.wall_labels = options.tissue_labels;
    o.blood_labels = options.cavity_labels;
    if (o.blood_labels.empty()) {
        std::set<int> others;
        for (std::int32_t label : volume.labels)
            if (label != 0 && std::find(o.wall_labels.begin(), o.wall_labels.end(), label) == o.wall_labels.end()) others.insert(label);
        o.blood_labels.assign(others.begin(), others.end());
    }
    const ChamberLabels c = chamber_labels_from_names(report.segment_names);
    if (choice.type == DefectType::vsd) o.side_a = c.left_ventricle, o.side_b = c.right_ventricle;
    else o.side_a = c.left_atrium, o.side_b = c.right_atrium;
    if (o.side_a == 0 || o.side_b == 0) o.side_a = o.side_b = 0;
    o.aorta = c.aorta;
    if (choice.type == DefectType::asd && o.side_a != 0) {
        // Label maps that name the chambers seldom label the atria's thin walls (MM-WHS labels
        // the left ventricle's wall only): between the atria's blood, unlabelled voxels are the wall.
        if (std::find(o.wall_labels.begin(), o.wall_labels.end(), 0) == o.wall_labels.end()) o.wall_labels.push_back(0);
    }
    for (int side : {o.side_a, o.side_b})
        if (side != 0 && std::find(o.blood_labels.begin(), o.blood_labels.end(), side) == o.blood_labels.end()) o.blood_labels.push_back(side);
    try {
        report.defect = timed(report, "defect", [&] { return carve_defect(volume, o, report.segment_names, progress); });
    } catch (const OptionError& error) {
        // Only a convention that tells the chambers apart can place a defect without a point.
        const LabelConvention* match = report.convention_match.empty() ? nullptr : find_label_convention(report.convention_match);
        if (!match || !match->chambers()) throw;
        throw OptionError(std::string(error.what()) + " (" + report.convention_hint + ")");
    } catch (const InputError& error) {
        throw InputError(input.string() + ": " + error.what());
    }
}

void print_defect_summary(const DefectReport& d, const SegmentNames& names) {
    std::printf("defect      %s%s: %.1f mm opening (measured: a clear passage %.1f mm across), %zu voxels carved\n",
                to_string(d.type).c_str(), d.site ? (", " + to_string(*d.site) + " site").c_str() : "", d.diameter_mm,
                d.measured_diameter_mm, d.voxels_carved);
    std::printf("            centre %.1f, %.1f, %.1f (LPS mm), axis %.2f, %.2f, %.2f; wall %.1f mm thick there\n", d.centre.x(),
                d.centre.y(), d.centre.z(), d.normal.x(), d.normal.y(), d.normal.z(), d.wall_thickness_mm);
    std::printf("            joins %s and %s: %s", describe_label(d.label_a, names).c_str(), describe_label(d.label_b, names).c_str(),
                d.connected ? "connected through the opening (flood fill)" : "NOT connected");
    if (d.distance_to_aorta_mm >= 0) std::printf("; %.1f mm from the aorta's blood", d.distance_to_aorta_mm);
    if (d.sites_tried) std::printf("; %zu place(s) tried", d.sites_tried);
    std::printf("; %.2f s\n", d.seconds);
}

void pack_stage(Scenario& scenario, const PackingOptions& options, Progress& progress, BuildReport& report) {
    std::vector<std::int32_t> new_index;
    scenario.packing = timed(report, "pack", [&] {
        return pack_particles(scenario.lattice, options, progress, &report.packing, &new_index);
    });
    if (scenario.simulation_surface)
        for (auto& triangle : scenario.simulation_surface->triangles)
            for (auto& vertex : triangle) vertex = new_index[std::size_t(vertex)];
    if (scenario.mapping)  // the carriers of embedded vertices are particle indices too
        for (auto& carriers : scenario.mapping->particles)
            for (auto& particle : carriers) particle = new_index[std::size_t(particle)];
}

void simulation_surface_stage(Scenario& scenario, Progress& progress, BuildReport& report) {
    scenario.simulation_surface = timed(report, "simsurface", [&] {
        return build_simulation_surface(scenario.lattice, progress, &report.simulation_surface);
    });
    append(report.warnings, report.simulation_surface.warnings);
    scenario.mapping.reset();
}

void mapping_stage(Scenario& scenario, const std::filesystem::path& visual_mesh, Progress& progress, BuildReport& report,
                   MappingMethod method) {
    if (!visual_mesh.empty()) {
        TriangleMesh mesh = timed(report, "read visual mesh", [&] { return read_mesh(visual_mesh); });
        report.mesh = analyse_mesh(mesh);
        if (!report.mesh.closed() || !report.mesh.manifold())
            report.warnings.push_back(visual_mesh.string() + ": the visual mesh is not a closed 2-manifold (" +
                                      std::to_string(report.mesh.boundary_edges) + " boundary edges, " +
                                      std::to_string(report.mesh.nonmanifold_edges) + " non-manifold edges, " +
                                      std::to_string(report.mesh.nonmanifold_vertices) +
                                      " non-manifold vertices): it is mapped, but its shading may show seams");
        if (mesh.normals.size() != mesh.positions.size()) compute_vertex_normals(mesh);
        scenario.visual = to_visual_mesh(mesh);
    }
    if (!scenario.visual) return;
    if (!scenario.simulation_surface) simulation_surface_stage(scenario, progress, report);
    std::vector<Eigen::Vector3d> positions;
    positions.reserve(scenario.visual->positions.size());
    for (const auto& p : scenario.visual->positions) positions.emplace_back(p[0], p[1], p[2]);
    MappingOptions options;
    options.lattice_spacing_mm = scenario.lattice.spacing;
    options.method = method;
    scenario.mapping = timed(report, "map", [&] {
        return map_visual_mesh(positions, scenario.lattice, *scenario.simulation_surface, options, progress, &report.mapping);
    });
    for (const auto& warning : report.mapping.warnings)
        report.warnings.push_back((visual_mesh.empty() ? std::string() : visual_mesh.string() + ": ") + warning);
}

void hold_stage(Scenario& scenario, const BuildOptions& options, Progress& progress, BuildReport& report) {
    Lattice& lattice = scenario.lattice;
    timed(report, "supports", [&] {
        SupportOptions supports = options.supports;
        supports.full_fraction = options.layout.occupancy;  // thin-wall particles carry their cell's tissue only
        report.supports = add_supports(lattice, supports);
        report.free_pieces = drop_free_pieces(lattice, options.free_pieces);
    });
    const auto& pieces = report.free_pieces;
    report.layout.particles = lattice.particles.size();
    if (pieces.dropped_particles > 0) {
        report.layout.anchored = std::size_t(std::count(lattice.particles.anchored.begin(), lattice.particles.anchored.end(), 1));
        const ThinWallSummary thin = summarise_thin_walls(lattice);  // of the particles kept
        report.layout.thin_particles = thin.particles;
        report.layout.thin_volume_share = thin.volume_share;
    }
    if (pieces.free_pieces_kept > 0)
        report.warnings.push_back(std::to_string(pieces.free_pieces_kept) + " lattice piece(s) of " +
                                  std::to_string(pieces.free_particles_kept) +
                                  " particles are held by nothing (--allow-free): they fall under gravity and drift under instruments");
    const Eigen::Vector3d& g = options.solver.gravity;
    scenario.solver.balanced_gravity = Eigen::Vector3d::Zero();
    // The pieces after dropping (balancing moves no particle between pieces).
    const Pieces pieces_left = find_pieces(lattice.particles, lattice.springs);
    const bool any_held = std::find(pieces_left.held.begin(), pieces_left.held.end(), true) != pieces_left.held.end();
    if (options.balance_rest_state && g.norm() > 0) {
        report.balance = timed(report, "balance", [&] { return balance_rest_state(lattice, g, {}, progress); });
        append(report.warnings, report.balance.warnings);
        if (report.balance.balanced) scenario.solver.balanced_gravity = g;
        // Weak supports: the balance hides the sag at rest, but the heart still swings that far
        // under a disturbance of its own weight.
        if (report.balance.max_sag_mm > 5.0)
            report.warnings.push_back("the supports are weak: without the balanced rest state the heart would sag by up to " +
                                      std::to_string(report.balance.max_sag_mm) +
                                      " mm under gravity; raise --support-stiffness or use --support boundary");
    } else if (g.norm() > 0) {
        report.balance = timed(report, "balance", [&] {
            // Measure the sag anyway (on a copy) so the summary can say what the unbalanced state does.
            if (!any_held) return RestBalanceReport{};
            Lattice copy = lattice;
            try {
                RestBalanceReport sag = balance_rest_state(copy, g, {}, progress);
                sag.balanced = false;
                return sag;
            } catch (const InputError&) {
                return RestBalanceReport{};  // a mechanism nothing holds: no linear sag to report
            }
        });
        if (report.balance.max_sag_mm > 0)
            report.warnings.push_back("--rest-state imaged: the springs are unstressed at the imaged shape, so the heart sags by up to " +
                                      std::to_string(report.balance.max_sag_mm) + " mm under gravity when the simulation starts");
    }
    if (!any_held && g.norm() > 0)
        report.warnings.push_back("nothing holds the heart (no anchor, no support) and gravity is on: it free-falls in heartsim");
}

namespace {

/// The grown wall of label `label`, or nullptr.
const GrownStructure* grown_wall(const WallsReport& walls, int label) {
    for (const GrownStructure& wall : walls.grown)
        if (wall.structure.wall_label == label) return &wall;
    return nullptr;
}

}  // namespace

Scenario build_scenario(const BuildOptions& options, Progress& progress, BuildReport& report) {
    Scenario scenario;
    scenario.generator = std::string("heartprep ") + HEARTSIM_VERSION;
    scenario.source.file_name = options.input.filename().string();
    // References, not a structured binding: clang 14 (the sanitize preset) cannot capture those in lambdas.
    SelectionOptions chosen = options.selection;
    SelectedVolume selected = read_and_select(options.input, options.labels, chosen, progress, report, options.defect, options.walls);
    const LabelVolume& volume = selected.volume;
    const Selection& selection = selected.selection;
    scenario.source.sha256 = timed(report, "hash", [&] { return label_map_sha256(options.input); });
    scenario.source.geometry = volume.geometry;
    scenario.source.tissue_labels.clear();  // the input's labels: a grown wall's label is not the input's
    for (int label : chosen.tissue_labels)
        if (!grown_wall(report.walls, label)) scenario.source.tissue_labels.push_back(label);
    for (std::size_t v = 0; v < volume.labels.size(); ++v)
        if (selection.tissue.values[v]) report.tissue_volume_by_label_mm3[volume.labels[v]] += volume.geometry.voxel_volume();
    scenario.source.cavity_labels = chosen.cavity_labels;
    scenario.source.anchor_labels = chosen.anchor_labels;
    scenario.source.anchor_border = chosen.anchor_border;
    scenario.source.tissue_volume_mm3 = report.selection.tissue_volume_mm3;
    if (report.defect) {
        scenario.source.defect = to_string(report.defect->type);
        scenario.source.defect_centre = report.defect->centre;
        scenario.source.defect_axis = report.defect->normal;
        scenario.source.defect_diameter_mm = report.defect->diameter_mm;
    }
    // One material per tissue label, named after its segment (segment_names.h material_name),
    // with the values given for that label or else the first material's.
    LayoutOptions layout = options.layout;
    layout.materials.clear();
    for (int label : chosen.tissue_labels) {
        auto given = std::find_if(options.layout.materials.begin(), options.layout.materials.end(),
                                  [&](const Material& m) { return m.label == label; });
        Material material = given != options.layout.materials.end() ? *given
                            : options.layout.materials.empty()      ? Material{}
                                                                    : options.layout.materials.front();
        material.label = label;
        material.name = material_name(label, report.segment_names);
        layout.materials.push_back(material);
    }

    if (options.visual && options.visual_mesh.empty()) {
        TriangleMesh mesh = timed(report, "surface",
                                  [&] { return extract_surface(selection.tissue, options.surface, progress, &report.surface); });
        report.mesh = timed(report, "check surface", [&] { return analyse_mesh(mesh); });
        append(report.warnings, report.surface.warnings);
        if (!report.mesh.closed() || !report.mesh.manifold())
            report.warnings.push_back("the visual surface is not a closed 2-manifold (" +
                                      std::to_string(report.mesh.boundary_edges) + " boundary edges, " +
                                      std::to_string(report.mesh.nonmanifold_edges) + " non-manifold edges)");
        scenario.visual = to_visual_mesh(mesh);
    }

    scenario.lattice = timed(report, "layout", [&] {
        return layout_particles(selection, chosen.tissue_labels, volume, layout, progress, &report.layout);
    });
    append(report.warnings, report.layout.warnings);
    if (!report.walls.grown.empty())
        for (const Material& material : scenario.lattice.materials) {
            TissueOrigin origin;
            if (const GrownStructure* wall = grown_wall(report.walls, material.label)) {
                origin.grown = true;
                origin.thickness_mm = wall->structure.thickness_mm;
                origin.grown_from = wall->structure.blood_labels.front();
            }
            origin.volume_mm3 = report.tissue_volume_by_label_mm3[material.label];
            scenario.tissue_origin.push_back(origin);
        }
    scenario.solver = options.solver;  // gravity, drag, safety; hold_stage and the critical step fill in the rest
    hold_stage(scenario, options, progress, report);

    double damping_eigenvalue = 0.0;
    report.stability = timed(report, "critical step", [&] {
        ProgressStage stage(progress, "critical time step", 0);
        // The dashpots, support dampers and drag shorten the stable step: the runtime's solver
        // estimates the same from the same arrays (solver.h damped_critical_dt_ms), so a step of
        // dt_ms is one substep there.
        damping_eigenvalue = estimate_damping_eigenvalue(scenario.lattice.particles, scenario.lattice.springs,
                                                         damping_ratios(scenario.lattice.materials), scenario.solver.damping);
        // The volume term's cells stiffen the tissue's dilatation (volume_cells.h): the step shrinks
        // with the dilatational wave speed.
        const VolumeCells cells = volume_cells(scenario.lattice.particles, added_lame_moduli(scenario.lattice.materials));
        return estimate_critical_time_step(scenario.lattice.particles, scenario.lattice.springs, 300, 1e-6, cells.empty() ? nullptr : &cells);
    });
    auto& solver = scenario.solver;
    solver.critical_dt_ms = report.stability.critical_dt_ms;
    solver.critical_dt_bound_ms = report.stability.critical_dt_bound_ms;
    const bool unbounded = !std::isfinite(solver.critical_dt_ms);
    if (unbounded) {
        // No free particle or no spring: nothing limits the step; choose one that keeps a free
        // particle's fall per step tiny and say so.
        solver.critical_dt_ms = solver.critical_dt_bound_ms = 1.0;
    }
    // The solver's own policy (stability.h), so that a step of dt_ms is one substep in heartsim.
    const TimeStepLimits limits = time_step_limits(solver.critical_dt_ms, unbounded ? 1.0 : 0.0, solver.safety_factor,
                                                   [&] { return damping_eigenvalue; });
    solver.damped_critical_dt_ms = limits.damped_critical_dt_ms;
    solver.dt_ms = limits.dt_ms;
    if (unbounded) {
        char message[160];
        std::snprintf(message, sizeof message, "no spring between free particles: the critical time step is unbounded; dt set to %g ms",
                      solver.dt_ms);
        report.warnings.push_back(message);
    }

    pack_stage(scenario, options.packing, progress, report);
    simulation_surface_stage(scenario, progress, report);
    if (options.visual) mapping_stage(scenario, options.visual_mesh, progress, report, options.mapping);
    landmark_stage(scenario, volume, report);
    // libmodel names options by their meaning; the scenario keeps the warnings as heartprep says them.
    for (std::string& warning : report.warnings) warning = spell_options(warning, heartprep_flags);
    return scenario;
}

namespace {

/// A grown wall's name without "(grown)".
std::string wall_name(const std::string& name) {
    const std::string suffix = " (grown)";
    return name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0
               ? name.substr(0, name.size() - suffix.size())
               : name;
}

std::string format(const char* pattern, double value) {
    char text[64];
    std::snprintf(text, sizeof text, pattern, value);
    return text;
}

}  // namespace

std::string heart_contents(const Scenario& scenario) {
    const auto& materials = scenario.lattice.materials;
    double total = scenario.source.tissue_volume_mm3;
    if (total <= 0)  // a file without the label map's volume: the particles' tissue
        for (std::size_t i = 0; i < scenario.lattice.particles.size(); ++i) {
            const auto row = std::size_t(scenario.lattice.particles.material[i]);
            total += double(scenario.lattice.particles.mass[i]) / (row < materials.size() ? materials[row].density : Material{}.density);
        }
    std::string labelled, grown;
    double labelled_mm3 = 0, grown_mm3 = 0, thinnest = 1e30, thickest = 0;
    for (std::size_t m = 0; m < materials.size(); ++m) {
        const TissueOrigin origin = m < scenario.tissue_origin.size() ? scenario.tissue_origin[m] : TissueOrigin{};
        if (origin.grown) {
            grown += (grown.empty() ? "" : ", ") + wall_name(materials[m].name);
            grown_mm3 += origin.volume_mm3;
            thinnest = std::min(thinnest, origin.thickness_mm), thickest = std::max(thickest, origin.thickness_mm);
        } else {
            labelled += (labelled.empty() ? "" : ", ") + std::string("label ") + std::to_string(materials[m].label) + " '" + materials[m].name + "'";
            labelled_mm3 += origin.volume_mm3;
        }
    }
    std::string text = "a heart of " + format("%.1f", total / 1000.0) + " mL of tissue (";
    if (grown.empty()) return text + labelled + " as labelled; no wall grown)";
    const std::string range = thinnest == thickest ? format("%g mm", thinnest) : format("%g", thinnest) + "-" + format("%g mm", thickest);
    return text + labelled + " " + format("%.1f mL", labelled_mm3 / 1000.0) + " as labelled; grown where the labels show only blood, " +
           range + ": " + grown + ", " + format("%.1f mL", grown_mm3 / 1000.0) + ")";
}

void print_build_summary(const BuildReport& report, const Scenario& scenario) {
    const auto& g = report.header.geometry;
    std::printf("input       %s (%s, %s), %d x %d x %d voxels of %.3f x %.3f x %.3f mm\n", scenario.source.file_name.c_str(),
                report.header.format.c_str(), report.header.component_type.c_str(), g.dims[0], g.dims[1], g.dims[2],
                g.spacing[0], g.spacing[1], g.spacing[2]);
    if (report.defect) print_defect_summary(*report.defect, report.segment_names);
    const auto& s = report.selection;
    std::string tissue;
    for (int label : scenario.source.tissue_labels) tissue += (tissue.empty() ? "" : ", ") + describe_label(label, report.segment_names);
    for (const GrownStructure& wall : report.walls.grown)
        tissue += ", " + describe_label(wall.structure.wall_label, report.segment_names) + " " + format("%g mm", wall.structure.thickness_mm);
    std::string cavity;
    if (!scenario.source.cavity_labels.empty()) {
        char text[64];
        std::snprintf(text, sizeof text, "; cavity %.1f mL", s.cavity_volume_mm3 / 1000.0);
        cavity = text;
    }
    std::printf("tissue      label %s: %zu voxels, %.1f mL%s; %zu islands, %zu dropped (%zu voxels)\n", tissue.c_str(), s.tissue_voxels,
                s.tissue_volume_mm3 / 1000.0, cavity.c_str(), s.islands.size(), s.islands_dropped, s.voxels_dropped);
    if (scenario.visual)
        std::printf("surface     %zu vertices, %zu triangles (marching cubes %zu); %s, Euler characteristic %ld, "
                    "%zu component(s), area %.0f mm², encloses %.1f mL\n",
                    report.mesh.vertices, report.mesh.faces, report.surface.marching_cubes_triangles,
                    report.mesh.closed() && report.mesh.manifold() ? "closed 2-manifold" : "NOT a closed 2-manifold",
                    report.mesh.euler_characteristic, report.mesh.components, report.mesh.area, report.mesh.volume / 1000.0);
    const auto& l = report.layout;
    std::printf("lattice     spacing %.3f mm, %d x %d x %d cells; %zu particles (%zu anchored), %zu springs "
                "(%zu face, %zu edge), mass %.2f g\n",
                l.spacing, scenario.lattice.dims[0], scenario.lattice.dims[1], scenario.lattice.dims[2], l.particles,
                l.anchored, l.face_springs + l.edge_springs, l.face_springs, l.edge_springs, l.total_mass);
    std::printf("thin walls  %zu particles on walls thinner than half a cell, %zu added to thicken walls; %zu particles "
                "(%.1f%% of the tissue volume) still one particle thick\n",
                l.ridges, l.thickened, l.thin_particles, 100 * l.thin_volume_share);
    if (!report.free_pieces.piece_sizes.empty()) {
        const auto& f = report.free_pieces;
        std::string sizes;
        for (std::size_t k = 0; k < f.piece_sizes.size() && k < 6; ++k) sizes += (k ? ", " : "") + std::to_string(f.piece_sizes[k]);
        if (f.piece_sizes.size() > 6) sizes += ", ...";
        std::printf("pieces      %zu connected piece(s) of %s particles; %zu held by nothing dropped (%zu particles)%s\n", f.pieces,
                    sizes.c_str(), f.dropped_pieces, f.dropped_particles,
                    f.free_pieces_kept ? (", " + std::to_string(f.free_pieces_kept) + " free kept (--allow-free)").c_str() : "");
    }
    {
        const auto& sp = report.supports;
        if (sp.total_stiffness > 0)
            std::printf("supports    %s: %zu particles, %.3g kPa/mm over %.0f mm²; elastic foundation %.3g kPa/mm² on every free "
                        "particle (%.3g N/mm); %.3g N/mm in all (1 N moves the whole heart %.3g mm)\n",
                        to_string(sp.region), sp.supported, sp.stiffness_kpa_per_mm, sp.area_mm2, sp.embedding_kpa_per_mm2,
                        sp.embedding_stiffness, sp.total_stiffness, 1.0 / sp.total_stiffness);
        else
            std::printf("supports    none\n");
        const auto& b = report.balance;
        if (b.balanced)
            std::printf("rest state  balanced under gravity (%.4g N): sag it replaces max %.3f mm, mean %.3f mm; pre-strain max %.2g%%; "
                        "%d CG iterations\n",
                        b.weight_n, b.max_sag_mm, b.mean_sag_mm, 100 * b.max_prestrain, b.iterations);
        else if (b.max_sag_mm > 0)
            std::printf("rest state  imaged, unstressed: it sags by up to %.3f mm under gravity\n", b.max_sag_mm);
        else
            std::printf("rest state  imaged, unstressed%s\n", scenario.solver.gravity.norm() > 0 ? "" : " (no gravity)");
    }
    std::printf("time step   critical %.4g ms (Lanczos, %d iterations), proven bound %.4g ms, damped %.4g ms; dt %.4g ms\n",
                scenario.solver.critical_dt_ms, report.stability.iterations, scenario.solver.critical_dt_bound_ms,
                scenario.solver.damped_critical_dt_ms, scenario.solver.dt_ms);
    if (scenario.packing)
        std::printf("packing     %s, %d x %d texture (%.0f%% occupied, %.1f MB per position buffer), neighbour table %.1f MB, "
                    "%.0f%% of springs within a 4 KB window\n",
                    to_string(scenario.packing->scheme), report.packing.width, report.packing.height, 100 * report.packing.occupancy,
                    double(report.packing.texture_bytes) / 1e6, double(report.packing.neighbour_bytes) / 1e6,
                    100 * report.packing.springs_within_window);
    if (scenario.simulation_surface) {
        const auto& r = report.simulation_surface;
        std::printf("simsurface  %zu triangles over %zu boundary particles, %zu component(s), Euler characteristic %ld, "
                    "%zu non-manifold edges, %zu non-manifold vertices, %zu thin-wall triangles in %zu sheet region(s)\n",
                    r.triangles, r.boundary_particles, r.components, r.euler_characteristic, r.nonmanifold_edges,
                    r.nonmanifold_vertices, r.thin_wall_triangles, r.sheet_regions);
    }
    if (scenario.mapping)
        std::printf("mapping     %zu visual vertices: %zu embedded in lattice cells (%zu convex), %zu in tangent "
                    "space (offset mean %.3f mm, max %.3f mm); rest error max %.2g mm; sensitivity bound mean %.2f, max %.2f\n",
                    scenario.mapping->offset.size(), report.mapping.embedded, report.mapping.embedded_convex,
                    report.mapping.tangent, report.mapping.mean_offset_mm, report.mapping.max_offset_mm,
                    report.mapping.max_rest_error_mm, report.mapping.mean_amplification, report.mapping.max_amplification);
    std::printf("stages     ");
    double total = 0;
    for (const auto& t : report.times) {
        std::printf(" %s %.3f s,", t.stage.c_str(), t.seconds);
        total += t.seconds;
    }
    std::printf(" total %.3f s\n", total);
}

namespace {

/// The walls line of the technician's summary: each wall grown, its thickness and volume, or why none was.
void print_walls_summary(const BuildReport& report) {
    const WallsReport& walls = report.walls;
    if (!walls.asked) {
        std::printf("walls       as labelled (--walls labelled): no wall grown\n");
        return;
    }
    if (walls.grown.empty()) {
        std::printf("walls       as labelled: %s\n", walls.none_because.c_str());
        return;
    }
    std::string text;
    for (const GrownStructure& wall : walls.grown)
        text += (text.empty() ? "" : ", ") + wall_name(wall.structure.name) + " " + format("%g mm", wall.structure.thickness_mm) + " (" +
                format("%.1f mL", wall.grown.volume_mm3 / 1000.0) + ")";
    std::printf("walls       grown into the background around the blood%s: %s\n",
                walls.convention.empty() ? "" : (" (" + walls.convention + "'s labels)").c_str(), text.c_str());
}

}  // namespace

void print_plain_summary(const BuildReport& report, const Scenario& scenario, const std::filesystem::path& output) {
    auto thousands = [](std::size_t n) {
        std::string digits = std::to_string(n), out;
        for (std::size_t k = 0; k < digits.size(); ++k) {
            if (k && (digits.size() - k) % 3 == 0) out += ',';
            out += digits[k];
        }
        return out;
    };
    const auto& l = report.layout;
    if (!report.header.data_file.empty()) std::printf("voxels      from %s\n", report.header.data_file.string().c_str());
    if (!report.convention.empty()) {
        const LabelConvention& convention = *find_label_convention(report.convention);
        std::printf("labels      %s (--labels %s)%s\n", convention.title.c_str(), report.convention.c_str(),
                    convention.labelled_walls.empty() ? "" : (": " + convention.labelled_walls).c_str());
    }
    else if (!report.convention_hint.empty()) std::printf("labels      %s\n", report.convention_hint.c_str());
    std::printf("built       %s from %s: %s particles %.2f mm apart%s\n", heart_contents(scenario).c_str(), scenario.source.file_name.c_str(),
                thousands(scenario.lattice.particles.size()).c_str(), l.spacing,
                scenario.visual ? (", a detailed surface of " + thousands(scenario.visual->triangles.size()) + " triangles").c_str() : "");
    // How it is held, in the words of docs/user-guide.md "How the heart is held".
    const auto& sp = report.supports;
    std::string held;
    if (l.anchored > 0) held = thousands(l.anchored) + " particles anchored";
    if (sp.supported > 0)
        held += (held.empty() ? "" : ", ") + std::string("on its ") + (sp.region == SupportRegion::posterior ? "posterior surface" : "whole surface") +
                " (" + thousands(sp.supported) + " particles on supports)";
    if (sp.embedding_stiffness > 0) held += (held.empty() ? "" : " and ") + std::string("a weak elastic foundation");
    const bool gravity = scenario.solver.gravity.norm() > 0;
    if (held.empty()) held = gravity ? "by nothing: it falls under gravity" : "by nothing (no gravity: it floats where it is)";
    else if (report.balance.balanced) held += ": it stays where it was imaged";
    else if (report.balance.max_sag_mm > 0) held += ": it sags by up to " + std::to_string(report.balance.max_sag_mm).substr(0, 4) + " mm";
    std::printf("held        %s\n", held.c_str());
    print_walls_summary(report);
    if (report.defect)
        std::printf("defect      a %.0f mm %s (measured %.1f mm) at %.1f, %.1f, %.1f (LPS mm)\n", report.defect->diameter_mm,
                    report.defect->type == DefectType::vsd ? "ventricular septal defect" : "atrial septal defect",
                    report.defect->measured_diameter_mm, report.defect->centre.x(), report.defect->centre.y(), report.defect->centre.z());
    // Fit for simulation: what would show in heartsim, plainly.
    std::vector<std::string> flaws;
    if (scenario.visual && (!report.mesh.closed() || !report.mesh.manifold()))
        flaws.push_back("the detailed surface has holes (" + std::to_string(report.mesh.boundary_edges) + " open edges): gaps show in it");
    if (report.free_pieces.free_pieces_kept > 0) flaws.push_back(std::to_string(report.free_pieces.free_pieces_kept) + " loose piece(s) drift");
    if (held.rfind("by nothing: it falls", 0) == 0) flaws.push_back("nothing holds it");
    const std::size_t warnings = report.warnings.size();
    const std::string pieces = report.free_pieces.pieces <= 1 ? "one piece" : std::to_string(report.free_pieces.pieces) + " pieces";
    if (flaws.empty() && warnings == 0)
        std::printf("fit         ready to simulate: %s, stable at a step of %.3f ms\n", pieces.c_str(), scenario.solver.dt_ms);
    else {
        std::string text;
        for (const std::string& f : flaws) text += (text.empty() ? "" : "; ") + f;
        if (warnings) text += (text.empty() ? "" : "; ") + std::to_string(warnings) + " warning(s) below: read what each means";
        std::printf("fit         simulates (%s, a step of %.3f ms), but look at this first: %s\n", pieces.c_str(), scenario.solver.dt_ms, text.c_str());
    }
    const std::filesystem::path xdmf = xdmf_beside(output);
    std::vector<std::pair<std::string, std::string>> next = {
        {"heartsim " + output.string(), "simulate it in a window (H: the keys)"},
        {"ParaView: open " + xdmf.string(), "the detailed mesh, the simulation surface, the particles"},
        {"heartprep inspect " + output.string(), "every figure of the build (heartprep build --verbose prints them too)"}};
    if (report.defect)
        next.insert(next.begin() + 1, {"heartsim run " + output.string() + " --clip defect", "the window cut open across the defect"});
    std::size_t width = 0;
    for (const auto& n : next) width = std::max(width, n.first.size());
    for (std::size_t k = 0; k < next.size(); ++k)
        std::printf("%s%-*s  %s\n", k == 0 ? "next        " : "            ", int(width), next[k].first.c_str(), next[k].second.c_str());
}

void print_warnings(const std::vector<std::string>& warnings) {
    for (const auto& w : warnings) std::fprintf(stderr, "heartprep: warning: %s\n", spell_options(w, heartprep_flags).c_str());
}

}  // namespace heartsim::cli
