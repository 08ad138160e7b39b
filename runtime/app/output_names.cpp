// The names of a run's unnamed outputs: output_names.h.
#include "runtime/app/output_names.h"

#include <cstdio>
#include <filesystem>

namespace heartsim {

std::string numbered_screenshot(const std::string& path, long long step) {
    const std::filesystem::path p(path);
    char suffix[32];
    std::snprintf(suffix, sizeof suffix, "-%06lld", step);
    return (p.parent_path() / (p.stem().string() + suffix + p.extension().string())).string();
}

std::string timestamped_path(const std::string& scenario, const std::tm& local_time, const std::string& ending) {
    const std::filesystem::path p(scenario);
    char stamp[32];
    std::strftime(stamp, sizeof stamp, "-%Y%m%d-%H%M%S", &local_time);
    // A name is taken when the file, or a recording's journal for it, exists.
    auto taken = [](const std::filesystem::path& path) {
        return std::filesystem::exists(path) || std::filesystem::exists(path.string() + ".journal");
    };
    std::filesystem::path path = p.parent_path() / (p.stem().string() + stamp + ending);
    for (int n = 2; taken(path); ++n)  // two in the same second: -2, -3, …
        path = p.parent_path() / (p.stem().string() + stamp + "-" + std::to_string(n) + ending);
    return path.string();
}

std::string timestamped_screenshot(const std::string& scenario, const std::tm& local_time) {
    return timestamped_path(scenario, local_time, ".png");
}

}  // namespace heartsim
