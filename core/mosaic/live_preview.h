#pragma once
#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "core/geometry/transform.h"

namespace uavm {

// The operator's progress picture: a fixed-size canvas (memory does not grow with the flight) onto which each newly
// registered frame's thumbnail is pasted with its transform at the time. When the flight leaves the canvas, the
// picture is shrunk to make room. The JPEG holds the part of the canvas the flight covers (the canvas keeps room to
// grow; a viewer should not have to show it). Written atomically (temp file + rename) so a viewer never sees half a
// JPEG.
class LivePreview {
 public:
  explicit LivePreview(int canvas_side = 1024);
  void Add(const cv::Mat& thumbnail_bgr, const Mat3& mosaic_from_thumbnail);
  [[nodiscard]] bool Write(const std::string& path, std::string* error) const;
  [[nodiscard]] const cv::Mat& image() const { return canvas_; }
  // The JPEG bytes of the last Write(), shared (immutable) with readers such as the live HTTP server.
  [[nodiscard]] std::shared_ptr<const std::string> last_jpeg() const { return last_jpeg_; }
  // The last Write()'s JPEG: its pixels from mosaic coordinates and its size (what its georeference composes with).
  [[nodiscard]] const Mat3& last_jpeg_from_mosaic() const { return last_jpeg_from_mosaic_; }
  [[nodiscard]] cv::Size last_jpeg_size() const { return last_jpeg_size_; }

 private:
  [[nodiscard]] cv::Rect ContentInView() const;  // the covered part of the canvas, in canvas pixels

  int side_;
  cv::Mat canvas_;
  Mat3 view_from_mosaic_ = Mat3::Identity();
  bool empty_ = true;
  cv::Rect2d content_;  // mosaic coordinates covered so far
  mutable std::shared_ptr<const std::string> last_jpeg_;
  mutable Mat3 last_jpeg_from_mosaic_ = Mat3::Identity();
  mutable cv::Size last_jpeg_size_;
};

}  // namespace uavm
