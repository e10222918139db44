#include "core/mosaic/compositor.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <list>
#include <memory>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <unordered_map>

#include "core/buffers/image_buffer.h"
#include "core/imageio/jpeg_memory.h"
#include "core/imageio/png_writer.h"
#include "core/mosaic/gdal_writer.h"
#include "core/mosaic/selection.h"
#include "core/mosaic/tile_blender.h"
#include "core/util/clock.h"
#include "core/util/hilbert.h"
#include "core/util/memory.h"
#include "core/util/parallel.h"

namespace uavm {

bool CompositorOptions::Check(std::string* why) const {
  auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (tiff_block < 16 || tiff_block % 16 != 0) return fail("mosaic.tiff_block must be a multiple of 16");
  if (tile_size < tiff_block || tile_size % tiff_block != 0)
    return fail("mosaic.tile_size must be a multiple of tiff_block");
  if (num_bands < 0 || num_bands > 10) return fail("mosaic.num_bands must be in [0,10]");
  if (threads < 1 || threads > 64) return fail("mosaic.threads must be in [1,64]");
  if (gdal_cache_mib < 1) return fail("mosaic.gdal_cache_mib must be >= 1");
  if (!(compressed_share >= 0.0 && compressed_share <= 1.0)) return fail("mosaic.compressed_share must be in [0, 1]");
  if (!(decoded_cache_mib >= 0.0)) return fail("mosaic.decoded_cache_mib must be >= 0");
  if (!(max_covered_fraction > 0.0 && max_covered_fraction <= 1.0))
    return fail("mosaic.max_covered_fraction must be in (0,1]");
  if (quicklook_long_side < 16) return fail("mosaic.quicklook_long_side must be >= 16");
  return true;
}

namespace {

// Per tile pixel (tile + margin) and worker: the worker's own buffers (TileWork) at their largest, ~55 bytes (the
// blender's 16-bit sums and float weights, the fed piece's pyramids, each 4/3 of a level: 27; its bordered copy,
// mask and expanded level: 10; owner, mask, maps, warp, blended image and mask: 18), and the quick-look's share of a
// tile and what OpenCV allocates inside its calls. Measured as 1 vs 2 workers: ~30 MiB for 704x704 (bench/memory.sh).
constexpr double kBytesPerBlendPixel = 64;
// GDAL/libtiff beyond the block cache while tiles are written (1 MiB RGB/RGBA copies of a tile, compression state,
// the driver): measured as --no-tiff vs TIFF minus the cache on 12 MP flights.
constexpr double kWriterOverheadMiB = 8;
// A JPEG decoded at 1/2^k (DCT scaling) and resized to the image: the decode may be up to 1.6x the image's side
// (the loader enlarges by up to 1.25x after a reduction that halves again), i.e. 2.56x its area, beside the image.
constexpr double kWorstLoadPerImageByte = 2.56 + 1.0;
// The resident set, as a share of the budget, above which a tile's end gives free heap pages back to the kernel.
constexpr double kTrimAboveBudgetShare = 0.9;
// Image pixels a region load may add on each side of the part asked for: libjpeg's MCU columns (16 px at most) and
// the margin a resized region keeps.
constexpr double kRegionPad = 24;

}  // namespace

double CompositorOptions::BlendMiBPerWorker() const {
  const double side = tile_size + 2.0 * Margin();
  return side * side * kBytesPerBlendPixel / kMiB;
}

double CompositorOptions::WriterMiB() const {
  return gdal_cache_mib + kWriterOverheadMiB;
}

CompositorMemory FitCompositorMemory(size_t pixel_bytes, size_t largest_load, size_t largest_crop, int threads,
                                     size_t blend_bytes_per_worker) {
  CompositorMemory m;
  m.threads = std::max(1, threads);
  m.largest_part = largest_crop;
  for (;;) {
    const size_t cache = pixel_bytes > largest_load ? pixel_bytes - largest_load : 0;
    const size_t floor = static_cast<size_t>(m.threads) * largest_crop;
    if (cache >= floor) {
      m.cache_bytes = cache;
      return m;
    }
    if (m.threads == 1) {
      m.cache_bytes = floor;
      m.fits = false;
      return m;
    }
    --m.threads;
    pixel_bytes += blend_bytes_per_worker;
  }
}

namespace {

// Inverse map of one frame evaluated over an ROI of the canvas, and its distance-to-border in canvas pixels.
struct FrameGeometry {
  Mat3 image_from_canvas;
  cv::Size size;
  double canvas_px_per_image_px = 1.0;
  cv::Rect2d bbox;  // footprint bounding box in the canvas
  cv::Point2d avoid_centre;
  double avoid_radius = 0.0;
};

FrameGeometry MakeGeometry(const CompositeInput& in) {
  FrameGeometry g;
  g.image_from_canvas = in.canvas_from_image.inverse();
  g.size = in.image_size;
  const Vec2 centre(0.5 * (in.image_size.width - 1), 0.5 * (in.image_size.height - 1));
  // Local scale at the centre (exact for affine maps).
  const Vec2 c0 = Apply(in.canvas_from_image, centre);
  const Vec2 cx = Apply(in.canvas_from_image, centre + Vec2(1, 0));
  const Vec2 cy = Apply(in.canvas_from_image, centre + Vec2(0, 1));
  const Eigen::Matrix2d J = (Eigen::Matrix2d() << cx - c0, cy - c0).finished();
  g.canvas_px_per_image_px = std::sqrt(std::abs(J.determinant()));
  const auto fp = Footprint(in.canvas_from_image, in.image_size.width, in.image_size.height);
  g.bbox = cv::boundingRect(fp);
  g.avoid_centre = in.avoid_centre;
  g.avoid_radius = in.avoid_radius;
  return g;
}

// Seams from distance-to-border are smooth, so ownership is decided on a grid of kSeamStep x kSeamStep cells aligned
// to the canvas (identical in every tile), then spread to the cells' pixels. A cell is owned only when its centre lies
// kSeamMargin px inside the owner, so that every pixel of the cell is inside it too.
constexpr int kSeamStep = 4;

// Fills image coordinates (map_x, map_y) for the canvas points (x0 + c * step + offset, y0 + r * step + offset),
// c < size.width, r < size.height. step 1, offset 0: every pixel of an ROI.
void ComputeMapsGrid(const FrameGeometry& g, int x0, int y0, cv::Size size, int step, double offset, cv::Mat* map_x,
                     cv::Mat* map_y) {
  const cv::Rect roi(x0, y0, size.width, size.height);
  map_x->create(size, CV_32F);
  map_y->create(size, CV_32F);
  const Mat3& H = g.image_from_canvas;
  const bool affine = IsAffine(H, 1e-15);
  for (int r = 0; r < roi.height; ++r) {
    auto* mx = map_x->ptr<float>(r);
    auto* my = map_y->ptr<float>(r);
    const double v = roi.y + r * step + offset;
    const double bx = H(0, 1) * v + H(0, 2);
    const double by = H(1, 1) * v + H(1, 2);
    const double bw = H(2, 1) * v + H(2, 2);
    for (int c = 0; c < roi.width; ++c) {
      const double u = roi.x + c * step + offset;
      const double x = H(0, 0) * u + bx;
      const double y = H(1, 0) * u + by;
      if (affine) {
        mx[c] = static_cast<float>(x);
        my[c] = static_cast<float>(y);
      } else {
        const double w = H(2, 0) * u + bw;
        mx[c] = static_cast<float>(x / w);
        my[c] = static_cast<float>(y / w);
      }
    }
  }
}

void ComputeMaps(const FrameGeometry& g, const cv::Rect& roi, cv::Mat* map_x, cv::Mat* map_y) {
  ComputeMapsGrid(g, roi.x, roi.y, roi.size(), 1, 0.0, map_x, map_y);
}

// The seam margin (see below); a frame's pixel that is inside it always scores above it.
constexpr float kSeamMargin = 3.0f;  // > half the cell diagonal (2.1 px) of the kSeamStep cells

// Distance to the nearest image border in canvas pixels; negative outside the image. Inside the frame's avoid disc
// it is scaled down towards the disc's centre (to a tenth at half its radius and nearer), so that a frame that sees
// the same ground farther from its own disc takes it; never below the seam margin, so that ground only this frame sees
// stays its own.
void BorderDistance(const FrameGeometry& g, const cv::Mat& map_x, const cv::Mat& map_y, cv::Mat* dist) {
  dist->create(map_x.size(), CV_32F);
  const float w1 = static_cast<float>(g.size.width - 1);
  const float h1 = static_cast<float>(g.size.height - 1);
  const float s = static_cast<float>(g.canvas_px_per_image_px);
  const auto ax = static_cast<float>(g.avoid_centre.x);
  const auto ay = static_cast<float>(g.avoid_centre.y);
  const auto radius = static_cast<float>(g.avoid_radius);
  for (int r = 0; r < map_x.rows; ++r) {
    const auto* mx = map_x.ptr<float>(r);
    const auto* my = map_y.ptr<float>(r);
    auto* d = dist->ptr<float>(r);
    for (int c = 0; c < map_x.cols; ++c) {
      d[c] = s * std::min(std::min(mx[c], w1 - mx[c]), std::min(my[c], h1 - my[c]));
      if (radius > 0 && d[c] > kSeamMargin + 1) {
        const float t = std::hypot(mx[c] - ax, my[c] - ay) / radius;  // 0 at the centre, 1 at the rim
        if (t < 1) {
          const float keep = 0.1f + 0.9f * std::clamp(2 * t - 1, 0.0f, 1.0f);
          d[c] = std::max(kSeamMargin + 1, d[c] * keep);
        }
      }
    }
  }
}

// One worker's buffers, reused for every tile it blends (core/buffers/image_buffer.h) and reserved before the first
// (MakeTileWorks): a worker's working set is fixed by the tile's ROI, however many tiles and frames the mosaic has.
struct TileWork {
  explicit TileWork(int num_bands) : blender(num_bands > 0 ? MakeMultiBandBlender(num_bands) : MakeSeamOnlyBlender()) {}
  // Every buffer at what a ROI of up to `largest_roi` needs, resident (see TileBlender::Reserve): per ROI pixel the
  // views BlendRoi takes (maps 8 bytes, owner 2, mask 1, warped image 3, blended image and mask 4) and per seam cell
  // its distances (best and current 4 each, owner 2; the cell maps share the pixel maps).
  void Reserve(cv::Size largest_roi);
  std::unique_ptr<TileBlender> blender;
  ImageBuffer best_dist, cell_owner, map_x, map_y, dist, owner, mask, warped, image, image_mask;
};

// Seam cells over a ROI (see BlendRoi): every cell a pixel of it falls in, for any position of the ROI on the canvas.
cv::Size SeamCellsCovering(cv::Size roi) {
  return {(roi.width + kSeamStep - 1) / kSeamStep + 1, (roi.height + kSeamStep - 1) / kSeamStep + 1};
}

void TileWork::Reserve(cv::Size largest_roi) {
  const auto pixels = static_cast<size_t>(largest_roi.area());
  const auto cells = static_cast<size_t>(SeamCellsCovering(largest_roi).area());
  best_dist.ReserveResident(cells * CV_ELEM_SIZE(CV_32F));
  cell_owner.ReserveResident(cells * CV_ELEM_SIZE(CV_16S));
  dist.ReserveResident(cells * CV_ELEM_SIZE(CV_32F));
  map_x.ReserveResident(std::max(pixels, cells) * CV_ELEM_SIZE(CV_32F));
  map_y.ReserveResident(std::max(pixels, cells) * CV_ELEM_SIZE(CV_32F));
  owner.ReserveResident(pixels * CV_ELEM_SIZE(CV_16S));
  mask.ReserveResident(pixels * CV_ELEM_SIZE(CV_8U));
  warped.ReserveResident(pixels * CV_ELEM_SIZE(CV_8UC3));
  image.ReserveResident(pixels * CV_ELEM_SIZE(CV_8UC3));
  image_mask.ReserveResident(pixels * CV_ELEM_SIZE(CV_8U));
  blender->Reserve(largest_roi);
}

// Each cell's owner among `candidates`: the frame whose border is farthest (-1: none reaches kSeamMargin).
cv::Mat SeamCellOwners(const std::vector<FrameGeometry>& geometry, const std::vector<size_t>& candidates,
                       cv::Point cell0, cv::Size cells, TileWork* work) {
  cv::Mat best_dist = work->best_dist.View(cells, CV_32F);
  best_dist.setTo(kSeamMargin);
  cv::Mat cell_owner = work->cell_owner.View(cells, CV_16S);
  cell_owner.setTo(-1);
  cv::Mat map_x = work->map_x.View(cells, CV_32F);
  cv::Mat map_y = work->map_y.View(cells, CV_32F);
  cv::Mat dist = work->dist.View(cells, CV_32F);
  for (size_t k = 0; k < candidates.size(); ++k) {
    ComputeMapsGrid(geometry[candidates[k]], cell0.x * kSeamStep, cell0.y * kSeamStep, cells, kSeamStep,
                    0.5 * (kSeamStep - 1), &map_x, &map_y);
    BorderDistance(geometry[candidates[k]], map_x, map_y, &dist);
    for (int r = 0; r < cells.height; ++r) {
      const auto* d = dist.ptr<float>(r);
      auto* b = best_dist.ptr<float>(r);
      auto* o = cell_owner.ptr<int16_t>(r);
      for (int c = 0; c < cells.width; ++c) {
        if (d[c] > b[c]) {
          b[c] = d[c];
          o[c] = static_cast<int16_t>(k);
        }
      }
    }
  }
  return cell_owner;
}

// Blends one ROI from the frames listed in `candidates` (indices into geometry / images) with `work`'s buffers.
// *out_image and *out_mask are views into them: valid until the worker's next tile.
bool BlendRoi(const std::vector<FrameGeometry>& geometry, const std::vector<size_t>& candidates,
              const std::function<cv::Mat(size_t, cv::Point2d*)>& image_of, const cv::Rect& roi, int num_bands,
              TileWork* work, cv::Mat* out_image, cv::Mat* out_mask) {
  const cv::Point cell0(roi.x / kSeamStep, roi.y / kSeamStep);
  const cv::Size cells((roi.x + roi.width + kSeamStep - 1) / kSeamStep - cell0.x,
                       (roi.y + roi.height + kSeamStep - 1) / kSeamStep - cell0.y);
  const cv::Mat cell_owner = SeamCellOwners(geometry, candidates, cell0, cells, work);
  cv::Mat owner = work->owner.View(roi.size(), CV_16S);
  for (int r = 0; r < roi.height; ++r) {
    const auto* o = cell_owner.ptr<int16_t>((roi.y + r) / kSeamStep - cell0.y);
    auto* dst = owner.ptr<int16_t>(r);
    for (int c = 0; c < roi.width; ++c) dst[c] = o[(roi.x + c) / kSeamStep - cell0.x];
  }
  TileBlender& blender = *work->blender;
  blender.Prepare(roi);
  bool fed = false;
  cv::Mat mask = work->mask.View(roi.size(), CV_8U);
  for (size_t k = 0; k < candidates.size(); ++k) {
    cv::compare(owner, cv::Scalar(static_cast<double>(k)), mask, cv::CMP_EQ);
    if (cv::countNonZero(mask) == 0) continue;
    cv::Point2d crop_tl;  // the image may be part of the frame (see NeededParts)
    // Held (shared with the cache) only while it is warped: a worker pins one frame, not all of its tile's.
    const cv::Mat img = image_of(candidates[k], &crop_tl);
    if (img.empty()) continue;
    // Only the owned area plus the pyramid's reach is warped and fed: each pixel is blended about once, not once
    // per overlapping frame.
    const int reach = BlendReach(num_bands);
    cv::Rect owned = cv::boundingRect(mask);
    owned = cv::Rect(owned.x - reach, owned.y - reach, owned.width + 2 * reach, owned.height + 2 * reach) &
            cv::Rect(0, 0, roi.width, roi.height);
    const cv::Rect sub(roi.x + owned.x, roi.y + owned.y, owned.width, owned.height);
    cv::Mat map_x = work->map_x.View(sub.size(), CV_32F);
    cv::Mat map_y = work->map_y.View(sub.size(), CV_32F);
    ComputeMaps(geometry[candidates[k]], sub, &map_x, &map_y);
    if (crop_tl != cv::Point2d()) {
      map_x -= static_cast<float>(crop_tl.x);
      map_y -= static_cast<float>(crop_tl.y);
    }
    // Reflect beyond the frame edge: the pyramid then sees image texture, not black, next to the seam.
    cv::Mat warped = work->warped.View(sub.size(), img.type());
    cv::remap(img, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REFLECT);
    blender.Feed(warped, mask(owned), sub.tl());
    fed = true;
  }
  if (!fed) return false;
  *out_image = work->image.View(roi.size(), CV_8UC3);
  *out_mask = work->image_mask.View(roi.size(), CV_8U);
  blender.Blend(out_image, out_mask);
  // The blender's mask is the union of fed masks; pixels no frame owns stay transparent.
  cv::compare(owner, cv::Scalar(0), mask, cv::CMP_LT);
  out_mask->setTo(0, mask);
  out_image->setTo(cv::Scalar::all(0), mask);
  return true;
}

// Canvas bounding box of the seam cells each frame owns (the same ownership BlendRoi computes per tile: canvas-aligned
// kSeamStep cells, farthest border wins), computed in bands of cell rows so that no canvas-sized map is held. A frame
// that owns nothing gets an empty box: it is never decoded.
std::vector<cv::Rect> OwnedCanvasBoxes(const std::vector<FrameGeometry>& geometry, cv::Size canvas) {
  constexpr int kBandCells = 128;
  const cv::Size all_cells((canvas.width + kSeamStep - 1) / kSeamStep, (canvas.height + kSeamStep - 1) / kSeamStep);
  std::vector<cv::Rect> owned(geometry.size());
  cv::Mat map_x;
  cv::Mat map_y;
  cv::Mat dist;
  for (int cy0 = 0; cy0 < all_cells.height; cy0 += kBandCells) {
    const cv::Size cells(all_cells.width, std::min(kBandCells, all_cells.height - cy0));
    const cv::Rect2d band(0, cy0 * kSeamStep, canvas.width, cells.height * kSeamStep);
    cv::Mat best(cells, CV_32F, cv::Scalar(kSeamMargin));
    cv::Mat owner(cells, CV_32S, cv::Scalar(-1));
    for (size_t k = 0; k < geometry.size(); ++k) {
      const cv::Rect2d hit = geometry[k].bbox & band;
      if (hit.area() <= 0) continue;
      // Only the cells under the frame's bounding box.
      const int c0 = std::max(0, static_cast<int>(hit.x) / kSeamStep - 1);
      const int c1 = std::min(cells.width, static_cast<int>(hit.x + hit.width) / kSeamStep + 2);
      if (c1 <= c0) continue;
      ComputeMapsGrid(geometry[k], c0 * kSeamStep, cy0 * kSeamStep, cv::Size(c1 - c0, cells.height), kSeamStep,
                      0.5 * (kSeamStep - 1), &map_x, &map_y);
      BorderDistance(geometry[k], map_x, map_y, &dist);
      for (int r = 0; r < cells.height; ++r) {
        const auto* d = dist.ptr<float>(r);
        auto* b = best.ptr<float>(r) + c0;
        auto* o = owner.ptr<int>(r) + c0;
        for (int c = 0; c < c1 - c0; ++c)
          if (d[c] > b[c]) {
            b[c] = d[c];
            o[c] = static_cast<int>(k);
          }
      }
    }
    for (int r = 0; r < cells.height; ++r) {
      const auto* o = owner.ptr<int>(r);
      for (int c = 0; c < cells.width; ++c)
        if (o[c] >= 0) {
          const cv::Rect cell(c * kSeamStep, (cy0 + r) * kSeamStep, kSeamStep, kSeamStep);
          cv::Rect& box = owned[static_cast<size_t>(o[c])];
          box = box.empty() ? cell : (box | cell);
        }
    }
  }
  return owned;
}

// Frames' needed parts between tiles, in two tiers of bounded bytes: decoded parts (least recently used first out)
// and, behind them, the same parts kept as in-memory JPEG (~1/10 of the bytes), so that a part evicted from the first
// tier comes back from a 3 MP decode of our own copy instead of another 12 MP decode of the stored frame (whose
// entropy decoding alone is most of a load). Thread-safe. Loads run outside the lock so that the other worker keeps
// blending; they are serialised when a load is a whole frame (the compositor's largest transient buffer).
class PartCache {
 public:
  PartCache(const PartLoadFn& load, size_t decoded_bytes, size_t compressed_bytes, bool parallel_loads)
      : load_(load), decoded_(decoded_bytes), compressed_(compressed_bytes), parallel_loads_(parallel_loads) {}

  // At least `need` of frame `id`; an empty image when it cannot be read. The part shares the cache's buffer while
  // the caller holds it, so that another worker's eviction cannot free it.
  // A frame another worker is reading (from its file or from memory) is waited for, not read twice: the workers'
  // consecutive tiles often start on the same frame (caliterra: 32 loads of its 19 composited frames before, 2
  // workers).
  [[nodiscard]] FramePart Get(int id, const cv::Rect& need) {
    std::vector<uchar> jpeg;
    cv::Point2d origin;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      read_done_.wait(lock, [&] { return std::find(reading_.begin(), reading_.end(), id) == reading_.end(); });
      if (const FramePart* hit = decoded_.Find(id)) return *hit;
      if (const CompressedPart* hit = compressed_.Find(id)) {
        ++compressed_hits_;
        jpeg = hit->jpeg;  // copied: an eviction may drop the entry while it is decoded
        origin = hit->origin;
      }
      reading_.push_back(id);
    }
    // Whatever way this leaves (an exception from the read or the insertion too), the frame stops being read and its
    // waiters wake. (An exception still ends the program: ParallelForOnWorkers does not carry one across threads.)
    struct DoneReading {
      PartCache* cache;
      int id;
      ~DoneReading() {
        {
          std::lock_guard<std::mutex> lock(cache->mutex_);
          auto& reading = cache->reading_;
          reading.erase(std::find(reading.begin(), reading.end(), id));
        }
        cache->read_done_.notify_all();
      }
    } done_reading{this, id};
    FramePart part = ReadPart(id, need, jpeg, origin);
    if (!part.image.empty()) {
      std::lock_guard<std::mutex> lock(mutex_);
      const size_t bytes = part.image.total() * part.image.elemSize();
      part = decoded_.Insert(id, std::move(part), bytes);
    }
    return part;
  }
  // Frame `id`'s part from our compressed copy (when `jpeg` holds one), else from its file.
  FramePart ReadPart(int id, const cv::Rect& need, const std::vector<uchar>& jpeg, const cv::Point2d& origin) {
    FramePart part = jpeg.empty() ? FramePart{} : Decompress(jpeg, origin);
    if (!jpeg.empty() && part.image.empty()) {  // our own copy unreadable: dropped, the frame read again
      std::lock_guard<std::mutex> lock(mutex_);
      compressed_.Erase(id);
    }
    if (part.image.empty()) {
      part = Load(id, need);
      // The compressed copy is kept now, while this worker holds the pixels: were the decoded part evicted before a
      // copy was kept, the next tile would read the file again.
      if (!part.image.empty()) Compress(id, part);
    }
    return part;
  }
  // Drops frame `id` from both tiers: no tile left needs it. Without this a long flight's cache filled to its cap with
  // parts of tiles long written (the 5000-frame flight's compose peak 1.4x the 200-frame one's).
  void Release(int id) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (decoded_.Erase(id) | compressed_.Erase(id)) ++released_;
  }
  [[nodiscard]] size_t loads() const { return loads_; }
  [[nodiscard]] double load_ms() const { return load_ms_; }
  [[nodiscard]] size_t reloads_from_memory() const { return compressed_hits_; }
  [[nodiscard]] size_t released() const { return released_; }
  [[nodiscard]] size_t peak_bytes() const { return decoded_.peak() + compressed_.peak(); }

 private:
  struct CompressedPart {
    std::vector<uchar> jpeg;
    cv::Point2d origin;
  };

  // A least-recently-used map of bounded bytes. An entry whose buffer a caller still holds is not evicted (that
  // would free nothing); when every entry is held, the tier may exceed its capacity.
  template <typename Value>
  class Lru {
   public:
    explicit Lru(size_t capacity) : capacity_(capacity) {}
    [[nodiscard]] size_t capacity() const { return capacity_; }
    const Value* Find(int id) {
      auto it = entries_.find(id);
      if (it == entries_.end()) return nullptr;
      order_.splice(order_.begin(), order_, it->second.pos);
      return &it->second.value;
    }
    Value Insert(int id, Value value, size_t bytes) {
      auto it = entries_.find(id);
      if (it != entries_.end()) return it->second.value;
      auto victim = order_.end();
      while (used_ + bytes > capacity_ && victim != order_.begin()) {
        --victim;
        auto e = entries_.find(*victim);
        if (Held(e->second.value)) continue;
        used_ -= e->second.bytes;
        entries_.erase(e);
        victim = order_.erase(victim);
      }
      // The entry first, then its place in the order (undone if that throws): never an id in order_ without an entry.
      auto& entry = entries_[id];
      try {
        order_.push_front(id);
      } catch (...) {
        entries_.erase(id);
        throw;
      }
      entry = Entry{value, bytes, order_.begin()};
      used_ += bytes;
      peak_ = std::max(peak_, used_);
      return value;
    }
    bool Erase(int id) {
      auto it = entries_.find(id);
      if (it == entries_.end()) return false;
      used_ -= it->second.bytes;
      order_.erase(it->second.pos);
      entries_.erase(it);
      return true;
    }
    [[nodiscard]] size_t peak() const { return peak_; }

   private:
    struct Entry {
      Value value;
      size_t bytes = 0;
      std::list<int>::iterator pos;
    };
    static bool Held(const FramePart& p) { return p.image.u != nullptr && p.image.u->refcount > 1; }
    static bool Held(const CompressedPart&) { return false; }
    size_t capacity_;
    size_t used_ = 0;
    size_t peak_ = 0;
    std::list<int> order_;
    std::unordered_map<int, Entry> entries_;
  };

  FramePart Load(int id, const cv::Rect& need) {
    std::unique_lock<std::mutex> serial(load_mutex_, std::defer_lock);
    if (!parallel_loads_) serial.lock();
    const StageTimer timer;
    FramePart part = Trim(load_(id, need), need);
    const double ms = timer.ElapsedMs();
    std::lock_guard<std::mutex> lock(mutex_);
    ++loads_;
    load_ms_ += ms;
    return part;
  }

  // Keeps a JPEG of the part when the second tier is on and the copy is smaller than the pixels. Quality 95: the
  // blend sees differences of about a grey level, far below the exposure differences it blends away.
  void Compress(int id, const FramePart& part) {
    if (compressed_.capacity() == 0) return;
    CompressedPart c{{}, part.origin};
    std::string why;
    if (!EncodeJpegBgr(part.image, 95, &c.jpeg, &why)) {
      spdlog::warn("composite: a part of frame {} not kept in memory ({})", id, why);
      return;
    }
    const size_t bytes = c.jpeg.size();
    if (bytes >= part.image.total() * part.image.elemSize() || bytes > compressed_.capacity()) return;
    std::lock_guard<std::mutex> lock(mutex_);
    compressed_.Insert(id, std::move(c), bytes);
  }

  // Our own copy back; an empty part (the frame's area left empty, as for an unreadable frame) if it cannot be read.
  static FramePart Decompress(const std::vector<uchar>& jpeg, cv::Point2d origin) {
    FramePart part{cv::Mat(), origin};
    std::string why;
    if (!DecodeJpegBgr(jpeg, &part.image, &why))
      spdlog::warn("composite: a part kept in memory is unreadable ({})", why);
    return part;
  }

  // A whole frame (or more than needed at whole-pixel offsets) is cut to `need` before it is cached; the rest is freed.
  static FramePart Trim(FramePart part, const cv::Rect& need) {
    if (part.image.empty() || part.origin.x != std::floor(part.origin.x) || part.origin.y != std::floor(part.origin.y))
      return part;
    const cv::Point tl(static_cast<int>(part.origin.x), static_cast<int>(part.origin.y));
    const cv::Rect rel = (need - tl) & cv::Rect(0, 0, part.image.cols, part.image.rows);
    if (rel.empty() || rel.size() == part.image.size()) return part;
    return FramePart{part.image(rel).clone(), cv::Point2d(rel.x + tl.x, rel.y + tl.y)};
  }

  PartLoadFn load_;
  Lru<FramePart> decoded_;
  Lru<CompressedPart> compressed_;
  bool parallel_loads_;
  std::mutex mutex_;  // both tiers, the frames being read and the counters
  std::condition_variable read_done_;
  std::vector<int> reading_;  // frames a worker is reading: one per worker at most
  std::mutex load_mutex_;     // serial loads
  size_t loads_ = 0;          // counting reloads after eviction
  double load_ms_ = 0.0;      // summed over workers
  size_t compressed_hits_ = 0;
  size_t released_ = 0;
};

// Each frame is needed only over what it owns plus the pyramid's reach: with 75 % / 40 % overlaps a frame owns a
// fifth of its area, so the cache holds ~5x more frames and decodes each about once. Rectangles in each frame's image
// grid; empty = the frame owns nothing.
std::vector<cv::Rect> NeededParts(const std::vector<FrameGeometry>& geometry, cv::Size canvas, int num_bands) {
  const int reach = BlendReach(num_bands) + 2 * kSeamStep;
  const std::vector<cv::Rect> owned = OwnedCanvasBoxes(geometry, canvas);
  std::vector<cv::Rect> need(geometry.size());
  for (size_t i = 0; i < geometry.size(); ++i) {
    if (owned[i].empty()) continue;
    const cv::Rect2d box(owned[i].x - reach, owned[i].y - reach, owned[i].width + 2 * reach,
                         owned[i].height + 2 * reach);
    // Corners suffice: a projective map takes the rectangle to a convex quadrilateral.
    double x0 = 1e300, y0 = 1e300, x1 = -1e300, y1 = -1e300;
    for (const Vec2& c : {Vec2(box.x, box.y), Vec2(box.x + box.width, box.y), Vec2(box.x, box.y + box.height),
                          Vec2(box.x + box.width, box.y + box.height)}) {
      const Vec2 p = Apply(geometry[i].image_from_canvas, c);
      x0 = std::min(x0, p.x());
      y0 = std::min(y0, p.y());
      x1 = std::max(x1, p.x());
      y1 = std::max(y1, p.y());
    }
    const cv::Rect grown(static_cast<int>(std::floor(x0)) - 2, static_cast<int>(std::floor(y0)) - 2,
                         static_cast<int>(std::ceil(x1 - x0)) + 5, static_cast<int>(std::ceil(y1 - y0)) + 5);
    need[i] = grown & cv::Rect(0, 0, geometry[i].size.width, geometry[i].size.height);
    spdlog::debug("composite: frame {} owns {}x{} canvas px; needs {}x{} of {}x{}", i, owned[i].width, owned[i].height,
                  need[i].width, need[i].height, geometry[i].size.width, geometry[i].size.height);
  }
  return need;
}

// Bytes one load of frame `in` holds at once when it reads `need` (empty = the whole image).
size_t LoadBytes(const CompositeInput& in, const cv::Rect& need) {
  const double image = static_cast<double>(in.image_size.area()) * 3;
  const double whole = in.load_bytes > 0 ? static_cast<double>(in.load_bytes) : kWorstLoadPerImageByte * image;
  if (!in.region_loads || need.empty()) return static_cast<size_t>(whole);
  // A region grows to libjpeg's MCU columns and by the resize's margin: kRegionPad image px per side at most.
  const double part = (need.width + 2.0 * kRegionPad) * (need.height + 2.0 * kRegionPad) * 3;
  return static_cast<size_t>(whole * std::min(1.0, part / image));
}

}  // namespace

bool RenderRoi(const std::vector<CompositeInput>& frames, const std::vector<cv::Mat>& images, const cv::Rect& roi,
               int num_bands, cv::Mat* image, cv::Mat* mask) {
  std::vector<FrameGeometry> geometry;
  std::vector<size_t> candidates;
  for (size_t i = 0; i < frames.size(); ++i) {
    geometry.push_back(MakeGeometry(frames[i]));
    if ((geometry.back().bbox & cv::Rect2d(roi)).area() > 0) candidates.push_back(i);
  }
  TileWork work(num_bands);
  cv::Mat blended_image;
  cv::Mat blended_mask;
  if (!BlendRoi(
          geometry, candidates, [&](size_t i, cv::Point2d*) { return images[i]; }, roi, num_bands, &work,
          &blended_image, &blended_mask))
    return false;
  *image = blended_image.clone();  // the views die with `work`
  *mask = blended_mask.clone();
  return true;
}

std::vector<cv::Rect> TilesAlongHilbertCurve(cv::Size canvas, int tile_size) {
  const int cols = (canvas.width + tile_size - 1) / tile_size;
  const int rows = (canvas.height + tile_size - 1) / tile_size;
  std::vector<cv::Rect> tiles;
  tiles.reserve(static_cast<size_t>(cols) * static_cast<size_t>(rows));
  const cv::Rect canvas_rect(0, 0, canvas.width, canvas.height);
  for (const auto& [x, y] : CellsAlongHilbertCurve(cols, rows))
    tiles.push_back(cv::Rect(x * tile_size, y * tile_size, tile_size, tile_size) & canvas_rect);
  return tiles;
}

namespace {

// Frame pixels are the loads in flight and the cache of needed parts. Under a budget they are also
// held to what the budget leaves once the flight's remains (measured, not assumed: they vary with the flight), the TIFF
// writer and the workers are counted; frames too large for that then cost a worker rather than the budget.
CompositorMemory PlanMemory(const std::vector<CompositeInput>& used, const std::vector<cv::Rect>& need,
                            bool parallel_loads, bool with_tiff, double resident_mib,
                            const CompositorOptions& options) {
  size_t largest_part = 0;
  size_t largest_load = 0;
  for (size_t i = 0; i < used.size(); ++i) {
    largest_load = std::max(largest_load, LoadBytes(used[i], need[i]));
    const cv::Size part = need[i].empty() ? used[i].image_size : need[i].size();
    largest_part = std::max(largest_part, static_cast<size_t>(part.area()) * 3);
  }
  const size_t blend_bytes = static_cast<size_t>(options.BlendMiBPerWorker() * kMiB);
  size_t pixel_bytes = options.image_cache_bytes;
  if (options.memory_budget_mib > 0) {
    // What the plan does not itemise: the inputs' records and geometry (a few hundred bytes each), the selection's
    // work, allocator slack. Measured: a 5000-frame flight peaked 3.5 MiB above the itemised figure without it.
    const double unplanned_mib = 6.0 + static_cast<double>(used.size()) * 1024.0 / kMiB;
    const double left = options.memory_budget_mib - resident_mib - (with_tiff ? options.WriterMiB() : 0.0) -
                        options.threads * options.BlendMiBPerWorker() - unplanned_mib;
    pixel_bytes = std::min(pixel_bytes, static_cast<size_t>(std::max(0.0, left) * kMiB));
  }
  // Parallel loads only when they take little from the cache: with large parts a load in flight per worker would
  // evict what the next tiles need and cost more loads than the parallelism saves.
  parallel_loads =
      parallel_loads && largest_load * static_cast<size_t>(std::max(1, options.threads)) * 4 <= pixel_bytes;
  const size_t in_flight = largest_load * static_cast<size_t>(parallel_loads ? std::max(1, options.threads) : 1);
  CompositorMemory memory = FitCompositorMemory(pixel_bytes, in_flight, largest_part, options.threads, blend_bytes);
  memory.parallel_loads = parallel_loads;
  const auto mib = [](size_t bytes) { return static_cast<double>(bytes) / kMiB; };
  spdlog::info("composite: {} worker(s), frame cache {:.0f} MiB, loads {:.0f} MiB{}{}", memory.threads,
               mib(memory.cache_bytes), mib(in_flight), parallel_loads ? " (parts, in parallel)" : "",
               options.memory_budget_mib > 0 ? fmt::format(" ({:.0f} MiB resident at the start)", resident_mib) : "");
  if (!memory.fits)
    spdlog::warn(
        "composite: frames of {:.0f} MiB per load do not fit the memory budget of {} MiB with one worker; "
        "lower mosaic_scale to hold it",
        mib(largest_load), options.memory_budget_mib);
  return memory;
}

// The quick-look, made on disk: tiles arrive in any order (along a Hilbert curve), so their reduced pieces go into a
// raw BGRA file of the quick-look's size, sparse (what no tile wrote reads back as transparent zeros), which Finish
// streams into the PNG row by row. Memory: one row and the PNG compressor, whatever the canvas (held whole, the
// quick-look was 9 MiB of a 5000-frame flight's compose phase against 3 at 200 frames); disk: the raw image (16 MB
// at most at 2000 px) until the PNG is written, then removed. Put is safe from several threads for disjoint pieces.
class QuicklookFile {
 public:
  QuicklookFile() = default;
  QuicklookFile(const QuicklookFile&) = delete;
  QuicklookFile& operator=(const QuicklookFile&) = delete;
  ~QuicklookFile() {
    if (fd_ >= 0) ::close(fd_);
    if (!raw_path_.empty()) std::remove(raw_path_.c_str());
  }

  bool Open(const std::string& png_path, cv::Size size, std::string* error) {
    png_path_ = png_path;
    raw_path_ = png_path + ".raw.tmp";
    size_ = size;
    fd_ = ::open(raw_path_.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd_ < 0 || ::ftruncate(fd_, static_cast<off_t>(RowBytes() * static_cast<size_t>(size.height))) != 0)
      return Fail(raw_path_, error);
    return true;
  }

  bool Put(cv::Point at, const cv::Mat& bgra, std::string* error) {
    for (int y = 0; y < bgra.rows; ++y) {
      const size_t offset = RowBytes() * static_cast<size_t>(at.y + y) + 4 * static_cast<size_t>(at.x);
      if (!Transfer(::pwrite, bgra.ptr(y), static_cast<size_t>(bgra.cols) * 4, offset)) return Fail(raw_path_, error);
    }
    return true;
  }

  // The PNG at png_path (written beside it and renamed: a reader never sees half of one); the raw file removed.
  bool Finish(std::string* error) {
    const std::string tmp = png_path_ + ".tmp";
    PngRowWriter png;
    std::vector<uint8_t> row(RowBytes());
    bool ok = png.Open(tmp, size_.width, size_.height, error);
    for (int y = 0; ok && y < size_.height; ++y) {
      ok = Transfer(::pread, row.data(), row.size(), RowBytes() * static_cast<size_t>(y)) || Fail(raw_path_, error);
      ok = ok && png.WriteRow(row.data(), error);
    }
    std::string finish_error;  // the first failure's reason is the one to keep
    if (!png.Finish(&finish_error) && ok) {
      *error = finish_error;
      ok = false;
    }
    if (ok && std::rename(tmp.c_str(), png_path_.c_str()) != 0) ok = Fail(png_path_, error);
    if (!ok) std::remove(tmp.c_str());
    return ok;
  }

 private:
  [[nodiscard]] size_t RowBytes() const { return static_cast<size_t>(size_.width) * 4; }
  // All `bytes` through pread or pwrite, retried where the call moved fewer or was interrupted; a short count that
  // makes no progress is a full disk (it sets no errno of its own).
  template <typename Call, typename Byte>  // Byte: const uchar for pwrite, uchar for pread
  bool Transfer(Call call, Byte* data, size_t bytes, size_t offset) const {
    while (bytes > 0) {
      const ssize_t n = call(fd_, data, bytes, static_cast<off_t>(offset));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        if (n == 0) errno = ENOSPC;
        return false;
      }
      data += n;
      bytes -= static_cast<size_t>(n);
      offset += static_cast<size_t>(n);
    }
    return true;
  }
  static bool Fail(const std::string& path, std::string* error) {
    *error = "quick-look: " + path + ": " + std::strerror(errno);
    return false;
  }

  int fd_ = -1;
  std::string png_path_;
  std::string raw_path_;
  cv::Size size_;
};

// Where finished tiles go: the TIFF (may be null) and the quick-look (none without a path). Thread-safe; the first
// write error stops it.
class TileSink {
 public:
  TileSink(cv::Size canvas, int quicklook_long_side, GdalTiffWriter* tiff) : tiff_(tiff) {
    q_ = std::min(1.0, quicklook_long_side / static_cast<double>(std::max(canvas.width, canvas.height)));
    quicklook_size_ = cv::Size(std::max(1, static_cast<int>(std::lround(canvas.width * q_))),
                               std::max(1, static_cast<int>(std::lround(canvas.height * q_))));
  }
  [[nodiscard]] bool OpenQuicklook(const std::string& path) {
    if (path.empty()) return true;
    quicklook_ = std::make_unique<QuicklookFile>();
    if (quicklook_->Open(path, quicklook_size_, &error_)) return true;
    failed_ = true;
    return false;
  }
  [[nodiscard]] bool failed() const { return failed_; }

  void Put(const cv::Rect& tile, const cv::Mat& image, const cv::Mat& mask) {
    // Quick-look share of this tile, made outside the lock.
    const int x0 = static_cast<int>(std::lround(tile.x * q_));
    const int y0 = static_cast<int>(std::lround(tile.y * q_));
    const int x1 = std::min(quicklook_size_.width, static_cast<int>(std::lround((tile.x + tile.width) * q_)));
    const int y1 = std::min(quicklook_size_.height, static_cast<int>(std::lround((tile.y + tile.height) * q_)));
    cv::Mat small;
    if (quicklook_ && x1 > x0 && y1 > y0) {
      cv::Mat bgra;
      cv::cvtColor(image, bgra, cv::COLOR_BGR2BGRA);
      cv::insertChannel(mask, bgra, 3);
      cv::resize(bgra, small, cv::Size(x1 - x0, y1 - y0), 0, 0, cv::INTER_AREA);
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (failed_) return;
    std::string err;
    if ((tiff_ != nullptr && !tiff_->Write(image, mask, tile.tl(), &err)) ||
        (!small.empty() && !quicklook_->Put({x0, y0}, small, &err))) {
      error_ = err;
      failed_ = true;
      return;
    }
    ++tiles_written_;
  }
  void Finish(CompositeResult* result) {
    result->tiles_written = tiles_written_;
    if (!failed_ && quicklook_ && !quicklook_->Finish(&error_)) failed_ = true;
    result->error = error_;
    result->quicklook_size = quicklook_size_;
    quicklook_.reset();
  }

 private:
  GdalTiffWriter* tiff_;
  double q_ = 1.0;
  cv::Size quicklook_size_;
  std::unique_ptr<QuicklookFile> quicklook_;  // null: no quick-look asked for
  std::mutex mutex_;
  std::atomic<bool> failed_{false};
  std::string error_;
  int tiles_written_ = 0;
};

// Each tile's frames, and per frame the tiles still to make that need it: when the last is made the frame's part
// leaves the cache, so the cache holds the frames about the tiles in progress, not every frame it has met (a long
// flight's cache otherwise filled to its cap with parts of tiles long written).
struct TileFrames {
  template <typename RoiOf>
  TileFrames(const std::vector<cv::Rect>& tiles, const std::vector<FrameGeometry>& geometry, const RoiOf& roi_of)
      : candidates(tiles.size()), tiles_left(geometry.size()) {
    for (size_t t = 0; t < tiles.size(); ++t) {
      const cv::Rect2d roi(roi_of(tiles[t]));
      for (size_t i = 0; i < geometry.size(); ++i)
        if ((geometry[i].bbox & roi).area() > 0) {
          candidates[t].push_back(i);
          tiles_left[i].fetch_add(1, std::memory_order_relaxed);
        }
    }
  }
  // A tile that needed frame i is made; true when it was the last.
  bool Done(size_t i) { return tiles_left[i].fetch_sub(1, std::memory_order_acq_rel) == 1; }

  std::vector<std::vector<size_t>> candidates;  // per tile, frames (indices into the used frames) in ascending order
  std::vector<std::atomic<int>> tiles_left;     // per frame
};

// Frame selection on footprints: `frames` keeps, in order, those SelectByOverlap keeps. In place, and the footprints
// gone before the tiles start: every per-frame list of a long flight is held once.
void KeepByOverlap(cv::Size canvas, double max_covered_fraction, std::vector<CompositeInput>* frames,
                   CompositeResult* result) {
  std::vector<std::vector<cv::Point2f>> footprints;
  footprints.reserve(frames->size());
  for (const auto& f : *frames)
    footprints.push_back(Footprint(f.canvas_from_image, f.image_size.width, f.image_size.height));
  const std::vector<bool> keep =
      SelectByOverlap(footprints, cv::Rect2d(0, 0, canvas.width, canvas.height), max_covered_fraction);
  size_t kept = 0;
  for (size_t i = 0; i < frames->size(); ++i) {
    if (keep[i])
      (*frames)[kept++] = (*frames)[i];
    else
      ++result->frames_dropped_by_overlap;
  }
  frames->resize(kept);
  frames->shrink_to_fit();  // the dropped frames' inputs (128 bytes each) are not carried through the tiles
  result->frames_used = static_cast<int>(kept);
}

// One TileWork per worker, reserved. Under a budget the workers' buffers are the plan's line (BlendMiBPerWorker),
// resident from the phase's start: a tile's ROI with its margins, whatever the canvas. Grown as pieces came, they were
// what the flight's canvas and largest pieces happened to need: a short flight narrower than one tile composed in less
// (~9 MiB less of them at 200 frames than at 5000), so the phase grew with the flight. Without a budget, the largest
// ROI of this canvas.
template <typename RoiOf>
std::vector<TileWork> MakeTileWorks(const CompositorOptions& options, int threads, const std::vector<cv::Rect>& tiles,
                                    const RoiOf& roi_of) {
  cv::Size largest_roi(options.tile_size + 2 * options.Margin(), options.tile_size + 2 * options.Margin());
  if (options.memory_budget_mib <= 0) {
    largest_roi = cv::Size();
    for (const cv::Rect& tile : tiles) {
      const cv::Size roi = roi_of(tile).size();
      largest_roi = cv::Size(std::max(largest_roi.width, roi.width), std::max(largest_roi.height, roi.height));
    }
  }
  std::vector<TileWork> works;
  works.reserve(static_cast<size_t>(threads));
  for (int w = 0; w < threads; ++w) works.emplace_back(options.num_bands);
  // Each worker's buffers made resident on a thread of their own: ~55 ms a worker at 704x704 (brighton_beach), which
  // held back the first tile.
  ParallelFor(works.size(), threads, [&](size_t w) { works[w].Reserve(largest_roi); });
  return works;
}

}  // namespace

CompositeResult Composite(std::vector<CompositeInput> frames, cv::Size canvas, const ImageLoadFn& load,
                          const CompositorOptions& options, GdalTiffWriter* tiff) {
  return Composite(
      std::move(frames), canvas,
      [&](int id, const cv::Rect&) {
        return FramePart{load(id), cv::Point2d()};
      },
      options, tiff);
}

CompositeResult Composite(std::vector<CompositeInput> frames, cv::Size canvas, const PartLoadFn& load,
                          const CompositorOptions& options, GdalTiffWriter* tiff) {
  CompositeResult result;
  StageTimer timer;
  // What the flight left, before the compositor allocates anything.
  const double resident_mib = options.memory_budget_mib > 0 ? CurrentRssMiB() : 0.0;
  result.canvas = canvas;
  std::vector<CompositeInput> used = std::move(frames);
  KeepByOverlap(canvas, options.max_covered_fraction, &used, &result);
  std::vector<FrameGeometry> geometry;
  geometry.reserve(used.size());
  for (const auto& f : used) geometry.push_back(MakeGeometry(f));
  const std::vector<cv::Rect> need = NeededParts(geometry, canvas, options.num_bands);
  TileSink sink(canvas, options.quicklook_long_side, tiff);
  if (!sink.OpenQuicklook(options.quicklook_path)) {
    sink.Finish(&result);
    return result;
  }
  // Parts may be loaded in parallel (see PlanMemory); a whole-frame load, the largest transient buffer, one at a time.
  const bool parallel_loads =
      !used.empty() && std::all_of(used.begin(), used.end(), [](const CompositeInput& in) { return in.region_loads; });
  const CompositorMemory memory = PlanMemory(used, need, parallel_loads, tiff != nullptr, resident_mib, options);
  // The decoded tier keeps at least one part per worker and at most decoded_cache_mib more; the second tier a share
  // of the rest.
  const size_t floor = static_cast<size_t>(memory.threads) * memory.largest_part;
  const double rest = static_cast<double>(memory.cache_bytes > floor ? memory.cache_bytes - floor : 0);
  const auto compressed = static_cast<size_t>(options.compressed_share * rest);
  const auto decoded =
      floor + static_cast<size_t>(std::min((1.0 - options.compressed_share) * rest, options.decoded_cache_mib * kMiB));
  PartCache cache(load, decoded, compressed, memory.parallel_loads);
  std::mutex report_mutex;
  std::vector<bool> reported_unreadable(used.size(), false);
  auto image_of = [&](size_t i, cv::Point2d* origin) -> cv::Mat {
    const cv::Rect whole(cv::Point(), geometry[i].size);
    FramePart part = cache.Get(used[i].id, need[i].empty() ? whole : need[i]);
    *origin = part.origin;
    if (part.image.empty()) {
      std::lock_guard<std::mutex> lock(report_mutex);
      if (!reported_unreadable[i]) {
        reported_unreadable[i] = true;
        ++result.frames_unreadable;
        spdlog::warn("composite: frame {} could not be loaded; its area stays empty", used[i].id);
      }
    }
    return part.image;
  };
  const int margin = options.Margin();
  const cv::Rect canvas_rect(0, 0, canvas.width, canvas.height);
  // Tiles are independent; workers take them along a Hilbert curve, claimed in increasing order. Consecutive tiles
  // are neighbours, so a frame loaded for one tile serves the next few from a small cache (row-major order went across
  // the whole canvas and decoded each 12 MP frame ~9 times), and every aligned 2^k x 2^k block of tiles is visited in
  // one run, so each TIFF overview block (2^k tiles wide) is completed soon after it is started and GDAL's small block
  // cache never writes one twice. Writing is serialised; warping and blending, the bulk of the work, run in parallel.
  const std::vector<cv::Rect> tiles = TilesAlongHilbertCurve(canvas, options.tile_size);
  const auto roi_of = [&](const cv::Rect& tile) {
    return cv::Rect(tile.x - margin, tile.y - margin, tile.width + 2 * margin, tile.height + 2 * margin) & canvas_rect;
  };
  TileFrames frames_of(tiles, geometry, roi_of);
  std::vector<TileWork> works = MakeTileWorks(options, memory.threads, tiles, roi_of);
  ParallelForOnWorkers(tiles.size(), memory.threads, [&](size_t t, size_t worker) {
    if (sink.failed()) return;
    const cv::Rect tile = tiles[t];
    const cv::Rect roi = roi_of(tile);
    const std::vector<size_t>& candidates = frames_of.candidates[t];
    cv::Mat image;
    cv::Mat mask;
    if (!candidates.empty() &&
        BlendRoi(geometry, candidates, image_of, roi, options.num_bands, &works[worker], &image, &mask)) {
      const cv::Rect inner(tile.x - roi.x, tile.y - roi.y, tile.width, tile.height);
      if (cv::countNonZero(mask(inner)) > 0) sink.Put(tile, image(inner), mask(inner));
    }
    for (size_t i : candidates)
      if (frames_of.Done(i)) cache.Release(used[i].id);
    // The workers' own buffers stay; what goes back is what OpenCV allocates inside its calls, the quick-look's
    // piece of the tile and the parts the cache released. Only near the budget: pages given back after every tile
    // were faulted in again by the next (brighton_beach: compose 3.9 -> 3.4 s, its peak 222 -> 232 MiB of 256).
    if (options.memory_budget_mib > 0 && CurrentRssMiB() > kTrimAboveBudgetShare * options.memory_budget_mib)
      TrimHeap();
  });
  sink.Finish(&result);
  if (!result.error.empty()) return result;
  result.image_loads = static_cast<int>(cache.loads());
  result.reloads_from_memory = static_cast<int>(cache.reloads_from_memory());
  result.parts_released = static_cast<int>(cache.released());
  result.cache_peak_bytes = cache.peak_bytes();
  result.load_ms = cache.load_ms();
  result.ms = timer.ElapsedMs();
  result.ok = true;
  return result;
}

}  // namespace uavm
