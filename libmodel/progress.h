/// @file progress.h
/// @brief One small interface through which long work reports progress and can be cancelled
/// (OpenVDB's interrupter idea). The CLI turns it into a progress bar; tests pass null_progress().
#pragma once

#include <cstdint>
#include <string_view>

namespace heartsim {

class Progress {
public:
    virtual ~Progress() = default;
    /// A new stage begins; `total` work units (0 when unknown).
    virtual void begin(std::string_view stage, std::uint64_t total) = 0;
    /// `done` of the stage's `total` units are finished (absolute, not an increment).
    /// Implementations must be cheap and thread-safe: workers may call it concurrently.
    virtual void update(std::uint64_t done) = 0;
    /// The current stage is finished.
    virtual void end() = 0;
    /// True when the caller wants the work stopped; long loops then throw heartsim::Cancelled.
    virtual bool cancelled() const { return false; }
};

/// A Progress that reports nothing and never cancels.
Progress& null_progress();

/// Calls begin() on construction and end() on destruction, so a stage always closes.
class ProgressStage {
public:
    ProgressStage(Progress& progress, std::string_view stage, std::uint64_t total)
        : progress_(progress) { progress_.begin(stage, total); }
    ~ProgressStage() { progress_.end(); }
    ProgressStage(const ProgressStage&) = delete;
    ProgressStage& operator=(const ProgressStage&) = delete;
    void update(std::uint64_t done) { progress_.update(done); }
private:
    Progress& progress_;
};

}  // namespace heartsim
