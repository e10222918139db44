#include "core/mosaic/compositor.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <list>
#include <opencv2/imgproc.hpp>
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
  if (tile_size < tiff_block || tile_size % tiff_block != 0) return fail("mosaic.tile_size must be a multiple of tiff_block");
  if (num_bands < 0 || num_bands > 10) return fail("mosaic.num_bands must be in [0,10]");
  if (!(max_covered_fraction > 0.0 && max_covered_fraction <= 1.0)) return fail("mosaic.max_covered_fraction must be in (0,1]");
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

// Fills image coordinates (map_x, map_y) for every canvas pixel of `roi`.
void ComputeMaps(const FrameGeometry& g, const cv::Rect& roi, cv::Mat* map_x, cv::Mat* map_y) {
  map_x->create(roi.size(), CV_32F);
  map_y->create(roi.size(), CV_32F);
  const Mat3& H = g.image_from_canvas;
  const bool affine = IsAffine(H, 1e-15);
  for (int r = 0; r < roi.height; ++r) {
    auto* mx = map_x->ptr<float>(r);
    auto* my = map_y->ptr<float>(r);
    const double v = roi.y + r;
    const double bx = H(0, 1) * v + H(0, 2);
    const double by = H(1, 1) * v + H(1, 2);
    const double bw = H(2, 1) * v + H(2, 2);
    for (int c = 0; c < roi.width; ++c) {
      const double u = roi.x + c;
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
  cv::Mat best_dist(roi.size(), CV_32F, cv::Scalar(-1.0f));
  cv::Mat owner(roi.size(), CV_16S, cv::Scalar(-1));
  cv::Mat map_x;
  cv::Mat map_y;
  cv::Mat dist;
  for (size_t k = 0; k < candidates.size(); ++k) {
    ComputeMaps(geometry[candidates[k]], roi, &map_x, &map_y);
    BorderDistance(geometry[candidates[k]], map_x, map_y, &dist);
    for (int r = 0; r < roi.height; ++r) {
      const auto* d = dist.ptr<float>(r);
      auto* b = best_dist.ptr<float>(r);
      auto* o = owner.ptr<int16_t>(r);
      for (int c = 0; c < roi.width; ++c) {
        if (d[c] >= 0.0f && d[c] > b[c]) {
          b[c] = d[c];
          o[c] = static_cast<int16_t>(k);
        }
      }
    }
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
  const cv::Mat* Get(int id, bool* unreadable) {
    auto it = entries_.find(id);
    if (it != entries_.end()) {
      lru_.splice(lru_.begin(), lru_, it->second.pos);
      return &it->second.image;
    }
    cv::Mat img = load_(id);
    if (img.empty()) {
      *unreadable = true;
      return nullptr;
    }
    const size_t bytes = img.total() * img.elemSize();
    while (!lru_.empty() && used_ + bytes > capacity_) {
      auto victim = entries_.find(lru_.back());
      used_ -= victim->second.bytes;
      entries_.erase(victim);
      lru_.pop_back();
    }
    lru_.push_front(id);
    auto& e = entries_[id];
    e.image = std::move(img);
    e.bytes = bytes;
    e.pos = lru_.begin();
    used_ += bytes;
    return &e.image;
  }

 private:
  struct Entry {
    cv::Mat image;
    size_t bytes = 0;
    std::list<int>::iterator pos;
  };
  ImageLoadFn load_;
  size_t capacity_;
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
  return BlendRoi(geometry, candidates, [&](size_t i) { return &images[i]; }, roi, num_bands, image, mask);
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
    if (keep[i]) used.push_back(frames[i]);
    else ++result.frames_dropped_by_overlap;
  }
  result.frames_used = static_cast<int>(used.size());
  std::vector<FrameGeometry> geometry;
  for (const auto& f : used) geometry.push_back(MakeGeometry(f));

  const double q = std::min(1.0, options.quicklook_long_side / static_cast<double>(std::max(canvas.width, canvas.height)));
  result.quicklook = cv::Mat(std::max(1, static_cast<int>(std::lround(canvas.height * q))),
                             std::max(1, static_cast<int>(std::lround(canvas.width * q))), CV_8UC4, cv::Scalar::all(0));
  ImageCache cache(load, options.image_cache_bytes);
  std::vector<bool> reported_unreadable(used.size(), false);
  const int margin = options.Margin();
  const cv::Rect canvas_rect(0, 0, canvas.width, canvas.height);
  for (int ty = 0; ty < canvas.height; ty += options.tile_size) {
    for (int tx = 0; tx < canvas.width; tx += options.tile_size) {
      const cv::Rect tile = cv::Rect(tx, ty, options.tile_size, options.tile_size) & canvas_rect;
      const cv::Rect roi = cv::Rect(tile.x - margin, tile.y - margin, tile.width + 2 * margin,
                                    tile.height + 2 * margin) & canvas_rect;
      std::vector<size_t> candidates;
      for (size_t i = 0; i < geometry.size(); ++i)
        if ((geometry[i].bbox & cv::Rect2d(roi)).area() > 0) candidates.push_back(i);
      if (candidates.empty()) continue;
      cv::Mat image;
      cv::Mat mask;
      auto image_of = [&](size_t i) -> const cv::Mat* {
        bool unreadable = false;
        const cv::Mat* img = cache.Get(used[i].id, &unreadable);
        if (unreadable && !reported_unreadable[i]) {
          reported_unreadable[i] = true;
          ++result.frames_unreadable;
          spdlog::warn("composite: frame {} could not be loaded; its area stays empty", used[i].id);
        }
        return img;
      };
      if (!BlendRoi(geometry, candidates, image_of, roi, options.num_bands, &image, &mask)) continue;
      const cv::Rect inner(tile.x - roi.x, tile.y - roi.y, tile.width, tile.height);
      const cv::Mat tile_image = image(inner);
      const cv::Mat tile_mask = mask(inner);
      if (cv::countNonZero(tile_mask) == 0) continue;
      if (tiff != nullptr) {
        std::string err;
        if (!tiff->Write(tile_image, tile_mask, tile.tl(), &err)) {
          result.error = err;
          return result;
        }
      }
      ++result.tiles_written;
      // Quick-look: this tile's share, resized into place.
      const int x0 = static_cast<int>(std::lround(tile.x * q));
      const int y0 = static_cast<int>(std::lround(tile.y * q));
      const int x1 = std::min(result.quicklook.cols, static_cast<int>(std::lround((tile.x + tile.width) * q)));
      const int y1 = std::min(result.quicklook.rows, static_cast<int>(std::lround((tile.y + tile.height) * q)));
      if (x1 > x0 && y1 > y0) {
        cv::Mat bgra;
        cv::cvtColor(tile_image, bgra, cv::COLOR_BGR2BGRA);
        std::vector<cv::Mat> ch;
        cv::split(bgra, ch);
        ch[3] = tile_mask;
        cv::merge(ch, bgra);
        cv::Mat small;
        cv::resize(bgra, small, cv::Size(x1 - x0, y1 - y0), 0, 0, cv::INTER_AREA);
        small.copyTo(result.quicklook(cv::Rect(x0, y0, x1 - x0, y1 - y0)));
      }
    }
  }
  result.ms = timer.ElapsedMs();
  result.ok = true;
  return result;
}

}  // namespace uavm
