#include "core/pipeline/resource_log.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "core/buffers/mat_pool.h"
#include "core/util/memory.h"

namespace uavm {

void ResourceLog::FlightStart() {
  fds_at_start_ = OpenFileDescriptors();
  watch_.Enter("flight");
}

void ResourceLog::FlightEnd() {
  FlushMatPool();  // the flight's pooled detector buffers: the solves start without them
  flight_end_rss_mib_ = CurrentRssMiB();
  flight_end_heap_ = CurrentHeapStats();
  flight_end_arena_ = RecordArena::counters();
  fds_at_flight_end_ = OpenFileDescriptors();
}

namespace {

// The end's solves, whose blocks come and go a solve at a time. Not `end_match`, `lens` and `radiometry`: they load,
// decode or match frames as the flight does (the lens rematches its window's edges), and mapping each of their buffers
// cost `radiometry` 5 -> 12.6 s at 5000 frames.
bool IsEndSolve(const std::string& phase) {
  for (const char* solve : {"end_load", "adjust", "refine"})
    if (phase == solve) return true;
  return false;
}

}  // namespace

void ResourceLog::EnterPhase(const std::string& name) {
  // The pool may keep free blocks up to the in-use peak since its last flush: without a flush here, blocks an earlier
  // phase freed stayed resident through the next ones, however little those used.
  if (const MatPool* pool = InstalledMatPool()) {
    const MatPoolStats s = pool->Stats();
    spdlog::debug("phase {}: image pool gives back {:.1f} MiB of free blocks ({:.1f} MiB in use)", name,
                  static_cast<double>(s.pooled_bytes) / kMiB, static_cast<double>(s.in_use_bytes) / kMiB);
  }
  FlushMatPool();
  TrimHeap();  // first: a block the trimmed arena cannot serve is mapped
  SetMmapThreshold(IsEndSolve(name) ? kEndSolvesMmapThreshold : kFlightMmapThreshold);
  watch_.Enter(name);
}

void ResourceLog::ComposeEnd() {
  FlushMatPool();  // the compositor's pooled buffers: the products phase has its own
}

namespace {

nlohmann::json MatPoolJson() {
  const MatPool* pool = InstalledMatPool();
  if (pool == nullptr) return nullptr;
  const MatPoolStats s = pool->Stats();
  return {{"hits", s.hits},
          {"misses", s.misses},
          {"evictions", s.evictions},
          {"peak_pooled_mib", static_cast<double>(s.peak_pooled_bytes) / kMiB}};
}

}  // namespace

nlohmann::json ResourceLog::FdsJson() const {
  return {{"flight_start", fds_at_start_}, {"flight_end", fds_at_flight_end_}};
}

nlohmann::json ResourceLog::MemoryJson(const MemoryPlan& mp) const {
  nlohmann::json phases = nlohmann::json::array();
  nlohmann::json phase_peak = nlohmann::json::object();
  double end_peak = 0;
  for (const PhaseMemory& p : watch_.Phases()) {
    phases.push_back({{"phase", p.name},
                      {"peak_rss_mib", p.peak_rss_mib},
                      {"peak_anon_mib", p.peak_anon_mib},
                      {"seconds", p.seconds},
                      {"heap_in_use_at_start_mib", p.heap_at_start.in_use_mib},
                      {"heap_arena_at_start_mib", p.heap_at_start.arena_mib}});
    phase_peak[p.name] = p.peak_rss_mib;
    if (p.name != "flight") end_peak = std::max(end_peak, p.peak_rss_mib);
  }
  return {{"budget_mib", mp.budget_mib},
          // The run's peak over every phase: VmHWM, never reset (what ru_maxrss and /usr/bin/time read as well).
          {"peak_rss_mib", watch_.PeakRssMiB()},
          // Each phase's own peak, sampled (see MemoryWatch), in the order the phases ran.
          {"phases", phases},
          {"phase_peak_rss_mib", phase_peak},
          {"end_peak_rss_mib", end_peak},
          {"flight_end_rss_mib", flight_end_rss_mib_},
          {"flight_end_heap",
           {{"in_use_mib", flight_end_heap_.in_use_mib},
            {"arena_mib", flight_end_heap_.arena_mib},
            {"mmapped_mib", flight_end_heap_.mmapped_mib}}},
          // The small records the flight keeps to its end, on pages of their own (RecordArena): whether those are a
          // file's (reclaimable) or anonymous memory, what its runs hold resident at most, what is in use, and the
          // blocks that went to malloc because its range (or the disk) was full.
          {"flight_end_record_arena",
           {{"file_backed", flight_end_arena_.file_backed},
            {"carved_mib", static_cast<double>(flight_end_arena_.carved_bytes) / kMiB},
            {"in_use_mib", static_cast<double>(flight_end_arena_.in_use_bytes) / kMiB},
            {"blocks", flight_end_arena_.blocks_in_use},
            {"fallbacks", flight_end_arena_.fallbacks}}},
          {"mat_pool", MatPoolJson()},
          {"plan_flight_mib", mp.FlightMiB()},
          {"plan_end_mib", mp.EndMiB()},
          {"plan",
           {{"baseline_mib", mp.baseline_mib},
            {"graph_mib", mp.graph_mib},
            {"frames_reserved", mp.frames_reserved},
            {"sift_mib", mp.sift_mib},
            {"sift_bands", mp.sift_bands},
            {"queue_mib", mp.queue_mib},
            {"queue_capacity", mp.queue_capacity},
            {"feature_cache_mib", mp.feature_cache_mib},
            {"relocalization_mib", mp.relocalization_mib},
            {"relocalization_descriptors", mp.relocalization_descriptors},
            {"subpixel_mib", mp.subpixel_mib},
            {"subpixel_frames", mp.subpixel_frames},
            {"live_tiles_mib", mp.live_tiles_mib},
            {"refine_mib", mp.refine_mib},
            {"refine_correspondences", mp.refine_correspondences},
            {"end_points_mib", mp.end_points_mib},
            {"end_correspondences", mp.end_correspondences},
            {"residue_mib", mp.residue_mib},
            {"image_cache_mib", mp.image_cache_mib},
            {"blend_mib", mp.blend_mib},
            {"gdal_cache_mib", mp.gdal_cache_mib}}}};
}

}  // namespace uavm
