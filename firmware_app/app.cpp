#include "firmware_app/app.h"

#include <spdlog/spdlog.h>

#include <memory>
#include <thread>

#include "core/pipeline/memory_budget.h"
#include "core/pipeline/mosaicker.h"
#include "core/session/session_dir.h"
#include "core/util/bounded_queue.h"
#include "core/util/clock.h"
#include "core/util/memory.h"
#include "hal/replay/replay_source.h"
#include "hal/sim/sim_source.h"

namespace uavm::app {

namespace {

std::unique_ptr<hal::FrameSource> MakeSource(const RunConfig& config, std::string* error) {
  const std::string& s = config.source;
  const auto colon = s.find(':');
  const std::string scheme = colon == std::string::npos ? "" : s.substr(0, colon);
  const std::string arg = colon == std::string::npos ? s : s.substr(colon + 1);
  if (scheme == "replay") {
    hal::ReplayOptions o;
    o.path = arg;
    o.stride = config.stride;
    return std::make_unique<hal::ReplaySource>(o);
  }
  if (scheme == "sim") {
    // A simulated flight over a real image (plan YAML: see hal/sim/sim_plan.h); frames are rendered, not decoded.
    return std::make_unique<hal::SimSource>(hal::SimOptions{arg, "", "", 0});
  }
  *error = "unknown source '" + s + "' (expected replay:PATH or sim:PLAN.yaml)";
  return nullptr;
}

// One captured item: a frame, or the record of an input the source skipped.
struct Item {
  hal::Status status = hal::Status::kOk;
  std::string name;
  std::string message;
  Mosaicker::Prepared prepared;
};

}  // namespace

int Run(const RunConfig& config) {
  std::string error;
  auto source = MakeSource(config, &error);
  if (!source) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  if (source->Open(&error) != hal::Status::kOk) {
    spdlog::error("cannot open source: {}", error);
    return kExitSourceError;
  }
  SessionPaths paths;
  if (!PrepareSessionDir(config.out_dir, &paths, &error)) {
    spdlog::error("{}", error);
    return kExitOutputError;
  }
  // Decode no more than the working resolution needs (JPEG DCT scaling); the compositor re-reads at its own scale.
  source->SetDecodeHint({config.pipeline.work_long_side});
  spdlog::info("source {}, output {}", source->Describe(), config.out_dir);

  // The budget sizes caches, pools and the detector's bands; the plan is for the working frame's usual 4:3 shape
  // (the detector adapts its bands to each frame's real size).
  PipelineOptions pipeline = config.pipeline;
  MemoryPlan plan;
  if (!ApplyMemoryBudget(pipeline.work_long_side, pipeline.work_long_side * 3 / 4, &pipeline, &plan, &error)) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  if (plan.budget_mib > 0)
    spdlog::info(
        "memory budget {:.0f} MiB: flight ~{:.0f} MiB (detector {:.0f} MiB in {} band(s), queue {}, feature cache "
        "{:.0f}, relocalisation {:.0f}), end ~{:.0f} MiB (image cache {:.0f}, blending {:.0f}, tile {})",
        plan.budget_mib, plan.FlightMiB(), plan.sift_mib, plan.sift_bands, plan.queue_capacity, plan.feature_cache_mib,
        plan.relocalization_mib, plan.EndMiB(), plan.image_cache_mib, plan.blend_mib, pipeline.mosaic.tile_size);
  Mosaicker mosaicker(pipeline, paths);
  mosaicker.SetMemoryPlan(plan);
  BoundedQueue<Item> queue(
      static_cast<size_t>(pipeline.queue_capacity),
      source->IsReplay() ? BoundedQueue<Item>::Policy::kBlock : BoundedQueue<Item>::Policy::kDropOldest);
  bool source_failed = false;
  std::string source_error;
  std::thread capture([&] {
    int delivered = 0;
    for (;;) {
      if (config.max_frames > 0 && delivered >= config.max_frames) break;
      Item item;
      std::string err;
      hal::Frame frame;
      StageTimer decode_timer;
      item.status = source->Next(&frame, &err);
      const double decode_ms = decode_timer.ElapsedMs();
      item.name = frame.source_name;
      if (item.status == hal::Status::kEndOfStream) break;
      if (item.status == hal::Status::kError) {
        source_failed = true;
        source_error = err;
        break;
      }
      item.message = err;
      if (item.status == hal::Status::kOk) {
        ++delivered;
        // Features are computed here, on the capture side, overlapping the previous frame's matching.
        try {
          item.prepared = mosaicker.Prepare(std::move(frame));
          item.prepared.decode_ms = decode_ms;
        } catch (const std::exception& e) {
          // An input OpenCV cannot process (e.g. a degenerate size) is skipped like a corrupt file, never fatal.
          item.status = hal::Status::kSkipped;
          item.message = std::string("cannot process frame: ") + e.what();
        }
      }
      if (!queue.Push(std::move(item))) break;
    }
    queue.Close();
  });

  while (auto item = queue.Pop()) {
    if (item->status == hal::Status::kSkipped) {
      mosaicker.RecordSkipped(item->name, item->message);
      continue;
    }
    try {
      const auto outcome = mosaicker.AddFrame(std::move(item->prepared));
      (void)outcome;
    } catch (const std::exception& e) {
      spdlog::error("frame {} could not be registered: {}", item->name, e.what());
    }
    const auto& stats = mosaicker.stage_stats();
    if (mosaicker.frames_in() % 10 == 0)
      spdlog::info("{} frames, median {:.0f} ms/frame, RSS {:.0f} MiB", mosaicker.frames_in(),
                   stats.Get("frame_total").median, CurrentRssMiB());
  }
  capture.join();
  source->Close();
  mosaicker.RecordDropped(queue.dropped());
  if (source_failed) spdlog::error("source stopped: {} (finishing with what was received)", source_error);

  if (!mosaicker.Finish(&error)) {
    spdlog::error("cannot write the session (output not writable or disk full): {}", error);
    return kExitOutputError;
  }
  spdlog::info("done: {}/{} registered, residual RMS {:.2f} px, peak RSS {:.0f} MiB", mosaicker.registered_count(),
               mosaicker.frames_in(), mosaicker.residual_rms_px(), PeakRssMiB());
  if (mosaicker.registered_count() == 0) return kExitNothingRegistered;
  return source_failed ? kExitSourceError : kExitOk;
}

}  // namespace uavm::app
