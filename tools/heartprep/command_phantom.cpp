// `heartprep phantom`: synthetic label maps we generate ourselves (the bundled sample).
#include "commands.h"

#include "formats/volume_io.h"
#include "cli/cli_messages.h"
#include "cli/command_errors.h"
#include "libmodel/errors.h"
#include "libmodel/phantom.h"

#include <CLI/CLI.hpp>

#include <cstdio>
#include <map>
#include <memory>

namespace heartsim::cli {

void add_phantom_command(CLI::App& app) {
    auto* command = app.add_subcommand("phantom", "Write a synthetic label map: a two-ventricle heart with a septal defect, "
                                                  "or a sphere / thick shell");
    command->footer("\nLabels: 0 background, 1 myocardium, 2 blood pool (as HVSMR).\n"
                    "Example: heartprep phantom -o vsd.nii.gz --vsd-diameter 10 --vsd-position 0.8");
    auto o = std::make_shared<PhantomOptions>();
    auto output = std::make_shared<std::string>();
    auto shape = std::make_shared<std::string>("heart");
    command->add_option("-o,--output", *output, "Label map to write: .nii.gz, .nii, .nrrd, .mha, .mhd")->required();
    command->add_option("--shape", *shape, "heart, sphere or shell")->check(CLI::IsMember({"heart", "sphere", "shell"}))->capture_default_str();
    command->add_option("--voxel", o->voxel_mm, "Voxel size, mm")->check(cli_messages::positive())->capture_default_str();
    command->add_option("--size", o->size, "Voxels along the longest axis (overrides --voxel)")->check(CLI::Range(8, 2048));
    command->add_option("--margin", o->margin_mm, "Background around the shape, mm")->check(cli_messages::non_negative())->capture_default_str();
    command->add_option("--lv-radius", o->lv_radius_mm, "Left-ventricle cavity radius, mm")->capture_default_str()->group("Heart");
    command->add_option("--lv-length", o->lv_length_mm, "Left-ventricle cavity long semi-axis, mm")->capture_default_str()->group("Heart");
    command->add_option("--wall", o->wall_mm, "LV wall and septum thickness, mm")->capture_default_str()->group("Heart");
    command->add_option("--rv-wall", o->rv_wall_mm, "RV free-wall thickness, mm")->capture_default_str()->group("Heart");
    command->add_option("--vsd-diameter", o->vsd_diameter_mm, "Ventricular septal defect diameter, mm (0 = intact septum)")
        ->capture_default_str()
        ->group("Heart");
    command->add_option("--vsd-position", o->vsd_position, "VSD height along the septum, 0 = apex, 1 = base")
        ->capture_default_str()
        ->group("Heart");
    command->add_option("--radius", o->radius_mm, "Sphere radius or shell outer radius, mm")->capture_default_str()->group("Sphere and shell");
    command->add_option("--inner-radius", o->inner_radius_mm, "Shell inner radius, mm")->capture_default_str()->group("Sphere and shell");
    command->callback([=] {
        if (const std::string problem = label_volume_path_problem(*output); !problem.empty()) throw UsageError(problem);
        LabelVolume volume;
        try {
            o->shape = parse_phantom_shape(*shape);
            volume = make_phantom(*o);
        } catch (const InputError& e) {
            throw UsageError(e.what());  // the phantom's only input is its options: a wrong one is a usage error
        }
        write_label_volume(*output, volume);
        std::map<int, std::size_t> counts;
        for (auto label : volume.labels) ++counts[label];
        const auto& g = volume.geometry;
        std::printf("wrote %s: %d x %d x %d voxels of %.3f mm; myocardium %zu voxels (%.1f mL), blood pool %zu voxels (%.1f mL)\n",
                    output->c_str(), g.dims[0], g.dims[1], g.dims[2], g.spacing[0], counts[1],
                    double(counts[1]) * g.voxel_volume() / 1000, counts[2], double(counts[2]) * g.voxel_volume() / 1000);
    });
}

}  // namespace heartsim::cli
