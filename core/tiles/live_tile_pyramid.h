#pragma once
// The growing map as a tile pyramid on disk during the flight (what the live HTTP server hands to ground stations):
// 256x256 RGBA PNG tiles at max_zoom and every coarser zoom down to min_zoom. Each registered frame is drawn into the
// max_zoom tiles it touches (newest on top, feathered at its border: a fast live blend; the end-of-flight multi-band
// mosaic stays the product), then their parents are rebuilt up to min_zoom. A frame that a solve moved is drawn
// again: the tiles of its old and new places are re-rendered from every frame that touches them (read back from the
// session's frames/). All of it runs on one low-priority worker thread behind a bounded job queue: the frame loop
// only enqueues and never waits.
//
// Memory is fixed by the options: `cache_tiles` decoded tiles (256 KiB each), `frame_cache` decoded frames and at
// most `queue_images` frames waiting with their pixels; per drawn frame a small record (its transform and tiles,
// ~100 B + 4 B per max_zoom tile it touches).
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>
#include <thread>
#include <vector>

#include "core/geometry/transform.h"
#include "core/tiles/tile_set.h"

namespace uavm {

struct LiveTileOptions {
  bool enabled = false;     // the onboard program turns it on with --http unless the configuration says no
  int cache_tiles = 64;     // decoded tiles kept (256 KiB each)
  int frame_cache = 4;      // decoded frames kept for re-rendering (work resolution)
  int queue_images = 3;     // frames waiting with their pixels; later ones are read again from frames/
  int queue_jobs = 16384;   // jobs waiting (~200 B each; a new grid queues the whole flight); past it, dropped, counted
  int feather_px = 16;      // the blend ramp at a frame's border, work pixels
  int png_compression = 1;  // zlib level: fast (tiles are re-written often during the flight; ~7 ms a tile at 1)
  int batch_jobs = 8;       // queued frames drawn before their tiles are written (shared tiles written once)
  double cascade_every_s = 2.0;  // coarser zooms rebuilt at most this often while frames wait (always when idle)
  int levels = 8;                // zooms below max_zoom kept (min_zoom = max_zoom - levels, >= 0)
  double redraw_shift_px = 2.0;  // a moved frame is drawn again when a corner moved more (max_zoom pixels)
  // The onboard program starts the pyramid again (every frame drawn anew) when a new live georeference moves the
  // drawn map by more than this; smaller refits keep the tiles where they are (GPS noise, not the map, moved).
  double refit_shift_m = 3.0;
  [[nodiscard]] bool Check(std::string* why) const;
};

// A grid: web-mercator XYZ (geographic) or a local pyramid; the frames' transforms are to max_zoom pixels.
struct TileGrid {
  bool geographic = false;
  int max_zoom = 0;
  int min_zoom = 0;
};

// A frame to draw: a newly registered one (with its pixels) or a moved one (pixels null: read again from `path`).
struct TileFrame {
  int id = -1;
  std::string path;  // the stored frame (frames/...), read back for re-rendering
  cv::Size work_size;
  Mat3 grid_from_work = Mat3::Identity();  // work pixel centres -> max_zoom global pixels (corners at integers)
  std::shared_ptr<const cv::Mat> image;    // work-resolution BGR, or null
  int decode_reduce = 1;                   // JPEG DCT scaling (1, 2, 4, 8) that reads `path` no smaller than work size
  int64_t registered_ns = 0;               // monotonic: when the frame loop registered it (tile latency); 0: a redraw
  double heading = 0.0;  // the frame's rotation into the mosaic, handed to the reader (whose shading turns with it)
};

struct LiveTileStats {
  int64_t frames_drawn = 0;
  int64_t frames_redrawn = 0;
  int64_t frames_reread = 0;  // decoded again from frames/ (moved, or queued without pixels)
  int64_t resets = 0;
  int64_t tiles_written = 0;
  int64_t jobs_dropped = 0;
  int64_t jobs_superseded = 0;  // dropped by Cancel()
  int64_t write_errors = 0;
  double busy_ms = 0;
  std::vector<double> latency_ms;  // registered -> its tiles on disk, the newest 1024 frames
};

class LiveTilePyramid {
 public:
  // Reads a stored frame at its work size (BGR), as drawn (e.g. its radiometry corrected: TileFrame's id and heading);
  // called on the worker thread, must be thread-safe.
  using FrameReader =
      std::function<cv::Mat(int id, const std::string& path, cv::Size work_size, int decode_reduce, double heading)>;
  // Called on the worker thread after each batch of tiles is on disk; must not block.
  using Listener = std::function<void(std::shared_ptr<const TileSetInfo>)>;

  LiveTilePyramid(std::string dir, const LiveTileOptions& options, FrameReader reader, Listener listener);
  ~LiveTilePyramid();
  LiveTilePyramid(const LiveTilePyramid&) = delete;
  LiveTilePyramid& operator=(const LiveTilePyramid&) = delete;

  // A new grid (the first georeference, a new one, another piece of the flight): generation + 1, drawn in a directory
  // of its own (DIR/<generation>/z/x/y.png) and published once it has caught up with the queue; the previous grid's
  // tiles stay served until then and are removed afterwards. The caller then draws the frames again.
  void Reset(const TileGrid& grid);
  // Never blocks. False when the job was dropped (queue full, or the pyramid stopped on a write error).
  [[nodiscard]] bool Draw(TileFrame frame);
  // Waits until every queued job is done (end of flight, tests).
  void Drain();
  // Drops what waits (counted in jobs_superseded) and waits for the batch being drawn: at the end of a flight whose
  // final tiles will replace the live ones, the backlog would only compete with the final solve and compositing.
  void Cancel();
  [[nodiscard]] std::shared_ptr<const TileSetInfo> Info() const;
  [[nodiscard]] LiveTileStats Stats() const;
  [[nodiscard]] size_t queued() const;

 private:
  struct Job {
    bool reset = false;
    TileGrid grid;
    TileFrame frame;
  };
  [[nodiscard]] std::vector<Job> NextBatch();  // blocks until jobs come; empty when stopping
  // Counts the batch; returns the tile set to publish (null while a new grid is still catching up).
  [[nodiscard]] std::shared_ptr<const TileSetInfo> Account(const std::vector<Job>& batch,
                                                           const std::vector<int>& outcome, bool flushed, double ms,
                                                           const std::string& error);
  class Renderer;
  void Work();

  LiveTileOptions options_;
  Listener listener_;
  std::unique_ptr<Renderer> renderer_;  // touched by the worker only
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<Job> jobs_;
  int images_queued_ = 0;
  bool busy_ = false;
  bool stop_ = false;
  std::shared_ptr<const TileSetInfo> info_;
  int64_t published_generation_ = -1;
  LiveTileStats stats_;
  std::thread worker_;
};

}  // namespace uavm
