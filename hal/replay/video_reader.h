#pragma once
// The frames of a video file for ReplaySource. OpenCV's videoio reads them, but from a module of its own
// (libuavm_video_reader.so) that is loaded only when a video is replayed: videoio linked into the onboard program
// mapped ~100 more shared libraries (FFmpeg, GStreamer and theirs) at every start, 0.1 s and 18 MB of RSS on a 2-core
// x86-64, for a source most flights never use.
#include <memory>
#include <opencv2/core.hpp>
#include <string>

namespace uavm::hal {

class VideoReader {
 public:
  virtual ~VideoReader() = default;
  // The next frame (8-bit, 1 or 3 channels); false at the end of the stream.
  [[nodiscard]] virtual bool Read(cv::Mat* image) = 0;
  // Skips a frame; false at the end of the stream.
  [[nodiscard]] virtual bool Grab() = 0;
};

// Opens `path` through the module: UAVM_VIDEO_READER (a path) when set, else lib/uavmosaic/ beside the program's
// bin/ (the installed layout), else the build tree's. The module stays loaded for the process's life (a reader's code
// lives in it). nullptr with the reason when the module or the video cannot be opened.
[[nodiscard]] std::unique_ptr<VideoReader> OpenVideo(const std::string& path, std::string* error);

}  // namespace uavm::hal

// The module's entry point: a reader of `path`, or nullptr when no back-end opens it. The caller owns the reader.
extern "C" uavm::hal::VideoReader* uavm_open_video(const char* path);
