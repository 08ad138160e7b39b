/// @file stress_gesture.h
/// @brief The two-handed stress gesture shared by tests/test_solver.cpp and the solver benchmark:
/// each hand chases a random target anywhere in the heart's box at up to `speed` mm/ms (2 mm/ms,
/// 2 m/s, is faster than hands move in surgery), a new target every 40 steps; the grabber (hand 1)
/// lets go at each new target and grabs again 5 steps later. The second constructor sets up the
/// instruments and targets that tests/test_solver.cpp and solver_bench share.
#pragma once

#include "libmodel/sim/solver.h"

#include <Eigen/Geometry>

#include <array>
#include <cstdlib>
#include <functional>
#include <random>

namespace heartsim::test {

class StressGesture {
public:
    /// Draws the start poses and the first targets (hand 0, hand 1; then the targets) and places
    /// both instruments.
    StressGesture(Solver& solver, std::function<InstrumentPose()> random_pose, double speed_mm_per_ms = 2.0)
        : random_pose_(std::move(random_pose)), speed_(speed_mm_per_ms) {
        current_ = {random_pose_(), random_pose_()};
        target_ = {random_pose_(), random_pose_()};
        for (int hand = 0; hand < 2; ++hand) solver.set_pose(hand, current_[std::size_t(hand)]);
    }

    /// The test's and the benchmark's gesture: a 3 × 3 × 8 mm probe on hand 0 and a 4 mm grabber
    /// on hand 1, whose targets are uniform in the box of `particles`' rest positions with
    /// uniformly random orientations, all drawn from `seed` (std::rand too: Eigen's
    /// Quaterniond::UnitRandom draws from it, so a run does not depend on what ran before).
    StressGesture(Solver& solver, const Particles& particles, unsigned seed) : StressGesture(solver, random_poses(solver, particles, seed)) {}

    /// Moves both hands for step `step` (0, 1, …), before solver.step().
    void before_step(Solver& solver, long long step) {
        if (step % 40 == 0) {
            target_ = {random_pose_(), random_pose_()};
            solver.release(1);
        }
        for (int hand = 0; hand < 2; ++hand) {
            auto& c = current_[std::size_t(hand)];
            const Eigen::Vector3d to = target_[std::size_t(hand)].position - c.position;
            const double reach = speed_ * solver.time_step_ms();
            c.position += to.norm() > reach ? Eigen::Vector3d(to.normalized() * reach) : to;
            c.orientation = c.orientation.slerp(0.05, target_[std::size_t(hand)].orientation);
            solver.set_pose(hand, c);
        }
        if (step % 40 == 5) solver.begin_grab(1);
    }

private:
    static std::function<InstrumentPose()> random_poses(Solver& solver, const Particles& particles, unsigned seed) {
        Eigen::AlignedBox3d box;
        for (const auto& r : particles.rest_position) box.extend(Eigen::Vector3d(r[0], r[1], r[2]));
        solver.set_instrument(0, {.kind = InstrumentKind::probe, .semi_axes = Eigen::Vector3d(3, 3, 8)});
        solver.set_instrument(1, {.kind = InstrumentKind::grabber, .semi_axes = Eigen::Vector3d(4, 4, 4)});
        std::srand(seed);
        return [box, random = std::mt19937(seed), unit = std::uniform_real_distribution<double>(0.0, 1.0)]() mutable {
            const Eigen::Vector3d p = box.min() + box.diagonal().cwiseProduct(Eigen::Vector3d(unit(random), unit(random), unit(random)));
            return InstrumentPose{p, Eigen::Quaterniond::UnitRandom()};
        };
    }

    std::function<InstrumentPose()> random_pose_;
    double speed_;
    std::array<InstrumentPose, 2> current_, target_;
};

}  // namespace heartsim::test
