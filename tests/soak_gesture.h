/// @file soak_gesture.h
/// @brief The soak's gesture, shared by tests/bench/soak_bench.cpp and tests/test_supports.cpp: a
/// 3 mm grabber (hand 1) travels at 2 mm/ms, holding nothing, to a site where a pull is held
/// hardest (beside an anchor, or among the 2 % of particles with the stiffest supports), grabs,
/// pulls 20 mm in a random direction over 200 ms, lets go and waits 100 ms, then travels to the
/// next site (docs/benchmarks.md "Soak").
#pragma once

#include "formats/scenario.h"
#include "libmodel/sim/solver.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <random>
#include <vector>

namespace heartsim::test {

/// Free particles beside an anchor (a spring to one), or, where nothing is anchored, the 2 % with
/// the stiffest support springs: where a pull is held hardest.
inline std::vector<std::size_t> held_hardest(const Scenario& scenario) {
    const Particles& p = scenario.lattice.particles;
    const auto& neighbours = scenario.packing->neighbours;
    std::vector<std::size_t> sites;
    for (std::size_t i = 0; i < p.size(); ++i) {
        if (p.anchored[i]) continue;
        for (std::int32_t j : neighbours[i])
            if (j >= 0 && p.anchored[std::size_t(j)]) {
                sites.push_back(i);
                break;
            }
    }
    if (!sites.empty() || !p.supported()) return sites;
    std::vector<std::size_t> order(p.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    const std::size_t keep = std::max<std::size_t>(1, order.size() / 50);
    std::partial_sort(order.begin(), order.begin() + std::ptrdiff_t(keep), order.end(),
                      [&](std::size_t a, std::size_t b) { return p.support_stiffness[a] > p.support_stiffness[b]; });
    order.resize(keep);
    return order;
}

class SoakGesture {
public:
    enum class Phase { travel, pull, wait };

    /// Places the grabber at the first site; `sites` from held_hardest, not empty.
    SoakGesture(Solver& solver, const Scenario& scenario, std::vector<std::size_t> sites, unsigned seed)
        : rest_(scenario.lattice.particles.rest_position), sites_(std::move(sites)), random_(seed), pick_(0, sites_.size() - 1) {
        const double dt = solver.time_step_ms();
        pull_steps_ = std::max(1LL, (long long)std::lround(200.0 / dt));
        wait_steps_ = std::max(1LL, (long long)std::lround(100.0 / dt));
        travel_per_step_ = 2.0 * dt;
        solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d::Constant(3.0)});
        hand_ = site_ = rest_of(sites_[pick_(random_)]);
        solver.set_pose(1, {hand_, Eigen::Quaterniond::Identity()});
    }

    /// Moves the grabber for the next step, grabbing and letting go; before solver.step().
    void before_step(Solver& solver) {
        if (phase_ == Phase::travel) {
            const Eigen::Vector3d to = site_ - hand_;
            hand_ += to.norm() > travel_per_step_ ? Eigen::Vector3d(to.normalized() * travel_per_step_) : to;
            if (hand_ == site_) {
                held_total_ += (long long)solver.begin_grab(1);
                ++grabs_;
                direction_ = Eigen::Vector3d(gauss_(random_), gauss_(random_), gauss_(random_)).normalized();
                phase_ = Phase::pull, phase_step_ = 0;
            }
        } else if (phase_ == Phase::pull) {
            hand_ = site_ + 20.0 * double(++phase_step_) / double(pull_steps_) * direction_;
            if (phase_step_ == pull_steps_) {
                solver.release(1);
                phase_ = Phase::wait, phase_step_ = 0;
            }
        } else if (++phase_step_ == wait_steps_) {
            site_ = rest_of(sites_[pick_(random_)]);
            phase_ = Phase::travel;
        }
        solver.set_pose(1, {hand_, Eigen::Quaterniond::Identity()});
    }

    Phase phase() const { return phase_; }
    long long phase_step() const { return phase_step_; }
    long long grabs() const { return grabs_; }
    long long held_total() const { return held_total_; }

private:
    Eigen::Vector3d rest_of(std::size_t i) const { return Eigen::Vector3d(rest_[i][0], rest_[i][1], rest_[i][2]); }

    const std::vector<std::array<float, 3>>& rest_;
    std::vector<std::size_t> sites_;
    std::mt19937 random_;
    std::uniform_int_distribution<std::size_t> pick_;
    std::normal_distribution<double> gauss_{0, 1};
    long long pull_steps_ = 1, wait_steps_ = 1;
    double travel_per_step_ = 0;
    Eigen::Vector3d hand_, site_, direction_ = Eigen::Vector3d::UnitX();
    Phase phase_ = Phase::travel;
    long long phase_step_ = 0, grabs_ = 0, held_total_ = 0;
};

}  // namespace heartsim::test
