#pragma once
// A frame stored in the session (frames/) read back at a given size: JPEG DCT-scaled decode by 1/reduce (2-3x
// cheaper than a full decode), then resized to `size`. Used by the compositor (at the canvas's sampling) and the live
// tiles (at the working size); thread-safe. Empty on an unreadable file.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

namespace uavm {

inline cv::Mat LoadStoredFrame(const std::string& path, cv::Size size, int reduce) {
  const int flag = reduce >= 8   ? cv::IMREAD_REDUCED_COLOR_8
                   : reduce >= 4 ? cv::IMREAD_REDUCED_COLOR_4
                   : reduce >= 2 ? cv::IMREAD_REDUCED_COLOR_2
                                 : cv::IMREAD_COLOR;
  cv::Mat img;
  try {
    img = cv::imread(path, flag | cv::IMREAD_IGNORE_ORIENTATION);
  } catch (const cv::Exception&) {
    return {};
  }
  if (img.empty() || img.size() == size) return img;
  cv::Mat out;
  cv::resize(img, out, size, 0, 0, cv::INTER_AREA);
  return out;
}

}  // namespace uavm
