#pragma once
#include <string>

#include "core/pipeline/options.h"

namespace uavm {

// How a memory budget is spent. The flight and the end of the flight do not overlap in time, so each has the whole
// budget minus what lives through both (the process itself, the match graph):
//   flight: baseline + SIFT scale space + frames in the queue + feature cache + relocalisation index + graph
//           + the sub-pixel refinement's grey images
//   end:    baseline + graph + what the flight leaves + max(refinement solver, compositor: frame pixels (one load,
//           decoded-frame cache) + tile blenders + TIFF writer; the quick-look is made on disk)
// The compositor refits its frame pixels and workers to the real frame and canvas sizes (FitCompositorMemory).
// Every figure is MiB. Estimates come from the sizes of the buffers involved; the benchmark measures the outcome.
struct MemoryPlan {
  double budget_mib = 0;
  double baseline_mib = 0;  // code, shared libraries, thread stacks, allocator slack
  double graph_mib = 0;     // match graph and per-frame state, reserved for max_flight_frames
  int frames_reserved = 0;  // the flight length graph_mib covers (max_flight_frames, or fewer on a small budget)
  // Flight.
  double sift_mib = 0;  // per band
  int sift_bands = 1;
  double queue_mib = 0;
  int queue_capacity = 0;
  double feature_cache_mib = 0;
  double relocalization_mib = 0;
  int relocalization_descriptors = 0;
  double subpixel_mib = 0;  // grey working images kept for the sub-pixel refinement
  int subpixel_frames = 0;
  double live_tiles_mib = 0;  // the live tile pyramid (flight and end: its worker lives until the final tiles)
  // End of flight.
  double refine_mib = 0;
  int refine_correspondences = 0;
  double end_points_mib = 0;  // the edges' points the end's solves hold (a share of each edge's beyond the cap)
  int end_correspondences = 0;
  double residue_mib = 0;      // resident after the flight beyond baseline and graph (heap the flight leaves)
  double image_cache_mib = 0;  // all frame pixels of the compositor
  double blend_mib = 0;
  double gdal_cache_mib = 0;  // the TIFF writer: GDAL's cache and its overhead

  [[nodiscard]] double FlightMiB() const;
  [[nodiscard]] double EndMiB() const;
};

// The live tile pyramid's fixed memory (core/tiles/live_tile_pyramid.h): its tile cache, decoded and queued frames.
[[nodiscard]] double LiveTilesMiB(const LiveTileOptions& o, int work_width, int work_height);

// Per-frame working memory of a width x height working frame in the queue (colour + grey copies, float descriptors).
[[nodiscard]] double QueuedFrameMiB(int work_width, int work_height, int max_features);

// Fits the caches and pools of `options` into options->memory_budget_mib (0 = no budget: nothing is changed and the
// plan only describes the configured sizes). `work_width` x `work_height` is the expected working frame size.
// Fails with a reason when even the smallest configuration does not fit.
[[nodiscard]] bool ApplyMemoryBudget(int work_width, int work_height, PipelineOptions* options, MemoryPlan* plan,
                                     std::string* why);

}  // namespace uavm
