#pragma once
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

namespace uavm {

// The session journal (journal.jsonl in the session directory): one JSON object per line, appended as the flight
// goes, so that a killed run can be resumed (`--resume`) without losing a frame it had accepted.
//
// What is recorded: every accepted frame (after its bytes and features are in the session directory), every input
// that was skipped and why, and the end of the flight. Edges are recorded as they are made in edges.bin; transforms
// and tiles are recomputed on resume from the journaled frames (registration is deterministic for the same frames in
// the same order), so a resumed run ends with the same registered set and the same maps as an uninterrupted one.
//
// fsync policy: the journal is flushed to the kernel after every line (a killed process loses nothing), and
// fdatasync'ed every `sync_every` accepted frames and at the end (a power cut loses at most that many frames'
// journal lines; their files are then re-read from the source on resume).
//
// A torn last line (a line without its newline, or one that does not parse) ends the journal: ReadJournal keeps
// what came before it, and reopening for append cuts it off.
struct JournalFrame {
  int id = -1;
  std::string name;         // the source's name for it (replay: the file name); resume skips inputs by this name
  std::string stored_file;  // file name inside frames/
  int64_t timestamp_ns = 0;
  int width = 0;  // original size
  int height = 0;
  // Where the frame was taken, when known (telemetry or EXIF): a resumed run gets telemetry's positions back from
  // here, since the stored file carries at most EXIF's.
  std::optional<double> latitude_deg = std::nullopt;
  std::optional<double> longitude_deg = std::nullopt;
  std::optional<double> relative_altitude_m = std::nullopt;
  std::optional<double> yaw_deg = std::nullopt;
};

struct JournalSkip {
  std::string name;
  std::string reason;
};

struct JournalContents {
  std::vector<JournalFrame> frames;
  std::vector<JournalSkip> skipped;
  bool finished = false;     // the previous run completed its flight
  uint64_t valid_bytes = 0;  // length of the well-formed prefix
  int torn_lines = 0;        // 0 or 1: a line cut off by the kill
};

// Reads a journal. False (with a reason) only when the file exists but is not a journal; a missing file is an empty
// journal.
[[nodiscard]] bool ReadJournal(const std::string& path, JournalContents* out, std::string* error);
// Parses journal text (ReadJournal's core; also what the fuzzer drives).
[[nodiscard]] bool ParseJournal(const std::string& text, JournalContents* out, std::string* error);

class SessionJournal {
 public:
  SessionJournal() = default;
  ~SessionJournal();
  SessionJournal(const SessionJournal&) = delete;
  SessionJournal& operator=(const SessionJournal&) = delete;

  // Starts a new journal, or (append) continues one after its last well-formed line (`valid_bytes`).
  [[nodiscard]] bool Open(const std::string& path, bool append, uint64_t valid_bytes, int sync_every,
                          std::string* error);
  [[nodiscard]] bool is_open() const { return file_ != nullptr; }
  [[nodiscard]] bool AddFrame(const JournalFrame& frame, std::string* error);
  [[nodiscard]] bool AddSkip(const JournalSkip& skip, std::string* error);
  [[nodiscard]] bool AddResumed(size_t frames, std::string* error);
  [[nodiscard]] bool AddFinished(std::string* error);
  void Close();
  [[nodiscard]] size_t syncs() const { return syncs_; }

 private:
  [[nodiscard]] bool WriteLine(const std::string& line, bool sync, std::string* error);

  std::FILE* file_ = nullptr;
  std::string path_;
  int sync_every_ = 1;
  int since_sync_ = 0;
  size_t syncs_ = 0;
};

}  // namespace uavm
