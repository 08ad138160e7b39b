// The libFuzzer targets' shared helpers (fuzz_support.h).
#include "fuzz_support.h"

#include <cstdio>
#include <cstdlib>
#include <fcntl.h>
#include <system_error>
#include <unistd.h>

namespace heartsim::fuzz {

namespace {

const std::filesystem::path& folder() {
    static const std::filesystem::path path = [] {
        std::filesystem::path p = std::filesystem::path("/dev/shm") / ("heartsim-fuzz-" + std::to_string(::getpid()));
        std::filesystem::create_directories(p);
        std::atexit([] {
            std::error_code ignored;
            std::filesystem::remove_all(folder(), ignored);
        });
        return p;
    }();
    return path;
}

}  // namespace

std::filesystem::path write_input(const std::uint8_t* data, std::size_t size, const std::string& name) {
    const std::filesystem::path path = folder() / name;
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (fd < 0) {  // the folder was removed under us (a cleanup of /dev/shm): make it again
        std::error_code ignored;
        std::filesystem::create_directories(folder(), ignored);
        fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    }
    if (fd < 0) broken("cannot create " + path.string());
    for (std::size_t done = 0; done < size;) {
        const ssize_t n = ::write(fd, data + done, size - done);
        if (n <= 0) broken("cannot write " + path.string());
        done += std::size_t(n);
    }
    ::close(fd);
    return path;
}

void broken(const std::string& what) {
    std::fprintf(stderr, "fuzz target: %s\n", what.c_str());
    std::abort();
}

}  // namespace heartsim::fuzz
