#include "core/pipeline/canvas_load.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "core/imageio/jpeg_region.h"
#include "core/pipeline/stored_frame.h"

namespace uavm {

namespace {

bool IsJpeg(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".jpg" || ext == ".jpeg";
}

}  // namespace

CanvasLoad PlanCanvasLoad(const std::string& path, cv::Size original, double keep) {
  CanvasLoad how;
  // DCT-scaled decoding is 2-3x cheaper than full; a decode up to 1.25x coarser than the canvas is accepted for it.
  while (how.reduce < 8 && 1.25 / (how.reduce * 2) >= keep) how.reduce *= 2;
  const cv::Size wanted(std::max(1, static_cast<int>(std::lround(original.width * keep))),
                        std::max(1, static_cast<int>(std::lround(original.height * keep))));
  how.jpeg = IsJpeg(path);
  // libjpeg's scaled output is ceil(size / reduce); other formats are decoded whole (OpenCV then shrinks them).
  how.decoded = how.jpeg ? cv::Size((original.width + how.reduce - 1) / how.reduce,
                                    (original.height + how.reduce - 1) / how.reduce)
                         : original;
  const auto bytes = [](cv::Size s) { return static_cast<size_t>(s.area()) * 3; };
  if (how.jpeg && how.decoded.width <= wanted.width) {
    how.size = how.decoded;  // used as decoded
    how.peak_bytes = bytes(how.decoded);
  } else {
    how.size = wanted;
    how.peak_bytes = bytes(how.decoded) + bytes(wanted);
  }
  return how;
}

FramePart LoadCanvasPart(const std::string& path, const CanvasLoad& how, const cv::Rect& need) {
  if (how.jpeg) {
    const double sx = static_cast<double>(how.size.width) / how.decoded.width;
    const double sy = static_cast<double>(how.size.height) / how.decoded.height;
    const bool resized = how.size != how.decoded;
    // A resized part starts and ends 2 decoded px beyond what it needs: INTER_AREA's cells stay inside it.
    const cv::Rect region = !resized ? need
                                     : cv::Rect(cv::Point(static_cast<int>(std::floor(need.x / sx)) - 2,
                                                          static_cast<int>(std::floor(need.y / sy)) - 2),
                                                cv::Point(static_cast<int>(std::ceil(need.br().x / sx)) + 2,
                                                          static_cast<int>(std::ceil(need.br().y / sy)) + 2));
    JpegRegion part;
    std::string why;
    if (DecodeJpegRegion(path, static_cast<unsigned>(how.reduce), region, &part, &why) &&
        part.scaled_size == how.decoded) {
      if (!resized) return FramePart{std::move(part.bgr), cv::Point2d(part.origin)};
      cv::Mat out;
      cv::resize(part.bgr, out, cv::Size(), sx, sy, cv::INTER_AREA);
      return FramePart{std::move(out), cv::Point2d(part.origin.x * sx, part.origin.y * sy)};
    }
    spdlog::debug("composite: {} loaded whole ({})", path, why.empty() ? "unexpected scaled size" : why);
  }
  return FramePart{LoadStoredFrame(path, how.size, how.reduce), cv::Point2d()};
}

}  // namespace uavm
