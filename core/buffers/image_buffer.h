#pragma once
// One block of memory that serves Mats of any size and type up to its capacity, for work done again and again on
// pieces of different sizes (a tile's warps, masks and pyramid levels). cv::Mat::create reallocates whenever the
// size changes; a freed piece and the next, slightly larger one then leave the heap with holes that neither fits
// (a 5000-frame flight's mosaic peaked 25 MiB higher with them). A view into a block that only ever grows keeps the
// working set at the largest piece. OpenCV functions write into a view without reallocating when its size and type
// are those they produce.
#include <cstddef>
#include <opencv2/core.hpp>

namespace uavm {

class ImageBuffer {
 public:
  // A Mat of `size` and `type` over the block (continuous), grown first when it is too small. Its contents are
  // whatever the block held; a view from an earlier call stays valid unless this call grew the block.
  [[nodiscard]] cv::Mat View(cv::Size size, int type);
  // Grows the block to `bytes` now (e.g. for the largest piece a worker will see).
  void Reserve(size_t bytes);
  // Reserve, and writes the whole block so that its pages are resident now: the holder's memory is then the same
  // whatever it views later (a block mapped afresh is resident only where it has been written).
  void ReserveResident(size_t bytes);
  [[nodiscard]] size_t capacity() const { return block_.total(); }

 private:
  cv::Mat block_;  // capacity bytes (continuous)
};

}  // namespace uavm
