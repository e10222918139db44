#include "core/tiles/live_tile_pyramid.h"

#include <pthread.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <list>
#include <opencv2/imgproc.hpp>
#include <unordered_map>
#include <unordered_set>

#include "core/tiles/tile_render.h"
#include "core/tiles/tile_store.h"
#include "core/tiles/web_mercator.h"
#include "core/util/clock.h"

namespace uavm {

bool LiveTileOptions::Check(std::string* why) const {
  const auto fail = [why](const char* what) {
    *why = std::string("live_tiles: ") + what;
    return false;
  };
  if (cache_tiles < 16) return fail("cache_tiles must be >= 16");
  if (frame_cache < 1) return fail("frame_cache must be >= 1");
  if (queue_images < 0 || queue_jobs < 16) return fail("queue_images must be >= 0 and queue_jobs >= 16");
  if (feather_px < 0 || feather_px > 256) return fail("feather_px must be in [0, 256]");
  if (png_compression < 0 || png_compression > 9) return fail("png_compression must be in [0, 9]");
  if (levels < 0 || levels > 24) return fail("levels must be in [0, 24]");
  if (!(redraw_shift_px >= 0)) return fail("redraw_shift_px must be >= 0");
  if (!(refit_shift_m > 0)) return fail("refit_shift_m must be > 0");
  return true;
}

// The worker's state: the grid, the tiles and what each frame covers.
class LiveTilePyramid::Renderer {
 public:
  Renderer(std::string dir, const LiveTileOptions& o, FrameReader reader)
      : options_(o), base_(std::move(dir)), reader_(std::move(reader)) {
    std::error_code ec;
    std::filesystem::remove_all(base_, ec);  // a previous run's tiles are not this flight's (a resume draws again)
    store_ = std::make_unique<TileStore>(base_ + "/0", o.cache_tiles, o.png_compression);
  }

  // A new grid in a directory of its own (base/<generation>): the old one stays served until the new one has
  // caught up (RemoveOlderGenerations), so that a client never sees the map vanish.
  void Reset(const TileGrid& grid) {
    ++generation_;
    written_before_ += store_->tiles_written();
    errors_before_ += store_->write_errors();
    store_ = std::make_unique<TileStore>(base_ + "/" + std::to_string(generation_), options_.cache_tiles,
                                         options_.png_compression);
    store_->Clear();
    grid_ = grid;
    records_.clear();
    index_.clear();
    images_.clear();
    bounds_ = cv::Rect2d();
    pending_.clear();
  }

  void RemoveOlderGenerations() const {
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(base_, ec))
      if (e.path().filename() != std::to_string(generation_)) std::filesystem::remove_all(e.path(), ec);
  }
  [[nodiscard]] int64_t generation() const { return generation_; }
  [[nodiscard]] int64_t tiles_written() const { return written_before_ + store_->tiles_written(); }
  [[nodiscard]] int64_t write_errors() const { return errors_before_ + store_->write_errors(); }

  // Draws a new frame or one that moved; false when nothing was drawn (no pixels, or a move too small to matter).
  bool Draw(const TileFrame& f, bool* redrawn, bool* reread) {
    auto it = records_.find(f.id);
    if (it == records_.end()) return DrawNew(f, reread);
    Record& r = it->second;
    // Sub-pixel moves of a solve cost nothing (the tiles keep the old place).
    if (MaxCornerShift(r.grid_from_work, f.grid_from_work, r.work_size) <= options_.redraw_shift_px) return false;
    *redrawn = true;
    std::unordered_set<TileKey, TileKeyHash> dirty(r.tiles.begin(), r.tiles.end());
    Unindex(f.id, r);
    r.grid_from_work = f.grid_from_work;
    r.heading = f.heading;
    r.tiles = TilesOf(f.grid_from_work, f.work_size);
    Index(f.id, r);
    dirty.insert(r.tiles.begin(), r.tiles.end());
    RenderAgain(dirty, reread);
    pending_.insert(dirty.begin(), dirty.end());
    return true;
  }

  // The coarser zooms over what changed since the last call.
  [[nodiscard]] bool HasPending() const { return !pending_.empty(); }
  void CascadePending() {
    Cascade(std::move(pending_));
    pending_.clear();
  }

  [[nodiscard]] bool Flush(std::string* error) { return store_->Flush(error); }

  [[nodiscard]] std::shared_ptr<const TileSetInfo> Info(int frames) const {
    auto info = std::make_shared<TileSetInfo>();
    info->dir = store_->dir();
    info->geographic = grid_.geographic;
    info->min_zoom = grid_.min_zoom;
    info->max_zoom = grid_.max_zoom;
    info->generation = generation_;
    info->updated_ns = MonotonicNs();
    info->frames = frames;
    if (grid_.geographic) {
      const Vec2 nw = LonLatFromMercatorPixel(Vec2(bounds_.x, bounds_.y), grid_.max_zoom);
      const Vec2 se = LonLatFromMercatorPixel(Vec2(bounds_.br().x, bounds_.br().y), grid_.max_zoom);
      info->west = nw.x(), info->north = nw.y(), info->east = se.x(), info->south = se.y();
    } else {
      const double s = std::ldexp(1.0, grid_.max_zoom);
      info->west = bounds_.x / s, info->east = bounds_.br().x / s;
      info->north = -bounds_.y / s, info->south = -bounds_.br().y / s;
    }
    return info;
  }
  [[nodiscard]] int frames() const { return static_cast<int>(records_.size()); }

 private:
  struct Record {
    std::string path;
    cv::Size work_size;
    int decode_reduce = 1;
    Mat3 grid_from_work;
    double heading = 0.0;
    std::vector<TileKey> tiles;  // max_zoom tiles it touches
  };

  bool DrawNew(const TileFrame& f, bool* reread) {
    Record& r = records_[f.id];
    r.path = f.path;
    r.work_size = f.work_size;
    r.decode_reduce = f.decode_reduce;
    r.grid_from_work = f.grid_from_work;
    r.heading = f.heading;
    r.tiles = TilesOf(f.grid_from_work, f.work_size);
    Index(f.id, r);
    const auto fp = Footprint(f.grid_from_work, f.work_size.width, f.work_size.height);
    const cv::Rect2d box = cv::boundingRect(fp);
    bounds_ = bounds_.area() > 0 ? (bounds_ | box) : box;
    const FramePixels* px = f.image ? Remember(f.id, *f.image) : Pixels(f.id, r, reread);
    if (px == nullptr) return false;
    for (const TileKey& k : r.tiles) {
      cv::Mat& tile = store_->Get(k);
      if (PaintFrame(px->bgr, px->weight, TileFromWork(k, f.grid_from_work), &tile)) store_->MarkDirty(k);
    }
    pending_.insert(r.tiles.begin(), r.tiles.end());
    return true;
  }

  // The max_zoom tiles the frame's footprint touches, inside the world.
  [[nodiscard]] std::vector<TileKey> TilesOf(const Mat3& grid_from_work, cv::Size size) const {
    const cv::Rect2d box = cv::boundingRect(Footprint(grid_from_work, size.width, size.height));
    const int n = 1 << grid_.max_zoom;
    const int x0 = std::max(0, static_cast<int>(std::floor(box.x / kTileSize)));
    const int y0 = std::max(0, static_cast<int>(std::floor(box.y / kTileSize)));
    const int x1 = std::min(n - 1, static_cast<int>(std::floor(box.br().x / kTileSize)));
    const int y1 = std::min(n - 1, static_cast<int>(std::floor(box.br().y / kTileSize)));
    std::vector<TileKey> keys;
    const cv::Size work = size;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x)
        if (FrameTouchesTile(grid_from_work, work, x, y)) keys.push_back({grid_.max_zoom, x, y});
    return keys;
  }

  [[nodiscard]] Mat3 TileFromWork(const TileKey& k, const Mat3& grid_from_work) const {
    // Tile pixel centres: global pixel corner (x*256, y*256) is the tile's pixel (0,0)'s corner.
    return Translation(-k.x * kTileSize - 0.5, -k.y * kTileSize - 0.5) * grid_from_work;
  }

  void Index(int id, const Record& r) {
    for (const TileKey& k : r.tiles) {
      auto& ids = index_[k];
      ids.insert(std::upper_bound(ids.begin(), ids.end(), id), id);
    }
  }
  void Unindex(int id, const Record& r) {
    for (const TileKey& k : r.tiles) {
      auto it = index_.find(k);
      if (it == index_.end()) continue;
      auto& ids = it->second;
      ids.erase(std::remove(ids.begin(), ids.end(), id), ids.end());
      if (ids.empty()) index_.erase(it);
    }
  }

  // Max_zoom tiles drawn again from every frame that touches them, oldest first (as they were drawn live). Frame by
  // frame, so that each is decoded once however many of the tiles it covers.
  void RenderAgain(const std::unordered_set<TileKey, TileKeyHash>& tiles, bool* reread) {
    std::vector<int> ids;
    for (const TileKey& k : tiles) {
      store_->Get(k).setTo(cv::Scalar::all(0));
      store_->MarkDirty(k);
      auto it = index_.find(k);
      if (it != index_.end()) ids.insert(ids.end(), it->second.begin(), it->second.end());
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    for (int id : ids) {
      const Record& r = records_.at(id);
      const FramePixels* px = Pixels(id, r, reread);
      if (px == nullptr) continue;
      for (const TileKey& k : r.tiles) {
        if (tiles.count(k) == 0) continue;
        cv::Mat& tile = store_->Get(k);
        if (PaintFrame(px->bgr, px->weight, TileFromWork(k, r.grid_from_work), &tile)) store_->MarkDirty(k);
      }
    }
  }

  // Parents of the changed tiles, zoom by zoom, down to min_zoom.
  void Cascade(std::unordered_set<TileKey, TileKeyHash> changed) {
    for (int z = grid_.max_zoom - 1; z >= grid_.min_zoom; --z) {
      std::unordered_set<TileKey, TileKeyHash> parents;
      for (const TileKey& c : changed) parents.insert({z, c.x >> 1, c.y >> 1});
      for (const TileKey& p : parents) {
        cv::Mat children(2 * kTileSize, 2 * kTileSize, CV_8UC4);
        for (int q = 0; q < 4; ++q) {
          const TileKey c{z + 1, 2 * p.x + (q & 1), 2 * p.y + (q >> 1)};
          store_->Get(c).copyTo(children(cv::Rect((q & 1) * kTileSize, (q >> 1) * kTileSize, kTileSize, kTileSize)));
        }
        cv::Mat& tile = store_->Get(p);
        HalveRgba(children, &tile);
        store_->MarkDirty(p);
      }
      changed = std::move(parents);
    }
  }

  struct FramePixels {
    cv::Mat bgr;
    cv::Mat weight;
  };
  // The frame's pixels if cached (then most recently used), else null.
  const FramePixels* Cached(int id) {
    for (auto it = images_.begin(); it != images_.end(); ++it)
      if (it->first == id) {
        images_.splice(images_.begin(), images_, it);
        return &images_.front().second;
      }
    return nullptr;
  }
  const FramePixels* Remember(int id, const cv::Mat& bgr) {
    if (const FramePixels* px = Cached(id)) return px;
    if (images_.size() >= static_cast<size_t>(options_.frame_cache)) images_.pop_back();
    if (weight_.size() != bgr.size()) weight_ = FeatherWeight(bgr.size(), options_.feather_px);  // one per frame size
    images_.emplace_front(id, FramePixels{bgr, weight_});
    return &images_.front().second;
  }
  const FramePixels* Pixels(int id, const Record& r, bool* reread) {
    if (const FramePixels* px = Cached(id)) return px;
    const cv::Mat bgr = reader_ ? reader_(id, r.path, r.work_size, r.decode_reduce, r.heading) : cv::Mat();
    if (bgr.empty()) {
      spdlog::warn("live tiles: cannot read {} again; its tiles miss it", r.path);
      return nullptr;
    }
    *reread = true;
    return Remember(id, bgr);
  }

  LiveTileOptions options_;
  std::string base_;
  std::unique_ptr<TileStore> store_;
  int64_t written_before_ = 0, errors_before_ = 0;  // by the stores of earlier grids
  FrameReader reader_;
  TileGrid grid_;
  int64_t generation_ = 0;
  std::unordered_map<int, Record> records_;
  std::unordered_map<TileKey, std::vector<int>, TileKeyHash> index_;  // max_zoom tile -> frames, ascending
  std::list<std::pair<int, FramePixels>> images_;                     // most recently used first
  cv::Mat weight_;                                                    // shared, read-only: frames of one size
  cv::Rect2d bounds_;                                                 // max_zoom pixels drawn so far
  std::unordered_set<TileKey, TileKeyHash> pending_;  // max_zoom tiles whose parents are not rebuilt yet
};

LiveTilePyramid::LiveTilePyramid(std::string dir, const LiveTileOptions& options, FrameReader reader, Listener listener)
    : options_(options),
      listener_(std::move(listener)),
      renderer_(std::make_unique<Renderer>(std::move(dir), options, std::move(reader))) {
  worker_ = std::thread([this] { Work(); });
}

LiveTilePyramid::~LiveTilePyramid() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void LiveTilePyramid::Reset(const TileGrid& grid) {
  std::lock_guard lock(mutex_);
  // Whatever waits was meant for the old grid.
  jobs_.clear();
  images_queued_ = 0;
  Job j;
  j.reset = true;
  j.grid = grid;
  jobs_.push_back(std::move(j));
  ++stats_.resets;
  wake_.notify_one();
}

bool LiveTilePyramid::Draw(TileFrame frame) {
  std::lock_guard lock(mutex_);
  if (stop_ || jobs_.size() >= static_cast<size_t>(options_.queue_jobs)) {
    ++stats_.jobs_dropped;
    return false;
  }
  if (frame.image) {
    if (images_queued_ >= options_.queue_images)
      frame.image.reset();  // read again from frames/ when its turn comes: the queue's memory stays bounded
    else
      ++images_queued_;
  }
  jobs_.push_back(Job{false, {}, std::move(frame)});
  wake_.notify_one();
  return true;
}

void LiveTilePyramid::Drain() {
  std::unique_lock lock(mutex_);
  idle_.wait(lock, [this] { return (jobs_.empty() && !busy_) || stop_; });
}

void LiveTilePyramid::Cancel() {
  {
    std::lock_guard lock(mutex_);
    stats_.jobs_superseded += static_cast<int64_t>(jobs_.size());
    jobs_.clear();
    images_queued_ = 0;
  }
  Drain();
}

std::shared_ptr<const TileSetInfo> LiveTilePyramid::Info() const {
  std::lock_guard lock(mutex_);
  return info_;
}

LiveTileStats LiveTilePyramid::Stats() const {
  std::lock_guard lock(mutex_);
  LiveTileStats s = stats_;
  return s;
}

size_t LiveTilePyramid::queued() const {
  std::lock_guard lock(mutex_);
  return jobs_.size();
}

std::vector<LiveTilePyramid::Job> LiveTilePyramid::NextBatch() {
  std::unique_lock lock(mutex_);
  busy_ = false;
  idle_.notify_all();
  wake_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
  std::vector<Job> batch;
  if (stop_) return batch;
  while (!jobs_.empty() && batch.size() < static_cast<size_t>(std::max(1, options_.batch_jobs))) {
    if (jobs_.front().frame.image) --images_queued_;
    batch.push_back(std::move(jobs_.front()));
    jobs_.pop_front();
  }
  busy_ = true;
  return batch;
}

// Outcome bits of a job.
constexpr int kDrawnNew = 1, kDrawnAgain = 2, kReadAgain = 4;

std::shared_ptr<const TileSetInfo> LiveTilePyramid::Account(const std::vector<Job>& batch,
                                                            const std::vector<int>& outcome, bool flushed, double ms,
                                                            const std::string& error) {
  std::lock_guard lock(mutex_);
  stats_.busy_ms += ms;
  stats_.tiles_written = renderer_->tiles_written();
  stats_.write_errors = renderer_->write_errors();
  const int64_t now = MonotonicNs();
  for (size_t i = 0; i < batch.size(); ++i) {
    if ((outcome[i] & kReadAgain) != 0) ++stats_.frames_reread;
    if ((outcome[i] & kDrawnAgain) != 0) ++stats_.frames_redrawn;
    if ((outcome[i] & kDrawnNew) == 0) continue;
    ++stats_.frames_drawn;
    if (batch[i].frame.registered_ns <= 0) continue;  // a redraw on a new grid: not a latency
    if (stats_.latency_ms.size() >= 1024) stats_.latency_ms.erase(stats_.latency_ms.begin());
    stats_.latency_ms.push_back(static_cast<double>(now - batch[i].frame.registered_ns) * 1e-6);
  }
  if (!flushed) {
    // A full disk: stop drawing (what is on disk stays valid); the flight goes on without live tiles.
    spdlog::error("live tiles stopped: {}", error);
    stop_ = true;
    jobs_.clear();
    idle_.notify_all();
  }
  // A new grid is published once it has caught up (nothing queued): until then clients keep the previous one.
  const bool newer = renderer_->generation() != published_generation_;
  if (newer && !jobs_.empty() && flushed) return nullptr;
  if (newer) {
    renderer_->RemoveOlderGenerations();
    published_generation_ = renderer_->generation();
  }
  info_ = renderer_->Info(renderer_->frames());
  return info_;
}

void LiveTilePyramid::Work() {
  // Below the frame loop: the map on the ground may lag, registration must not.
  setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
  pthread_setname_np(pthread_self(), "uavm-tiles");
  int64_t last_cascade_ns = MonotonicNs();
  for (;;) {
    const std::vector<Job> batch = NextBatch();
    if (batch.empty()) return;
    const int64_t t0 = MonotonicNs();
    std::vector<int> outcome(batch.size(), 0);
    for (size_t i = 0; i < batch.size(); ++i) {
      if (batch[i].reset) {
        renderer_->Reset(batch[i].grid);
        continue;
      }
      bool redrawn = false, reread = false;
      if (renderer_->Draw(batch[i].frame, &redrawn, &reread)) outcome[i] |= redrawn ? kDrawnAgain : kDrawnNew;
      if (reread) outcome[i] |= kReadAgain;
    }
    // The coarser zooms when the queue is empty, or every cascade_every_s while it is not: every frame touches them.
    const bool due = queued() == 0 || static_cast<double>(t0 - last_cascade_ns) * 1e-9 > options_.cascade_every_s;
    if (renderer_->HasPending() && due) {
      renderer_->CascadePending();
      last_cascade_ns = MonotonicNs();
    }
    std::string error;
    const bool flushed = renderer_->Flush(&error);
    auto info = Account(batch, outcome, flushed, static_cast<double>(MonotonicNs() - t0) * 1e-6, error);
    if (info && listener_) listener_(std::move(info));
    if (!flushed) return;
  }
}

}  // namespace uavm
