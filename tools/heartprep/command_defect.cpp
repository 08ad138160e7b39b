// `heartprep defect`: a septal defect carved into a patient's label map (libmodel/defect.h).
#include "commands.h"
#include "pipeline.h"
#include "terminal_progress.h"

#include "cli/cli_messages.h"
#include "cli/command_errors.h"
#include "formats/atomic_file.h"
#include "formats/volume_io.h"
#include "libmodel/errors.h"

#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <memory>

namespace heartsim::cli {

void DefectFlags::add(CLI::App& command, const char* type_flag, const char* group) {
    command.add_option(type_flag, type, "vsd: a ventricular septal defect (between the ventricles); asd: an atrial one")
        ->check(CLI::IsMember({"vsd", "asd"}))
        ->group(group);
    command.add_option("--diameter", diameter_mm, "The opening's diameter, mm")
        ->check(cli_messages::within(plausible::defect_diameter_mm))
        ->capture_default_str()
        ->group(group);
    command.add_option("--at", at,
                       "A point in or near the septum, LPS mm (3D Slicer shows RAS: negate its first two numbers); the "
                       "opening goes through the wall there along the wall's normal. Needed where the chambers are not "
                       "labelled apart (HVSMR 2016: one blood pool)")
        ->delimiter(',')
        ->expected(3)
        ->type_name("X,Y,Z")
        ->group(group);
    command.add_option("--site", site,
                       "Without --at, where on the septum (chambers labelled apart, e.g. --labels mmwhs): vsd perimembranous "
                       "(default: nearest the aorta, below the aortic valve), muscular (halfway to the apex) or apical; asd "
                       "secundum (default: the middle of the atrial septum)")
        ->check(CLI::IsMember({"perimembranous", "muscular", "apical", "secundum"}))
        ->group(group);
    command.add_option("--max-wall", max_wall_mm, "The thickest wall taken for a septum, mm")
        ->check(CLI::Range(1.0, 60.0))
        ->capture_default_str()
        ->group(group);
}

void DefectFlags::apply(DefectChoice& choice) const {
    choice.type = parse_defect_type(type);
    choice.diameter_mm = diameter_mm;
    choice.max_wall_mm = max_wall_mm;
    if (!at.empty()) {
        if (at.size() != 3 || !std::isfinite(at[0]) || !std::isfinite(at[1]) || !std::isfinite(at[2]))
            throw UsageError("--at must be three finite numbers X,Y,Z (LPS mm)");
        choice.at = Eigen::Vector3d(at[0], at[1], at[2]);
        if (!site.empty()) throw UsageError("--site places a defect without a point: give --at or --site, not both");
    }
    if (!site.empty()) choice.site = parse_defect_site(site);
}

void add_defect_command(CLI::App& app) {
    auto* command = app.add_subcommand("defect", "Carve a septal defect (VSD or ASD) into a label map: label map -> label map");
    command->footer(
        "\nExamples:\n"
        "  heartprep defect ct_train_1002_label.nii.gz --labels mmwhs --type vsd --diameter 10 -o vsd.nii.gz\n"
        "  heartprep defect ct_train_1002_label.nii.gz --labels mmwhs --type vsd --site muscular -o vsd.nii.gz\n"
        "  heartprep defect training_axial_crop_pat1-label.nii.gz --type vsd --diameter 8 --at 10.5,-120,35 -o vsd.nii.gz\n"
        "The opening is a cylinder through the wall along its normal at the point; the wall voxels in it become the blood\n"
        "of the pool on their side, every other voxel keeps its label. The report gives the centre, the measured\n"
        "diameter, the wall's thickness there and whether the two pools now connect (a flood fill through the opening).\n"
        "Where the chambers are labelled apart (--labels mmwhs, or a .seg.nrrd naming left and right ventricle and\n"
        "atrium), --at may be left out and --site chooses the place. The output takes the input's grid and\n"
        "orientation; its format follows its extension. It is written atomically: a refusal leaves no file.\n"
        "heartprep build takes the same options (--defect vsd --diameter 10 ...) to build a heart with a defect in one step.");
    auto input = std::make_shared<std::filesystem::path>();
    auto output = std::make_shared<std::string>();
    auto labels = std::make_shared<LabelChoice>();
    auto flags = std::make_shared<DefectFlags>();
    flags->type = "vsd";
    auto quiet = std::make_shared<bool>(false);
    command->add_option("input", *input, "Label map: .nii, .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd")->required();
    command->add_option("-o,--output", *output, "Label map to write: .nii, .nii.gz, .nrrd, .seg.nrrd, .mha, .mhd")->required();
    flags->add(*command, "--type", "Defect");
    command->add_option("--tissue", labels->tissue, "The wall's labels (numbers or segment names); default: as heartprep build")
        ->delimiter(',')
        ->type_name("L[,L...]")
        ->group("Labels");
    command->add_option("--cavity", labels->cavity,
                        "The blood pools' labels; default: the convention's blood labels, else every label but the wall's and 0")
        ->delimiter(',')
        ->type_name("L[,L...]")
        ->group("Labels");
    command->add_option("--labels", labels->label_table,
                        "A label convention (" + label_convention_names() + ") or a label table file, as heartprep build")
        ->type_name("NAME|FILE")
        ->group("Labels");
    command->add_flag("-q,--quiet", *quiet, "No progress and no summary (warnings are still printed)");
    command->callback([=] {
        if (output->empty()) throw UsageError("no output file given (-o OUT.nii.gz)");
        if (const std::string problem = label_volume_path_problem(*output); !problem.empty()) throw UsageError(problem);
        check_destination(*output);
        DefectChoice choice;
        flags->apply(choice);
        TerminalProgress progress(*quiet);
        BuildReport report;
        SelectionOptions selection;
        LabelVolume volume = read_and_resolve(*input, *labels, selection, progress, report);
        // An output never replaces an input: nor, through a MetaImage header's data file, its voxels.
        const std::vector<InputFile> inputs = {{*input, "the input label map"},
                                               {report.header.data_file, "the input label map's data file"},
                                               {labels->label_table, "the --labels file"}};
        for (const std::filesystem::path& file : label_volume_files(*output))
            refuse_an_input_as_output("-o " + *output + (file == *output ? "" : " (its voxels go to " + file.string() + ")"), file, inputs);
        defect_stage(volume, *input, choice, selection, progress, report);
        {
            ProgressStage stage(progress, "write label map", 0);
            write_label_volume(*output, volume, report.header.segment_names);
        }
        if (!*quiet) {
            if (!report.convention.empty()) std::printf("labels      %s (--labels %s)\n", find_label_convention(report.convention)->title.c_str(), report.convention.c_str());
            print_defect_summary(*report.defect, report.segment_names);
            std::printf("wrote       %s\n", output->c_str());
        }
        print_warnings(report.warnings);
    });
}

}  // namespace heartsim::cli
