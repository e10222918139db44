#pragma once
#include <Eigen/Core>
#include <Eigen/LU>  // inverse() and determinant() of the 3x3 maps
#include <array>
#include <functional>
#include <opencv2/core.hpp>
#include <vector>

namespace uavm {

// Every map between image planes is a 3x3 matrix `tgt_from_src`, acting on pixel centres ((0,0) = centre of the
// top-left pixel). Affine maps have a last row (0, 0, 1); the projective refinement fills the rest.
using Mat3 = Eigen::Matrix3d;
using Vec2 = Eigen::Vector2d;
using Vec2f = Eigen::Vector2f;  // a stored point: what edges.bin keeps, half a Vec2's memory

[[nodiscard]] Vec2 Apply(const Mat3& tgt_from_src, const Vec2& p);
[[nodiscard]] bool IsAffine(const Mat3& m, double tol = 1e-12);

// Map from pixel centres of an image to pixel centres of the same image resized by `scale`
// (cv::resize convention: x' = (x + 0.5) * scale - 0.5).
[[nodiscard]] Mat3 ResizeMap(double scale_x, double scale_y);
[[nodiscard]] Mat3 Translation(double tx, double ty);

// The four corner pixel centres of a w x h image, clockwise from top-left.
[[nodiscard]] std::array<Vec2, 4> ImageCorners(int width, int height);
// Corners of a w x h image mapped by tgt_from_src.
[[nodiscard]] std::vector<cv::Point2f> Footprint(const Mat3& tgt_from_src, int width, int height);
// An axis-aligned box; the default one is empty (the first point added makes it that point).
struct Bounds2 {
  double minx = 1e300, miny = 1e300, maxx = -1e300, maxy = -1e300;
};
// `box` grown to hold the footprints of the images `ids`: image id, of size size_of(id), mapped by tgt_from_src[id].
[[nodiscard]] Bounds2 FootprintBounds(const std::vector<int>& ids, const std::vector<Mat3>& tgt_from_src,
                                      const std::function<cv::Size(int)>& size_of, Bounds2 box = {});
[[nodiscard]] double PolygonArea(const std::vector<cv::Point2f>& polygon);
// Area of the intersection of two convex polygons (0 when disjoint or degenerate).
[[nodiscard]] double ConvexOverlapArea(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b);

// Linear part diagnostics of an affine map: mean axis scale, shear-like anisotropy (0 for a similarity), rotation
// (rad).
struct LinearPart {
  double scale = 1.0;
  double anisotropy = 0.0;
  double rotation = 0.0;
  double det = 1.0;
};
[[nodiscard]] LinearPart Decompose(const Mat3& affine);
// sqrt |det J| of tgt_from_src's Jacobian at `at`: target pixels per source pixel there (exact for projective maps,
// whose upper-left 2x2 is not their Jacobian away from the origin).
[[nodiscard]] double LocalScale(const Mat3& tgt_from_src, const Vec2& at);
// The affine minimising the squared distance to `projective` over a grid x grid lattice of pixel centres spanning a
// width x height frame (the simulator's ground truth for an affine model).
[[nodiscard]] Mat3 ClosestAffine(const Mat3& projective, int width, int height, int grid = 17);

[[nodiscard]] cv::Matx23d ToCvAffine(const Mat3& m);
[[nodiscard]] cv::Matx33d ToCv(const Mat3& m);
[[nodiscard]] Mat3 FromCv(const cv::Matx23d& m);

}  // namespace uavm
