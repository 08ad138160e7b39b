/// @file atomic_file.h
/// @brief Every writer's "write beside, then rename into place": a reader never sees a
/// half-written file, and a failed write leaves nothing behind.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace heartsim {

/// A hidden name beside `path` that no other writer in this or another process uses at the same
/// time (process id and a per-process counter), ending in `extension` (by default `path`'s own)
/// for writers that choose the format by it; ITK needs whole compound extensions (".nii.gz").
std::filesystem::path temporary_beside(const std::filesystem::path& path);
std::filesystem::path temporary_beside(const std::filesystem::path& path, const std::string& extension);

/// Removes the temporaries of `path` (files or staging folders named by temporary_beside) that
/// a killed writer left behind: those whose process no longer exists. Every atomic write does
/// this first, so a crash costs disk space only until the next write of the same file.
void sweep_stale_temporaries(const std::filesystem::path& path);

/// Throws OutputError naming `path` unless a file can be written there: `path` is a folder, a
/// part of its folder path is a file ("out.txt/scenario.h5"), its folder does not exist, or the
/// folder is not writable or takes no new file (tried with a temporary file, removed at once:
/// /proc passes root's access check). write_file_atomically checks the same, less the trial (its
/// own temporary file is one); commands that work for a long time before writing check their
/// outputs with it before they start.
void check_destination(const std::filesystem::path& path);

/// A small file that belongs with the one written (the ParaView description beside an HDF5
/// file): written to a temporary of its own and flushed before either file takes its name.
struct FileBeside {
    std::filesystem::path path;
    std::string bytes;
    std::string what;  ///< names it in errors ("the XDMF description")
};

/// Writes `path` atomically: `fill(temporary)` writes a file at temporary_beside(path), which is
/// flushed to the disk (fsync) and then renamed onto `path`, and the folder is flushed too, so a
/// crash leaves the old file or the whole new one. When fill throws or the rename fails, the
/// temporary is removed and the error passes on. Throws OutputError naming `path` when
/// check_destination refuses it, or the flush or rename fails.
/// With `beside`, each of those files is written and flushed too before any rename, and renamed
/// into place after `path`: a full disk at any of them leaves every old file as it was.
void write_file_atomically(const std::filesystem::path& path, const std::function<void(const std::filesystem::path&)>& fill,
                           const std::vector<FileBeside>& beside = {});

/// Writes `size` bytes to `file` (created or truncated) with POSIX calls, for a `fill` of
/// write_file_atomically (which flushes them to the disk); OutputError `failure` + the system's
/// reason when any of it fails (a full disk).
void write_bytes(const std::filesystem::path& file, const void* data, std::size_t size, const std::string& failure);

/// Whether errno `error` says the disk took no more (ENOSPC, EDQUOT, EFBIG). For writers whose
/// library tells a failed write only by a short file or a flag: their message names this cause.
bool disk_full(int error);

/// write_file_atomically of `size` bytes; `what` names the file in errors ("the screenshot").
void write_bytes_atomically(const std::filesystem::path& path, const void* data, std::size_t size, const std::string& what);

/// Whether `a` and `b` name one file: where both exist, the same device and inode (so a hard
/// link, a symbolic link, "./x" and an absolute spelling all match); otherwise the same path once
/// made absolute, with the symbolic links of the folders that exist followed.
bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

/// A file a command reads, and how its messages name it ("the scenario being run").
struct InputFile {
    std::filesystem::path path;
    std::string what;
};

/// An output never replaces an input: OptionError "`output_name`: that is `what`; give another
/// file" when `output` is one of `inputs` (same_file), before anything is written. `output_name`
/// says which output ("--stats-csv out.csv", "-o out.nii.gz").
void refuse_an_input_as_output(const std::string& output_name, const std::filesystem::path& output, const std::vector<InputFile>& inputs);

}  // namespace heartsim
