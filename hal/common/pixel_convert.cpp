#include "hal/common/pixel_convert.h"

#include <algorithm>
#include <cctype>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm::hal {

bool ParsePixelFormat(const std::string& name, PixelFormat* format) {
  std::string n = name;
  std::transform(n.begin(), n.end(), n.begin(), [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
  if (n == "YUYV")
    *format = PixelFormat::kYuyv;
  else if (n == "NV12")
    *format = PixelFormat::kNv12;
  else if (n == "MJPEG" || n == "MJPG")
    *format = PixelFormat::kMjpeg;
  else if (n == "RGB24")
    *format = PixelFormat::kRgb24;
  else if (n == "BGR24")
    *format = PixelFormat::kBgr24;
  else
    return false;
  return true;
}

const char* ToString(PixelFormat format) {
  switch (format) {
    case PixelFormat::kYuyv:
      return "YUYV";
    case PixelFormat::kNv12:
      return "NV12";
    case PixelFormat::kMjpeg:
      return "MJPEG";
    case PixelFormat::kRgb24:
      return "RGB24";
    case PixelFormat::kBgr24:
      return "BGR24";
  }
  return "?";
}

namespace {

Status TooShort(const RawImage& raw, size_t need, std::string* error) {
  *error = std::string(ToString(raw.format)) + " buffer of " + std::to_string(raw.bytes) + " bytes, " +
           std::to_string(need) + " needed for " + std::to_string(raw.width) + "x" + std::to_string(raw.height);
  return Status::kSkipped;
}

}  // namespace

Status ConvertToBgr(const RawImage& raw, cv::Mat* out, std::string* error) {
  if (raw.data == nullptr || raw.width <= 0 || raw.height <= 0) {
    *error = "empty buffer";
    return Status::kSkipped;
  }
  const auto w = static_cast<size_t>(raw.width);
  const auto h = static_cast<size_t>(raw.height);
  // cv::Mat headers over driver memory: read-only use, the const_cast never leads to a write.
  auto* data = const_cast<uint8_t*>(raw.data);
  switch (raw.format) {
    case PixelFormat::kYuyv: {
      const size_t stride = raw.stride > 0 ? static_cast<size_t>(raw.stride) : w * 2;
      if (raw.width % 2 != 0 || stride < w * 2) {
        *error = "YUYV needs an even width and a stride of at least 2 bytes per pixel";
        return Status::kSkipped;
      }
      const size_t need = stride * (h - 1) + w * 2;
      if (raw.bytes < need) return TooShort(raw, need, error);
      const cv::Mat src(raw.height, raw.width, CV_8UC2, data, stride);
      cv::cvtColor(src, *out, cv::COLOR_YUV2BGR_YUYV);
      return Status::kOk;
    }
    case PixelFormat::kNv12: {
      const size_t stride = raw.stride > 0 ? static_cast<size_t>(raw.stride) : w;
      if (raw.width % 2 != 0 || raw.height % 2 != 0 || stride < w) {
        *error = "NV12 needs an even width and height";
        return Status::kSkipped;
      }
      const size_t need = stride * h * 3 / 2;
      if (raw.bytes < need) return TooShort(raw, need, error);
      // Y rows then UV rows, both at `stride`: one (h * 3/2) x w single-channel image as OpenCV expects.
      const cv::Mat src(raw.height * 3 / 2, raw.width, CV_8UC1, data, stride);
      cv::cvtColor(src, *out, cv::COLOR_YUV2BGR_NV12);
      return Status::kOk;
    }
    case PixelFormat::kRgb24:
    case PixelFormat::kBgr24: {
      const size_t stride = raw.stride > 0 ? static_cast<size_t>(raw.stride) : w * 3;
      if (stride < w * 3) {
        *error = "24-bit RGB stride shorter than the width";
        return Status::kSkipped;
      }
      const size_t need = stride * (h - 1) + w * 3;
      if (raw.bytes < need) return TooShort(raw, need, error);
      const cv::Mat src(raw.height, raw.width, CV_8UC3, data, stride);
      if (raw.format == PixelFormat::kRgb24)
        cv::cvtColor(src, *out, cv::COLOR_RGB2BGR);
      else
        src.copyTo(*out);
      return Status::kOk;
    }
    case PixelFormat::kMjpeg: {
      if (raw.bytes < 4 || raw.data[0] != 0xFF || raw.data[1] != 0xD8) {
        *error = "MJPEG buffer does not start with a JPEG SOI marker";
        return Status::kSkipped;
      }
      const cv::Mat src(1, static_cast<int>(raw.bytes), CV_8UC1, data);
      cv::Mat decoded;
      try {
        decoded = cv::imdecode(src, cv::IMREAD_COLOR);
      } catch (const cv::Exception& e) {
        *error = std::string("MJPEG frame does not decode: ") + e.what();
        return Status::kSkipped;
      }
      if (decoded.empty()) {
        *error = "MJPEG frame does not decode";
        return Status::kSkipped;
      }
      if (decoded.cols != raw.width || decoded.rows != raw.height) {
        *error = "MJPEG frame is " + std::to_string(decoded.cols) + "x" + std::to_string(decoded.rows) + ", " +
                 std::to_string(raw.width) + "x" + std::to_string(raw.height) + " negotiated";
        return Status::kSkipped;
      }
      *out = std::move(decoded);
      return Status::kOk;
    }
  }
  *error = "unknown pixel format";
  return Status::kSkipped;
}

}  // namespace uavm::hal
