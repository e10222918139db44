#pragma once
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace uavm {

struct FeatureOptions {
  // Keep at most this many keypoints (strongest first).
  int max_features = 3000;
  // Start threshold. OpenCV's default 0.04 finds only tens of keypoints on soft aerial frames.
  double contrast_threshold = 0.01;
  // When fewer keypoints than this are found, the threshold is lowered (x1/3) down to min_contrast_threshold.
  int target_min_features = 1500;
  double min_contrast_threshold = 0.001;
  int octave_layers = 3;
  // L1-normalise and square-root descriptors (RootSIFT): better ratio-test matching at no cost.
  bool root_sift = true;
  // OpenCV 4.6's SIFT instead of ours (core/features/dog_sift.h), for comparison: the same conventions, ~3x the time.
  bool opencv_sift = false;
  // Memory cap on the scale space (ours keeps 6 int16 images of the doubled first octave: 48 bytes per working pixel,
  // 34 MiB for 1000x750; OpenCV's 11 float images per octave of the whole pyramid, 235 bytes, 168 MiB). Above it the
  // frame is processed in horizontal bands with an overlap (band_margin px) that covers the detection and descriptor
  // support of all but the coarsest octaves; 0 = no cap. Set from the memory budget.
  int max_scale_space_mib = 0;
  int band_margin = 48;
  // Detect and describe on a half-size copy (area-averaged): SIFT doubles its input first, so this is SIFT's scale
  // space from the working resolution up, at ~1/4 of the time and memory; positions are mapped back to the working
  // copy (measured in bench/results/speed-profile-*.md).
  bool half_size = false;
  // Ours only: the first octave at twice the input's size (Lowe's and OpenCV's default) or at the input's own. The
  // doubled octave holds 4 of the scale space's 5.3 input-sized images of work; what it buys is measured in
  // bench/results/sift-first-octave-*.md.
  bool double_first_octave = true;
  // Ours only: the descriptor from this many bilinear samples a cell and side on its rotated grid (a fixed cost per
  // keypoint whatever its scale), or from every pixel of its window as OpenCV's (0). What it changes is measured in
  // bench/results/sift-sampled-descriptor-*.md.
  int descriptor_samples_per_cell = 4;
  // Ours only: the detection's loops on worker threads of the extractor's own that poll for the next loop through a
  // frame (BurstWorkers), or on OpenCV's pool, whose threads sleep between loops (false). The same keypoints either
  // way; what it changes is measured in bench/results/sift-burst-workers-*.md.
  bool awake_workers = true;

  [[nodiscard]] bool Check(std::string* why) const;
};

// MiB of the scale space for a width x height image (ours: DogSiftScaleSpaceMiB; OpenCV's: doubled first octave, 6
// Gaussian + 5 DoG float images per octave, the whole pyramid at once).
[[nodiscard]] double SiftScaleSpaceMiB(int width, int height, const FeatureOptions& options);
// Number of horizontal bands Extract() uses for a width x height image under `options`.
[[nodiscard]] int SiftBands(int width, int height, const FeatureOptions& options);

// Keypoints of one frame at working resolution. Descriptors are CV_32F, one row per point.
struct Features {
  std::vector<cv::Point2f> points;
  cv::Mat descriptors;
  double contrast_threshold_used = 0.0;

  [[nodiscard]] size_t size() const { return points.size(); }
  [[nodiscard]] size_t MemoryBytes() const {
    return points.size() * sizeof(cv::Point2f) + descriptors.total() * descriptors.elemSize();
  }
};

class BurstWorkers;
class DogSiftBuffers;

// Keeps our detector's scale space (DogSiftBuffers) from one Extract to the next, so that a flight's frames reuse one
// block (SiftScaleSpaceMiB / bands: the memory plan's detector figure) instead of mapping it anew, and its worker
// threads (BurstWorkers: cv::getNumThreads() - 1, started by the first Extract, awake through each detection); a call
// made while another holds them uses a block of its own and cv::parallel_for_. ReleaseBuffers() gives the block back
// and joins the workers (the end of the flight).
class SiftExtractor {
 public:
  explicit SiftExtractor(const FeatureOptions& options);
  ~SiftExtractor();
  SiftExtractor(const SiftExtractor&) = delete;
  SiftExtractor& operator=(const SiftExtractor&) = delete;
  // `gray` is CV_8UC1. Never throws on valid 8-bit input; an empty image gives no features. Thread-safe.
  [[nodiscard]] Features Extract(const cv::Mat& gray) const;
  void ReleaseBuffers() const;
  [[nodiscard]] size_t HeldBytes() const;

 private:
  struct Held;
  // One detection at `threshold`, whole image or banded; strongest max_features kept. Positions in pixel-centre
  // coordinates.
  void Detect(const cv::Mat& gray, double threshold, DogSiftBuffers* buffers, BurstWorkers* workers,
              std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors) const;

  FeatureOptions options_;
  std::unique_ptr<Held> held_;
};

}  // namespace uavm
