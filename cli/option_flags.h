/// @file option_flags.h
/// @brief From an option's meaning to a program's flag. libmodel names the option a message is
/// about by what it means, in braces (`{LayoutOptions::occupancy} must be in (0, 1]`), since it
/// knows no command line (libmodel/errors.h OptionError); heartprep spells it as its flag
/// (`--occupancy must be in (0, 1]`) where it prints an error or a warning. The runtime's parts
/// below heartsim's command line (the live link, the section plane, the haptic run, the plans)
/// name their options the same way, and heartsim spells them with its own table.
#pragma once

#include <span>
#include <string>
#include <string_view>

namespace heartsim::cli {

/// One option: its meaning as libmodel names it (an options struct's field, or a plain name for
/// a choice that no libmodel struct holds) and the flag that sets it.
struct OptionFlag {
    std::string_view option;
    std::string_view flag;
};

/// `text` with every `{meaning}` that `flags` lists spelled as its flag. Anything else in braces is
/// left as it is: a file name or a segment name may hold braces of its own.
inline std::string spell_options(std::string_view text, std::span<const OptionFlag> flags) {
    std::string out;
    out.reserve(text.size());
    std::size_t at = 0;
    while (at < text.size()) {
        const std::size_t open = text.find('{', at);
        const std::size_t close = open == std::string_view::npos ? open : text.find('}', open);
        if (close == std::string_view::npos) break;
        out.append(text, at, open - at);
        const std::string_view meaning = text.substr(open + 1, close - open - 1);
        std::string_view spelled = text.substr(open, close - open + 1);
        for (const OptionFlag& f : flags)
            if (f.option == meaning) spelled = f.flag;
        out.append(spelled);
        at = close + 1;
    }
    out.append(text.substr(std::min(at, text.size())));
    return out;
}

/// heartprep's flags for the options libmodel names.
inline constexpr OptionFlag heartprep_flags[] = {
    {"LayoutOptions::occupancy", "--occupancy"},
    {"LayoutOptions::thicken_fraction", "--thicken-fraction"},
    {"LayoutOptions::ridge_fraction", "--ridge-fraction"},
    {"LayoutOptions::spacing_mm", "--spacing"},
    {"LayoutOptions::particle_budget", "--particles"},
    {"MappingOptions::method", "--mapping"},
    {"PackingOptions::scheme", "--packing"},
    {"SelectionOptions::tissue_labels", "--tissue"},
    {"SelectionOptions::cavity_labels", "--cavity"},
    {"SelectionOptions::anchor_labels", "--anchor-label"},
    {"SelectionOptions::anchor_border", "--anchor-border"},
    {"SelectionOptions::min_island_mm3", "--min-island"},
    {"SupportOptions::region", "--support"},
    {"SupportOptions::stiffness_kpa_per_mm", "--support-stiffness"},
    {"SupportOptions::embedding_kpa_per_mm2", "--embedding-stiffness"},
    {"SupportOptions::damping_ratio", "--support-damping"},
    {"FreePieceOptions::drop_below_particles", "--drop-free-below"},
    {"FreePieceOptions::allow_free", "--allow-free"},
    {"rest_state", "--rest-state"},
    {"label_table", "--labels FILE"},
    {"DefectOptions::type", "--defect"},
    {"DefectOptions::diameter_mm", "--diameter"},
    {"DefectOptions::at", "--at"},
    {"DefectOptions::site", "--site"},
    {"DefectOptions::max_wall_mm", "--max-wall"},
    {"PhantomOptions::size", "--size"},
    {"PhantomOptions::voxel_mm", "--voxel"},
    {"PhantomOptions::margin_mm", "--margin"},
    {"PhantomOptions::lv_radius_mm", "--lv-radius"},
    {"PhantomOptions::lv_length_mm", "--lv-length"},
    {"PhantomOptions::wall_mm", "--wall"},
    {"PhantomOptions::rv_wall_mm", "--rv-wall"},
    {"PhantomOptions::vsd_diameter_mm", "--vsd-diameter"},
    {"PhantomOptions::vsd_position", "--vsd-position"},
    {"PhantomOptions::radius_mm", "--radius"},
    {"PhantomOptions::inner_radius_mm", "--inner-radius"},
};

/// heartsim's flags for the options its runtime parts name (runtime/link/slicer_link.h,
/// section_plane.h, camera.h, contact.h, real_time.h, trajectory.h, incision_plan.h, repair_plan.h,
/// haptics/haptic_run.h).
inline constexpr OptionFlag heartsim_flags[] = {
    {"SlicerLinkOptions::endpoint", "--igtl"},
    {"SlicerLinkOptions::bind", "--igtl-bind"},
    {"SlicerLinkOptions::mesh_rate_hz", "--igtl-mesh-rate"},
    {"RealTimeMode", "--real-time"},
    {"SectionRequest", "--clip"},
    {"LookAt", "--look-at"},
    {"ViewDirection", "--view"},
    {"ContactMode", "--contact"},
    {"fixed_probe", "--probe"},
    {"fixed_grabber", "--grab"},
    {"IncisionPlanOptions::approach", "--approach"},
    {"LookAt::eye", "--eye"},
    {"OperationPlanOptions::approach", "--approach"},
    {"OperationPlanOptions::length_mm", "--length"},
    {"OperationPlanOptions::spread_mm", "--spread"},
    {"OperationPlanOptions::coronary_clearance_mm", "--coronary-clearance"},
    {"OperationPlanOptions::max_wall_mm", "--max-wall"},
    {"OperationPlanOptions::eye_distance_mm", "--eye-distance"},
    {"RepairPlanOptions::side", "--side"},
    {"RepairPlanOptions::stitches", "--stitches"},
    {"RepairPlanOptions::rim_mm", "--rim"},
    {"RepairPlanOptions::thickness_mm", "--thickness"},
    {"RepairPlanOptions::patch_diameter_mm", "--patch-diameter"},
    {"RepairPlanOptions::conduction_zone", "--conduction-zone"},
    {"RepairPlanOptions::zone_rim_mm", "--zone-rim"},
    {"RepairPlanOptions::zone_margin_deg", "--zone-margin"},
    {"ConductionZoneOptions::band_mm", "--zone-band"},
    {"ConductionZoneOptions::half_width_deg", "--zone-half-width"},
    {"ConductionZoneOptions::ring_reach_mm", "--zone-reach"},
    {"HapticRunSettings::devices", "--device"},
    {"HapticRunSettings::instruments", "--instrument"},
    {"HapticRunSettings::record", "--record"},
};

}  // namespace heartsim::cli
