// The journal of a --record session (recording_journal.h).
#include "recording_journal.h"

#include "hdf5_io.h"  // lookup3

#include "libmodel/errors.h"
#include "libmodel/surgery/patch.h"

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

namespace heartsim {

static_assert(std::endian::native == std::endian::little, "the journal stores numbers as they lie in memory: little-endian");

namespace {

constexpr char file_magic[16] = {'h', 'e', 'a', 'r', 't', 's', 'i', 'm', ' ', 'j', 'o', 'u', 'r', 'n', 'a', 'l'};
constexpr std::uint32_t record_magic = 0x524a5348u;  // "HSJR"
constexpr std::size_t record_header = 20;           // magic, kind, bytes, checksum
/// 2 adds the recording's arithmetic after its interpolation; a version-1 journal (written before
/// the slot's multiply-adds were fused) is read with "separate". 3 adds the solver's rules after
/// the arithmetic (a byte, 1 when they follow); a journal before it is read without them. 4 adds
/// to each chunk, after the diverged column, a byte (1 when the mass-scale column follows) and the
/// column. 5 adds after the mass-scale column a byte (1 when the instrument and semi-axes columns
/// follow) and the two columns, and at the end of the session record its patch material. 6 adds
/// the contact_skin rule after the others (a journal before it is read with 0).
constexpr std::uint32_t journal_version = 6;
enum Kind : std::uint32_t { session_record = 1, chunk_record = 2, end_record = 3 };

/// A payload being built.
class Bytes {
public:
    void raw(const void* data, std::size_t size) {
        const auto* p = static_cast<const unsigned char*>(data);
        bytes.insert(bytes.end(), p, p + size);
    }
    template <class T> void put(T value) { raw(&value, sizeof value); }
    template <class T> void column(const std::vector<T>& values) { raw(values.data(), values.size() * sizeof(T)); }
    void text(const std::string& s) {
        put<std::uint64_t>(s.size());
        raw(s.data(), s.size());
    }
    std::vector<unsigned char> bytes;
};

/// A payload being read: every read checks the bytes are there.
class Cursor {
public:
    Cursor(const unsigned char* data, std::size_t size, std::string where) : p_(data), left_(size), where_(std::move(where)) {}
    void raw(void* out, std::size_t size) {
        need(size);
        std::memcpy(out, p_, size);
        p_ += size, left_ -= size;
    }
    template <class T> T get() {
        T value;
        raw(&value, sizeof value);
        return value;
    }
    /// `count` values appended to `out` (rows of arrays or numbers).
    template <class T> void column(std::vector<T>& out, std::uint64_t count) {
        if (count > left_ / sizeof(T)) need(left_ + 1);  // before resizing: a count from a damaged record must not allocate
        const std::size_t at = out.size();
        out.resize(at + std::size_t(count));
        if (count) raw(out.data() + at, std::size_t(count) * sizeof(T));
    }
    std::string text() {
        const auto n = get<std::uint64_t>();
        need(n);
        std::string s(reinterpret_cast<const char*>(p_), std::size_t(n));
        p_ += n, left_ -= std::size_t(n);
        return s;
    }
    std::size_t left() const { return left_; }
    void need(std::uint64_t size) const {
        if (size > left_) throw InputError(where_ + " ends early (a bug in the heartsim that wrote it, or a foreign file)");
    }

private:
    const unsigned char* p_;
    std::size_t left_;
    std::string where_;
};

std::uint32_t checksum(std::uint32_t kind, std::uint64_t size, const unsigned char* payload) {
    std::vector<unsigned char> covered(12 + size);
    std::memcpy(covered.data(), &kind, 4);
    std::memcpy(covered.data() + 4, &size, 8);
    if (size) std::memcpy(covered.data() + 12, payload, std::size_t(size));
    return h5::lookup3(covered.data(), covered.size());
}

/// Writes all of `data`; "" or the reason it failed.
std::string write_all(int fd, const unsigned char* data, std::size_t size) {
    while (size > 0) {
        const ssize_t n = ::write(fd, data, size);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            const int reason = n < 0 ? errno : ENOSPC;
            return std::string(std::strerror(reason)) + (reason == ENOSPC || reason == EFBIG ? "; disk full?" : "");
        }
        data += n, size -= std::size_t(n);
    }
    return "";
}

void sync_folder(const std::filesystem::path& path) {
    const auto folder = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    const int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) return;
    ::fsync(fd);  // some file systems cannot sync a folder; the journal is still there
    ::close(fd);
}

}  // namespace

std::filesystem::path journal_path(const std::filesystem::path& recording) {
    std::filesystem::path journal = recording;
    journal += ".journal";
    return journal;
}

bool journal_in_use(const std::filesystem::path& journal) {
    const int fd = ::open(journal.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return false;
    const bool locked = ::flock(fd, LOCK_SH | LOCK_NB) != 0 && errno == EWOULDBLOCK;
    ::close(fd);
    return locked;
}

// ------------------------------------------------------------------------------------------------
// Writing

RecordingJournal::RecordingJournal(const std::filesystem::path& path, const Recording& session, const std::string& target) : path_(path) {
    fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644);
    if (fd_ < 0) {
        if (errno == EEXIST) throw InputError(path.string() + ": a journal is already there (another session's); it is never replaced");
        throw OutputError(path.string() + ": cannot create the session's journal: " + std::strerror(errno));
    }
    // Whatever fails from here on (out of memory while serialising, a thread that cannot start)
    // leaves no journal: nothing of the session is in it yet.
    try {
    ::flock(fd_, LOCK_EX | LOCK_NB);
    Bytes b;
    b.put(journal_version);
    b.text(target);
    b.put<std::int64_t>(::getpid());
    b.text(session.scenario);
    b.put<std::int64_t>(session.particles);
    b.put(session.dt_ms);
    b.put<std::int32_t>(session.substeps);
    b.text(session.backend);
    b.text(session.contact);
    b.text(session.interpolation);
    b.text(session.arithmetic);
    b.put<std::uint8_t>(session.rules ? 1 : 0);
    if (session.rules) for_each_rule([&](const char*, const auto& value) { b.put(value); }, *session.rules);
    b.put(session.rate_hz);
    b.put<std::int32_t>(session.coupling ? 1 : 0);
    for (const RecordedHand& hand : session.hands) {
        used_hands_.push_back(hand.used);
        b.put<std::uint8_t>(hand.used ? 1 : 0);
        if (!hand.used) continue;
        b.text(hand.device);
        b.text(hand.device_name);
        b.text(hand.instrument);
        b.put(hand.semi_axes_mm);
        b.put(hand.max_force_n);
        b.put(hand.mapping_offset_mm);
        b.put(hand.mapping_rotation);
        b.put(hand.mapping_scale);
        b.put(hand.force_scale);
    }
    b.text(session.patch_material);
    std::vector<unsigned char> record(record_header + b.bytes.size());
    const std::uint32_t kind = session_record;
    const std::uint64_t size = b.bytes.size();
    const std::uint32_t sum = checksum(kind, size, b.bytes.data());
    std::memcpy(record.data() + 20, b.bytes.data(), b.bytes.size());
    std::memcpy(record.data(), &record_magic, 4);
    std::memcpy(record.data() + 4, &kind, 4);
    std::memcpy(record.data() + 8, &size, 8);
    std::memcpy(record.data() + 16, &sum, 4);
    std::string error = write_all(fd_, reinterpret_cast<const unsigned char*>(file_magic), sizeof file_magic);
    if (error.empty()) error = write_all(fd_, record.data(), record.size());
    if (error.empty() && ::fsync(fd_) != 0) error = std::strerror(errno);
    if (!error.empty()) throw OutputError(path.string() + ": cannot write the session's journal (" + error + ")");
    sync_folder(path);
    thread_ = std::thread([this] { run(); });
    } catch (...) {
        ::close(fd_);
        fd_ = -1;
        ::unlink(path.c_str());
        throw;
    }
}

RecordingJournal::~RecordingJournal() { stop(); }

void RecordingJournal::stop() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
}

void RecordingJournal::queue(std::uint32_t kind, std::vector<unsigned char> payload) {
    std::vector<unsigned char> record(record_header + payload.size());
    const std::uint64_t size = payload.size();
    const std::uint32_t sum = checksum(kind, size, payload.data());
    std::memcpy(record.data(), &record_magic, 4);
    std::memcpy(record.data() + 4, &kind, 4);
    std::memcpy(record.data() + 8, &size, 8);
    std::memcpy(record.data() + 16, &sum, 4);
    if (!payload.empty()) std::memcpy(record.data() + record_header, payload.data(), payload.size());
    {
        std::lock_guard lock(mutex_);
        queue_.push_back(std::move(record));
        ++queued_records_;
    }
    wake_.notify_one();
}

void RecordingJournal::append(const Recording& rows) {
    const RecordedSteps& s = rows.steps;
    const std::size_t n = s.size();
    if (s.wall_ms.size() != n || s.tool_time_ms.size() != n || s.tool_position_mm.size() != n || s.tool_orientation.size() != n ||
        s.grab.size() != n || s.applied.size() != n || s.force_n.size() != n || s.force_step.size() != n || s.diverged.size() != n ||
        (!s.mass_scale.empty() && s.mass_scale.size() != n) || (!s.instrument.empty() && s.instrument.size() != n) ||
        s.semi_axes_mm.size() != s.instrument.size())
        throw OutputError(path_.string() + ": the step columns have different lengths (a bug in heartsim)");
    Bytes b;
    b.put<std::uint64_t>(n);
    b.column(s.time_ms);
    b.column(s.wall_ms);
    b.column(s.tool_time_ms);
    b.column(s.tool_position_mm);
    b.column(s.tool_orientation);
    b.column(s.grab);
    b.column(s.applied);
    b.column(s.force_n);
    b.column(s.force_step);
    b.column(s.diverged);
    b.put<std::uint8_t>(s.mass_scale.empty() ? 0 : 1);
    b.column(s.mass_scale);
    b.put<std::uint8_t>(s.instrument.empty() ? 0 : 1);
    b.column(s.instrument);
    b.column(s.semi_axes_mm);
    for (std::size_t h = 0; h < used_hands_.size(); ++h) {
        if (!used_hands_[h]) continue;
        const RecordedHand& hand = rows.hands[h];
        const std::size_t t = hand.tick_time_ms.size();
        if (hand.position_mm.size() != t || hand.orientation.size() != t || hand.buttons.size() != t || hand.input_n.size() != t ||
            hand.force_n.size() != t || hand.gain.size() != t)
            throw OutputError(path_.string() + ": the tick columns of hand " + std::to_string(h) + " have different lengths (a bug in heartsim)");
        b.put<std::uint64_t>(t);
        b.column(hand.tick_time_ms);
        b.column(hand.position_mm);
        b.column(hand.orientation);
        b.column(hand.buttons);
        b.column(hand.input_n);
        b.column(hand.force_n);
        b.column(hand.gain);
    }
    b.put<std::uint64_t>(rows.events.size());
    for (const RecordedEvent& e : rows.events) {
        b.put(e.time_ms);
        b.put<std::int32_t>(e.hand);
        b.text(e.what);
    }
    queue(chunk_record, std::move(b.bytes));
}

void RecordingJournal::end(const Recording& r) {
    Bytes b;
    for (double v : {r.period_p50_ms, r.period_p99_ms, r.period_max_ms, r.period_mean_ms}) b.put(v);
    b.put<std::int64_t>(r.periods);
    b.put<std::int64_t>(r.overruns);
    for (double v : {r.latency_p50_ms, r.latency_p99_ms, r.latency_max_ms}) b.put(v);
    queue(end_record, std::move(b.bytes));
}

void RecordingJournal::run() {
    // Nothing here allocates (the swaps exchange the deques' storage, clear() keeps their maps):
    // out of memory cannot end the program on this thread.
    auto& batch = batch_;
    for (;;) {
        batch.clear();
        {
            std::unique_lock lock(mutex_);
            wake_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
            if (queue_.empty()) return;  // stopping, and everything written
            batch.swap(queue_);
            if (!failure_.empty() || out_of_memory_) {  // after a failure nothing more is written
                written_records_ += batch.size();
                written_.notify_all();
                continue;
            }
        }
        std::string error;
        bool out_of_memory = false;
        try {
            for (const auto& record : batch)
                if (error.empty()) error = write_all(fd_, record.data(), record.size());
            if (error.empty() && ::fdatasync(fd_) != 0) error = std::strerror(errno);
        } catch (const std::bad_alloc&) {  // an error's message could not be made
            out_of_memory = true;
        }
        {
            std::lock_guard lock(mutex_);
            written_records_ += batch.size();
            try {
                if (!error.empty() && failure_.empty() && !out_of_memory_)
                    failure_ = path_.string() + ": cannot write the session's journal (" + error + ")";
            } catch (const std::bad_alloc&) {
                out_of_memory = true;
            }
            // The message is made by the thread that asks (failure(), wait()).
            out_of_memory_ = out_of_memory_ || out_of_memory;
        }
        written_.notify_all();
    }
}

std::string RecordingJournal::wait() {
    std::unique_lock lock(mutex_);
    written_.wait(lock, [&] { return written_records_ == queued_records_; });
    return failure_message();
}

std::string RecordingJournal::failure() const {
    std::lock_guard lock(mutex_);
    return failure_message();
}

std::string RecordingJournal::failure_message() const {
    if (failure_.empty() && out_of_memory_) return path_.string() + ": cannot write the session's journal (out of memory)";
    return failure_;
}

void RecordingJournal::remove() {
    stop();
    std::error_code ignored;
    std::filesystem::remove(path_, ignored);
    sync_folder(path_);
}

// ------------------------------------------------------------------------------------------------
// Reading

namespace {

/// The journal's bytes; throws InputError where the file is missing, unreadable or no journal.
std::vector<unsigned char> journal_bytes(const std::filesystem::path& path) {
    const std::string name = path.string();
    std::error_code error;
    if (!std::filesystem::is_regular_file(path, error)) throw InputError(name + ": " + (std::filesystem::exists(path) ? "not a file" : "file not found"));
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(name + ": cannot be read");
    std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (bytes.size() < sizeof file_magic || std::memcmp(bytes.data(), file_magic, sizeof file_magic) != 0)
        throw InputError(name + ": not a heartsim --record journal (it does not start with \"heartsim journal\")");
    return bytes;
}

/// The session record: the run's settings and its hands (`used`: which hands have a device);
/// returns the journal's version, for the chunks after it.
std::uint32_t read_session_record(Cursor& c, const std::string& where, JournalContents& contents, std::vector<bool>& used) {
    Recording& r = contents.recording;
    const std::uint32_t version = c.get<std::uint32_t>();
    if (version < 1 || version > journal_version)
        throw InputError(where + ": journal version " + std::to_string(version) + " is not supported (this build reads versions 1 to " +
                         std::to_string(journal_version) + ")");
    contents.target = c.text();
    contents.pid = c.get<std::int64_t>();
    r.scenario = c.text();
    r.particles = c.get<std::int64_t>();
    r.dt_ms = c.get<double>();
    r.substeps = c.get<std::int32_t>();
    r.backend = c.text();
    r.contact = c.text();
    r.interpolation = c.text();
    r.arithmetic = version == 1 ? "separate" : c.text();
    if (!known_arithmetic(r.arithmetic))
        throw InputError(where + ": the session's arithmetic must be fused or separate, not '" + r.arithmetic + "'");
    if (version >= 3 && c.get<std::uint8_t>() != 0) {
        SolverRules rules;
        for_each_rule(
            [&](const char* name, auto& value) {
                if (version < 6 && std::string(name) == "contact_skin") value = 0.0;
                else value = c.get<std::remove_reference_t<decltype(value)>>();
            },
            rules);
        if (const std::string wrong = check_rules(rules); !wrong.empty()) throw InputError(where + ": the session's rules: " + wrong);
        r.rules = rules;
    }
    r.rate_hz = c.get<double>();
    r.coupling = c.get<std::int32_t>() != 0;
    for (RecordedHand& hand : r.hands) {
        hand.used = c.get<std::uint8_t>() != 0;
        used.push_back(hand.used);
        if (!hand.used) continue;
        hand.device = c.text();
        hand.device_name = c.text();
        hand.instrument = c.text();
        hand.semi_axes_mm = c.get<std::array<double, 3>>();
        hand.max_force_n = c.get<double>();
        hand.mapping_offset_mm = c.get<std::array<double, 3>>();
        hand.mapping_rotation = c.get<std::array<double, 4>>();
        hand.mapping_scale = c.get<double>();
        hand.force_scale = c.get<double>();
    }
    r.patch_material = version >= 5 ? c.text() : "pericardium";
    try {
        patch_material_named(r.patch_material);
    } catch (const InputError& e) {
        throw InputError(where + ": the session's " + e.what());
    }
    return version;
}

/// A chunk record: its steps, each used hand's device ticks and its events appended to the
/// recording; `last_ms` rises to the latest time it holds.
void read_chunk_record(Cursor& c, const std::string& where, std::uint32_t version, const std::vector<bool>& used, Recording& r,
                       double& last_ms) {
    RecordedSteps& s = r.steps;
    const auto n = c.get<std::uint64_t>();
    c.column(s.time_ms, n);
    c.column(s.wall_ms, n);
    c.column(s.tool_time_ms, n);
    c.column(s.tool_position_mm, n);
    c.column(s.tool_orientation, n);
    c.column(s.grab, n);
    c.column(s.applied, n);
    c.column(s.force_n, n);
    c.column(s.force_step, n);
    c.column(s.diverged, n);
    if (version >= 4 && c.get<std::uint8_t>() != 0) {
        s.mass_scale.resize(s.diverged.size() - n, 1.0);  // rows of earlier chunks without the column ran at 1
        c.column(s.mass_scale, n);
        for (std::size_t k = s.mass_scale.size() - n; k < s.mass_scale.size(); ++k)
            if (!valid_mass_scale(s.mass_scale[k]))
                throw InputError(where + ": a step's mass scale is " + std::to_string(s.mass_scale[k]) + ", expected 1 … 1024");
    } else if (!s.mass_scale.empty()) {
        s.mass_scale.resize(s.diverged.size(), 1.0);
    }
    // A recording either has the instrument columns throughout or not at all (HapticRun).
    if (version >= 5 && c.get<std::uint8_t>() != 0) {
        if (s.instrument.size() != s.diverged.size() - n)
            throw InputError(where + ": a chunk has the instrument columns and an earlier one did not");
        c.column(s.instrument, n);
        c.column(s.semi_axes_mm, n);
        for (std::size_t k = s.instrument.size() - n; k < s.instrument.size(); ++k)
            for (int h = 0; h < 2; ++h)
                if (const StepInstrumentFault fault = check_step_instrument(s.instrument[k][h], s.semi_axes_mm[k][h], used[std::size_t(h)]);
                    !fault.what.empty())
                    throw InputError(where + ": a step's " + fault.dataset + ", hand " + std::to_string(h) + fault.what);
    } else if (!s.instrument.empty() && n > 0) {
        throw InputError(where + ": a chunk lacks the instrument columns an earlier one had");
    }
    if (n) last_ms = std::max(last_ms, s.wall_ms.back());
    for (std::size_t h = 0; h < used.size(); ++h) {
        if (!used[h]) continue;
        RecordedHand& hand = r.hands[h];
        const auto t = c.get<std::uint64_t>();
        c.column(hand.tick_time_ms, t);
        c.column(hand.position_mm, t);
        c.column(hand.orientation, t);
        c.column(hand.buttons, t);
        c.column(hand.input_n, t);
        c.column(hand.force_n, t);
        c.column(hand.gain, t);
        if (t) last_ms = std::max(last_ms, hand.tick_time_ms.back());
    }
    const auto events = c.get<std::uint64_t>();
    if (events > c.left() / 20) c.need(c.left() + 1);  // each at least a time, a hand and a string's length
    for (std::uint64_t e = 0; e < events; ++e) {
        RecordedEvent event;
        event.time_ms = c.get<double>();
        event.hand = c.get<std::int32_t>();
        event.what = c.text();
        last_ms = std::max(last_ms, event.time_ms);
        r.events.push_back(std::move(event));
    }
}

/// The end record: the run's timing figures.
void read_end_record(Cursor& c, Recording& r) {
    r.period_p50_ms = c.get<double>();
    r.period_p99_ms = c.get<double>();
    r.period_max_ms = c.get<double>();
    r.period_mean_ms = c.get<double>();
    r.periods = c.get<std::int64_t>();
    r.overruns = c.get<std::int64_t>();
    r.latency_p50_ms = c.get<double>();
    r.latency_p99_ms = c.get<double>();
    r.latency_max_ms = c.get<double>();
}

}  // namespace

JournalContents read_recording_journal(const std::filesystem::path& path) {
    const std::string name = path.string();
    const std::vector<unsigned char> bytes = journal_bytes(path);

    JournalContents contents;
    Recording& r = contents.recording;
    std::vector<bool> used;
    std::size_t at = sizeof file_magic;
    double last_ms = 0.0;
    std::uint32_t version = 0;  // the session record's, for the chunks after it
    while (at < bytes.size()) {
        // A record cut short or failing its checksum ends the journal.
        if (bytes.size() - at < record_header) break;
        std::uint32_t magic, kind, sum;
        std::uint64_t size;
        std::memcpy(&magic, bytes.data() + at, 4);
        std::memcpy(&kind, bytes.data() + at + 4, 4);
        std::memcpy(&size, bytes.data() + at + 8, 8);
        std::memcpy(&sum, bytes.data() + at + 16, 4);
        if (magic != record_magic || size > bytes.size() - at - record_header) break;
        const unsigned char* payload = bytes.data() + at + record_header;
        if (checksum(kind, size, payload) != sum) break;
        const std::string where = name + ": record at byte " + std::to_string(at);
        Cursor c(payload, std::size_t(size), where);
        if ((kind == session_record) != used.empty())
            throw InputError(where + ": " + (used.empty() ? "the journal does not start with its session record" : "a second session record"));
        if (kind == session_record) {
            version = read_session_record(c, where, contents, used);
        } else if (kind == chunk_record) {
            read_chunk_record(c, where, version, used, r, last_ms);
            ++contents.chunks;
        } else if (kind == end_record) {
            read_end_record(c, r);
            contents.ended = true;
        } else {
            throw InputError(where + ": record kind " + std::to_string(kind) + " is not known (a journal of a newer heartsim?)");
        }
        if (c.left() != 0) throw InputError(where + ": " + std::to_string(c.left()) + " bytes more than its contents");
        at += record_header + std::size_t(size);
    }
    if (used.empty()) throw InputError(name + ": its session record is missing or damaged: nothing can be recovered");
    contents.ignored_bytes = bytes.size() - at;
    if (!contents.ended) r.events.push_back({last_ms, -1, "interrupted"});
    std::stable_sort(r.events.begin(), r.events.end(), [](const RecordedEvent& x, const RecordedEvent& y) { return x.time_ms < y.time_ms; });
    return contents;
}

}  // namespace heartsim
