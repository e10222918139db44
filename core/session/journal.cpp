#include "core/session/journal.h"

#include <unistd.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>

#include "core/session/session_dir.h"

namespace uavm {

namespace {

// The optional position fields of a frame line, by key (pointers into `f`: const or not as `f` is).
template <typename Frame>
auto PoseFields(Frame& f) {
  using Field = decltype(&f.latitude_deg);
  return std::array<std::pair<const char*, Field>, 4>{
      {{"lat", &f.latitude_deg}, {"lon", &f.longitude_deg}, {"rel_alt", &f.relative_altitude_m}, {"yaw", &f.yaw_deg}}};
}

// A value that is not a finite number is left out (the frame is then placed as if it had none).
void ReadPose(const nlohmann::json& j, JournalFrame* f) {
  for (const auto& [key, value] : PoseFields(*f)) {
    const auto it = j.find(key);
    if (it == j.end() || !it->is_number()) continue;
    const double v = it->get<double>();
    if (std::isfinite(v)) *value = v;
  }
}
constexpr int kVersion = 1;
// File names are bytes, JSON is UTF-8: invalid sequences are replaced rather than thrown on.
std::string Dump(const nlohmann::json& j) {
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

// An integer field within [lo, hi]; anything else (missing, a float, a string, out of range) is not this program's
// journal. nlohmann's get<int>() of 2e76 would be undefined behaviour, hence the checks first.
bool IntField(const nlohmann::json& j, const char* key, int64_t lo, int64_t hi, int64_t* out) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_number_integer()) return false;
  if (it->is_number_unsigned()) {
    const uint64_t u = it->get<uint64_t>();
    if (u > static_cast<uint64_t>(hi)) return false;
    *out = static_cast<int64_t>(u);
  } else {
    *out = it->get<int64_t>();
  }
  return *out >= lo && *out <= hi;
}
}  // namespace

bool ParseJournal(const std::string& text, JournalContents* out, std::string* error) {
  *out = JournalContents{};
  size_t pos = 0;
  bool first = true;
  while (pos < text.size()) {
    const size_t nl = text.find('\n', pos);
    if (nl == std::string::npos) {
      out->torn_lines = 1;  // the kill came in the middle of a write
      break;
    }
    const nlohmann::json j = nlohmann::json::parse(text.begin() + static_cast<long>(pos),
                                                   text.begin() + static_cast<long>(nl), nullptr, false);
    if (j.is_discarded() || !j.is_object() || !j.contains("type") || !j["type"].is_string()) {
      if (first) {
        *error = "not a uavmosaic session journal";
        return false;
      }
      out->torn_lines = 1;
      break;
    }
    const std::string type = j["type"].get<std::string>();
    try {
      if (first) {
        int64_t version = 0;
        if (type != "session" || !IntField(j, "version", 0, 1 << 20, &version) || version != kVersion) {
          *error = "not a uavmosaic session journal (or a newer version)";
          return false;
        }
      } else if (type == "frame") {
        JournalFrame f;
        int64_t id = 0;
        int64_t width = 0;
        int64_t height = 0;
        constexpr int64_t kMaxInt = std::numeric_limits<int>::max();
        if (!IntField(j, "id", 0, kMaxInt, &id) || !IntField(j, "width", 1, kMaxInt, &width) ||
            !IntField(j, "height", 1, kMaxInt, &height) ||
            !IntField(j, "timestamp_ns", std::numeric_limits<int64_t>::min(), std::numeric_limits<int64_t>::max(),
                      &f.timestamp_ns)) {
          out->torn_lines = 1;
          break;
        }
        f.id = static_cast<int>(id);
        f.width = static_cast<int>(width);
        f.height = static_cast<int>(height);
        f.name = j.at("name").get<std::string>();
        f.stored_file = j.at("stored").get<std::string>();
        ReadPose(j, &f);
        // Frames are journaled in id order, one each: anything else is not this program's journal.
        if (f.id != static_cast<int>(out->frames.size()) || f.width <= 0 || f.height <= 0 ||
            f.stored_file.find('/') != std::string::npos || f.stored_file.empty()) {
          out->torn_lines = 1;
          break;
        }
        out->frames.push_back(std::move(f));
      } else if (type == "skipped") {
        out->skipped.push_back({j.at("name").get<std::string>(), j.at("reason").get<std::string>()});
      } else if (type == "finished") {
        out->finished = true;
      }  // "resumed" and unknown types: informational
    } catch (const nlohmann::json::exception&) {
      out->torn_lines = 1;
      break;
    }
    first = false;
    pos = nl + 1;
    out->valid_bytes = pos;
  }
  return true;
}

bool ReadJournal(const std::string& path, JournalContents* out, std::string* error) {
  *out = JournalContents{};
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return true;
  std::string text;
  if (!ReadTextFile(path, &text, error)) return false;
  return ParseJournal(text, out, error);
}

SessionJournal::~SessionJournal() {
  Close();
}

bool SessionJournal::Open(const std::string& path, bool append, uint64_t valid_bytes, int sync_every,
                          std::string* error) {
  Close();
  path_ = path;
  sync_every_ = std::max(1, sync_every);
  std::error_code ec;
  if (append && !std::filesystem::exists(path, ec)) append = false;  // killed before its first line: start anew
  if (append) {
    // Cut off a torn last line before appending after it.
    std::filesystem::resize_file(path, valid_bytes, ec);
    if (ec) {
      *error = "cannot repair journal " + path + ": " + ec.message();
      return false;
    }
  }
  file_ = std::fopen(path.c_str(), append ? "ab" : "wb");
  if (file_ == nullptr) {
    *error = "cannot write journal " + path;
    return false;
  }
  if (!append || valid_bytes == 0) {
    nlohmann::json j{{"type", "session"}, {"version", kVersion}};
    return WriteLine(Dump(j), true, error);
  }
  return true;
}

void SessionJournal::Close() {
  if (file_ != nullptr) {
    std::fflush(file_);
    ::fdatasync(fileno(file_));
    std::fclose(file_);
  }
  file_ = nullptr;
}

bool SessionJournal::WriteLine(const std::string& line, bool sync, std::string* error) {
  if (file_ == nullptr) {
    *error = "journal not open";
    return false;
  }
  const std::string with_newline = line + "\n";
  // One fwrite + fflush per line: the kernel gets whole lines, so a killed process leaves at most one torn line.
  if (std::fwrite(with_newline.data(), 1, with_newline.size(), file_) != with_newline.size() ||
      std::fflush(file_) != 0) {
    *error = "journal write failed (disk full?): " + path_;
    return false;
  }
  if (sync || ++since_sync_ >= sync_every_) {
    since_sync_ = 0;
    ++syncs_;
    if (::fdatasync(fileno(file_)) != 0) {
      *error = "journal sync failed: " + path_;
      return false;
    }
  }
  return true;
}

bool SessionJournal::AddFrame(const JournalFrame& f, std::string* error) {
  nlohmann::json j{{"type", "frame"},
                   {"id", f.id},
                   {"name", f.name},
                   {"stored", f.stored_file},
                   {"timestamp_ns", f.timestamp_ns},
                   {"width", f.width},
                   {"height", f.height}};
  for (const auto& [key, value] : PoseFields(f))
    if (*value) j[key] = **value;
  return WriteLine(Dump(j), false, error);
}

bool SessionJournal::AddSkip(const JournalSkip& s, std::string* error) {
  const nlohmann::json j{{"type", "skipped"}, {"name", s.name}, {"reason", s.reason}};
  return WriteLine(Dump(j), false, error);
}

bool SessionJournal::AddResumed(size_t frames, std::string* error) {
  const nlohmann::json j{{"type", "resumed"}, {"frames", frames}};
  return WriteLine(Dump(j), true, error);
}

bool SessionJournal::AddFinished(std::string* error) {
  const nlohmann::json j{{"type", "finished"}};
  return WriteLine(Dump(j), true, error);
}

}  // namespace uavm
