// Atomic writes (atomic_file.h).
#include "atomic_file.h"

#include "libmodel/errors.h"

#include <unistd.h>

#include <atomic>
#include <fstream>
#include <system_error>

namespace heartsim {

std::filesystem::path temporary_beside(const std::filesystem::path& path, const std::string& extension) {
    static std::atomic<unsigned> counter{0};
    std::string name = ".";  // built by appends: GCC 12 warns (-Wrestrict, a false positive) on "." + std::string&&
    name += path.filename().string();
    name += ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
    name += extension;
    return path.parent_path() / name;
}

std::filesystem::path temporary_beside(const std::filesystem::path& path) { return temporary_beside(path, path.extension().string()); }

void write_file_atomically(const std::filesystem::path& path, const std::function<void(const std::filesystem::path&)>& fill) {
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    if (!std::filesystem::is_directory(folder)) throw OutputError(path.string() + ": folder " + folder.string() + " does not exist");
    if (::access(folder.c_str(), W_OK) != 0) throw OutputError(path.string() + ": folder " + folder.string() + " is not writable");
    const auto temporary = temporary_beside(path);
    try {
        fill(temporary);
        std::error_code error;
        std::filesystem::rename(temporary, path, error);
        if (error) throw OutputError(path.string() + ": cannot rename the finished file into place: " + error.message());
    } catch (...) {
        std::error_code ignored;
        std::filesystem::remove(temporary, ignored);
        throw;
    }
}

void write_bytes_atomically(const std::filesystem::path& path, const void* data, std::size_t size, const std::string& what) {
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
        if (!out) throw OutputError(path.string() + ": cannot write " + what + " (cannot create " + temporary.string() + ")");
        out.write(static_cast<const char*>(data), std::streamsize(size));
        out.flush();
        if (!out) throw OutputError(path.string() + ": cannot write " + what + " (disk full?)");
    });
}

}  // namespace heartsim
