#include "core/features/sift.h"

#include <algorithm>
#include <mutex>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/features/dog_sift.h"
#include "core/util/burst_workers.h"

namespace uavm {

bool FeatureOptions::Check(std::string* why) const {
  auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (max_features < 16) return fail("features.max_features must be >= 16");
  if (!(contrast_threshold > 0.0 && contrast_threshold < 1.0))
    return fail("features.contrast_threshold must be in (0,1)");
  if (!(min_contrast_threshold > 0.0 && min_contrast_threshold <= contrast_threshold))
    return fail("features.min_contrast_threshold must be in (0, contrast_threshold]");
  if (target_min_features < 0) return fail("features.target_min_features must be >= 0");
  if (octave_layers < 1 || octave_layers > 8) return fail("features.octave_layers must be in [1,8]");
  if (max_scale_space_mib < 0) return fail("features.max_scale_space_mib must be >= 0");
  if (band_margin < 16) return fail("features.band_margin must be >= 16");
  if (descriptor_samples_per_cell != 0 && (descriptor_samples_per_cell < 2 || descriptor_samples_per_cell > 8))
    return fail("features.descriptor_samples_per_cell must be 0 (every pixel) or in [2,8]");
  return true;
}

double SiftScaleSpaceMiB(int width, int height, const FeatureOptions& options) {
  if (!options.opencv_sift)
    return DogSiftScaleSpaceMiB(width, height, options.octave_layers, options.double_first_octave);
  // Octave -1 is 2w x 2h; each further octave a quarter of the previous: 4/3 of the first in all.
  constexpr double kImagesPerOctave = 11.0;  // 6 Gaussian + 5 difference-of-Gaussian, float
  const double first = 4.0 * static_cast<double>(width) * static_cast<double>(height) * sizeof(float);
  return first * kImagesPerOctave * 4.0 / 3.0 / (1024.0 * 1024.0);
}

int SiftBands(int width, int height, const FeatureOptions& options) {
  if (options.max_scale_space_mib <= 0) return 1;
  constexpr int kMaxBands = 16;
  for (int bands = 1; bands <= kMaxBands; ++bands) {
    const int rows = (height + bands - 1) / bands + (bands > 1 ? 2 * options.band_margin : 0);
    if (SiftScaleSpaceMiB(width, std::min(rows, height), options) <= options.max_scale_space_mib) return bands;
  }
  return kMaxBands;
}

struct SiftExtractor::Held {
  std::mutex mutex;
  DogSiftBuffers buffers;
  std::unique_ptr<BurstWorkers> workers;
};

SiftExtractor::SiftExtractor(const FeatureOptions& options) : options_(options), held_(std::make_unique<Held>()) {}

SiftExtractor::~SiftExtractor() = default;

void SiftExtractor::ReleaseBuffers() const {
  const std::lock_guard<std::mutex> lock(held_->mutex);
  held_->buffers.Release();
  held_->workers.reset();
}

size_t SiftExtractor::HeldBytes() const {
  const std::lock_guard<std::mutex> lock(held_->mutex);
  return held_->buffers.bytes();
}

namespace {

// One SIFT pass over `gray`: at most max_features keypoints (OpenCV keeps ties at the cut, so it may return a few
// more), positions in pixel-centre coordinates. With `ladder` (ours only), the threshold is lowered within the pass
// as Extract's loop would (DogSiftOptions::target_min_features); *threshold_used says where it stopped.
void DetectOnce(const cv::Mat& gray, const FeatureOptions& options, int max_features, double threshold,
                DogSiftBuffers* buffers, BurstWorkers* workers, std::vector<cv::KeyPoint>* keypoints,
                cv::Mat* descriptors, bool ladder = false, double* threshold_used = nullptr) {
  keypoints->clear();
  if (threshold_used != nullptr) *threshold_used = threshold;
  if (options.opencv_sift) {
    auto sift = cv::SIFT::create(max_features, options.octave_layers, threshold, 10.0, 1.6);
    sift->detectAndCompute(gray, cv::noArray(), *keypoints, *descriptors);
    // OpenCV's SIFT reports positions as doubled-image index / 2, while pixel centres of the doubled image sit at
    // (i + 0.5) / 2 - 0.5: every keypoint is 0.25 px too far right and down. Harmless for a pure translation, but
    // with rotation or scale it biases the fitted transform by (I - L) * 0.25 px.
    for (auto& k : *keypoints) k.pt -= cv::Point2f(0.25f, 0.25f);
    return;
  }
  DogSiftOptions o;
  o.octave_layers = options.octave_layers;
  o.contrast_threshold = threshold;
  o.max_features = max_features;
  o.double_first_octave = options.double_first_octave;
  o.descriptor_samples_per_cell = options.descriptor_samples_per_cell;
  if (ladder) {
    o.target_min_features = options.target_min_features;
    o.min_contrast_threshold = options.min_contrast_threshold;
  }
  std::vector<SiftKeypoint> found;
  DetectAndDescribeSift(gray, o, &found, descriptors, threshold_used, buffers, workers);
  keypoints->reserve(found.size());
  for (const auto& k : found) keypoints->emplace_back(k.point, k.size, k.angle, k.response, k.octave);
}

}  // namespace

void SiftExtractor::Detect(const cv::Mat& gray, double threshold, DogSiftBuffers* buffers, BurstWorkers* workers,
                           std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors) const {
  const int bands = SiftBands(gray.cols, gray.rows, options_);
  if (bands <= 1) {
    DetectOnce(gray, options_, options_.max_features, threshold, buffers, workers, keypoints, descriptors);
    if (keypoints->size() > static_cast<size_t>(options_.max_features)) {
      std::vector<size_t> order(keypoints->size());
      for (size_t i = 0; i < order.size(); ++i) order[i] = i;
      std::stable_sort(order.begin(), order.end(),
                       [&](size_t a, size_t b) { return (*keypoints)[a].response > (*keypoints)[b].response; });
      order.resize(static_cast<size_t>(options_.max_features));
      std::sort(order.begin(), order.end());
      std::vector<cv::KeyPoint> kept;
      cv::Mat kept_desc(static_cast<int>(order.size()), descriptors->cols, descriptors->type());
      for (size_t i = 0; i < order.size(); ++i) {
        kept.push_back((*keypoints)[order[i]]);
        descriptors->row(static_cast<int>(order[i])).copyTo(kept_desc.row(static_cast<int>(i)));
      }
      *keypoints = std::move(kept);
      *descriptors = kept_desc;
    }
    return;
  }
  // Each band is detected with its overlap and keeps the keypoints of its own rows; per band a proportional share
  // of max_features (with slack) bounds the descriptor work, then the strongest max_features overall are kept.
  const int band_rows = (gray.rows + bands - 1) / bands;
  std::vector<cv::KeyPoint> all;
  std::vector<cv::Mat> rows;
  for (int b = 0; b < bands; ++b) {
    const int y0 = b * band_rows;
    const int y1 = std::min(gray.rows, y0 + band_rows);
    if (y0 >= y1) break;
    const int ry0 = std::max(0, y0 - options_.band_margin);
    const int ry1 = std::min(gray.rows, y1 + options_.band_margin);
    const int share = static_cast<int>(1.5 * options_.max_features * (y1 - y0) / gray.rows) + 16;
    std::vector<cv::KeyPoint> kps;
    cv::Mat desc;
    DetectOnce(gray.rowRange(ry0, ry1), options_, share, threshold, buffers, workers, &kps, &desc);
    for (size_t i = 0; i < kps.size(); ++i) {
      cv::KeyPoint kp = kps[i];
      kp.pt.y += static_cast<float>(ry0);
      if (kp.pt.y < static_cast<float>(y0) - 0.5f || kp.pt.y >= static_cast<float>(y1) - 0.5f) continue;
      all.push_back(kp);
      rows.push_back(desc.row(static_cast<int>(i)));
    }
  }
  std::vector<size_t> order(all.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return all[a].response > all[b].response; });
  if (order.size() > static_cast<size_t>(options_.max_features))
    order.resize(static_cast<size_t>(options_.max_features));
  keypoints->clear();
  descriptors->create(static_cast<int>(order.size()), rows.empty() ? 128 : rows.front().cols, CV_32F);
  for (size_t i = 0; i < order.size(); ++i) {
    keypoints->push_back(all[order[i]]);
    rows[order[i]].copyTo(descriptors->row(static_cast<int>(i)));
  }
}

Features SiftExtractor::Extract(const cv::Mat& gray_in) const {
  Features out;
  if (gray_in.empty() || gray_in.type() != CV_8UC1) return out;
  cv::Mat gray = gray_in;
  const bool half = options_.half_size && std::min(gray_in.cols, gray_in.rows) >= 64;
  if (half) cv::resize(gray_in, gray, cv::Size((gray_in.cols + 1) / 2, (gray_in.rows + 1) / 2), 0, 0, cv::INTER_AREA);
  std::vector<cv::KeyPoint> keypoints;
  double threshold = options_.contrast_threshold;
  // The held scale space, for our detector and while no other call has it; let go once detection is done.
  std::unique_lock<std::mutex> lock(held_->mutex, std::defer_lock);
  if (!options_.opencv_sift) (void)lock.try_lock();
  DogSiftBuffers* buffers = lock.owns_lock() ? &held_->buffers : nullptr;
  if (lock.owns_lock() && options_.awake_workers && !held_->workers && cv::getNumThreads() > 1)
    held_->workers = std::make_unique<BurstWorkers>(cv::getNumThreads() - 1);
  BurstWorkers* workers = lock.owns_lock() ? held_->workers.get() : nullptr;
  if (!options_.opencv_sift && SiftBands(gray.cols, gray.rows, options_) == 1) {
    // Ours lowers the threshold on one scale space instead of detecting again.
    DetectOnce(gray, options_, options_.max_features, threshold, buffers, workers, &keypoints, &out.descriptors, true,
               &out.contrast_threshold_used);
  } else {
    for (;;) {
      keypoints.clear();
      Detect(gray, threshold, buffers, workers, &keypoints, &out.descriptors);
      out.contrast_threshold_used = threshold;
      if (static_cast<int>(keypoints.size()) >= options_.target_min_features) break;
      const double next = threshold / 3.0;
      if (next < options_.min_contrast_threshold) break;
      threshold = next;
    }
  }
  if (lock.owns_lock()) lock.unlock();
  out.points.reserve(keypoints.size());
  for (const auto& kp : keypoints) out.points.push_back(kp.pt);
  // Pixel centres map as (p + 0.5) * s - 0.5 with s the exact size ratio (2 for an even side: 2p + 0.5; an odd side
  // is shrunk by slightly less than 2).
  if (half) {
    const float sx = static_cast<float>(gray_in.cols) / static_cast<float>(gray.cols);
    const float sy = static_cast<float>(gray_in.rows) / static_cast<float>(gray.rows);
    for (auto& p : out.points) p = cv::Point2f((p.x + 0.5f) * sx - 0.5f, (p.y + 0.5f) * sy - 0.5f);
  }
  if (options_.root_sift && !out.descriptors.empty()) {
    // Row by row (the same bits on any number of threads); ~1 ms of 3000 rows on one core.
    cv::parallel_for_(cv::Range(0, out.descriptors.rows), [&](const cv::Range& range) {
      for (int r = range.start; r < range.end; ++r) {
        cv::Mat row = out.descriptors.row(r);
        const double l1 = cv::norm(row, cv::NORM_L1);
        if (l1 > 0) row /= l1;
        cv::sqrt(row, row);
      }
    });
  }
  return out;
}

}  // namespace uavm
