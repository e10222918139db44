#include "core/mosaic/compositor.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <list>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <thread>
#include <unordered_map>

#include "core/mosaic/gdal_writer.h"
#include "core/mosaic/selection.h"
#include "core/mosaic/tile_blender.h"
#include "core/util/clock.h"

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
  if (!(max_covered_fraction > 0.0 && max_covered_fraction <= 1.0))
    return fail("mosaic.max_covered_fraction must be in (0,1]");
  if (quicklook_long_side < 16) return fail("mosaic.quicklook_long_side must be >= 16");
  return true;
}

namespace {

// Inverse map of one frame evaluated over an ROI of the canvas, and its distance-to-border in canvas pixels.
struct FrameGeometry {
  Mat3 image_from_canvas;
  cv::Size size;
  double canvas_px_per_image_px = 1.0;
  cv::Rect2d bbox;  // footprint bounding box in the canvas
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
  return g;
}

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

// Distance to the nearest image border in canvas pixels; negative outside the image.
void BorderDistance(const FrameGeometry& g, const cv::Mat& map_x, const cv::Mat& map_y, cv::Mat* dist) {
  dist->create(map_x.size(), CV_32F);
  const float w1 = static_cast<float>(g.size.width - 1);
  const float h1 = static_cast<float>(g.size.height - 1);
  const float s = static_cast<float>(g.canvas_px_per_image_px);
  for (int r = 0; r < map_x.rows; ++r) {
    const auto* mx = map_x.ptr<float>(r);
    const auto* my = map_y.ptr<float>(r);
    auto* d = dist->ptr<float>(r);
    for (int c = 0; c < map_x.cols; ++c) {
      d[c] = s * std::min(std::min(mx[c], w1 - mx[c]), std::min(my[c], h1 - my[c]));
    }
  }
}

// Blends one ROI from the frames listed in `candidates` (indices into geometry / images).
bool BlendRoi(const std::vector<FrameGeometry>& geometry, const std::vector<size_t>& candidates,
              const std::function<const cv::Mat*(size_t)>& image_of, const cv::Rect& roi, int num_bands,
              cv::Mat* out_image, cv::Mat* out_mask) {
  // Seams from distance-to-border are smooth, so ownership is decided on a grid of kSeamStep x kSeamStep cells
  // aligned to the canvas (identical in every tile), then spread to the cells' pixels. A cell is owned only when its
  // centre lies kSeamMargin px inside the owner, so that every pixel of the cell is inside it too.
  constexpr int kSeamStep = 4;
  constexpr float kSeamMargin = 3.0f;  // > half the cell diagonal (2.1 px)
  const int cx0 = roi.x / kSeamStep;
  const int cy0 = roi.y / kSeamStep;
  const cv::Size cells((roi.x + roi.width + kSeamStep - 1) / kSeamStep - cx0,
                       (roi.y + roi.height + kSeamStep - 1) / kSeamStep - cy0);
  cv::Mat best_dist(cells, CV_32F, cv::Scalar(kSeamMargin));
  cv::Mat cell_owner(cells, CV_16S, cv::Scalar(-1));
  cv::Mat map_x;
  cv::Mat map_y;
  cv::Mat dist;
  for (size_t k = 0; k < candidates.size(); ++k) {
    ComputeMapsGrid(geometry[candidates[k]], cx0 * kSeamStep, cy0 * kSeamStep, cells, kSeamStep, 0.5 * (kSeamStep - 1),
                    &map_x, &map_y);
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
  cv::Mat owner(roi.size(), CV_16S);
  for (int r = 0; r < roi.height; ++r) {
    const auto* o = cell_owner.ptr<int16_t>((roi.y + r) / kSeamStep - cy0);
    auto* dst = owner.ptr<int16_t>(r);
    for (int c = 0; c < roi.width; ++c) dst[c] = o[(roi.x + c) / kSeamStep - cx0];
  }
  auto blender = num_bands > 0 ? MakeMultiBandBlender(num_bands) : MakeSeamOnlyBlender();
  blender->Prepare(roi);
  bool fed = false;
  cv::Mat warped;
  cv::Mat mask;
  for (size_t k = 0; k < candidates.size(); ++k) {
    cv::compare(owner, cv::Scalar(static_cast<double>(k)), mask, cv::CMP_EQ);
    if (cv::countNonZero(mask) == 0) continue;
    const cv::Mat* img = image_of(candidates[k]);
    if (img == nullptr || img->empty()) continue;
    // Only the owned area plus the pyramid's reach is warped and fed: each pixel is blended about once, not once
    // per overlapping frame.
    const int reach = num_bands > 0 ? (3 << num_bands) : 0;
    cv::Rect owned = cv::boundingRect(mask);
    owned = cv::Rect(owned.x - reach, owned.y - reach, owned.width + 2 * reach, owned.height + 2 * reach) &
            cv::Rect(0, 0, roi.width, roi.height);
    const cv::Rect sub(roi.x + owned.x, roi.y + owned.y, owned.width, owned.height);
    ComputeMaps(geometry[candidates[k]], sub, &map_x, &map_y);
    // Reflect beyond the frame edge: the pyramid then sees image texture, not black, next to the seam.
    cv::remap(*img, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REFLECT);
    blender->Feed(warped, mask(owned), sub.tl());
    fed = true;
  }
  if (!fed) return false;
  blender->Blend(out_image, out_mask);
  // The blender's mask is the union of fed masks; pixels no frame owns stay transparent.
  cv::Mat covered;
  cv::compare(owner, cv::Scalar(0), covered, cv::CMP_GE);
  out_mask->setTo(0, ~covered);
  out_image->setTo(cv::Scalar::all(0), ~covered);
  return true;
}

// Bounded LRU of decoded frames between tiles.
class ImageCache {
 public:
  ImageCache(const ImageLoadFn& load, size_t capacity) : load_(load), capacity_(capacity) {}
  // Both calls under the caller's lock; the decode itself happens outside it (see Composite).
  [[nodiscard]] cv::Mat Peek(int id) {
    auto it = entries_.find(id);
    if (it == entries_.end()) return {};
    lru_.splice(lru_.begin(), lru_, it->second.pos);
    return it->second.image;  // shares the buffer: an eviction cannot free it under a user
  }
  cv::Mat Insert(int id, cv::Mat img) {
    ++loads_;
    auto it = entries_.find(id);
    if (it != entries_.end()) return it->second.image;  // another worker decoded it meanwhile
    const size_t bytes = img.total() * img.elemSize();
    while (!lru_.empty() && used_ + bytes > capacity_) {
      auto victim = entries_.find(lru_.back());
      used_ -= victim->second.bytes;
      entries_.erase(victim);
      lru_.pop_back();
    }
    lru_.push_front(id);
    auto& e = entries_[id];
    e.image = img;
    e.bytes = bytes;
    e.pos = lru_.begin();
    used_ += bytes;
    return img;
  }
  [[nodiscard]] const ImageLoadFn& loader() const { return load_; }

 private:
  struct Entry {
    cv::Mat image;
    size_t bytes = 0;
    std::list<int>::iterator pos;
  };
  ImageLoadFn load_;
  size_t capacity_;
  size_t loads_ = 0;

 public:
  [[nodiscard]] size_t loads() const { return loads_; }

 private:
  size_t used_ = 0;
  std::list<int> lru_;
  std::unordered_map<int, Entry> entries_;
};

}  // namespace

bool RenderRoi(const std::vector<CompositeInput>& frames, const std::vector<cv::Mat>& images, const cv::Rect& roi,
               int num_bands, cv::Mat* image, cv::Mat* mask) {
  std::vector<FrameGeometry> geometry;
  std::vector<size_t> candidates;
  for (size_t i = 0; i < frames.size(); ++i) {
    geometry.push_back(MakeGeometry(frames[i]));
    if ((geometry.back().bbox & cv::Rect2d(roi)).area() > 0) candidates.push_back(i);
  }
  return BlendRoi(
      geometry, candidates, [&](size_t i) { return &images[i]; }, roi, num_bands, image, mask);
}

CompositeResult Composite(const std::vector<CompositeInput>& frames, cv::Size canvas, const ImageLoadFn& load,
                          const CompositorOptions& options, GdalTiffWriter* tiff) {
  CompositeResult result;
  StageTimer timer;
  result.canvas = canvas;
  // Frame selection on footprints.
  std::vector<std::vector<cv::Point2f>> footprints;
  for (const auto& f : frames)
    footprints.push_back(Footprint(f.canvas_from_image, f.image_size.width, f.image_size.height));
  const std::vector<bool> keep =
      SelectByOverlap(footprints, cv::Rect2d(0, 0, canvas.width, canvas.height), options.max_covered_fraction);
  std::vector<CompositeInput> used;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (keep[i])
      used.push_back(frames[i]);
    else
      ++result.frames_dropped_by_overlap;
  }
  result.frames_used = static_cast<int>(used.size());
  std::vector<FrameGeometry> geometry;
  for (const auto& f : used) geometry.push_back(MakeGeometry(f));

  const double q =
      std::min(1.0, options.quicklook_long_side / static_cast<double>(std::max(canvas.width, canvas.height)));
  result.quicklook = cv::Mat(std::max(1, static_cast<int>(std::lround(canvas.height * q))),
                             std::max(1, static_cast<int>(std::lround(canvas.width * q))), CV_8UC4, cv::Scalar::all(0));
  ImageCache cache(load, options.image_cache_bytes);
  std::vector<bool> reported_unreadable(used.size(), false);
  const int margin = options.Margin();
  const cv::Rect canvas_rect(0, 0, canvas.width, canvas.height);
  std::vector<cv::Rect> tiles;
  for (int ty = 0; ty < canvas.height; ty += options.tile_size)
    for (int tx = 0; tx < canvas.width; tx += options.tile_size)
      tiles.push_back(cv::Rect(tx, ty, options.tile_size, options.tile_size) & canvas_rect);
  // Tiles are independent: workers take them in row-major order (which keeps the frame cache warm). Decoding and
  // writing are serialised; warping and blending, the bulk of the work, run in parallel.
  std::mutex cache_mutex;
  std::mutex out_mutex;
  std::atomic<size_t> next_tile{0};
  std::string write_error;
  auto worker = [&] {
    for (;;) {
      const size_t t = next_tile.fetch_add(1);
      if (t >= tiles.size()) return;
      const cv::Rect tile = tiles[t];
      const cv::Rect roi =
          cv::Rect(tile.x - margin, tile.y - margin, tile.width + 2 * margin, tile.height + 2 * margin) & canvas_rect;
      std::vector<size_t> candidates;
      for (size_t i = 0; i < geometry.size(); ++i)
        if ((geometry[i].bbox & cv::Rect2d(roi)).area() > 0) candidates.push_back(i);
      if (candidates.empty()) continue;
      // Images used by this tile are pinned (shared) so that another worker's eviction cannot free them.
      std::vector<cv::Mat> pinned(candidates.size());
      auto image_of = [&](size_t i) -> const cv::Mat* {
        const size_t k = static_cast<size_t>(std::find(candidates.begin(), candidates.end(), i) - candidates.begin());
        if (pinned[k].empty()) {
          {
            std::lock_guard<std::mutex> lock(cache_mutex);
            pinned[k] = cache.Peek(used[i].id);
          }
          if (pinned[k].empty()) {
            cv::Mat img = cache.loader()(used[i].id);  // decode outside the lock: the workers decode in parallel
            std::lock_guard<std::mutex> lock(cache_mutex);
            if (img.empty()) {
              if (!reported_unreadable[i]) {
                reported_unreadable[i] = true;
                ++result.frames_unreadable;
                spdlog::warn("composite: frame {} could not be loaded; its area stays empty", used[i].id);
              }
            } else {
              pinned[k] = cache.Insert(used[i].id, std::move(img));
            }
          }
        }
        return pinned[k].empty() ? nullptr : &pinned[k];
      };
      cv::Mat image;
      cv::Mat mask;
      if (!BlendRoi(geometry, candidates, image_of, roi, options.num_bands, &image, &mask)) continue;
      const cv::Rect inner(tile.x - roi.x, tile.y - roi.y, tile.width, tile.height);
      const cv::Mat tile_image = image(inner);
      const cv::Mat tile_mask = mask(inner);
      if (cv::countNonZero(tile_mask) == 0) continue;
      // Quick-look share of this tile.
      const int x0 = static_cast<int>(std::lround(tile.x * q));
      const int y0 = static_cast<int>(std::lround(tile.y * q));
      const int x1 = std::min(result.quicklook.cols, static_cast<int>(std::lround((tile.x + tile.width) * q)));
      const int y1 = std::min(result.quicklook.rows, static_cast<int>(std::lround((tile.y + tile.height) * q)));
      cv::Mat small;
      if (x1 > x0 && y1 > y0) {
        cv::Mat bgra;
        cv::cvtColor(tile_image, bgra, cv::COLOR_BGR2BGRA);
        cv::insertChannel(tile_mask, bgra, 3);
        cv::resize(bgra, small, cv::Size(x1 - x0, y1 - y0), 0, 0, cv::INTER_AREA);
      }
      std::lock_guard<std::mutex> lock(out_mutex);
      if (!write_error.empty()) return;
      if (tiff != nullptr) {
        std::string err;
        if (!tiff->Write(tile_image, tile_mask, tile.tl(), &err)) {
          write_error = err;
          return;
        }
      }
      ++result.tiles_written;
      if (!small.empty()) small.copyTo(result.quicklook(cv::Rect(x0, y0, x1 - x0, y1 - y0)));
    }
  };
  const int threads = std::max(1, std::min<int>(options.threads, static_cast<int>(tiles.size())));
  std::vector<std::thread> pool;
  for (int k = 1; k < threads; ++k) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
  if (!write_error.empty()) {
    result.error = write_error;
    return result;
  }
  result.image_loads = static_cast<int>(cache.loads());
  result.ms = timer.ElapsedMs();
  result.ok = true;
  return result;
}

}  // namespace uavm
