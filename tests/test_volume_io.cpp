/// @file test_volume_io.cpp
/// @brief Label-map I/O: round trips through every format, hand-written files whose geometry we
/// compute independently, the real HVSMR case against nibabel's numbers, and damaged inputs.
#include "formats/label_table.h"
#include "formats/volume_io.h"
#include "libmodel/errors.h"
#include "test_support.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <random>

namespace heartsim {
namespace {

namespace fs = std::filesystem;
using test::TempDir;
using test::HandNifti;
using test::write_bytes;

/// A small volume with a rotated, anisotropic, offset grid and labels that identify each voxel.
LabelVolume make_test_volume(int nx, int ny, int nz, int label_scale = 1, int label_offset = 0) {
    LabelVolume volume;
    volume.geometry.dims = {nx, ny, nz};
    volume.geometry.spacing = Eigen::Vector3d(0.7, 1.3, 2.1);
    volume.geometry.origin = Eigen::Vector3d(-12.5, 33.25, 101.75);
    volume.geometry.direction = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    volume.labels.resize(volume.geometry.voxel_count());
    for (std::size_t index = 0; index < volume.labels.size(); ++index)
        volume.labels[index] = int((index * 7) % 301) * label_scale + label_offset;
    return volume;
}


void append_text(std::vector<unsigned char>& bytes, const std::string& text) { bytes.insert(bytes.end(), text.begin(), text.end()); }

/// Cuts `count` bytes off the end of a file, as an interrupted copy would.
void truncate_by(const fs::path& path, std::uint64_t count) {
    fs::resize_file(path, fs::file_size(path) - count);
}

/// Expects `action` to throw E whose message contains every one of `parts`.
template <class E, class F>
void expect_error(F&& action, const std::vector<std::string>& parts) {
    try {
        action();
        ADD_FAILURE() << "expected an exception mentioning '" << parts.front() << "'";
    } catch (const E& error) {
        const std::string message = error.what();
        for (const auto& part : parts) EXPECT_NE(message.find(part), std::string::npos) << "'" << part << "' not in: " << message;
    }
}

// -------------------------------------------------------------------------------------------
// Round trips.

class RoundTrip : public ::testing::TestWithParam<std::string> {};

void expect_same_volume(const LabelVolume& expected, const LabelVolume& actual, double tolerance) {
    EXPECT_EQ(actual.geometry.dims, expected.geometry.dims);
    EXPECT_TRUE(actual.labels == expected.labels) << "labels differ";
    for (int d = 0; d < 3; ++d) {
        EXPECT_NEAR(actual.geometry.spacing[d], expected.geometry.spacing[d], tolerance) << "spacing " << d;
        EXPECT_NEAR(actual.geometry.origin[d], expected.geometry.origin[d], tolerance) << "origin " << d;
        for (int e = 0; e < 3; ++e)
            EXPECT_NEAR(actual.geometry.direction(d, e), expected.geometry.direction(d, e), tolerance)
                << "direction " << d << "," << e;
    }
}

/// NIfTI stores spacing and the affine as float32: relative error about 6e-8, i.e. ~1e-5 mm at
/// 100 mm. NRRD and MetaImage store decimal text.
double geometry_tolerance(const std::string& extension) {
    return extension.rfind(".nii", 0) == 0 ? 2e-5 : 1e-9;
}

TEST_P(RoundTrip, SmallLabelsKeepLabelsAndGeometry) {
    TempDir folder;
    const fs::path path = folder / ("volume" + GetParam());
    const LabelVolume volume = make_test_volume(9, 6, 5);
    write_label_volume(path, volume);
    VolumeHeader header;
    const LabelVolume read = read_label_volume(path, {}, &header);
    expect_same_volume(volume, read, geometry_tolerance(GetParam()));
    EXPECT_EQ(header.component_type, "unsigned_short");  // every label fits 16 bits
}

TEST_P(RoundTrip, WideAndNegativeLabelsUseInt32) {
    TempDir folder;
    const fs::path path = folder / ("wide" + GetParam());
    const LabelVolume volume = make_test_volume(5, 4, 3, 100000, -2000000);
    write_label_volume(path, volume);
    VolumeHeader header;
    const LabelVolume read = read_label_volume(path, {}, &header);
    expect_same_volume(volume, read, geometry_tolerance(GetParam()));
    EXPECT_EQ(header.component_type, "int");
}

TEST_P(RoundTrip, LeavesOnlyTheNamedFiles) {
    TempDir folder;
    write_label_volume(folder / ("only" + GetParam()), make_test_volume(4, 4, 4));
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(folder.path())) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    if (GetParam() == ".mhd") {
        ASSERT_EQ(names.size(), 2u);  // header plus its data file
        EXPECT_EQ(names[0], "only.mhd");
        EXPECT_EQ(names[1], "only.raw");
    } else {
        ASSERT_EQ(names.size(), 1u);
        EXPECT_EQ(names[0], "only" + GetParam());
    }
}

INSTANTIATE_TEST_SUITE_P(EveryExtension, RoundTrip,
                         ::testing::Values(".nii", ".nii.gz", ".nrrd", ".seg.nrrd", ".mha", ".mhd"),
                         [](const ::testing::TestParamInfo<std::string>& info) {
                             std::string name = info.param.substr(1);
                             std::replace(name.begin(), name.end(), '.', '_');
                             return name;
                         });

TEST(VolumeWrite, SegNrrdKeepsSegmentNames) {
    TempDir folder;
    const fs::path path = folder / "named.seg.nrrd";
    LabelVolume volume = make_test_volume(4, 3, 2);
    for (auto& label : volume.labels) label %= 3;
    write_label_volume(path, volume, {{1, "Myocardium"}, {2, "Blood pool"}});
    const VolumeHeader header = read_volume_header(path);
    EXPECT_EQ(header.segment_names, (std::map<int, std::string>{{1, "Myocardium"}, {2, "Blood pool"}}));
}

// -------------------------------------------------------------------------------------------
// Geometry of a hand-written NIfTI, computed independently from the standard's affine.

TEST(VolumeRead, HandWrittenNiftiSformGivesNiftiWorldInLps) {
    const std::array<short, 3> dims = {4, 3, 2};
    const Eigen::Vector3f spacing(0.6f, 0.9f, 1.7f);
    const Eigen::Matrix3f rotation =
        Eigen::AngleAxisf(0.5f, Eigen::Vector3f(0.2f, -1.0f, 0.7f).normalized()).toRotationMatrix();
    Eigen::Matrix<float, 3, 4> srow;
    srow.leftCols<3>() = rotation * spacing.asDiagonal();
    srow.col(3) = Eigen::Vector3f(10.5f, -20.25f, 30.0f);

    HandNifti nifti(dims, 2 /*uint8*/, 8);
    for (int axis = 0; axis < 3; ++axis) nifti.set_pixdim(axis, spacing[axis]);
    nifti.set_sform(srow);
    std::vector<std::uint8_t> voxels(24);
    for (std::size_t index = 0; index < voxels.size(); ++index) voxels[index] = std::uint8_t(index * 3);
    nifti.append_voxels(voxels);

    TempDir folder;
    const fs::path path = folder / "hand.nii";
    write_bytes(path, nifti.bytes);
    const LabelVolume volume = read_label_volume(path);
    ASSERT_EQ(volume.geometry.dims, (std::array<int, 3>{4, 3, 2}));
    for (std::size_t index = 0; index < voxels.size(); ++index) EXPECT_EQ(volume.labels[index], voxels[index]);

    // NIfTI world is RAS: x = srow · (i,j,k,1). LPS flips the first two axes.
    const Eigen::Matrix3d ras_to_lps = Eigen::Vector3d(-1, -1, 1).asDiagonal();
    for (const Eigen::Vector3d& ijk : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(3, 0, 0), Eigen::Vector3d(0, 2, 0),
                                      Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(3, 2, 1), Eigen::Vector3d(1, 2, 0)}) {
        const Eigen::Vector3d ras = srow.cast<double>() * ijk.homogeneous();
        const Eigen::Vector3d expected = ras_to_lps * ras;
        const Eigen::Vector3d actual = volume.geometry.to_world(ijk);
        EXPECT_LT((actual - expected).norm(), 1e-4) << "voxel " << ijk.transpose() << ": " << actual.transpose()
                                                    << " vs " << expected.transpose();
    }
}

// -------------------------------------------------------------------------------------------
// A NIfTI with both a qform and a sform (qform_code and sform_code set): where they disagree,
// heartprep keeps ITK's choice and says which, why, and how far apart they are.

struct TwoTransformNifti {
    Eigen::Matrix<double, 3, 4> qform_ras;  ///< continuous voxel index -> RAS mm, from the quaternion
    Eigen::Matrix<double, 3, 4> sform_ras;  ///< from srow
};

/// Writes a 5×4×3 NIfTI whose sform is its qform turned by `degrees` (about an oblique axis
/// through the first voxel's centre) and then moved by `mm`.
/// `shear` adds that multiple of the sform's i axis to its j axis.
TwoTransformNifti write_two_transform_nifti(const fs::path& path, short qform_code, short sform_code, double mm, double degrees,
                                            double shear = 0.0) {
    const Eigen::Vector3d spacing(0.8, 0.9, 1.1);
    const Eigen::Quaterniond qform_rotation(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, -2, 0.5).normalized()));
    const Eigen::Vector3d qoffset(-30.0, 12.0, 45.0);
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d(0.3, 0.8, -0.5).normalized()).toRotationMatrix();
    TwoTransformNifti result;
    result.qform_ras.leftCols<3>() = qform_rotation.toRotationMatrix() * spacing.asDiagonal();
    result.qform_ras.col(3) = qoffset;
    result.sform_ras.leftCols<3>() = turn * result.qform_ras.leftCols<3>();
    result.sform_ras.col(3) = qoffset + mm * Eigen::Vector3d(2, -1, 2) / 3.0;
    result.sform_ras.col(1) += shear * result.sform_ras.col(0);

    HandNifti nifti({5, 4, 3}, 2 /*uint8*/, 8);
    for (int axis = 0; axis < 3; ++axis) nifti.set_pixdim(axis, float(spacing[axis]));
    nifti.set_sform(result.sform_ras.cast<float>());
    nifti.set_sform_code(sform_code);
    // NIfTI stores a ≥ 0: (x, y, z) of the quaternion with w ≥ 0.
    const Eigen::Quaterniond q = qform_rotation.w() < 0 ? Eigen::Quaterniond(-qform_rotation.coeffs()) : qform_rotation;
    nifti.set_qform(qform_code, Eigen::Vector3f(float(q.x()), float(q.y()), float(q.z())), qoffset.cast<float>());
    std::vector<std::uint8_t> voxels(60, 1);
    nifti.append_voxels(voxels);
    write_bytes(path, nifti.bytes);
    return result;
}

/// The largest distance between `volume`'s voxel positions and those of `ras` (a NIfTI affine,
/// RAS), over the eight corner voxels; LPS = diag(−1, −1, 1)·RAS.
double distance_from(const LabelVolume& volume, const Eigen::Matrix<double, 3, 4>& ras) {
    const Eigen::Matrix3d ras_to_lps = Eigen::Vector3d(-1, -1, 1).asDiagonal();
    double largest = 0.0;
    for (int corner = 0; corner < 8; ++corner) {
        const Eigen::Vector3d ijk((corner & 1) ? 4 : 0, (corner & 2) ? 3 : 0, (corner & 4) ? 2 : 0);
        largest = std::max(largest, (volume.geometry.to_world(ijk) - ras_to_lps * (ras * ijk.homogeneous())).norm());
    }
    return largest;
}

TEST(VolumeRead, NiftiQformAndSformThatAgreeGiveNoWarning) {
    TempDir folder;
    const fs::path path = folder / "agree.nii";
    const TwoTransformNifti transforms = write_two_transform_nifti(path, 1, 1, 0.0, 0.0);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_TRUE(header.warnings.empty()) << header.warnings.front();
    EXPECT_LT(distance_from(volume, transforms.qform_ras), 1e-4);
}

/// sform code 2 (aligned anatomy), 20 mm and 25° from the qform: ITK reads the qform.
TEST(VolumeRead, NiftiSformOfCodeTwoThatDisagreesLeavesTheQformAndWarns) {
    TempDir folder;
    const fs::path path = folder / "disagree.nii";
    const TwoTransformNifti transforms = write_two_transform_nifti(path, 1, 2, 20.0, 25.0);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_LT(distance_from(volume, transforms.qform_ras), 1e-3);
    EXPECT_GT(distance_from(volume, transforms.sform_ras), 19.0);
    ASSERT_EQ(header.warnings.size(), 1u);
    const std::string& warning = header.warnings.front();
    for (const char* part : {"disagree", "20.00 mm apart at the first voxel", "25.00° apart", "heartprep uses the qform",
                             "code 2, aligned anatomy", "nibabel would use the sform"})
        EXPECT_NE(warning.find(part), std::string::npos) << "'" << part << "' not in: " << warning;
    EXPECT_EQ(warning.rfind(path.string(), 0), 0u) << warning;
    // The header alone says the same.
    EXPECT_EQ(read_volume_header(path).warnings, header.warnings);
}

/// sform code 1 (scanner anatomy): ITK prefers the sform, and heartprep says so.
TEST(VolumeRead, NiftiSformOfCodeOneThatDisagreesIsUsedWithAWarning) {
    TempDir folder;
    const fs::path path = folder / "disagree-scanner.nii";
    const TwoTransformNifti transforms = write_two_transform_nifti(path, 1, 1, 20.0, 25.0);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_LT(distance_from(volume, transforms.sform_ras), 1e-3);
    ASSERT_EQ(header.warnings.size(), 1u);
    const std::string& warning = header.warnings.front();
    for (const char* part : {"20.00 mm apart at the first voxel", "25.00° apart", "heartprep uses the sform", "code 1, scanner anatomy"})
        EXPECT_NE(warning.find(part), std::string::npos) << "'" << part << "' not in: " << warning;
}

/// A sform with shear is no rotation: ITK keeps the qform even where the sform's code is 1.
TEST(VolumeRead, NiftiSformWithShearLeavesTheQformAndWarns) {
    TempDir folder;
    const fs::path path = folder / "shear.nii";
    const TwoTransformNifti transforms = write_two_transform_nifti(path, 1, 1, 0.0, 0.0, 0.3);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_LT(distance_from(volume, transforms.qform_ras), 1e-3);
    ASSERT_EQ(header.warnings.size(), 1u);
    const std::string& warning = header.warnings.front();
    for (const char* part : {"0.00 mm apart at the first voxel", "heartprep uses the qform", "shear"})
        EXPECT_NE(warning.find(part), std::string::npos) << "'" << part << "' not in: " << warning;
}

/// Only one code set: nothing to compare, whatever the other fields hold.
TEST(VolumeRead, NiftiWithOnlyAQformGivesNoWarning) {
    TempDir folder;
    const fs::path path = folder / "qform-only.nii";
    const TwoTransformNifti transforms = write_two_transform_nifti(path, 1, 0, 20.0, 25.0);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_TRUE(header.warnings.empty());
    EXPECT_LT(distance_from(volume, transforms.qform_ras), 1e-3);
}

// -------------------------------------------------------------------------------------------
// Label tables (--labels): names for a NIfTI's labels.

TEST(LabelTable, ReadsSlicerItkSnapAndCsvLayouts) {
    TempDir folder;
    std::ofstream(folder / "slicer.ctbl") << "# Color table file\n0 Background 0 0 0 0\n1 blood_pool 255 0 0 255\n\n2 Myocardium 0 255 0 255\n";
    std::ofstream(folder / "snap.txt") << "################################################\n"
                                          "    0     0    0    0        0  0  0    \"Clear Label\"\n"
                                          "    1   255    0    0        1  1  1    \"blood pool\"\n"
                                          "    2     0  255    0        1  1  1    \"Myocardium\"\n";
    std::ofstream(folder / "slicer.csv") << "LabelValue,Name,Color_R,Color_G,Color_B,Color_A\n0,Background,0,0,0,0\n1,blood pool,255,0,0,255\n"
                                            "2,\"Myocardium\",0,255,0,255\n";
    const std::map<int, std::string> expected = {{0, "Background"}, {1, "blood pool"}, {2, "Myocardium"}};
    EXPECT_EQ(read_label_table(folder / "slicer.ctbl"), expected);
    std::map<int, std::string> snap = expected;
    snap[0] = "Clear Label";
    EXPECT_EQ(read_label_table(folder / "snap.txt"), snap);
    EXPECT_EQ(read_label_table(folder / "slicer.csv"), expected);
}

TEST(LabelTable, BadTablesAreRefusedNamingFileAndLine) {
    TempDir folder;
    std::ofstream(folder / "twice.txt") << "1 myocardium 0 0 0 255\n1 blood_pool 0 0 0 255\n";
    expect_error<InputError>([&] { read_label_table(folder / "twice.txt"); }, {"twice.txt", "line 2", "label 1 is named twice"});
    std::ofstream(folder / "empty.txt") << "# nothing here\n";
    expect_error<InputError>([&] { read_label_table(folder / "empty.txt"); }, {"empty.txt", "names no labels"});
    std::ofstream(folder / "words.txt") << "myocardium is label one\n";
    expect_error<InputError>([&] { read_label_table(folder / "words.txt"); }, {"words.txt", "line 1", "expected"});
    expect_error<InputError>([&] { read_label_table(folder / "absent.txt"); }, {"absent.txt", "not found"});
}

// -------------------------------------------------------------------------------------------
// Real data: HVSMR 2016 pat0, numbers measured with nibabel (README beside the file).

TEST(VolumeRead, RealHvsmrCaseMatchesNibabel) {
    const fs::path path = test::real_case("hvsmr16_pat0");
    if (path.empty()) GTEST_SKIP() << "real data not found under " << HEARTSIM_REAL_DATA << "; skipping";
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    // Its qform (code 2) and sform (code 1) are both set and agree (nibabel): nothing to warn of.
    EXPECT_TRUE(header.warnings.empty()) << header.warnings.front();
    EXPECT_EQ(volume.geometry.dims, (std::array<int, 3>{127, 207, 141}));
    EXPECT_NEAR(volume.geometry.spacing[0], 0.885417, 1e-5);
    EXPECT_NEAR(volume.geometry.spacing[1], 0.885417, 1e-5);
    EXPECT_NEAR(volume.geometry.spacing[2], 0.889999, 1e-5);
    std::map<int, std::size_t> counts;
    for (auto label : volume.labels) ++counts[label];
    EXPECT_EQ(counts[1], 251459u);
    EXPECT_EQ(counts[2], 635481u);
    EXPECT_EQ(counts[0], 2819809u);

    // nibabel's RAS affine (README), rounded to 1e-4 mm; LPS = diag(-1,-1,1) RAS.
    Eigen::Matrix<double, 3, 4> ras_affine;
    ras_affine << 0, 0, 0.8900, -78.0850,
                  -0.8854, 0, 0, 53.4050,
                  0, -0.8854, 0, 124.1470;
    const Eigen::Matrix3d ras_to_lps = Eigen::Vector3d(-1, -1, 1).asDiagonal();
    for (const Eigen::Vector3d& ijk : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 0, 0),
                                      Eigen::Vector3d(0, 1, 0)}) {
        const Eigen::Vector3d expected = ras_to_lps * (ras_affine * ijk.homogeneous());
        EXPECT_LT((volume.geometry.to_world(ijk) - expected).norm(), 1e-3) << "voxel " << ijk.transpose();
    }
    // +k points Right (nibabel: PIR), i.e. -x in LPS, by one k spacing.
    const Eigen::Vector3d step_k = volume.geometry.to_world({0, 0, 1}) - volume.geometry.to_world({0, 0, 0});
    EXPECT_NEAR(step_k.x(), -0.889999, 1e-5);
    EXPECT_NEAR(step_k.y(), 0.0, 1e-5);
    EXPECT_NEAR(step_k.z(), 0.0, 1e-5);
}

// -------------------------------------------------------------------------------------------
// Hand-written 3D Slicer segmentations.

std::string segmentation_header(const std::string& dimension_lines) {
    return "NRRD0004\n"
           "# Complete NRRD file format specification at:\n"
           "# http://teem.sourceforge.net/nrrd/format.html\n"
           "type: unsigned char\n" +
           dimension_lines +
           "encoding: raw\n"
           "space origin: (1,2,3)\n"
           "Segment0_ID:=Segment_1\n"
           "Segment0_Name:=Myocardium\n"
           "Segment0_LabelValue:=1\n"
           "Segment0_Layer:=0\n"
           "Segment1_ID:=Segment_2\n"
           "Segment1_Name:=Blood pool\n"
           "Segment1_LabelValue:=2\n";
}

TEST(VolumeRead, SingleLayerSegNrrdGivesLabelsAndSegmentNames) {
    std::vector<unsigned char> bytes;
    append_text(bytes, segmentation_header("dimension: 3\n"
                                           "space: left-posterior-superior\n"
                                           "sizes: 4 3 2\n"
                                           "space directions: (0.5,0,0) (0,0.75,0) (0,0,1.25)\n"
                                           "kinds: domain domain domain\n") +
                           "Segment1_Layer:=0\n\n");
    std::vector<std::int32_t> labels(24);
    for (std::size_t index = 0; index < labels.size(); ++index) {
        labels[index] = int(index % 3);
        bytes.push_back(std::uint8_t(labels[index]));
    }
    TempDir folder;
    const fs::path path = folder / "heart.seg.nrrd";
    write_bytes(path, bytes);
    VolumeHeader header;
    const LabelVolume volume = read_label_volume(path, {}, &header);
    EXPECT_EQ(volume.labels, labels);
    EXPECT_EQ(header.format, "NRRD");
    EXPECT_EQ(header.segment_names, (std::map<int, std::string>{{1, "Myocardium"}, {2, "Blood pool"}}));
    EXPECT_NEAR(volume.geometry.spacing[1], 0.75, 1e-12);
    EXPECT_NEAR(volume.geometry.origin[2], 3.0, 1e-12);
}

// Found by fuzz_volume_nrrd: a segment number or layer beyond int's range made
// std::stoi throw std::out_of_range out of the reader instead of a refusal naming the field.
TEST(VolumeReadErrors, SegNrrdNumbersOutOfRangeAreRefused) {
    const std::string dimensions = "dimension: 3\nspace: left-posterior-superior\nsizes: 4 3 2\n"
                                   "space directions: (0.5,0,0) (0,0.75,0) (0,0,1.25)\nkinds: domain domain domain\n";
    TempDir folder;
    const std::pair<std::string, std::string> cases[] = {
        {"Segment99999999999_Name:=Far\nSegment1_Layer:=0\n", "Segment99999999999_Name"},
        {"Segment1_Layer:=99999999999\n", "Segment1_Layer is '99999999999'"},
        {"Segment1_Layer:=one\n", "Segment1_Layer is 'one'"},
        {"Segment2_LabelValue:=99999999999\nSegment1_Layer:=0\n", "Segment2_LabelValue is '99999999999'"}};
    for (const auto& [extra, expected] : cases) {
        std::vector<unsigned char> bytes;
        append_text(bytes, segmentation_header(dimensions) + extra + "\n");
        bytes.resize(bytes.size() + 24, 1);
        const fs::path path = folder / "odd.seg.nrrd";
        write_bytes(path, bytes);
        expect_error<InputError>([&] { read_volume_header(path); }, {expected});
    }
}

TEST(VolumeRead, MultiLayerSegNrrdIsRefused) {
    std::vector<unsigned char> bytes;
    append_text(bytes, segmentation_header("dimension: 4\n"
                                           "space: left-posterior-superior\n"
                                           "sizes: 2 4 3 2\n"
                                           "space directions: none (0.5,0,0) (0,0.75,0) (0,0,1.25)\n"
                                           "kinds: list domain domain domain\n") +
                           "Segment1_Layer:=1\n\n");
    bytes.resize(bytes.size() + 2 * 24, 1);
    TempDir folder;
    const fs::path path = folder / "layers.seg.nrrd";
    write_bytes(path, bytes);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "multi-layer", "single layer", "labelmap"});
}

// -------------------------------------------------------------------------------------------
// Bad input: each names the file and the problem.

TEST(VolumeReadErrors, MissingFile) {
    TempDir folder;
    const fs::path path = folder / "absent.nii.gz";
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "not found"});
}

TEST(VolumeReadErrors, UnsupportedExtension) {
    TempDir folder;
    const fs::path path = folder / "labels.txt";
    write_bytes(path, {'1', '2', '3'});
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "unsupported", ".txt", ".nii.gz", ".seg.nrrd", ".mha"});
}

TEST(VolumeReadErrors, FloatImageIsRefused) {
    HandNifti nifti({2, 2, 2}, 16 /*float32*/, 32);
    nifti.append_voxels(std::vector<float>{1.7f, -3.2f, 0.0f, 2.0f, 1.0f, 1.0f, 0.5f, 7.9f});
    TempDir folder;
    const fs::path path = folder / "probability.nii";
    write_bytes(path, nifti.bytes);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "float image", "integer label map"});
}

TEST(VolumeReadErrors, TruncatedGzipNifti) {
    TempDir folder;
    const fs::path path = folder / "cut.nii.gz";
    write_label_volume(path, make_test_volume(40, 40, 40));
    truncate_by(path, fs::file_size(path) / 2);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "truncated", "128000 bytes"});
}

TEST(VolumeReadErrors, TruncatedPlainNifti) {
    TempDir folder;
    const fs::path path = folder / "cut.nii";
    write_label_volume(path, make_test_volume(10, 10, 10));
    truncate_by(path, 100);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "truncated", "2000 bytes"});
}

TEST(VolumeReadErrors, TruncatedMetaImage) {
    TempDir folder;
    const fs::path path = folder / "cut.mha";
    write_label_volume(path, make_test_volume(40, 40, 40));
    truncate_by(path, 200);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "truncated"});
}

TEST(VolumeReadErrors, TruncatedMetaImageDataFile) {
    TempDir folder;
    const fs::path path = folder / "cut.mhd";
    write_label_volume(path, make_test_volume(10, 10, 10));
    truncate_by(folder / "cut.raw", 10);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "truncated", "cut.raw"});
}

TEST(VolumeReadErrors, TruncatedNrrd) {
    TempDir folder;
    const fs::path path = folder / "cut.nrrd";
    write_label_volume(path, make_test_volume(40, 40, 40));
    truncate_by(path, 30);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "truncated"});
}

/// A valid uint8 2×2×2 NIfTI except for one pixdim.
fs::path nifti_with_spacing(const TempDir& folder, const std::string& name, int axis, float value) {
    HandNifti nifti({2, 2, 2}, 2, 8);
    nifti.set_pixdim(axis, value);
    nifti.append_voxels(std::vector<std::uint8_t>(8, 1));
    const fs::path path = folder / name;
    write_bytes(path, nifti.bytes);
    return path;
}

TEST(VolumeReadErrors, ZeroSpacing) {
    TempDir folder;
    const fs::path path = nifti_with_spacing(folder, "zero.nii", 1, 0.0f);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "spacing along j", "pixdim[2] is 0"});
}

TEST(VolumeReadErrors, NegativeSpacing) {
    TempDir folder;
    const fs::path path = nifti_with_spacing(folder, "negative.nii", 0, -1.5f);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "spacing along i", "pixdim[1] is -1.5"});
}

TEST(VolumeReadErrors, NanSpacing) {
    TempDir folder;
    const fs::path path = nifti_with_spacing(folder, "nan.nii", 2, std::numeric_limits<float>::quiet_NaN());
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "spacing along k", "pixdim[3] is nan"});
    expect_error<InputError>([&] { read_volume_header(path); }, {path.string(), "pixdim[3]"});
}

TEST(VolumeReadErrors, ImplausibleSpacing) {
    // 1e-6 mm voxels (whose lattice would not fit in memory: heartprep hung) and metre-sized ones
    // (a unit mistake) are refused at reading, by plausible.h's voxel range.
    TempDir folder;
    const fs::path tiny = nifti_with_spacing(folder, "tiny.nii", 0, 1e-6f);
    expect_error<InputError>([&] { read_label_volume(tiny); }, {tiny.string(), "voxel spacing along i", "outside the plausible range"});
    const fs::path huge = nifti_with_spacing(folder, "huge.nii", 2, 1000.0f);
    expect_error<InputError>([&] { read_label_volume(huge); }, {huge.string(), "voxel spacing along k is 1000 mm", "outside the plausible range"});
}

TEST(VolumeReadErrors, ZeroSpacingNrrd) {
    // A zero space-direction vector: ITK's NRRD reader reports spacing 0 for that axis.
    std::vector<unsigned char> bytes;
    append_text(bytes, "NRRD0004\ntype: unsigned char\ndimension: 3\nspace: left-posterior-superior\n"
                       "sizes: 2 2 2\nspace directions: (0,0,0) (0,1,0) (0,0,1)\nencoding: raw\n\n");
    bytes.resize(bytes.size() + 8, 1);
    TempDir folder;
    const fs::path path = folder / "flat.nrrd";
    write_bytes(path, bytes);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "spacing along i", "expected a finite positive"});
}

TEST(VolumeReadErrors, NanSpacingNrrdAndMetaImage) {
    // ITK reads a NaN spacing as 1 mm without a word: the header is refused before ITK sees it.
    TempDir folder;
    std::vector<unsigned char> nrrd;
    append_text(nrrd, "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\nspacings: nan 1 1\nencoding: raw\n\n");
    nrrd.resize(nrrd.size() + 8, 1);
    write_bytes(folder / "nan.nrrd", nrrd);
    expect_error<InputError>([&] { read_label_volume(folder / "nan.nrrd"); }, {"nan.nrrd", "NRRD field 'spacings' is 'nan 1 1'", "finite"});
    std::vector<unsigned char> mha;
    append_text(mha, "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                     "ElementSpacing = nan 1 1\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n");
    mha.resize(mha.size() + 8, 1);
    write_bytes(folder / "nan.mha", mha);
    expect_error<InputError>([&] { read_label_volume(folder / "nan.mha"); }, {"nan.mha", "MetaImage ElementSpacing is 'nan 1 1'", "finite"});
}

TEST(VolumeHeaderWarnings, AMetaImageOrNrrdWithoutAVoxelSizeReadsAsOneMillimetreAndSaysSo) {
    // Both formats default to 1 mm voxels: the file reads, with ITK's 1 mm, and one warning names
    // the file and the field to add. With the field there is no warning.
    TempDir folder;
    auto mha = [&](const std::string& name, const std::string& spacing_line) {
        std::vector<unsigned char> bytes;
        append_text(bytes, "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n" + spacing_line +
                               "DimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n");
        bytes.resize(bytes.size() + 8, 1);
        write_bytes(folder / name, bytes);
        return read_volume_header(folder / name);
    };
    auto nrrd = [&](const std::string& name, const std::string& spacing_line) {
        std::vector<unsigned char> bytes;
        append_text(bytes, "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\n" + spacing_line + "encoding: raw\n\n");
        bytes.resize(bytes.size() + 8, 1);
        write_bytes(folder / name, bytes);
        return read_volume_header(folder / name);
    };
    for (const VolumeHeader& header : {mha("bare.mha", ""), nrrd("bare.nrrd", "")}) {
        for (int a = 0; a < 3; ++a) EXPECT_EQ(header.geometry.spacing[std::size_t(a)], 1.0) << header.format;
        ASSERT_EQ(header.warnings.size(), 1u) << header.format;
        EXPECT_NE(header.warnings.front().find("gives no voxel size"), std::string::npos) << header.warnings.front();
        EXPECT_NE(header.warnings.front().find(header.format == "NRRD" ? "bare.nrrd" : "bare.mha"), std::string::npos) << header.warnings.front();
        EXPECT_NE(header.warnings.front().find("1 mm voxels assumed"), std::string::npos) << header.warnings.front();
    }
    for (const VolumeHeader& header : {mha("spaced.mha", "ElementSpacing = 0.9 0.9 0.9\n"), nrrd("spaced.nrrd", "spacings: 0.9 0.9 0.9\n"),
                                       nrrd("directed.nrrd", "space: left-posterior-superior\nspace directions: (0.9,0,0) (0,0.9,0) (0,0,0.9)\n")}) {
        EXPECT_TRUE(header.warnings.empty()) << header.warnings.front();
        EXPECT_NEAR(header.geometry.spacing[0], 0.9, 1e-6) << header.format;
    }
}

TEST(VolumeReadErrors, NegativeSpacingMetaImage) {
    // MetaIO reports the -2 as written; ITK's reader would quietly make it +2.
    std::vector<unsigned char> bytes;
    append_text(bytes, "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                       "ElementSpacing = 1 1 -2\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n");
    bytes.resize(bytes.size() + 8, 1);
    TempDir folder;
    const fs::path path = folder / "mirrored.mha";
    write_bytes(path, bytes);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "spacing along k: -2"});
}

TEST(VolumeReadErrors, TooLargeFailsOnTheEstimate) {
    // 60000³ bytes claimed, 16 present: must be refused on the estimate, before any allocation.
    std::vector<unsigned char> bytes;
    append_text(bytes,
                "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                "ElementSpacing = 1 1 1\nDimSize = 60000 60000 60000\nElementType = MET_UCHAR\n"
                "ElementDataFile = LOCAL\n");
    bytes.resize(bytes.size() + 16, 0);
    TempDir folder;
    const fs::path path = folder / "huge.mha";
    write_bytes(path, bytes);
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "too large", "60000×60000×60000"});
}

// -------------------------------------------------------------------------------------------
// Found by fuzzing (tests/fuzz): each was a crash, undefined behaviour, an escaped exception of
// another type or an allocation of the declared size before the reader refused the file.

fs::path write_text_file(const TempDir& folder, const std::string& name, const std::string& text) {
    std::vector<unsigned char> bytes;
    append_text(bytes, text);
    const fs::path path = folder / name;
    write_bytes(path, bytes);
    return path;
}

TEST(VolumeReadErrors, NiftiVoxOffsetThatIsNoByteOffset) {
    // fuzz_volume_nii: vox_offset 1e31 (a float) was cast to a 64-bit byte offset, undefined.
    TempDir folder;
    for (float offset : {1e31f, std::numeric_limits<float>::infinity()}) {
        HandNifti nifti({2, 2, 2}, 2, 8);
        nifti.put<float>(108, offset);
        nifti.append_voxels(std::vector<std::uint8_t>(8, 1));
        const fs::path path = folder / "offset.nii";
        write_bytes(path, nifti.bytes);
        expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "NIfTI vox_offset is "});
    }
}

TEST(VolumeReadErrors, NiftiOrientationOutsideItsRangeIsRefusedBeforeItk) {
    // fuzz_volume_nii: ITK hands the orientation to vnl_svd, which aborts the process on a NaN and
    // never returns on -1.7e38.
    TempDir folder;
    HandNifti nifti({2, 2, 2}, 2, 8);
    nifti.set_sform(Eigen::Matrix<float, 3, 4>::Identity());
    nifti.put<float>(280 + 16 * 1 + 4 * 2, std::numeric_limits<float>::quiet_NaN());  // srow_y[2]
    nifti.append_voxels(std::vector<std::uint8_t>(8, 1));
    const fs::path path = folder / "nan-sform.nii";
    write_bytes(path, nifti.bytes);
    expect_error<InputError>([&] { read_volume_header(path); }, {path.string(), "NIfTI srow_y[2] is nan"});
    expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "NIfTI srow_y[2] is nan"});
    // Finite but near the end of the float range: vnl_svd never returned.
    nifti.put<float>(280 + 16 * 1 + 4 * 2, -1.7e38f);
    write_bytes(path, nifti.bytes);
    expect_error<InputError>([&] { read_volume_header(path); }, {path.string(), "NIfTI srow_y[2] is -1.7e+38", "outside the plausible range"});
}

TEST(VolumeReadErrors, MetaImageElementTypeItkDoesNotKnow) {
    // fuzz_volume_mha: ITK's size query threw through a noexcept function (std::terminate).
    TempDir folder;
    const fs::path path = write_text_file(folder, "type.mha", "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_\n"
                                                              "ElementDataFile = LOCAL\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(path); }, {path.string(), "no element type ITK knows"});
}

TEST(VolumeReadErrors, MetaImageFieldNameTooLongForMetaIOIsRefusedBeforeIt) {
    // fuzz_volume_mha: MetaIO strcpy's a field name into 255 bytes; 300 characters aborted the
    // process (glibc's buffer overflow check) inside ITK. NDims sizes MetaIO's arrays and matrices.
    TempDir folder;
    const std::string header = "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n";
    const fs::path named = write_text_file(folder, "name.mha", header + std::string(300, 'K') + " = 1\nElementDataFile = LOCAL\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_label_volume(named); }, {named.string(), "line 5", "field name of 300 characters"});
    expect_error<InputError>([&] { read_volume_header(named); }, {named.string(), "field name of 300 characters"});
    const fs::path dims = write_text_file(folder, "dims.mha", "ObjectType = Image\nNDims = 100\nTransformMatrix = 1\nElementDataFile = LOCAL\n");
    expect_error<InputError>([&] { read_label_volume(dims); }, {dims.string(), "MetaImage NDims is '100'"});
    // fuzz_volume_mha, 10-minute run: MetaIO takes a value from the next '=' on, past the line's
    // end, so "NDims" alone read the next line's 99999999 as NDims and its arrays for minutes.
    const fs::path split = write_text_file(folder, "split.mha", "ObjectType = Image\nNDims\nx = 99999999\nDimSize = 2 2 2\n"
                                                               "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(split); }, {split.string(), "line 2 'NDims' has no '='"});
    // The rerun: a name MetaIO reads as "NDims" (it stops at the NUL), with a value of millions.
    const fs::path nul = write_text_file(folder, "nul.mha", "ObjectType = Image\nNDims = 3\n" + std::string("NDims\0x", 7) +
                                                           " = 99999999\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
                                                           std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(nul); }, {nul.string(), "line 3 holds a NUL byte"});
    // The confirmation run: MetaIO allocated CompressedDataSize bytes (a terabyte) before reading.
    const fs::path packed = write_text_file(folder, "packed.mha", "ObjectType = Image\nNDims = 3\nCompressedData = True\n"
                                                                 "CompressedDataSize = 1000000000000\nDimSize = 2 2 2\n"
                                                                 "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(packed); }, {packed.string(), "CompressedDataSize is '1000000000000'"});
    // Found by fuzz_volume_mha: MetaIO strcpy's a string field's value (ObjectType, Name,
    // Comment, …) into 255 bytes too; a 300-character ObjectType aborted in MetaObject::M_Read.
    for (const std::string field : {"ObjectType", "Comment", "Name", "AnatomicalOrientation"}) {
        const fs::path long_value = write_text_file(folder, "value.mha", field + " = " + std::string(300, 'v') + "\n" + header +
                                                                            "ElementDataFile = LOCAL\n" + std::string(8, '\1'));
        expect_error<InputError>([&] { read_volume_header(long_value); },
                                 {long_value.string(), "line 1", field + " has a value of 300 characters"});
    }
}

// A damaged header's message names the file and the field, in words a technician can act on:
// not ITK's object addresses, NrrdIO's chain of function names, a stale errno, or MetaIO's own
// lines on stderr ahead of the error.
TEST(VolumeReadErrors, DamagedHeadersAreExplainedWithoutTheLibrariesInternals) {
    TempDir folder;
    auto message_of = [](const fs::path& path) {
        testing::internal::CaptureStderr();
        std::string message;
        try {
            read_volume_header(path);
        } catch (const InputError& error) {
            message = error.what();
        }
        const std::string printed = testing::internal::GetCapturedStderr();
        EXPECT_EQ(printed, "") << path;
        EXPECT_EQ(message.find("0x"), std::string::npos) << message;
        EXPECT_EQ(message.find("[nrrd]"), std::string::npos) << message;
        EXPECT_EQ(message.find("Reason:"), std::string::npos) << message;
        EXPECT_NE(message.find(path.string()), std::string::npos) << message;
        return message;
    };
    const std::string voxels(64, '\1');
    // MetaIO took the next line's "ElementType" as the missing size, then said that ElementType
    // was missing; ours counts the numbers against NDims first.
    for (const auto& [field, line, expected] :
         std::vector<std::array<std::string, 3>>{{"DimSize", "DimSize = 4 4\nElementSpacing = 1 1 1\n", "2 numbers; NDims = 3 needs 3"},
                                                 {"ElementSpacing", "DimSize = 4 4 4\nElementSpacing = 1 1\n", "2 numbers; NDims = 3 needs 3"},
                                                 {"TransformMatrix", "DimSize = 4 4 4\nTransformMatrix = 1 0 0 0 1 0\n", "6 numbers; NDims = 3 needs 9"}}) {
        const fs::path path = write_text_file(folder, field + ".mha", "ObjectType = Image\nNDims = 3\n" + line +
                                                                      "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + voxels);
        const std::string message = message_of(path);
        EXPECT_NE(message.find(std::string(field == "DimSize" ? "line 3: " : "line 4: ") + field), std::string::npos) << message;
        EXPECT_NE(message.find(expected), std::string::npos) << message;
    }
    // More numbers than NDims are what MetaIO (and so every reader built on it) accepts.
    const fs::path extra = write_text_file(folder, "extra.mha", "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4 4\nElementSpacing = 1 1 1\n"
                                                                "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + voxels);
    EXPECT_EQ(read_label_volume(extra).labels.size(), 64u);
    // What MetaIO finds itself (no ElementType at all) comes from its own line, once, in the error.
    const fs::path untyped = write_text_file(folder, "untyped.mha", "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementSpacing = 1 1 1\n"
                                                                    "ElementDataFile = LOCAL\n" + voxels);
    EXPECT_NE(message_of(untyped).find("cannot read the MetaImage header: MetaIO: ElementType required and not defined"), std::string::npos);
    // niftilib refused an unknown datatype on stderr, and ITK called the file no NIfTI file.
    std::string nifti(352, '\0');
    const std::int32_t sizeof_hdr = 348;
    const std::int16_t dim[8] = {3, 4, 4, 4, 1, 1, 1, 1}, datatype = 9999, bitpix = 8;
    const float pixdim[8] = {1, 1, 1, 1, 1, 1, 1, 1}, vox_offset = 352;
    std::memcpy(&nifti[0], &sizeof_hdr, 4);
    std::memcpy(&nifti[40], dim, sizeof dim);
    std::memcpy(&nifti[70], &datatype, 2);
    std::memcpy(&nifti[72], &bitpix, 2);
    std::memcpy(&nifti[76], pixdim, sizeof pixdim);
    std::memcpy(&nifti[108], &vox_offset, 4);
    std::memcpy(&nifti[344], "n+1", 4);
    const fs::path typed = write_text_file(folder, "typed.nii", nifti + voxels);
    EXPECT_NE(message_of(typed).find("NIfTI datatype is 9999; expected a NIfTI type code"), std::string::npos);
    // NrrdIO's innermost reasons, without the links that only say that reading failed.
    const fs::path sizes = write_text_file(folder, "sizes.nrrd", "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4\nspacings: 1 1 1\n"
                                                                 "encoding: raw\n\n" + voxels);
    const std::string sizes_message = message_of(sizes);
    EXPECT_NE(sizes_message.find("cannot read the NRRD header: trouble parsing sizes info |4 4|; parsed 2 values, but dimension is 3"),
              std::string::npos) << sizes_message;
    const fs::path endian = write_text_file(folder, "endian.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 4 4 2\nspacings: 1 1 1\n"
                                                                   "encoding: raw\n\n" + voxels);
    EXPECT_NE(message_of(endian).find("type (short) and encoding (raw) require endian info"), std::string::npos);
}

// fuzz_volume_nrrd (10-minute run after the fix above): a second `encoding:` line that this
// reader did not know as gzip left the voxel data unchecked, and NrrdIO then allocated 2 GB for
// the sizes it had read. Fields given twice and encodings it cannot check are refused.
TEST(VolumeReadErrors, NrrdFieldGivenTwiceOrUnknownEncodingIsRefused) {
    TempDir folder;
    const std::string start = "NRRD0004\ntype: unsigned char\ndimension: 3\nspace: left-posterior-superior\nsizes: 4 3 2\n"
                              "space directions: (1,0,0) (0,1,0) (0,0,1)\nkinds: domain domain domain\n";
    const fs::path twice = write_text_file(folder, "twice.nrrd", start + "encoding: raw\nencoding: gz   x\n\n" + std::string(24, '\1'));
    expect_error<InputError>([&] { read_volume_header(twice); }, {twice.string(), "line 9 gives the field 'encoding' a second time"});
    const fs::path odd = write_text_file(folder, "odd.nrrd", start + "encoding: gz   x\n\n" + std::string(24, '\1'));
    expect_error<InputError>([&] { read_volume_header(odd); }, {odd.string(), "encoding"});  // NrrdIO's refusal or ours
    // The same header with one known encoding reads.
    const fs::path good = write_text_file(folder, "good.nrrd", start + "encoding: raw\n\n" + std::string(24, '\1'));
    EXPECT_EQ(read_label_volume(good).labels.size(), 24u);
}

TEST(VolumeReadErrors, DataFileThatIsNoRegularFile) {
    // fuzz_volume_nrrd: `data file: /dev/zero` or a folder made our size check throw
    // std::filesystem::filesystem_error instead of InputError.
    TempDir folder;
    fs::create_directory(folder / "data");
    for (const std::string data : {std::string("/dev/zero"), std::string("data")}) {
        const fs::path path = write_text_file(folder, "detached.nrrd",
                                              "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: " + data + "\n\n");
        expect_error<InputError>([&] { read_label_volume(path); }, {path.string(), "is not a regular file"});
    }
}

TEST(VolumeReadErrors, TextEncodedNrrdMustHoldACharacterPerValueBeforeAnyAllocation) {
    // 10^9 voxels declared in ascii with three values present: refused on the file size, not after
    // allocating a gigabyte; and NrrdIO's several lines of complaint about a short file become one.
    TempDir folder;
    const fs::path huge = write_text_file(folder, "huge.nrrd",
                                          "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 1000 1000 1000\nencoding: ascii\n\n1 2 3\n");
    expect_error<InputError>([&] { read_label_volume(huge); }, {huge.string(), "1000000000 values as text", "need at least 1000000000 bytes"});
    const fs::path hex = write_text_file(folder, "hex.nrrd", "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\nencoding: hex\n\n0102\n");
    expect_error<InputError>([&] { read_label_volume(hex); }, {hex.string(), "as hex", "need at least 16 bytes"});
    const fs::path short_text = write_text_file(folder, "short.nrrd",
                                                "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\nencoding: ascii\n\n1 2 3         \n");
    try {
        read_label_volume(short_text);
        ADD_FAILURE() << "three values read as eight";
    } catch (const InputError& e) {
        EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find(short_text.string()), std::string::npos) << e.what();
    }
}

TEST(VolumeReadErrors, NrrdHeaderLineTooLongForNrrdIOsMessagesIsRefusedBeforeIt) {
    // fuzz_volume_nrrd, 10-minute run: NrrdIO copies a line it cannot parse into a 1025-byte stack
    // buffer with its complaint; a 1012-character type line aborted the process (stack protector).
    TempDir folder;
    const fs::path path = write_text_file(folder, "long.nrrd", "NRRD0004\ntype: " + std::string(1012, 'u') +
                                                               "\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(path); }, {path.string(), "NRRD header line 2 has 1018 characters"});
    // NrrdIO also ends a line at a lone carriage return: a comment with one in it hid a long field
    // line behind it (found by fuzz_volume_nrrd: a 116-character comment, then 1,248
    // characters, the stack protector again). The pieces count as lines, as NrrdIO counts them.
    const fs::path hidden = write_text_file(folder, "hidden.nrrd", "NRRD0004\n# a comment\r+" + std::string(1247, 'u') +
                                                                   "\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n" + std::string(8, '\1'));
    expect_error<InputError>([&] { read_volume_header(hidden); }, {hidden.string(), "NRRD header line 3 has 1248 characters"});
    // CR LF line breaks are one break each, not a blank line that would end the header early.
    const fs::path crlf = write_text_file(folder, "crlf.nrrd", "NRRD0004\r\ntype: unsigned char\r\ndimension: 3\r\nsizes: 2 2 2\r\nencoding: raw\r\n"
                                                               "spacings: 1 1 1\r\n\r\n" + std::string(8, '\1'));
    EXPECT_NO_THROW(read_label_volume(crlf));
}

TEST(VolumeReadErrors, DataSpreadOverSeveralFilesIsRefused) {
    // NrrdIO and MetaIO format each file name with a printf pattern from the header.
    TempDir folder;
    const fs::path nrrd = write_text_file(folder, "list.nrrd",
                                          "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: slice%s%s%n.raw 1 2 1\n\n");
    expect_error<InputError>([&] { read_label_volume(nrrd); }, {nrrd.string(), "several files"});
    const fs::path mha = write_text_file(folder, "list.mha",
                                         "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LIST\na.raw\nb.raw\n");
    expect_error<InputError>([&] { read_label_volume(mha); }, {mha.string(), "several files"});
}

TEST(VolumeReadErrors, MemoryLimitOption) {
    TempDir folder;
    const fs::path path = folder / "small.nrrd";
    write_label_volume(path, make_test_volume(10, 10, 10));
    expect_error<InputError>([&] { read_label_volume(path, {.memory_limit_bytes = 1000}); },
                             {path.string(), "too large", "memory limit"});
    EXPECT_NO_THROW(read_label_volume(path, {.memory_limit_bytes = 16000}));
}

TEST(VolumeWriteErrors, MissingFolderLeavesNoFile) {
    TempDir folder;
    const fs::path path = folder / "missing" / "out.nii.gz";
    expect_error<OutputError>([&] { write_label_volume(path, make_test_volume(4, 4, 4)); }, {path.string()});
    EXPECT_FALSE(fs::exists(folder / "missing"));
    EXPECT_TRUE(fs::is_empty(folder.path()));
}

TEST(VolumeWriteErrors, FailedRenameRemovesTemporaryFile) {
    // The target name is taken by a non-empty folder: the temporary file is written, the rename
    // fails, and nothing but the folder may remain.
    TempDir folder;
    const fs::path path = folder / "taken.nrrd";
    fs::create_directory(path);
    write_bytes(path / "keep", {'x'});
    expect_error<OutputError>([&] { write_label_volume(path, make_test_volume(4, 4, 4)); }, {path.string()});
    std::vector<fs::path> entries(fs::directory_iterator(folder.path()), fs::directory_iterator{});
    ASSERT_EQ(entries.size(), 1u);
    EXPECT_EQ(entries[0].filename(), "taken.nrrd");
}

}  // namespace
}  // namespace heartsim
