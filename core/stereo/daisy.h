#pragma once
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace uavm::stereo {

// Dense DAISY descriptors (Tola, Lepetit and Fua, PAMI 2010) with the parameters of the dense-matching notes the
// product grew from (radius 15, 3 rings, 8 histograms per ring, 8 orientations: 200 values), computed as
// scikit-image's skimage.feature.daisy computes them (the independent implementation tests/daisy_test.cpp compares
// with): gradient orientations soft-binned by a circular normal (kappa = orientations / pi) and weighted by the
// gradient magnitude; each orientation layer smoothed by a Gaussian per ring (sigma = ring radius / 2, the centre
// with the first ring's); sampled at the centre and at `histograms` points on each ring; each histogram scaled to unit
// length ("daisy" normalisation). OpenCV's DAISY (xfeatures2d) is not in Debian 12's OpenCV build.
struct DaisyOptions {
  double radius = 15.0;
  int rings = 3;
  int histograms = 8;  // per ring
  int orientations = 8;
  [[nodiscard]] int size() const { return (rings * histograms + 1) * orientations; }
  // Bytes per quantised descriptor: size() rounded up to 32 (whole AVX2 registers), zero padded.
  [[nodiscard]] int stride() const { return (size() + 31) / 32 * 32; }
  [[nodiscard]] bool Check(std::string* why = nullptr) const;
};

class DenseDaisy {
 public:
  explicit DenseDaisy(const DaisyOptions& options = {});
  const DaisyOptions& options() const { return options_; }
  // The smoothed orientation layers of an 8-bit gray image ((rings + 1) x orientations float images).
  void Prepare(const cv::Mat& gray);
  // Normalised descriptor of pixel (x, y), size() floats; ring samples outside the image take the nearest border
  // pixel's histogram.
  void Descriptor(int x, int y, float* out) const;
  // Row y's descriptors quantised to bytes (round(value * 255)), stride() bytes per pixel.
  void Row(int y, uint8_t* out) const;
  // Bytes Prepare keeps for a width x height image.
  [[nodiscard]] static size_t LayerBytes(const DaisyOptions& options, int width, int height);

 private:
  DaisyOptions options_;
  std::vector<cv::Mat1f> layers_;   // level * orientations + o; level 0 = the centre's smoothing
  std::vector<cv::Point> offsets_;  // per histogram (centre first): its sample offset from the pixel
  std::vector<int> levels_;         // per histogram: its smoothing level
  int width_ = 0, height_ = 0;
};

// L1 distance of two quantised descriptors of `stride` bytes.
[[nodiscard]] int DaisyDistance(const uint8_t* a, const uint8_t* b, int stride);

}  // namespace uavm::stereo
