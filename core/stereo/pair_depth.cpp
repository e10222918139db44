#include "core/stereo/pair_depth.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/util/fail.h"
#include "core/util/memory.h"

namespace uavm::stereo {
namespace {

bool Finite(const cv::Vec3d& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

// Pixels along the border of an image (every `step` px), where the footprint's extremes lie.
std::vector<cv::Point2f> BorderPoints(cv::Size size, int step) {
  std::vector<cv::Point2f> pts;
  const float w = static_cast<float>(size.width - 1);
  const float h = static_cast<float>(size.height - 1);
  for (int x = 0; x < size.width; x += step) {
    pts.emplace_back(static_cast<float>(x), 0.0f);
    pts.emplace_back(static_cast<float>(x), h);
  }
  for (int y = 0; y < size.height; y += step) {
    pts.emplace_back(0.0f, static_cast<float>(y));
    pts.emplace_back(w, static_cast<float>(y));
  }
  pts.emplace_back(w, h);
  return pts;
}

}  // namespace

bool PairDepthOptions::Check(std::string* why) const {
  auto bad = [&](const char* what) {
    if (why) *why = what;
    return false;
  };
  if (!(min_depth > 0.0) || !(max_depth > min_depth)) return bad("need 0 < min_depth < max_depth");
  if (max_disparity < 0 || max_disparity_cap < 1) return bad("max_disparity >= 0 and max_disparity_cap >= 1");
  if (!(image_scale > 0.0) || image_scale > 1.0) return bad("image_scale must be in (0, 1]");
  if (sample_step < 1) return bad("sample_step must be >= 1");
  if (min_triangulation_angle_deg < 0.0 || min_triangulation_angle_deg >= 90.0)
    return bad("min_triangulation_angle_deg must be in [0, 90)");
  return sgm.Check(why);
}

bool RectifyCameras(const StereoCamera& cam1, const StereoCamera& cam2, RectifiedPair* rect, std::string* error) {
  if (rect == nullptr) return Fail(error, "no output");
  if (cam1.size.width <= 0 || cam1.size.height <= 0 || cam2.size.width <= 0 || cam2.size.height <= 0)
    return Fail(error, "camera image size not set");
  const cv::Vec3d base = cam2.c - cam1.c;
  const double b = cv::norm(base);
  if (!Finite(base) || !(b > 0.0)) return Fail(error, "camera centres coincide (zero baseline)");
  // Rectified frame: x along the baseline, z the mean viewing direction made orthogonal to it.
  const cv::Vec3d x = base / b;
  const cv::Vec3d z1(cam1.R(2, 0), cam1.R(2, 1), cam1.R(2, 2));
  const cv::Vec3d z2(cam2.R(2, 0), cam2.R(2, 1), cam2.R(2, 2));
  const cv::Vec3d zm = z1 + z2;
  cv::Vec3d y = zm.cross(x);
  const double ny = cv::norm(y);
  if (!(ny > 1e-6 * cv::norm(zm))) return Fail(error, "baseline is along the viewing direction: cannot rectify");
  y /= ny;
  const cv::Vec3d z = x.cross(y);
  cv::Matx33d rect_from_world(x[0], x[1], x[2], y[0], y[1], y[2], z[0], z[1], z[2]);
  const cv::Vec3d zr1 = rect_from_world * z1;
  const cv::Vec3d zr2 = rect_from_world * z2;
  if (zr1[2] < 0.1 || zr2[2] < 0.1) return Fail(error, "cameras look too far apart to rectify");

  // Common focal length: the larger one, so no image is down-sampled.
  const double f = std::max({cam1.K(0, 0), cam1.K(1, 1), cam2.K(0, 0), cam2.K(1, 1)});
  const StereoCamera* cams[2] = {&cam1, &cam2};
  cv::Rect2d box;
  for (int k = 0; k < 2; ++k) {
    rect->rect_from_cam[k] = rect_from_world * cams[k]->R.t();
    const std::vector<cv::Point2f> border = BorderPoints(cams[k]->size, 16);
    std::vector<cv::Point2f> mapped;
    const cv::Matx33d unit_k(f, 0, 0, 0, f, 0, 0, 0, 1);
    cv::undistortPoints(border, mapped, cv::Mat(cams[k]->K), cv::Mat(cams[k]->dist), cv::Mat(rect->rect_from_cam[k]),
                        cv::Mat(unit_k));
    double x0 = std::numeric_limits<double>::max(), y0 = x0, x1 = -x0, y1 = -x0;
    for (const auto& p : mapped) {
      x0 = std::min(x0, static_cast<double>(p.x));
      x1 = std::max(x1, static_cast<double>(p.x));
      y0 = std::min(y0, static_cast<double>(p.y));
      y1 = std::max(y1, static_cast<double>(p.y));
    }
    const cv::Rect2d r(x0, y0, x1 - x0, y1 - y0);
    box = k == 0 ? r : (box | r);
  }
  const int limit = 2 * std::max({cam1.size.width, cam1.size.height, cam2.size.width, cam2.size.height});
  if (!(box.width > 0 && box.height > 0) || box.width > limit || box.height > limit)
    return Fail(error, "rectified images would be too large (strongly converging or oblique views)");
  rect->K = cv::Matx33d(f, 0, -box.x, 0, f, -box.y, 0, 0, 1);
  rect->size = cv::Size(static_cast<int>(std::ceil(box.width)) + 1, static_cast<int>(std::ceil(box.height)) + 1);
  rect->rect_from_world = rect_from_world;
  rect->baseline = b;
  for (int k = 0; k < 2; ++k) {
    cv::initUndistortRectifyMap(cv::Mat(cams[k]->K), cv::Mat(cams[k]->dist), cv::Mat(rect->rect_from_cam[k]),
                                cv::Mat(rect->K), rect->size, CV_32FC1, rect->map_x[k], rect->map_y[k]);
  }
  return true;
}

bool DensePointsFromPair(const cv::Mat& img1, const StereoCamera& cam1, const cv::Mat& img2, const StereoCamera& cam2,
                         const PairDepthOptions& opts, std::vector<ColoredPoint>* points, std::string* error) {
  std::string why;
  if (!opts.Check(&why)) return Fail(error, "bad pair-depth options: " + why);
  if (points == nullptr) return Fail(error, "no output");
  if (img1.empty() || img2.empty()) return Fail(error, "empty image");
  if (img1.size() != cam1.size || img2.size() != cam2.size) return Fail(error, "image size differs from camera size");
  if (img1.depth() != CV_8U || img2.depth() != CV_8U) return Fail(error, "images must be 8-bit");
  for (const cv::Mat* img : {&img1, &img2})
    if (img->channels() != 1 && img->channels() != 3 && img->channels() != 4)
      return Fail(error, "images must have 1, 3 or 4 channels");
  RectifiedPair rect;
  if (!RectifyCameras(cam1, cam2, &rect, error)) return false;

  cv::Mat r1, r2;
  cv::remap(img1, r1, rect.map_x[0], rect.map_y[0], cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  cv::remap(img2, r2, rect.map_x[1], rect.map_y[1], cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  // Disparity range at matching scale s: d = f * b * s / z. The scale is lowered until the matcher's buffers
  // (5 bytes per pixel and disparity) fit its memory limit.
  SgmOptions sgm = opts.sgm;
  double s = opts.image_scale;
  for (;;) {
    const double fb = rect.K(0, 0) * rect.baseline * s;
    if (opts.max_disparity > 0) {
      sgm.min_disparity = 0;
      sgm.num_disparities = std::min(opts.max_disparity, opts.max_disparity_cap);
    } else {
      const int d_min = static_cast<int>(std::floor(fb / opts.max_depth));
      const int d_max = static_cast<int>(std::ceil(fb / opts.min_depth));
      sgm.min_disparity = std::max(0, d_min - 1);
      sgm.num_disparities = std::clamp(d_max + 2 - sgm.min_disparity, 2, opts.max_disparity_cap);
    }
    const double mib =
        5.0 * (rect.size.width * s) * (rect.size.height * s) * ((sgm.num_disparities + 15) / 16 * 16) / kMiB;
    if (mib <= 0.95 * sgm.max_memory_mib || s < 0.05) break;
    s *= 0.9;
  }
  cv::Mat m1 = r1, m2 = r2;
  double sx = 1.0, sy = 1.0;
  if (s < 1.0) {
    cv::resize(r1, m1, cv::Size(), s, s, cv::INTER_AREA);
    cv::resize(r2, m2, cv::Size(), s, s, cv::INTER_AREA);
    // cv::resize maps with exactly fx = fy = s (not the ratio of the rounded sizes).
    sx = s;
    sy = s;
  }
  cv::Mat disp, measured;
  if (!ComputeDisparity(m1, m2, sgm, &disp, error, &measured)) return false;

  // Valid rectified pixels of the left image (the remap leaves black outside the footprint).
  cv::Mat inside1, inside2;
  cv::remap(cv::Mat(img1.size(), CV_8UC1, cv::Scalar(255)), inside1, rect.map_x[0], rect.map_y[0], cv::INTER_NEAREST,
            cv::BORDER_CONSTANT);
  cv::remap(cv::Mat(img2.size(), CV_8UC1, cv::Scalar(255)), inside2, rect.map_x[1], rect.map_y[1], cv::INTER_NEAREST,
            cv::BORDER_CONSTANT);
  // Census windows that reach the black outside of a footprint match badly: keep away from the border by the
  // window's reach (at matching scale).
  const int reach = static_cast<int>(std::ceil(std::max(sgm.census_width, sgm.census_height) / (2.0 * s))) + 1;
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1));
  cv::erode(inside1, inside1, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::erode(inside2, inside2, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));

  const double f = rect.K(0, 0);
  const double cx = rect.K(0, 2);
  const double cy = rect.K(1, 2);
  const cv::Matx33d world_from_rect = rect.rect_from_world.t();
  const double min_angle = opts.min_triangulation_angle_deg * CV_PI / 180.0;
  points->clear();
  for (int y = 0; y < disp.rows; y += opts.sample_step) {
    const float* d = disp.ptr<float>(y);
    const uint8_t* m = measured.ptr<uint8_t>(y);
    for (int x = 0; x < disp.cols; x += opts.sample_step) {
      if (!m[x] || !std::isfinite(d[x]) || d[x] <= 0.0f) continue;
      // Back to full rectified resolution (pixel centres scale about the corner).
      const double u = (x + 0.5) / sx - 0.5;
      const double v = (y + 0.5) / sy - 0.5;
      const double dd = d[x] / sx;
      const int ui = static_cast<int>(std::lround(u));
      const int vi = static_cast<int>(std::lround(v));
      const int u2 = static_cast<int>(std::lround(u - dd));
      if (ui < 0 || vi < 0 || ui >= r1.cols || vi >= r1.rows || u2 < 0 || u2 >= r2.cols) continue;
      if (!inside1.at<uint8_t>(vi, ui) || !inside2.at<uint8_t>(vi, u2)) continue;
      const double zr = f * rect.baseline / dd;
      const cv::Vec3d pr((u - cx) * zr / f, (v - cy) * zr / f, zr);
      const cv::Vec3d world = cam1.c + world_from_rect * pr;
      // Triangulation angle between the two rays.
      const cv::Vec3d a = world - cam1.c;
      const cv::Vec3d b = world - cam2.c;
      const double cosang = a.dot(b) / (cv::norm(a) * cv::norm(b));
      if (std::acos(std::clamp(cosang, -1.0, 1.0)) < min_angle) continue;
      const double depth1 = (cam1.R * (world - cam1.c))[2];
      if (depth1 < opts.min_depth || depth1 > opts.max_depth) continue;
      ColoredPoint p;
      p.xyz = cv::Vec3f(static_cast<float>(world[0]), static_cast<float>(world[1]), static_cast<float>(world[2]));
      if (r1.channels() == 3) {
        p.bgr = r1.at<cv::Vec3b>(vi, ui);
      } else if (r1.channels() == 4) {
        const cv::Vec4b v4 = r1.at<cv::Vec4b>(vi, ui);
        p.bgr = cv::Vec3b(v4[0], v4[1], v4[2]);
      } else {
        const uint8_t g = r1.at<uint8_t>(vi, ui);
        p.bgr = cv::Vec3b(g, g, g);
      }
      points->push_back(p);
    }
  }
  return true;
}

}  // namespace uavm::stereo
