// The scenario file: a write/read round trip of every dataset, and the reader's refusals.
#include "formats/atomic_file.h"
#include "formats/csv.h"
#include "formats/hdf5_io.h"
#include "formats/scenario.h"
#include "libmodel/errors.h"
#include "libmodel/lattice.h"
#include "libmodel/select.h"
#include "libmodel/simulation_surface.h"
#include "scenario_damage.h"
#include "test_support.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <hdf5.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <thread>

using namespace heartsim;
using test::overwrite;
using test::refusal;

namespace {

Scenario sample_scenario() {
    LabelVolume v;
    v.geometry.dims = {10, 8, 6};
    v.geometry.spacing = Eigen::Vector3d(0.9, 1.1, 1.3);
    v.geometry.origin = Eigen::Vector3d(-4.5, 12.0, 30.25);
    v.geometry.direction << 0, 1, 0, -1, 0, 0, 0, 0, 1;
    v.labels.assign(v.geometry.voxel_count(), 0);
    for (int k = 1; k < 5; ++k)
        for (int j = 1; j < 7; ++j)
            for (int i = 1; i < 9; ++i) v.labels[v.geometry.linear(i, j, k)] = 1;
    Scenario s;
    s.generator = "test";
    s.source.file_name = "block.nii.gz";
    s.source.sha256 = std::string(64, 'a');
    s.source.geometry = v.geometry;
    s.source.tissue_labels = {1};
    s.source.cavity_labels = {2, 3};
    s.source.anchor_border = true;
    SelectionOptions keep_all;
    keep_all.min_island_mm3 = 0;
    const Selection selection = select_tissue(v, keep_all);
    s.lattice = layout_particles(selection, {1}, v, {.spacing_mm = 1.7, .occupancy = 0.3});
    s.lattice.particles.anchored[0] = 1;
    VisualMesh mesh;
    mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    mesh.normals = {{0, 0, -1}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    s.visual = mesh;
    s.solver.dt_ms = 0.05;
    s.solver.critical_dt_ms = 0.11;
    s.solver.critical_dt_bound_ms = 0.07;
    s.solver.substeps = 3;
    s.solver.damping = 0.01;
    s.solver.gravity = Eigen::Vector3d(0, 9.81e-3, 0);
    return s;
}

void remove_object(const std::filesystem::path& file, const char* name) {
    hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    H5Ldelete(f, name, H5P_DEFAULT);
    H5Fclose(f);
}

/// Where the first (only) chunk of /particles/mass lies in `file` and how many bytes it holds, as
/// HDF5's own index says: the place the damage tests write to.
struct ChunkPlace {
    haddr_t address = 0;
    hsize_t stored = 0;
};
ChunkPlace mass_chunk(const std::filesystem::path& file) {
    ChunkPlace place;
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    const hid_t d = H5Dopen2(f, "particles/mass", H5P_DEFAULT);
    hsize_t offset[1] = {0};
    unsigned filter_mask = 0;
    EXPECT_GE(H5Dget_chunk_info_by_coord(d, offset, &filter_mask, &place.address, &place.stored), 0) << file;
    H5Dclose(d);
    H5Fclose(f);
    return place;
}

/// Flips one bit of the stored masses in `file`: the chunk's Fletcher-32 checksum no longer matches.
void flip_a_stored_mass_bit(const std::filesystem::path& file) {
    const auto [address, stored] = mass_chunk(file);
    ASSERT_GT(stored, 8u);
    std::fstream bytes(file, std::ios::in | std::ios::out | std::ios::binary);
    bytes.seekg(std::streamoff(address + 2));
    char byte = 0;
    bytes.read(&byte, 1);
    byte ^= 0x10;
    bytes.seekp(std::streamoff(address + 2));
    bytes.write(&byte, 1);
}

}  // namespace

TEST(Scenario, LatticeDimsBeyondTheSourceVolumeAreRefusedNamingTheAttribute) {
    // The builder's lattice covers the source volume, ceil(extent / spacing) cells per axis; a
    // damaged count (2e9) made readers that size a grid by it fail with "out of memory".
    test::TempDir dir;
    const Scenario s = sample_scenario();
    const auto file = dir / "s.h5";
    write_scenario(file, s);
    for (int a = 0; a < 3; ++a) {
        const double extent = s.source.geometry.dims[std::size_t(a)] * s.source.geometry.spacing[a];
        EXPECT_EQ(s.lattice.dims[std::size_t(a)], int(std::ceil(extent / s.lattice.spacing - 1e-9))) << "axis " << a;
    }
    EXPECT_EQ(refusal(file), "");
    test::overwrite_attribute(file, "lattice", "dims", std::vector<std::int32_t>{2000000000, s.lattice.dims[1], s.lattice.dims[2]},
                              H5T_NATIVE_INT32);
    const std::string message = refusal(file);
    for (const char* part : {"s.h5", "/lattice", "dims 2000000000 x", "at most", "source volume along axis 0"})
        EXPECT_NE(message.find(part), std::string::npos) << part << " in: " << message;
}

TEST(Scenario, APositionTextureWiderThanAnyGpuHoldsIsRefusedNamingTheAttribute) {
    // A width of 1e9 made the reader's texel check ask for gigabytes ("out of memory").
    test::TempDir dir;
    Scenario s = sample_scenario();
    s.packing = pack_particles(s.lattice);
    const auto file = dir / "s.h5";
    write_scenario(file, s);
    EXPECT_EQ(refusal(file), "");
    {
        hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        hid_t g = H5Dopen2(f, "packing/texture_coord", H5P_DEFAULT);
        hid_t attribute = H5Aopen(g, "width", H5P_DEFAULT);
        const std::int32_t width = 1000000000;
        ASSERT_GE(H5Awrite(attribute, H5T_NATIVE_INT32, &width), 0);
        H5Aclose(attribute);
        H5Dclose(g);
        H5Fclose(f);
    }
    const std::string message = refusal(file);
    for (const char* part : {"s.h5", "/packing/texture_coord", "width x height 1000000000 x", "at most 16384"})
        EXPECT_NE(message.find(part), std::string::npos) << part << " in: " << message;
}

TEST(Scenario, RoundTripKeepsEveryDataset) {
    test::TempDir dir;
    const Scenario s = sample_scenario();
    write_scenario(dir / "s.h5", s);
    const Scenario r = read_scenario(dir / "s.h5");

    EXPECT_EQ(r.generator, s.generator);
    EXPECT_EQ(r.source.file_name, s.source.file_name);
    EXPECT_EQ(r.source.sha256, s.source.sha256);
    EXPECT_EQ(r.source.geometry.dims, s.source.geometry.dims);
    EXPECT_TRUE(r.source.geometry.spacing.isApprox(s.source.geometry.spacing, 1e-15));
    EXPECT_TRUE(r.source.geometry.origin.isApprox(s.source.geometry.origin, 1e-15));
    EXPECT_TRUE(r.source.geometry.direction.isApprox(s.source.geometry.direction, 1e-15));
    EXPECT_EQ(r.source.tissue_labels, s.source.tissue_labels);
    EXPECT_EQ(r.source.cavity_labels, s.source.cavity_labels);
    EXPECT_EQ(r.source.anchor_labels, s.source.anchor_labels);
    EXPECT_EQ(r.source.anchor_border, s.source.anchor_border);

    EXPECT_EQ(r.lattice.spacing, s.lattice.spacing);
    EXPECT_EQ(r.lattice.dims, s.lattice.dims);
    EXPECT_EQ(r.lattice.index_to_world, s.lattice.index_to_world);
    ASSERT_EQ(r.lattice.materials.size(), s.lattice.materials.size());
    EXPECT_EQ(r.lattice.materials[0].name, s.lattice.materials[0].name);
    EXPECT_EQ(r.lattice.materials[0].label, s.lattice.materials[0].label);
    EXPECT_FLOAT_EQ(float(r.lattice.materials[0].density), float(s.lattice.materials[0].density));
    EXPECT_FLOAT_EQ(float(r.lattice.materials[0].youngs_modulus_kpa), float(s.lattice.materials[0].youngs_modulus_kpa));
    EXPECT_FLOAT_EQ(float(r.lattice.materials[0].damping_ratio), float(s.lattice.materials[0].damping_ratio));

    const auto& p = r.lattice.particles;
    EXPECT_EQ(p.rest_position, s.lattice.particles.rest_position);
    EXPECT_EQ(p.lattice_index, s.lattice.particles.lattice_index);
    EXPECT_EQ(p.mass, s.lattice.particles.mass);
    EXPECT_EQ(p.material, s.lattice.particles.material);
    EXPECT_EQ(p.anchored, s.lattice.particles.anchored);
    EXPECT_EQ(r.lattice.springs.pairs, s.lattice.springs.pairs);
    EXPECT_EQ(r.lattice.springs.rest_length, s.lattice.springs.rest_length);
    EXPECT_EQ(r.lattice.springs.stiffness, s.lattice.springs.stiffness);

    ASSERT_TRUE(r.visual.has_value());
    EXPECT_EQ(r.visual->positions, s.visual->positions);
    EXPECT_EQ(r.visual->normals, s.visual->normals);
    EXPECT_EQ(r.visual->triangles, s.visual->triangles);

    EXPECT_EQ(r.solver.dt_ms, s.solver.dt_ms);
    EXPECT_EQ(r.solver.substeps, s.solver.substeps);
    EXPECT_EQ(r.solver.damping, s.solver.damping);
    EXPECT_EQ(r.solver.gravity, s.solver.gravity);
    EXPECT_EQ(r.solver.critical_dt_ms, s.solver.critical_dt_ms);
    EXPECT_EQ(r.solver.critical_dt_bound_ms, s.solver.critical_dt_bound_ms);
}

TEST(Scenario, VisualIsOptional) {
    test::TempDir dir;
    Scenario s = sample_scenario();
    s.visual.reset();
    write_scenario(dir / "s.h5", s);
    EXPECT_FALSE(read_scenario(dir / "s.h5").visual.has_value());
}

TEST(Scenario, ReaderNamesTheDatasetAndTheProblem) {
    test::TempDir dir;
    const Scenario s = sample_scenario();
    const std::size_t n = s.lattice.particles.size();
    auto fresh = [&](const char* name) {
        auto path = dir / name;
        write_scenario(path, s);
        return path;
    };

    auto file = fresh("nan.h5");
    auto positions = std::vector<float>(3 * n, 0.0f);
    positions[4] = std::nanf("");
    overwrite(file, "particles/rest_position", positions, H5T_NATIVE_FLOAT);
    EXPECT_NE(refusal(file).find("particles/rest_position: value 4 is not finite"), std::string::npos) << refusal(file);

    file = fresh("range.h5");
    auto pairs = std::vector<std::int32_t>(2 * s.lattice.springs.size(), 0);
    for (std::size_t i = 0; i < s.lattice.springs.size(); ++i) {
        pairs[2 * i] = 0;
        pairs[2 * i + 1] = std::int32_t(n + 5);
    }
    overwrite(file, "springs/pairs", pairs, H5T_NATIVE_INT32);
    EXPECT_NE(refusal(file).find("springs/pairs: entry 1 is"), std::string::npos) << refusal(file);

    file = fresh("mass.h5");
    overwrite(file, "particles/mass", std::vector<float>(n, -1.0f), H5T_NATIVE_FLOAT);
    EXPECT_NE(refusal(file).find("particles/mass"), std::string::npos) << refusal(file);

    file = fresh("missing.h5");
    remove_object(file, "springs/stiffness");
    EXPECT_NE(refusal(file).find("springs/stiffness: missing dataset"), std::string::npos) << refusal(file);

    file = fresh("triangles.h5");
    overwrite(file, "visual/triangles", std::vector<std::int32_t>(12, 9), H5T_NATIVE_INT32);
    EXPECT_NE(refusal(file).find("visual/triangles"), std::string::npos) << refusal(file);

    std::ofstream(dir / "text.h5") << "not hdf5";
    EXPECT_NE(refusal(dir / "text.h5").find("not an HDF5 file"), std::string::npos);
    EXPECT_NE(refusal(dir / "absent.h5").find("file not found"), std::string::npos);
}

TEST(Scenario, SimulationSurfaceNormalWeightsRoundTripAndAreValidated) {
    test::TempDir dir;
    Scenario s = sample_scenario();
    const std::int32_t n = std::int32_t(s.lattice.particles.size());
    ASSERT_GE(n, 3);
    // Two twins (one counted) and a third triangle.
    s.simulation_surface = SimulationSurface{{{0, 1, 2}, {0, 2, 1}, {1, 2, n - 1}}, {1, 0, 1}};
    const auto file = dir / "surface.h5";
    write_scenario(file, s);
    const Scenario back = read_scenario(file);
    ASSERT_TRUE(back.simulation_surface);
    EXPECT_TRUE(*back.simulation_surface == *s.simulation_surface);
    // A weight other than 0 or 1 is refused, naming the dataset.
    overwrite(file, "simsurface/normal_weight", std::vector<std::uint8_t>{1, 2, 1}, H5T_NATIVE_UINT8);
    EXPECT_NE(refusal(file).find("simsurface/normal_weight"), std::string::npos) << refusal(file);
    EXPECT_NE(refusal(file).find("not 0 or 1"), std::string::npos) << refusal(file);
    // A file written before the weights existed reads with every triangle counted.
    remove_object(file, "simsurface/normal_weight");
    const Scenario old = read_scenario(file);
    ASSERT_TRUE(old.simulation_surface);
    EXPECT_EQ(old.simulation_surface->normal_weight, std::vector<std::uint8_t>(3, 1));
    // Weights of the wrong shape: refused on reading, and not written.
    s.simulation_surface->normal_weight = {1, 0};
    EXPECT_THROW(write_scenario(dir / "bad.h5", s), InputError);
    s.simulation_surface->normal_weight = {1, 0, 1};
    write_scenario(file, s);
    remove_object(file, "simsurface/normal_weight");
    {
        hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        hid_t g = H5Gopen2(f, "simsurface", H5P_DEFAULT);
        const hsize_t two = 2;
        hid_t space = H5Screate_simple(1, &two, nullptr);
        hid_t set = H5Dcreate2(g, "normal_weight", H5T_NATIVE_UINT8, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
        const std::uint8_t ones[2] = {1, 1};
        H5Dwrite(set, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, ones);
        H5Dclose(set);
        H5Sclose(space);
        H5Gclose(g);
        H5Fclose(f);
    }
    EXPECT_NE(refusal(file).find("simsurface/normal_weight"), std::string::npos) << refusal(file);
}

TEST(Scenario, MappingCarriersRoundTripAndAreValidated) {
    test::TempDir dir;
    Scenario s = sample_scenario();
    const std::int32_t n = std::int32_t(s.lattice.particles.size());
    ASSERT_GE(n, 8);
    s.simulation_surface = SimulationSurface::all_counted({{0, 1, 2}, {1, 2, 3}});
    VisualMapping m;
    for (std::size_t v = 0; v < s.visual->positions.size(); ++v) {
        m.triangle.push_back(std::int32_t(v % 2));
        m.barycentric.push_back({0.5f, 0.25f, 0.25f});
        m.offset.push_back(v == 0 ? 0.5f : 0.0f);
        m.particles.push_back({0, 1, 2, 3, 4, 5, 6, n - 1});
        m.weights.push_back({0.25f, 0.25f, 0.125f, 0.125f, 0.0625f, 0.0625f, 0.0625f, 0.0625f});
    }
    s.mapping = m;
    const auto file = dir / "carriers.h5";
    write_scenario(file, s);
    const Scenario back = read_scenario(file);
    ASSERT_TRUE(back.mapping);
    EXPECT_EQ(back.mapping->particles, m.particles);
    EXPECT_EQ(back.mapping->weights, m.weights);
    // Weights that do not sum to 1, and a carrier outside the particles, are refused by name.
    std::vector<float> weights(8 * m.weights.size(), 0.125f);
    weights[3] = 0.5f;
    overwrite(file, "mapping/weights", weights, H5T_NATIVE_FLOAT);
    EXPECT_NE(refusal(file).find("mapping/weights"), std::string::npos) << refusal(file);
    EXPECT_NE(refusal(file).find("row 0 does not sum to 1"), std::string::npos) << refusal(file);
    write_scenario(file, s);
    std::vector<std::int32_t> carriers(8 * m.particles.size(), 0);
    carriers[5] = n;
    overwrite(file, "mapping/particles", carriers, H5T_NATIVE_INT32);
    EXPECT_NE(refusal(file).find("mapping/particles"), std::string::npos) << refusal(file);
    // One without the other is refused; neither (an older file) reads as the triangle's corners.
    write_scenario(file, s);
    remove_object(file, "mapping/weights");
    EXPECT_NE(refusal(file).find("mapping/weights"), std::string::npos) << refusal(file);
    remove_object(file, "mapping/particles");
    const Scenario old = read_scenario(file);
    ASSERT_TRUE(old.mapping);
    EXPECT_TRUE(old.mapping->particles.empty());
    std::array<std::int32_t, 8> p;
    std::array<float, 8> w;
    mapping_carriers(*old.mapping, *old.simulation_surface, 1, p, w);
    EXPECT_EQ(p, (std::array<std::int32_t, 8>{1, 2, 3, 1, 1, 1, 1, 1}));
    EXPECT_EQ(w, (std::array<float, 8>{0.5f, 0.25f, 0.25f, 0, 0, 0, 0, 0}));
}

TEST(Scenario, WrongElementTypeIsRefused) {
    test::TempDir dir;
    const auto file = dir / "type.h5";
    write_scenario(file, sample_scenario());
    // Replace /particles/mass by a float64 dataset of the same shape.
    const std::size_t n = sample_scenario().lattice.particles.size();
    hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    H5Ldelete(f, "particles/mass", H5P_DEFAULT);
    hsize_t dims[1] = {n};
    hid_t space = H5Screate_simple(1, dims, nullptr);
    hid_t set = H5Dcreate2(f, "particles/mass", H5T_IEEE_F64LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    std::vector<double> ones(n, 1.0);
    H5Dwrite(set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, ones.data());
    H5Dclose(set);
    H5Sclose(space);
    H5Fclose(f);
    EXPECT_NE(refusal(file).find("particles/mass: has element type float64, expected float32"), std::string::npos) << refusal(file);
}

TEST(Scenario, FailedWriteLeavesNoFile) {
    test::TempDir dir;
    EXPECT_THROW(write_scenario(dir / "no" / "such" / "folder.h5", sample_scenario()), OutputError);
    EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

TEST(Scenario, Sha256OfAKnownString) {
    test::TempDir dir;
    std::ofstream(dir / "abc.txt") << "abc";
    // FIPS 180-2, appendix B.1.
    EXPECT_EQ(sha256_file(dir / "abc.txt"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

TEST(AtomicFile, AFailedWriteLeavesNeitherTheFileNorItsTemporaryAndASuccessfulOneReplacesTheFile) {
    test::TempDir dir;
    const auto path = dir / "table.csv";
    write_bytes_atomically(path, "old\n", 4, "the table");
    EXPECT_THROW(write_file_atomically(path, [](const std::filesystem::path& temporary) {
                     std::ofstream(temporary) << "half";
                     throw OutputError("disk full");
                 }),
                 OutputError);
    std::ifstream in(path);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(text, "old\n") << "the old file stays whole";
    std::size_t entries = 0;
    for ([[maybe_unused]] const auto& entry : std::filesystem::directory_iterator(dir.path())) ++entries;
    EXPECT_EQ(entries, 1u) << "no temporary left beside it";
    // Temporaries are distinct, hidden, beside the file, and keep its extension.
    const auto a = temporary_beside(path), b = temporary_beside(path);
    EXPECT_NE(a, b);
    EXPECT_EQ(a.parent_path(), dir.path());
    EXPECT_EQ(a.filename().string().front(), '.');
    EXPECT_EQ(a.extension(), ".csv");
    // A missing folder is named.
    try {
        write_bytes_atomically(dir / "missing" / "x.csv", "x", 1, "the table");
        ADD_FAILURE() << "no error";
    } catch (const OutputError& e) {
        EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
    }
}

TEST(Csv, FieldsFollowRfc4180QuotingAndAreTrimmed) {
    using Fields = std::vector<std::string>;
    EXPECT_EQ(csv_fields(" a , b,c \r"), (Fields{"a", "b", "c"}));
    EXPECT_EQ(csv_fields("\"x, y\",\"say \"\"hi\"\"\",z"), (Fields{"x, y", "say \"hi\"", "z"}));
    EXPECT_EQ(csv_fields("1,2,"), (Fields{"1", "2", ""})) << "a trailing comma is an empty last field";
    EXPECT_EQ(csv_fields(""), (Fields{""}));
    EXPECT_EQ(csv_fields("\t0.5\t,\t-1e3"), (Fields{"0.5", "-1e3"}));
}

TEST(Scenario, AFlippedBitASparseHugeDatasetAndAFifoAreRefused) {
    test::TempDir dir;
    const Scenario s = sample_scenario();

    // One flipped bit in the stored masses: the chunk's Fletcher-32 checksum no longer matches.
    write_scenario(dir / "flipped.h5", s);
    flip_a_stored_mass_bit(dir / "flipped.h5");
    EXPECT_NE(refusal(dir / "flipped.h5").find("particles/mass: cannot be read (damaged file"), std::string::npos)
        << refusal(dir / "flipped.h5");

    // A dataset that declares 2²⁸ rows but stores nothing: refused before its 3 GB are allocated.
    write_scenario(dir / "sparse.h5", s);
    {
        const hid_t f = H5Fopen((dir / "sparse.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
        H5Ldelete(f, "particles/rest_position", H5P_DEFAULT);
        const hsize_t dims[2] = {hsize_t(1) << 28, 3};
        const hid_t space = H5Screate_simple(2, dims, nullptr);
        const hid_t set = H5Dcreate2(f, "particles/rest_position", H5T_IEEE_F32LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
        H5Dclose(set), H5Sclose(space), H5Fclose(f);
    }
    EXPECT_NE(refusal(dir / "sparse.h5").find("particles/rest_position: declares [268435456,3] values"), std::string::npos)
        << refusal(dir / "sparse.h5");

    // A FIFO would block the reader for ever: only regular files are opened.
    ASSERT_EQ(::mkfifo((dir / "fifo.h5").c_str(), 0600), 0);
    EXPECT_NE(refusal(dir / "fifo.h5").find("not a regular file"), std::string::npos) << refusal(dir / "fifo.h5");
}

TEST(Scenario, TheSuperblockChecksumMatchesTheOneHdf5WritesItself) {
    // heartsim builds its files in memory and repairs the superblock checksum that HDF5 1.10's
    // file image leaves stale (hdf5_io.h). The repair's lookup3 must give exactly the checksum
    // HDF5 writes to a file it creates on disk in the same format.
    test::TempDir dir;
    const hid_t access = H5Pcreate(H5P_FILE_ACCESS);
    H5Pset_libver_bounds(access, H5F_LIBVER_V18, H5F_LIBVER_LATEST);
    const hid_t file = H5Fcreate((dir / "direct.h5").c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, access);
    ASSERT_GE(file, 0);
    H5Fclose(file), H5Pclose(access);
    std::ifstream in(dir / "direct.h5", std::ios::binary);
    std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_GE(bytes.size(), 48u);
    ASSERT_TRUE(bytes[8] == 2 || bytes[8] == 3) << "superblock version " << int(bytes[8]);
    const std::size_t covered = 12 + 4 * std::size_t(bytes[9]);
    const std::uint32_t stored = std::uint32_t(bytes[covered]) | std::uint32_t(bytes[covered + 1]) << 8 |
                                 std::uint32_t(bytes[covered + 2]) << 16 | std::uint32_t(bytes[covered + 3]) << 24;
    EXPECT_EQ(h5::lookup3(bytes.data(), covered), stored);
    // A stale checksum is put right: the file opens again.
    const std::vector<unsigned char> good = bytes;
    bytes[covered] ^= 0xff;
    h5::repair_superblock_checksum(bytes);
    EXPECT_EQ(bytes, good);
}

TEST(AtomicFile, AFolderThatTakesNoFileIsRefusedBeforeTheWorkAndATrialLeavesNothing) {
    // /proc takes no new file, and root's access(W_OK) says yes there: check_destination must
    // find out by trying, so a run or build that would end unable to save is refused first.
    if (!std::filesystem::is_directory("/proc")) GTEST_SKIP() << "no /proc on this machine";
    try {
        check_destination("/proc/heartsim-check.h5");
        ADD_FAILURE() << "/proc/heartsim-check.h5 was accepted as a destination";
    } catch (const OutputError& e) {
        const std::string message = e.what();
        EXPECT_NE(message.find("/proc/heartsim-check.h5: "), std::string::npos) << message;
        EXPECT_TRUE(message.find("cannot create a file in folder /proc") != std::string::npos || message.find("not writable") != std::string::npos)
            << message;
    }
    // Where a file can go, the trial file is gone again and the destination not yet made.
    test::TempDir dir;
    check_destination(dir / "out.h5");
    EXPECT_TRUE(std::filesystem::is_empty(dir.path())) << "check_destination left a file behind";
}

TEST(AtomicFile, TemporariesOfKilledWritersAreSweptOnTheNextWrite) {
    // A writer killed mid-write leaves its temporary (a file, or a MetaImage staging folder).
    // The next write of the same file removes those whose process is gone, and only those.
    test::TempDir dir;
    const auto path = dir / "out.h5";
    const pid_t child = ::fork();
    if (child == 0) ::_exit(0);
    ASSERT_GT(child, 0);
    ::waitpid(child, nullptr, 0);  // a process that no longer exists
    const std::string dead = std::to_string(child), alive = std::to_string(::getpid());
    std::ofstream(dir / (".out.h5.tmp-" + dead + "-0.h5")) << "half";
    std::filesystem::create_directory(dir / (".out.h5.tmp-" + dead + "-1"));
    std::ofstream(dir / (".out.h5.tmp-" + dead + "-1") / "out.raw") << "half";
    std::ofstream(dir / (".out.h5.tmp-" + alive + "-7.h5")) << "in use";  // this process: still writing
    std::ofstream(dir / (".other.h5.tmp-" + dead + "-0.h5")) << "another file's";
    write_bytes_atomically(path, "new", 3, "the test file");
    EXPECT_FALSE(std::filesystem::exists(dir / (".out.h5.tmp-" + dead + "-0.h5")));
    EXPECT_FALSE(std::filesystem::exists(dir / (".out.h5.tmp-" + dead + "-1")));
    EXPECT_TRUE(std::filesystem::exists(dir / (".out.h5.tmp-" + alive + "-7.h5")));
    EXPECT_TRUE(std::filesystem::exists(dir / (".other.h5.tmp-" + dead + "-0.h5")));
    EXPECT_TRUE(std::filesystem::exists(path));
}

TEST(Scenario, AbsurdButWellFormedValuesAreRefusedByTheirPlausibleRange) {
    // A 1e-30 g particle or a 1e9 mm spring are finite and positive, but no heart: each is refused
    // naming the dataset, the entry, the value and the range (libmodel/plausible.h).
    test::TempDir dir;
    const Scenario s = sample_scenario();
    ASSERT_GT(s.lattice.particles.size(), 3u);
    write_scenario(dir / "mass.h5", s);
    std::vector<float> masses(s.lattice.particles.mass.begin(), s.lattice.particles.mass.end());
    masses[3] = 1e-30f;
    overwrite(dir / "mass.h5", "particles/mass", masses, H5T_NATIVE_FLOAT);
    EXPECT_NE(refusal(dir / "mass.h5").find("particles/mass: entry 3 is 1e-30 g, outside the plausible range [1e-12, 10000] g"), std::string::npos)
        << refusal(dir / "mass.h5");
    write_scenario(dir / "length.h5", s);
    std::vector<float> lengths(s.lattice.springs.rest_length.begin(), s.lattice.springs.rest_length.end());
    lengths[0] = 1e9f;
    overwrite(dir / "length.h5", "springs/rest_length", lengths, H5T_NATIVE_FLOAT);
    EXPECT_NE(refusal(dir / "length.h5").find("springs/rest_length: entry 0 is 1e+09 mm, outside the plausible range"), std::string::npos)
        << refusal(dir / "length.h5");
}

TEST(Scenario, ASourceDefectOfNoPlausibleSizeOrOutsideItsLabelMapIsRefused) {
    // A scenario's /source records the septal defect heartprep carved: its diameter within the
    // range heartprep carves, its centre inside the label map it was carved into. A tampered one
    // (1e9 mm wide, or 1e9 mm away) would have plan-repair lay a patch the size of a city.
    test::TempDir dir;
    Scenario s = sample_scenario();
    const VolumeGeometry& g = s.source.geometry;
    s.source.defect = "vsd";
    s.source.defect_axis = Eigen::Vector3d(1, 0, 0);
    s.source.defect_diameter_mm = 4.0;
    // The last voxel's centre along each axis, and half a voxel beyond it: the box's corner.
    const Eigen::Vector3d last(g.dims[0] - 1, g.dims[1] - 1, g.dims[2] - 1);
    s.source.defect_centre = g.to_world(last + Eigen::Vector3d(0.45, 0.45, 0.45));
    write_scenario(dir / "corner.h5", s);
    EXPECT_EQ(read_scenario(dir / "corner.h5").source.defect_centre, s.source.defect_centre);
    auto refused = [&](const Scenario& tampered, const std::string& name, const std::string& words) {
        write_scenario(dir / name, tampered);
        const std::string why = refusal(dir / name);
        EXPECT_NE(why.find("/source"), std::string::npos) << why;
        EXPECT_NE(why.find(words), std::string::npos) << why;
    };
    for (const auto& [diameter, printed] : {std::pair{1e9, "1e+09"}, std::pair{0.1, "0.1"}, std::pair{61.0, "61"}}) {
        Scenario wide = s;
        wide.source.defect_diameter_mm = diameter;
        refused(wide, "diameter.h5", std::string("defect_diameter_mm is ") + printed + " mm, outside the plausible range");
    }
    for (const Eigen::Vector3d& ijk : {Eigen::Vector3d(last.x() + 0.55, 0, 0), Eigen::Vector3d(0, -0.55, 0),
                                       Eigen::Vector3d(0, 0, 1e9 / g.spacing.z())}) {
        Scenario away = s;
        away.source.defect_centre = g.to_world(ijk);
        refused(away, "away.h5", "lies outside the label map it was carved into");
    }
}

TEST(Scenario, HdfPrintsNothingOfItsOwnOnAnyThread) {
    // A refusal is one message of ours, whichever thread reads: HDF5's own error stack, which it
    // prints per thread unless told not to on that thread, never reaches standard error.
    test::TempDir dir;
    write_scenario(dir / "whole.h5", sample_scenario());
    EXPECT_NO_THROW(read_scenario(dir / "whole.h5"));  // this thread has read a file
    // One flipped bit in the stored masses: HDF5 itself fails the chunk's checksum.
    write_scenario(dir / "flipped.h5", sample_scenario());
    flip_a_stored_mass_bit(dir / "flipped.h5");
    std::fflush(stderr);
    const int saved = dup(STDERR_FILENO);
    const int captured = open((dir / "stderr.txt").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ASSERT_GE(saved, 0);
    ASSERT_GE(captured, 0);
    dup2(captured, STDERR_FILENO);
    std::string message;
    std::thread([&] {
        try {
            read_scenario(dir / "flipped.h5");
        } catch (const InputError& e) {
            message = e.what();
        }
    }).join();
    std::fflush(stderr);
    dup2(saved, STDERR_FILENO);
    close(saved), close(captured);
    EXPECT_NE(message.find("particles/mass"), std::string::npos) << message;
    std::ifstream in(dir / "stderr.txt");
    const std::string printed((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(printed, "") << "HDF5 printed on the reading thread";
}

TEST(Scenario, StringsAreStoredFixedLengthInTheChecksummedObjectHeaders) {
    // fuzz_scenario: a damaged global heap (where HDF5 keeps variable-length strings, under no
    // checksum) made HDF5 1.10's H5HG_read copy as many bytes as the heap claimed, out of bounds.
    // Strings are now fixed-length, stored in the object headers the 1.8 format checksums; they
    // read back whole, the empty ones included.
    test::TempDir dir;
    const auto file = dir / "s.h5";
    Scenario s = sample_scenario();
    s.generator = "heartprep 0.1.0, with an ünïcode name";
    s.batch_key = "";
    s.source.file_name = "";
    write_scenario(file, s);
    {
        hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
        ASSERT_GE(f, 0);
        for (const auto& [object, name] : {std::pair{"/", "format"}, {"/", "generator"}, {"/source", "file_name"}}) {
            hid_t a = H5Aopen_by_name(f, object, name, H5P_DEFAULT, H5P_DEFAULT);
            hid_t t = H5Aget_type(a);
            EXPECT_EQ(H5Tget_class(t), H5T_STRING) << object << " " << name;
            EXPECT_EQ(H5Tis_variable_str(t), 0) << object << " " << name << " is a variable-length string";
            H5Tclose(t);
            H5Aclose(a);
        }
        hid_t d = H5Dopen2(f, "/materials/name", H5P_DEFAULT);
        hid_t t = H5Dget_type(d);
        EXPECT_EQ(H5Tis_variable_str(t), 0) << "/materials/name is a variable-length string";
        H5Tclose(t);
        H5Dclose(d);
        H5Fclose(f);
    }
    const Scenario back = read_scenario(file);
    EXPECT_EQ(back.generator, s.generator);
    EXPECT_EQ(back.source.file_name, "");
    ASSERT_EQ(back.lattice.materials.size(), s.lattice.materials.size());
    for (std::size_t m = 0; m < s.lattice.materials.size(); ++m) EXPECT_EQ(back.lattice.materials[m].name, s.lattice.materials[m].name);
}

namespace {

/// A file as heartsim wrote them before strings were fixed-length: root attribute `format` a
/// variable-length string (kept in the global heap).
void write_variable_length_format(const std::filesystem::path& path) {
    hid_t file = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, H5T_VARIABLE);
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t attribute = H5Acreate2(file, "format", type, space, H5P_DEFAULT, H5P_DEFAULT);
    const char* value = "heartsim.scenario";
    H5Awrite(attribute, type, &value);
    H5Aclose(attribute);
    H5Sclose(space);
    H5Tclose(type);
    H5Fclose(file);
}

}  // namespace

TEST(Scenario, ADamagedGlobalHeapIsRefusedBeforeHdf5ReadsAVariableLengthString) {
    // fuzz_scenario / fuzz_recording on files with variable-length strings: HDF5 1.10 looped forever
    // on a global heap whose free-space object has size 0, and copied out of bounds from an object
    // larger than its collection. Such files (written before this change) are still read, once
    // their heaps are walked and found sound.
    test::TempDir dir;
    const auto file = dir / "old.h5";
    write_variable_length_format(file);
    std::vector<unsigned char> bytes;
    {
        std::ifstream in(file, std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    EXPECT_EQ(h5::global_heap_problem(file), "");
    const std::string intact = refusal(file);
    EXPECT_EQ(intact.find("global heap"), std::string::npos) << intact;
    EXPECT_NE(intact.find("format_version"), std::string::npos) << "the format string was not read: " << intact;

    const std::string signature("GCOL\1\0\0\0", 8);
    const auto at = std::search(bytes.begin(), bytes.end(), signature.begin(), signature.end());
    ASSERT_NE(at, bytes.end()) << "no global heap collection in the file";
    const std::size_t heap = std::size_t(at - bytes.begin());
    auto patched = [&](std::size_t offset, std::uint64_t size, const char* name) {
        std::vector<unsigned char> copy = bytes;
        for (int i = 0; i < 8; ++i) copy[offset + 8 + std::size_t(i)] = static_cast<unsigned char>(size >> (8 * i));
        const auto path = dir / name;
        test::write_bytes(path, copy);
        return path;
    };
    // The first object (the string) claims 10^12 bytes; then the first object is made the free
    // space (index 0) of size 0.
    const auto huge = patched(heap + 16, 1000000000000ull, "huge.h5");
    EXPECT_NE(refusal(huge).find("global heap collection at byte " + std::to_string(heap)), std::string::npos) << refusal(huge);
    std::vector<unsigned char> zero = bytes;
    zero[heap + 16] = zero[heap + 17] = 0;
    for (int i = 0; i < 8; ++i) zero[heap + 24 + std::size_t(i)] = 0;
    test::write_bytes(dir / "zero.h5", zero);
    EXPECT_NE(refusal(dir / "zero.h5").find("does not fit in it"), std::string::npos) << refusal(dir / "zero.h5");
}

TEST(Scenario, AChunkIndexRecordClaimingGigabytesIsRefusedBeforeHdf5Allocates) {
    // fuzz_scenario, fuzz_recording: the chunk index of the 1.8 format is a version-1 B-tree,
    // outside every checksum; a record claiming a 4 GiB chunk made HDF5 1.10 allocate 4 GiB before
    // reading it. The record is found by the chunk's address (H5Dget_chunk_info) that follows its
    // key: chunk size (4 bytes), filter mask (4), offsets (rank + 1 of 8).
    test::TempDir dir;
    write_scenario(dir / "s.h5", sample_scenario());
    const auto [address, stored] = mass_chunk(dir / "s.h5");
    std::vector<unsigned char> bytes;
    {
        std::ifstream in(dir / "s.h5", std::ios::binary);
        bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    std::string pointer(8, '\0');
    for (int i = 0; i < 8; ++i) pointer[std::size_t(i)] = char((address >> (8 * i)) & 0xff);
    std::size_t found = 0, record = 0;
    for (auto it = bytes.begin(); (it = std::search(it, bytes.end(), pointer.begin(), pointer.end())) != bytes.end(); ++it) {
        const std::size_t at = std::size_t(it - bytes.begin());
        if (at < 24) continue;
        const std::size_t size_at = at - 24;  // rank 1: two offsets, a mask, the size
        std::uint32_t size = 0;
        std::memcpy(&size, &bytes[size_at], 4);
        if (size == stored) ++found, record = size_at;
    }
    ASSERT_EQ(found, 1u) << "the chunk's index record was not found";
    const std::uint32_t claimed = 0xFF000008u;
    std::memcpy(&bytes[record], &claimed, 4);
    test::write_bytes(dir / "claims.h5", bytes);
    EXPECT_NE(refusal(dir / "claims.h5").find("particles/mass: chunk 0 claims 4278190088 bytes"), std::string::npos)
        << refusal(dir / "claims.h5");
    // A record of 0 bytes: HDF5 reports the empty buffer as a failed allocation, which read as
    // "out of memory" (std::bad_alloc out of the reader) before zero-byte chunks were refused.
    const std::uint32_t nothing = 0;
    std::memcpy(&bytes[record], &nothing, 4);
    test::write_bytes(dir / "empty.h5", bytes);
    try {
        read_scenario(dir / "empty.h5");
        ADD_FAILURE() << "a zero-byte chunk was read";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("particles/mass: chunk 0 claims 0 bytes"), std::string::npos) << e.what();
    }
    // Three bytes of a Fletcher-32-checksummed chunk: HDF5 checksummed 2^64 - 1 of them (SEGV).
    const std::uint32_t three = 3;
    std::memcpy(&bytes[record], &three, 4);
    test::write_bytes(dir / "three.h5", bytes);
    EXPECT_NE(refusal(dir / "three.h5").find("particles/mass: chunk 0 claims 3 bytes"), std::string::npos) << refusal(dir / "three.h5");
    // An uncompressed chunk 4 bytes short: HDF5 copied the whole chunk out of the shorter one.
    const std::uint32_t short_by_four = std::uint32_t(stored - 4);
    std::memcpy(&bytes[record], &short_by_four, 4);
    test::write_bytes(dir / "short.h5", bytes);
    EXPECT_NE(refusal(dir / "short.h5").find("particles/mass: chunk 0 claims " + std::to_string(stored - 4) + " bytes"), std::string::npos)
        << refusal(dir / "short.h5");
}

// A material's Poisson's ratio (/materials/poisson_ratio, docs/scenario-format.md): a file of springs
// alone does not write it and reads as 1/4, as every older file does; one declared above 1/4 comes
// back as written with the face springs of k = E·h/(2(1 + ν)); one outside [0.25, 0.499] is refused
// naming the dataset and the row.
TEST(Scenario, APoissonRatioRoundTripsAFileWithoutOneReadsAsOneQuarterAndOneOutOfRangeIsRefused) {
    test::TempDir dir;
    Scenario s = sample_scenario();
    ASSERT_EQ(s.lattice.materials[0].poisson_ratio, 0.25);
    write_scenario(dir / "springs.h5", s);
    EXPECT_EQ(read_scenario(dir / "springs.h5").lattice.materials[0].poisson_ratio, 0.25);
    s.lattice.materials[0].poisson_ratio = 0.45;
    write_scenario(dir / "nu.h5", s);
    const Scenario r = read_scenario(dir / "nu.h5");
    EXPECT_FLOAT_EQ(float(r.lattice.materials[0].poisson_ratio), 0.45f);
    EXPECT_FLOAT_EQ(float(r.lattice.materials[0].youngs_modulus_kpa), float(s.lattice.materials[0].youngs_modulus_kpa));
    EXPECT_NEAR(spring_stiffness(s.lattice.materials[0].youngs_modulus_kpa, s.lattice.spacing, 0.45),
                1e-3 * s.lattice.materials[0].youngs_modulus_kpa * s.lattice.spacing / 2.9, 1e-12);
    for (const float bad : {0.5f, 0.2f}) {
        write_scenario(dir / "bad.h5", s);
        overwrite(dir / "bad.h5", "materials/poisson_ratio", std::vector<float>(s.lattice.materials.size(), bad), H5T_NATIVE_FLOAT);
        const std::string message = refusal(dir / "bad.h5");
        EXPECT_NE(message.find("materials/poisson_ratio"), std::string::npos) << message;
        EXPECT_NE(message.find("row 0"), std::string::npos) << message;
    }
}
