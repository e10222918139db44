#include "firmware_app/app.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <thread>
#include <unordered_set>

#include "core/pipeline/memory_budget.h"
#include "core/pipeline/mosaicker.h"
#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "core/util/bounded_queue.h"
#include "core/util/clock.h"
#include "core/util/memory.h"
#include "firmware_app/live_server.h"
#include "firmware_app/service_notifier.h"
#include "firmware_app/status_line.h"
#include "hal/common/camera_options.h"
#include "hal/replay/replay_source.h"
#include "hal/sim/sim_source.h"
#include "hal/telemetry/telemetry_source.h"
#include "hal/telemetry/telemetry_watch.h"
#include "hal/v4l2/v4l2_source.h"
#ifdef UAVM_HAVE_LIBCAMERA
#include "hal/libcamera/libcamera_source.h"
#endif

namespace uavm::app {

namespace {

volatile std::sig_atomic_t g_stop_signal = 0;

void OnStopSignal(int sig) {
  g_stop_signal = sig;
}

std::unique_ptr<hal::FrameSource> MakeSource(const RunConfig& config, std::string* error) {
  const std::string& s = config.source;
  const auto colon = s.find(':');
  const std::string scheme = colon == std::string::npos ? "" : s.substr(0, colon);
  const std::string arg = colon == std::string::npos ? s : s.substr(colon + 1);
  if (scheme == "replay") {
    hal::ReplayOptions o;
    o.path = arg;
    o.stride = config.stride;
    o.keep_uniform_with_telemetry = !config.telemetry.empty();  // calm water: a frame to place, not a bad file
    return std::make_unique<hal::ReplaySource>(o);
  }
  if (scheme == "sim") {
    // A simulated flight over a real image (plan YAML: see hal/sim/sim_plan.h); frames are rendered, not decoded.
    return std::make_unique<hal::SimSource>(hal::SimOptions{arg, "", "", 0});
  }
  if (scheme == "v4l2" || scheme == "libcamera") {
    // A live camera: v4l2:/dev/videoN?width=..&height=..&format=..&fps=.. (hal/common/camera_options.h).
    hal::CameraOptions o;
    if (!hal::ParseCameraOptions(arg, &o, error)) return nullptr;
    if (scheme == "v4l2") return std::make_unique<hal::V4l2Source>(o);
#ifdef UAVM_HAVE_LIBCAMERA
    return std::make_unique<hal::LibcameraSource>(o);
#else
    *error = "this build has no libcamera back-end (configure with -DUAVM_WITH_LIBCAMERA=ON, needs libcamera-dev)";
    return nullptr;
#endif
  }
  *error = "unknown source '" + s + "' (expected replay:PATH, sim:PLAN.yaml, v4l2:/dev/videoN or libcamera:N)";
  return nullptr;
}

// One captured item: a frame, or the record of an input the source skipped.
struct Item {
  hal::Status status = hal::Status::kOk;
  std::string name;
  std::string message;
  Mosaicker::Prepared prepared;
};

// Registers the journal's frames again from the session directory, in their order. Returns the source names the
// journal already has (accepted or skipped), which the live source then passes over.
bool ResumeFromJournal(const SessionPaths& paths, const JournalContents& journal, Mosaicker* mosaicker,
                       std::unordered_set<std::string>* seen, std::string* error) {
  hal::ReplayOptions stored_options;
  stored_options.path = paths.frames();
  hal::ReplaySource stored(stored_options);
  for (const auto& skip : journal.skipped) {
    mosaicker->RecordSkipped(skip.name, skip.reason, /*journal=*/false);
    seen->insert(skip.name);
  }
  if (journal.frames.empty()) return true;
  if (stored.Open(error) != hal::Status::kOk) return false;
  for (const JournalFrame& jf : journal.frames) {
    // frames/ is in id order (NNNNNN_ prefix); a file there without a journal line (killed between the two) is
    // passed over: its input is taken from the source again.
    hal::Frame frame;
    std::string err;
    for (;;) {
      const hal::Status st = stored.Next(&frame, &err);
      if (st == hal::Status::kEndOfStream || st == hal::Status::kError) {
        *error = "resume: frame " + jf.stored_file + " of the journal is missing from frames/";
        return false;
      }
      if (frame.source_name == jf.stored_file) break;
    }
    if (frame.original_size != cv::Size(jf.width, jf.height)) {
      *error = "resume: frames/" + jf.stored_file + " does not match the journal";
      return false;
    }
    frame.source_name = jf.name;
    frame.timestamp_ns = jf.timestamp_ns;
    // The position the interrupted run had (telemetry's, which the stored file does not carry), else its EXIF's.
    if (jf.latitude_deg && jf.longitude_deg) {
      frame.metadata.latitude_deg = jf.latitude_deg;
      frame.metadata.longitude_deg = jf.longitude_deg;
      frame.metadata.relative_altitude_m = jf.relative_altitude_m;
      frame.metadata.flight_yaw_deg = jf.yaw_deg;
    }
    if (mosaicker->frames_in() != static_cast<size_t>(jf.id)) {
      *error = "resume: journal frame ids are not consecutive";
      return false;
    }
    const auto outcome = mosaicker->AddFrame(mosaicker->PrepareStored(std::move(frame), jf.id, jf.stored_file));
    (void)outcome;  // registered or not, exactly as in the interrupted run
    seen->insert(jf.name);
  }
  stored.Close();
  return true;
}

}  // namespace

int ListCameras() {
  const auto v4l2 = hal::ListV4l2Devices();
  std::printf("V4L2 (%zu nodes):\n", v4l2.size());
  for (const auto& d : v4l2) {
    std::printf("  v4l2:%s  %s (%s, %s)%s\n", d.path.c_str(), d.card.c_str(), d.driver.c_str(), d.bus.c_str(),
                d.capture ? "" : "  [no single-planar capture]");
    for (const auto& f : d.formats) std::printf("      %s\n", f.c_str());
  }
#ifdef UAVM_HAVE_LIBCAMERA
  std::string error;
  const auto cams = hal::ListLibcameraCameras(&error);
  if (!error.empty()) std::printf("libcamera: %s\n", error.c_str());
  std::printf("libcamera (%zu cameras):\n", cams.size());
  for (const auto& c : cams) std::printf("  %s\n", c.c_str());
#else
  std::printf("libcamera: not built (UAVM_WITH_LIBCAMERA=OFF)\n");
#endif
  std::fflush(stdout);
  return kExitOk;
}

void InstallStopHandlers() {
  struct sigaction sa {};
  sa.sa_handler = OnStopSignal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  // Past a file-size limit, writes fail with EFBIG (reported like a full disk) instead of killing the process.
  std::signal(SIGXFSZ, SIG_IGN);
}

// --telemetry: started before the first frame (a listening link must hear the fixes before the frames they place).
// Null without --telemetry; `failed` when it was asked for and cannot start (start-up: a usage error).
std::unique_ptr<hal::TelemetrySource> StartTelemetry(const RunConfig& config, bool* failed) {
  *failed = false;
  if (config.telemetry.empty()) return nullptr;
  const auto& t = config.pipeline.telemetry;
  hal::TelemetryOptions options;
  options.latency_ns = static_cast<int64_t>(t.latency_ms * 1e6);
  options.max_gap_ns = static_cast<int64_t>(t.max_gap_s * 1e9);
  options.max_hold_ns = static_cast<int64_t>(t.max_hold_s * 1e9);
  options.exif_utc_offset_s = t.exif_utc_offset_s;
  std::string error;
  auto source = hal::MakeTelemetrySource(config.telemetry, options, &error);
  if (source && source->Start(&error) != hal::Status::kOk) source.reset();
  if (!source) {
    spdlog::error("{}", error);
    *failed = true;
    return nullptr;
  }
  spdlog::info("telemetry: {}", source->Describe());
  return source;
}

nlohmann::json TelemetryJson(const hal::TelemetryReport& r) {
  return {{"kind", r.kind},
          {"match", r.match},
          {"frames_asked", r.frames_asked},
          {"frames_placed", r.frames_placed},
          {"frames_without", r.frames_without},
          {"fixes", r.track.fixes},
          {"no_fix", r.track.no_fix},
          {"stale", r.track.stale},
          {"outside", r.track.outside},
          {"out_of_order", r.track.out_of_order},
          {"history_overwritten", r.track.overwritten},
          {"packets", r.parser.packets},
          {"crc_errors", r.parser.crc_errors},
          {"unknown_messages", r.parser.unknown},
          {"signed_packets_unverified", r.parser.signed_packets},
          {"bytes_skipped", r.parser.bytes_skipped + r.resync_bytes},
          {"log_truncated", r.log_truncated},
          {"log_overlaps_frames", r.log_overlaps_frames},
          {"triggers", r.triggers},
          {"triggers_missing", r.triggers_missing},
          {"triggers_without_fix", r.triggers_without_fix},
          {"link_losses", r.link_losses}};
}

namespace {

// The source opened, the telemetry started (with --telemetry) and the session directory prepared. kExitOk, or the
// exit code.
int OpenSourceAndSession(const RunConfig& config, std::unique_ptr<hal::FrameSource>* source,
                         std::unique_ptr<hal::TelemetrySource>* telemetry, SessionPaths* paths) {
  std::string error;
  *source = MakeSource(config, &error);
  if (!*source) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  if ((*source)->Open(&error) != hal::Status::kOk) {
    spdlog::error("cannot open source: {}", error);
    return kExitSourceError;
  }
  bool telemetry_failed = false;
  *telemetry = StartTelemetry(config, &telemetry_failed);
  if (telemetry_failed) return kExitUsage;
  if (!PrepareSessionDir(config.out_dir, paths, &error)) {
    spdlog::error("{}", error);
    return kExitOutputError;
  }
  // Decode no more than the working resolution needs (JPEG DCT scaling); the compositor re-reads at its own scale.
  (*source)->SetDecodeHint({config.pipeline.work_long_side});
  spdlog::info("source {}, output {}", (*source)->Describe(), config.out_dir);
  return kExitOk;
}

// The budget sizes caches, pools and the detector's bands; the plan is for the working frame's usual 4:3 shape (the
// detector adapts its bands to each frame's real size). kExitOk, or the exit code.
int PlanMemory(PipelineOptions* pipeline, MemoryPlan* plan) {
  std::string error;
  if (!ApplyMemoryBudget(pipeline->work_long_side, pipeline->work_long_side * 3 / 4, pipeline, plan, &error)) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  if (plan->budget_mib > 0)
    spdlog::info(
        "memory budget {:.0f} MiB: flight ~{:.0f} MiB (detector {:.0f} MiB in {} band(s), queue {}, feature cache "
        "{:.0f}, relocalisation {:.0f}), end ~{:.0f} MiB (image cache {:.0f}, blending {:.0f}, tile {})",
        plan->budget_mib, plan->FlightMiB(), plan->sift_mib, plan->sift_bands, plan->queue_capacity,
        plan->feature_cache_mib, plan->relocalization_mib, plan->EndMiB(), plan->image_cache_mib, plan->blend_mib,
        pipeline->mosaic.tile_size);
  return kExitOk;
}

// What the flight shows of itself: the terminal's status line and the live view's status (and previews).
class FlightStatus {
 public:
  FlightStatus(const Mosaicker& mosaicker, double budget_mib) : mosaicker_(mosaicker) {
    status_.budget_mib = budget_mib;
  }
  // The mosaicker (declared first in Run) outlives the server: its tile worker must stop calling into it.
  ~FlightStatus() {
    if (tiles_source_ != nullptr) tiles_source_->SetTilesListeners(nullptr, nullptr);
  }
  FlightStatus(const FlightStatus&) = delete;
  FlightStatus& operator=(const FlightStatus&) = delete;

  // The live view (off without --http). kExitOk, or the exit code.
  int StartLiveView(const RunConfig& config, const PipelineOptions& pipeline, Mosaicker* mosaicker) {
    serving_ = !config.http.empty();
    run_start_ns_ = MonotonicNs();
    if (!serving_) return kExitOk;
    std::string error;
    LiveServer::Options lo;
    lo.leaflet_dir = pipeline.leaflet_dir;
    lo.basemap_url = config.basemap;
    if (!ParseHostPort(config.http, &lo.host, &lo.port)) {
      spdlog::error("--http: expected HOST:PORT, got '{}'", config.http);
      return kExitUsage;
    }
    if (!live_.Start(lo, &error)) {
      spdlog::error("--http: {}", error);
      return kExitUsage;
    }
    mosaicker->SetPreviewListener(
        [this](std::shared_ptr<const std::string> jpeg, std::shared_ptr<const nlohmann::json> georef) {
          live_.PublishJpeg(std::move(jpeg), std::move(georef));
        });
    mosaicker->SetTilesListeners(
        [this](std::shared_ptr<const TileSetInfo> t) { live_.PublishTiles(std::move(t)); },
        [this](std::shared_ptr<const std::string> g) { live_.PublishFootprints(std::move(g)); });
    tiles_source_ = mosaicker;
    run_start_ns_ = MonotonicNs();  // the run's uptime starts with the server up
    return kExitOk;
  }

  void Publish(const char* state, bool wait) {
    status_.state = state;
    status_.frames_in = static_cast<int>(mosaicker_.frames_in());
    status_.uptime_s = static_cast<double>(MonotonicNs() - run_start_ns_) * 1e-9;
    status_.fps = status_.uptime_s > 0 ? status_.frames_in / status_.uptime_s : 0.0;
    status_.median_frame_ms = mosaicker_.stage_stats().Get("frame_total").median;
    status_.rss_mib = CurrentRssMiB();
    status_.peak_rss_mib = PeakRssMiB();
    status_.last_error = line_.last_error();
    if (serving_) live_.PublishStatus(status_, wait);
  }

  // After each frame: the live view's status, the status line (a TTY) or a log line every 10 frames.
  void FrameDone(int registered_live, size_t dropped) {
    status_.registered = registered_live;
    status_.dropped = static_cast<int>(dropped);
    Publish("flying", false);
    if (line_.tty())
      line_.Update(fmt::format("{} frames | {:.1f} fps | {} registered | {} dropped | {:.0f} ms/frame | RSS {:.0f} MiB",
                               status_.frames_in, status_.fps, registered_live, status_.dropped,
                               status_.median_frame_ms, status_.rss_mib));
  }
  void LogEvery10Frames(int registered_live) const {
    if (mosaicker_.frames_in() % 10 == 0 && !line_.tty())
      spdlog::info("{} frames, median {:.0f} ms/frame, {:.1f} fps, {} registered, RSS {:.0f} MiB",
                   mosaicker_.frames_in(), mosaicker_.stage_stats().Get("frame_total").median, status_.fps,
                   registered_live, CurrentRssMiB());
  }

  // The finished map stays served (a client that kept the URL gets the end-of-flight tiles) until `seconds` have
  // passed or a stop signal comes.
  void Linger(double seconds) const {
    if (!serving_ || !(seconds > 0)) return;
    spdlog::info("live view: the finished map stays served for {:.0f} s (SIGTERM ends it)", seconds);
    const int64_t end = MonotonicNs() + static_cast<int64_t>(seconds * 1e9);
    while (g_stop_signal == 0 && MonotonicNs() < end) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }

  LiveStatus& status() { return status_; }
  StatusLine& line() { return line_; }

 private:
  const Mosaicker& mosaicker_;
  StatusLine line_;
  // Declared before the loop's state in Run, so it stops last; it only ever reads copies.
  LiveServer live_;
  Mosaicker* tiles_source_ = nullptr;  // borrowed: the listeners it calls are cleared before live_ goes
  bool serving_ = false;
  int64_t run_start_ns_ = 0;
  LiveStatus status_;
};

// The journal started (or continued, with --resume: its frames registered again). `seen`: the source names the
// journal has. kExitOk, or the exit code.
int StartJournal(const RunConfig& config, const SessionPaths& paths, Mosaicker* mosaicker, JournalContents* journal,
                 std::unordered_set<std::string>* seen) {
  std::string error;
  const std::string journal_path = paths.Join("journal.jsonl");
  if (config.resume) {
    if (!ReadJournal(journal_path, journal, &error)) {
      spdlog::error("cannot resume: {}: {}", journal_path, error);
      return kExitUsage;
    }
    if (journal->torn_lines > 0)
      spdlog::warn("journal: a torn last line (the run was killed while writing it) dropped");
    spdlog::info("resuming: {} frames and {} skipped inputs in the journal{}", journal->frames.size(),
                 journal->skipped.size(), journal->finished ? " (the previous run had finished its flight)" : "");
  }
  if (!mosaicker->StartJournal(config.resume, journal->valid_bytes, &error)) {
    spdlog::error("{}", error);
    return kExitOutputError;
  }
  if (config.resume) {
    if (!ResumeFromJournal(paths, *journal, mosaicker, seen, &error)) {
      spdlog::error("{}", error);
      return kExitOutputError;
    }
    spdlog::info("resumed {} frames from the session", mosaicker->frames_in());
  }
  return kExitOk;
}

struct CaptureOutcome {
  bool source_failed = false;
  std::string source_error;
};

// An input OpenCV cannot process (e.g. a degenerate size) is skipped like a corrupt file, never fatal.
void MarkUnprocessable(const std::exception& e, Item* item) {
  item->status = hal::Status::kSkipped;
  item->message = std::string("cannot process frame: ") + e.what();
}

// The load thread: frames from the source (decoded) and their working copies, into `loaded` until the source ends,
// max_frames, a stop signal or a closed queue. A stage of its own, so that the next frame's decode runs while this
// one's SIFT does (SIFT keeps about 1.6 of two cores busy; the decode and resize fill the rest).
void LoadFrames(const RunConfig& config, hal::FrameSource* source, hal::TelemetrySource* telemetry,
                const Mosaicker* mosaicker, const std::unordered_set<std::string>& seen, int delivered,
                BoundedQueue<Item>* loaded, CaptureOutcome* outcome) {
  hal::TelemetryWatch telemetry_watch;
  for (;;) {
    if (config.max_frames > 0 && delivered >= config.max_frames) break;
    if (g_stop_signal != 0) break;
    Item item;
    std::string err;
    hal::Frame frame;
    StageTimer decode_timer;
    item.status = source->Next(&frame, &err);
    const double decode_ms = decode_timer.ElapsedMs();
    item.name = frame.source_name;
    if (item.status == hal::Status::kEndOfStream) break;
    if (item.status == hal::Status::kError) {
      outcome->source_failed = true;
      outcome->source_error = err;
      break;
    }
    item.message = err;
    if (seen.count(item.name) != 0) continue;  // accepted or skipped before the interruption
    if (item.status == hal::Status::kOk) {
      ++delivered;
      if (telemetry) {
        const auto pose = telemetry->PoseFor(frame);
        if (pose) hal::ApplyPose(*pose, &frame.metadata);
        telemetry_watch.Saw(frame.source_name, pose.has_value(), telemetry->Report());
      }
      try {
        item.prepared = mosaicker->PrepareImages(std::move(frame));
        item.prepared.decode_ms = decode_ms;
      } catch (const std::exception& e) {
        MarkUnprocessable(e, &item);
      }
    }
    if (!loaded->Push(std::move(item))) break;
  }
  loaded->Close();
}

// The detect thread: each loaded frame's features (overlapping the previous frame's matching), into the flight
// queue. When the flight loop closes that queue (storage failed), `loaded` is closed too and the load thread stops.
void DetectFrames(const Mosaicker* mosaicker, BoundedQueue<Item>* loaded, BoundedQueue<Item>* queue) {
  while (auto item = loaded->Pop()) {
    if (item->status == hal::Status::kOk) {
      try {
        mosaicker->DetectFeatures(&item->prepared);
      } catch (const std::exception& e) {
        MarkUnprocessable(e, &*item);
      }
    }
    if (!queue->Push(std::move(*item))) {
      loaded->Close();
      break;
    }
  }
  queue->Close();
}

// The flight loop: each captured frame registered (or its skip recorded) in order. Returns false when the session
// could not store frames any more (capture is then stopped).
bool RegisterFrames(const RunConfig& config, BoundedQueue<Item>* queue, Mosaicker* mosaicker, ServiceNotifier* notifier,
                    FlightStatus* status, hal::TelemetrySource* telemetry) {
  int registered_live = 0;  // joined the first frame's part of the map during the flight (the status line)
  int64_t last_gcs_status_ns = 0;
  while (auto item = queue->Pop()) {
    if (item->status == hal::Status::kSkipped) {
      mosaicker->RecordSkipped(item->name, item->message);
      continue;
    }
    try {
      if (mosaicker->AddFrame(std::move(item->prepared)) == FrameOutcome::kRegistered) ++registered_live;
    } catch (const std::exception& e) {
      spdlog::error("frame {} could not be registered: {}", item->name, e.what());
    }
    if (!mosaicker->storage_failure().empty()) {
      // Disk full (or the storage went away): taking more frames would only lose them. What is stored stays valid,
      // and a resumed run takes the rest from the source.
      spdlog::error(
          "the session cannot store frames any more (disk full?): capture stopped after {} frames; "
          "free space and run again with --resume",
          mosaicker->frames_in());
      queue->Close();
      return false;
    }
    notifier->Progress(static_cast<int>(mosaicker->frames_in()), registered_live, CurrentRssMiB(), PeakRssMiB());
    status->FrameDone(registered_live, queue->dropped());
    // Test hook (--process-delay-ms): a slow consumer, so that a live camera's drop-oldest queue is exercised.
    if (config.process_delay_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(config.process_delay_ms));
    status->LogEvery10Frames(registered_live);
    // The operator's ground station shows the mapper's state (a STATUSTEXT every 5 s over the telemetry link).
    if (telemetry != nullptr && MonotonicNs() - last_gcs_status_ns > 5'000'000'000) {
      last_gcs_status_ns = MonotonicNs();
      telemetry->SendStatus(fmt::format("uavm: {} frames, {} registered, RSS {:.0f} MiB", mosaicker->frames_in(),
                                        registered_live, CurrentRssMiB()));
    }
  }
  return true;
}

// After the flight: the telemetry's report, the drop and capture counters, the end solves and compositing, the exit
// code.
int FinishFlight(hal::FrameSource* source, hal::TelemetrySource* telemetry, const BoundedQueue<Item>& queue,
                 const CaptureOutcome& capture, bool storage_stopped, Mosaicker* mosaicker, ServiceNotifier* notifier,
                 FlightStatus* status) {
  source->Close();
  if (telemetry) {
    telemetry->Stop();
    const hal::TelemetryReport tr = telemetry->Report();
    spdlog::log(tr.frames_without > 0 ? spdlog::level::warn : spdlog::level::info,
                "telemetry: {} of {} frames placed ({} without: stale, lost, no fix or not covered; report.json "
                "\"telemetry\" counts each)",
                tr.frames_placed, tr.frames_asked, tr.frames_without);
    mosaicker->SetReportSection("telemetry", TelemetryJson(tr));
  }
  // Frames lost to a slow consumer: in this queue, and in a camera source's own capture queue.
  const hal::CaptureCounters counters = source->Counters();
  mosaicker->RecordDropped(queue.dropped() + counters.dropped);
  mosaicker->RecordCapture(counters);
  if (g_stop_signal != 0)
    spdlog::warn("signal {} received: capture stopped; registering and compositing the {} frames received",
                 static_cast<int>(g_stop_signal), mosaicker->frames_in());
  if (capture.source_failed)
    spdlog::error("source stopped: {} (finishing with what was received)", capture.source_error);
  status->line().Finish();
  status->status().dropped = static_cast<int>(queue.dropped() + counters.dropped);
  status->Publish("finishing", true);
  notifier->Stopping(fmt::format("flight over after {} frames: final solve and mosaic", mosaicker->frames_in()));
  bool finished = false;
  std::string error;
  {
    const WatchdogHeartbeat heartbeat(notifier);  // the end solves and compositing have no frame loop to feed it
    finished = mosaicker->Finish(&error);
  }
  status->status().registered = mosaicker->registered_count();
  status->Publish(finished ? "done" : "failed", true);
  if (!finished) {
    spdlog::error("cannot write the session (output not writable or disk full): {}", error);
    return kExitOutputError;
  }
  // The peak over every phase (the kernel's high-water mark is never reset): what an outside tool reads too.
  const double peak = PeakRssMiB();
  spdlog::info("done: {}/{} registered, residual RMS {:.2f} px, peak RSS {:.0f} MiB", mosaicker->registered_count(),
               mosaicker->frames_in(), mosaicker->residual_rms_px(), peak);
  notifier->Status(fmt::format("done: {}/{} registered, peak RSS {:.0f} MiB", mosaicker->registered_count(),
                               mosaicker->frames_in(), peak));
  if (storage_stopped) return kExitOutputError;
  if (mosaicker->registered_count() == 0) return kExitNothingRegistered;
  return capture.source_failed ? kExitSourceError : kExitOk;
}

}  // namespace

int Run(const RunConfig& config) {
  std::unique_ptr<hal::FrameSource> source;
  std::unique_ptr<hal::TelemetrySource> telemetry;
  SessionPaths paths;
  if (const int rc = OpenSourceAndSession(config, &source, &telemetry, &paths); rc != kExitOk) return rc;
  PipelineOptions pipeline = config.pipeline;
  MemoryPlan plan;
  if (const int rc = PlanMemory(&pipeline, &plan); rc != kExitOk) return rc;
  Mosaicker mosaicker(pipeline, paths);
  mosaicker.SetMemoryPlan(plan);
  FlightStatus status(mosaicker, plan.budget_mib);
  if (const int rc = status.StartLiveView(config, pipeline, &mosaicker); rc != kExitOk) return rc;
  status.Publish("starting", true);
  JournalContents journal;
  std::unordered_set<std::string> seen;
  if (const int rc = StartJournal(config, paths, &mosaicker, &journal, &seen); rc != kExitOk) return rc;
  ServiceNotifier notifier;
  notifier.Ready(fmt::format("capturing from {} into {}", source->Describe(), config.out_dir));
  BoundedQueue<Item> queue(static_cast<size_t>(pipeline.queue_capacity), source->IsReplay()
                                                                             ? BoundedQueue<Item>::Policy::kBlock
                                                                             : BoundedQueue<Item>::Policy::kDropOldest);
  // One frame between loading and detection: the decode of the next frame overlaps this one's SIFT. The loader waits
  // for detection (a camera's own queue drops its oldest frames meanwhile, as before: no CPU is spent on frames that
  // would be dropped here).
  BoundedQueue<Item> loaded(1, BoundedQueue<Item>::Policy::kBlock);
  CaptureOutcome capture_outcome;
  std::thread load(LoadFrames, std::cref(config), source.get(), telemetry.get(), &mosaicker, std::cref(seen),
                   static_cast<int>(journal.frames.size()), &loaded, &capture_outcome);
  std::thread detect(DetectFrames, &mosaicker, &loaded, &queue);
  const bool storage_stopped = !RegisterFrames(config, &queue, &mosaicker, &notifier, &status, telemetry.get());
  detect.join();
  load.join();
  const int rc = FinishFlight(source.get(), telemetry.get(), queue, capture_outcome, storage_stopped, &mosaicker,
                              &notifier, &status);
  status.Linger(config.http_linger_s);
  return rc;
}

}  // namespace uavm::app
