#pragma once
#include <string>
#include <vector>

#include "core/adjust/affine_adjuster.h"
#include "core/adjust/global_refiner.h"
#include "core/features/sift.h"
#include "core/georef/georef.h"
#include "core/georef/products.h"
#include "core/georef/telemetry_bridge.h"
#include "core/lens/camera_setup.h"
#include "core/matching/global_index.h"
#include "core/matching/pair_matcher.h"
#include "core/mosaic/compositor.h"
#include "core/radiometry/radiometry.h"
#include "core/registration/registration_engine.h"
#include "core/tiles/live_tile_pyramid.h"

namespace uavm {

// The onboard program's options: the registration engine's (a base, so that its YAML keys and defaults are
// defined once) and what the session, preview, compositor and products take.
struct PipelineOptions : RegistrationOptions {
  int work_long_side = 1000;   // working resolution for features and registration (never upscaled)
  int journal_sync_every = 1;  // accepted frames between fdatasyncs of journal.jsonl (a power cut loses fewer)
  // Frames between returns of free heap pages to the kernel (malloc_trim); 0 = never. Every frame: the resident set
  // between frames of a 2000-frame flight 219 MiB instead of 236 every 5 frames (bench/memory.sh's flight), for ~1 ms.
  int trim_heap_every = 1;
  int preview_every = 5;  // live.jpg every N frames; 0 = off
  int preview_side = 1024;
  double mosaic_scale = 0.5;    // mosaic.tif GSD relative to the reference frame's original resolution
  int max_canvas_side = 60000;  // guards against a runaway transform making a giant canvas
  // Memory budget of the whole program, MiB: caches, pools and the feature detector's bands are sized to fit it
  // (core/pipeline/memory_budget.h); 0 = no budget, every cache takes its own setting.
  int memory_budget_mib = 256;
  // Frames whose per-frame state (graph edges, records, maps, footprints) the memory plan reserves room for: the
  // flight's caches are sized after it (53 min at 1 frame/s; 20 MiB). A larger reserve is taken from the detector's
  // share, which splits 1000 px working frames into more bands and moves their keypoints: at 6000 frames
  // brighton_beach's held-out RMS went from 0.98 to 1.21 px.
  int max_flight_frames = 3150;
  int feature_cache_mib = 192;
  int queue_capacity = 4;
  bool write_tiff = true;

  FeatureOptions features;
  // (matching, relocalization, adjust and refine are the engine's; refine's `model` is a top-level key.)
  CompositorOptions mosaic;
  // The lens the frames are undistorted with (configured, or looked up in lensfun's database by EXIF); the end of
  // the flight calibrates it (camera.self_calibrate, the engine's lens_calibration).
  CameraOptions camera;
  // Per-frame gains and the lens's vignetting, estimated from the overlaps and removed before blending.
  RadiometryOptions radiometry;
  // Georeferencing from EXIF GPS and the map products (COG, KMZ, web tiles, index.html): core/georef.
  GeorefOptions georef;
  // Frames and pieces no image links, placed by their position, height and heading (core/georef/telemetry_bridge).
  BridgeOptions bridge;
  bool write_products = true;  // mosaic.kmz, tiles/, index.html (mosaic.tif is a COG whenever it is written)
  TileOptions tiles;
  // The live tile pyramid (core/tiles): on with --http (unless --no-live-tiles) or live_tiles.enabled.
  LiveTileOptions live_tiles;
  std::string leaflet_dir = "/usr/share/javascript/leaflet";  // Debian's libjs-leaflet, copied into the session

  [[nodiscard]] bool Check(std::string* why) const;
};

// YAML config: keys as in ToYaml(); unknown keys are an error (a typo must not be silently ignored), except in
// `sections_read_elsewhere`, whose keys another unit reads and checks (the program's `telemetry:` is hal's).
[[nodiscard]] bool LoadOptionsYaml(const std::string& path, PipelineOptions* options, std::string* error,
                                   const std::vector<std::string>& sections_read_elsewhere = {});
// The same from YAML text; `origin` names it in messages (e.g. the file it came from).
[[nodiscard]] bool ParseOptionsYaml(const std::string& text, const std::string& origin, PipelineOptions* options,
                                    std::string* error, const std::vector<std::string>& sections_read_elsewhere = {});
[[nodiscard]] std::string ToYaml(const PipelineOptions& options);

}  // namespace uavm
