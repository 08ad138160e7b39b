// The one HDF5 layer of formats/ (hdf5_io.h) through HDF5's C API.
#include "hdf5_io.h"

#include "atomic_file.h"
#include "xdmf.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <mutex>
#include <new>

namespace heartsim::h5 {

namespace {

/// HDF5 prints its own error stack by default; every caller reports its own message instead.
/// A thread-safe HDF5 keeps that setting per thread (a recording written on the window's
/// simulation thread would print the stack), so each thread turns it off once.
void quiet() {
    thread_local bool done = false;
    if (!done) H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr), done = true;
}

/// Whether the HDF5 call that just failed could not allocate memory (its error stack records
/// "no space available for allocation" or "can't allocate space"): a full memory, not a damaged
/// file. HDF5 clears the stack when the next API call starts, and H5Ewalk2 does not.
bool allocation_failed() {
    bool found = false;
    H5Ewalk2(
        H5E_DEFAULT, H5E_WALK_DOWNWARD,
        [](unsigned, const H5E_error2_t* entry, void* data) -> herr_t {
            if (entry->min_num == H5E_NOSPACE || entry->min_num == H5E_CANTALLOC) *static_cast<bool*>(data) = true;
            return 0;
        },
        &found);
    return found;
}

/// An object path for messages: "/" for the root, "/source" for "source".
std::string object_name(const std::string& object) {
    if (!object.empty() && object[0] == '/') return object;
    std::string name = "/";  // built by appends: GCC 12 warns (-Wrestrict, a false positive) on "/" + std::string
    name += object;
    return name;
}

/// Fixed-length UTF-8 strings of `width` bytes (at least 1), padded with zeros. Not variable-length:
/// those live in HDF5's global heap, which the file format does not checksum, and HDF5 1.10's
/// H5HG_read copies as many bytes as a damaged heap claims (fuzz_scenario found it); fixed-length
/// strings sit in the object headers, which are checksummed.
Handle utf8_string_type(std::size_t width) {
    Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(type.get(), std::max<std::size_t>(width, 1));
    H5Tset_strpad(type.get(), H5T_STR_NULLPAD);
    H5Tset_cset(type.get(), H5T_CSET_UTF8);
    return type;
}

Handle dataspace(std::initializer_list<std::size_t> dims) {
    if (dims.size() == 0) return Handle(H5Screate(H5S_SCALAR), H5Sclose);
    std::vector<hsize_t> d(dims.begin(), dims.end());
    return Handle(H5Screate_simple(int(d.size()), d.data(), nullptr), H5Sclose);
}

/// Whether `count` values of `type` at `data` are all finite (integers always are).
bool all_finite(const ElementType& type, const void* data, std::size_t count) {
    if (!type.floating || !data) return true;
    for (std::size_t i = 0; i < count; ++i) {
        const double v = type.size == 4 ? double(static_cast<const float*>(data)[i]) : static_cast<const double*>(data)[i];
        if (!std::isfinite(v)) return false;
    }
    return true;
}

std::string shape_text(const std::vector<long>& shape) {
    std::string text = "[";
    for (std::size_t i = 0; i < shape.size(); ++i) {
        if (i) text += ",";
        text += shape[i] < 0 ? std::string("N") : std::to_string(shape[i]);
    }
    return text + "]";
}

}  // namespace

std::uint32_t lookup3(const unsigned char* k, std::size_t length) {
    // Bob Jenkins' lookup3 hashlittle, byte by byte (the same on every endianness), initval 0.
    auto rot = [](std::uint32_t x, int r) { return (x << r) | (x >> (32 - r)); };
    std::uint32_t a, b, c;
    a = b = c = 0xdeadbeefu + std::uint32_t(length);
    auto word = [&](std::size_t at, std::size_t count) {
        std::uint32_t w = 0;
        for (std::size_t i = 0; i < count; ++i) w += std::uint32_t(k[at + i]) << (8 * i);
        return w;
    };
    while (length > 12) {
        a += word(0, 4), b += word(4, 4), c += word(8, 4);
        a -= c, a ^= rot(c, 4), c += b;
        b -= a, b ^= rot(a, 6), a += c;
        c -= b, c ^= rot(b, 8), b += a;
        a -= c, a ^= rot(c, 16), c += b;
        b -= a, b ^= rot(a, 19), a += c;
        c -= b, c ^= rot(b, 4), b += a;
        length -= 12, k += 12;
    }
    if (length == 0) return c;
    a += word(0, std::min<std::size_t>(length, 4));
    if (length > 4) b += word(4, std::min<std::size_t>(length - 4, 4));
    if (length > 8) c += word(8, length - 8);
    c ^= b, c -= rot(b, 14);
    a ^= c, a -= rot(c, 11);
    b ^= a, b -= rot(a, 25);
    c ^= b, c -= rot(b, 16);
    a ^= c, a -= rot(c, 4);
    b ^= a, b -= rot(a, 14);
    c ^= b, c -= rot(b, 24);
    return c;
}

void repair_superblock_checksum(std::vector<unsigned char>& image) {
    // Superblock versions 2 and 3: signature (8), version, size of offsets O, size of lengths,
    // status flags, four addresses of O bytes, then the lookup3 checksum of all before it.
    if (image.size() < 12 || (image[8] != 2 && image[8] != 3)) return;
    const std::size_t covered = 12 + 4 * std::size_t(image[9]);
    if (image.size() < covered + 4) return;
    const std::uint32_t sum = lookup3(image.data(), covered);
    for (int i = 0; i < 4; ++i) image[covered + std::size_t(i)] = static_cast<unsigned char>(sum >> (8 * i));
}

// ---------------------------------------------------------------------------------------------
// Writing

void Writer::fail(const std::string& what) const {
    if (allocation_failed()) throw std::bad_alloc();
    throw OutputError(path_ + ": " + what);
}

void Writer::group(const std::string& name) {
    Handle g(H5Gcreate2(file_, name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
    if (!g.valid()) fail("cannot create group " + object_name(name));
}

void Writer::write_dataset(const std::string& name, const ElementType& type, const void* data, std::initializer_list<std::size_t> dims) {
    const std::size_t count = element_count(dims);
    // No heartsim file holds NaN or infinity: a non-finite value is a diverged simulation or a bug,
    // and is refused here rather than handed to the next reader.
    if (!all_finite(type, data, count)) fail("dataset " + name + " holds a non-finite value; nothing was written");
    Handle space = dataspace(dims);
    Handle properties(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
    if (count > 0 && dims.size() > 0) {
        // Chunks of about 64k elements, whole rows each, each with a Fletcher-32 checksum: a
        // flipped bit is a read error, not a different simulation.
        std::vector<hsize_t> chunk(dims.begin(), dims.end());
        const std::size_t row = count / chunk[0];
        chunk[0] = std::min<hsize_t>(chunk[0], std::max<hsize_t>(1, 65536 / row));
        H5Pset_chunk(properties.get(), int(chunk.size()), chunk.data());
        if (count >= 4096) {
            H5Pset_shuffle(properties.get());
            H5Pset_deflate(properties.get(), 1);
        }
        H5Pset_fletcher32(properties.get());
    }
    Handle set(H5Dcreate2(file_, name.c_str(), type.file, space.get(), H5P_DEFAULT, properties.get(), H5P_DEFAULT), H5Dclose);
    if (!set.valid()) fail("cannot create dataset " + name);
    if (count && H5Dwrite(set.get(), type.memory, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
        fail("cannot write dataset " + name);
}

void Writer::strings(const std::string& name, const std::vector<std::string>& values) {
    Handle space = dataspace({values.size()});
    std::size_t width = 1;
    for (const auto& v : values) width = std::max(width, v.size());
    Handle type = utf8_string_type(width);
    Handle set(H5Dcreate2(file_, name.c_str(), type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose);
    std::vector<char> text(values.size() * width, '\0');
    for (std::size_t i = 0; i < values.size(); ++i) std::memcpy(text.data() + i * width, values[i].data(), values[i].size());
    if (!set.valid() || (!values.empty() && H5Dwrite(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, text.data()) < 0))
        fail("cannot write dataset " + name);
}

void Writer::attribute(const std::string& object, const std::string& name, const std::string& value) {
    Handle type = utf8_string_type(value.size());
    Handle space = dataspace({});
    Handle attribute(H5Acreate_by_name(file_, object.c_str(), name.c_str(), type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
                     H5Aclose);
    std::string padded = value;
    padded.resize(std::max<std::size_t>(value.size(), 1), '\0');
    if (!attribute.valid() || H5Awrite(attribute.get(), type.get(), padded.data()) < 0)
        fail("cannot write attribute " + name + " of " + object_name(object));
}

void Writer::write_attribute(const std::string& object, const std::string& name, const ElementType& type, const void* values,
                             std::initializer_list<std::size_t> dims) {
    if (!all_finite(type, values, element_count(dims)))
        fail("attribute " + name + " of " + object_name(object) + " is not finite; nothing was written");
    Handle space = dataspace(dims);
    Handle attribute(H5Acreate_by_name(file_, object.c_str(), name.c_str(), type.file, space.get(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
                     H5Aclose);
    // An empty list is a zero-length attribute; H5Awrite still wants a non-null buffer.
    const std::int64_t unused = 0;
    if (!attribute.valid() || H5Awrite(attribute.get(), type.memory, values ? values : &unused) < 0)
        fail("cannot write attribute " + name + " of " + object_name(object));
}

void Writer::header(const std::string& format, int version, const std::string& units) {
    attribute("/", "format", format);
    attribute("/", "format_version", std::int32_t(version));
    attribute("/", "units", units);
    attribute("/", "frame", "LPS");
}

void write_file(const std::filesystem::path& path, const std::function<void(Writer&)>& fill,
                const std::function<void(const std::filesystem::path&)>& check, const std::vector<FileBeside>& beside) {
    quiet();
    const std::string name = path.string();
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        // The file is built in memory (HDF5's core driver, no backing store) and written out by
        // write_bytes below: HDF5 itself never writes to the disk, so a full disk is one clear
        // error here, never a library left holding a half-flushed file that crashes its exit
        // handler (as HDF5 1.10 did after a failed write).
        std::vector<unsigned char> image;
        {
            Handle access(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
            H5Pset_fapl_core(access.get(), 16 << 20, 0);
            // The 1.8 file format and later checksum the superblock and object headers, so
            // damaged metadata is refused too.
            H5Pset_libver_bounds(access.get(), H5F_LIBVER_V18, H5F_LIBVER_LATEST);
            Handle file(H5Fcreate(temporary.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, access.get()), H5Fclose);
            if (!file.valid()) {
                if (allocation_failed()) throw std::bad_alloc();
                throw OutputError(name + ": cannot create the file in memory");
            }
            Writer writer(file.get(), name);
            fill(writer);
            if (H5Fflush(file.get(), H5F_SCOPE_GLOBAL) < 0) writer.fail("cannot flush");
            const ssize_t size = H5Fget_file_image(file.get(), nullptr, 0);
            if (size <= 0) writer.fail("cannot take the file image");
            image.resize(std::size_t(size));
            if (H5Fget_file_image(file.get(), image.data(), image.size()) != size) writer.fail("cannot take the file image");
        }
        repair_superblock_checksum(image);
        write_bytes(temporary, image.data(), image.size(), name + ": cannot write the file");
        if (check) check(temporary);
    }, beside);
}

// ---------------------------------------------------------------------------------------------
// Reading

std::string global_heap_problem(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    static constexpr unsigned char signature[8] = {'G', 'C', 'O', 'L', 1, 0, 0, 0};
    auto u64 = [&](std::size_t at) {
        std::uint64_t v = 0;
        for (int i = 7; i >= 0; --i) v = (v << 8) | bytes[at + std::size_t(i)];
        return v;
    };
    auto where = [](std::size_t at) { return "global heap collection at byte " + std::to_string(at); };
    for (auto it = bytes.begin(); (it = std::search(it, bytes.end(), std::begin(signature), std::end(signature))) != bytes.end(); ++it) {
        const std::size_t start = std::size_t(it - bytes.begin());
        if (bytes.size() - start < 16) return where(start) + ": truncated";
        const std::uint64_t size = u64(start + 8);
        if (size < 4096 || size > bytes.size() - start) return where(start) + ": size " + std::to_string(size) + " outside the file";
        const std::size_t end = start + std::size_t(size);
        // Objects: index (2), references (2), reserved (4), size (8), data padded to 8 bytes; index 0
        // is the free space, whose size counts its own header. A tail under 16 bytes is free space.
        for (std::size_t at = start + 16; end - at >= 16;) {
            const unsigned index = unsigned(bytes[at]) | unsigned(bytes[at + 1]) << 8;
            const std::uint64_t object = u64(at + 8);
            const std::uint64_t need = index == 0 ? object : (object > size ? size + 1 : 16 + ((object + 7) & ~std::uint64_t(7)));
            if (need < 16 || need > end - at)
                return where(start) + ": object " + std::to_string(index) + " of " + std::to_string(object) + " bytes at byte " +
                       std::to_string(at) + " does not fit in it";
            at += std::size_t(need);
        }
    }
    return {};
}

void Reader::check_heaps_once() const {
    if (heaps_checked_) return;
    heaps_checked_ = true;
    const std::string problem = global_heap_problem(path_);
    if (!problem.empty()) fail("", "damaged file: " + problem + " (variable-length strings are not read from it)");
}

Reader::Reader(const std::filesystem::path& path) : path_(path.string()) {
    quiet();
    if (!std::filesystem::exists(path)) fail("", "file not found");
    // A FIFO or a device would block or never end: only regular files are read.
    if (!std::filesystem::is_regular_file(path)) fail("", "not a regular file");
    if (H5Fis_hdf5(path.c_str()) <= 0) {
        const std::string instead = xdmf_given_instead_of_h5(path);  // case.xmf2 given for case.h5
        fail("", "not an HDF5 file" + (instead.empty() ? std::string() : ": " + instead));
    }
    file_ = Handle(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
    if (!file_.valid()) fail("", "cannot open (damaged HDF5 file?)");
}

void Reader::fail(const std::string& where, const std::string& what) const {
    if (allocation_failed()) throw std::bad_alloc();
    throw InputError(path_ + ": " + (where.empty() ? "" : where + ": ") + what);
}

bool Reader::exists(const std::string& name) const {
    // H5Lexists wants every group on the way to exist: check each prefix in turn.
    for (std::size_t slash = name.find('/', 1); slash != std::string::npos; slash = name.find('/', slash + 1))
        if (H5Lexists(file_.get(), name.substr(0, slash).c_str(), H5P_DEFAULT) <= 0) return false;
    return H5Lexists(file_.get(), name.c_str(), H5P_DEFAULT) > 0;
}

bool Reader::has_attribute(const std::string& object, const std::string& name) const {
    return (object == "/" || exists(object)) && H5Aexists_by_name(file_.get(), object.c_str(), name.c_str(), H5P_DEFAULT) > 0;
}

int Reader::header(const std::string& format, int oldest, int newest, const std::string& units, const std::string& hint) const {
    const std::string found = string_attribute("/", "format");
    if (found != format) fail("/", "attribute format is '" + found + "', not " + format + (hint.empty() ? "" : " (" + hint + ")"));
    const int version = number<std::int32_t>("/", "format_version");
    if (version < oldest || version > newest)
        fail("/", "format_version " + std::to_string(version) + " is not supported (this build reads " +
                      (oldest == newest ? "version " + std::to_string(oldest)
                                        : "versions " + std::to_string(oldest) + " to " + std::to_string(newest)) +
                      "); use a matching heartsim");
    if (string_attribute("/", "units") != units) fail("/", "attribute units must be '" + units + "'");
    if (string_attribute("/", "frame") != "LPS") fail("/", "attribute frame must be 'LPS'");
    return version;
}

Handle Reader::open_dataset(const std::string& name) const {
    if (!exists(name)) fail(name, "missing dataset");
    Handle set(H5Dopen2(file_.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
    if (!set.valid()) fail(name, "is not a dataset");
    return set;
}

void Reader::check_chunks(hid_t set, const std::string& name, std::size_t element_size) const {
    // The chunk index of the 1.8 file format is a version-1 B-tree, which no checksum covers, and
    // HDF5 1.10 allocates as many bytes as a record says a chunk holds before reading it
    // (fuzz_scenario: 4 GiB from a damaged record). Each chunk must lie inside the file and hold at
    // most what its values take, plus what deflate adds to data it cannot compress.
    Handle create(H5Dget_create_plist(set), H5Pclose);
    if (H5Pget_layout(create.get()) != H5D_CHUNKED) {
        // Contiguous or compact: HDF5 copies the declared size out of what is stored (fuzz_recording:
        // a heap-buffer-overflow in H5VM_memcpyvv), so what is stored must be all of it, or nothing
        // (never written: fill values).
        const hsize_t stored = H5Dget_storage_size(set);
        hssize_t values = 0;
        {
            Handle space(H5Dget_space(set), H5Sclose);
            values = H5Sget_simple_extent_npoints(space.get());
        }
        if (stored != 0 && stored != hsize_t(values) * element_size)
            fail(name, "stores " + std::to_string(stored) + " bytes for " + std::to_string(values) + " values of " +
                           std::to_string(element_size) + " bytes (damaged file?)");
        return;
    }
    hsize_t chunk[H5S_MAX_RANK] = {};
    const int rank = H5Pget_chunk(create.get(), H5S_MAX_RANK, chunk);
    if (rank <= 0) fail(name, "chunked without chunk dimensions (damaged file?)");
    double values = 1.0;
    for (int d = 0; d < rank; ++d) values *= double(chunk[d]);
    const double most = values * double(element_size) * (1.0 + 1.0 / 64.0) + 1024.0;
    // HDF5 1.10's Fletcher-32 filter checksums a chunk's size minus 4 bytes: a smaller chunk wraps
    // that to nearly 2^64 and reads off the end (fuzz_scenario, fuzz_recording: SEGV in
    // H5_checksum_fletcher32). A checksummed chunk holds 4 bytes of checksum and at least one of data.
    bool checksummed = false, other_filters = false;
    for (int f = 0, n = H5Pget_nfilters(create.get()); f < n; ++f) {
        unsigned flags = 0, config = 0;
        std::size_t elements = 0;
        const H5Z_filter_t filter = H5Pget_filter2(create.get(), unsigned(f), &flags, &elements, nullptr, 0, nullptr, &config);
        if (filter == H5Z_FILTER_FLETCHER32) checksummed = true;
        else other_filters = true;
    }
    const hsize_t least = checksummed ? 5 : 1;
    // Without compression a chunk is exactly its values (and the checksum): HDF5 copies a whole
    // chunk out of a shorter one (fuzz_recording: a heap-buffer-overflow in H5VM_memcpyvv, where a
    // truncated all-zero chunk still matched its Fletcher-32 sum of zero).
    const hsize_t exact = other_filters ? 0 : hsize_t(values) * element_size + (checksummed ? 4 : 0);
    hsize_t chunks = 0, file_size = 0;
    Handle space(H5Dget_space(set), H5Sclose);  // HDF5 1.10 takes no H5S_ALL here
    if (H5Dget_num_chunks(set, space.get(), &chunks) < 0 || H5Fget_filesize(file_.get(), &file_size) < 0)
        fail(name, "its chunk index cannot be read (damaged file?)");
    for (hsize_t i = 0; i < chunks; ++i) {
        hsize_t offset[H5S_MAX_RANK] = {}, size = 0;
        unsigned filters = 0;
        haddr_t address = 0;
        if (H5Dget_chunk_info(set, space.get(), i, offset, &filters, &address, &size) < 0)
            fail(name, "chunk " + std::to_string(i) + " cannot be located (damaged file?)");
        // A zero-byte chunk: HDF5 reports its empty buffer as a failed allocation (which would read as
        // out of memory); a checksummed one under 5 bytes: the Fletcher-32 overrun above.
        if (size < least || (exact && size != exact) || double(size) > most || address == HADDR_UNDEF || address > file_size || size > file_size - address)
            fail(name, "chunk " + std::to_string(i) + " claims " + std::to_string(size) + " bytes at byte " + std::to_string(address) +
                           " of a " + std::to_string(file_size) + "-byte file (damaged file?)");
    }
}

void Reader::read_dataset(const std::string& name, const ElementType& type, std::initializer_list<long> shape, std::size_t* rows,
                          const std::function<void*(std::size_t)>& allocate) const {
    const Handle set = open_dataset(name);
    {
        Handle stored(H5Dget_type(set.get()), H5Tclose);
        const H5T_class_t type_class = H5Tget_class(stored.get());
        const std::size_t size = H5Tget_size(stored.get());
        const bool ok = size == type.size &&
                        (type.floating ? type_class == H5T_FLOAT
                                       : type_class == H5T_INTEGER && (H5Tget_sign(stored.get()) != H5T_SGN_NONE) == type.is_signed);
        if (!ok) {
            const std::string found = type_class == H5T_FLOAT ? "float" : type_class == H5T_INTEGER ? "integer" : "non-numeric";
            fail(name, "has element type " + found + std::to_string(8 * size) + ", expected " + type.name);
        }
    }
    const std::vector<long> expected(shape);
    Handle space(H5Dget_space(set.get()), H5Sclose);
    const int rank = H5Sget_simple_extent_ndims(space.get());
    if (rank != int(expected.size())) fail(name, "has rank " + std::to_string(rank) + ", expected shape " + shape_text(expected));
    std::vector<hsize_t> dims(expected.size());
    H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
    std::vector<long> found(dims.begin(), dims.end());
    for (std::size_t i = 0; i < expected.size(); ++i)
        if (expected[i] >= 0 && found[i] != expected[i]) fail(name, "has shape " + shape_text(found) + ", expected " + shape_text(expected));
    std::size_t count = 1;
    for (hsize_t d : dims) count *= std::size_t(d);
    // The declared size against what the file holds, before allocating: deflate compresses at
    // most about 1032:1, so a dataset declaring far more than that over its stored bytes is
    // damaged or crafted (unwritten, sparse), and would otherwise cost its declared size in memory.
    const double declared = double(count) * double(type.size);
    const double stored = double(H5Dget_storage_size(set.get()));
    if (declared > 1100.0 * stored + 65536.0)
        fail(name, "declares " + shape_text(found) + " values (" + std::to_string(std::uint64_t(declared)) + " bytes) but the file stores " +
                       std::to_string(std::uint64_t(stored)) + " bytes of them (damaged file?)");
    check_chunks(set.get(), name, type.size);
    void* data = allocate(count);
    if (count && H5Dread(set.get(), type.memory, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
        fail(name, "cannot be read (damaged file: a checksum or the compressed data does not match)");
    if (rows) *rows = dims.empty() ? 1 : std::size_t(dims[0]);
}

std::vector<std::string> Reader::strings(const std::string& name, long rows) const {
    const Handle set = open_dataset(name);
    Handle type(H5Dget_type(set.get()), H5Tclose);
    if (H5Tget_class(type.get()) != H5T_STRING) fail(name, "expected strings");
    Handle space(H5Dget_space(set.get()), H5Sclose);
    if (H5Sget_simple_extent_ndims(space.get()) != 1) fail(name, "expected a one-dimensional dataset");
    hsize_t dims[1] = {0};
    H5Sget_simple_extent_dims(space.get(), dims, nullptr);
    if (rows >= 0 && dims[0] != hsize_t(rows)) fail(name, "has " + std::to_string(dims[0]) + " entries, expected " + std::to_string(rows));
    const std::size_t n = std::size_t(dims[0]);
    std::vector<std::string> values;
    if (H5Tis_variable_str(type.get()) > 0) {
        check_heaps_once();
        std::vector<char*> pointers(n, nullptr);
        if (n && H5Dread(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0) fail(name, "cannot be read");
        for (char* p : pointers) values.emplace_back(p ? p : "");
        if (n) H5Dvlen_reclaim(type.get(), space.get(), H5P_DEFAULT, pointers.data());
        return values;
    }
    const std::size_t width = H5Tget_size(type.get());
    std::vector<char> text(n * width, '\0');
    if (n && H5Dread(set.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, text.data()) < 0) fail(name, "cannot be read");
    for (std::size_t i = 0; i < n; ++i) {
        const char* begin = text.data() + i * width;
        values.emplace_back(begin, std::find(begin, begin + width, '\0'));
    }
    return values;
}

Handle Reader::open_attribute(const std::string& object, const std::string& name) const {
    if (object != "/" && !exists(object)) fail(object_name(object), "missing");
    if (H5Aexists_by_name(file_.get(), object.c_str(), name.c_str(), H5P_DEFAULT) <= 0)
        fail(object_name(object), "attribute " + name + " missing");
    Handle attribute(H5Aopen_by_name(file_.get(), object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid()) fail(object_name(object), "attribute " + name + " cannot be opened");
    return attribute;
}

std::string Reader::string_attribute(const std::string& object, const std::string& name) const {
    const std::string owner = object_name(object);
    Handle attribute = open_attribute(object, name);
    Handle type(H5Aget_type(attribute.get()), H5Tclose);
    if (H5Tget_class(type.get()) != H5T_STRING) fail(owner, "attribute " + name + " is not a string");
    {  // one string only: H5Aread writes every element into the buffer
        Handle space(H5Aget_space(attribute.get()), H5Sclose);
        if (H5Sget_simple_extent_npoints(space.get()) != 1) fail(owner, "attribute " + name + " must be a single string");
    }
    if (H5Tis_variable_str(type.get()) > 0) {
        check_heaps_once();
        char* value = nullptr;
        Handle memory(H5Tcopy(H5T_C_S1), H5Tclose);
        H5Tset_size(memory.get(), H5T_VARIABLE);
        H5Tset_cset(memory.get(), H5Tget_cset(type.get()));
        if (H5Aread(attribute.get(), memory.get(), &value) < 0) fail(owner, "attribute " + name + " cannot be read");
        std::string result = value ? value : "";
        H5free_memory(value);
        return result;
    }
    std::string value(H5Tget_size(type.get()), '\0');
    if (H5Aread(attribute.get(), type.get(), value.data()) < 0) fail(owner, "attribute " + name + " cannot be read");
    return value.substr(0, value.find('\0'));
}

void Reader::read_attribute(const std::string& object, const std::string& name, const ElementType& type, long count,
                            const std::function<void*(std::size_t)>& allocate) const {
    const std::string owner = object_name(object);
    Handle attribute = open_attribute(object, name);
    {
        Handle stored(H5Aget_type(attribute.get()), H5Tclose);
        const H5T_class_t type_class = H5Tget_class(stored.get());
        if (type_class != H5T_INTEGER && type_class != H5T_FLOAT) fail(owner, "attribute " + name + " is not numeric");
    }
    // The count is checked before reading: H5Aread writes every element of the attribute.
    Handle space(H5Aget_space(attribute.get()), H5Sclose);
    const hssize_t n = H5Sget_simple_extent_npoints(space.get());
    if (count == 1 && n != 1) fail(owner, "attribute " + name + " must be a single value");
    if (count >= 0 && n != count)
        fail(owner, "attribute " + name + " has " + std::to_string(n) + " values, expected " + std::to_string(count));
    void* data = allocate(std::size_t(std::max<hssize_t>(n, 0)));
    if (n > 0 && H5Aread(attribute.get(), type.memory, data) < 0) fail(owner, "attribute " + name + " cannot be read (expected numbers)");
}

}  // namespace heartsim::h5
