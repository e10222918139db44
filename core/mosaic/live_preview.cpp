#include "core/mosaic/live_preview.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm {

namespace {

// The part of the canvas a paste of a `thumb`-sized image by `view_from_thumb` touches, with 2 px of room so that the
// erosion of its mask sees the footprint's edge; empty when nothing lands (or the map is not finite, or puts a corner
// behind the camera). Warping the whole canvas instead cost two canvas-sized buffers (4 MiB at 1024 px) and a
// canvas-wide warp, erosion and copy per frame.
cv::Rect PasteBox(const Mat3& view_from_thumb, cv::Size thumb, cv::Size canvas) {
  if (!view_from_thumb.allFinite()) return {};
  // The pixels' outer edges, not their centres: a nearest-neighbour mask reaches half a source pixel beyond them.
  const double x1 = thumb.width - 0.5;
  const double y1 = thumb.height - 0.5;
  double x_min = std::numeric_limits<double>::infinity();
  double y_min = x_min;
  double x_max = -x_min;
  double y_max = -x_min;
  for (const Vec2& corner : {Vec2(-0.5, -0.5), Vec2(x1, -0.5), Vec2(x1, y1), Vec2(-0.5, y1)}) {
    const Eigen::Vector3d h = view_from_thumb * Eigen::Vector3d(corner.x(), corner.y(), 1.0);
    if (!(h.z() > 0)) return {};
    x_min = std::min(x_min, h.x() / h.z());
    x_max = std::max(x_max, h.x() / h.z());
    y_min = std::min(y_min, h.y() / h.z());
    y_max = std::max(y_max, h.y() / h.z());
  }
  constexpr double kRoom = 2.0;
  const double limit = 4.0 * std::max(canvas.width, canvas.height);  // keeps the casts below in range
  const auto at = [limit](double v) { return static_cast<int>(std::clamp(v, -limit, limit)); };
  const cv::Point lo(at(std::floor(x_min - kRoom)), at(std::floor(y_min - kRoom)));
  const cv::Point hi(at(std::ceil(x_max + kRoom)) + 1, at(std::ceil(y_max + kRoom)) + 1);
  return cv::Rect(lo, hi) & cv::Rect(cv::Point(0, 0), canvas);
}

}  // namespace

LivePreview::LivePreview(int canvas_side)
    : side_(canvas_side), canvas_(canvas_side, canvas_side, CV_8UC3, cv::Scalar::all(0)) {}

void LivePreview::Add(const cv::Mat& thumb, const Mat3& mosaic_from_thumb) {
  if (thumb.empty()) return;
  const cv::Rect2d fp = cv::boundingRect(Footprint(mosaic_from_thumb, thumb.cols, thumb.rows));
  const cv::Rect2d wanted = empty_ ? fp : (content_ | fp);
  const cv::Rect2d view_rect(0, 0, side_, side_);
  const auto in_view = [&](const cv::Rect2d& r) {
    const Vec2 a = Apply(view_from_mosaic_, Vec2(r.x, r.y));
    const Vec2 b = Apply(view_from_mosaic_, Vec2(r.x + r.width, r.y + r.height));
    return a.x() >= 0 && a.y() >= 0 && b.x() < side_ && b.y() < side_;
  };
  if (empty_ || !in_view(wanted)) {
    // Refit with 25 % room to grow, so the picture is not rescaled on every frame.
    const double extent = std::max(wanted.width, wanted.height) * 1.25;
    const double s = std::min(empty_ ? 1.0 : 1e9, side_ / extent);
    const double cx = wanted.x + wanted.width / 2;
    const double cy = wanted.y + wanted.height / 2;
    Mat3 next = Mat3::Identity();
    next(0, 0) = next(1, 1) = s;
    next(0, 2) = side_ / 2.0 - s * cx;
    next(1, 2) = side_ / 2.0 - s * cy;
    if (!empty_) {
      const Mat3 new_from_old = next * view_from_mosaic_.inverse();
      cv::Mat moved;
      cv::warpAffine(canvas_, moved, cv::Mat(ToCvAffine(new_from_old)), canvas_.size(), cv::INTER_AREA);
      canvas_ = moved;
    }
    view_from_mosaic_ = next;
  }
  const Mat3 view_from_thumb = view_from_mosaic_ * mosaic_from_thumb;
  const cv::Rect roi = PasteBox(view_from_thumb, thumb.size(), canvas_.size());
  if (roi.empty()) {
    content_ = wanted;
    empty_ = false;
    return;
  }
  Mat3 roi_from_view = Mat3::Identity();
  roi_from_view(0, 2) = -roi.x;
  roi_from_view(1, 2) = -roi.y;
  const Mat3 roi_from_thumb = roi_from_view * view_from_thumb;
  cv::Mat mask(thumb.size(), CV_8U, cv::Scalar(255));
  cv::Mat warped;
  cv::Mat warped_mask;
  if (IsAffine(roi_from_thumb, 1e-12)) {
    cv::warpAffine(thumb, warped, cv::Mat(ToCvAffine(roi_from_thumb)), roi.size(), cv::INTER_LINEAR);
    cv::warpAffine(mask, warped_mask, cv::Mat(ToCvAffine(roi_from_thumb)), roi.size(), cv::INTER_NEAREST);
  } else {
    cv::warpPerspective(thumb, warped, cv::Mat(ToCv(roi_from_thumb)), roi.size(), cv::INTER_LINEAR);
    cv::warpPerspective(mask, warped_mask, cv::Mat(ToCv(roi_from_thumb)), roi.size(), cv::INTER_NEAREST);
  }
  // Bilinear warping blends the thumbnail's edge with black: leave that 1 px rim out.
  cv::erode(warped_mask, warped_mask, cv::Mat());
  cv::Mat target = canvas_(roi);
  warped.copyTo(target, warped_mask);
  content_ = wanted;
  empty_ = false;
}

cv::Rect LivePreview::ContentInView() const {
  const cv::Rect whole(0, 0, canvas_.cols, canvas_.rows);
  if (empty_) return whole;
  const Vec2 a = Apply(view_from_mosaic_, Vec2(content_.x, content_.y));
  const Vec2 b = Apply(view_from_mosaic_, Vec2(content_.x + content_.width, content_.y + content_.height));
  constexpr int kMargin = 4;
  const cv::Point lo(static_cast<int>(std::floor(std::min(a.x(), b.x()))) - kMargin,
                     static_cast<int>(std::floor(std::min(a.y(), b.y()))) - kMargin);
  const cv::Point hi(static_cast<int>(std::ceil(std::max(a.x(), b.x()))) + kMargin,
                     static_cast<int>(std::ceil(std::max(a.y(), b.y()))) + kMargin);
  const cv::Rect r = cv::Rect(lo, hi) & whole;
  return r.area() > 0 ? r : whole;
}

bool LivePreview::Write(const std::string& path, std::string* error) const {
  const std::string tmp = path + ".tmp";
  std::vector<uchar> bytes;
  const cv::Rect crop = ContentInView();
  if (!cv::imencode(".jpg", canvas_(crop), bytes, {cv::IMWRITE_JPEG_QUALITY, 85})) {
    *error = "JPEG encode failed";
    return false;
  }
  last_jpeg_ = std::make_shared<const std::string>(bytes.begin(), bytes.end());
  Mat3 jpeg_from_view = Mat3::Identity();
  jpeg_from_view(0, 2) = -crop.x;
  jpeg_from_view(1, 2) = -crop.y;
  last_jpeg_from_mosaic_ = jpeg_from_view * view_from_mosaic_;
  last_jpeg_size_ = crop.size();
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) {
    *error = "cannot write " + tmp;
    return false;
  }
  const bool ok = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size();
  if (std::fclose(f) != 0 || !ok) {
    std::remove(tmp.c_str());
    *error = "write failed: " + tmp;
    return false;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    *error = "rename failed: " + path;
    return false;
  }
  return true;
}

}  // namespace uavm
