/// @file output_names.h
/// @brief The names heartsim gives the files a run writes without being told one: a screenshot
/// every N steps, the window's P screenshots and recordings beside the scenario.
#pragma once

#include <ctime>
#include <string>

namespace heartsim {

/// SCENARIO-YYYYmmdd-HHMMSS`ending` beside `scenario` (the .h5) at `local_time`, with -2, -3, …
/// appended while that name, or its recording journal (NAME.journal), exists already.
std::string timestamped_path(const std::string& scenario, const std::tm& local_time, const std::string& ending);

/// The P key's screenshot: SCENARIO-YYYYmmdd-HHMMSS.png beside `scenario` (the .h5) at
/// `local_time`, with -2, -3, … appended when that name exists already.
std::string timestamped_screenshot(const std::string& scenario, const std::tm& local_time);

/// OUT.png → OUT-000123.png for step 123.
std::string numbered_screenshot(const std::string& path, long long step);

}  // namespace heartsim
