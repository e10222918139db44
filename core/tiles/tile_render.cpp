#include "core/tiles/tile_render.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>

#include "core/tiles/tile_set.h"

namespace uavm {

cv::Mat FeatherWeight(cv::Size size, int feather) {
  cv::Mat w(size, CV_8U);
  const double f = std::max(1, feather);
  for (int y = 0; y < size.height; ++y) {
    auto* row = w.ptr<uchar>(y);
    const int dy = std::min(y, size.height - 1 - y);
    for (int x = 0; x < size.width; ++x) {
      const int d = std::min(dy, std::min(x, size.width - 1 - x));
      row[x] = cv::saturate_cast<uchar>(std::max(1.0, 255.0 * (d + 1) / f));
    }
  }
  return w;
}

bool PaintFrame(const cv::Mat& bgr, const cv::Mat& weight, const Mat3& tile_from_work, cv::Mat* tile) {
  const cv::Size size(kTileSize, kTileSize);
  cv::Mat colour, alpha;
  const cv::Matx33d m = ToCv(tile_from_work);
  // Colour replicated past the border so that the bilinear edge adds no black; coverage from the weight alone.
  cv::warpPerspective(weight, alpha, m, size, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  if (cv::countNonZero(alpha) == 0) return false;
  cv::warpPerspective(bgr, colour, m, size, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  for (int y = 0; y < kTileSize; ++y) {
    const auto* c = colour.ptr<cv::Vec3b>(y);
    const auto* a = alpha.ptr<uchar>(y);
    auto* t = tile->ptr<cv::Vec4b>(y);
    for (int x = 0; x < kTileSize; ++x) {
      if (a[x] == 0) continue;
      if (t[x][3] == 0) {
        t[x] = cv::Vec4b(c[x][0], c[x][1], c[x][2], 255);
        continue;
      }
      const int w = a[x];
      for (int k = 0; k < 3; ++k) t[x][k] = static_cast<uchar>((c[x][k] * w + t[x][k] * (255 - w) + 127) / 255);
      t[x][3] = 255;
    }
  }
  return true;
}

void HalveRgba(const cv::Mat& children, cv::Mat* parent) {
  // Premultiplied average over each 2x2 block, then back to straight alpha.
  for (int y = 0; y < kTileSize; ++y) {
    const auto* r0 = children.ptr<cv::Vec4b>(2 * y);
    const auto* r1 = children.ptr<cv::Vec4b>(2 * y + 1);
    auto* out = parent->ptr<cv::Vec4b>(y);
    for (int x = 0; x < kTileSize; ++x) {
      const cv::Vec4b* px[4] = {&r0[2 * x], &r0[2 * x + 1], &r1[2 * x], &r1[2 * x + 1]};
      int a = 0, c[3] = {0, 0, 0};
      for (const cv::Vec4b* p : px) {
        a += (*p)[3];
        for (int k = 0; k < 3; ++k) c[k] += (*p)[k] * (*p)[3];
      }
      if (a == 0) {
        out[x] = cv::Vec4b(0, 0, 0, 0);
        continue;
      }
      for (int k = 0; k < 3; ++k) out[x][k] = static_cast<uchar>((c[k] + a / 2) / a);
      out[x][3] = static_cast<uchar>((a + 2) / 4);
    }
  }
}

double MaxCornerShift(const Mat3& before, const Mat3& after, cv::Size size) {
  double worst = 0;
  for (const Vec2& c : ImageCorners(size.width, size.height))
    worst = std::max(worst, (Apply(before, c) - Apply(after, c)).norm());
  return worst;
}

bool FrameTouchesTile(const Mat3& grid_from_work, cv::Size size, int x, int y) {
  const auto fp = Footprint(grid_from_work, size.width, size.height);
  // The footprint's corners are pixel centres: grow the tile by half a pixel so that edge pixels count.
  const float x0 = static_cast<float>(x * kTileSize) - 1.f, y0 = static_cast<float>(y * kTileSize) - 1.f;
  const float x1 = x0 + kTileSize + 2.f, y1 = y0 + kTileSize + 2.f;
  const std::vector<cv::Point2f> tile = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  return ConvexOverlapArea(fp, tile) > 0;
}

}  // namespace uavm
