#pragma once
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "hal/common/frame_source.h"
#include "hal/replay/video_reader.h"

namespace uavm::hal {

struct ReplayOptions {
  std::string path;  // an image folder or a video file
  int stride = 1;    // take every stride-th input (video frames or folder files)
  bool read_metadata = true;
};

// File replay: every file of an image folder in natural filename order, or the frames of a video file.
// Files that are not images, or cannot be decoded, come back as kSkipped with the reason.
class ReplaySource final : public FrameSource {
 public:
  explicit ReplaySource(ReplayOptions options);
  [[nodiscard]] Status Open(std::string* error) override;
  [[nodiscard]] Status Next(Frame* frame, std::string* error) override;
  void Close() override;
  [[nodiscard]] std::string Describe() const override;
  [[nodiscard]] size_t NumFiles() const { return files_.size(); }

 private:
  [[nodiscard]] Status NextFile(Frame* frame, std::string* error);
  [[nodiscard]] Status NextVideo(Frame* frame, std::string* error);

  ReplayOptions options_;
  std::vector<std::string> files_;
  size_t next_file_ = 0;
  std::unique_ptr<VideoReader> video_;
  uint64_t next_index_ = 0;
  uint64_t video_frame_ = 0;
  struct Seen {
    size_t size;
    std::string name;
  };
  std::unordered_map<size_t, Seen> seen_;  // content hash of every frame delivered: duplicates are skipped
  // The file being decoded, kept between frames: a fresh 4 MB buffer a photo was a fresh mapping, zeroed page by page
  // by the kernel and then by resize() (~8 % of the flight's CPU on brighton_beach, perf). Freed by Close().
  std::vector<uchar> file_bytes_;
};

}  // namespace uavm::hal
