#include "core/eval/image_score.h"

#include <Eigen/Dense>
#include <algorithm>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

namespace uavm::eval {

namespace {

struct Prepared {
  cv::Mat grey;
  cv::Mat mask;
  double scale = 1.0;  // reduced / original
};

Prepared Prepare(const cv::Mat& in, int max_long_side) {
  Prepared p;
  if (in.channels() == 4) {
    cv::extractChannel(in, p.mask, 3);
    cv::threshold(p.mask, p.mask, 0, 255, cv::THRESH_BINARY);
    cv::cvtColor(in, p.grey, cv::COLOR_BGRA2GRAY);
  } else if (in.channels() == 3) {
    cv::cvtColor(in, p.grey, cv::COLOR_BGR2GRAY);
  } else {
    p.grey = in.clone();
  }
  if (p.grey.depth() != CV_8U) p.grey.convertTo(p.grey, CV_8U);
  const int long_side = std::max(in.cols, in.rows);
  if (long_side > max_long_side) {
    p.scale = static_cast<double>(max_long_side) / long_side;
    cv::resize(p.grey, p.grey, cv::Size(), p.scale, p.scale, cv::INTER_AREA);
    if (!p.mask.empty()) cv::resize(p.mask, p.mask, p.grey.size(), 0, 0, cv::INTER_NEAREST);
  }
  // Keypoints on the flown area's border see the transparent outside: keep them off it.
  if (!p.mask.empty()) cv::erode(p.mask, p.mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(9, 9)));
  return p;
}

// Reduced-image keypoint -> original pixel centre. OpenCV's SIFT places keypoints 0.25 px right/down of the
// pixel-centre convention (it upsamples the image first); removing it avoids a scale-dependent bias.
Vec2 ToOriginal(const cv::Point2f& k, double scale) {
  return {(k.x - 0.25 + 0.5) / scale - 0.5, (k.y - 0.25 + 0.5) / scale - 0.5};
}

}  // namespace

bool ScoreMosaicImage(const cv::Mat& mosaic, const cv::Mat& canvas, ImageScore* score, std::string* error,
                      const ImageScoreOptions& options) {
  *score = ImageScore{};
  if (mosaic.empty() || canvas.empty()) {
    *error = "empty image";
    return false;
  }
  const Prepared pm = Prepare(mosaic, options.max_long_side);
  const Prepared pc = Prepare(canvas, options.max_long_side);
  // Low contrast threshold: mosaics and aerial canvases are soft; the default finds too few points.
  auto sift = cv::SIFT::create(options.max_features, 3, 0.01);
  std::vector<cv::KeyPoint> km, kc;
  cv::Mat dm, dc;
  sift->detectAndCompute(pm.grey, pm.mask, km, dm);
  sift->detectAndCompute(pc.grey, pc.mask, kc, dc);
  if (km.size() < 10 || kc.size() < 10) {
    *error =
        "too few SIFT keypoints (mosaic " + std::to_string(km.size()) + ", canvas " + std::to_string(kc.size()) + ")";
    return false;
  }
  cv::FlannBasedMatcher matcher;
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(dm, dc, knn, 2);
  std::vector<cv::Point2f> src, dst;
  for (const auto& m : knn) {
    if (m.size() == 2 && m[0].distance < options.ratio * m[1].distance) {
      src.push_back(km[static_cast<size_t>(m[0].queryIdx)].pt);
      dst.push_back(kc[static_cast<size_t>(m[0].trainIdx)].pt);
    }
  }
  score->matches = static_cast<int>(src.size());
  if (src.size() < 6) {
    *error = "too few matches: " + std::to_string(src.size());
    return false;
  }
  std::vector<uchar> inl;
  const cv::Mat a = cv::estimateAffine2D(src, dst, inl, cv::RANSAC, options.ransac_px, 5000, 0.999, 10);
  if (a.empty()) {
    *error = "RANSAC found no affine";
    return false;
  }
  // Least-squares refit over the inliers in original pixels, so residuals are canvas pixels.
  std::vector<Vec2> ps, pd;
  for (size_t i = 0; i < src.size(); ++i) {
    if (!inl[i]) continue;
    ps.push_back(ToOriginal(src[i], pm.scale));
    pd.push_back(ToOriginal(dst[i], pc.scale));
  }
  score->inliers = static_cast<int>(ps.size());
  if (ps.size() < 6) {
    *error = "too few inliers: " + std::to_string(ps.size());
    return false;
  }
  Eigen::MatrixXd design(static_cast<Eigen::Index>(ps.size()), 3);
  Eigen::MatrixXd rhs(static_cast<Eigen::Index>(ps.size()), 2);
  for (size_t i = 0; i < ps.size(); ++i) {
    const auto r = static_cast<Eigen::Index>(i);
    design.row(r) << ps[i].x(), ps[i].y(), 1.0;
    rhs.row(r) << pd[i].x(), pd[i].y();
  }
  const Eigen::MatrixXd x = design.colPivHouseholderQr().solve(rhs);
  Mat3 m = Mat3::Identity();
  m.row(0) = x.col(0).transpose();
  m.row(1) = x.col(1).transpose();
  score->canvas_from_mosaic = m;
  std::vector<double> res;
  res.reserve(ps.size());
  for (size_t i = 0; i < ps.size(); ++i) res.push_back((Apply(m, ps[i]) - pd[i]).norm());
  std::sort(res.begin(), res.end());
  score->median_px = res[res.size() / 2];
  score->p90_px = res[std::min(res.size() - 1, res.size() * 9 / 10)];
  return true;
}

}  // namespace uavm::eval
