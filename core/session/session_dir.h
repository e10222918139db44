#pragma once
#include <cstdio>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

// Layout of a session directory (documented in README.md):
//   transforms.csv  graph.csv  correspondences.csv  report.json  config.yaml  live.jpg  mosaic.png  mosaic.tif
//   frames/   the original bytes of every accepted frame (EXIF kept), named <index>_<source name>
//   features/ per-frame keypoints and 8-bit RootSIFT descriptors (working resolution)
struct SessionPaths {
  std::string root;
  [[nodiscard]] std::string Join(const std::string& name) const { return root + "/" + name; }
  [[nodiscard]] std::string frames() const { return Join("frames"); }
  [[nodiscard]] std::string features() const { return Join("features"); }
};

// Creates the directory tree and proves it is writable. On failure: false and a one-line reason.
[[nodiscard]] bool PrepareSessionDir(const std::string& root, SessionPaths* paths, std::string* error);

// One writer per session directory: an exclusive advisory lock (flock) on "<root>/.lock", which holds the owner's PID.
// Two runs on one directory would truncate each other's edges.bin and journal; the second is refused instead. The
// kernel drops the lock when its process ends, however it ends (a kill leaves nothing to clean up for --resume).
// Owns the lock file's descriptor; movable, not copyable.
class SessionLock {
 public:
  SessionLock() = default;
  ~SessionLock();
  SessionLock(SessionLock&& other) noexcept;
  SessionLock& operator=(SessionLock&& other) noexcept;
  SessionLock(const SessionLock&) = delete;
  SessionLock& operator=(const SessionLock&) = delete;
  // False, with "session directory ... is in use by process N" or the system's reason, when another run holds it or
  // the lock file cannot be made. True but not held() where the filesystem has no locks: unlocked_reason() says why.
  [[nodiscard]] bool Acquire(const SessionPaths& paths, std::string* error);
  [[nodiscard]] bool held() const { return fd_ >= 0; }
  [[nodiscard]] const std::string& unlocked_reason() const { return unlocked_reason_; }

 private:
  int fd_ = -1;
  std::string unlocked_reason_;
};

// Writes via a temp file and rename, so a reader never sees a half-written file.
[[nodiscard]] bool WriteFileAtomic(const std::string& path, std::string_view contents, std::string* error);

// A file written in pieces that appears whole or not at all: data goes to "<path>.tmp", Commit() renames it.
// Dropped without Commit(), the temp file is removed.
class AtomicFileWriter {
 public:
  AtomicFileWriter() = default;
  ~AtomicFileWriter();
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;
  [[nodiscard]] bool Open(const std::string& path, std::string* error);
  void Write(std::string_view data);  // errors are remembered and reported by Commit()
  [[nodiscard]] bool Commit(std::string* error);

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
  bool failed_ = false;
};

inline constexpr const char* kTransformsHeader = "index,filename,registered,a00,a01,a02,a10,a11,a12,h20,h21,placed_by";
// Sessions written before the placed_by column (every registered frame was placed by images); still read.
inline constexpr const char* kTransformsHeaderV1 = "index,filename,registered,a00,a01,a02,a10,a11,a12,h20,h21";

struct TransformRow {
  int index = -1;
  std::string filename;
  bool registered = false;
  Mat3 mosaic_from_frame = Mat3::Identity();  // original-resolution frame pixels -> mosaic.tif pixels
  // How a registered frame got its place: "image" (registration) or "telemetry" (its position, height and heading,
  // where no image linked it); empty when not registered.
  std::string placed_by;
};

[[nodiscard]] std::string FormatTransformsCsv(const std::vector<TransformRow>& rows);
// One row of transforms.csv with its newline (what FormatTransformsCsv writes after the header): a long flight's table
// is streamed row by row.
[[nodiscard]] std::string FormatTransformsRow(const TransformRow& row);
// Parses transforms.csv; rejects a wrong header or malformed registered rows.
[[nodiscard]] bool ParseTransformsCsv(const std::string& text, std::vector<TransformRow>* rows, std::string* error);
[[nodiscard]] bool ReadTextFile(const std::string& path, std::string* text, std::string* error);

}  // namespace uavm
