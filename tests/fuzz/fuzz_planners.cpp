// libFuzzer target: the planners on a tampered scenario. read_scenario (formats/scenario.h), then,
// on what it accepts, heartsim plan-repair's plan (runtime/surgery/repair_plan.h, on a scenario with a
// septal defect) and plan-incision's for both approaches (runtime/surgery/incision_plan.h), with their
// defaults. A refusal (InputError, OptionError among them) is expected; a plan that is made must
// be one `heartsim run --trajectory` reads back (check_planned_trajectory), and the work is bounded
// by libFuzzer's time and memory limits whatever the file says (a defect 1e9 mm wide, a centre
// 1e9 mm away).
#include "fuzz_support.h"

#include "formats/scenario.h"
#include "runtime/surgery/incision_plan.h"
#include "runtime/surgery/repair_plan.h"
#include "runtime/core/trajectory.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::filesystem::path path = heartsim::fuzz::write_input(data, size, "input.h5");
    heartsim::Scenario scenario;
    bool read = false;
    heartsim::fuzz::expect_refusal_or_success([&] {
        scenario = heartsim::read_scenario(path);
        read = true;
    });
    if (!read) return 0;
    auto planned = [](const heartsim::Trajectory& trajectory) {
        try {
            heartsim::check_planned_trajectory(trajectory);
        } catch (const heartsim::InputError& e) {
            heartsim::fuzz::broken(std::string("a planner made a trajectory the reader refuses: ") + e.what());
        }
    };
    if (!scenario.source.defect.empty())
        heartsim::fuzz::expect_refusal_or_success([&] { planned(heartsim::plan_repair(scenario).trajectory); });
    for (const heartsim::IncisionApproach approach : {heartsim::IncisionApproach::ventriculotomy, heartsim::IncisionApproach::atriotomy})
        heartsim::fuzz::expect_refusal_or_success([&] { planned(heartsim::plan_incision(scenario, {.approach = approach}).trajectory); });
    return 0;
}
