#pragma once
// SIFT (Lowe 2004) of our own: a difference-of-Gaussian detector and the 4x4x8 gradient descriptor, with OpenCV 4.6's
// conventions (3 layers an octave, sigma 1.6, a doubled first octave, its contrast and edge thresholds, the descriptor
// quantised to 0..255) so that options and figures carry over. What differs is how it is computed:
//  - one octave's images at a time, its L + 3 Gaussian layers only (L + 3 of the first octave's size at the peak, not
//    the whole pyramid's 2 L + 5 per octave): the differences of Gaussians are computed where they are read, row by row
//    for the extremum search; all in one block from the Mat allocator (the pool hands it back every frame); each
//    octave's layers 1 .. L stay for the descriptors;
//  - a scale space in fixed point: int16 images of grey levels x 256 (half the bytes of floats), separable Gaussians
//    to 3 sigma with Q15 weights summed exactly and rounded once a pass (core/features/q15_blur.h: AVX2 and NEON,
//    twice the lanes of floats), in blocks of rows with a ring of horizontally blurred rows: integers, so x86-64 and
//    aarch64 give the same scale space; the extremum search in int16 lanes too, a sample beating the neighbours
//    before it and matching those after it (integers tie);
//  - Lowe's first rejection at half the contrast threshold (OpenCV floors it to whole grey levels: 0 at the onboard
//    0.01), then the 8 neighbours in the same layer and the 2 in the same place above and below, vectorised, before
//    the 26-neighbour test; orientations and
//    descriptors only for keypoints that can be among the strongest `max_features` (OpenCV orients every extremum);
//  - the descriptor from a fixed grid of bilinear samples on its rotated window (4 x 4 a cell and over the half-cell
//    margin OpenCV reads: 20 x 20), gradients as differences of neighbouring samples: the same work at every scale,
//    where OpenCV's every-pixel window grows with the scale squared (~900 pixels at sigma 2, 2300 at 3.2); the same
//    matches (graf pair, a turned frame, the gate's flights over 16 seeds: bench/results/sift-sampled-descriptor-*);
//    descriptor_samples_per_cell = 0 gives OpenCV's every-pixel window instead;
//  - orientation gradients eight pixels at a time (the same vector extension), the windows visited in the order they
//    lie in the image; exp, atan2 and sin/cos from core/features/portable_math.h.
// Keypoints are in the input's pixel-centre coordinates (pixel i's centre is at i).
#include <opencv2/core.hpp>
#include <vector>

namespace uavm {

class BurstWorkers;

struct DogSiftOptions {
  int octave_layers = 3;
  double contrast_threshold = 0.01;  // on |DoG| * octave_layers, intensities in 0..1 (OpenCV's meaning)
  // With fewer than target_min_features keypoints the threshold is lowered (x 1/3, not below min_contrast_threshold,
  // which must then be > 0) as if detection were run again, but on the same scale space: only the extremum search is
  // repeated, on the first octave, while its count promises too few. Not exactly a second detection: an extremum
  // whose first sample lies between the two levels' first rejections is kept at the higher level too (rare).
  int target_min_features = 0;
  double min_contrast_threshold = 0.0;
  // The level of that ladder (0 = contrast_threshold) at which the first octave is searched first; the levels above
  // are taken from that one search, exactly as searches of their own would find them, so this changes the cost, not
  // the keypoints. -1: the level of the threshold the last frame needed (held in the caller's DogSiftBuffers; 0 without
  // them): a
  // low-texture flight's frames then skip the search at the top that promised too few (~2 ms a 640x480 frame), and a
  // textured one's do not fit the extra candidates of a lower level (~1 ms a 1000x562 frame).
  int first_octave_search_level = -1;
  double edge_threshold = 10.0;
  double sigma = 1.6;
  int max_features = 3000;  // strongest by |DoG| response; 0 = all
  bool double_first_octave = true;
  // The descriptor from S x S bilinear samples a cell on its rotated grid (S = this, 2 .. 8), or from every pixel of
  // its window as OpenCV's (0).
  int descriptor_samples_per_cell = 4;
};

struct SiftKeypoint {
  cv::Point2f point;     // input pixel coordinates
  float size = 0.f;      // diameter of the blob in input pixels (OpenCV's KeyPoint::size)
  float angle = 0.f;     // degrees, [0, 360), OpenCV's convention
  float response = 0.f;  // |DoG| at the interpolated extremum
  int octave = 0;        // 0 = the first (doubled) octave
};

// The scale space's memory (one block, DogSiftScaleSpaceMiB), and the ladder's level the last frame needed, kept from
// one call to the next by a caller that
// detects frame after frame. Without it each call takes its block from the allocator: between two frames of a flight
// the image pool gave it back to make room for the matching's buffers, and the kernel zeroed every page of the new
// one (9 % of a simulated flight's CPU, ~15 ms a frame). The block grows to the largest image seen and is kept until
// Release(); one call at a time uses it.
class DogSiftBuffers {
 public:
  void Release() { block_.release(); }
  [[nodiscard]] size_t bytes() const { return block_.total() * block_.elemSize(); }
  // A block of at least `needed` bytes: the one held when it is large enough, else a new one that replaces it.
  [[nodiscard]] uchar* Take(size_t needed);
  // The threshold the last frame's first octave needed (DogSiftOptions::first_octave_search_level; 0 = none yet): a
  // value, not a level, because a detection done again lower starts its ladder further down.
  [[nodiscard]] double first_octave_threshold() const { return first_octave_threshold_; }
  void set_first_octave_threshold(double threshold) { first_octave_threshold_ = threshold; }

 private:
  cv::Mat block_;
  double first_octave_threshold_ = 0.0;
};

// Detects and describes `gray` (CV_8UC1). Descriptors: CV_32F, one row of 128 per keypoint, values 0..255 as
// OpenCV's. Keypoints come strongest first; with max_features > 0 at most that many (OpenCV keeps ties at the cut;
// this does not). Thread-safe (for calls with different `buffers` and `workers`, or none). With `buffers` the scale
// space lives in their block instead of one of its own. Its loops run on `workers` (kept awake through the call), or
// on cv::parallel_for_ without them; the same bits either way, on any number of threads.
void DetectAndDescribeSift(const cv::Mat& gray, const DogSiftOptions& options, std::vector<SiftKeypoint>* keypoints,
                           cv::Mat* descriptors, double* contrast_threshold_used = nullptr,
                           DogSiftBuffers* buffers = nullptr, BurstWorkers* workers = nullptr);

// The scale space DetectAndDescribeSift holds for a width x height image, in MiB: the L + 3 int16 images of its first
// octave (up to 8 layers), 6 for the default 3 (the rows of its Gaussian strips and the keypoints are small beside
// them).
[[nodiscard]] double DogSiftScaleSpaceMiB(int width, int height, int octave_layers = 3,
                                          bool double_first_octave = true);

}  // namespace uavm
