// heartprep's `defect` command and `build --defect` (libmodel/defect.h from the command line), on
// the synthetic two-chamber block and on the real MM-WHS hearts.
#include "formats/scenario.h"
#include "formats/volume_io.h"
#include "libmodel/defect.h"
#include "libmodel/label_conventions.h"
#include "libmodel/mesh.h"
#include "defect_block.h"
#include "runtime/view/camera.h"
#include "runtime/gl/renderer.h"
#include "runtime/view/png.h"
#include "runtime_test_support.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <numbers>
#include <set>

using namespace heartsim;
using namespace heartsim::test::defect_block;
using heartsim::test::cut_colour;
using heartsim::test::cut_pixels;

namespace {

struct MmwhsCase {
    const char* folder;
    const char* file;
    const char* convention;
};

/// An automatic defect on a real MM-WHS heart: run through heartprep, then checked here on the
/// label map it wrote.
void check_automatic_defect(const MmwhsCase& c, const std::string& type, const std::string& site) {
    const auto input = test::real_data_dir() / c.folder / c.file;
    if (test::real_data_dir().empty() || !std::filesystem::exists(input)) GTEST_SKIP() << "real case absent: " << input;
    const LabelConvention& convention = *find_label_convention(c.convention);
    const int a = type == "vsd" ? convention.left_ventricle : convention.left_atrium;
    const int b = type == "vsd" ? convention.right_ventricle : convention.right_atrium;
    test::TempDir dir;
    const auto output = dir / "defect.nii.gz";
    const auto run = test::run_command(test::quoted(HEARTPREP_EXE) + " defect " + test::quoted(input.string()) + " --labels " +
                                       c.convention + " --type " + type + " --site " + site + " --diameter 10 -o " +
                                       test::quoted(output.string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("connected through the opening"), std::string::npos) << run.output;
    const LabelVolume before = read_label_volume(input), after = read_label_volume(output);
    ASSERT_EQ(before.labels.size(), after.labels.size());
    EXPECT_TRUE(after.geometry.voxel_to_world().isApprox(before.geometry.voxel_to_world(), 1e-6));
    // Every changed voxel was wall (the myocardium, or for an atrial septum an unlabelled one)
    // and became blood of one of the two pools; the pools, apart before, now connect.
    std::size_t changed = 0;
    for (std::size_t i = 0; i < before.labels.size(); ++i) {
        if (before.labels[i] == after.labels[i]) continue;
        ++changed;
        EXPECT_TRUE(before.labels[i] == convention.myocardium || before.labels[i] == 0) << before.labels[i];
        EXPECT_TRUE(after.labels[i] == a || after.labels[i] == b) << after.labels[i];
    }
    // A 10 mm opening through a wall a few mm thick: between a disc 1 mm thick and a cylinder 20 mm long.
    const double voxel_mm3 = before.geometry.voxel_volume();
    EXPECT_GT(double(changed) * voxel_mm3, std::numbers::pi * 25.0 * 1.0);
    EXPECT_LT(double(changed) * voxel_mm3, std::numbers::pi * 36.0 * 20.0);
    if (type == "vsd") {
        EXPECT_FALSE(pools_connect(before, a, b));
    }
    EXPECT_TRUE(pools_connect(after, a, b));
}

}  // namespace

TEST(SeptalDefectRealHearts, AnAutomaticVsdJoinsTheVentriclesOfEveryMmwhsHeart) {
    for (const MmwhsCase& c : {MmwhsCase{"mmwhs_ct1002", "ct_train_1002_label.nii.gz", "mmwhs"},
                               MmwhsCase{"mmwhs_wh", "mmwhs_wh-label.nii.gz", "mmwhs-ordinal"}})
        for (const char* site : {"perimembranous", "muscular"}) {
            SCOPED_TRACE(std::string(c.folder) + " " + site);
            check_automatic_defect(c, "vsd", site);
        }
}

TEST(SeptalDefectRealHearts, AnAutomaticAsdJoinsTheAtriaOfEveryMmwhsHeart) {
    for (const MmwhsCase& c : {MmwhsCase{"mmwhs_ct1002", "ct_train_1002_label.nii.gz", "mmwhs"},
                               MmwhsCase{"mmwhs_wh", "mmwhs_wh-label.nii.gz", "mmwhs-ordinal"}}) {
        SCOPED_TRACE(c.folder);
        check_automatic_defect(c, "asd", "secundum");
    }
}

namespace {

/// The block written as a label map in `dir`, and a point of its septum, LPS mm, as `--at` takes it.
struct BlockFile {
    Block block = make_block();
    std::filesystem::path input;
    Eigen::Vector3d at;
    std::string point;
    explicit BlockFile(const test::TempDir& dir) : input(dir / "block.nrrd"), at(block.world({0.5, -4.0, 6.0})) {
        write_label_volume(input, block.volume);
        point = std::to_string(at.x()) + "," + std::to_string(at.y()) + "," + std::to_string(at.z());
    }
};

}  // namespace

TEST(HeartprepDefect, WritesTheLabelMapWithTheHoleInTheInputsGridAndRefusesWithoutWriting) {
    test::TempDir dir;
    const BlockFile file(dir);
    const Block& block = file.block;
    const auto& input = file.input;
    const Eigen::Vector3d at = file.at;
    const std::string& point = file.point;
    const std::string heartprep = test::quoted(HEARTPREP_EXE);
    const auto output = dir / "vsd.nrrd";
    const auto run = test::run_command(heartprep + " defect " + test::quoted(input.string()) + " --type vsd --diameter 8 --at " + point +
                                       " -o " + test::quoted(output.string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("connected through the opening"), std::string::npos) << run.output;
    const LabelVolume after = read_label_volume(output);
    EXPECT_TRUE(after.geometry.voxel_to_world().isApprox(block.volume.geometry.voxel_to_world(), 1e-9));
    // The same hole as the library makes, voxel for voxel.
    LabelVolume expected = block.volume;
    DefectOptions o = block_options(false);
    o.blood_labels = {left, right};
    o.diameter_mm = 8.0;
    o.at = at;
    carve_defect(expected, o);
    EXPECT_EQ(after.labels, expected.labels);
    EXPECT_NE(after.labels, block.volume.labels);

    // Refusals: exit 1 for the data (an opening larger than the septum), exit 2 for the command
    // line; no file either way.
    const auto refused = dir / "refused.nrrd";
    auto attempt = [&](const std::string& options) {
        return test::run_command(heartprep + " defect " + test::quoted(input.string()) + " " + options + " -o " + test::quoted(refused.string()));
    };
    const auto too_wide = attempt("--diameter 45 --at " + point);
    EXPECT_EQ(too_wide.exit_code, 1) << too_wide.output;
    EXPECT_NE(too_wide.output.find("does not fit"), std::string::npos) << too_wide.output;
    const auto no_point = attempt("--type vsd");
    EXPECT_EQ(no_point.exit_code, 2) << no_point.output;
    EXPECT_NE(no_point.output.find("--at"), std::string::npos) << no_point.output;
    const auto both = attempt("--at " + point + " --site muscular");
    EXPECT_EQ(both.exit_code, 2) << both.output;
    EXPECT_FALSE(std::filesystem::exists(refused));

    // build --defect: the scenario records the defect, and inspect shows it.
    const auto scenario_path = dir / "vsd.h5";
    const auto build = test::run_command(heartprep + " build " + test::quoted(input.string()) + " --defect vsd --diameter 8 --at " + point +
                                         " --particles 4000 -q -o " + test::quoted(scenario_path.string()));
    ASSERT_EQ(build.exit_code, 0) << build.output;
    const Scenario scenario = read_scenario(scenario_path);
    EXPECT_EQ(scenario.source.defect, "vsd");
    EXPECT_DOUBLE_EQ(scenario.source.defect_diameter_mm, 8.0);
    const Eigen::Vector3d centre = block.rotation.transpose() * scenario.source.defect_centre;
    EXPECT_NEAR(centre.x(), 0.0, 0.5);
    EXPECT_NEAR((block.rotation.transpose() * scenario.source.defect_axis).x() * (block.rotation.transpose() * scenario.source.defect_axis).x(),
                1.0, 1e-3);
    const auto inspect = test::run_command(heartprep + " inspect " + test::quoted(scenario_path.string()));
    EXPECT_NE(inspect.output.find("defect      vsd, 8.0 mm"), std::string::npos) << inspect.output;
    // Without --defect the same build has no defect recorded and keeps the septum whole.
    const auto plain_path = dir / "plain.h5";
    ASSERT_EQ(test::run_command(heartprep + " build " + test::quoted(input.string()) + " --particles 4000 -q -o " +
                                test::quoted(plain_path.string())).exit_code, 0);
    const Scenario plain = read_scenario(plain_path);
    EXPECT_TRUE(plain.source.defect.empty());
    // A defect's shape without --defect is refused, not built without one.
    for (const std::string& shaping : std::vector<std::string>{"--diameter 8", "--site muscular", "--max-wall 12", "--at " + point}) {
        const auto unshaped = dir / "unshaped.h5";
        const auto r = test::run_command(heartprep + " build " + test::quoted(input.string()) + " " + shaping + " --particles 4000 -q -o " +
                                         test::quoted(unshaped.string()));
        EXPECT_EQ(r.exit_code, 2) << shaping << ": " << r.output;
        EXPECT_NE(r.output.find(shaping.substr(0, shaping.find(' ')) + " shapes a septal defect, and no --defect was given"), std::string::npos)
            << r.output;
        EXPECT_FALSE(std::filesystem::exists(unshaped)) << shaping;
    }
    // The detailed surface encloses the tissue: the defect's build lacks the carved septum, and
    // its surface has one more handle (a hole through the wall: Euler characteristic 2 less).
    auto measure = [](const Scenario& s) {
        TriangleMesh mesh;
        for (const auto& p : s.visual->positions) mesh.positions.emplace_back(p[0], p[1], p[2]);
        mesh.triangles = s.visual->triangles;
        return analyse_mesh(mesh);
    };
    const MeshReport with_hole = measure(scenario), whole = measure(plain);
    EXPECT_EQ(with_hole.euler_characteristic, whole.euler_characteristic - 2);
    std::size_t carved = 0;
    for (std::size_t i = 0; i < after.labels.size(); ++i) carved += after.labels[i] != block.volume.labels[i];
    const double carved_mm3 = double(carved) * block.volume.geometry.voxel_volume();
    EXPECT_NEAR(whole.volume - with_hole.volume, carved_mm3, 0.1 * carved_mm3);
}



TEST(HeartprepDefect, NeverWritesOverItsInputHoweverTheOutputIsSpelled) {
    // The input named again (relative, "./", absolute), through a hard link or a symbolic link:
    // refused before anything is written, exit 2, the input's bytes and inode as they were.
    test::TempDir dir;
    const BlockFile file(dir);
    const std::string heartprep = test::quoted(HEARTPREP_EXE);
    auto bytes = [](const std::filesystem::path& path) {
        std::ifstream in(path, std::ios::binary);
        return std::string(std::istreambuf_iterator<char>(in), {});
    };
    const std::string before = bytes(file.input);
    std::filesystem::create_hard_link(file.input, dir / "hard.nrrd");
    std::filesystem::create_symlink(file.input.filename(), dir / "soft.nrrd");
    auto defect = [&](const std::string& input, const std::string& output) {
        return test::run_command("cd " + test::quoted(dir.path()) + " && " + heartprep + " defect " + test::quoted(input) +
                                 " --type vsd --diameter 8 --at " + file.point + " -q -o " + test::quoted(output));
    };
    for (const std::string& output : std::vector<std::string>{"block.nrrd", "./block.nrrd", file.input.string(), "hard.nrrd", "soft.nrrd"}) {
        const auto run = defect("block.nrrd", output);
        EXPECT_EQ(run.exit_code, 2) << output << ": " << run.output;
        EXPECT_NE(run.output.find("-o " + output + ": that is the input label map; give another file"), std::string::npos) << run.output;
    }
    EXPECT_TRUE(bytes(file.input) == before) << "the input was rewritten";
    EXPECT_EQ(std::filesystem::hard_link_count(file.input), 2u) << "the input was replaced";
    EXPECT_TRUE(std::filesystem::is_symlink(dir / "soft.nrrd"));

    // MetaImage: a .mhd header's voxels are in the data file it names. An output whose own data
    // file would be the input's is refused too, and the input's voxels stay as they were.
    const auto header = dir / "case.mhd";
    write_label_volume(header, file.block.volume);
    const auto written = read_volume_header(header).data_file;
    ASSERT_EQ(written, label_volume_files(header).at(1)) << "the data file a .mhd gets is not where it was expected";
    std::string text = bytes(header);
    const std::string named = "ElementDataFile = " + written.filename().string();
    ASSERT_NE(text.find(named), std::string::npos) << text;
    text.replace(text.find(named), named.size(), "ElementDataFile = voxels.raw");
    std::ofstream(dir / "other.mhd", std::ios::binary) << text;
    std::filesystem::rename(written, dir / "voxels.raw");
    const std::string voxels = bytes(dir / "voxels.raw");
    ASSERT_EQ(read_label_volume(dir / "other.mhd").labels, file.block.volume.labels);
    const auto run = defect("other.mhd", "voxels.mhd");
    EXPECT_EQ(run.exit_code, 2) << run.output;
    EXPECT_NE(run.output.find("-o voxels.mhd (its voxels go to voxels.raw): that is the input label map's data file"), std::string::npos)
        << run.output;
    EXPECT_TRUE(bytes(dir / "voxels.raw") == voxels) << "the input's voxels were rewritten";
    EXPECT_FALSE(std::filesystem::exists(dir / "voxels.mhd"));

    // Another name writes both files of the pair, and nothing else.
    const auto written_pair = defect("other.mhd", "vsd.mhd");
    ASSERT_EQ(written_pair.exit_code, 0) << written_pair.output;
    EXPECT_EQ(read_volume_header(dir / "vsd.mhd").data_file, dir / "vsd.raw");
    EXPECT_NE(read_label_volume(dir / "vsd.mhd").labels, file.block.volume.labels);
    std::set<std::string> names;
    for (const auto& entry : std::filesystem::directory_iterator(dir.path())) names.insert(entry.path().filename().string());
    EXPECT_EQ(names, (std::set<std::string>{"block.nrrd", "hard.nrrd", "soft.nrrd", "case.mhd", "other.mhd", "voxels.raw", "vsd.mhd", "vsd.raw"}));
}

TEST(HeartsimDefectSection, ClipDefectCutsAcrossTheOpeningAndLooksAtIt) {
    // The block with an 8 mm VSD and without: --clip defect puts the plane through the opening's
    // centre holding its axis, and the camera looks at that centre: there the intact septum's cut
    // wall shows, and the defect's opening does not.
    test::TempDir dir;
    const BlockFile file(dir);
    const auto& input = file.input;
    const std::string& point = file.point;
    const std::string heartprep = test::quoted(HEARTPREP_EXE), heartsim = test::quoted(HEARTSIM_EXE);
    for (const char* name : {"vsd", "intact"}) {
        const std::string defect = std::string(name) == "vsd" ? " --defect vsd --diameter 8 --at " + point : "";
        const auto built = test::run_command(heartprep + " build " + test::quoted(input.string()) + defect + " --particles 4000 -q -o " +
                                             test::quoted((dir / (std::string(name) + ".h5")).string()));
        ASSERT_EQ(built.exit_code, 0) << built.output;
    }
    const Scenario vsd = read_scenario(dir / "vsd.h5");
    const auto run = test::run_command(heartsim + " run " + test::quoted((dir / "vsd.h5").string()) +
                                       " --headless --backend cpu --steps 0 --size 400x400 --clip defect --screenshot " +
                                       test::quoted((dir / "vsd.png").string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    // The plane the run says it used: through the defect's centre, its normal across the axis.
    double px, py, pz, nx, ny, nz;
    const auto line = run.output.find("through (");
    ASSERT_NE(line, std::string::npos) << run.output;
    ASSERT_EQ(std::sscanf(run.output.c_str() + line, "through (%lf, %lf, %lf) mm, normal (%lf, %lf, %lf)", &px, &py, &pz, &nx, &ny, &nz), 6)
        << run.output;
    EXPECT_LT((Eigen::Vector3d(px, py, pz) - vsd.source.defect_centre).norm(), 0.02);
    EXPECT_LT(std::abs(Eigen::Vector3d(nx, ny, nz).dot(vsd.source.defect_axis)), 1e-3);
    // The intact block under the same plane and camera: the plane given, the camera turned to it
    // and placed as the run placed it (--look-at at the distance it said).
    double distance = 0.0;
    const auto camera_line = run.output.find("section view: the camera ");
    ASSERT_NE(camera_line, std::string::npos) << run.output;
    ASSERT_EQ(std::sscanf(run.output.c_str() + camera_line, "section view: the camera %lf mm", &distance), 1) << run.output;
    char plane[256], look[256];
    std::snprintf(plane, sizeof plane, "%.4f,%.4f,%.4f,%.6f,%.6f,%.6f", px, py, pz, nx, ny, nz);
    std::snprintf(look, sizeof look, "%.4f,%.4f,%.4f,%.4f", px, py, pz, distance);
    const auto intact = test::run_command(heartsim + " run " + test::quoted((dir / "intact.h5").string()) +
                                          " --headless --backend cpu --steps 0 --size 400x400 --clip " + plane + " --view section --look-at " +
                                          look + " --screenshot " + test::quoted((dir / "intact.png").string()));
    ASSERT_EQ(intact.exit_code, 0) << intact.output;
    const Image with_hole = read_png(dir / "vsd.png"), whole = read_png(dir / "intact.png");
    // The picture's centre is the defect's: cut wall in the intact septum, none in the opening.
    EXPECT_TRUE(cut_colour(whole, 200, 200));
    EXPECT_FALSE(cut_colour(with_hole, 200, 200));
    EXPECT_GT(cut_pixels(whole), cut_pixels(with_hole));
    EXPECT_GT(cut_pixels(with_hole), 1000u) << "the rest of the section still shows its cut wall";

    // Asked of a heart without a defect, or a section view without a plane: exit 2, one clear line.
    const auto no_defect = test::run_command(heartsim + " run " + test::quoted((dir / "intact.h5").string()) +
                                             " --headless --steps 0 --clip defect --screenshot " + test::quoted((dir / "x.png").string()));
    EXPECT_EQ(no_defect.exit_code, 2) << no_defect.output;
    EXPECT_NE(no_defect.output.find("no septal defect"), std::string::npos) << no_defect.output;
    const auto no_plane = test::run_command(heartsim + " run " + test::quoted((dir / "intact.h5").string()) +
                                            " --headless --steps 0 --view section --screenshot " + test::quoted((dir / "x.png").string()));
    EXPECT_EQ(no_plane.exit_code, 2) << no_plane.output;
    EXPECT_NE(no_plane.output.find("--clip"), std::string::npos) << no_plane.output;
}

namespace {

/// The opening's width in `image`, pixels, seen from the picture's centre (where the camera's
/// target, the defect's centre, projects): for each direction through the centre, 1° apart, the
/// chord between the first cut-coloured pixels on either side (the picture's edge where none
/// lies); the narrowest chord. The plane holds the defect's axis, so the septum shows as a band of
/// cut wall with the opening a gap across it: the narrowest chord runs along the band, from one
/// edge of the gap to the other. `closed`: whether both ends of that chord are cut wall.
double narrowest_chord(const Image& image, bool* closed) {
    const double cx = 0.5 * image.width, cy = 0.5 * image.height;
    double best = std::numeric_limits<double>::infinity();
    for (int degree = 0; degree < 180; ++degree) {
        const double angle = degree * std::numbers::pi / 180.0;
        double chord = 0.0;
        bool both = true;
        for (const double sign : {1.0, -1.0}) {
            double r = 0.0;
            bool hit = false;
            for (; r < double(image.width + image.height); r += 0.5) {
                const int x = int(std::floor(cx + sign * r * std::cos(angle))), y = int(std::floor(cy + sign * r * std::sin(angle)));
                if (x < 0 || y < 0 || x >= image.width || y >= image.height) break;
                if (cut_colour(image, x, y)) {
                    hit = true;
                    break;
                }
            }
            chord += r;
            both = both && hit;
        }
        if (chord < best) best = chord, *closed = both;
    }
    return best;
}

}  // namespace

// --clip defect frames the opening close up: the camera on the defect's centre at the distance
// where the opening and 4 mm round it span two thirds of the picture's height, so a 10 mm VSD
// spans 10 / 18 of that, 37 %. Measured in the picture: the gap in the septum's cut band, against
// where the defect's 10 mm project from the camera the run said (the distance, the camera's 30°
// field of view). --look-at, given, wins: the fitted distance, the opening smaller.
TEST(HeartsimDefectSection, ClipDefectFramesTheOpeningCloseUp) {
    test::TempDir dir;
    const BlockFile file(dir);
    const std::string heartprep = test::quoted(HEARTPREP_EXE), heartsim = test::quoted(HEARTSIM_EXE);
    const double diameter_mm = 10.0;
    const auto built = test::run_command(heartprep + " build " + test::quoted(file.input.string()) + " --defect vsd --diameter 10 --at " +
                                         file.point + " --particles 4000 -q -o " + test::quoted((dir / "vsd.h5").string()));
    ASSERT_EQ(built.exit_code, 0) << built.output;
    const Scenario vsd = read_scenario(dir / "vsd.h5");
    ASSERT_DOUBLE_EQ(vsd.source.defect_diameter_mm, diameter_mm);
    const int width = 480, height = 360;
    const std::string size = " --size " + std::to_string(width) + "x" + std::to_string(height);
    const auto run = test::run_command(heartsim + " run " + test::quoted((dir / "vsd.h5").string()) + " --headless --backend cpu --steps 0" +
                                       size + " --clip defect --screenshot " + test::quoted((dir / "close.png").string()));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    double distance = 0.0;
    const auto line = run.output.find("section view: the camera ");
    ASSERT_NE(line, std::string::npos) << run.output;
    ASSERT_EQ(std::sscanf(run.output.c_str() + line, "section view: the camera %lf mm", &distance), 1) << run.output;
    const Image close = read_png(dir / "close.png");
    ASSERT_EQ(close.height, height);
    const double mm_per_pixel = 2.0 * distance * std::tan(0.5 * double(Camera{}.fov_y_degrees) * std::numbers::pi / 180.0) / height;
    const double projected = diameter_mm / mm_per_pixel;
    bool closed = false;
    const double seen = narrowest_chord(close, &closed);
    std::printf("  --clip defect: camera %.1f mm away; the 10 mm opening projects to %.1f px, the gap seen %.1f px: %.1f %% of the "
                "picture's %d px height\n",
                distance, projected, seen, 100.0 * seen / height, height);
    if (HasFailure() || std::getenv("HEARTSIM_KEEP_PICTURES")) write_png("defect_close.png", close);
    EXPECT_FALSE(cut_colour(close, width / 2, height / 2)) << "the picture's centre is the opening's";
    EXPECT_TRUE(closed) << "cut wall on both sides of the opening";
    EXPECT_NEAR(seen, projected, 0.12 * projected) << "the gap is the defect's diameter where the camera projects it";
    EXPECT_GE(seen, 0.30 * height) << "the opening spans a good part of the picture";

    // --look-at on the same centre without a distance: the camera at the fitted distance, farther.
    char look[128];
    std::snprintf(look, sizeof look, "%.4f,%.4f,%.4f", vsd.source.defect_centre.x(), vsd.source.defect_centre.y(), vsd.source.defect_centre.z());
    const auto far = test::run_command(heartsim + " run " + test::quoted((dir / "vsd.h5").string()) + " --headless --backend cpu --steps 0" +
                                       size + " --clip defect --look-at " + look + " --screenshot " + test::quoted((dir / "far.png").string()));
    ASSERT_EQ(far.exit_code, 0) << far.output;
    EXPECT_EQ(far.output.find("section view: the camera "), std::string::npos) << far.output;
    bool far_closed = false;
    const double far_seen = narrowest_chord(read_png(dir / "far.png"), &far_closed);
    std::printf("  with --look-at (the fitted distance): the gap %.1f px\n", far_seen);
    EXPECT_TRUE(far_closed);
    EXPECT_LT(far_seen, 0.7 * seen) << "--look-at keeps the fitted view";
}
