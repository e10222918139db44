// libuavm_video_reader.so: hal/replay/video_reader.h's reader on OpenCV's videoio (see there why a module).
#include <opencv2/videoio.hpp>
#include <opencv2/videoio/registry.hpp>

#include "hal/replay/video_reader.h"

namespace uavm::hal {
namespace {

class OpenCvVideoReader final : public VideoReader {
 public:
  explicit OpenCvVideoReader(const char* path)
      // FFmpeg reads every container a drone writes; asking for it alone keeps OpenCV from probing its other
      // back-ends (GStreamer, camera plugins) on a file that does not open: slow, and their plugins never free what
      // they take.
      : capture_(path, cv::videoio_registry::hasBackend(cv::CAP_FFMPEG) ? cv::CAP_FFMPEG : cv::CAP_ANY) {}
  ~OpenCvVideoReader() override { capture_.release(); }
  [[nodiscard]] bool opened() const { return capture_.isOpened(); }
  bool Read(cv::Mat* image) override { return capture_.read(*image) && !image->empty(); }
  bool Grab() override { return capture_.grab(); }

 private:
  cv::VideoCapture capture_;
};

}  // namespace
}  // namespace uavm::hal

extern "C" __attribute__((visibility("default"))) uavm::hal::VideoReader* uavm_open_video(const char* path) {
  try {
    auto reader = std::make_unique<uavm::hal::OpenCvVideoReader>(path);
    return reader->opened() ? reader.release() : nullptr;
  } catch (const std::exception&) {  // OpenCV's own errors (cv::Exception) included: none crosses the module's edge
    return nullptr;
  }
}
