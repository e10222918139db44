#include "core/pipeline/mosaicker.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <unordered_set>

#include "core/adjust/affine_adjuster.h"
#include "core/matching/pair_matcher.h"
#include "core/mosaic/gdal_writer.h"
#include "core/util/clock.h"
#include "core/util/memory.h"

namespace uavm {

namespace fs = std::filesystem;

namespace {

constexpr int kThumbLongSide = 320;

std::string StoredName(int id, const std::string& name) {
  char prefix[16];
  std::snprintf(prefix, sizeof(prefix), "%06d_", id);
  std::string safe = name;
  for (char& c : safe)
    if (c == '/' || c == ':' || c == '\\') c = '_';
  return prefix + safe;
}

}  // namespace

// The engine's view of the session's feature cache (features/ on disk behind a bounded memory cache).
class Mosaicker::StoreFeatures final : public FeatureProvider {
 public:
  explicit StoreFeatures(FeatureStore* store) : store_(store) {}
  std::shared_ptr<const Features> Get(int id) override { return store_->Get(id); }
  std::shared_ptr<const Features> Load(int id) override {
    auto features = std::make_shared<Features>();
    std::string err;
    if (!store_->Load(id, features.get(), &err)) {
      spdlog::warn("features of frame {}: {}", id, err);
      return nullptr;
    }
    return features;
  }
  void ReleaseAll() override {
    store_->Clear();
    TrimHeap();  // the solves and the compositor get the pages back
  }

 private:
  FeatureStore* store_;  // borrowed: the Mosaicker's
};

// The engine's view of edges.bin; null (points stay in memory) when the file could not be opened.
class Mosaicker::StoreEdges final : public EdgeSpill {
 public:
  explicit StoreEdges(EdgeStore* store) : store_(store) {}
  bool Append(Edge* edge, std::string* error) override { return store_->Append(edge, error); }
  bool Load(Edge* edge, std::string* error) override { return store_->Load(edge, error); }
  size_t Release(Edge* edge) override { return store_->Release(edge); }

 private:
  EdgeStore* store_;  // borrowed: the Mosaicker's
};

namespace {

// Without the file every edge keeps its points in memory: slower to grow flat, nothing lost.
EdgeStore* OpenEdgeStore(EdgeStore* store, const std::string& path) {
  std::string error;
  if (store->Open(path, &error)) return store;
  spdlog::warn("{}; edge points stay in memory", error);
  return nullptr;
}

}  // namespace

Mosaicker::Mosaicker(const PipelineOptions& options, SessionPaths paths)
    : options_(options),
      paths_(std::move(paths)),
      extractor_(options.features),
      feature_store_(paths_.features(), static_cast<size_t>(options.feature_cache_mib) << 20),
      store_features_(std::make_unique<StoreFeatures>(&feature_store_)),
      store_edges_(OpenEdgeStore(&edge_store_, paths_.Join("edges.bin")) != nullptr
                       ? std::make_unique<StoreEdges>(&edge_store_)
                       : nullptr),
      refiner_(options.subpixel),
      engine_(options, store_features_.get(), store_edges_.get()),
      preview_(options.preview_side),
      start_ns_(MonotonicNs()) {
  if (options.subpixel.enabled) engine_.SetRefiner(&refiner_);
  resources_.FlightStart();
  StartLiveTiles();
}

Mosaicker::~Mosaicker() = default;

void Mosaicker::RecordSkipped(const std::string& file, const std::string& reason, bool journal) {
  spdlog::warn("skipped {}: {}", file, reason);
  skipped_.push_back({file, reason});
  std::string error;
  if (journal && journal_.is_open() && !journal_.AddSkip({file, reason}, &error)) spdlog::error("{}", error);
}

bool Mosaicker::StartJournal(bool append, uint64_t valid_bytes, std::string* error) {
  return journal_.Open(paths_.Join("journal.jsonl"), append, valid_bytes, options_.journal_sync_every, error);
}

bool Mosaicker::StoreFrameBytes(int id, const Frame& frame, const std::vector<uchar>& encoded, FrameState* state,
                                std::string* error) {
  state->stored_file = paths_.frames() + "/" + StoredName(id, frame.source_name);
  std::error_code ec;
  if (!frame.source_path.empty()) {
    // The original bytes, EXIF included: the ground tool and the final composite read them at full resolution.
    fs::copy_file(frame.source_path, state->stored_file, fs::copy_options::overwrite_existing, ec);
    if (ec) {
      *error = "cannot store frame " + frame.source_name + ": " + ec.message();
      return false;
    }
    return true;
  }
  if (fs::path(state->stored_file).extension() != ".jpg") state->stored_file += ".jpg";
  if (encoded.empty() || !WriteFileAtomic(state->stored_file, std::string(encoded.begin(), encoded.end()), error)) {
    *error = "cannot store frame " + frame.source_name + (error->empty() ? "" : ": " + *error);
    return false;
  }
  return true;
}

void Mosaicker::UpdatePreview(int id, const cv::Mat& work_bgr) {
  if (options_.preview_every <= 0) return;
  const double s = std::min(1.0, kThumbLongSide / static_cast<double>(std::max(work_bgr.cols, work_bgr.rows)));
  cv::Mat thumb;
  cv::resize(work_bgr, thumb, cv::Size(), s, s, cv::INTER_AREA);
  const Mat3 work_from_thumb =
      ResizeMap(static_cast<double>(thumb.cols) / work_bgr.cols, static_cast<double>(thumb.rows) / work_bgr.rows)
          .inverse();
  preview_.Add(thumb, engine_.mosaic_from_work(id) * work_from_thumb);
  AddLiveGeorefPoint(id);
  if (static_cast<int>(frames_.size()) % options_.preview_every == 0) {
    std::string err;
    if (!preview_.Write(paths_.Join("live.jpg"), &err)) spdlog::warn("live preview: {}", err);
    auto georef = UpdateLiveGeoref();
    if (preview_listener_) preview_listener_(preview_.last_jpeg(), std::move(georef));
    PublishLiveFootprints();
  }
}

Mosaicker::Prepared Mosaicker::Prepare(Frame frame) const {
  Prepared p = PrepareImages(std::move(frame));
  DetectFeatures(&p);
  return p;
}

void Mosaicker::DetectFeatures(Prepared* p) const {
  StageTimer t;
  p->features = extractor_.Extract(p->work_gray);
  WorkLens(p->frame, p->work_gray.size()).UndistortPoints(&p->features.points);
  p->features_ms = t.ElapsedMs();
}

Mosaicker::Prepared Mosaicker::PrepareStored(Frame frame, int id, const std::string& stored_name) const {
  const std::string stored = stored_name;
  frame.source_path = paths_.frames() + "/" + stored_name;  // a path: nothing gets encoded
  Prepared p = PrepareImages(std::move(frame));
  p.resumed = true;
  p.stored_name = stored_name;
  std::string error;
  StageTimer t;
  if (!feature_store_.Load(id, &p.features, &error)) {
    spdlog::warn("resume: {}; detecting features of {} again", error, stored);
    p.features = extractor_.Extract(p.work_gray);
    WorkLens(p.frame, p.work_gray.size()).UndistortPoints(&p.features.points);
  }
  p.features_ms = t.ElapsedMs();
  return p;
}

Mosaicker::Prepared Mosaicker::PrepareImages(Frame frame) const {
  StageTimer t;
  Prepared p;
  const int long_side = std::max(frame.original_size.width, frame.original_size.height);
  const double s = std::min(1.0, options_.work_long_side / static_cast<double>(long_side));
  const cv::Size work_size(std::max(1, static_cast<int>(std::lround(frame.original_size.width * s))),
                           std::max(1, static_cast<int>(std::lround(frame.original_size.height * s))));
  if (frame.image.size() == work_size)
    p.work_bgr = frame.image;
  else
    cv::resize(frame.image, p.work_bgr, work_size, 0, 0, cv::INTER_AREA);
  cv::cvtColor(p.work_bgr, p.work_gray, cv::COLOR_BGR2GRAY);
  // Features are found on the recorded pixels (no resampling) and their positions undistorted (Prepare); the live
  // view, thumbnails and tiles draw the ideal image, on which the maps act.
  const Undistorter& lens = WorkLens(frame, work_size);
  if (lens.active()) p.work_bgr = lens.UndistortImage(p.work_bgr);
  if (frame.source_path.empty()) {
    // No file to copy into the session (camera, video, simulation): encode here, on the capture thread.
    try {
      cv::imencode(".jpg", frame.image, p.encoded, {cv::IMWRITE_JPEG_QUALITY, 95});
    } catch (const cv::Exception&) {
      p.encoded.clear();
    }
  }
  frame.image.release();  // the decoded original is not needed any more: keep queued frames small
  p.prepare_ms = t.ElapsedMs();
  p.frame = std::move(frame);
  return p;
}

cv::Mat Mosaicker::IdealGray(const Prepared& p) const {
  if (!WorkLens(p.frame, p.work_gray.size()).active()) return p.work_gray;
  cv::Mat gray;  // the features' coordinates are the undistorted image's
  cv::cvtColor(p.work_bgr, gray, cv::COLOR_BGR2GRAY);
  return gray;
}

bool Mosaicker::StoreFrame(int id, const Prepared& prepared, FrameState* st) {
  const Frame& frame = prepared.frame;
  std::string error;
  if (prepared.resumed) {
    st->stored_file = paths_.frames() + "/" + prepared.stored_name;
    feature_store_.Adopt(id, prepared.features);
    ++resumed_frames_;
    return true;
  }
  if (!StoreFrameBytes(id, frame, prepared.encoded, st, &error)) {
    // The session is to blame unless the source's file itself went away (a vanishing source is the source's error).
    std::error_code ec;
    if (frame.source_path.empty() || fs::exists(frame.source_path, ec)) storage_failure_ = error;
  } else if (!feature_store_.Put(id, prepared.features, &error)) {
    storage_failure_ = error;
  } else {
    // Accepted: its bytes and features are in the session, so a resumed run will find it.
    JournalFrame jf{id,
                    st->name,
                    fs::path(st->stored_file).filename().string(),
                    st->timestamp_ns,
                    st->original_size.width,
                    st->original_size.height};
    jf.latitude_deg = st->metadata.latitude_deg;
    jf.longitude_deg = st->metadata.longitude_deg;
    jf.relative_altitude_m = st->metadata.relative_altitude_m;
    jf.yaw_deg = st->metadata.flight_yaw_deg;
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

FrameOutcome Mosaicker::AddFrame(Prepared prepared) {
  StageTimer frame_timer;
  StageTimer t;
  const Frame& frame = prepared.frame;
  HandEngineTheCamera(prepared.work_bgr.size());
  const int id = engine_.AddFrame(prepared.work_bgr.size());
  if (memory_plan_.frames_reserved > 0 && id == memory_plan_.frames_reserved)
    spdlog::warn(
        "the flight is longer than the {} frames the memory plan reserved per-frame state for (max_flight_frames, "
        "at most 15 % of the budget): each further frame takes ~6.5 KiB beyond the plan",
        memory_plan_.frames_reserved);
  FrameState& st = frames_.emplace_back();
  st.id = id;
  st.name = frame.source_name;
  st.original_size = frame.original_size;
  st.timestamp_ns = frame.timestamp_ns;
  st.metadata = frame.metadata;
  st.work_from_original = ResizeMap(static_cast<double>(prepared.work_bgr.cols) / frame.original_size.width,
                                    static_cast<double>(prepared.work_bgr.rows) / frame.original_size.height);
  st.work_size = prepared.work_bgr.size();
  if (!StoreFrame(id, prepared, &st)) return FrameOutcome::kFailed;
  const cv::Mat thumb = StoreThumbnail(id, prepared.work_bgr);
  stats_.Add("prepare", prepared.prepare_ms + t.ElapsedMs());
  stats_.Add("features", prepared.features_ms);
  if (prepared.decode_ms > 0) stats_.Add("decode", prepared.decode_ms);
  Features& feats = prepared.features;
  // Match on the 8-bit values, exactly what later queries from the store will see.
  feats.descriptors = DequantizeDescriptors(QuantizeDescriptors(feats.descriptors));
  RegisterTiming timing;
  const std::optional<PositionHint> hint = PositionHintFor(st.metadata);
  const size_t edges_before = engine_.edges().size();
  if (options_.subpixel.enabled) refiner_.Put(id, IdealGray(prepared));
  const FrameOutcome outcome = engine_.Register(id, feats, &timing, hint ? &*hint : nullptr);
  stats_.Add("matching", timing.matching_ms);
  stats_.Add("adjust", timing.adjust_ms);
  t.Restart();
  const cv::Mat live_bgr = LiveViewImage(id, prepared.work_bgr, thumb, edges_before);
  if (engine_.frame(id).failure.empty() || id == 0) UpdatePreview(id, live_bgr);
  stats_.Add("preview", t.ElapsedMs());
  t.Restart();
  UpdateLiveTiles(id, live_bgr);
  if (live_tiles_) stats_.Add("live_tiles", t.ElapsedMs());  // the frame loop's share; the drawing is the worker's
  // Every few frames, not every frame: a trim walks the arenas (~1 ms).
  if (options_.trim_heap_every > 0 && id % options_.trim_heap_every == 0) TrimHeap();
  const double frame_ms = frame_timer.ElapsedMs();
  stats_.Add("frame_total", frame_ms);
  // One line per frame at debug level: bench/flight_length.sh draws the per-frame cost along a flight from it.
  spdlog::debug("frame {} ({}) processed in {:.1f} ms", id, st.name, frame_ms);
  return outcome;
}

bool Mosaicker::Finish(std::string* error) {
  resources_.FlightEnd();
  StopLiveTilesForFinalTiles();
  solution_ = engine_.Finish([this](const std::string& phase) { resources_.EnterPhase(phase); });
  if (!solution_.ok) {
    *error = solution_.failure;
    return false;
  }
  if (solution_.component.size() >= 2) {
    stats_.Add("final_adjust", solution_.adjust_ms);
    stats_.Add("refine", solution_.refine_ms);
  }
  final_registered_ = static_cast<int>(solution_.component.size());
  spdlog::info("registered {}/{} frames, residual RMS {:.3f} px (median {:.3f}) at working resolution",
               final_registered_, frames_.size(), solution_.rms_px, solution_.median_px);
  resources_.EnterPhase("radiometry");
  SolveFrameRadiometry(solution_.component);
  if (!WriteOutputs(solution_.component, error)) return false;
  std::string journal_error;
  if (journal_.is_open() && !journal_.AddFinished(&journal_error)) spdlog::warn("{}", journal_error);
  return true;
}

}  // namespace uavm
