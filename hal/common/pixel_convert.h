#pragma once
#include <cstddef>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>

#include "hal/common/frame_source.h"

namespace uavm::hal {

// Pixel formats the camera back-ends accept, by their memory layout (not by any one API's name for it).
enum class PixelFormat {
  kYuyv,   // packed 4:2:2, bytes Y0 U Y1 V (V4L2 YUYV, libcamera YUYV)
  kNv12,   // 4:2:0, a Y plane then an interleaved UV plane at `stride * height` (V4L2 NV12, libcamera NV12)
  kMjpeg,  // one JPEG image per buffer (V4L2 MJPG, libcamera MJPEG)
  kRgb24,  // bytes R G B (V4L2 RGB24, libcamera BGR888)
  kBgr24,  // bytes B G R (V4L2 BGR24, libcamera RGB888)
};

// "YUYV", "NV12", "MJPEG" (also "MJPG"), "RGB24", "BGR24"; case-insensitive.
[[nodiscard]] bool ParsePixelFormat(const std::string& name, PixelFormat* format);
[[nodiscard]] const char* ToString(PixelFormat format);

// One captured image in driver memory (borrowed: only valid while its buffer is held).
struct RawImage {
  const uint8_t* data = nullptr;
  size_t bytes = 0;  // bytes used
  int width = 0;
  int height = 0;
  int stride = 0;  // bytes per line of the first plane (0 = packed)
  PixelFormat format = PixelFormat::kYuyv;
};

// Converts to 8-bit BGR, what the matcher takes, into `out` (reallocated only when its size or type differs).
// YUV uses the BT.601 limited-range matrix (what V4L2 drivers default to for SDTV/webcam sizes). A buffer shorter
// than its format needs, or a JPEG that does not decode to the negotiated size, is kSkipped with the reason in
// `error` (a damaged frame, the stream goes on).
[[nodiscard]] Status ConvertToBgr(const RawImage& raw, cv::Mat* out, std::string* error);

}  // namespace uavm::hal
