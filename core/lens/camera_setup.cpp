#include "core/lens/camera_setup.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "core/lens/lens_database.h"

namespace uavm {

namespace {

constexpr double kFullFrameDiagonalMm = 43.2666;  // 36 x 24 mm
constexpr double kDefaultHalfDiagonalDeg = 42.0;

double FocalFrom35mm(double focal_35mm, cv::Size size) {
  return focal_35mm / kFullFrameDiagonalMm * std::hypot(size.width, size.height);
}

}  // namespace

bool CameraOptions::Check(std::string* why) const {
  const bool finite = std::isfinite(k1) && std::isfinite(k2) && std::isfinite(p1) && std::isfinite(p2);
  if (!finite || std::abs(k1) > 2 || std::abs(k2) > 2 || std::abs(p1) > 0.1 || std::abs(p2) > 0.1 || !(focal_px >= 0)) {
    if (why != nullptr) *why = "camera: |k1|, |k2| <= 2, |p1|, |p2| <= 0.1, focal_px >= 0 (0 = from EXIF)";
    return false;
  }
  return true;
}

CameraChoice ChooseCamera(const CameraOptions& options, const FrameMetadata& metadata, cv::Size original) {
  CameraChoice c;
  double focal = options.focal_px;
  c.focal_from = "configuration";
  if (!(focal > 0) && metadata.focal_length_35mm && *metadata.focal_length_35mm > 0) {
    focal = FocalFrom35mm(*metadata.focal_length_35mm, original);
    c.focal_from = "exif_35mm";
  }
  if (!(focal > 0)) {
    focal = 0.5 * std::hypot(original.width, original.height) / std::tan(kDefaultHalfDiagonalDeg * CV_PI / 180.0);
    c.focal_from = "default";
  }
  c.camera = PinholeCamera::Centred(original.width, original.height, focal, {});
  c.source = "none";
  if (options.Configured()) {
    c.camera.distortion = {options.k1, options.k2, options.p1, options.p2};
    c.source = "configuration";
    return c;
  }
  if (!options.database) {
    c.detail = "database lookup off";
    return c;
  }
  LensDatabaseEntry entry;
  if (!LookUpLensDistortion(metadata.make, metadata.model, metadata.focal_length_mm.value_or(0.0), c.camera, &entry,
                            &c.detail))
    return c;
  if (c.focal_from == "default" && metadata.focal_length_mm && entry.crop_factor > 0) {
    // The database's crop factor gives the 35 mm equivalent EXIF left out: look up again with the real focal.
    c.camera.focal_px = FocalFrom35mm(*metadata.focal_length_mm * entry.crop_factor, original);
    c.focal_from = "exif_crop_factor";
    if (!LookUpLensDistortion(metadata.make, metadata.model, *metadata.focal_length_mm, c.camera, &entry, &c.detail))
      return c;
  }
  c.detail = entry.camera + ", " + entry.lens;
  if (entry.raw_files) {
    // This program reads processed frames (JPEG, video, a camera's stream): a compact corrects its lens in them
    // (caliterra's Canon: -16 % in the raw-file entry, ~-1 % left in its JPEGs). Resampled by the raw lens, the
    // frames lost their periphery to the crop and the maps disagreed with independent matches (COLMAP's: 27 % of
    // them beyond 3 px against 8 % on the recorded pixels, bench/independent_score.sh); the self-calibration
    // starts from the recorded pixels instead.
    c.detail += ": calibrated on raw files, not used for processed frames";
    return c;
  }
  c.camera.distortion = entry.distortion;
  c.source = "database";
  return c;
}

Undistorter::Undistorter(const PinholeCamera& camera) : active_(!camera.distortion.IsZero()), camera_(camera) {
  if (!active_) return;
  cv::Mat map_x(camera.height, camera.width, CV_32FC1), map_y(camera.height, camera.width, CV_32FC1);
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      const Vec2 d = camera.DistortPixel(Vec2(x, y));
      map_x.at<float>(y, x) = static_cast<float>(d.x());
      map_y.at<float>(y, x) = static_cast<float>(d.y());
    }
  cv::convertMaps(map_x, map_y, map1_, map2_, CV_16SC2);
}

void Undistorter::UndistortPoints(std::vector<cv::Point2f>* points) const {
  if (!active_) return;
  for (auto& p : *points) {
    const Vec2 u = camera_.UndistortPixel(Vec2(p.x, p.y));
    p = cv::Point2f(static_cast<float>(u.x()), static_cast<float>(u.y()));
  }
}

cv::Mat Undistorter::UndistortImage(const cv::Mat& recorded) const {
  if (!active_ || recorded.cols != camera_.width || recorded.rows != camera_.height) return recorded;
  cv::Mat ideal;
  cv::remap(recorded, ideal, map1_, map2_, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return ideal;
}

cv::Rect RecordedRectFor(const PinholeCamera& camera, const cv::Rect& ideal) {
  double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
  constexpr int kSteps = 16;
  const auto extend = [&](double x, double y) {
    const Vec2 d = camera.DistortPixel(Vec2(x, y));
    x0 = std::min(x0, d.x());
    y0 = std::min(y0, d.y());
    x1 = std::max(x1, d.x());
    y1 = std::max(y1, d.y());
  };
  // The border's image bounds the whole rectangle's for any lens a flight uses (the mapping is monotonic in radius).
  for (int i = 0; i <= kSteps; ++i) {
    const double tx = ideal.x + (ideal.width - 1) * static_cast<double>(i) / kSteps;
    const double ty = ideal.y + (ideal.height - 1) * static_cast<double>(i) / kSteps;
    extend(tx, ideal.y);
    extend(tx, ideal.y + ideal.height - 1);
    extend(ideal.x, ty);
    extend(ideal.x + ideal.width - 1, ty);
  }
  // A rectangle through the centre lines also holds their extremes (barrel: mid-edges reach furthest out).
  const cv::Rect r(cv::Point(static_cast<int>(std::floor(x0)) - 2, static_cast<int>(std::floor(y0)) - 2),
                   cv::Point(static_cast<int>(std::ceil(x1)) + 3, static_cast<int>(std::ceil(y1)) + 3));
  return r & cv::Rect(0, 0, camera.width, camera.height);
}

cv::Mat UndistortPart(const PinholeCamera& camera, const cv::Mat& recorded, const cv::Point2d& recorded_origin,
                      const cv::Rect& ideal) {
  // The lens evaluated on a 16 px lattice and interpolated bilinearly in between (its curvature makes that exact to
  // ~0.02 px; a per-pixel evaluation cost ~60 ms per 3 MP part, seconds over a flight), band by band so that the
  // coordinate maps stay small beside the compositor's budgeted cache.
  constexpr int kStep = 16;
  const int nodes = ideal.width / kStep + 2;
  std::vector<cv::Point2f> top(static_cast<size_t>(nodes)), bottom(top.size());
  const auto node_row = [&](int y, std::vector<cv::Point2f>* row) {
    for (int i = 0; i < nodes; ++i) {
      const Vec2 d = camera.DistortPixel(Vec2(ideal.x + i * kStep, ideal.y + y));
      (*row)[static_cast<size_t>(i)] =
          cv::Point2f(static_cast<float>(d.x() - recorded_origin.x), static_cast<float>(d.y() - recorded_origin.y));
    }
  };
  cv::Mat out(ideal.size(), recorded.type());
  cv::Mat map_x(std::min(kStep, ideal.height), ideal.width, CV_32FC1), map_y(map_x.size(), CV_32FC1);
  node_row(0, &top);
  for (int y0 = 0; y0 < ideal.height; y0 += kStep) {
    node_row(y0 + kStep, &bottom);
    const int rows = std::min(kStep, ideal.height - y0);
    for (int r = 0; r < rows; ++r) {
      const float t = static_cast<float>(r) / kStep;
      auto* mx = map_x.ptr<float>(r);
      auto* my = map_y.ptr<float>(r);
      for (int x = 0; x < ideal.width; ++x) {
        const auto i = static_cast<size_t>(x / kStep);
        const float s = static_cast<float>(x % kStep) / kStep;
        const cv::Point2f p =
            (1 - t) * ((1 - s) * top[i] + s * top[i + 1]) + t * ((1 - s) * bottom[i] + s * bottom[i + 1]);
        mx[x] = p.x;
        my[x] = p.y;
      }
    }
    cv::Mat band = out.rowRange(y0, y0 + rows);
    cv::remap(recorded, band, map_x.rowRange(0, rows), map_y.rowRange(0, rows), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    std::swap(top, bottom);
  }
  return out;
}

}  // namespace uavm
