#include "core/pipeline/flight_session.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <sstream>
#include <string_view>

#include "core/buffers/mat_pool.h"
#include "core/util/clock.h"
#include "core/util/memory.h"
#include "core/util/record_arena.h"

namespace uavm {

namespace fs = std::filesystem;

namespace {
// Frames per window of the large-buffer pool's peak (MatPool::StartPeakWindow): long enough that every frame's
// detector and matching buffers recur in it, short enough that a rare peak is forgotten within minutes.
constexpr int kPoolWindowFrames = 100;
}  // namespace

std::unique_ptr<FlightSession> FlightSession::Create(const PipelineOptions& options, SessionPaths paths,
                                                     std::string* error) {
  // The budget sizes caches, pools and the detector's bands; the plan is for the working frame's usual 4:3 shape
  // (the detector adapts its bands to each frame's real size).
  PipelineOptions sized = options;
  MemoryPlan plan;
  if (!ApplyMemoryBudget(sized.work_long_side, sized.work_long_side * 3 / 4, &sized, &plan, error)) return nullptr;
  if (plan.budget_mib > 0)
    spdlog::info(
        "memory budget {:.0f} MiB: flight ~{:.0f} MiB (detector {:.0f} MiB in {} band(s), queue {}, feature cache "
        "{:.0f}, relocalisation {:.0f}), end ~{:.0f} MiB (image cache {:.0f}, blending {:.0f}, tile {})",
        plan.budget_mib, plan.FlightMiB(), plan.sift_mib, plan.sift_bands, plan.queue_capacity, plan.feature_cache_mib,
        plan.relocalization_mib, plan.EndMiB(), plan.image_cache_mib, plan.blend_mib, sized.mosaic.tile_size);
  return std::make_unique<FlightSession>(sized, plan, std::move(paths));
}

FlightSession::FlightSession(const PipelineOptions& options, const MemoryPlan& plan, SessionPaths paths)
    : options_(options),
      plan_(plan),
      paths_(std::move(paths)),
      preparer_(options.work_long_side, options.camera, options.features),
      stores_(paths_, static_cast<size_t>(options.feature_cache_mib) << 20),
      refiner_(options.subpixel),
      engine_(options, stores_.feature_provider(), stores_.edge_spill()) {
  counters_.start_ns = MonotonicNs();
  if (options.subpixel.enabled) engine_.SetRefiner(&refiner_);
  // The live tiles redraw the frames a solve moved: the engine keeps that log only for them.
  engine_.TrackMoves(options.live_tiles.enabled);
  resources_.FlightStart();
}

FlightSession::~FlightSession() = default;

FlightSession::StartStatus FlightSession::Start(bool resume, StoredFrameReader* stored, std::string* error) {
  // The records the flight keeps to its end go to file pages in the session directory (reclaimable), not anonymous
  // memory, where the directory is on a disk. Once per process: a second session's records share the first's file.
  std::string why;
  if (RecordArena::BackWithFile(paths_.root, &why))
    spdlog::debug("flight records: file-backed pages in {}", paths_.root);
  else
    spdlog::debug("flight records: anonymous memory ({})", why);
  const std::string journal_path = paths_.Join("journal.jsonl");
  JournalContents journal;
  if (resume) {
    if (!ReadJournal(journal_path, &journal, error)) {
      *error = "cannot resume: " + journal_path + ": " + *error;
      return StartStatus::kBadJournal;
    }
    if (journal.torn_lines > 0) spdlog::warn("journal: a torn last line (the run was killed while writing it) dropped");
    spdlog::info("resuming: {} frames and {} skipped inputs in the journal{}", journal.frames.size(),
                 journal.skipped.size(), journal.finished ? " (the previous run had finished its flight)" : "");
  }
  if (!journal_.Open(journal_path, resume, journal.valid_bytes, options_.journal_sync_every, error))
    return StartStatus::kOutputError;
  if (!resume) return StartStatus::kOk;
  if (!Resume(journal, stored, error)) return StartStatus::kOutputError;
  spdlog::info("resumed {} frames from the session", frames_in());
  return StartStatus::kOk;
}

// Registers the journal's frames again from frames/, in their order.
bool FlightSession::Resume(const JournalContents& journal, StoredFrameReader* stored, std::string* error) {
  for (const auto& skip : journal.skipped) {
    RecordSkipped(skip.name, skip.reason, /*journal=*/false);
    seen_.insert(skip.name);
  }
  if (journal.frames.empty()) return true;
  if (!stored->Open(paths_.frames(), error)) return false;
  for (const JournalFrame& jf : journal.frames) {
    // frames/ is in id order (NNNNNN_ prefix); a file there without a journal line (killed between the two) is
    // passed over: its input is taken from the source again.
    Frame frame;
    for (;;) {
      const StoredFrameReader::Status status = stored->Next(&frame);
      if (status == StoredFrameReader::Status::kEnd) {
        *error = "resume: frame " + jf.stored_file + " of the journal is missing from frames/";
        return false;
      }
      if (frame.source_name != jf.stored_file) continue;
      if (status == StoredFrameReader::Status::kUnreadable) {
        *error = "resume: frames/" + jf.stored_file + " of the journal cannot be read";
        return false;
      }
      break;
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
    if (frames_in() != static_cast<size_t>(jf.id)) {
      *error = "resume: journal frame ids are not consecutive";
      return false;
    }
    const auto outcome = AddFrame(PrepareStored(std::move(frame), jf.id, jf.stored_file));
    (void)outcome;  // registered or not, exactly as in the interrupted run
    seen_.insert(jf.name);
  }
  return true;
}

// A frame of the journal being resumed: decoded from frames/, its features read from features/ (computed again only
// if their file is unreadable). AddFrame then registers it exactly as the interrupted run did.
PreparedFrame FlightSession::PrepareStored(Frame frame, int id, const std::string& stored_name) const {
  frame.source_path = paths_.frames() + "/" + stored_name;  // a path: nothing gets encoded
  PreparedFrame p = preparer_.PrepareImages(std::move(frame));
  p.resumed = true;
  p.stored_name = stored_name;
  std::string error;
  StageTimer t;
  if (!stores_.features().Load(id, &p.features, &error)) {
    spdlog::warn("resume: {}; detecting features of {} again", error, stored_name);
    preparer_.DetectFeatures(&p);
  }
  p.features_ms = t.ElapsedMs();
  return p;
}

void FlightSession::RecordSkipped(const std::string& file, const std::string& reason, bool journal) {
  spdlog::warn("skipped {}: {}", file, reason);
  record_.AddSkipped({file, reason});
  std::string error;
  if (journal && journal_.is_open() && !journal_.AddSkip({file, reason}, &error)) spdlog::error("{}", error);
}

void FlightSession::HandEngineTheCamera(cv::Size work_size) {
  const Undistorter& work = preparer_.lens().work();
  if (engine_.has_camera() || work.camera().width != work_size.width || work.camera().height != work_size.height)
    return;
  engine_.SetCamera(work.camera(), preparer_.lens().choice().source == "configuration");
}

bool FlightSession::StoreFrame(int id, const PreparedFrame& prepared, SessionFrame* st) {
  const Frame& frame = prepared.frame;
  std::string error;
  if (prepared.resumed) {
    st->stored_file = paths_.frames() + "/" + prepared.stored_name;
    stores_.features().Adopt(id, prepared.features);
    ++counters_.resumed_frames;
    return true;
  }
  st->stored_file = paths_.frames() + "/" + StoredName(id, frame.source_name);
  if (frame.source_path.empty() && fs::path(st->stored_file).extension() != ".jpg") st->stored_file += ".jpg";
  if (!stores_.StoreFrameBytes(frame, prepared.encoded, st->stored_file, &error)) {
    // The session is to blame unless the source's file itself went away (a vanishing source is the source's error).
    std::error_code ec;
    if (frame.source_path.empty() || fs::exists(frame.source_path, ec)) storage_failure_ = error;
  } else if (!stores_.features().Put(id, prepared.features, &error)) {
    storage_failure_ = error;
  } else {
    // Accepted: its bytes and features are in the session, so a resumed run will find it.
    JournalFrame jf{id,
                    st->name,
                    fs::path(st->stored_file).filename().string(),
                    st->timestamp_ns,
                    st->original_size.width,
                    st->original_size.height};
    jf.latitude_deg = st->metadata().latitude_deg;
    jf.longitude_deg = st->metadata().longitude_deg;
    jf.relative_altitude_m = st->metadata().relative_altitude_m;
    jf.yaw_deg = st->metadata().flight_yaw_deg;
    if (journal_.is_open() && !journal_.AddFrame(jf, &error)) {
      // The frame itself is stored, but a journal that cannot grow means the disk is full: stop here.
      spdlog::error("{}; a resumed run would take this frame from the source again", error);
      storage_failure_ = error;
    }
    return true;
  }
  engine_.SetFailure(id, error);
  spdlog::error("{}", error);
  return false;
}

SessionFrame& FlightSession::RecordFrame(int id, const PreparedFrame& prepared) {
  const Frame& frame = prepared.frame;
  SessionFrame& st = record_.Append();
  st.id = id;
  st.name = frame.source_name;
  st.original_size = frame.original_size;
  st.timestamp_ns = frame.timestamp_ns;
  st.set_metadata(frame.metadata);
  st.work_size = prepared.work_bgr.size();
  return st;
}

FrameOutcome FlightSession::AddFrame(PreparedFrame prepared) {
  // The records this frame leaves for the rest of the flight (session and engine records, names, paths, edges, map
  // nodes) go to pages of their own, not between the frame's transient buffers (see RecordArena).
  const RecordArena::Scope records_on_their_own_pages;
  // The rule for frames of one colour (the capture threads apply it too, before spending work on them); a frame the
  // journal accepted is registered again as it was.
  if (const char* why = WhyNotRegistrable(prepared.flatness, prepared.frame.metadata); why && !prepared.resumed) {
    RecordSkipped(prepared.frame.source_name, why);
    return FrameOutcome::kFailed;
  }
  StageTimer frame_timer;
  StageTimer t;
  HandEngineTheCamera(prepared.work_bgr.size());
  const int id = engine_.AddFrame(prepared.work_bgr.size());
  if (plan_.frames_reserved > 0 && id == plan_.frames_reserved)
    spdlog::warn(
        "the flight is longer than the {} frames the memory plan reserved per-frame state for (max_flight_frames, "
        "at most 15 % of the budget): each further frame takes ~6.5 KiB beyond the plan",
        plan_.frames_reserved);
  SessionFrame& st = RecordFrame(id, prepared);
  if (!StoreFrame(id, prepared, &st)) return FrameOutcome::kFailed;
  const cv::Mat thumb = options_.radiometry.enabled
                            ? stores_.StoreThumbnail(id, prepared.work_bgr, options_.radiometry.thumb_long_side)
                            : cv::Mat();
  stats_.Add("prepare", prepared.prepare_ms + t.ElapsedMs());
  stats_.Add("features", prepared.features_ms);
  if (prepared.decode_ms > 0) stats_.Add("decode", prepared.decode_ms);
  Features& feats = prepared.features;
  // Match on the 8-bit values, exactly what later queries from the store will see.
  feats.descriptors = DequantizeDescriptors(QuantizeDescriptors(feats.descriptors));
  RegisterTiming timing;
  HintRequest hint{&st.metadata(), std::nullopt};
  events_.hint_request.Emit(hint);
  const size_t edges_before = engine_.edges().size();
  if (options_.subpixel.enabled) refiner_.Put(id, preparer_.IdealGray(prepared));
  const FrameOutcome outcome = engine_.Register(id, feats, &timing, hint.hint ? &*hint.hint : nullptr);
  stats_.Add("matching", timing.matching_ms);
  stats_.Add("adjust", timing.adjust_ms);
  events_.registered.Emit(RegisteredFrame{id, &prepared.work_bgr, &thumb, edges_before, engine_.TakeMoved()});
  // Blocks the pool did not need in the last window go back to the kernel (each is a mapping of its own).
  if (id % kPoolWindowFrames == kPoolWindowFrames - 1)
    if (const MatPool* pool = InstalledMatPool()) pool->StartPeakWindow();
  // Every few frames, not every frame: a trim walks the arenas (~1 ms).
  if (options_.trim_heap_every > 0 && id % options_.trim_heap_every == 0) TrimHeap();
  const double frame_ms = frame_timer.ElapsedMs();
  stats_.Add("frame_total", frame_ms);
  // One line per frame at debug level: bench/flight_length.sh draws the per-frame cost along a flight from it.
  spdlog::debug("frame {} ({}) processed in {:.1f} ms", id, st.name, frame_ms);
  return outcome;
}

Solution FlightSession::Solve() {
  Solution solution = engine_.Finish([this](const std::string& phase) { resources_.EnterPhase(phase); });
  if (!solution.ok) return solution;
  if (solution.component.size() >= 2) {
    stats_.Add("final_adjust", solution.adjust_ms);
    stats_.Add("refine", solution.refine_ms);
  }
  spdlog::info("registered {}/{} frames, residual RMS {:.3f} px (median {:.3f}) at working resolution",
               solution.component.size(), frames_in(), solution.rms_px, solution.median_px);
  return solution;
}

void FlightSession::MarkFinished() {
  std::string error;
  if (journal_.is_open() && !journal_.AddFinished(&error)) spdlog::warn("{}", error);
}

// graph.csv and correspondences.csv (original-resolution pixels, so the ground tool needs no working sizes).
bool FlightSession::WriteEdgeTables(const IdSet& in_component, std::string* error) {
  // Both grow with the flight (correspondences.csv ~5 kB per edge, graph.csv ~70 bytes): streamed to disk edge by
  // edge, and an edge whose points are only in edges.bin is read, written and given back.
  AtomicFileWriter graph_csv;
  if (!graph_csv.Open(paths_.Join("graph.csv"), error)) return false;
  graph_csv.Write("src,tgt,src_file,tgt_file,matches,inliers,used\n");
  AtomicFileWriter corr_csv;
  if (!corr_csv.Open(paths_.Join("correspondences.csv"), error)) return false;
  corr_csv.Write("src,tgt,x_src,y_src,x_tgt,y_tgt\n");
  std::string row;
  for (Edge& e : engine_.mutable_edges()) {
    const bool used = in_component.contains(e.src) && in_component.contains(e.tgt) && engine_.EdgeCounts(e);
    row = fmt::format("{},{},{},{},{},{},{}\n", e.src, e.tgt, record_.frame(e.src).name, record_.frame(e.tgt).name,
                      e.num_matches, e.num_inliers, used ? 1 : 0);
    graph_csv.Write(row);
    std::string load_error;
    const bool was_resident = e.points_resident;
    if (!stores_.edges().Load(&e, &load_error)) {
      spdlog::warn("correspondences.csv: edge {}-{} left out ({})", e.src, e.tgt, load_error);
      continue;
    }
    if (!was_resident && used) engine_.AsSolved(&e);  // the pixels the final solves used (a calibrated lens)
    const Mat3 src_orig = record_.frame(e.src).work_from_original().inverse();
    const Mat3 tgt_orig = record_.frame(e.tgt).work_from_original().inverse();
    char line[160];
    for (size_t k = 0; k < e.points.size(); ++k) {
      const Vec2 a = Apply(src_orig, e.points.src(k).cast<double>());
      const Vec2 b = Apply(tgt_orig, e.points.tgt(k).cast<double>());
      const int n =
          std::snprintf(line, sizeof(line), "%d,%d,%.7g,%.7g,%.7g,%.7g\n", e.src, e.tgt, a.x(), a.y(), b.x(), b.y());
      corr_csv.Write(std::string_view(line, static_cast<size_t>(std::max(0, n))));
    }
    // The solves are done: the compositor gets the memory (the points stay in edges.bin).
    stores_.edges().Release(&e);
  }
  return corr_csv.Commit(error) && graph_csv.Commit(error);
}

void FlightSession::DropEdgeRecords() {
  edge_records_dropped_ += engine_.edges().size();
  engine_.ReleaseEdgeRecords();
  // Most of the freed records sat on pages of their own (RecordArena): those pages go back to the system now, not
  // when records of the same size come to reuse them (none will).
  const size_t returned = RecordArena::ReturnFreeRuns();
  spdlog::info("end of flight: {} edge records dropped after the tables, {:.1f} MiB of record pages given back",
               edge_records_dropped_, static_cast<double>(returned) / kMiB);
}

namespace {

nlohmann::json SummaryJson(const Summary& s) {
  return {{"median", s.median}, {"p95", s.p95}, {"max", s.max}, {"total", s.total}, {"count", s.count}};
}

}  // namespace

nlohmann::json FlightSession::Report(const Solution& solution, const CompositeResult& composite) const {
  nlohmann::json report;
  report["frames_in"] = record_.size() + record_.skipped().size();
  report["frames_decoded"] = record_.size();
  report["dropped_by_queue"] = counters_.dropped_frames;
  const CaptureCounters& capture = counters_.capture;
  report["camera"] = {{"captured", capture.captured},
                      {"dropped_in_source", capture.dropped},
                      {"driver_gaps", capture.driver_gaps},
                      {"reconnects", capture.reconnects}};
  report["wall_s"] = static_cast<double>(MonotonicNs() - counters_.start_ns) * 1e-9;  // this run's, after a resume too
  report["resumed_frames"] = counters_.resumed_frames;
  report["open_fds"] = resources_.FdsJson();
  report["log"] = {{"warnings", LogWarnings()}, {"errors", LogErrors()}};
  report["journal_syncs"] = journal_.syncs();
  report["peak_rss_mib"] = resources_.PeakRssMiB();  // every phase's: the high-water mark is never reset
  ReportRegistration(solution, &report);
  report["memory"] = ReportMemory(solution, composite);
  nlohmann::json skipped = nlohmann::json::array();
  for (const auto& s : record_.skipped()) skipped.push_back({{"file", s.file}, {"reason", s.reason}});
  report["skipped"] = skipped;
  nlohmann::json stages;
  for (const auto& name : stats_.Stages()) stages[name] = SummaryJson(stats_.Get(name));
  report["stages_ms"] = stages;
  return report;
}

// The registration's part: residuals, refinement, the engine's counters.
void FlightSession::ReportRegistration(const Solution& solution, nlohmann::json* out) const {
  nlohmann::json& report = *out;
  report["residual_rms_px"] = solution.rms_px;
  report["residual_median_px"] = solution.median_px;
  report["residual_units"] = solution.refine.ok ? "transfer error, pixels of the target frame at working resolution"
                                                : "pixels of the reference frame at working resolution";
  report["holdout_rms_px"] = solution.holdout_final.rms;
  report["holdout_median_px"] = solution.holdout_final.median;
  report["holdout_points"] = solution.holdout_final.count;
  report["holdout_inlier_rms_px"] = solution.holdout_inliers.rms;
  report["holdout_inlier_share"] =
      solution.holdout_final.count > 0
          ? static_cast<double>(solution.holdout_inliers.count) / static_cast<double>(solution.holdout_final.count)
          : 0.0;
  report["model"] = solution.refine.ok ? ToString(solution.model) : "affine";
  report["refine"] = {{"ok", solution.refine.ok},
                      {"failure", solution.refine.failure},
                      {"iterations", solution.refine.iterations},
                      {"initial_rms_px", solution.refine.initial_rms_px},
                      {"final_rms_px", solution.refine.final_rms_px},
                      {"final_all_rms_px", solution.refine.final_all_rms_px},
                      {"inliers", solution.refine.final_inliers},
                      {"outliers_removed", solution.refine.outliers},
                      {"solver_correspondences", solution.refine.num_used},
                      {"holdout_linear_rms_px", solution.holdout_linear.rms},
                      {"holdout_other_model_rms_px", solution.holdout_other_model_rms},
                      {"correspondences", solution.refine.num_residuals},
                      {"seconds", solution.refine.seconds}};
  const RegistrationCounters rc = engine_.counters();
  report["relocalized"] = rc.relocalized;
  report["joined_on_retry"] = rc.joined_on_retry;
  report["joined_where_telemetry_placed"] = rc.joined_where_telemetry_placed;
  report["component_merges"] = rc.component_merges;
  report["edges"] = engine_.edges().size() + edge_records_dropped_;
  report["edges_added_at_end"] = rc.edges_added_at_end;
  report["feature_store"] = {{"disk_loads", stores_.features().disk_loads()},
                             {"evictions", stores_.features().evictions()}};
  const SubpixelCounters& sc = refiner_.counters();
  report["subpixel"] = {{"enabled", options_.subpixel.enabled},
                        {"cache_frames", options_.subpixel.cache_frames},
                        {"edges_refined", sc.edges_refined},
                        {"edges_not_cached", sc.edges_not_cached},
                        {"edges_kept_unrefined", sc.edges_kept_unrefined},
                        {"points_refined", sc.points_refined},
                        {"points_dropped", sc.points_dropped}};
}

// What the run took and what it gave up so that the memory budget held.
nlohmann::json FlightSession::ReportMemory(const Solution& solution, const CompositeResult& composite) const {
  const RegistrationCounters rc = engine_.counters();
  const RefineResult& refine = solution.refine;
  nlohmann::json memory = resources_.MemoryJson(plan_);
  memory["plan"]["tile_size"] = options_.mosaic.tile_size;
  memory["plan"]["compositor_threads"] = options_.mosaic.threads;
  // What did not fit and went to disk or was thinned, so that the budget held.
  memory["spilled"] = {
      {"feature_sets_evicted", stores_.features().evictions()},
      {"feature_sets_reloaded", stores_.features().disk_loads()},
      {"relocalization_thinnings", rc.relocalization_thinnings},
      {"frames_not_indexed_same_ground", rc.frames_not_indexed},
      {"edges_to_disk", rc.edges_released},
      {"edge_mib_to_disk", static_cast<double>(rc.edge_bytes_released) / kMiB},
      {"edges_reloaded_in_flight", rc.edges_reloaded},
      {"end_points_left_on_disk", rc.end_points_thinned},
      {"end_points_per_edge", rc.end_points_per_edge},
      {"edges_bin_mib", static_cast<double>(stores_.edges().bytes_written()) / kMiB},
      {"frame_redecodes", std::max(0, composite.image_loads - composite.frames_used)},
      {"refine_correspondences_skipped", refine.num_residuals - std::min(refine.num_residuals, refine.num_used)},
      {"frames_dropped_by_queue", counters_.dropped_frames}};
  return memory;
}

}  // namespace uavm
