#pragma once
// SIFT (Lowe 2004) of our own: a difference-of-Gaussian detector and the 4x4x8 gradient descriptor, with OpenCV 4.6's
// conventions (3 layers an octave, sigma 1.6, a doubled first octave, the same thresholds, the descriptor quantised to
// 0..255) so that options and figures carry over. What differs is how it is computed:
//  - one octave's images at a time, in buffers reused by every octave (8 images of the first octave's size, not the
//    whole pyramid's 11 per octave), taken from the Mat allocator (the pool);
//  - separable Gaussians in strips of rows, loops the compiler vectorises across columns (SSE2/AVX2 on x86-64 by
//    function clones, NEON on aarch64), in one fixed order of float operations: x86-64 and aarch64 give the same bits;
//  - a cheap first rejection (half the contrast threshold, then the 8 neighbours in the same layer) before the
//    26-neighbour test, and orientations and descriptors only for keypoints that can still be among the strongest
//    `max_features` (OpenCV computes orientations for every extremum and drops most afterwards);
//  - exp, atan2 and sin/cos from core/features/portable_math.h.
// Keypoints are in the input's pixel-centre coordinates (pixel i's centre is at i).
#include <opencv2/core.hpp>
#include <vector>

namespace uavm {

struct DogSiftOptions {
  int octave_layers = 3;
  double contrast_threshold = 0.01;  // on |DoG| * octave_layers, intensities in 0..1 (OpenCV's meaning)
  // With fewer than target_min_features keypoints the threshold is lowered (x 1/3, not below min_contrast_threshold)
  // as if detection were run again, but on the same scale space: only the extremum search is repeated, on the first
  // octave, while its count promises too few.
  int target_min_features = 0;
  double min_contrast_threshold = 0.0;
  double edge_threshold = 10.0;
  double sigma = 1.6;
  int max_features = 3000;  // strongest by |DoG| response; 0 = all
  bool double_first_octave = true;
  // Orientations and descriptors of the doubled octave's keypoints from its Gaussian layers at the input's resolution
  // (every second pixel): a quarter of those keypoints' work and memory, but 7-8 % fewer correct matches
  // (bench/sift_peers.cpp) and the accuracy gate's flights 0.87 -> 0.97 of OpenCV's error (geometric mean): off.
  bool describe_at_input_resolution = false;
};

struct SiftKeypoint {
  cv::Point2f point;     // input pixel coordinates
  float size = 0.f;      // diameter of the blob in input pixels (OpenCV's KeyPoint::size)
  float angle = 0.f;     // degrees, [0, 360), OpenCV's convention
  float response = 0.f;  // |DoG| at the interpolated extremum
  int octave = 0;        // 0 = the first (doubled) octave
};

// Detects and describes `gray` (CV_8UC1). Descriptors: CV_32F, one row of 128 per keypoint, values 0..255 as
// OpenCV's. Keypoints come strongest first; with max_features > 0 at most that many (OpenCV keeps ties at the cut;
// this does not). Thread-safe; uses cv::parallel_for_.
void DetectAndDescribeSift(const cv::Mat& gray, const DogSiftOptions& options, std::vector<SiftKeypoint>* keypoints,
                           cv::Mat* descriptors, double* contrast_threshold_used = nullptr);

// Bytes of the scale space DetectAndDescribeSift holds for a width x height image, in MiB: the 8 float images of its
// first octave (the rows of its Gaussian strips and the keypoints are small beside them).
[[nodiscard]] double DogSiftScaleSpaceMiB(int width, int height, bool double_first_octave = true);

}  // namespace uavm
