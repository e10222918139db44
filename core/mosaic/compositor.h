#pragma once
#include <functional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "core/geometry/transform.h"

namespace uavm {

class GdalTiffWriter;

// Canvas pixels a multi-band blend of `num_bands` levels reads around a pixel (0 for hard seams): what a tile's
// margin, a frame's warped area beyond what it owns and its cached crop must cover so that the pyramid sees
// image, not a border. The one definition: the compositor and the memory budget (via Margin()) use it.
[[nodiscard]] constexpr int BlendReach(int num_bands) {
  return num_bands > 0 ? 3 << num_bands : 0;
}

struct CompositorOptions {
  int tile_size = 1024;  // canvas pixels per composited tile (a multiple of tiff_block)
  int tiff_block = 512;
  int num_bands = 5;                  // multi-band levels; 0 = hard seams only
  double max_covered_fraction = 0.9;  // overlap-based frame selection (see SelectByOverlap)
  int quicklook_long_side = 2000;
  // Where the quick-look PNG goes (empty: none; set by the caller, not a config key). It is made on disk as the
  // tiles arrive (see Composite), so it costs no memory whatever the canvas.
  std::string quicklook_path;
  // All frame pixels: the loads in flight and the decoded frame parts kept between tiles.
  size_t image_cache_bytes = size_t{256} << 20;
  // Share of the frame cache, beyond one decoded part per worker, that keeps parts as in-memory JPEG (reloaded by a
  // small decode instead of the stored frame's); 0 = decoded parts only.
  double compressed_share = 0.75;
  // The decoded tier's bytes beyond one part per worker, MiB at most (0 = none): a fixed line of the plan. Without it
  // the tier took its share of whatever the budget left, and a long flight (more frames about each tile) filled it
  // where a short one did not: 20 MiB at 5000 frames against 14 at 200. A part it evicts is a small JPEG decode away.
  double decoded_cache_mib = 8;
  bool build_overviews = true;
  int threads = 2;          // tile workers
  int gdal_cache_mib = 64;  // GDAL's block cache while the TIFF is written (tiles are written once)
  // The whole program's memory budget, MiB (0 = none; set by ApplyMemoryBudget, not a config key): frame pixels and
  // workers are fitted into what is left of it when compositing starts (see FitCompositorMemory).
  int memory_budget_mib = 0;

  [[nodiscard]] bool Check(std::string* why) const;
  // Margin around each tile so that the pyramid of the blend does not see the tile border (a hard-seam tile still
  // keeps 2 px).
  [[nodiscard]] int Margin() const { return num_bands > 0 ? BlendReach(num_bands) : 2; }
  // Working memory of one tile worker, MiB: 16-bit Laplacian pyramids and their Gaussian sources, float weights,
  // warped frame, maps, masks over the tile and its margin. The one definition: the budget plans with it.
  [[nodiscard]] double BlendMiBPerWorker() const;
  // The TIFF writer while tiles are written: GDAL's block cache and what GDAL/libtiff hold besides it.
  [[nodiscard]] double WriterMiB() const;
};

// How the compositor's memory is split once the frames and the canvas are known.
struct CompositorMemory {
  int threads = 1;
  size_t cache_bytes = 0;       // decoded (cropped) frames kept between tiles
  size_t largest_part = 0;      // bytes of the largest decoded part: the cache keeps one per worker at least
  bool fits = true;             // false: even one worker with one cached frame exceeds the allowance
  bool parallel_loads = false;  // workers load frame parts at the same time (set by the compositor)
};

// Splits `pixel_bytes`, all the memory for frame pixels (the loads in flight, the cache), when the loads in flight
// hold `largest_load` bytes at most and the largest cached crop is `largest_crop` bytes. Each of `threads` workers
// holds at least one cached crop; while that does not fit, a worker is dropped and its `blend_bytes_per_worker` go to
// frame pixels.
[[nodiscard]] CompositorMemory FitCompositorMemory(size_t pixel_bytes, size_t largest_load, size_t largest_crop,
                                                   int threads, size_t blend_bytes_per_worker);

// A frame to composite: canvas_from_image acts on the pixel grid of the image that `load` returns.
struct CompositeInput {
  int id = -1;
  Mat3 canvas_from_image = Mat3::Identity();
  cv::Size image_size;
  // Most bytes a load of the whole frame holds at once (e.g. a larger decode and its resized copy); 0 = not known,
  // then taken as the worst a DCT-scaled JPEG decode resized to image_size gives (see Composite).
  size_t load_bytes = 0;
  // The loader reads only the part asked for (JPEG region decoding): a load then holds about load_bytes times the
  // part's share of the image, and such loads may run in parallel.
  bool region_loads = false;
  // A disc of the image the seams keep out of where another frame sees the same ground (e.g. the sun's hotspot and
  // the drone's shadow, which no gain removes); image_size pixels, radius 0 = none.
  cv::Point2d avoid_centre;
  double avoid_radius = 0.0;
};

using ImageLoadFn = std::function<cv::Mat(int id)>;  // BGR8 image of a frame; empty = unreadable

// Part of a frame's image: `image`'s pixel (0, 0) is at `origin` in the image_size grid (fractional when the loader
// resized a decoded part: the part keeps the whole image's sampling, only its start moves).
struct FramePart {
  cv::Mat image;  // BGR8; empty = unreadable
  cv::Point2d origin;
};
// Returns at least `need` (pixels of the frame's image_size grid) of frame `id`, or more (the whole image, origin 0).
using PartLoadFn = std::function<FramePart(int id, const cv::Rect& need)>;

struct CompositeResult {
  bool ok = false;
  std::string error;
  cv::Size canvas;
  int frames_used = 0;
  int frames_dropped_by_overlap = 0;
  int frames_unreadable = 0;
  int tiles_written = 0;
  int image_loads = 0;          // loads of stored frames, counting reloads after cache eviction
  int reloads_from_memory = 0;  // parts decoded again from the cache's in-memory JPEG instead
  int parts_released = 0;       // frames dropped from the cache once no tile left needed them
  size_t cache_peak_bytes = 0;  // the frame cache's high-water mark, both tiers
  double load_ms = 0.0;         // time in those decodes, summed over the workers
  double ms = 0.0;
  cv::Size quicklook_size;  // of the PNG at options.quicklook_path (RGBA, transparent outside the flown area)
};

// The canvas's tiles of tile_size (clipped at its edges) in the order the compositor makes them: along a Hilbert curve
// over the smallest power-of-two grid that holds them.
[[nodiscard]] std::vector<cv::Rect> TilesAlongHilbertCurve(cv::Size canvas, int tile_size);

// Composites `frames` onto a canvas of size `canvas` tile by tile: per tile, each pixel is owned by the frame whose
// border is farthest (distance-to-border seams, in canvas pixels), owners are warped and blended with multi-band
// blending over the tile plus a margin, and the tile goes to `tiff` (may be null) and the quick-look. A write error
// (a full disk) stops it with the error in the result; what was written is removed or left incomplete for a retry.
// `frames` is taken (moved in by a caller that has no more use for it): a long flight's inputs are filtered in place
// instead of copied.
[[nodiscard]] CompositeResult Composite(std::vector<CompositeInput> frames, cv::Size canvas, const PartLoadFn& load,
                                        const CompositorOptions& options, GdalTiffWriter* tiff);
// The same with a loader of whole frames.
[[nodiscard]] CompositeResult Composite(std::vector<CompositeInput> frames, cv::Size canvas, const ImageLoadFn& load,
                                        const CompositorOptions& options, GdalTiffWriter* tiff);

// Renders one ROI of the canvas (for tests and previews), with the same seams and blending as Composite.
[[nodiscard]] bool RenderRoi(const std::vector<CompositeInput>& frames, const std::vector<cv::Mat>& images,
                             const cv::Rect& roi, int num_bands, cv::Mat* image, cv::Mat* mask);

}  // namespace uavm
