#include "core/session/session_dir.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <utility>

namespace uavm {

namespace fs = std::filesystem;

bool PrepareSessionDir(const std::string& root, SessionPaths* paths, std::string* error) {
  std::error_code ec;
  paths->root = root;
  for (const std::string& d : {root, paths->frames(), paths->features()}) {
    fs::create_directories(d, ec);
    if (ec || !fs::is_directory(d)) {
      *error = "cannot create output directory " + d + (ec ? ": " + ec.message() : "");
      return false;
    }
  }
  const std::string probe = paths->Join(".write_probe");
  if (!WriteFileAtomic(probe, "ok\n", error)) {
    *error = "output directory is not writable: " + root;
    return false;
  }
  fs::remove(probe, ec);
  return true;
}

SessionLock::~SessionLock() {
  if (fd_ >= 0) ::close(fd_);
}

SessionLock::SessionLock(SessionLock&& other) noexcept
    : fd_(other.fd_), unlocked_reason_(std::move(other.unlocked_reason_)) {
  other.fd_ = -1;
}

SessionLock& SessionLock::operator=(SessionLock&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    unlocked_reason_ = std::move(other.unlocked_reason_);
    other.fd_ = -1;
  }
  return *this;
}

bool SessionLock::Acquire(const SessionPaths& paths, std::string* error) {
  const std::string path = paths.Join(".lock");
  int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  // A lock file another user left (read-only to us) still locks: flock needs no write access.
  if (fd < 0 && errno == EACCES) fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    *error = "cannot create " + path + ": " + std::strerror(errno);
    return false;
  }
  unlocked_reason_.clear();
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int why = errno;
    if (why != EWOULDBLOCK) {
      // A filesystem without locks (some network and FUSE mounts): the run goes on unguarded, and says so.
      ::close(fd);
      unlocked_reason_ = "cannot lock " + path + ": " + std::strerror(why);
      return true;
    }
    char owner[32] = {};
    const ssize_t n = ::pread(fd, owner, sizeof(owner) - 1, 0);
    ::close(fd);
    std::string pid = n > 0 ? std::string(owner, static_cast<size_t>(n)) : std::string("?");
    while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
    *error = "session directory " + paths.root + " is in use by process " + pid +
             " (one run per session; wait for it to end, or choose another --out)";
    return false;
  }
  const std::string pid = std::to_string(::getpid()) + "\n";
  // Without the PID written (a read-only lock file) the lock still holds: only a refused second run's message is
  // poorer.
  [[maybe_unused]] const bool pid_written =
      ::ftruncate(fd, 0) == 0 && ::pwrite(fd, pid.data(), pid.size(), 0) == static_cast<ssize_t>(pid.size());
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
  return true;
}

bool WriteFileAtomic(const std::string& path, std::string_view contents, std::string* error) {
  const std::string tmp = path + ".tmp";
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) {
    *error = "cannot write " + tmp;
    return false;
  }
  const bool wrote = std::fwrite(contents.data(), 1, contents.size(), f) == contents.size();
  const bool closed = std::fclose(f) == 0;
  if (!wrote || !closed || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    *error = "write failed (disk full?): " + path;
    return false;
  }
  return true;
}

AtomicFileWriter::~AtomicFileWriter() {
  if (file_ != nullptr) {
    std::fclose(file_);
    std::remove((path_ + ".tmp").c_str());
  }
}

bool AtomicFileWriter::Open(const std::string& path, std::string* error) {
  path_ = path;
  failed_ = false;
  file_ = std::fopen((path + ".tmp").c_str(), "wb");
  if (file_ == nullptr) {
    *error = "cannot write " + path + ".tmp";
    return false;
  }
  return true;
}

void AtomicFileWriter::Write(std::string_view data) {
  if (file_ == nullptr || failed_) return;
  if (std::fwrite(data.data(), 1, data.size(), file_) != data.size()) failed_ = true;
}

bool AtomicFileWriter::Commit(std::string* error) {
  if (file_ == nullptr) {
    *error = "nothing to commit: " + path_;
    return false;
  }
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  const std::string tmp = path_ + ".tmp";
  if (failed_ || !closed || std::rename(tmp.c_str(), path_.c_str()) != 0) {
    std::remove(tmp.c_str());
    *error = "write failed (disk full?): " + path_;
    return false;
  }
  return true;
}

std::string FormatTransformsRow(const TransformRow& r) {
  std::string out = std::to_string(r.index) + "," + r.filename;
  if (!r.registered) return out + ",0,,,,,,,,,\n";
  // Normalised so the projective part's constant term is 1, as the header's formula assumes.
  const Mat3 m = r.mosaic_from_frame / r.mosaic_from_frame(2, 2);
  char buf[256];  // the numbers only: the file name is appended whole, whatever its length or bytes
  std::snprintf(buf, sizeof(buf), ",1,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g,", m(0, 0), m(0, 1), m(0, 2),
                m(1, 0), m(1, 1), m(1, 2), m(2, 0), m(2, 1));
  out += buf;
  out += (r.placed_by.empty() ? std::string("image") : r.placed_by) + "\n";
  return out;
}

std::string FormatTransformsCsv(const std::vector<TransformRow>& rows) {
  std::string out = std::string(kTransformsHeader) + "\n";
  for (const auto& r : rows) out += FormatTransformsRow(r);
  return out;
}

bool ParseTransformsCsv(const std::string& text, std::vector<TransformRow>* rows, std::string* error) {
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line) || (line != kTransformsHeader && line != kTransformsHeaderV1)) {
    *error = "transforms.csv: unexpected header";
    return false;
  }
  const size_t columns = line == kTransformsHeader ? 12 : 11;
  rows->clear();
  int line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    if (!line.empty() && line.back() == ',') cells.emplace_back();
    if (cells.size() != columns) {
      *error = "transforms.csv line " + std::to_string(line_no) + ": expected " + std::to_string(columns) + " columns";
      return false;
    }
    TransformRow r;
    try {
      r.index = std::stoi(cells[0]);
      r.filename = cells[1];
      r.registered = cells[2] == "1";
      if (r.registered) {
        double v[8];
        for (int k = 0; k < 8; ++k) v[k] = std::stod(cells[static_cast<size_t>(3 + k)]);
        r.mosaic_from_frame << v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], 1.0;
        r.placed_by = columns == 12 ? cells[11] : "image";
        if (r.placed_by != "image" && r.placed_by != "telemetry") {
          *error = "transforms.csv line " + std::to_string(line_no) + ": placed_by must be image or telemetry";
          return false;
        }
      }
    } catch (const std::exception&) {
      *error = "transforms.csv line " + std::to_string(line_no) + ": not a number";
      return false;
    }
    rows->push_back(r);
  }
  return true;
}

bool ReadTextFile(const std::string& path, std::string* text, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot read " + path;
    return false;
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  *text = ss.str();
  return true;
}

}  // namespace uavm
