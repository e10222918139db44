#include "core/geometry/transform.h"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace uavm {

Vec2 Apply(const Mat3& m, const Vec2& p) {
  const Eigen::Vector3d q = m * Eigen::Vector3d(p.x(), p.y(), 1.0);
  return {q.x() / q.z(), q.y() / q.z()};
}

bool IsAffine(const Mat3& m, double tol) {
  return std::abs(m(2, 0)) <= tol && std::abs(m(2, 1)) <= tol && std::abs(m(2, 2) - 1.0) <= tol;
}

Mat3 ResizeMap(double scale_x, double scale_y) {
  Mat3 m = Mat3::Identity();
  m(0, 0) = scale_x;
  m(1, 1) = scale_y;
  m(0, 2) = 0.5 * scale_x - 0.5;
  m(1, 2) = 0.5 * scale_y - 0.5;
  return m;
}

Mat3 Translation(double tx, double ty) {
  Mat3 m = Mat3::Identity();
  m(0, 2) = tx;
  m(1, 2) = ty;
  return m;
}

std::array<Vec2, 4> ImageCorners(int width, int height) {
  const double w = width - 1.0;
  const double h = height - 1.0;
  return {Vec2(0, 0), Vec2(w, 0), Vec2(w, h), Vec2(0, h)};
}

std::vector<cv::Point2f> Footprint(const Mat3& tgt_from_src, int width, int height) {
  std::vector<cv::Point2f> out;
  out.reserve(4);
  for (const Vec2& c : ImageCorners(width, height)) {
    const Vec2 p = Apply(tgt_from_src, c);
    out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  }
  return out;
}

Bounds2 FootprintBounds(const std::vector<int>& ids, const std::vector<Mat3>& tgt_from_src,
                        const std::function<cv::Size(int)>& size_of, Bounds2 box) {
  for (int id : ids) {
    const cv::Size size = size_of(id);
    for (const auto& p : Footprint(tgt_from_src[static_cast<size_t>(id)], size.width, size.height)) {
      box.minx = std::min<double>(box.minx, p.x);
      box.miny = std::min<double>(box.miny, p.y);
      box.maxx = std::max<double>(box.maxx, p.x);
      box.maxy = std::max<double>(box.maxy, p.y);
    }
  }
  return box;
}

double PolygonArea(const std::vector<cv::Point2f>& polygon) {
  if (polygon.size() < 3) return 0.0;
  return std::abs(cv::contourArea(polygon));
}

double ConvexOverlapArea(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b) {
  if (a.size() < 3 || b.size() < 3) return 0.0;
  // intersectConvexConvex needs a consistent orientation and convex input; a bad transform can fold a footprint.
  if (!cv::isContourConvex(a) || !cv::isContourConvex(b)) return 0.0;
  std::vector<cv::Point2f> inter;
  const float area = cv::intersectConvexConvex(a, b, inter, true);
  return area > 0.0f ? static_cast<double>(area) : 0.0;
}

LinearPart Decompose(const Mat3& m) {
  const Eigen::Matrix2d lin = m.topLeftCorner<2, 2>();
  Eigen::JacobiSVD<Eigen::Matrix2d> svd(lin);
  const Eigen::Vector2d sv = svd.singularValues();
  LinearPart out;
  out.scale = std::sqrt(std::max(sv(0) * sv(1), 0.0));
  out.anisotropy = sv(1) > 0 ? sv(0) / sv(1) - 1.0 : 1e9;
  out.rotation = std::atan2(lin(1, 0) - lin(0, 1), lin(0, 0) + lin(1, 1));
  out.det = lin.determinant();
  return out;
}

cv::Matx23d ToCvAffine(const Mat3& m) {
  return {m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2)};
}

cv::Matx33d ToCv(const Mat3& m) {
  return {m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2), m(2, 0), m(2, 1), m(2, 2)};
}

Mat3 FromCv(const cv::Matx23d& a) {
  Mat3 m = Mat3::Identity();
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = a(r, c);
  return m;
}

double LocalScale(const Mat3& m, const Vec2& at) {
  const double w = m(2, 0) * at.x() + m(2, 1) * at.y() + m(2, 2);
  const Vec2 p = Apply(m, at);
  // d(x/w)/du = (m0u - p.x m2u) / w, likewise for y.
  const double j00 = (m(0, 0) - p.x() * m(2, 0)) / w;
  const double j01 = (m(0, 1) - p.x() * m(2, 1)) / w;
  const double j10 = (m(1, 0) - p.y() * m(2, 0)) / w;
  const double j11 = (m(1, 1) - p.y() * m(2, 1)) / w;
  return std::sqrt(std::abs(j00 * j11 - j01 * j10));
}

Mat3 ClosestAffine(const Mat3& projective, int width, int height, int grid) {
  // Two independent linear least-squares problems (one per output coordinate) sharing the design matrix [x y 1].
  const int n = grid * grid;
  Eigen::MatrixXd a(n, 3);
  Eigen::MatrixXd b(n, 2);
  int k = 0;
  for (int j = 0; j < grid; ++j) {
    for (int i = 0; i < grid; ++i, ++k) {
      const Vec2 p((width - 1.0) * i / (grid - 1), (height - 1.0) * j / (grid - 1));
      const Vec2 q = Apply(projective, p);
      a.row(k) << p.x(), p.y(), 1.0;
      b.row(k) << q.x(), q.y();
    }
  }
  const Eigen::MatrixXd x = a.colPivHouseholderQr().solve(b);
  Mat3 m = Mat3::Identity();
  m.row(0) = x.col(0).transpose();
  m.row(1) = x.col(1).transpose();
  return m;
}

}  // namespace uavm
