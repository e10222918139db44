#include "core/pipeline/memory_budget.h"

#include <algorithm>
#include <cmath>

#include "core/util/memory.h"

namespace uavm {

namespace {

// Measured on x86-64 Debian 12 (bench/memory.sh): the onboard program with its libraries loaded and its threads
// started, before the first frame.
constexpr double kBaselineMiB = 72.0;
// Per-frame state that lives through the flight and its end (edge records without their points, frame records,
// maps, footprints, index entries) with the heap it fragments: the resident set at the flight's end grew by 6.2 KiB per
// frame from 200 to 5000 frames (bench/memory.sh, sim_memory.yaml). Reserved for max_flight_frames. The small records
// among it are file pages where the session is on a disk (RecordArena::BackWithFile): resident, so counted here, but
// reclaimable under a memory limit.
constexpr double kGraphBytesPerFrame = 6.5 * 1024;
// Relocalisation index per descriptor, as reserved: its 8-bit row (128 B), its frame records (12) and the kd-forest
// (80: global_index_test) take ~220. The figure stays at the 800 the detector's cap was tuned with (a float copy and
// cvflann's trees): lowering it would give the detector more room, fewer bands where the budget binds (when it was
// OpenCV's: sim frames 3 -> 2, +26 MiB of scale space) and move keypoints. The ~11 MiB it leaves at 256 MiB are the
// flight's headroom for transients the plan does not list (the flight's measured peak is ~13 MiB above its plan:
// bench/memory.sh).
constexpr double kBytesPerIndexedDescriptor = 800;
// What the flight leaves resident beyond the baseline and the graph when it ends (arena pages malloc_trim cannot
// return, state OpenCV, GDAL and Ceres built on first use): measured 102-112 MiB at the end of the solves on the
// bundled 12 MP flights and their 8-12 MP resizes, whatever the frame size. The compositor measures it again.
constexpr double kFlightResidueMiB = 20.0;
// Ceres per correspondence: residual block, cost functor, Jacobian blocks and their compressed-row copy. This is the
// factorisation's (up to refine.max_frames_per_solve frames); beyond, the iterative solve (core/adjust/tree_lm) holds
// no per-correspondence state, only per-frame and per-edge blocks (their figure is stated once, in tree_lm.h): below
// this line up to ~35 000 frames at the default cap.
constexpr double kBytesPerSolverCorrespondence = 1100;
// An edge's point pair held by the end's solves (two float 2-vectors), with its share of held-out pairs (a quarter).
constexpr double kBytesPerEndPoint = 16 * 1.25;
double BlendMiB(const CompositorOptions& m) {
  return m.threads * m.BlendMiBPerWorker();
}

double FeatureSetMiB(int max_features) {
  return max_features * (128 * 4 + 8) / kMiB;
}

}  // namespace

double MemoryPlan::FlightMiB() const {
  return baseline_mib + graph_mib + sift_mib + queue_mib + feature_cache_mib + relocalization_mib + subpixel_mib +
         live_tiles_mib;
}

double MemoryPlan::EndMiB() const {
  return baseline_mib + graph_mib + residue_mib + live_tiles_mib +
         std::max(end_points_mib + refine_mib, image_cache_mib + blend_mib + gdal_cache_mib);
}

double LiveTilesMiB(const LiveTileOptions& o, int work_width, int work_height) {
  if (!o.enabled) return 0;
  const double tile = 256.0 * 256 * 4 / kMiB;
  // A decoded frame: colour (3 B/px) plus its share of the blend weight; a tile write's PNG buffer; the children of a
  // parent being rebuilt; per-frame records (bounded by the flight, counted in the graph's reserve).
  const double frame = static_cast<double>(work_width) * work_height * 3 / kMiB;
  return o.cache_tiles * tile + (o.frame_cache + o.queue_images) * frame + 6 * tile;
}

double QueuedFrameMiB(int work_width, int work_height, int max_features) {
  return static_cast<double>(work_width) * work_height * 4 / kMiB + FeatureSetMiB(max_features);
}

namespace {

// The per-frame state's line: max_flight_frames of it, at most 15 % of the budget (a small budget covers a shorter
// flight: frames_reserved).
void ReserveFrameState(const PipelineOptions& o, MemoryPlan* p) {
  p->graph_mib = std::min(std::max(0, o.max_flight_frames) * kGraphBytesPerFrame / kMiB,
                          o.memory_budget_mib > 0 ? 0.15 * o.memory_budget_mib : HUGE_VAL);
  p->frames_reserved = static_cast<int>(p->graph_mib * kMiB / kGraphBytesPerFrame);
}

double IndexMiB(int descriptors) {
  return descriptors * kBytesPerIndexedDescriptor / kMiB;
}

double GrayMiB(int work_width, int work_height) {
  return static_cast<double>(work_width) * work_height / kMiB;
}

// SIFT's input: the working frame, or its half-size copy (features.half_size).
cv::Size SiftInput(int work_width, int work_height, const FeatureOptions& f) {
  if (!f.half_size || std::min(work_width, work_height) < 64) return {work_width, work_height};
  return {(work_width + 1) / 2, (work_height + 1) / 2};
}

// The plan of a run without a budget: each cache as configured.
MemoryPlan DescribeUnbudgeted(const PipelineOptions& o, int work_width, int work_height, MemoryPlan p,
                              double queue_mib) {
  p.queue_capacity = o.queue_capacity;
  p.queue_mib = queue_mib;
  const cv::Size sift = SiftInput(work_width, work_height, o.features);
  p.sift_bands = SiftBands(sift.width, sift.height, o.features);
  p.sift_mib = SiftScaleSpaceMiB(sift.width, sift.height, o.features) / p.sift_bands;
  p.feature_cache_mib = o.feature_cache_mib;
  p.subpixel_frames = o.subpixel.enabled ? o.subpixel.cache_frames : 0;
  p.subpixel_mib = p.subpixel_frames * GrayMiB(work_width, work_height);
  p.relocalization_descriptors = o.relocalization.max_descriptors;
  p.relocalization_mib = IndexMiB(o.relocalization.max_descriptors);
  p.refine_correspondences = o.refine.max_correspondences;
  p.refine_mib = o.refine.max_correspondences * kBytesPerSolverCorrespondence / kMiB;
  p.end_correspondences = o.end_correspondences;
  p.end_points_mib = o.end_correspondences * kBytesPerEndPoint / kMiB;
  p.live_tiles_mib = LiveTilesMiB(o.live_tiles, work_width, work_height);
  p.image_cache_mib = static_cast<double>(o.mosaic.image_cache_bytes) / kMiB;
  p.blend_mib = BlendMiB(o.mosaic);
  p.gdal_cache_mib = o.mosaic.WriterMiB();
  p.residue_mib = kFlightResidueMiB;
  return p;
}

}  // namespace

bool ApplyMemoryBudget(int work_width, int work_height, PipelineOptions* options, MemoryPlan* plan, std::string* why) {
  PipelineOptions& o = *options;
  MemoryPlan p;
  p.budget_mib = o.memory_budget_mib;
  p.baseline_mib = kBaselineMiB;
  ReserveFrameState(o, &p);
  const double frame_mib = QueuedFrameMiB(work_width, work_height, o.features.max_features);
  // Besides the queue, frames in flight: one being loaded, one waiting for detection, one being detected and one
  // being registered.
  const auto queue_mib = [&](int capacity) { return (capacity + 4) * frame_mib; };

  if (o.memory_budget_mib <= 0) {  // no budget: describe the configuration as it is
    *plan = DescribeUnbudgeted(o, work_width, work_height, p, queue_mib(o.queue_capacity));
    return true;
  }

  const double budget = o.memory_budget_mib;
  p.live_tiles_mib = LiveTilesMiB(o.live_tiles, work_width, work_height);
  const double avail = budget - p.baseline_mib - p.graph_mib - p.live_tiles_mib;
  const auto fail = [&](const std::string& msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (avail < 48)
    return fail("memory_budget_mib " + std::to_string(o.memory_budget_mib) + " is below the minimum of " +
                std::to_string(static_cast<int>(std::ceil(p.baseline_mib + p.graph_mib + 48))) + " MiB");

  // Flight. A small budget queues fewer frames: capture then waits (replay) or drops the oldest (camera).
  p.queue_capacity = budget >= 512 ? o.queue_capacity : std::min(o.queue_capacity, 2);
  p.queue_mib = queue_mib(p.queue_capacity);
  p.relocalization_descriptors =
      std::min(o.relocalization.max_descriptors,
               std::max(4096, static_cast<int>(0.06 * budget * kMiB / kBytesPerIndexedDescriptor)));
  p.relocalization_mib = IndexMiB(p.relocalization_descriptors);
  // Candidates (K recent + M overlapping + relocalisation) need a dozen feature sets; the rest reloads from disk.
  p.feature_cache_mib =
      std::min<double>(o.feature_cache_mib, std::max(12.0 * FeatureSetMiB(o.features.max_features), 0.1 * budget));
  // The sub-pixel refinement's images: the newest frames (candidates are mostly recent), at most 6 % of the budget.
  if (o.subpixel.enabled) {
    const int fit = static_cast<int>(0.06 * budget / GrayMiB(work_width, work_height));
    p.subpixel_frames = std::clamp(fit, 2, o.subpixel.cache_frames);
    p.subpixel_mib = p.subpixel_frames * GrayMiB(work_width, work_height);
  }
  const cv::Size sift = SiftInput(work_width, work_height, o.features);
  const double smallest_band = SiftScaleSpaceMiB(sift.width, 2 * o.features.band_margin + 32, o.features);
  // No slack is taken from the detector: a 4 % slack turned caliterra-sized frames' 3 bands into 4, which moved
  // keypoints and cost brighton_beach's held-out RMS 0.98 -> 1.21 px, for no measurable drop of the flight's peak
  // (what held the 5000-frame flight within the budget was trimming the heap after every frame).
  const double sift_cap = avail - p.queue_mib - p.relocalization_mib - p.feature_cache_mib - p.subpixel_mib;
  if (sift_cap < smallest_band)
    return fail("memory_budget_mib " + std::to_string(o.memory_budget_mib) + " leaves " +
                std::to_string(static_cast<int>(sift_cap)) + " MiB for feature detection on " +
                std::to_string(work_width) + "x" + std::to_string(work_height) +
                " working frames; raise the budget or lower work_long_side");
  FeatureOptions features = o.features;
  features.max_scale_space_mib = static_cast<int>(std::floor(sift_cap));
  if (o.features.max_scale_space_mib > 0)
    features.max_scale_space_mib = std::min(features.max_scale_space_mib, o.features.max_scale_space_mib);
  p.sift_bands = SiftBands(sift.width, sift.height, features);
  const int band_rows =
      (sift.height + p.sift_bands - 1) / p.sift_bands + (p.sift_bands > 1 ? 2 * features.band_margin : 0);
  p.sift_mib = SiftScaleSpaceMiB(sift.width, std::min(sift.height, band_rows), features);

  // End of flight: what the flight leaves, then the TIFF writer, the tile workers and frame pixels (one load, the
  // cache; the quick-look is made on disk). The plan cannot know the frames' size (the compositor loads them at the
  // canvas's scale): the compositor fits its pixels into what is left when it starts, dropping a worker for frames too
  // large.
  p.residue_mib = kFlightResidueMiB;
  CompositorOptions mosaic = o.mosaic;
  mosaic.gdal_cache_mib =
      static_cast<int>(std::floor(std::clamp(0.05 * budget, 4.0, static_cast<double>(o.mosaic.gdal_cache_mib))));
  mosaic.memory_budget_mib = o.memory_budget_mib;
  p.gdal_cache_mib = mosaic.WriterMiB();
  const double end_avail = avail - p.residue_mib - p.gdal_cache_mib;
  // Workers get at most half of it: frame pixels need a load and a cached frame per worker (the quick-look is made
  // on disk).
  while (BlendMiB(mosaic) > 0.5 * end_avail && mosaic.tile_size > mosaic.tiff_block) mosaic.tile_size /= 2;
  while (BlendMiB(mosaic) > 0.5 * end_avail && mosaic.threads > 1) --mosaic.threads;
  p.blend_mib = BlendMiB(mosaic);
  p.image_cache_mib = std::min(static_cast<double>(o.mosaic.image_cache_bytes) / kMiB, end_avail - p.blend_mib);
  if (p.image_cache_mib < 8)
    return fail("memory_budget_mib " + std::to_string(o.memory_budget_mib) + " leaves no room for the compositor");
  p.refine_correspondences =
      std::min(o.refine.max_correspondences,
               std::max(1000, static_cast<int>(0.8 * (avail - p.residue_mib) * kMiB / kBytesPerSolverCorrespondence)));
  p.refine_mib = p.refine_correspondences * kBytesPerSolverCorrespondence / kMiB;
  // The edges' points at the end: 2 % of the budget (~260 000 at 256 MiB: every point of a ~1000-frame flight).
  p.end_correspondences = std::min(o.end_correspondences > 0 ? o.end_correspondences : INT32_MAX,
                                   static_cast<int>(0.02 * budget * kMiB / kBytesPerEndPoint));
  p.end_points_mib = p.end_correspondences * kBytesPerEndPoint / kMiB;

  o.queue_capacity = p.queue_capacity;
  o.relocalization.max_descriptors = p.relocalization_descriptors;
  o.feature_cache_mib = static_cast<int>(std::floor(p.feature_cache_mib));
  o.features = features;
  if (o.subpixel.enabled) o.subpixel.cache_frames = p.subpixel_frames;
  // image_cache_bytes stays the configured cap: the compositor measures what the flight left and fits its frame
  // pixels into the rest of the budget, so the plan's figure (which assumes kFlightResidueMiB) is only a forecast.
  o.mosaic = mosaic;
  o.refine.max_correspondences = p.refine_correspondences;
  o.end_correspondences = p.end_correspondences;
  *plan = p;
  return true;
}

}  // namespace uavm
