// Atomic writes (atomic_file.h).
#include "atomic_file.h"

#include "libmodel/errors.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <system_error>

namespace heartsim {

namespace {

/// ".<name>.tmp-": what every temporary of `path` starts with. A file name may take 255 bytes;
/// the process id, counter and extension after this prefix take at most 46, so a name longer
/// than 203 bytes is shortened to its first 194 and a hash of the whole (FNV-1a, 8 hex digits):
/// a legal 255-byte output name still gets a temporary, and the same one on every run.
std::string temporary_prefix(const std::filesystem::path& path) {
    constexpr std::size_t longest = 203, kept = 194;
    std::string name = path.filename().string();
    if (name.size() > longest) {
        std::uint32_t hash = 2166136261u;
        for (unsigned char c : name) hash = (hash ^ c) * 16777619u;
        static const char* digits = "0123456789abcdef";
        std::string tail = "~";
        for (int shift = 28; shift >= 0; shift -= 4) tail += digits[(hash >> shift) & 15u];
        name = name.substr(0, kept) + tail;
    }
    std::string prefix = ".";  // built by appends: GCC 12 warns (-Wrestrict, a false positive) on "." + std::string&&
    prefix += name;
    prefix += ".tmp-";
    return prefix;
}

}  // namespace

std::filesystem::path temporary_beside(const std::filesystem::path& path, const std::string& extension) {
    static std::atomic<unsigned> counter{0};
    std::string name = temporary_prefix(path);
    name += std::to_string(::getpid()) + "-" + std::to_string(counter++);
    name += extension.size() <= 24 ? extension : extension.substr(extension.size() - 24);
    return path.parent_path() / name;
}

std::filesystem::path temporary_beside(const std::filesystem::path& path) { return temporary_beside(path, path.extension().string()); }

namespace {

/// fsync of an existing file or folder; false when it fails.
bool sync_to_disk(const std::filesystem::path& path, int flags) {
    const int fd = ::open(path.c_str(), flags | O_CLOEXEC);
    if (fd < 0) return false;
    const bool synced = ::fsync(fd) == 0;
    return ::close(fd) == 0 && synced;
}

}  // namespace

void sweep_stale_temporaries(const std::filesystem::path& path) {
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    const std::string prefix = temporary_prefix(path);
    std::error_code error;
    for (std::filesystem::directory_iterator it(folder, error), end; !error && it != end; it.increment(error)) {
        const std::string name = it->path().filename().string();
        if (name.compare(0, prefix.size(), prefix) != 0) continue;
        // .<name>.tmp-<pid>-<counter>[extension]: stale when no process <pid> exists any more.
        char* rest = nullptr;
        const long pid = std::strtol(name.c_str() + prefix.size(), &rest, 10);
        if (pid <= 0 || !rest || *rest != '-') continue;
        if (::kill(pid_t(pid), 0) == 0 || errno != ESRCH) continue;
        std::error_code ignored;
        std::filesystem::remove_all(it->path(), ignored);
    }
}

namespace {

/// check_destination without the trial file: what write_file_atomically checks before it creates
/// its own temporary file, which is the trial.
void check_destination_folder(const std::filesystem::path& path) {
    namespace fs = std::filesystem;
    const auto folder = path.parent_path().empty() ? fs::path(".") : path.parent_path();
    std::error_code error;
    if (path.filename().empty() || fs::is_directory(path, error))
        throw OutputError(path.string() + ": is a folder, expected a file name");
    if (!fs::is_directory(folder, error)) {
        // Walk up to the part of the path that exists, to name what is in the way.
        fs::path existing = folder;
        while (!existing.empty() && existing != existing.root_path() && !fs::exists(existing, error)) existing = existing.parent_path();
        if (!existing.empty() && fs::exists(existing, error) && !fs::is_directory(existing, error))
            throw OutputError(path.string() + ": " + existing.string() + " is a file, not a folder");
        throw OutputError(path.string() + ": folder " + folder.string() + " does not exist");
    }
    if (::access(folder.c_str(), W_OK) != 0) throw OutputError(path.string() + ": folder " + folder.string() + " is not writable");
}

}  // namespace

void check_destination(const std::filesystem::path& path) {
    check_destination_folder(path);
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    // access() says yes to root almost everywhere (/proc, /sys); only creating a file there shows
    // that the folder takes one, before a run or a build that would end unable to save.
    // A short name of its own, so that a long destination name is not blamed on the folder.
    static std::atomic<unsigned> trials{0};
    const auto trial = folder / (".heartsim-trial-" + std::to_string(::getpid()) + "-" + std::to_string(trials++));
    const int fd = ::open(trial.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (fd < 0) {
        const std::string reason = std::strerror(errno);
        throw OutputError(path.string() + ": cannot create a file in folder " + folder.string() + ": " + reason);
    }
    ::close(fd);
    ::unlink(trial.c_str());
}

void write_file_atomically(const std::filesystem::path& path, const std::function<void(const std::filesystem::path&)>& fill,
                           const std::vector<FileBeside>& beside) {
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    check_destination_folder(path);
    for (const FileBeside& file : beside) check_destination_folder(file.path);
    sweep_stale_temporaries(path);
    for (const FileBeside& file : beside) sweep_stale_temporaries(file.path);
    const auto temporary = temporary_beside(path);
    std::vector<std::filesystem::path> temporaries;
    for (const FileBeside& file : beside) temporaries.push_back(temporary_beside(file.path));
    std::size_t renamed = 0;  // the temporaries of `beside` already in place
    try {
        fill(temporary);
        if (!sync_to_disk(temporary, O_RDONLY))
            throw OutputError(path.string() + ": cannot flush the finished file to the disk: " + std::strerror(errno));
        for (std::size_t k = 0; k < beside.size(); ++k) {
            const std::string failure = path.string() + ": cannot write " + beside[k].what + " " + beside[k].path.string();
            write_bytes(temporaries[k], beside[k].bytes.data(), beside[k].bytes.size(), failure);
            if (!sync_to_disk(temporaries[k], O_RDONLY)) throw OutputError(failure + " (cannot flush it: " + std::strerror(errno) + ")");
        }
        std::error_code error;
        std::filesystem::rename(temporary, path, error);
        if (error) throw OutputError(path.string() + ": cannot rename the finished file into place: " + error.message());
        for (; renamed < beside.size(); ++renamed) {
            std::filesystem::rename(temporaries[renamed], beside[renamed].path, error);
            if (error)
                throw OutputError(path.string() + " was written, but " + beside[renamed].what + " " + beside[renamed].path.string() +
                                  " could not be renamed into place: " + error.message());
        }
    } catch (...) {
        std::error_code ignored;
        std::filesystem::remove(temporary, ignored);
        for (std::size_t k = renamed; k < temporaries.size(); ++k) std::filesystem::remove(temporaries[k], ignored);
        throw;
    }
    // The rename itself reaches the disk with the folder; some file systems cannot sync a folder,
    // and the file is complete either way, so a failure here is not an error.
    sync_to_disk(folder, O_RDONLY | O_DIRECTORY);
}

void write_bytes(const std::filesystem::path& file, const void* data, std::size_t size, const std::string& failure) {
    const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) throw OutputError(failure + " (cannot create " + file.string() + ": " + std::strerror(errno) + ")");
    const char* bytes = static_cast<const char*>(data);
    std::size_t written = 0;
    while (written < size) {
        const ssize_t n = ::write(fd, bytes + written, size - written);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            const int reason = n < 0 ? errno : ENOSPC;
            ::close(fd);
            throw OutputError(failure + " (" + std::strerror(reason) + (disk_full(reason) ? "; disk full?" : "") + ")");
        }
        written += std::size_t(n);
    }
    // No fsync here: every caller writes a temporary that write_file_atomically flushes before the rename.
    if (::close(fd) != 0) throw OutputError(failure + " (" + std::strerror(errno) + ")");
}

bool disk_full(int error) { return error == ENOSPC || error == EDQUOT || error == EFBIG; }

void write_bytes_atomically(const std::filesystem::path& path, const void* data, std::size_t size, const std::string& what) {
    write_file_atomically(path, [&](const std::filesystem::path& temporary) {
        write_bytes(temporary, data, size, path.string() + ": cannot write " + what);
    });
}

bool same_file(const std::filesystem::path& a, const std::filesystem::path& b) {
    struct stat first {}, second {};
    if (::stat(a.c_str(), &first) == 0 && ::stat(b.c_str(), &second) == 0)
        return first.st_dev == second.st_dev && first.st_ino == second.st_ino;
    std::error_code error_a, error_b;
    const auto whole_a = std::filesystem::weakly_canonical(std::filesystem::absolute(a, error_a), error_a);
    const auto whole_b = std::filesystem::weakly_canonical(std::filesystem::absolute(b, error_b), error_b);
    return !error_a && !error_b && whole_a == whole_b;
}

void refuse_an_input_as_output(const std::string& output_name, const std::filesystem::path& output, const std::vector<InputFile>& inputs) {
    for (const InputFile& input : inputs)
        if (!input.path.empty() && same_file(output, input.path))
            throw OptionError(output_name + ": that is " + input.what + "; give another file");
}

}  // namespace heartsim
