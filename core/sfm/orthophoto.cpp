#include "core/sfm/orthophoto.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <list>
#include <memory>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <set>
#include <unordered_map>
#include <vector>

#include "core/mosaic/compositor.h"
#include "core/mosaic/tile_blender.h"
#include "core/util/memory.h"
#include "core/util/parallel.h"

namespace uavm::sfm {

bool OrthoOptions::Check(std::string* why) const {
  const auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (gsd < 0.0) return fail("ortho gsd must be >= 0 (0 = the flight's)");
  if (tile_size < 64) return fail("ortho tile_size must be >= 64");
  if (num_bands < 0 || num_bands > 8) return fail("ortho num_bands must be in [0, 8]");
  if (seam_cell < 1 || seam_cell > 16) return fail("ortho seam_cell must be in [1, 16]");
  if (zbuffer_mib <= 0.0 || image_cache_mib <= 0.0) return fail("ortho memory caps must be > 0");
  if (occlusion_tolerance_cells <= 0.0) return fail("ortho occlusion tolerance must be > 0");
  if (threads < 1) return fail("ortho threads must be >= 1");
  if (!(object_height >= 0.0)) return fail("ortho object_height must be >= 0 (0 = seams anywhere)");
  return true;
}

nlohmann::json OrthoReport::ToJson() const {
  return {{"size", {grid.width, grid.height}},
          {"gsd", grid.cell},
          {"tiles", tiles},
          {"tiles_written", tiles_written},
          {"images_in_view", images_in_view},
          {"images_used", images_used},
          {"images_unreadable", images_unreadable},
          {"pixels_covered", pixels_covered},
          {"seam_cells_taken_from_another_view", cells_taken_from_another_view},
          {"seam_cells_occluded_in_every_view", cells_occluded_everywhere},
          {"standing_objects", objects},
          {"standing_objects_taken_whole", objects_taken_whole},
          {"seam_cells", seam_cells},
          {"seam_cells_on_standing_objects", seam_cells_on_objects},
          {"image_loads", image_loads},
          {"zbuffer_scale", zbuffer_scale},
          {"zbuffer_mib", zbuffer_mib},
          {"seconds", seconds}};
}

DsmGrid OrthoGridOver(const DsmGrid& dsm_grid, double gsd) {
  DsmGrid g;
  g.x0 = dsm_grid.x0;
  g.y0 = dsm_grid.y0;
  g.cell = gsd;
  g.width = std::max(1, static_cast<int>(std::ceil(dsm_grid.width * dsm_grid.cell / gsd)));
  g.height = std::max(1, static_cast<int>(std::ceil(dsm_grid.height * dsm_grid.cell / gsd)));
  return g;
}

bool SurfaceHeight(const cv::Mat1f& dsm, const DsmGrid& grid, float nodata, double x, double y, double* z) {
  const double fc = (x - grid.x0) / grid.cell - 0.5;
  const double fr = (grid.y0 - y) / grid.cell - 0.5;
  const int c0 = static_cast<int>(std::floor(fc));
  const int r0 = static_cast<int>(std::floor(fr));
  const double ax = fc - c0;
  const double ay = fr - r0;
  double sum = 0.0;
  double weight = 0.0;
  for (int dr = 0; dr < 2; ++dr) {
    for (int dc = 0; dc < 2; ++dc) {
      const int r = std::clamp(r0 + dr, 0, dsm.rows - 1);
      const int c = std::clamp(c0 + dc, 0, dsm.cols - 1);
      const float h = dsm(r, c);
      if (h == nodata) continue;
      const double w = (dr != 0 ? ay : 1.0 - ay) * (dc != 0 ? ax : 1.0 - ax) + 1e-9;
      sum += w * h;
      weight += w;
    }
  }
  if (weight <= 0.0) return false;
  *z = sum / weight;
  return true;
}

namespace {

constexpr float kFar = std::numeric_limits<float>::infinity();

// A frame as the orthophoto sees it: its z-buffer of the DSM and the ortho pixels its view of the DSM reaches.
struct FrameView {
  cv::Mat1f depth;           // depth along the optical axis, at `scale` of the frame's pixels; kFar = no surface
  cv::Rect ortho_box;        // ortho pixels whose surface projects into the frame (empty: it sees none)
  double max_radius2 = 0.0;  // normalised radius^2 beyond which the lens polynomial is not trusted (it folds back)
};

// The frame's normalised radius^2 at its farthest corner, with a margin: points beyond it are outside the frame.
double LensRadius2(const Camera& cam) {
  double r2 = 0.0;
  for (const auto& corner : {Eigen::Vector2d(0, 0), Eigen::Vector2d(cam.width - 1, 0),
                             Eigen::Vector2d(0, cam.height - 1), Eigen::Vector2d(cam.width - 1, cam.height - 1)})
    r2 = std::max(r2, cam.Undistort(corner).squaredNorm());
  return r2 * 1.2 * 1.2;
}

// A world point in frame pixels (false behind the camera or beyond the lens's trusted field); *depth along the axis.
bool ToPixel(const Camera& cam, const Pose& pose, double max_radius2, const Eigen::Vector3d& X, Eigen::Vector2d* pixel,
             double* depth) {
  const Eigen::Vector3d p = pose.ToCamera(X);
  if (p.z() <= 1e-9) return false;
  const Eigen::Vector2d xn(p.x() / p.z(), p.y() / p.z());
  if (xn.squaredNorm() > max_radius2) return false;
  *pixel = cam.Distort(xn);
  *depth = p.z();
  return true;
}

// Keeps the nearest depth of triangle (a, b, c) (x, y in z-buffer pixels, z depth) in `depth`; depth is interpolated
// linearly on the image, which over a DSM cell of a few pixels is well within the occlusion tolerance.
void RasterizeTriangle(const cv::Vec3f& a, const cv::Vec3f& b, const cv::Vec3f& c, cv::Mat1f* depth) {
  const float area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
  if (std::abs(area) < 1e-12f) return;
  const int x0 = std::max(0, static_cast<int>(std::floor(std::min({a[0], b[0], c[0]}))));
  const int x1 = std::min(depth->cols - 1, static_cast<int>(std::ceil(std::max({a[0], b[0], c[0]}))));
  const int y0 = std::max(0, static_cast<int>(std::floor(std::min({a[1], b[1], c[1]}))));
  const int y1 = std::min(depth->rows - 1, static_cast<int>(std::ceil(std::max({a[1], b[1], c[1]}))));
  constexpr float kEdge = -1e-3f;  // inclusive edges: neighbouring triangles leave no crack between them
  for (int yi = y0; yi <= y1; ++yi) {
    float* row = depth->ptr<float>(yi);
    const auto y = static_cast<float>(yi);
    for (int xi = x0; xi <= x1; ++xi) {
      const auto x = static_cast<float>(xi);
      const float w0 = ((b[0] - x) * (c[1] - y) - (b[1] - y) * (c[0] - x)) / area;
      const float w1 = ((c[0] - x) * (a[1] - y) - (c[1] - y) * (a[0] - x)) / area;
      const float w2 = 1.0f - w0 - w1;
      if (w0 < kEdge || w1 < kEdge || w2 < kEdge) continue;
      row[xi] = std::min(row[xi], w0 * a[2] + w1 * b[2] + w2 * c[2]);
    }
  }
}

// The frame's z-buffer of the DSM (the surface through the cell centres, two triangles a cell) and the ortho box its
// view reaches.
FrameView RenderFrameView(const Camera& cam, const Pose& pose, const cv::Mat1f& dsm, const DsmGrid& grid, float nodata,
                          const DsmGrid& ortho, double scale) {
  FrameView view;
  view.max_radius2 = LensRadius2(cam);
  view.depth = cv::Mat1f(std::max(1, static_cast<int>(std::ceil(cam.height * scale))),
                         std::max(1, static_cast<int>(std::ceil(cam.width * scale))), kFar);
  // Every vertex projected once: (x, y) in z-buffer pixels, depth; NaN = not usable.
  cv::Mat3f vertex(dsm.rows, dsm.cols, cv::Vec3f(NAN, NAN, NAN));
  int c_lo = dsm.cols, c_hi = -1, r_lo = dsm.rows, r_hi = -1;
  for (int r = 0; r < dsm.rows; ++r) {
    for (int c = 0; c < dsm.cols; ++c) {
      if (dsm(r, c) == nodata) continue;
      const Eigen::Vector3d X(grid.x0 + (c + 0.5) * grid.cell, grid.y0 - (r + 0.5) * grid.cell, dsm(r, c));
      Eigen::Vector2d px;
      double d = 0.0;
      if (!ToPixel(cam, pose, view.max_radius2, X, &px, &d)) continue;
      vertex(r, c) = cv::Vec3f(static_cast<float>((px.x() + 0.5) * scale - 0.5),
                               static_cast<float>((px.y() + 0.5) * scale - 0.5), static_cast<float>(d));
      if (px.x() >= 0 && px.y() >= 0 && px.x() <= cam.width - 1 && px.y() <= cam.height - 1) {
        c_lo = std::min(c_lo, c);
        c_hi = std::max(c_hi, c);
        r_lo = std::min(r_lo, r);
        r_hi = std::max(r_hi, r);
      }
    }
  }
  const auto usable = [](const cv::Vec3f& v) { return !std::isnan(v[0]); };
  const float w = static_cast<float>(view.depth.cols), h = static_cast<float>(view.depth.rows);
  const auto outside = [&](const cv::Vec3f& a, const cv::Vec3f& b, const cv::Vec3f& c) {
    return std::max({a[0], b[0], c[0]}) < -1 || std::min({a[0], b[0], c[0]}) > w || std::max({a[1], b[1], c[1]}) < -1 ||
           std::min({a[1], b[1], c[1]}) > h;
  };
  for (int r = 0; r + 1 < dsm.rows; ++r) {
    for (int c = 0; c + 1 < dsm.cols; ++c) {
      const cv::Vec3f& v00 = vertex(r, c);
      const cv::Vec3f& v01 = vertex(r, c + 1);
      const cv::Vec3f& v10 = vertex(r + 1, c);
      const cv::Vec3f& v11 = vertex(r + 1, c + 1);
      if (usable(v00) && usable(v01) && usable(v11) && !outside(v00, v01, v11))
        RasterizeTriangle(v00, v01, v11, &view.depth);
      if (usable(v00) && usable(v11) && usable(v10) && !outside(v00, v11, v10))
        RasterizeTriangle(v00, v11, v10, &view.depth);
    }
  }
  if (c_hi >= 0) {
    // DSM cells (one beyond, for the bilinear surface between centres) to ortho pixels.
    const double k = grid.cell / ortho.cell;
    const int x0 = static_cast<int>(std::floor((c_lo - 1) * k)), x1 = static_cast<int>(std::ceil((c_hi + 2) * k));
    const int y0 = static_cast<int>(std::floor((r_lo - 1) * k)), y1 = static_cast<int>(std::ceil((r_hi + 2) * k));
    view.ortho_box = cv::Rect(x0, y0, x1 - x0, y1 - y0) & cv::Rect(0, 0, ortho.width, ortho.height);
  }
  return view;
}

// Decoded frames kept between tiles, least recently used dropped first, within a byte cap (one frame at least).
class FrameCache {
 public:
  FrameCache(const OrthoImageLoad& load, size_t cap_bytes) : load_(load), cap_(cap_bytes) {}
  cv::Mat Get(size_t image) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = index_.find(image);
      if (it != index_.end()) {
        order_.splice(order_.begin(), order_, it->second);
        return it->second->second;
      }
    }
    cv::Mat loaded = load_(image);  // outside the lock: two workers decode at once
    std::lock_guard<std::mutex> lock(mutex_);
    ++loads_;
    if (loaded.empty()) unreadable_.insert(image);
    auto it = index_.find(image);
    if (it != index_.end()) return it->second->second;  // the other worker loaded it meanwhile
    order_.emplace_front(image, loaded);
    index_[image] = order_.begin();
    bytes_ += loaded.total() * loaded.elemSize();
    while (bytes_ > cap_ && order_.size() > 1) {
      const auto& last = order_.back();
      bytes_ -= last.second.total() * last.second.elemSize();
      index_.erase(last.first);
      order_.pop_back();
    }
    return loaded;
  }
  [[nodiscard]] size_t loads() const { return loads_; }
  [[nodiscard]] size_t unreadable() const { return unreadable_.size(); }

 private:
  const OrthoImageLoad& load_;
  size_t cap_;
  std::mutex mutex_;
  std::list<std::pair<size_t, cv::Mat>> order_;
  std::unordered_map<size_t, std::list<std::pair<size_t, cv::Mat>>::iterator> index_;
  size_t bytes_ = 0;
  size_t loads_ = 0;
  std::set<size_t> unreadable_;
};

// What a tile's work shares: the inputs and the frames' views.
struct OrthoContext {
  const Reconstruction& rec;
  const cv::Mat1f& dsm;
  const DsmGrid& dsm_grid;
  float nodata;
  const DsmGrid& ortho;
  const OrthoOptions& options;
  const std::vector<FrameView>& views;
  double scale;                                     // z-buffer scale
  double tolerance = 0;                             // depth tolerance, world units
  const struct StandingObjects* objects = nullptr;  // none: every cell from its own most nadir view
};

// What stands on the terrain (OrthoOptions::object_height), on the DSM's grid: each connected region above the
// height, grown by about a metre so that a seam around it runs on the ground beside its walls, with the frame that
// takes it whole. Made once before the tiles (the DSM's size: int labels and a byte mask); read by every worker.
struct StandingObjects {
  cv::Mat1i label;            // object id (1...), 0 = ground
  cv::Mat1b standing;         // 255 where the surface stands above the height (not grown): the seam counts' "on"
  std::vector<cv::Rect> box;  // per id (index 0 unused), in DSM cells
  std::vector<int> owner;     // per id: the image that takes it whole, -1 = none (each cell its own view)
};

// Counters a worker adds to the report.
struct TileCounts {
  size_t seam_cells = 0;
  size_t seam_cells_on_objects = 0;
  size_t taken_from_another = 0;
  size_t occluded_everywhere = 0;
  size_t covered = 0;
  std::vector<char> used;
};

// The world point of ortho pixel (col, row) (fractional: pixel centres at .0); false where the DSM has no height.
bool SurfacePoint(const OrthoContext& ctx, double col, double row, Eigen::Vector3d* X) {
  const double x = ctx.ortho.x0 + (col + 0.5) * ctx.ortho.cell;
  const double y = ctx.ortho.y0 - (row + 0.5) * ctx.ortho.cell;
  double z = 0.0;
  if (!SurfaceHeight(ctx.dsm, ctx.dsm_grid, ctx.nodata, x, y, &z)) return false;
  *X = Eigen::Vector3d(x, y, z);
  return true;
}

enum class Sight { kOutside, kOccluded, kSeen };

// How frame `image` sees the surface point X: outside its picture, hidden by something nearer in its z-buffer, or
// seen; *nadir the cosine between the ray to the camera and the vertical.
Sight SightOf(const OrthoContext& ctx, size_t image, const Eigen::Vector3d& X, double* nadir) {
  const Image& im = ctx.rec.images[image];
  const Camera& cam = ctx.rec.CameraOf(im);
  const FrameView& view = ctx.views[image];
  Eigen::Vector2d px;
  double depth = 0.0;
  if (!ToPixel(cam, im.pose, view.max_radius2, X, &px, &depth)) return Sight::kOutside;
  if (px.x() < 0 || px.y() < 0 || px.x() > cam.width - 1 || px.y() > cam.height - 1) return Sight::kOutside;
  *nadir = (im.pose.c - X).normalized().z();
  const int zx = std::clamp(static_cast<int>(std::lround((px.x() + 0.5) * ctx.scale - 0.5)), 0, view.depth.cols - 1);
  const int zy = std::clamp(static_cast<int>(std::lround((px.y() + 0.5) * ctx.scale - 0.5)), 0, view.depth.rows - 1);
  return depth > view.depth(zy, zx) + ctx.tolerance ? Sight::kOccluded : Sight::kSeen;
}

// Frames that see each kOverlapBlock x kOverlapBlock block's centre unoccluded (for the report's overlap map).
cv::Mat1b OverlapMap(const OrthoContext& ctx, int threads) {
  const int block = OrthoReport::kOverlapBlock;
  cv::Mat1b overlap((ctx.ortho.height + block - 1) / block, (ctx.ortho.width + block - 1) / block, uchar{0});
  ParallelFor(static_cast<size_t>(overlap.rows), threads, [&](size_t row) {
    const int r = static_cast<int>(row);
    for (int c = 0; c < overlap.cols; ++c) {
      const cv::Point px(std::min(c * block + block / 2, ctx.ortho.width - 1),
                         std::min(r * block + block / 2, ctx.ortho.height - 1));
      Eigen::Vector3d X;
      if (!SurfacePoint(ctx, px.x, px.y, &X)) continue;
      int seen = 0;
      for (size_t i = 0; i < ctx.views.size(); ++i) {
        double nadir = 0.0;
        if (ctx.views[i].ortho_box.contains(px) && SightOf(ctx, i, X, &nadir) == Sight::kSeen) ++seen;
      }
      overlap(r, c) = static_cast<uchar>(std::min(seen, 255));
    }
  });
  return overlap;
}

// The DSM cell under world (x, y); false outside the grid.
bool DsmCellAt(const OrthoContext& ctx, double x, double y, cv::Point* cell) {
  const int c = static_cast<int>(std::floor((x - ctx.dsm_grid.x0) / ctx.dsm_grid.cell));
  const int r = static_cast<int>(std::floor((ctx.dsm_grid.y0 - y) / ctx.dsm_grid.cell));
  if (c < 0 || r < 0 || c >= ctx.dsm.cols || r >= ctx.dsm.rows) return false;
  *cell = cv::Point(c, r);
  return true;
}

// The regions of `dsm` more than `height` above `terrain` (both on `grid`) of at least ~4 square metres (smaller
// ones, a post or a noisy cell, are no object and not counted as standing), grown by ~1 m, as labelled objects.
StandingObjects FindStandingObjects(const cv::Mat1f& dsm, const cv::Mat1f& terrain, const DsmGrid& grid, float nodata,
                                    double height) {
  StandingObjects objects;
  cv::Mat1b above(dsm.size(), uchar{0});
  for (int r = 0; r < dsm.rows; ++r)
    for (int c = 0; c < dsm.cols; ++c) {
      const float z = dsm(r, c), t = terrain(r, c);
      if (z != nodata && t != nodata && z - t > height) above(r, c) = 255;
    }
  cv::Mat1i blobs;
  cv::Mat stats, centroids;
  const int blob_count = cv::connectedComponentsWithStats(above, blobs, stats, centroids, 8, CV_32S);
  const double min_cells = 4.0 / (grid.cell * grid.cell);
  objects.standing = cv::Mat1b(dsm.size(), uchar{0});
  for (int r = 0; r < dsm.rows; ++r)
    for (int c = 0; c < dsm.cols; ++c)
      if (blobs(r, c) > 0 && blob_count > 0 && stats.at<int>(blobs(r, c), cv::CC_STAT_AREA) >= min_cells)
        objects.standing(r, c) = 255;
  const int grow = std::max(1, static_cast<int>(std::lround(1.0 / grid.cell)));
  cv::Mat1b grown;
  cv::dilate(objects.standing, grown,
             cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * grow + 1, 2 * grow + 1)));
  const int n = cv::connectedComponentsWithStats(grown, objects.label, stats, centroids, 8, CV_32S);
  objects.box.assign(static_cast<size_t>(std::max(n, 1)), cv::Rect());
  objects.owner.assign(objects.box.size(), -1);
  for (int id = 1; id < n; ++id)
    objects.box[static_cast<size_t>(id)] =
        cv::Rect(stats.at<int>(id, cv::CC_STAT_LEFT), stats.at<int>(id, cv::CC_STAT_TOP),
                 stats.at<int>(id, cv::CC_STAT_WIDTH), stats.at<int>(id, cv::CC_STAT_HEIGHT));
  return objects;
}

// Each object's owner: of the frames that see at least 90 % of it unoccluded (on up to ~400 of its standing cells: the
// ring of ground around it is not the object), the most nadir on average; else the one that sees most of it, if at
// least half; else none (its cells each take their own).
void ChooseObjectOwners(const OrthoContext& ctx, StandingObjects* objects) {
  ParallelFor(objects->box.size(), ctx.options.threads, [&](size_t id) {
    const cv::Rect box = objects->box[id];
    if (box.empty()) return;
    std::vector<Eigen::Vector3d> samples;
    const double area = static_cast<double>(box.width) * static_cast<double>(box.height);
    const int stride = std::max(1, static_cast<int>(std::sqrt(area / 400.0)));
    for (int r = box.y; r < box.y + box.height; r += stride)
      for (int c = box.x; c < box.x + box.width; c += stride)
        if (objects->label(r, c) == static_cast<int>(id) && objects->standing(r, c) != 0 && ctx.dsm(r, c) != ctx.nodata)
          samples.emplace_back(ctx.dsm_grid.x0 + (c + 0.5) * ctx.dsm_grid.cell,
                               ctx.dsm_grid.y0 - (r + 0.5) * ctx.dsm_grid.cell, ctx.dsm(r, c));
    if (samples.empty()) return;
    const double k = ctx.dsm_grid.cell / ctx.ortho.cell;
    const cv::Rect in_ortho(static_cast<int>((ctx.dsm_grid.x0 - ctx.ortho.x0) / ctx.ortho.cell + box.x * k),
                            static_cast<int>((ctx.ortho.y0 - ctx.dsm_grid.y0) / ctx.ortho.cell + box.y * k),
                            static_cast<int>(std::ceil(box.width * k)) + 1,
                            static_cast<int>(std::ceil(box.height * k)) + 1);
    int best_whole = -1, best_most = -1;
    double whole_nadir = -1.0;
    size_t most_seen = 0;
    for (size_t i = 0; i < ctx.views.size(); ++i) {
      if ((ctx.views[i].ortho_box & in_ortho).area() == 0) continue;
      size_t seen = 0;
      double nadir_sum = 0.0;
      for (const auto& X : samples) {
        double nadir = 0.0;
        if (SightOf(ctx, i, X, &nadir) != Sight::kSeen) continue;
        ++seen;
        nadir_sum += nadir;
      }
      if (seen >= 0.9 * static_cast<double>(samples.size()) && nadir_sum / static_cast<double>(seen) > whole_nadir) {
        whole_nadir = nadir_sum / static_cast<double>(seen);
        best_whole = static_cast<int>(i);
      }
      if (seen > most_seen) {
        most_seen = seen;
        best_most = static_cast<int>(i);
      }
    }
    objects->owner[id] = best_whole >= 0 ? best_whole : (2 * most_seen >= samples.size() ? best_most : -1);
  });
}

// The standing object (its label) whose surface hides X from frame `image`: where the ray to X meets the depth of the
// frame's z-buffer there; 0 when that is ground, off the grid, or nothing hides X.
int OccluderLabel(const OrthoContext& ctx, size_t image, const Eigen::Vector3d& X) {
  const Image& im = ctx.rec.images[image];
  const FrameView& view = ctx.views[image];
  Eigen::Vector2d px;
  double depth = 0.0;
  if (!ToPixel(ctx.rec.CameraOf(im), im.pose, view.max_radius2, X, &px, &depth)) return 0;
  const int zx = std::clamp(static_cast<int>(std::lround((px.x() + 0.5) * ctx.scale - 0.5)), 0, view.depth.cols - 1);
  const int zy = std::clamp(static_cast<int>(std::lround((px.y() + 0.5) * ctx.scale - 0.5)), 0, view.depth.rows - 1);
  const double nearer = view.depth(zy, zx);
  if (!(nearer > 0.0 && nearer < depth)) return 0;
  const Eigen::Vector3d hit = im.pose.c + (X - im.pose.c) * (nearer / depth);  // depths scale along a ray
  cv::Point cell;
  return DsmCellAt(ctx, hit.x(), hit.y(), &cell) ? ctx.objects->label(cell) : 0;
}

// The index into `candidates` of the frame that takes the standing object under X whole, -1 when none does. On the
// object itself the owner is kept also where the object hides X from it (a crown's or a roof's own far flank, seen
// past its top: another view there would cut the object with a seam); not where something else hides it, nor on the
// ring of ground around the object, where a hidden point comes from another frame as everywhere.
int ObjectOwnerAt(const OrthoContext& ctx, const std::vector<size_t>& candidates, const Eigen::Vector3d& X) {
  if (ctx.objects == nullptr) return -1;
  cv::Point cell;
  if (!DsmCellAt(ctx, X.x(), X.y(), &cell)) return -1;
  const int id = ctx.objects->label(cell);
  const int owner = id > 0 ? ctx.objects->owner[static_cast<size_t>(id)] : -1;
  if (owner < 0) return -1;
  const auto it = std::lower_bound(candidates.begin(), candidates.end(), static_cast<size_t>(owner));
  if (it == candidates.end() || *it != static_cast<size_t>(owner)) return -1;
  double nadir = 0.0;
  const Sight sight = SightOf(ctx, static_cast<size_t>(owner), X, &nadir);
  const bool take = sight == Sight::kSeen || (sight == Sight::kOccluded && ctx.objects->standing(cell) != 0 &&
                                              OccluderLabel(ctx, static_cast<size_t>(owner), X) == id);
  return take ? static_cast<int>(it - candidates.begin()) : -1;
}

// Seam cells of the tile's own part (`inner`, in `roi`'s pixels): cells with an owner whose right or lower neighbour
// has another; and of those the ones that cut a standing object (both cells on it, not its outline).
void CountSeams(const OrthoContext& ctx, const cv::Mat1s& owner, const cv::Rect& roi, const cv::Rect& inner,
                TileCounts* counts) {
  const int cell = ctx.options.seam_cell;
  const auto standing = [&](int r, int c) {
    cv::Point dsm_cell;
    const double x = ctx.ortho.x0 + (roi.x + c * cell + cell / 2 + 0.5) * ctx.ortho.cell;
    const double y = ctx.ortho.y0 - (roi.y + r * cell + cell / 2 + 0.5) * ctx.ortho.cell;
    return ctx.objects != nullptr && DsmCellAt(ctx, x, y, &dsm_cell) && ctx.objects->standing(dsm_cell) != 0;
  };
  for (int r = 0; r + 1 < owner.rows; ++r)
    for (int c = 0; c + 1 < owner.cols; ++c) {
      if (!inner.contains(cv::Point(c * cell + cell / 2, r * cell + cell / 2))) continue;
      const int16_t o = owner(r, c), right = owner(r, c + 1), down = owner(r + 1, c);
      const bool cut_right = right >= 0 && right != o, cut_down = down >= 0 && down != o;
      if (o < 0 || !(cut_right || cut_down)) continue;
      ++counts->seam_cells;
      if (standing(r, c) && ((cut_right && standing(r, c + 1)) || (cut_down && standing(r + 1, c))))
        ++counts->seam_cells_on_objects;
    }
}

// Per seam cell of `roi`, the index (into `candidates`, ascending) of the frame that takes the standing object there
// whole, else of the most nadir frame that sees the cell's surface point unoccluded (the most nadir frame that has it
// in view when none does); -1 = no frame or no surface.
cv::Mat1s SeamOwners(const OrthoContext& ctx, const std::vector<size_t>& candidates, const cv::Rect& roi,
                     TileCounts* counts) {
  const int cell = ctx.options.seam_cell;
  const cv::Size cells((roi.width + cell - 1) / cell, (roi.height + cell - 1) / cell);
  cv::Mat1s owner(cells, static_cast<int16_t>(-1));
  for (int r = 0; r < cells.height; ++r) {
    for (int c = 0; c < cells.width; ++c) {
      const double col = roi.x + std::min(c * cell + 0.5 * (cell - 1), roi.width - 1.0);
      const double row = roi.y + std::min(r * cell + 0.5 * (cell - 1), roi.height - 1.0);
      Eigen::Vector3d X;
      if (!SurfacePoint(ctx, col, row, &X)) continue;
      if (const int whole = ObjectOwnerAt(ctx, candidates, X); whole >= 0) {
        owner(r, c) = static_cast<int16_t>(whole);
        continue;
      }
      int best_seen = -1, best_any = -1;
      double score_seen = -2.0, score_any = -2.0;
      for (size_t k = 0; k < candidates.size(); ++k) {
        double score = 0.0;
        const Sight sight = SightOf(ctx, candidates[k], X, &score);
        if (sight == Sight::kOutside) continue;
        if (score > score_any) {
          score_any = score;
          best_any = static_cast<int>(k);
        }
        if (sight == Sight::kSeen && score > score_seen) {
          score_seen = score;
          best_seen = static_cast<int>(k);
        }
      }
      if (best_seen >= 0) {
        owner(r, c) = static_cast<int16_t>(best_seen);
        if (best_seen != best_any) ++counts->taken_from_another;
      } else if (best_any >= 0) {
        owner(r, c) = static_cast<int16_t>(best_any);
        ++counts->occluded_everywhere;
      }
    }
  }
  return owner;
}

// One worker's tile: ownership, then each owner's pixels (and the blend's reach around them) warped from its frame
// through the DSM and fed to the blender.
bool OrthoTile(const OrthoContext& ctx, FrameCache* cache, const std::vector<size_t>& candidates, const cv::Rect& roi,
               const cv::Rect& inner, TileBlender* blender, TileCounts* counts, cv::Mat* image, cv::Mat* mask) {
  const int cell = ctx.options.seam_cell;
  const cv::Mat1s cell_owner = SeamOwners(ctx, candidates, roi, counts);
  CountSeams(ctx, cell_owner, roi, inner, counts);
  cv::Mat1s owner(roi.size());
  for (int r = 0; r < roi.height; ++r)
    for (int c = 0; c < roi.width; ++c) owner(r, c) = cell_owner(r / cell, c / cell);
  blender->Prepare(roi);
  bool fed = false;
  const int reach = BlendReach(ctx.options.num_bands);
  cv::Mat1b own;
  for (size_t k = 0; k < candidates.size(); ++k) {
    cv::compare(owner, cv::Scalar(static_cast<double>(k)), own, cv::CMP_EQ);
    if (cv::countNonZero(own) == 0) continue;
    const cv::Mat frame = cache->Get(candidates[k]);
    if (frame.empty()) continue;
    const Image& im = ctx.rec.images[candidates[k]];
    const Camera& cam = ctx.rec.CameraOf(im);
    const FrameView& view = ctx.views[candidates[k]];
    cv::Rect box = cv::boundingRect(own);
    box = cv::Rect(box.x - reach, box.y - reach, box.width + 2 * reach, box.height + 2 * reach) &
          cv::Rect(0, 0, roi.width, roi.height);
    cv::Mat1f map_x(box.size(), -1.0f), map_y(box.size(), -1.0f);
    for (int r = 0; r < box.height; ++r) {
      for (int c = 0; c < box.width; ++c) {
        Eigen::Vector3d X;
        if (!SurfacePoint(ctx, roi.x + box.x + c, roi.y + box.y + r, &X)) continue;
        Eigen::Vector2d px;
        double depth = 0.0;
        if (!ToPixel(cam, im.pose, view.max_radius2, X, &px, &depth)) continue;
        map_x(r, c) = static_cast<float>(px.x());
        map_y(r, c) = static_cast<float>(px.y());
      }
    }
    cv::Mat warped;
    cv::remap(frame, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REFLECT);
    blender->Feed(warped, own(box), roi.tl() + box.tl());
    counts->used[candidates[k]] = 1;
    fed = true;
  }
  if (!fed) return false;
  blender->Blend(image, mask);
  cv::Mat1b none;
  cv::compare(owner, cv::Scalar(0), none, cv::CMP_LT);
  mask->setTo(0, none);
  image->setTo(cv::Scalar::all(0), none);
  return true;
}

}  // namespace

namespace {

// Every posed frame's z-buffer of the DSM, all within options.zbuffer_mib (at most a quarter of the frame's pixels).
bool RenderFrameViews(const Reconstruction& rec, const cv::Mat1f& dsm, const DsmGrid& dsm_grid, float nodata,
                      const DsmGrid& ortho_grid, const OrthoOptions& options, std::vector<FrameView>* views_out,
                      double* scale_out, OrthoReport* report, std::string* error) {
  // The z-buffers' scale: every posed frame's depth map within zbuffer_mib, at most a quarter of the frame's pixels.
  double frame_pixels = 0.0;
  for (const auto& im : rec.images)
    if (im.posed) frame_pixels += static_cast<double>(rec.CameraOf(im).width) * rec.CameraOf(im).height;
  if (frame_pixels <= 0.0) {
    *error = "orthophoto: no posed frame";
    return false;
  }
  const double scale = std::min(0.25, std::sqrt(options.zbuffer_mib * kMiB / (4.0 * frame_pixels)));
  report->zbuffer_scale = scale;
  std::vector<FrameView>& views = *views_out;
  views.assign(rec.images.size(), FrameView{});
  ParallelFor(rec.images.size(), options.threads, [&](size_t i) {
    if (rec.images[i].posed)
      views[i] =
          RenderFrameView(rec.CameraOf(rec.images[i]), rec.images[i].pose, dsm, dsm_grid, nodata, ortho_grid, scale);
  });
  for (const auto& v : views) {
    report->zbuffer_mib += static_cast<double>(v.depth.total()) * 4.0 / kMiB;
    if (!v.ortho_box.empty()) ++report->images_in_view;
  }

  *scale_out = scale;
  return true;
}

// The tiles along a Hilbert curve, each blended by a worker and handed to `sink` (one at a time); per worker counts.
bool BlendTiles(const OrthoContext& ctx, const OrthoImageLoad& load, const OrthoTileSink& sink,
                std::vector<TileCounts>* counts_out, OrthoReport* report, std::string* error, size_t* loads,
                size_t* unreadable) {
  const OrthoOptions& options = ctx.options;
  const DsmGrid& ortho_grid = ctx.ortho;
  const Reconstruction& rec = ctx.rec;
  const std::vector<FrameView>& views = ctx.views;
  std::vector<TileCounts>& counts = *counts_out;
  counts.assign(static_cast<size_t>(options.threads), TileCounts{});
  const std::vector<cv::Rect> tiles =
      TilesAlongHilbertCurve(cv::Size(ortho_grid.width, ortho_grid.height), options.tile_size);
  report->tiles = static_cast<int>(tiles.size());
  const int margin = std::max(2, BlendReach(options.num_bands));
  const cv::Rect whole(0, 0, ortho_grid.width, ortho_grid.height);
  FrameCache cache(load, static_cast<size_t>(options.image_cache_mib * kMiB));
  std::vector<std::unique_ptr<TileBlender>> blenders;
  for (int w = 0; w < options.threads; ++w) {
    blenders.push_back(options.num_bands > 0 ? MakeMultiBandBlender(options.num_bands) : MakeSeamOnlyBlender());
    counts[static_cast<size_t>(w)].used.assign(rec.images.size(), 0);
  }
  std::mutex sink_mutex;
  std::atomic<bool> failed{false};
  std::string sink_error;
  ParallelForOnWorkers(tiles.size(), options.threads, [&](size_t t, size_t worker) {
    if (failed) return;
    const cv::Rect tile = tiles[t];
    const cv::Rect roi =
        cv::Rect(tile.x - margin, tile.y - margin, tile.width + 2 * margin, tile.height + 2 * margin) & whole;
    std::vector<size_t> candidates;
    for (size_t i = 0; i < views.size(); ++i)
      if ((views[i].ortho_box & roi).area() > 0) candidates.push_back(i);
    cv::Mat image, mask;
    const cv::Rect inner(tile.x - roi.x, tile.y - roi.y, tile.width, tile.height);
    if (candidates.empty() ||
        !OrthoTile(ctx, &cache, candidates, roi, inner, blenders[worker].get(), &counts[worker], &image, &mask))
      return;
    const int covered = cv::countNonZero(mask(inner));
    if (covered == 0) return;
    std::lock_guard<std::mutex> lock(sink_mutex);
    counts[worker].covered += static_cast<size_t>(covered);
    ++report->tiles_written;
    std::string why;
    if (!failed && !sink(image(inner), mask(inner), tile.tl(), &why)) {
      failed = true;
      sink_error = why;
    }
  });
  if (failed) {
    *error = "orthophoto: " + sink_error;
    return false;
  }
  *loads = cache.loads();
  *unreadable = cache.unreadable();
  return true;
}

}  // namespace

bool MakeOrthophoto(const Reconstruction& rec, const cv::Mat1f& dsm, const cv::Mat1f& terrain, const DsmGrid& dsm_grid,
                    float nodata, const DsmGrid& ortho_grid, const OrthoOptions& options, const OrthoImageLoad& load,
                    const OrthoTileSink& sink, OrthoReport* report, std::string* error) {
  const auto start = std::chrono::steady_clock::now();
  if (!options.Check(error)) return false;
  *report = OrthoReport{};
  report->grid = ortho_grid;
  if (dsm.empty() || ortho_grid.width <= 0 || ortho_grid.height <= 0) {
    *error = "orthophoto: no DSM";
    return false;
  }
  std::vector<FrameView> views;
  double scale = 0.0;
  if (!RenderFrameViews(rec, dsm, dsm_grid, nodata, ortho_grid, options, &views, &scale, report, error)) return false;
  OrthoContext ctx{
      rec, dsm, dsm_grid, nodata, ortho_grid, options, views, scale, options.occlusion_tolerance_cells * dsm_grid.cell};
  report->overlap = OverlapMap(ctx, options.threads);
  StandingObjects objects;
  if (options.object_height > 0.0 && terrain.size() == dsm.size()) {
    objects = FindStandingObjects(dsm, terrain, dsm_grid, nodata, options.object_height);
    if (options.seams_off_objects) ChooseObjectOwners(ctx, &objects);
    ctx.objects = &objects;
    for (size_t id = 1; id < objects.box.size(); ++id) {
      report->objects += objects.box[id].empty() ? 0 : 1;
      report->objects_taken_whole += objects.owner[id] >= 0 ? 1 : 0;
    }
  }
  std::vector<TileCounts> counts;
  size_t loads = 0, unreadable = 0;
  if (!BlendTiles(ctx, load, sink, &counts, report, error, &loads, &unreadable)) return false;
  std::vector<char> used(rec.images.size(), 0);
  for (const auto& c : counts) {
    report->pixels_covered += c.covered;
    report->cells_taken_from_another_view += c.taken_from_another;
    report->cells_occluded_everywhere += c.occluded_everywhere;
    report->seam_cells += c.seam_cells;
    report->seam_cells_on_objects += c.seam_cells_on_objects;
    for (size_t i = 0; i < used.size(); ++i) used[i] = static_cast<char>(used[i] | c.used[i]);
  }
  report->images_used = static_cast<int>(std::count(used.begin(), used.end(), 1));
  report->image_loads = loads;
  report->images_unreadable = static_cast<int>(unreadable);
  report->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return true;
}

}  // namespace uavm::sfm
