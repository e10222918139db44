// The onboard program's wiring: the source and telemetry, the FlightSession with its LiveView, the capture threads,
// the flight loop, the end of the flight and the exit code.
#include "firmware_app/app.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <csignal>
#include <memory>
#include <thread>

#include "core/pipeline/finish_flight.h"
#include "core/pipeline/flight_session.h"
#include "core/pipeline/live_view.h"
#include "core/pipeline/work_lens.h"
#include "core/session/session_dir.h"
#include "core/util/bounded_queue.h"
#include "core/util/clock.h"
#include "core/util/memory.h"
#include "firmware_app/capture.h"
#include "firmware_app/flight_status.h"
#include "firmware_app/service_notifier.h"
#include "firmware_app/sources.h"

namespace uavm::app {

namespace {

volatile std::sig_atomic_t g_stop_signal = 0;

void OnStopSignal(int sig) {
  g_stop_signal = sig;
}

// The source opened, the telemetry started (with --telemetry) and the session directory prepared and locked (one run
// per session). kExitOk, or the exit code.
int OpenSourceAndSession(const RunConfig& config, std::unique_ptr<hal::FrameSource>* source,
                         std::unique_ptr<hal::TelemetrySource>* telemetry, SessionPaths* paths, SessionLock* lock) {
  std::string error;
  // The session first: a second run on the same --out is refused before it touches the first one's camera or
  // telemetry link.
  if (!PrepareSessionDir(config.out_dir, paths, &error)) {
    spdlog::error("{}", error);
    return kExitOutputError;
  }
  if (!lock->Acquire(*paths, &error)) {
    spdlog::error("{}", error);
    return kExitOutputError;
  }
  if (!lock->held()) spdlog::warn("{}: a second run on this --out would not be refused", lock->unlocked_reason());
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
  // Decode no more than the working resolution needs (JPEG DCT scaling); the compositor re-reads at its own scale.
  (*source)->SetDecodeHint({config.pipeline.work_long_side});
  spdlog::info("source {}, output {}", (*source)->Describe(), config.out_dir);
  return kExitOk;
}

// The journal started (or continued, with --resume: its frames registered again). kExitOk, or the exit code.
int StartSession(const RunConfig& config, FlightSession* session) {
  std::string error;
  ReplayStoredFrames stored;
  switch (session->Start(config.resume, &stored, &error)) {
    case FlightSession::StartStatus::kOk:
      return kExitOk;
    case FlightSession::StartStatus::kBadJournal:
      spdlog::error("{}", error);
      return kExitUsage;
    case FlightSession::StartStatus::kOutputError:
      break;
  }
  spdlog::error("{}", error);
  return kExitOutputError;
}

// The flight loop: each captured frame registered (or its skip recorded) in order. Returns false when the session
// could not store frames any more (capture is then stopped).
bool RegisterFrames(const RunConfig& config, BoundedQueue<Item>* queue, const hal::FrameSource& source,
                    FlightSession* session, ServiceNotifier* notifier, FlightStatus* status,
                    hal::TelemetrySource* telemetry) {
  int registered_live = 0;  // joined the first frame's part of the map during the flight (the status line)
  int64_t last_gcs_status_ns = 0;
  while (auto item = queue->Pop()) {
    if (item->status == hal::Status::kSkipped) {
      session->RecordSkipped(item->name, item->message);
      continue;
    }
    try {
      if (session->AddFrame(std::move(item->prepared)) == FrameOutcome::kRegistered) ++registered_live;
    } catch (const std::exception& e) {
      spdlog::error("frame {} could not be registered: {}", item->name, e.what());
    }
    if (!session->storage_failure().empty()) {
      // Disk full (or the storage went away): taking more frames would only lose them. What is stored stays valid,
      // and a resumed run takes the rest from the source.
      spdlog::error(
          "the session cannot store frames any more (disk full?): capture stopped after {} frames; "
          "free space and run again with --resume",
          session->frames_in());
      queue->Close();
      return false;
    }
    notifier->Progress(static_cast<int>(session->frames_in()), registered_live, CurrentRssMiB(), PeakRssMiB());
    status->FrameDone(registered_live, source.Counters().dropped);
    // Test hook (--process-delay-ms): a slow consumer, so that a live camera's own drop-oldest queue is exercised.
    if (config.process_delay_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(config.process_delay_ms));
    status->LogEvery10Frames(registered_live);
    // The operator's ground station shows the mapper's state (a STATUSTEXT every 5 s over the telemetry link).
    if (telemetry != nullptr && MonotonicNs() - last_gcs_status_ns > 5'000'000'000) {
      last_gcs_status_ns = MonotonicNs();
      telemetry->SendStatus(fmt::format("uavm: {} frames, {} registered, RSS {:.0f} MiB", session->frames_in(),
                                        registered_live, CurrentRssMiB()));
    }
  }
  return true;
}

// What the flight's inputs say of themselves: the telemetry's report and the drop and capture counters.
OutputAdditions ReportInputs(const RunConfig& config, hal::FrameSource* source, hal::TelemetrySource* telemetry,
                             const CaptureOutcome& capture, FlightSession* session, FlightStatus* status) {
  source->Close();
  OutputAdditions additions;
  additions.config_yaml = hal::ToYaml(config.telemetry_timing);
  if (telemetry) {
    telemetry->Stop();
    const hal::TelemetryReport tr = telemetry->Report();
    spdlog::log(tr.frames_without > 0 ? spdlog::level::warn : spdlog::level::info,
                "telemetry: {} of {} frames placed ({} without: stale, lost, no fix or not covered; report.json "
                "\"telemetry\" counts each)",
                tr.frames_placed, tr.frames_asked, tr.frames_without);
    additions.report_sections["telemetry"] = TelemetryJson(tr);
  }
  // Frames lost to a slow consumer: in a camera source's own capture queue (the program's queues wait).
  const hal::CaptureCounters counters = source->Counters();
  session->RecordDropped(counters.dropped);
  session->RecordCapture(counters);
  if (g_stop_signal != 0)
    spdlog::warn("signal {} received: capture stopped; registering and compositing the {} frames received",
                 static_cast<int>(g_stop_signal), session->frames_in());
  if (capture.source_failed)
    spdlog::error("source stopped: {} (finishing with what was received)", capture.source_error);
  status->status().dropped = static_cast<int>(counters.dropped);
  return additions;
}

// After the flight: the end solves, compositing and products, the exit code.
int EndFlight(OutputAdditions additions, const CaptureOutcome& capture, bool storage_stopped, FlightSession* session,
              LiveView* view, ServiceNotifier* notifier, FlightStatus* status) {
  status->line().Finish();
  status->Publish("finishing", true);
  notifier->Stopping(fmt::format("flight over after {} frames: final solve and mosaic", session->frames_in()));
  bool finished = false;
  std::string error;
  FlightSummary summary;
  {
    const WatchdogHeartbeat heartbeat(notifier);  // the end solves and compositing have no frame loop to feed it
    finished = FinishFlight(session, view, std::move(additions), &summary, &error);
  }
  status->status().registered = summary.registered;
  status->Publish(finished ? "done" : "failed", true);
  if (!finished) {
    spdlog::error("cannot write the session (output not writable or disk full): {}", error);
    return kExitOutputError;
  }
  // The peak over every phase (the kernel's high-water mark is never reset): what an outside tool reads too.
  const double peak = PeakRssMiB();
  spdlog::info("done: {}/{} registered, residual RMS {:.2f} px, peak RSS {:.0f} MiB", summary.registered,
               session->frames_in(), summary.residual_rms_px, peak);
  notifier->Status(
      fmt::format("done: {}/{} registered, peak RSS {:.0f} MiB", summary.registered, session->frames_in(), peak));
  if (storage_stopped) return kExitOutputError;
  if (summary.registered == 0) return kExitNothingRegistered;
  return capture.source_failed ? kExitSourceError : kExitOk;
}

}  // namespace

int StopSignal() {
  return g_stop_signal;
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

int Run(const RunConfig& config) {
  const std::jthread lens_database = PreloadLensDatabase(config.pipeline.camera);
  std::unique_ptr<hal::FrameSource> source;
  std::unique_ptr<hal::TelemetrySource> telemetry;
  SessionPaths paths;
  SessionLock lock;  // held until the run returns
  if (const int rc = OpenSourceAndSession(config, &source, &telemetry, &paths, &lock); rc != kExitOk) return rc;
  std::string error;
  const auto session = FlightSession::Create(config.pipeline, paths, &error);
  if (!session) {
    spdlog::error("{}", error);
    return kExitUsage;
  }
  LiveView view(session->options(), paths, &session->record(), &session->lens(), &session->stage_stats());
  view.Follow(session.get());
  FlightStatus status(*session, session->memory_plan().budget_mib);
  if (const int rc = status.StartServer(config, &view); rc != kExitOk) return rc;
  status.Publish("starting", true);
  if (const int rc = StartSession(config, session.get()); rc != kExitOk) return rc;
  ServiceNotifier notifier;
  notifier.Ready(fmt::format("capturing from {} into {}", source->Describe(), config.out_dir));
  // Detected frames waiting for registration. It waits rather than drops, for a camera too: a camera's frames are
  // dropped in its own capture queue (V4L2, libcamera: the oldest, counted), before any decode, telemetry lookup or
  // SIFT is spent on them. Dropping here threw that work away (11 of 38 detected frames in a slow stretch of the camera
  // VM test) and took the CPU from the registration that was behind.
  BoundedQueue<Item> queue(static_cast<size_t>(session->options().queue_capacity), BoundedQueue<Item>::Policy::kBlock);
  // One frame between loading and detection: the decode of the next frame overlaps this one's SIFT. The loader waits
  // for detection likewise.
  BoundedQueue<Item> loaded(1, BoundedQueue<Item>::Policy::kBlock);
  CaptureOutcome capture;
  std::thread load(LoadFrames, std::cref(config), source.get(), telemetry.get(), &session->preparer(),
                   std::cref(session->seen()), static_cast<int>(session->frames_in()), &loaded, &capture);
  std::thread detect(DetectFrames, &session->preparer(), &loaded, &queue);
  const bool storage_stopped =
      !RegisterFrames(config, &queue, *source, session.get(), &notifier, &status, telemetry.get());
  detect.join();
  load.join();
  OutputAdditions additions = ReportInputs(config, source.get(), telemetry.get(), capture, session.get(), &status);
  const int rc = EndFlight(std::move(additions), capture, storage_stopped, session.get(), &view, &notifier, &status);
  status.Linger(config.http_linger_s);
  return rc;
}

}  // namespace uavm::app
