/// @file exchange.h
/// @brief The lock-free exchange between the device thread and the simulation: a latest-value
/// triple buffer and a fixed-capacity single-producer single-consumer queue.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <vector>

namespace heartsim::haptics {

/// Single writer, single reader, wait-free: the writer publishes whole values, the reader gets the
/// newest complete one (older ones may be skipped, never torn). A triple buffer: the writer fills
/// its back slot and swaps it with the shared middle slot (an atomic index with a "fresh" bit);
/// the reader swaps its front slot with the middle one when fresh. No locks, no allocation.
template <class T>
class LatestValue {
public:
    /// Writer side only.
    void publish(const T& value) {
        slots_[back_] = value;
        back_ = middle_.exchange(back_ | fresh_bit, std::memory_order_acq_rel) & index_mask;
    }
    /// Reader side only: the newest value into `out`; true when it is newer than the last fetch.
    /// Before the first publish, `out` gets a default T and false.
    bool fetch(T& out) {
        bool fresh = false;
        if (middle_.load(std::memory_order_acquire) & fresh_bit) {
            front_ = middle_.exchange(front_, std::memory_order_acq_rel) & index_mask;
            fresh = true;
        }
        out = slots_[front_];
        return fresh;
    }

private:
    static constexpr unsigned fresh_bit = 4, index_mask = 3;
    std::array<T, 3> slots_{};
    alignas(64) std::atomic<unsigned> middle_{1};
    alignas(64) unsigned back_ = 0;   // writer's
    alignas(64) unsigned front_ = 2;  // reader's
};

/// Single producer, single consumer queue of fixed capacity, wait-free: the device thread pushes
/// one record per tick, the simulation thread drains them. A full queue drops the new record and
/// counts it (the device thread never waits and never allocates).
template <class T>
class SpscQueue {
public:
    explicit SpscQueue(std::size_t capacity = 0) { reset(capacity); }
    /// Not concurrently with push / drain.
    void reset(std::size_t capacity) {
        std::size_t c = 1;
        while (c < capacity) c <<= 1;
        slots_.assign(capacity ? c : 0, T{});
        head_.store(0), tail_.store(0), dropped_.store(0);
    }
    bool enabled() const { return !slots_.empty(); }
    /// Producer only.
    bool push(const T& value) {
        const std::size_t tail = tail_.load(std::memory_order_relaxed);
        if (slots_.empty() || tail - head_.load(std::memory_order_acquire) >= slots_.size()) {
            dropped_.fetch_add(1, std::memory_order_relaxed);
            return false;
        }
        slots_[tail & (slots_.size() - 1)] = value;
        tail_.store(tail + 1, std::memory_order_release);
        return true;
    }
    /// Consumer only: appends everything queued to `out`; returns how many.
    std::size_t drain(std::vector<T>& out) {
        const std::size_t head = head_.load(std::memory_order_relaxed), tail = tail_.load(std::memory_order_acquire);
        for (std::size_t i = head; i < tail; ++i) out.push_back(slots_[i & (slots_.size() - 1)]);
        head_.store(tail, std::memory_order_release);
        return tail - head;
    }
    std::uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

private:
    std::vector<T> slots_;
    alignas(64) std::atomic<std::size_t> head_{0};
    alignas(64) std::atomic<std::size_t> tail_{0};
    std::atomic<std::uint64_t> dropped_{0};
};

}  // namespace heartsim::haptics
