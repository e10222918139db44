#include "core/eval/photometric.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "core/util/fail.h"

namespace uavm::eval {

namespace {

// Colour (CV_32FC3) and coverage (CV_32F, 1 = flown) of a BGR or BGRA image (8-bit, 16-bit or float).
void SplitCoverage(const cv::Mat& image, cv::Mat* colour, cv::Mat* coverage) {
  std::vector<cv::Mat> planes;
  cv::split(image, planes);
  if (planes.size() == 4) {
    // Only wholly opaque pixels: a reduced quick-look's partly transparent edge mixes in the unflown black.
    const double opaque = image.depth() == CV_8U ? 255.0 : image.depth() == CV_16U ? 65535.0 : 1.0;
    cv::Mat flown = planes[3] >= opaque;
    flown.convertTo(*coverage, CV_32F, 1.0 / 255.0);
    planes.pop_back();
  } else {
    *coverage = cv::Mat(image.size(), CV_32F, cv::Scalar(1.0));
  }
  cv::Mat merged;
  cv::merge(planes, merged);
  merged.convertTo(*colour, CV_32FC3);
}

// The mosaic image resampled onto the comparison grid: colour and a strict coverage mask (1 where every bilinear
// neighbour was flown). Reduced by area first when it is much finer than the grid, so the sampling does not alias.
void MosaicOnGrid(const cv::Mat& image, const Mat3& grid_from_image, cv::Size grid, cv::Mat* colour, cv::Mat* mask) {
  cv::Mat c, m;
  SplitCoverage(image, &c, &m);
  Mat3 from_image = grid_from_image;
  const double k = LocalScale(grid_from_image, Vec2(0.5 * (image.cols - 1), 0.5 * (image.rows - 1)));
  if (k < 0.5) {  // keep about two image pixels per grid pixel
    const cv::Size reduced(std::max(1, static_cast<int>(std::lround(image.cols * 2 * k))),
                           std::max(1, static_cast<int>(std::lround(image.rows * 2 * k))));
    cv::resize(c, c, reduced, 0, 0, cv::INTER_AREA);
    cv::resize(m, m, reduced, 0, 0, cv::INTER_AREA);
    from_image = grid_from_image * ResizeMap(static_cast<double>(image.cols) / reduced.width,
                                             static_cast<double>(image.rows) / reduced.height);
  }
  const cv::Matx33d image_from_grid = ToCv(from_image.inverse());
  cv::warpPerspective(c, *colour, image_from_grid, grid, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  cv::Mat cover;
  cv::warpPerspective(m, cover, image_from_grid, grid, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  cv::Mat full = cover >= 0.999f;
  full.convertTo(*mask, CV_32F, 1.0 / 255.0);
}

// Gaussian of `image` over the pixels of `mask` only: blur(image x mask) / blur(mask), and blur(mask) itself.
cv::Mat MaskedBlur(const cv::Mat& image, const cv::Mat& mask, double sigma, const cv::Mat& mask_blur) {
  cv::Mat masked, blurred;
  cv::Mat mask3;
  cv::merge(std::vector<cv::Mat>{mask, mask, mask}, mask3);
  cv::multiply(image, mask3, masked);
  cv::GaussianBlur(masked, blurred, cv::Size(0, 0), sigma, sigma, cv::BORDER_CONSTANT);
  cv::Mat weight3;
  cv::merge(std::vector<cv::Mat>{mask_blur, mask_blur, mask_blur}, weight3);
  cv::divide(blurred, cv::max(weight3, 1e-6), blurred);
  return blurred;
}

// Calls f(a, b, d^2) for channel c of every counted pixel: canvas a, mosaic b, d = max(a, floor).
template <typename F>
void ForCounted(const cv::Mat& canvas, const cv::Mat& mosaic, const cv::Mat& counted, int c, double floor, F f) {
  for (int y = 0; y < canvas.rows; ++y)
    for (int x = 0; x < canvas.cols; ++x) {
      if (counted.at<uchar>(y, x) == 0) continue;
      const double a = canvas.at<cv::Vec3f>(y, x)[c];
      const double d = std::max(a, floor);
      f(a, static_cast<double>(mosaic.at<cv::Vec3f>(y, x)[c]), d * d);
    }
}

// Steps 3 and 4 of the header over the counted pixels: h_c = 1 / g_c minimises sum ((h_c b - a) / d)^2, which is
// then the reported error.
void FitGainAndError(const cv::Mat& canvas, const cv::Mat& mosaic, const cv::Mat& counted, double dark_floor,
                     PhotometricResult* result) {
  const cv::Scalar mean = cv::mean(canvas, counted);
  result->pixels = cv::countNonZero(counted);
  double total = 0.0;
  for (int c = 0; c < 3; ++c) {
    double ab = 0, bb = 0;
    ForCounted(canvas, mosaic, counted, c, dark_floor * mean[c], [&](double a, double b, double d2) {
      ab += a * b / d2;
      bb += b * b / d2;
    });
    const double h = bb > 0 ? ab / bb : 0.0;
    ForCounted(canvas, mosaic, counted, c, dark_floor * mean[c],
               [&](double a, double b, double d2) { total += (h * b - a) * (h * b - a) / d2; });
    result->gain[static_cast<size_t>(c)] = h > 0 ? 1.0 / h : 0.0;
  }
  result->rms_percent = 100.0 * std::sqrt(total / (3.0 * static_cast<double>(std::max(1L, result->pixels))));
}

}  // namespace

bool PhotometricOptions::Check(std::string* error) const {
  if (!(sigma_footprint_fraction > 0 && sigma_footprint_fraction <= 4))
    return Fail(error, "sigma_footprint_fraction must be in (0, 4]");
  if (!(grid_sigma_px >= 1 && grid_sigma_px <= 64)) return Fail(error, "grid_sigma_px must be in [1, 64]");
  if (!(min_window_coverage > 0 && min_window_coverage <= 1))
    return Fail(error, "min_window_coverage must be in (0, 1]");
  if (!(dark_floor >= 0 && dark_floor < 1)) return Fail(error, "dark_floor must be in [0, 1)");
  return true;
}

bool PhotometricError(const cv::Mat& mosaic_image, const Mat3& mosaic_from_image, const cv::Mat& canvas,
                      const Mat3& canvas_from_mosaic, double footprint_side_px, PhotometricResult* result,
                      std::string* error, const PhotometricOptions& options) {
  *result = PhotometricResult{};
  if (!options.Check(error)) return false;
  if (canvas.empty() || canvas.channels() != 3 || mosaic_image.empty() ||
      (mosaic_image.channels() != 3 && mosaic_image.channels() != 4))
    return Fail(error, "photometric: needs a BGR canvas and a BGR or BGRA mosaic");
  if (!(footprint_side_px > 0)) return Fail(error, "photometric: the footprint side must be > 0");
  result->sigma_canvas_px = options.sigma_footprint_fraction * footprint_side_px;
  const double r = std::min(1.0, options.grid_sigma_px / result->sigma_canvas_px);
  const cv::Size grid(std::max(1, static_cast<int>(std::lround(canvas.cols * r))),
                      std::max(1, static_cast<int>(std::lround(canvas.rows * r))));
  result->grid_px_per_canvas_px = static_cast<double>(grid.width) / canvas.cols;
  cv::Mat canvas_grid;
  cv::resize(canvas, canvas_grid, grid, 0, 0, cv::INTER_AREA);
  canvas_grid.convertTo(canvas_grid, CV_32FC3);
  const Mat3 grid_from_canvas =
      ResizeMap(static_cast<double>(grid.width) / canvas.cols, static_cast<double>(grid.height) / canvas.rows);
  cv::Mat mosaic_grid, mask;
  MosaicOnGrid(mosaic_image, grid_from_canvas * canvas_from_mosaic * mosaic_from_image, grid, &mosaic_grid, &mask);

  const double sigma = result->sigma_canvas_px * result->grid_px_per_canvas_px;
  cv::Mat window;
  cv::GaussianBlur(mask, window, cv::Size(0, 0), sigma, sigma, cv::BORDER_CONSTANT);
  const cv::Mat counted = (mask > 0.5f) & (window >= static_cast<float>(options.min_window_coverage));
  if (cv::countNonZero(counted) == 0) return Fail(error, "photometric: the mosaic covers none of the canvas");
  FitGainAndError(MaskedBlur(canvas_grid, mask, sigma, window), MaskedBlur(mosaic_grid, mask, sigma, window), counted,
                  options.dark_floor, result);
  return true;
}

nlohmann::json ToJson(const PhotometricResult& r) {
  return {{"rms_percent", r.rms_percent},
          {"gain", {r.gain[0], r.gain[1], r.gain[2]}},
          {"sigma_canvas_px", r.sigma_canvas_px},
          {"grid_px_per_canvas_px", r.grid_px_per_canvas_px},
          {"pixels", r.pixels}};
}

double FootprintSidePx(const std::vector<GtRow>& gt, cv::Size frame_size) {
  std::vector<double> sides;
  for (const auto& g : gt)
    sides.push_back(
        std::sqrt(std::abs(PolygonArea(Footprint(g.canvas_from_frame, frame_size.width, frame_size.height)))));
  if (sides.empty()) return 0.0;
  std::nth_element(sides.begin(), sides.begin() + static_cast<long>(sides.size() / 2), sides.end());
  return sides[sides.size() / 2];
}

}  // namespace uavm::eval
