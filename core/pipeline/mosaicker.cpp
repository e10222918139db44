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

Edge EdgeFromPair(int src, int tgt, PairResult&& r) {
  Edge e;
  e.src = src;
  e.tgt = tgt;
  e.num_matches = r.num_matches;
  e.num_inliers = r.num_inliers;
  e.tgt_from_src = r.tgt_from_src;
  e.src_points = std::move(r.src_points);
  e.tgt_points = std::move(r.tgt_points);
  e.holdout_src_points = std::move(r.holdout_src_points);
  e.holdout_tgt_points = std::move(r.holdout_tgt_points);
  return e;
}

std::string StoredName(int id, const std::string& name) {
  char prefix[16];
  std::snprintf(prefix, sizeof(prefix), "%06d_", id);
  std::string safe = name;
  for (char& c : safe)
    if (c == '/' || c == ':' || c == '\\') c = '_';
  return prefix + safe;
}

}  // namespace

Mosaicker::Mosaicker(const PipelineOptions& options, SessionPaths paths)
    : options_(options),
      paths_(std::move(paths)),
      extractor_(options.features),
      feature_store_(paths_.features(), static_cast<size_t>(options.feature_cache_mib) << 20),
      global_index_(options.relocalization),
      preview_(options.preview_side),
      start_ns_(MonotonicNs()) {
  fds_at_start_ = OpenFileDescriptors();
  std::string error;
  // Without the file every edge keeps its points in memory: slower to grow flat, nothing lost.
  if (!edge_store_.Open(paths_.Join("edges.bin"), &error)) spdlog::warn("{}; edge points stay in memory", error);
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

bool Mosaicker::StoreFrameBytes(const hal::Frame& frame, const std::vector<uchar>& encoded, FrameState* state,
                                std::string* error) {
  state->stored_file = paths_.frames() + "/" + StoredName(state->id, frame.source_name);
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

const std::vector<int>& Mosaicker::MembersOf(int root) {
  static const std::vector<int> kNone;
  // A frame that registered nothing is a component of its own, outside the graph.
  return frames_[static_cast<size_t>(components_.Find(root))].in_graph ? components_.MembersOf(root) : kNone;
}

std::vector<const Edge*> Mosaicker::EdgesTouching(const std::unordered_set<int>& ids, int root) {
  std::vector<size_t> indices;
  for (int id : ids)
    for (size_t ei : adjacency_[static_cast<size_t>(id)]) indices.push_back(ei);
  // In the graph's order, each edge once: the adjustment then sums its terms in the same order as over all edges.
  std::sort(indices.begin(), indices.end());
  indices.erase(std::unique(indices.begin(), indices.end()), indices.end());
  std::vector<const Edge*> out;
  for (size_t ei : indices) {
    const Edge& e = graph_.edges()[ei];
    if (components_.Find(e.src) == root && components_.Find(e.tgt) == root) out.push_back(&e);
  }
  return out;
}

void Mosaicker::AddEdge(Edge edge) {
  best_inliers_ = std::max(best_inliers_, edge.num_inliers);
  RoundToFloat(&edge);  // what edges.bin keeps: a reloaded edge gives the same solution
  if (edge_store_.is_open()) {
    std::string error;
    if (!edge_store_.Append(&edge, &error)) {
      spdlog::warn("{}; edge points stay in memory from now on", error);
      edge_store_.Close();
    }
  }
  const size_t index = graph_.edges().size();
  adjacency_[static_cast<size_t>(edge.src)].push_back(index);
  adjacency_[static_cast<size_t>(edge.tgt)].push_back(index);
  graph_.AddEdge(std::move(edge));
}

void Mosaicker::ReleaseColdEdges() {
  if (options_.solve_window <= 0 || !edge_store_.is_open()) return;
  // Edges are appended as frames arrive, so an edge's newest frame rarely goes back in time: the scan stops at the
  // first edge still in the window. A solve that needs a released edge after all (a merged component) reloads it.
  const int cold_below = static_cast<int>(frames_.size()) - options_.solve_window;
  auto& edges = graph_.mutable_edges();
  for (; release_cursor_ < edges.size(); ++release_cursor_) {
    Edge& e = edges[release_cursor_];
    if (std::max(e.src, e.tgt) >= cold_below) break;
    const size_t bytes = edge_store_.Release(&e);
    if (bytes > 0) {
      ++edges_released_;
      edge_bytes_released_ += bytes;
    }
  }
}

bool Mosaicker::LoadEdgePoints(const std::vector<const Edge*>& edges) {
  for (const Edge* e : edges) {
    if (e->points_resident) continue;
    // The list borrows the graph's edges read-only; the graph (this object's) owns them mutably.
    Edge& edge = const_cast<Edge&>(*e);
    std::string error;
    if (!edge_store_.Load(&edge, &error)) {
      spdlog::error("{}", error);
      return false;
    }
  }
  return true;
}

// Re-expresses every frame of `other_root`'s component by `other_fix` (new = fix * old) and unites the two.
void Mosaicker::MergeInto(int keep_root, int other_root, const Mat3& other_fix) {
  for (int id : MembersOf(other_root)) {
    mosaic_from_work_[id] = other_fix * mosaic_from_work_[id];
    Place(id);
  }
  components_.Unite(keep_root, other_root);
  ++merges_;
  --num_components_;
}

void Mosaicker::FullSolve(int root) {
  const std::vector<int>& members = MembersOf(root);  // ascending ids
  if (members.size() < 2) return;
  const int anchor = members.front();
  // During the flight only the newest solve_window frames move (the rest is their fixed frame of reference): the
  // solve's memory and time stay bounded however long the flight. The end of the flight solves everything.
  const size_t window = options_.solve_window > 0 ? static_cast<size_t>(options_.solve_window) : members.size();
  std::unordered_set<int> variable(members.end() - static_cast<long>(std::min(window, members.size())), members.end());
  variable.erase(anchor);
  std::unordered_map<int, double> half_diag;  // the adjustment weighs its terms by the moving frames' sizes only
  for (int id : variable) half_diag[id] = frames_[static_cast<size_t>(id)].half_diagonal;
  // Only edges that touch a moving frame take part (AdjustAffine skips the others): found through the moving frames'
  // adjacency, so a windowed solve costs the window, not the component.
  std::vector<const Edge*> edges = EdgesTouching(variable, components_.Find(root));
  std::vector<const Edge*> needed;
  for (const Edge* e : edges)
    if (!e->points_resident) needed.push_back(e);
  if (!LoadEdgePoints(needed)) spdlog::warn("full adjustment without some edges (edges.bin unreadable)");
  edges_reloaded_ += needed.size();
  const auto result = AdjustAffine(edges, variable, half_diag, options_.adjust, &mosaic_from_work_);
  for (int id : variable) Place(id);
  ReleaseColdEdges();
  if (!result.ok) spdlog::warn("full adjustment failed: {}", result.failure);
  registered_since_full_ = 0;
}

bool Mosaicker::IsNewGround(int id) {
  const FrameState& me = frames_[static_cast<size_t>(id)];
  const double spacing = options_.relocalization.keyframe_spacing;
  // A frame that is not placed yet may be anywhere: it is indexed so that a later frame can find it.
  if (spacing <= 0 || !me.in_graph) return true;
  const auto work_centre = [](const FrameState& f) {
    return Vec2(0.5 * (f.work_size.width - 1), 0.5 * (f.work_size.height - 1));
  };
  const auto centre_of = [&](const FrameState& f) { return Apply(mosaic_from_work_[f.id], work_centre(f)); };
  const Vec2 c = centre_of(me);
  const double radius = spacing * me.half_diagonal * LocalScale(mosaic_from_work_[id], work_centre(me));
  const int root = components_.Find(id);
  // A keyframe whose centre is that close lies in a footprint that meets this square: the grid finds it.
  const cv::Rect2d near(c.x() - radius, c.y() - radius, 2.0 * radius, 2.0 * radius);
  for (int k : footprints_.Query(near)) {
    const FrameState& f = frames_[static_cast<size_t>(k)];
    if (f.keyframe && f.in_graph && components_.Find(k) == root && (centre_of(f) - c).norm() < radius) return false;
  }
  return true;
}

void Mosaicker::Place(int id) {
  const FrameState& f = frames_[static_cast<size_t>(id)];
  footprints_.Set(
      id, cv::Rect2d(cv::boundingRect(Footprint(mosaic_from_work_[id], f.work_size.width, f.work_size.height))));
}

void Mosaicker::UpdatePreview(int id, const cv::Mat& work_bgr) {
  if (options_.preview_every <= 0) return;
  const double s = std::min(1.0, kThumbLongSide / static_cast<double>(std::max(work_bgr.cols, work_bgr.rows)));
  cv::Mat thumb;
  cv::resize(work_bgr, thumb, cv::Size(), s, s, cv::INTER_AREA);
  const Mat3 work_from_thumb =
      ResizeMap(static_cast<double>(thumb.cols) / work_bgr.cols, static_cast<double>(thumb.rows) / work_bgr.rows)
          .inverse();
  preview_.Add(thumb, mosaic_from_work_[id] * work_from_thumb);
  if (static_cast<int>(frames_.size()) % options_.preview_every == 0) {
    std::string err;
    if (!preview_.Write(paths_.Join("live.jpg"), &err)) spdlog::warn("live preview: {}", err);
    if (preview_listener_) preview_listener_(preview_.last_jpeg());
  }
}

bool Mosaicker::TryJoin(int new_id, int other_id, const DescriptorIndex& index, const Features& feats) {
  auto other = feature_store_.Get(other_id);
  if (!other) return false;
  PairResult r = MatchPair(index, feats, *other, options_.matching);
  if (!r.ok || r.num_inliers < options_.relative_inlier_fraction * best_inliers_) return false;
  Edge e = EdgeFromPair(other_id, new_id, std::move(r));
  // mosaic_from_work(other) should become T_new * new_from_other; the other component moves with it.
  const Mat3 fix = mosaic_from_work_[new_id] * e.tgt_from_src * mosaic_from_work_[other_id].inverse();
  AddEdge(std::move(e));
  MergeInto(components_.Find(new_id), components_.Find(other_id), fix);
  FullSolve(components_.Find(new_id));
  return true;
}

void Mosaicker::TryRetries(int new_id, const DescriptorIndex& index, const Features& feats) {
  const int budget = std::min<int>(options_.retry_per_frame, static_cast<int>(retry_.size()));
  for (int k = 0; k < budget; ++k) {
    auto [id, attempts] = retry_.front();
    retry_.pop_front();
    if (components_.Find(id) == components_.Find(new_id)) continue;  // already joined through another frame
    if (TryJoin(new_id, id, index, feats)) {
      ++retried_ok_;
      spdlog::info("frame {} joined the mosaic on retry (via frame {})", frames_[static_cast<size_t>(id)].name,
                   frames_[static_cast<size_t>(new_id)].name);
      continue;
    }
    if (attempts + 1 < options_.retry_max_attempts) retry_.emplace_back(id, attempts + 1);
  }
}

void Mosaicker::Bridge(int new_id, const DescriptorIndex& index, const Features& feats) {
  // The flight is in pieces (a strip flown elsewhere first, a lost frame): look for the new frame's look-alikes in
  // other components. The global index answers from a tree rebuilt every few frames, so this costs one search.
  int tried = 0;
  for (int c : global_index_.Query(feats, 2 * options_.bridge_candidates, /*allow_stale=*/true)) {
    if (tried >= options_.bridge_candidates) break;
    if (components_.Find(c) == components_.Find(new_id)) continue;
    ++tried;
    if (TryJoin(new_id, c, index, feats))
      spdlog::info("frame {} joined two parts of the flight (via frame {})", frames_[static_cast<size_t>(new_id)].name,
                   frames_[static_cast<size_t>(c)].name);
  }
}

Mosaicker::Prepared Mosaicker::Prepare(hal::Frame frame) const {
  Prepared p = PrepareImages(std::move(frame));
  StageTimer t;
  p.features = extractor_.Extract(p.work_gray);
  p.features_ms = t.ElapsedMs();
  return p;
}

Mosaicker::Prepared Mosaicker::PrepareStored(hal::Frame frame, int id, const std::string& stored_name) const {
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
  }
  p.features_ms = t.ElapsedMs();
  return p;
}

Mosaicker::Prepared Mosaicker::PrepareImages(hal::Frame frame) const {
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

FrameOutcome Mosaicker::AddFrame(Prepared prepared) {
  StageTimer frame_timer;
  StageTimer t;
  hal::Frame& frame = prepared.frame;
  const int id = static_cast<int>(frames_.size());
  frames_.emplace_back();
  adjacency_.emplace_back();
  components_.Add();
  graph_.AddNode(id);
  FrameState& st = frames_.back();
  st.id = id;
  st.name = frame.source_name;
  st.original_size = frame.original_size;
  st.timestamp_ns = frame.timestamp_ns;
  st.metadata = frame.metadata;
  st.work_size = prepared.work_bgr.size();
  st.work_from_original = ResizeMap(static_cast<double>(st.work_size.width) / frame.original_size.width,
                                    static_cast<double>(st.work_size.height) / frame.original_size.height);
  st.half_diagonal = 0.5 * std::hypot(st.work_size.width, st.work_size.height);
  const cv::Mat& work_bgr = prepared.work_bgr;
  std::string error;
  if (prepared.resumed) {
    st.stored_file = paths_.frames() + "/" + prepared.stored_name;
  } else if (!StoreFrameBytes(frame, prepared.encoded, &st, &error)) {
    st.failure = error;
    // The session is to blame unless the source's file itself went away (a vanishing source is the source's error).
    std::error_code ec;
    if (frame.source_path.empty() || fs::exists(frame.source_path, ec)) storage_failure_ = error;
    spdlog::error("{}", error);
    return FrameOutcome::kFailed;
  }
  stats_.Add("prepare", prepared.prepare_ms + t.ElapsedMs());
  stats_.Add("features", prepared.features_ms);
  if (prepared.decode_ms > 0) stats_.Add("decode", prepared.decode_ms);
  t.Restart();
  Features& feats = prepared.features;
  if (prepared.resumed) {
    feature_store_.Adopt(id, feats);
    ++resumed_frames_;
  } else {
    if (!feature_store_.Put(id, feats, &error)) {
      st.failure = error;
      storage_failure_ = error;
      spdlog::error("{}", error);
      return FrameOutcome::kFailed;
    }
    // Accepted: its bytes and features are in the session, so a resumed run will find it.
    if (journal_.is_open() && !journal_.AddFrame({id, st.name, fs::path(st.stored_file).filename().string(),
                                                  st.timestamp_ns, st.original_size.width, st.original_size.height},
                                                 &error)) {
      // The frame itself is stored, but a journal that cannot grow means the disk is full: stop here.
      spdlog::error("{}; a resumed run would take this frame from the source again", error);
      storage_failure_ = error;
    }
  }
  st.has_features = true;
  // Match on the 8-bit values, exactly what later queries from the store will see.
  feats.descriptors = DequantizeDescriptors(QuantizeDescriptors(feats.descriptors));
  const DescriptorIndex index(feats, options_.matching);

  std::unordered_set<int> tried;
  struct Found {
    Edge edge;
  };
  std::vector<Found> found;
  bool have_estimate = false;  // mosaic_from_work_[id] holds a first estimate once a candidate matched
  auto try_candidate = [&](int cand) {
    if (!tried.insert(cand).second) return;
    auto other = feature_store_.Get(cand);
    if (!other) return;
    MatchGuide guide;
    const bool guided = have_estimate && components_.Find(cand) == components_.Find(found.front().edge.src);
    if (guided) {
      guide.tgt_from_src = mosaic_from_work_[id].inverse() * mosaic_from_work_[cand];
      guide.tgt_size = st.work_size;
    }
    PairResult r = MatchPair(index, feats, *other, options_.matching, guided ? &guide : nullptr);
    if (!r.ok) return;
    if (r.num_inliers < options_.relative_inlier_fraction * best_inliers_) return;
    found.push_back({EdgeFromPair(cand, id, std::move(r))});
    if (!have_estimate) {
      mosaic_from_work_[id] = mosaic_from_work_[cand] * found.back().edge.tgt_from_src.inverse();
      have_estimate = true;
    }
  };

  // 1) the last K frames that are in the graph.
  int taken = 0;
  for (int c = id - 1; c >= 0 && taken < options_.recent_candidates; --c) {
    if (!frames_[static_cast<size_t>(c)].has_features || !frames_[static_cast<size_t>(c)].in_graph) continue;
    try_candidate(c);
    ++taken;
  }
  // 2) relocalisation through the global index when the recent frames gave nothing.
  if (found.empty() && options_.relocalization_candidates > 0) {
    for (int c : global_index_.Query(feats, options_.relocalization_candidates)) try_candidate(c);
    if (!found.empty()) {
      ++relocalized_;
      spdlog::info("frame {} relocalised against frame {}", st.name,
                   frames_[static_cast<size_t>(found[0].edge.src)].name);
    }
  }
  int root = -1;
  if (!found.empty()) {
    // Base component: the largest one touched; the new frame's first estimate comes from its strongest edge there.
    std::map<int, int> size_of_root;
    for (const auto& f : found) size_of_root[components_.Find(f.edge.src)] = components_.SizeOf(f.edge.src);
    root = std::max_element(size_of_root.begin(), size_of_root.end(), [](const auto& a, const auto& b) {
             return a.second < b.second;
           })->first;
    const Edge* best = nullptr;
    for (const auto& f : found)
      if (components_.Find(f.edge.src) == root && (best == nullptr || f.edge.num_inliers > best->num_inliers))
        best = &f.edge;
    mosaic_from_work_[id] = mosaic_from_work_[best->src] * best->tgt_from_src.inverse();
    // 3) frames of that component whose footprint overlaps the estimate: closes loops between strips.
    // (The new frame is not united with `root` yet: its component is named explicitly.)
    for (int c : OverlapCandidates(id, root, tried)) try_candidate(c);
  }
  stats_.Add("matching", t.ElapsedMs());

  t.Restart();
  FrameOutcome outcome = FrameOutcome::kRegistered;
  if (found.empty()) {
    // A component of its own until a later frame connects it.
    mosaic_from_work_[id] = Mat3::Identity();
    st.in_graph = true;
    Place(id);
    ++num_components_;
    if (id == 0) {
      spdlog::info("frame {} starts the mosaic", st.name);
    } else {
      st.failure = "no verified match with any candidate";
      if (options_.retry_list_size > 0) {
        if (static_cast<int>(retry_.size()) >= options_.retry_list_size) retry_.pop_front();  // oldest gives way
        retry_.emplace_back(id, 0);
      }
      spdlog::info("frame {} matched none of {} candidates; kept for retry", st.name, tried.size());
    }
    outcome = id == 0 ? FrameOutcome::kRegistered : FrameOutcome::kNewComponent;
  } else {
    st.in_graph = true;
    std::vector<Edge> edges;
    for (auto& f : found) edges.push_back(std::move(f.edge));
    // Merge every other touched component into the base one, through the new frame.
    bool merged = false;
    for (const auto& e : edges) {
      const int other = components_.Find(e.src);
      if (other == components_.Find(root) || other == components_.Find(id)) continue;
      const Mat3 fix = mosaic_from_work_[id] * e.tgt_from_src * mosaic_from_work_[e.src].inverse();
      MergeInto(components_.Find(root), other, fix);
      merged = true;
    }
    components_.Unite(root, id);
    for (auto& e : edges) AddEdge(std::move(e));
    // Local update: only the new frame moves.
    std::unordered_map<int, double> half_diag{{id, st.half_diagonal}};
    std::vector<const Edge*> local;
    for (size_t ei : adjacency_[static_cast<size_t>(id)]) local.push_back(&graph_.edges()[ei]);
    const auto r = AdjustAffine(local, {id}, half_diag, options_.adjust, &mosaic_from_work_);
    if (!r.ok) spdlog::warn("local adjustment of {} failed: {}", st.name, r.failure);
    Place(id);
    st.failure.clear();
    // Full solves get rarer as the component grows (every max(N, size/20) frames): their cost grows with the
    // flight, and between them each new frame is still solved against all its neighbours, old strips included.
    const int solved =
        options_.solve_window > 0 ? std::min(components_.SizeOf(id), options_.solve_window) : components_.SizeOf(id);
    const int interval = std::max(options_.full_solve_every, solved / 20);
    if (++registered_since_full_ >= interval || merged) FullSolve(components_.Find(id));
    TryRetries(id, index, feats);
    if (num_components_ > 1 && options_.bridge_candidates > 0) Bridge(id, index, feats);
  }
  if (IsNewGround(id)) {
    global_index_.Add(id, feats);
    st.keyframe = true;
  } else {
    ++frames_not_indexed_;
  }
  stats_.Add("adjust", t.ElapsedMs());
  t.Restart();
  if (st.failure.empty() || id == 0) UpdatePreview(id, work_bgr);
  stats_.Add("preview", t.ElapsedMs());
  // Every few frames, not every frame: a trim walks the arenas (~1 ms).
  if (options_.trim_heap_every > 0 && id % options_.trim_heap_every == 0) TrimHeap();
  const double frame_ms = frame_timer.ElapsedMs();
  stats_.Add("frame_total", frame_ms);
  // One line per frame at debug level: bench/flight_length.sh draws the per-frame cost along a flight from it.
  spdlog::debug("frame {} processed in {:.1f} ms", id, frame_ms);
  return outcome;
}

std::vector<int> Mosaicker::OverlapCandidates(int id, int root, const std::unordered_set<int>& exclude) {
  std::vector<int> out;
  if (options_.overlap_candidates <= 0) return out;
  const FrameState& me = frames_[static_cast<size_t>(id)];
  const auto fp_me = Footprint(mosaic_from_work_[id], me.work_size.width, me.work_size.height);
  const cv::Rect2d box_me = cv::boundingRect(fp_me);
  const double area_me = PolygonArea(fp_me);
  if (!(area_me > 0)) return out;
  std::vector<std::pair<double, int>> overlaps;
  // Only frames whose footprint box meets this one's can overlap it: the grid gives them without a scan.
  for (int candidate : footprints_.Query(box_me)) {
    const FrameState& f = frames_[static_cast<size_t>(candidate)];
    if (f.id == id || !f.in_graph || exclude.count(f.id) != 0 || components_.Find(f.id) != components_.Find(root))
      continue;
    const auto fp = Footprint(mosaic_from_work_[f.id], f.work_size.width, f.work_size.height);
    if ((cv::Rect2d(cv::boundingRect(fp)) & box_me).area() <= 0) continue;
    const double a = ConvexOverlapArea(fp_me, fp);
    if (a / area_me >= options_.min_overlap_fraction) overlaps.emplace_back(a, f.id);
  }
  std::sort(overlaps.rbegin(), overlaps.rend());
  for (size_t k = 0; k < overlaps.size() && static_cast<int>(k) < options_.overlap_candidates; ++k)
    out.push_back(overlaps[k].second);
  return out;
}

// Frames only get to choose overlap candidates when they arrive, so the first frames of a flight (and any frame
// whose neighbours came later) have fewer edges than the rest: on simulated flights the first frame carried 3-4x the
// error of the others. At the end, frames with fewer edges than a new frame normally makes are matched against the
// frames that now overlap them (bounded: at most kMaxFrames frames, M candidates each).
void Mosaicker::Densify() {
  constexpr int kMaxFrames = 64;
  const int wanted = options_.recent_candidates + options_.overlap_candidates;
  int done = 0;
  for (auto& f : frames_) {
    if (done >= kMaxFrames) break;
    if (!f.in_graph || !f.has_features || static_cast<int>(adjacency_[static_cast<size_t>(f.id)].size()) >= wanted)
      continue;
    std::unordered_set<int> linked{f.id};
    for (size_t ei : adjacency_[static_cast<size_t>(f.id)]) {
      linked.insert(graph_.edges()[ei].src);
      linked.insert(graph_.edges()[ei].tgt);
    }
    const std::vector<int> candidates = OverlapCandidates(f.id, f.id, linked);
    if (candidates.empty()) continue;
    ++done;
    auto mine = feature_store_.Get(f.id);
    if (!mine) continue;
    const DescriptorIndex index(*mine, options_.matching);
    for (int other_id : candidates) {
      auto other = feature_store_.Get(other_id);
      if (!other) continue;
      MatchGuide guide;
      guide.tgt_from_src = mosaic_from_work_[f.id].inverse() * mosaic_from_work_[other_id];
      guide.tgt_size = f.work_size;
      PairResult r = MatchPair(index, *mine, *other, options_.matching, &guide);
      if (!r.ok || r.num_inliers < options_.relative_inlier_fraction * best_inliers_) continue;
      AddEdge(EdgeFromPair(other_id, f.id, std::move(r)));
      ++densified_edges_;
    }
  }
}

bool Mosaicker::Finish(std::string* error) {
  StageTimer t;
  flight_peak_rss_mib_ = std::max(PeakRssMiB(), HighWaterRssMiB());
  flight_end_rss_mib_ = CurrentRssMiB();
  flight_end_heap_ = CurrentHeapStats();
  fds_at_flight_end_ = OpenFileDescriptors();
  ResetPeakRss();
  Densify();
  // Nothing after this point matches features: their memory goes to the refinement and the compositor.
  feature_store_.Clear();
  global_index_.Release();
  TrimHeap();
  // Largest component over edges that pass both thresholds against the final best pair.
  std::vector<int> component =
      graph_.LargestComponent(options_.relative_inlier_fraction, options_.matching.min_inliers);
  if (frames_.empty()) component.clear();
  std::unordered_set<int> in_component(component.begin(), component.end());
  std::vector<Edge> pruned_out;
  std::vector<const Edge*> edges;
  for (const auto& e : graph_.edges())
    if (in_component.count(e.src) != 0 && in_component.count(e.tgt) != 0 &&
        graph_.EdgeCounts(e, options_.relative_inlier_fraction, options_.matching.min_inliers))
      edges.push_back(&e);
  // The final solves use every edge: the points given back during the flight come back from edges.bin.
  if (!LoadEdgePoints(edges)) spdlog::warn("final adjustment without some edges (edges.bin unreadable)");
  double rms = 0.0;
  double median = 0.0;
  if (component.size() >= 2) {
    // Re-anchor on the first frame (identity), then one full solve.
    const int anchor = component.front();
    const Mat3 fix = mosaic_from_work_[anchor].inverse();
    for (int id : component) mosaic_from_work_[id] = fix * mosaic_from_work_[id];
    std::unordered_set<int> variable(component.begin() + 1, component.end());
    std::unordered_map<int, double> half_diag;
    for (int id : component) half_diag[id] = frames_[static_cast<size_t>(id)].half_diagonal;
    const auto r = AdjustAffine(edges, variable, half_diag, options_.adjust, &mosaic_from_work_);
    if (!r.ok) {
      *error = "final adjustment failed: " + r.failure;
      return false;
    }
    rms = r.rms_px;
    median = r.median_px;
    stats_.Add("final_adjust", t.ElapsedMs());
    holdout_linear_ = TransferErrors(edges, mosaic_from_work_, true);
    // Refinement: transfer errors in frame pixels (no pull to shrink towards the anchor) and, with the homography
    // model, each frame's perspective.
    StageTimer refine_timer;
    RefineResult rr = RefineGlobal(edges, variable, anchor, half_diag, options_.refine, &mosaic_from_work_);
    refined_model_ = options_.refine.model;
    if (!rr.ok && options_.refine.model == MotionModel::kHomography) {
      spdlog::warn("homography refinement refused ({}); refining affine maps instead", rr.failure);
      RefineOptions affine = options_.refine;
      affine.model = MotionModel::kAffine;
      rr = RefineGlobal(edges, variable, anchor, half_diag, affine, &mosaic_from_work_);
      refined_model_ = MotionModel::kAffine;
    }
    refine_ = rr;
    stats_.Add("refine", refine_timer.ElapsedMs());
    holdout_final_ = TransferErrors(edges, mosaic_from_work_, true);
    holdout_inliers_ = TransferErrors(edges, mosaic_from_work_, true, options_.refine.outlier_px);
    if (rr.ok) {
      rms = rr.final_rms_px;
      median = rr.final_median_px;
      spdlog::info(
          "{} refinement: transfer error RMS {:.3f} -> {:.3f} px (held-out points {:.3f} -> {:.3f}), {} iterations, "
          "{:.1f} s",
          ToString(refined_model_), rr.initial_rms_px, rr.final_rms_px, holdout_linear_.rms, holdout_final_.rms,
          rr.iterations, rr.seconds);
    } else {
      spdlog::warn("refinement failed ({}); keeping the affine solution", rr.failure);
    }
  } else if (component.size() == 1) {
    mosaic_from_work_[component.front()] = Mat3::Identity();
  }
  for (auto& f : frames_) {
    if (in_component.count(f.id) != 0) continue;
    if (f.failure.empty()) f.failure = f.has_features ? "not in the largest connected component" : "not processed";
  }
  final_registered_ = static_cast<int>(component.size());
  final_rms_ = rms;
  spdlog::info("registered {}/{} frames, residual RMS {:.3f} px (median {:.3f}) at working resolution",
               final_registered_, frames_.size(), rms, median);
  residual_median_ = median;
  solve_peak_rss_mib_ = HighWaterRssMiB();
  ResetPeakRss();
  if (!WriteOutputs(component, error)) return false;
  std::string journal_error;
  if (journal_.is_open() && !journal_.AddFinished(&journal_error)) spdlog::warn("{}", journal_error);
  return true;
}

}  // namespace uavm
