#include "core/stereo/daisy.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <opencv2/imgproc.hpp>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace uavm::stereo {

bool DaisyOptions::Check(std::string* why) const {
  if (radius < 1.0 || rings < 1 || histograms < 1 || orientations < 2 || size() > 1024) {
    if (why) *why = "DAISY: radius >= 1, rings and histograms >= 1, orientations >= 2, at most 1024 values";
    return false;
  }
  return true;
}

DenseDaisy::DenseDaisy(const DaisyOptions& options) : options_(options) {
  const auto& o = options_;
  offsets_.emplace_back(0, 0);
  levels_.push_back(0);
  for (int r = 0; r < o.rings; ++r) {
    const double ring_radius = o.radius * (r + 1) / o.rings;
    for (int h = 0; h < o.histograms; ++h) {
      const double theta = 2.0 * M_PI * h / o.histograms;
      offsets_.emplace_back(static_cast<int>(std::lround(ring_radius * std::cos(theta))),
                            static_cast<int>(std::lround(ring_radius * std::sin(theta))));
      levels_.push_back(r + 1);
    }
  }
}

size_t DenseDaisy::LayerBytes(const DaisyOptions& options, int width, int height) {
  return static_cast<size_t>(options.rings + 1) * static_cast<size_t>(options.orientations) *
         static_cast<size_t>(width) * static_cast<size_t>(height) * sizeof(float);
}

void DenseDaisy::Prepare(const cv::Mat& gray) {
  const auto& o = options_;
  width_ = gray.cols;
  height_ = gray.rows;
  cv::Mat1f img;
  gray.convertTo(img, CV_32F, 1.0 / 255.0);
  // Forward differences, zero in the last column / row.
  cv::Mat1f dx(img.size(), 0.0f), dy(img.size(), 0.0f);
  for (int y = 0; y < img.rows; ++y) {
    for (int x = 0; x + 1 < img.cols; ++x) dx(y, x) = img(y, x + 1) - img(y, x);
    if (y + 1 < img.rows) {
      for (int x = 0; x < img.cols; ++x) dy(y, x) = img(y + 1, x) - img(y, x);
    }
  }
  // std::atan2, not cv::cartToPolar: the latter's angles are good to ~0.3 degrees only.
  cv::Mat1f magnitude(img.size()), angle(img.size());
  for (int y = 0; y < img.rows; ++y) {
    for (int x = 0; x < img.cols; ++x) {
      magnitude(y, x) = std::sqrt(dx(y, x) * dx(y, x) + dy(y, x) * dy(y, x));
      angle(y, x) = std::atan2(dy(y, x), dx(y, x));
    }
  }
  const double kappa = o.orientations / M_PI;
  std::vector<double> sigmas = {o.radius / (2.0 * o.rings)};
  for (int r = 0; r < o.rings; ++r) sigmas.push_back(o.radius * (r + 1) / (2.0 * o.rings));
  layers_.assign(static_cast<size_t>(o.rings + 1) * o.orientations, cv::Mat1f());
  cv::Mat1f hist(img.size());
  for (int k = 0; k < o.orientations; ++k) {
    const double centre = 2.0 * M_PI * k / o.orientations - M_PI;
    for (int y = 0; y < img.rows; ++y) {
      const float* a = angle[y];
      const float* m = magnitude[y];
      float* h = hist[y];
      for (int x = 0; x < img.cols; ++x) h[x] = static_cast<float>(std::exp(kappa * std::cos(a[x] - centre)) * m[x]);
    }
    for (size_t level = 0; level < sigmas.size(); ++level) {
      // scipy's gaussian_filter (truncate 4, mirror border "d c b a | a b c d"), as skimage's daisy smooths.
      const int half = static_cast<int>(4.0 * sigmas[level] + 0.5);
      const cv::Mat kernel = cv::getGaussianKernel(2 * half + 1, sigmas[level], CV_32F);
      cv::sepFilter2D(hist, layers_[level * static_cast<size_t>(o.orientations) + static_cast<size_t>(k)], CV_32F,
                      kernel, kernel, cv::Point(-1, -1), 0.0, cv::BORDER_REFLECT);
    }
  }
}

void DenseDaisy::Descriptor(int x, int y, float* out) const {
  const int no = options_.orientations;
  for (size_t h = 0; h < offsets_.size(); ++h) {
    const int sx = std::clamp(x + offsets_[h].x, 0, width_ - 1);
    const int sy = std::clamp(y + offsets_[h].y, 0, height_ - 1);
    float* v = out + h * static_cast<size_t>(no);
    double norm = 0.0;
    for (int k = 0; k < no; ++k) {
      v[k] = layers_[static_cast<size_t>(levels_[h] * no + k)](sy, sx) + 1e-10f;
      norm += static_cast<double>(v[k]) * v[k];
    }
    const float inv = static_cast<float>(1.0 / std::sqrt(norm));
    for (int k = 0; k < no; ++k) v[k] *= inv;
  }
}

void DenseDaisy::Row(int y, uint8_t* out) const {
  const int size = options_.size(), stride = options_.stride();
  std::vector<float> d(static_cast<size_t>(size));
  for (int x = 0; x < width_; ++x) {
    Descriptor(x, y, d.data());
    uint8_t* q = out + static_cast<size_t>(x) * static_cast<size_t>(stride);
    for (int i = 0; i < size; ++i) q[i] = static_cast<uint8_t>(std::lround(std::clamp(d[i], 0.0f, 1.0f) * 255.0f));
    std::fill(q + size, q + stride, uint8_t{0});
  }
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(UAVM_FUZZ_BUILD)
namespace {
__attribute__((target("avx2"))) int DistanceAvx2(const uint8_t* a, const uint8_t* b, int stride) {
  __m256i sum = _mm256_setzero_si256();
  for (int i = 0; i < stride; i += 32) {
    const __m256i va = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(a + i));
    const __m256i vb = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(b + i));
    sum = _mm256_add_epi64(sum, _mm256_sad_epu8(va, vb));
  }
  return static_cast<int>(_mm256_extract_epi64(sum, 0) + _mm256_extract_epi64(sum, 1) + _mm256_extract_epi64(sum, 2) +
                          _mm256_extract_epi64(sum, 3));
}
}  // namespace
#define UAVM_HAVE_AVX2_DAISY 1
#endif

int DaisyDistance(const uint8_t* a, const uint8_t* b, int stride) {
#ifdef UAVM_HAVE_AVX2_DAISY
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) return DistanceAvx2(a, b, stride);
#endif
  int sum = 0;
  for (int i = 0; i < stride; ++i) sum += std::abs(static_cast<int>(a[i]) - static_cast<int>(b[i]));
  return sum;
}

}  // namespace uavm::stereo
