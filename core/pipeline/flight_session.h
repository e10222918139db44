#pragma once
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include "core/frame/frame.h"
#include "core/mosaic/compositor.h"
#include "core/pipeline/end_of_flight.h"
#include "core/pipeline/flight_record.h"
#include "core/pipeline/frame_preparer.h"
#include "core/pipeline/memory_budget.h"
#include "core/pipeline/options.h"
#include "core/pipeline/resource_log.h"
#include "core/pipeline/session_stores.h"
#include "core/registration/registration_engine.h"
#include "core/session/journal.h"
#include "core/session/session_dir.h"
#include "core/util/signal.h"
#include "core/util/stats.h"

namespace uavm {

// What FlightSession tells its followers after each frame it handed to the engine (registered or not). The images
// are the frame loop's: valid during the call only.
struct RegisteredFrame {
  int id = -1;
  const cv::Mat* work_bgr = nullptr;  // the ideal working copy
  const cv::Mat* thumb = nullptr;     // its radiometry thumbnail (empty when radiometry is off)
  size_t edges_before = 0;            // the engine's edges before this frame: the ones after are its own
  std::vector<int> moved;             // frames a solve or a merge moved since the last event (with TrackMoves)
};

// A follower's say in a frame's registration before it happens: where telemetry places it (e.g. the live
// georeference), filled in by the first follower that knows.
struct HintRequest {
  const FrameMetadata* metadata = nullptr;
  std::optional<PositionHint> hint;
};

// Reads back a resumed session's stored frames (frames/, in id order, decoded with their metadata): the program's
// is hal's replay; a test's a fake.
class StoredFrameReader {
 public:
  enum class Status { kFrame, kUnreadable, kEnd };
  virtual ~StoredFrameReader() = default;
  [[nodiscard]] virtual bool Open(const std::string& frames_dir, std::string* error) = 0;
  [[nodiscard]] virtual Status Next(Frame* frame) = 0;
};

// The onboard session of one flight: each frame is prepared (working copy, features), stored (frames/, features/,
// thumbs/, the journal) and handed to the RegistrationEngine; its followers hear of it (FrameRegistered). Owns the
// session from start to end: the memory budget applied to the options, the journal, a resume of an interrupted run,
// and at the end the engine's solve, the registration's own tables and report. What the flight recorded is read
// through record(); the live view and the end of the flight are the session's followers, not its members.
class FlightSession final : public SessionEnd {
 public:
  // The options with the memory budget applied (the plan logged); null with the reason when they cannot hold.
  [[nodiscard]] static std::unique_ptr<FlightSession> Create(const PipelineOptions& options, SessionPaths paths,
                                                             std::string* error);
  FlightSession(const PipelineOptions& options, const MemoryPlan& plan, SessionPaths paths);
  ~FlightSession() override;
  FlightSession(const FlightSession&) = delete;
  FlightSession& operator=(const FlightSession&) = delete;

  // Prepares frames (thread-safe: the load and detect threads use it while the frame loop registers).
  [[nodiscard]] const FramePreparer& preparer() const { return preparer_; }

  // How Start() went: kBadJournal when --resume finds no readable journal (a usage error), kOutputError when the
  // journal cannot be written or the stored frames read back.
  enum class StartStatus { kOk, kBadJournal, kOutputError };
  // Starts the journal (journal.jsonl); with `resume`, continues it: the frames it accepted are registered again
  // from `stored` (no detection: the same result), its skipped inputs recorded. Afterwards seen() holds the source
  // names the journal has, which the source then passes over (until EndFlight()).
  [[nodiscard]] StartStatus Start(bool resume, StoredFrameReader* stored, std::string* error);
  [[nodiscard]] const std::unordered_set<std::string>& seen() const { return seen_; }

  // Registers the frame, or records it as skipped (no id, a journal line; kFailed) when WhyNotRegistrable() says it
  // has nothing to register. A frame being resumed is registered again as the journal has it.
  [[nodiscard]] FrameOutcome AddFrame(PreparedFrame prepared);
  [[nodiscard]] FrameOutcome AddFrame(Frame frame) { return AddFrame(preparer_.Prepare(std::move(frame))); }
  // An input the source could not turn into a frame (corrupt, empty, not an image).
  void RecordSkipped(const std::string& file, const std::string& reason, bool journal = true);
  void RecordDropped(size_t count) { counters_.dropped_frames = count; }
  // A live camera's counters (captured, dropped in its own queue, driver gaps, reconnects): report.json "camera".
  void RecordCapture(const CaptureCounters& counters) { counters_.capture = counters; }

  // Followers. Their connections disconnect themselves, whichever side goes first; a follower that borrows the
  // record (LiveView) must still not outlive the session.
  [[nodiscard]] Connection OnFrameRegistered(std::function<void(const RegisteredFrame&)> slot) {
    return events_.registered.Connect(std::move(slot));
  }
  [[nodiscard]] Connection OnHintRequest(std::function<void(HintRequest&)> slot) {
    return events_.hint_request.Connect(std::move(slot));
  }

  // The end of the flight: the last frame is in (the resources at the flight's end are noted), then the engine's
  // final solve of the largest component (its steps are memory phases).
  // The source is done, so the journal's names it passed over (seen()) go too.
  void EndFlight() {
    std::unordered_set<std::string>().swap(seen_);
    preparer_.ReleaseDetectorBuffers();
    resources_.FlightEnd();
  }
  [[nodiscard]] Solution Solve();
  // The end's side of the session (SessionEnd): its memory phases after the solve (radiometry, outputs, compose,
  // products); graph.csv and correspondences.csv (streamed, each edge's points read back and given up again); its
  // keys of report.json (counters, registration, memory), `solution` being Solve()'s.
  void EnterPhase(const std::string& name) override { resources_.EnterPhase(name); }
  void ComposeEnd() override { resources_.ComposeEnd(); }
  [[nodiscard]] bool WriteEdgeTables(const IdSet& in_component, std::string* error) override;
  void DropEdgeRecords() override;
  [[nodiscard]] nlohmann::json Report(const Solution& solution, const CompositeResult& composite) const override;
  // The journal says the flight was finished (a resumed run knows it has nothing to add).
  void MarkFinished();

  [[nodiscard]] const FlightRecord& record() const { return record_; }
  [[nodiscard]] size_t frames_in() const { return record_.size(); }
  [[nodiscard]] const PipelineOptions& options() const { return options_; }
  [[nodiscard]] const MemoryPlan& memory_plan() const { return plan_; }
  [[nodiscard]] const SessionPaths& paths() const { return paths_; }
  [[nodiscard]] const WorkLens& lens() const { return preparer_.lens(); }
  // Why the session could not store an accepted frame (disk full, storage gone); empty while all is well. Once set,
  // the caller stops taking frames: what is already in the session stays whole and a resumed run continues it.
  [[nodiscard]] const std::string& storage_failure() const { return storage_failure_; }
  // Per-stage timings (the followers add their own stages).
  [[nodiscard]] StageStats& stage_stats() { return stats_; }
  [[nodiscard]] const StageStats& stage_stats() const { return stats_; }

 private:
  struct Counters {
    size_t resumed_frames = 0;  // frames taken from the journal of an interrupted run
    size_t dropped_frames = 0;
    CaptureCounters capture;
    int64_t start_ns = 0;
  };

  [[nodiscard]] PreparedFrame PrepareStored(Frame frame, int id, const std::string& stored_name) const;
  [[nodiscard]] bool Resume(const JournalContents& journal, StoredFrameReader* stored, std::string* error);
  void HandEngineTheCamera(cv::Size work_size);
  [[nodiscard]] SessionFrame& RecordFrame(int id, const PreparedFrame& prepared);
  // Stores the frame's bytes and features and journals it; false (frame failed, maybe the storage) otherwise.
  [[nodiscard]] bool StoreFrame(int id, const PreparedFrame& prepared, SessionFrame* st);
  void ReportRegistration(const Solution& solution, nlohmann::json* report) const;
  [[nodiscard]] nlohmann::json ReportMemory(const Solution& solution, const CompositeResult& composite) const;

  PipelineOptions options_;
  MemoryPlan plan_;
  SessionPaths paths_;
  FramePreparer preparer_;
  SessionStores stores_;
  SubpixelRefiner refiner_;  // before engine_, which borrows it
  RegistrationEngine engine_;
  FlightRecord record_{&engine_};
  SessionJournal journal_;
  std::unordered_set<std::string> seen_;
  ResourceLog resources_;
  StageStats stats_;
  Counters counters_;
  std::string storage_failure_;
  size_t edge_records_dropped_ = 0;  // by DropEdgeRecords: report.json still counts them
  struct Events {
    Signal<const RegisteredFrame&> registered;
    Signal<HintRequest&> hint_request;
  } events_;
};

}  // namespace uavm
