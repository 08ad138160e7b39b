/// @file recording_journal.h
/// @brief The journal a `heartsim run … --record OUT.h5` session keeps beside OUT.h5 while it runs
/// (OUT.h5.journal), so a session killed outright (SIGKILL, a crash, the power) keeps all but its
/// last second: `heartsim recover OUT.h5.journal` turns what it holds into OUT.h5. OUT.h5 itself is
/// still written whole and atomically when the session ends, and the journal is then deleted.
/// docs/haptics.md "Recording and replay".
///
/// An append-only file: the 16 bytes "heartsim journal", then records of
///   u32 magic "HSJR", u32 kind, u64 payload bytes, u32 checksum (lookup3 of kind, bytes, payload), payload
/// kind 1, first and once: the session (the Recording's attributes and hands, the --record path,
///   the writer's process id); kind 2: a chunk, the rows added since the previous chunk (steps,
///   the device ticks of each hand with a device, events); kind 3: the end (the period and latency
///   figures of a session that ended normally). Numbers are little-endian IEEE / two's complement,
///   strings a u64 length and UTF-8 bytes. A record cut short or failing its checksum ends the
///   journal: the records before it are what a killed session left.
#pragma once

#include "formats/recording.h"

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace heartsim {

/// OUT.h5 → OUT.h5.journal (beside it; not a name sweep_stale_temporaries removes).
std::filesystem::path journal_path(const std::filesystem::path& recording);

/// Whether a running process holds `journal` open for writing (its advisory lock), i.e. a session
/// is recording now; false for a journal a killed session left.
bool journal_in_use(const std::filesystem::path& journal);

/// Writes a journal. Chunks are serialised on the caller's thread and written and flushed to the
/// disk (fdatasync) by the journal's own thread, so the caller never waits for the disk.
class RecordingJournal {
public:
    /// Creates `path` (InputError when it exists: it is never replaced), writes the session record
    /// of `session` (its attributes and hands; rows are ignored) with `target`, the --record path,
    /// and flushes it and the folder to the disk; OutputError naming `path` when that fails. Holds
    /// an advisory lock on the file while open (journal_in_use).
    RecordingJournal(const std::filesystem::path& path, const Recording& session, const std::string& target);
    /// Stops the thread and closes the file, which stays (a session that did not finish).
    ~RecordingJournal();
    RecordingJournal(const RecordingJournal&) = delete;
    RecordingJournal& operator=(const RecordingJournal&) = delete;

    /// Queues the rows of `rows` (steps, each used hand's ticks, events; attributes are ignored)
    /// as one chunk and returns without waiting for the disk.
    void append(const Recording& rows);
    /// Queues the end record with the period and latency figures of `statistics`.
    void end(const Recording& statistics);
    /// Waits until everything queued is on the disk; returns the first write failure ("" when none).
    /// After a failure nothing more is written (the journal keeps what was written before it).
    std::string wait();
    /// The first write failure so far ("" when none), without waiting.
    std::string failure() const;
    /// Stops the thread, closes and deletes the journal (the complete recording has been written).
    void remove();
    const std::filesystem::path& path() const { return path_; }

private:
    void queue(std::uint32_t kind, std::vector<unsigned char> payload);
    void run();
    void stop();

    std::filesystem::path path_;
    int fd_ = -1;
    mutable std::mutex mutex_;
    std::condition_variable wake_, written_;
    std::deque<std::vector<unsigned char>> queue_;
    /// The writer thread's batch, swapped with queue_: made with the journal, on the caller's
    /// thread, because a std::deque allocates when it is made and the writer thread must not throw.
    std::deque<std::vector<unsigned char>> batch_;
    std::uint64_t queued_records_ = 0, written_records_ = 0;
    std::vector<bool> used_hands_;
    bool stopping_ = false;
    std::string failure_;
    bool out_of_memory_ = false;  ///< the writer thread ran out of memory (its message is made by failure_message)
    /// failure_, or the out-of-memory message; under mutex_, on the thread that asks.
    std::string failure_message() const;
    std::thread thread_;
};

struct JournalContents {
    /// The session with the rows of every complete chunk, events in time order; a journal without
    /// its end record (a killed session) gains an `interrupted` event at the time of its last row,
    /// and its period and latency figures are 0.
    Recording recording;
    std::string target;               ///< the --record path the session was given
    std::int64_t pid = 0;             ///< the process that wrote it
    std::size_t chunks = 0;
    bool ended = false;               ///< the end record is there: the session ended normally
    std::uint64_t ignored_bytes = 0;  ///< after the last complete record: a record cut short by the kill
};

/// Reads a journal. InputError naming the file when it is not a journal, its session record is
/// damaged, or a complete record does not parse; a torn or damaged tail is not an error (counted
/// in ignored_bytes).
JournalContents read_recording_journal(const std::filesystem::path& path);

}  // namespace heartsim
