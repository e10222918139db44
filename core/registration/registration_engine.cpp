#include "core/registration/registration_engine.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <future>
#include <map>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "core/util/clock.h"
#include "core/util/fail.h"
#include "core/util/id_set.h"
#include "core/util/memory.h"
#include "core/util/record_arena.h"

namespace uavm {

namespace {

Edge EdgeFromPair(int src, int tgt, PairResult&& r) {
  Edge e;
  e.src = src;
  e.tgt = tgt;
  e.num_matches = r.num_matches;
  e.num_inliers = r.num_inliers;
  e.tgt_from_src = r.tgt_from_src;
  e.points = EdgePoints(r.src_points, r.tgt_points, r.holdout_src_points, r.holdout_tgt_points);
  return e;
}

}  // namespace

bool RegistrationOptions::Check(std::string* why) const {
  if (recent_candidates < 1 || overlap_candidates < 0)
    return Fail(why, "recent_candidates >= 1, overlap_candidates >= 0");
  if (!(min_overlap_fraction > 0 && min_overlap_fraction < 1))
    return Fail(why, "min_overlap_fraction must be in (0,1)");
  if (!(relative_inlier_fraction >= 0 && relative_inlier_fraction < 1))
    return Fail(why, "relative_inlier_fraction must be in [0,1)");
  if (relocalization_candidates < 0 || bridge_candidates < 0 || retry_list_size < 0 || retry_per_frame < 0 ||
      retry_max_attempts < 1)
    return Fail(why, "relocalization/retry settings must be >= 0");
  if (full_solve_every < 1) return Fail(why, "full_solve_every must be >= 1");
  if (solve_window < 0) return Fail(why, "solve_window must be >= 0 (0 = whole component)");
  if (end_correspondences < 0 || min_end_points < 3)
    return Fail(why, "end_correspondences must be >= 0 (0 = every point), min_end_points >= 3");
  return matching.Check(why) && relocalization.Check(why) && adjust.Check(why) && refine.Check(why) &&
         lens_calibration.Check(why) && subpixel.Check(why);
}

// What one frame's matching found so far: the candidates tried and the verified edges (new frame = tgt).
struct RegistrationEngine::Candidates {
  int id = -1;
  const Features* feats = nullptr;
  const DescriptorIndex* index = nullptr;
  const PositionHint* hint = nullptr;
  std::unordered_set<int> tried;
  std::vector<Edge> found;
  bool have_estimate = false;  // Map(id) holds a first estimate once a candidate matched
  std::optional<Mat3> motion;  // Map(id) predicted from the previous frames' motion, until a candidate matched
  int root = -1;               // the base component: the largest one the found edges touch
};

RegistrationEngine::RegistrationEngine(const RegistrationOptions& options, FeatureProvider* features, EdgeSpill* spill)
    : options_(options), features_(features), spill_(spill), global_index_(options.relocalization) {
  std::string why;
  if (!options_.Check(&why)) throw std::invalid_argument("registration options: " + why);
  if (features_ == nullptr) throw std::invalid_argument("registration engine: no feature provider");
  if (options_.subpixel.enabled && options_.matching.average_cells) {
    // The sub-pixel refinement tracks each kept source point: keypoints, not the cells' centroids.
    options_.matching.average_cells = false;
    spdlog::info("matching: one inlier per cell (subpixel.enabled tracks keypoints, not cell means)");
  }
}

int RegistrationEngine::AddFrame(cv::Size work_size) {
  const int id = static_cast<int>(frames_.size());
  FrameRecord& f = frames_.emplace_back();
  f.work_size = work_size;
  f.half_diagonal = 0.5 * std::hypot(work_size.width, work_size.height);
  adjacency_.emplace_back();
  components_.Add();
  graph_.AddNode(id);
  return id;
}

void RegistrationEngine::SetFailure(int id, std::string why) {
  Record(id).failure = std::move(why);
}

RegistrationCounters RegistrationEngine::counters() const {
  RegistrationCounters c = counters_;
  c.relocalization_thinnings = global_index_.thinnings();
  return c;
}

const std::vector<int>& RegistrationEngine::MembersOf(int root) const {
  static const std::vector<int> kNone;
  // A frame that registered nothing is a component of its own, outside the graph.
  return frame(components_.Find(root)).in_graph ? components_.MembersOf(root) : kNone;
}

std::vector<const Edge*> RegistrationEngine::EdgesTouching(const std::unordered_set<int>& ids, int root) {
  std::vector<size_t> indices;
  for (int id : ids)
    for (size_t ei : adjacency_.at(static_cast<size_t>(id))) indices.push_back(ei);
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

void RegistrationEngine::AddEdge(Edge edge) {
  best_inliers_ = std::max(best_inliers_, edge.num_inliers);
  if (spill_ != nullptr) {
    std::string error;
    if (!spill_->Append(&edge, &error)) {
      spdlog::warn("{}; edge points stay in memory from now on", error);
      spill_ = nullptr;
    }
  }
  // The edge's record and list entries are freed together at the end of the flight (ReleaseEdgeRecords).
  const RecordArena::Scope edge_records(RecordArena::Group::kEdges);
  const auto index = static_cast<uint32_t>(graph_.edges().size());
  adjacency_.at(static_cast<size_t>(edge.src)).push_back(index);
  adjacency_.at(static_cast<size_t>(edge.tgt)).push_back(index);
  graph_.AddEdge(std::move(edge));
}

void RegistrationEngine::ReleaseColdEdges() {
  if (options_.solve_window <= 0 || spill_ == nullptr) return;
  // Edges are appended as frames arrive, so an edge's newest frame rarely goes back in time: the scan stops at the
  // first edge still in the window. A solve that needs a released edge after all (a merged component) reloads it.
  const int cold_below = frames() - options_.solve_window;
  auto& edges = graph_.mutable_edges();
  for (; release_cursor_ < edges.size(); ++release_cursor_) {
    Edge& e = edges[release_cursor_];
    if (std::max(e.src, e.tgt) >= cold_below) break;
    const size_t bytes = spill_->Release(&e);
    if (bytes > 0) {
      ++counters_.edges_released;
      counters_.edge_bytes_released += bytes;
    }
  }
}

bool RegistrationEngine::LoadEdgePoints(const std::vector<const Edge*>& edges, size_t max_points, size_t max_holdout,
                                        size_t* dropped) {
  bool all = true;  // an edge that cannot be read stays without points; the others are still loaded
  for (const Edge* e : edges) {
    // The list borrows the graph's edges read-only; the graph (this object's) owns them mutably.
    Edge& edge = const_cast<Edge&>(*e);
    if (!edge.points_resident) {
      // Without a spill no edge was ever released.
      if (spill_ == nullptr) return false;
      std::string error;
      if (!spill_->Load(&edge, &error)) {
        spdlog::error("{}", error);
        all = false;
        continue;
      }
    }
    // Thinned only where the spill keeps every point: a writer reads them back from it (ReleaseAllEdges).
    if (max_points > 0 && spill_ != nullptr && edge.stored_at >= 0) {
      const size_t thinned = edge.points.Thin(max_points, max_holdout);
      if (dropped != nullptr) *dropped += thinned;
      if (thinned > 0) thinned_ = true;
    }
  }
  return all;
}

// Re-expresses every frame of `other_root`'s component by `other_fix` (new = fix * old) and unites the two.
void RegistrationEngine::MergeInto(int keep_root, int other_root, const Mat3& other_fix) {
  for (int id : MembersOf(other_root)) {
    SetMap(id, other_fix * Map(id));
    Place(id);
  }
  components_.Unite(keep_root, other_root);
  ++counters_.component_merges;
  --counters_.components;
}

void RegistrationEngine::FullSolve(int root) {
  const std::vector<int>& members = MembersOf(root);  // ascending ids
  if (members.size() < 2) return;
  const int anchor = members.front();
  // During the flight only the newest solve_window frames move (the rest is their fixed frame of reference): the
  // solve's memory and time stay bounded however long the flight. The end of the flight solves everything.
  const size_t window = options_.solve_window > 0 ? static_cast<size_t>(options_.solve_window) : members.size();
  std::unordered_set<int> variable(members.end() - static_cast<long>(std::min(window, members.size())), members.end());
  variable.erase(anchor);
  std::unordered_map<int, double> half_diag;  // the adjustment weighs its terms by the moving frames' sizes only
  for (int id : variable) half_diag[id] = Record(id).half_diagonal;
  // Only edges that touch a moving frame take part (AdjustAffine skips the others): found through the moving frames'
  // adjacency, so a windowed solve costs the window, not the component.
  std::vector<const Edge*> edges = EdgesTouching(variable, components_.Find(root));
  std::vector<const Edge*> needed;
  for (const Edge* e : edges)
    if (!e->points_resident) needed.push_back(e);
  if (!LoadEdgePoints(needed)) spdlog::warn("full adjustment without some edges (edges.bin unreadable)");
  counters_.edges_reloaded += needed.size();
  const auto result = AdjustAffine(edges, variable, half_diag, options_.adjust, &mosaic_from_work_);
  for (int id : variable) Place(id);
  ReleaseColdEdges();
  if (!result.ok) spdlog::warn("full adjustment failed: {}", result.failure);
  registered_since_full_ = 0;
}

bool RegistrationEngine::IsNewGround(int id) {
  const FrameRecord& me = Record(id);
  const double spacing = options_.relocalization.keyframe_spacing;
  // A frame that is not placed yet may be anywhere: it is indexed so that a later frame can find it.
  if (spacing <= 0 || !me.in_graph) return true;
  const auto centre_of = [&](int k) {
    const FrameRecord& f = Record(k);
    return Apply(Map(k), Vec2(0.5 * (f.work_size.width - 1), 0.5 * (f.work_size.height - 1)));
  };
  const Vec2 c = centre_of(id);
  const double radius = spacing * me.half_diagonal *
                        LocalScale(Map(id), Vec2(0.5 * (me.work_size.width - 1), 0.5 * (me.work_size.height - 1)));
  const int root = components_.Find(id);
  // A keyframe whose centre is that close lies in a footprint that meets this square: the grid finds it.
  const cv::Rect2d near(c.x() - radius, c.y() - radius, 2.0 * radius, 2.0 * radius);
  for (int k : footprints_.Query(near)) {
    const FrameRecord& f = Record(k);
    if (f.keyframe && f.in_graph && components_.Find(k) == root && (centre_of(k) - c).norm() < radius) return false;
  }
  return true;
}

void RegistrationEngine::Place(int id) {
  const FrameRecord& f = Record(id);
  if (track_moves_) moved_.push_back(id);
  footprints_.Set(id, cv::Rect2d(cv::boundingRect(Footprint(Map(id), f.work_size.width, f.work_size.height))));
}

Edge RegistrationEngine::MakeEdge(int src, int tgt, PairResult&& r) {
  if (refiner_ != nullptr)
    (void)refiner_->RefinePair(src, tgt, r.tgt_from_src, {&r.src_points, &r.tgt_points},
                               {&r.holdout_src_points, &r.holdout_tgt_points});  // false: kept as matched
  return EdgeFromPair(src, tgt, std::move(r));
}

bool RegistrationEngine::Acceptable(const PairResult& r) const {
  return r.ok && r.num_inliers >= options_.relative_inlier_fraction * best_inliers_;
}

bool RegistrationEngine::TryJoin(int new_id, int other_id, const DescriptorIndex& index, const Features& feats) {
  auto other = features_->Get(other_id);
  if (!other) return false;
  PairResult r = MatchPair(index, feats, *other, options_.matching);
  if (!Acceptable(r)) return false;
  Edge e = MakeEdge(other_id, new_id, std::move(r));
  // mosaic_from_work(other) should become T_new * new_from_other; the other component moves with it.
  const Mat3 fix = Map(new_id) * e.tgt_from_src * Map(other_id).inverse();
  AddEdge(std::move(e));
  MergeInto(components_.Find(new_id), components_.Find(other_id), fix);
  FullSolve(components_.Find(new_id));
  return true;
}

void RegistrationEngine::TryRetries(int new_id, const DescriptorIndex& index, const Features& feats) {
  const int budget = std::min<int>(options_.retry_per_frame, static_cast<int>(retry_.size()));
  for (int k = 0; k < budget; ++k) {
    auto [id, attempts] = retry_.front();
    retry_.pop_front();
    if (components_.Find(id) == components_.Find(new_id)) continue;  // already joined through another frame
    if (TryJoin(new_id, id, index, feats)) {
      ++counters_.joined_on_retry;
      spdlog::info("frame {} joined the mosaic on retry (via frame {})", id, new_id);
      continue;
    }
    if (attempts + 1 < options_.retry_max_attempts) retry_.emplace_back(id, attempts + 1);
  }
}

void RegistrationEngine::Bridge(int new_id, const DescriptorIndex& index, const Features& feats) {
  // The flight is in pieces (a strip flown elsewhere first, a lost frame): look for the new frame's look-alikes in
  // other components. The global index answers from a tree rebuilt every few frames, so this costs one search.
  int tried = 0;
  for (int c : global_index_.Query(feats, 2 * options_.bridge_candidates, /*allow_stale=*/true)) {
    if (tried >= options_.bridge_candidates) break;
    if (components_.Find(c) == components_.Find(new_id)) continue;
    ++tried;
    if (TryJoin(new_id, c, index, feats))
      spdlog::info("frame {} joined two parts of the flight (via frame {})", new_id, c);
  }
}

void RegistrationEngine::TryCandidate(int cand, Candidates* c) {
  if (!c->tried.insert(cand).second) return;
  auto other = features_->Get(cand);
  if (!other) return;
  MatchGuide guide;
  const bool guided = c->have_estimate && components_.Find(cand) == components_.Find(c->found.front().src);
  // Before any match, the motion prediction guides the candidates of the previous frame's component: a guided query
  // asks a few hundred spread points instead of all of them (see MatchOptions::max_guided_queries).
  const bool predicted = !guided && c->motion && c->id > 0 && components_.Find(cand) == components_.Find(c->id - 1);
  if (guided || predicted) {
    guide.tgt_from_src = (guided ? Map(c->id) : *c->motion).inverse() * Map(cand);
    guide.tgt_size = Record(c->id).work_size;
  }
  PairResult r = MatchPair(*c->index, *c->feats, *other, options_.matching, guided || predicted ? &guide : nullptr);
  // The motion changed (a turn, a gust): every point is asked, as without a prediction.
  if (predicted && !Acceptable(r)) r = MatchPair(*c->index, *c->feats, *other, options_.matching);
  if (!Acceptable(r)) {
    spdlog::debug("frame {} against {}: {} matches, {} inliers (needs {:.0f}){}{}", c->id, cand, r.num_matches,
                  r.num_inliers, options_.relative_inlier_fraction * best_inliers_, r.failure.empty() ? "" : ": ",
                  r.failure);
    return;
  }
  c->found.push_back(MakeEdge(cand, c->id, std::move(r)));
  if (!c->have_estimate) {
    SetMap(c->id, Map(cand) * c->found.back().tgt_from_src.inverse());
    c->have_estimate = true;
  }
}

std::optional<Mat3> RegistrationEngine::PredictFromMotion(int id) {
  const int before = id - 2;
  const int prev = id - 1;
  if (before < 0 || !Record(before).in_graph || !Record(prev).in_graph) return std::nullopt;
  if (components_.Find(before) != components_.Find(prev)) return std::nullopt;
  if (!placed(before) || !placed(prev)) return std::nullopt;
  const Mat3 before_from_prev = Map(before).inverse() * Map(prev);
  return Map(prev) * before_from_prev;
}

// The candidate set: 1) the last K frames in the graph; when they gave nothing, 2) the frames where telemetry places
// the frame (a PositionHint), then 3) the relocalisation index; 4) frames of the base component whose footprint
// overlaps the first estimate (closes loops between strips).
void RegistrationEngine::FindCandidates(int id, Candidates* c) {
  int taken = 0;
  for (int k = id - 1; k >= 0 && taken < options_.recent_candidates; --k) {
    if (!Record(k).has_features || !Record(k).in_graph) continue;
    TryCandidate(k, c);
    ++taken;
  }
  if (c->found.empty() && c->hint != nullptr) TryWhereTelemetryPlaces(id, c);
  if (c->found.empty() && options_.relocalization_candidates > 0) {
    for (int k : global_index_.Query(*c->feats, options_.relocalization_candidates)) TryCandidate(k, c);
    if (!c->found.empty()) {
      ++counters_.relocalized;
      spdlog::info("frame {} relocalised against frame {}", id, c->found[0].src);
    }
  }
  if (c->found.empty()) return;
  // Base component: the largest one touched; the new frame's first estimate comes from its strongest edge there.
  std::map<int, int> size_of_root;
  for (const auto& e : c->found) size_of_root[components_.Find(e.src)] = components_.SizeOf(e.src);
  const int root = std::max_element(size_of_root.begin(), size_of_root.end(), [](const auto& a, const auto& b) {
                     return a.second < b.second;
                   })->first;
  c->root = root;
  const Edge* best = nullptr;
  for (const auto& e : c->found)
    if (components_.Find(e.src) == root && (best == nullptr || e.num_inliers > best->num_inliers)) best = &e;
  SetMap(id, Map(best->src) * best->tgt_from_src.inverse());
  // (The new frame is not united with `root` yet: its component is named explicitly.)
  for (int k : OverlapCandidates(id, root, c->tried)) TryCandidate(k, c);
}

// Telemetry's guess: the new frame centred where the hint says, turned and scaled like the anchor frame (a heading
// error only turns the footprint about its centre: the overlap test still finds its neighbours); the frames its
// footprint overlaps in the anchor's component are tried. The guess is not kept: a match gives the estimate.
void RegistrationEngine::TryWhereTelemetryPlaces(int id, Candidates* c) {
  const PositionHint& hint = *c->hint;
  if (hint.anchor < 0 || hint.anchor >= id || !placed(hint.anchor) || !Record(hint.anchor).in_graph) return;
  const FrameRecord& me = Record(id);
  const Mat3 turned = Map(hint.anchor);
  const Vec2 at = Apply(turned, Vec2(0.5 * (me.work_size.width - 1), 0.5 * (me.work_size.height - 1)));
  SetMap(id, Translation(hint.centre.x() - at.x(), hint.centre.y() - at.y()) * turned);
  const std::vector<int> near = OverlapCandidates(id, hint.anchor, c->tried);
  mosaic_from_work_.erase(id);
  for (int k : near) TryCandidate(k, c);
  if (c->found.empty()) return;
  ++counters_.joined_where_telemetry_placed;
  spdlog::info("frame {} matched frame {} where telemetry placed it", id, c->found[0].src);
}

void RegistrationEngine::StartComponent(int id, const Candidates& c) {
  // A component of its own until a later frame connects it.
  SetMap(id, Mat3::Identity());
  FrameRecord& st = Record(id);
  st.in_graph = true;
  Place(id);
  ++counters_.components;
  if (id == 0) {
    spdlog::info("frame {} starts the mosaic", id);
    return;
  }
  st.failure = "no verified match with any candidate";
  if (options_.retry_list_size > 0) {
    if (static_cast<int>(retry_.size()) >= options_.retry_list_size) retry_.pop_front();  // oldest gives way
    retry_.emplace_back(id, 0);
  }
  spdlog::info("frame {} matched none of {} candidates; kept for retry", id, c.tried.size());
}

void RegistrationEngine::Join(int id, Candidates* c) {
  const int root = c->root;
  FrameRecord& st = Record(id);
  st.in_graph = true;
  std::vector<Edge> edges = std::move(c->found);
  // Merge every other touched component into the base one, through the new frame.
  bool merged = false;
  for (const auto& e : edges) {
    const int other = components_.Find(e.src);
    if (other == components_.Find(root) || other == components_.Find(id)) continue;
    const Mat3 fix = Map(id) * e.tgt_from_src * Map(e.src).inverse();
    MergeInto(components_.Find(root), other, fix);
    merged = true;
  }
  components_.Unite(root, id);
  for (auto& e : edges) AddEdge(std::move(e));
  // Local update: only the new frame moves.
  std::unordered_map<int, double> half_diag{{id, st.half_diagonal}};
  std::vector<const Edge*> local;
  for (size_t ei : adjacency_.at(static_cast<size_t>(id))) local.push_back(&graph_.edges()[ei]);
  const auto r = AdjustAffine(local, {id}, half_diag, options_.adjust, &mosaic_from_work_);
  if (!r.ok) spdlog::warn("local adjustment of frame {} failed: {}", id, r.failure);
  Place(id);
  st.failure.clear();
  // Full solves get rarer as the component grows (every max(N, size/20) frames): their cost grows with the
  // flight, and between them each new frame is still solved against all its neighbours, old strips included.
  const int solved =
      options_.solve_window > 0 ? std::min(components_.SizeOf(id), options_.solve_window) : components_.SizeOf(id);
  const int interval = std::max(options_.full_solve_every, solved / 20);
  if (++registered_since_full_ >= interval || merged) FullSolve(components_.Find(id));
  TryRetries(id, *c->index, *c->feats);
  if (counters_.components > 1 && options_.bridge_candidates > 0) Bridge(id, *c->index, *c->feats);
}

FrameOutcome RegistrationEngine::Register(int id, const Features& features, RegisterTiming* timing,
                                          const PositionHint* hint) {
  if (id != frames() - 1) throw std::logic_error("RegistrationEngine::Register: only the newest frame registers");
  StageTimer t;
  Record(id).has_features = true;
  const DescriptorIndex index(features, options_.matching);
  Candidates c;
  c.id = id;
  c.feats = &features;
  c.index = &index;
  c.hint = hint;
  c.motion = PredictFromMotion(id);
  FindCandidates(id, &c);
  if (timing != nullptr) timing->matching_ms = t.ElapsedMs();
  t.Restart();
  FrameOutcome outcome = FrameOutcome::kRegistered;
  if (c.found.empty()) {
    StartComponent(id, c);
    if (id != 0) outcome = FrameOutcome::kNewComponent;
  } else {
    Join(id, &c);
  }
  if (IsNewGround(id)) {
    global_index_.Add(id, features);
    Record(id).keyframe = true;
  } else {
    ++counters_.frames_not_indexed;
  }
  if (timing != nullptr) timing->adjust_ms = t.ElapsedMs();
  return outcome;
}

std::vector<int> RegistrationEngine::OverlapCandidates(int id, int root, const std::unordered_set<int>& exclude) {
  std::vector<int> out;
  if (options_.overlap_candidates <= 0) return out;
  const FrameRecord& me = Record(id);
  const auto fp_me = Footprint(Map(id), me.work_size.width, me.work_size.height);
  const cv::Rect2d box_me = cv::boundingRect(fp_me);
  const double area_me = PolygonArea(fp_me);
  if (!(area_me > 0)) return out;
  std::vector<std::pair<double, int>> overlaps;
  // Only frames whose footprint box meets this one's can overlap it: the grid gives them without a scan.
  for (int k : footprints_.Query(box_me)) {
    const FrameRecord& f = Record(k);
    if (k == id || !f.in_graph || exclude.count(k) != 0 || components_.Find(k) != components_.Find(root)) continue;
    const auto fp = Footprint(Map(k), f.work_size.width, f.work_size.height);
    if ((cv::Rect2d(cv::boundingRect(fp)) & box_me).area() <= 0) continue;
    const double a = ConvexOverlapArea(fp_me, fp);
    if (a / area_me >= options_.min_overlap_fraction) overlaps.emplace_back(a, k);
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
void RegistrationEngine::Densify() {
  constexpr int kMaxFrames = 64;
  const int wanted = options_.recent_candidates + options_.overlap_candidates;
  int done = 0;
  for (int id = 0; id < frames() && done < kMaxFrames; ++id) {
    const FrameRecord& f = Record(id);
    const auto& adjacent = adjacency_.at(static_cast<size_t>(id));
    if (!f.in_graph || !f.has_features || static_cast<int>(adjacent.size()) >= wanted) continue;
    std::unordered_set<int> linked{id};
    for (size_t ei : adjacent) {
      linked.insert(graph_.edges()[ei].src);
      linked.insert(graph_.edges()[ei].tgt);
    }
    const std::vector<int> candidates = OverlapCandidates(id, id, linked);
    if (candidates.empty()) continue;
    ++done;
    auto mine = features_->Get(id);
    if (!mine) continue;
    const DescriptorIndex index(*mine, options_.matching);
    for (int other_id : candidates) {
      auto other = features_->Get(other_id);
      if (!other) continue;
      MatchGuide guide;
      guide.tgt_from_src = Map(id).inverse() * Map(other_id);
      guide.tgt_size = f.work_size;
      PairResult r = MatchPair(index, *mine, *other, options_.matching, &guide);
      if (!Acceptable(r)) continue;
      AddEdge(MakeEdge(other_id, id, std::move(r)));
      ++counters_.edges_added_at_end;
    }
  }
}

Solution RegistrationEngine::Finish(const PhaseListener& enter_phase) {
  enter_phase_ = enter_phase;
  Solution s = FinishSolve();
  enter_phase_ = nullptr;
  // Thinned edges go back to edges.bin: whoever reads an edge after this gets all of its points (AsSolved).
  if (thinned_) ReleaseAllEdges();
  return s;
}

void RegistrationEngine::ReleaseAllEdges() {
  if (spill_ == nullptr) return;
  for (Edge& e : graph_.mutable_edges()) spill_->Release(&e);
  TrimHeap();  // the compositor gets the pages back
}

void RegistrationEngine::AsSolved(Edge* edge) const {
  if (solved_lens_ && camera_) ReprojectEdgePoints(*camera_, *solved_lens_, edge);
}

namespace {

// The held-out pairs an edge keeps beside `pairs` thinned pairs: a quarter, 2 at least.
size_t EndHoldoutShare(size_t pairs) {
  return std::max<size_t>(2, pairs / 4);
}

}  // namespace

// Each edge's share of the end's correspondences: all of them up to end_correspondences in total, then an even share
// of it (never below min_end_points): the solves' memory stops growing with the flight there.
std::pair<size_t, size_t> RegistrationEngine::EndPointsPerEdge(const std::vector<const Edge*>& edges) const {
  if (options_.end_correspondences <= 0 || edges.empty()) return {0, 0};
  size_t points = 0;
  for (const Edge* e : edges) points += static_cast<size_t>(e->num_inliers);
  const auto cap = static_cast<size_t>(options_.end_correspondences);
  if (points <= cap) return {0, 0};
  const size_t per_edge = std::max(static_cast<size_t>(options_.min_end_points), cap / edges.size());
  return {per_edge, EndHoldoutShare(per_edge)};
}

namespace {

// The end of a long flight's points: an edge still resident is read as it is; another is read back from the spill into
// one scratch edge, thinned to the end's share and moved to the solved lens's pixels, as LoadEdgePoints and the lens
// would have left it resident. The solves get the same numbers and hold one edge's points instead of all of them.
class EndPointReader final : public EdgePointSource {
 public:
  // Borrows the spill and the engine (its solved lens), which outlive the reader.
  EndPointReader(EdgeSpill* spill, const RegistrationEngine* engine, size_t max_points, size_t max_holdout)
      : spill_(spill), engine_(engine), max_points_(max_points), max_holdout_(max_holdout) {}

  const EdgePoints& Points(const Edge& edge) override {
    if (edge.points_resident) return edge.points;
    scratch_.src = edge.src;
    scratch_.tgt = edge.tgt;
    scratch_.stored_at = edge.stored_at;
    scratch_.points_resident = false;
    std::string error;
    if (!spill_->Load(&scratch_, &error)) {
      if (failed_++ == 0) spdlog::error("{}", error);
      scratch_.points.Free();
      return scratch_.points;
    }
    dropped_ += scratch_.points.Thin(max_points_, max_holdout_);
    engine_->AsSolved(&scratch_);
    return scratch_.points;
  }
  [[nodiscard]] size_t dropped() const { return dropped_; }  // pairs left on disk, summed over the reads
  [[nodiscard]] size_t failed() const { return failed_; }

 private:
  EdgeSpill* spill_;                  // borrowed
  const RegistrationEngine* engine_;  // borrowed
  size_t max_points_;
  size_t max_holdout_;
  Edge scratch_;
  size_t dropped_ = 0;
  size_t failed_ = 0;
};

}  // namespace

Solution RegistrationEngine::FinishSolve() {
  StageTimer t;
  // The relocalisation index serves the flight only (Densify looks for partners among footprints): its memory goes
  // before the last matching, not after it.
  global_index_.Release();
  EnterPhase("end_match");
  Densify();
  // Nothing after this point matches features: their memory goes to the solves (and the caller's compositor).
  features_->ReleaseAll();
  Solution s;
  // Largest component over edges that pass both thresholds against the final best pair.
  auto components = graph_.ComponentsBySize(options_.relative_inlier_fraction, options_.matching.min_inliers);
  if (!components.empty() && !frames_.empty()) {
    s.component = std::move(components.front());
    s.other_components.assign(std::make_move_iterator(components.begin() + 1),
                              std::make_move_iterator(components.end()));
  }
  // A byte per frame id (IdSet, where a hash set took ~40): the end phases carry it.
  const IdSet in_component(s.component);
  std::vector<const Edge*> edges;
  for (const auto& e : graph_.edges())
    if (in_component.contains(e.src) && in_component.contains(e.tgt) && EdgeCounts(e)) edges.push_back(&e);
  // The final solves use every edge: the points given back during the flight come back from the spill (an even share
  // of each edge's when all of them would outgrow end_correspondences).
  const auto [max_points, max_holdout] = EndPointsPerEdge(edges);
  counters_.end_points_per_edge = max_points;
  // All of the points when they fit end_correspondences. Beyond, the solves read an edge's share from the spill each
  // time they need it (edges.bin is read a few dozen times, from the page cache): what they hold stops growing with
  // the flight's edges, except the share of those still resident from the flight, thinned in place just before
  // end_load begins (the matching's window, up to ~1 MiB of points: that moment counts in end_match, whose peak is
  // higher).
  std::optional<EndPointReader> reader;
  bool loaded = true;
  if (max_points > 0 && spill_ != nullptr) {
    std::vector<const Edge*> resident;
    for (const Edge* e : edges)
      if (e->points_resident) resident.push_back(e);
    loaded = LoadEdgePoints(resident, max_points, max_holdout, &counters_.end_points_thinned);
    thinned_ = true;
    EnterPhase("end_load");
    reader.emplace(spill_, this, max_points, max_holdout);
    // One read of each: the pairs left on disk counted, and an unreadable edges.bin said before the solves.
    for (const Edge* e : edges) (void)reader->Points(*e);
    counters_.end_points_thinned += reader->dropped();
  } else {
    EnterPhase("end_load");
    loaded = LoadEdgePoints(edges, max_points, max_holdout, &counters_.end_points_thinned);
  }
  if (!loaded || (reader && reader->failed() > 0))
    spdlog::warn("final adjustment without some edges (edges.bin unreadable)");
  s.ok = true;
  if (s.component.size() >= 2) {
    SolveFinal(edges, reader ? &*reader : nullptr, t, &s);
  } else if (s.component.size() == 1) {
    SetMap(s.component.front(), Mat3::Identity());
  }
  for (int id = 0; id < frames(); ++id) {
    FrameRecord& f = Record(id);
    if (in_component.contains(id)) continue;
    if (f.failure.empty()) f.failure = f.has_features ? "not in the largest connected component" : "not processed";
  }
  return s;
}

size_t RegistrationEngine::RematchUnderLens(const std::vector<const Edge*>& edges, const LensDistortion& lens,
                                            std::vector<char>* at_lens) {
  const PinholeCamera& prepared = *camera_;
  PinholeCamera calibrated = prepared;
  calibrated.distortion = lens;
  const auto to_ideal = [&](const Features& f) {
    Features g;
    g.descriptors = f.descriptors;
    g.points.reserve(f.points.size());
    for (const cv::Point2f& p : f.points) {
      const Vec2 q = calibrated.UndistortPixel(prepared.DistortPixel(Vec2(p.x, p.y)));
      g.points.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
    }
    return g;
  };
  // One index per target frame: the pairs in target order.
  std::vector<size_t> order(edges.size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return edges[a]->tgt < edges[b]->tgt; });
  at_lens->assign(edges.size(), 0);
  const size_t max_points = counters_.end_points_per_edge;
  size_t rematched = 0;
  int indexed = -1;
  Features target;
  std::optional<DescriptorIndex> index;
  for (size_t i : order) {
    const Edge* e = edges[i];
    if (e->tgt != indexed) {
      indexed = e->tgt;
      index.reset();
      const auto t = features_->Load(e->tgt);
      if (!t) continue;
      target = to_ideal(*t);
      index.emplace(target, options_.matching);
    }
    const auto source = features_->Load(e->src);
    if (!index || !source) continue;
    MatchGuide guide;
    guide.tgt_from_src = Map(e->tgt).inverse() * Map(e->src);
    guide.tgt_size = Record(e->tgt).work_size;
    PairResult r = MatchPair(*index, target, to_ideal(*source), options_.matching, &guide);
    // A pair that verifies much worse under the lens than without it keeps its points (a guided query asks fewer
    // points than the flight's first query may have).
    if (!Acceptable(r) || 2 * r.num_inliers < e->num_inliers) continue;
    auto* edge = const_cast<Edge*>(e);  // the engine's own edge (the const view is the solve's)
    edge->points = EdgePoints(r.src_points, r.tgt_points, r.holdout_src_points, r.holdout_tgt_points);
    if (max_points > 0) (void)edge->points.Thin(max_points, EndHoldoutShare(max_points));
    (*at_lens)[i] = 1;
    ++rematched;
  }
  return rematched;
}

namespace {

// The held-out RMS, on `holdout`'s held-out points, of the refinement of the subset on `fit`'s points, all at `lens`'s
// ideal pixels (on copies: the engine's edges are not touched).
double HoldoutOfRefinement(const std::vector<const Edge*>& fit, const std::vector<Edge>& holdout,
                           const PinholeCamera& prepared, const LensDistortion& lens,
                           const std::unordered_set<int>& variable, int anchor,
                           const std::unordered_map<int, double>& half_diag, const RefineOptions& subset,
                           std::unordered_map<int, Mat3> maps) {
  std::vector<Edge> copies(fit.size());
  std::vector<const Edge*> view;
  for (size_t i = 0; i < fit.size(); ++i) {
    // The fit's points and the holdout's held-out points only: nothing is copied to be overwritten.
    copies[i].src = fit[i]->src;
    copies[i].tgt = fit[i]->tgt;
    copies[i].num_matches = fit[i]->num_matches;
    copies[i].num_inliers = fit[i]->num_inliers;
    copies[i].tgt_from_src = fit[i]->tgt_from_src;
    copies[i].points = EdgePoints::Combine(fit[i]->points, holdout[i].points);
    ReprojectEdgePoints(prepared, lens, &copies[i]);
    view.push_back(&copies[i]);
  }
  if (!RefineGlobal(view, variable, anchor, half_diag, subset, &maps).ok) return HUGE_VAL;
  return TransferErrors(view, maps, true).rms;
}

}  // namespace

void RegistrationEngine::CorrectLensAfterRematch(const std::vector<const Edge*>& edges,
                                                 const std::unordered_set<int>& variable, int anchor,
                                                 const std::unordered_map<int, double>& half_diag,
                                                 const PinholeCamera& resident, LensCalibration* lens) {
  const LensDistortion first = lens->distortion;
  std::vector<Edge> own(edges.size());
  for (size_t i = 0; i < own.size(); ++i) own[i] = *edges[i];
  // The rematched edges' points are at the first estimate's ideal pixels already; the others are moved there.
  std::vector<char> at_first_lens;
  lens->rematched_edges = RematchUnderLens(edges, first, &at_first_lens);
  lens->first_at_half_diagonal = lens->distortion_at_half_diagonal;
  // The correction is estimated on the points at the first estimate's ideal pixels: the solve's polynomial then
  // carries only what the first missed, which it represents well even where it could not represent a strong lens
  // whole (a -15 % barrel: 0.6 px at the corners).
  for (size_t i = 0; i < edges.size(); ++i)
    if (at_first_lens[i] == 0) ReprojectEdgePoints(resident, first, const_cast<Edge*>(edges[i]));
  PinholeCamera at_first = resident;
  at_first.distortion = LensDistortion{};
  LensCalibrationOptions options = options_.lens_calibration;
  options.max_halves_disagreement = 0;  // the lens is established; only the correction's held-out gain is asked
  const LensCalibration residual = CalibrateLens(edges, variable, anchor, half_diag, options_.refine, at_first, options,
                                                 mosaic_from_work_, "lens correction after the rematch");
  at_first.distortion = first;
  for (const Edge* e : edges) ReprojectEdgePoints(at_first, resident.distortion, const_cast<Edge*>(e));
  // Kept when it lowers the held-out RMS (the first lens already passed the decision).
  const bool kept = residual.tried && !residual.solve_failed && residual.holdout_with_px < residual.holdout_without_px;
  if (kept) {
    lens->distortion = ComposeRadial(first, residual.distortion, 1.05 * resident.HalfDiagonalRadius());
    PinholeCamera composed = resident;
    composed.distortion = lens->distortion;
    lens->distortion_at_half_diagonal = composed.RadialDistortionAtHalfDiagonal();
    lens->residual_holdout_without_px = residual.holdout_without_px;
    lens->residual_holdout_with_px = residual.holdout_with_px;
  }
  KeepBetterPoints(edges, &own, variable, anchor, half_diag, resident, lens);
  spdlog::info(
      "lens: {} of {} pairs matched again under it; correction {} (held-out RMS {:.3f} -> {:.3f} px): {:+.4f} -> "
      "{:+.4f} at the half-diagonal; the final solve takes the {} points (held-out RMS {:.3f} px with the flight's, "
      "{:.3f} with the rematched)",
      lens->rematched_edges, edges.size(), kept ? "kept" : "not kept", residual.holdout_without_px,
      residual.holdout_with_px, lens->first_at_half_diagonal, lens->distortion_at_half_diagonal,
      lens->rematched_points_kept ? "rematched" : "flight's", lens->holdout_flight_points_px,
      lens->holdout_rematched_points_px);
}

// Which points the final solve takes: the rematched ones find what the flight's RANSAC left out where the lens moves
// pixels most (a -10 % barrel, jittered: 0.17 px against the truth with them, 0.32 with the flight's), which the
// flight's held-out points, picked by that RANSAC too, barely see (0.643 against 0.641 px there). So they are taken
// unless the subset refined on them fits the flight's held-out points worse by more than
// rematch_holdout_tolerance: on a real camera the points near the corners can disagree with the rest (caliterra:
// 0.970 px against 0.798). Where the sub-pixel tracker refined the flight's points, those stay (the stored keypoints
// are not refined). The held-out points stay the flight's either way: the report's held-out RMS is a figure on the
// same points.
void RegistrationEngine::KeepBetterPoints(const std::vector<const Edge*>& edges, std::vector<Edge>* own,
                                          const std::unordered_set<int>& variable, int anchor,
                                          const std::unordered_map<int, double>& half_diag,
                                          const PinholeCamera& resident, LensCalibration* lens) {
  std::vector<const Edge*> flight;
  for (const Edge& e : *own) flight.push_back(&e);
  RefineOptions subset = options_.refine;
  subset.max_correspondences = options_.lens_calibration.max_correspondences;
  const bool refined = refiner_ != nullptr && options_.subpixel.enabled;
  if (!refined) {
    auto with_flight = std::async(std::launch::async, [&] {
      return HoldoutOfRefinement(flight, *own, resident, lens->distortion, variable, anchor, half_diag, subset,
                                 mosaic_from_work_);
    });
    lens->holdout_rematched_points_px = HoldoutOfRefinement(edges, *own, resident, lens->distortion, variable, anchor,
                                                            half_diag, subset, mosaic_from_work_);
    lens->holdout_flight_points_px = with_flight.get();
  }
  // A solve that failed on the flight's points judges nothing: the points the flight verified stay.
  lens->rematched_points_kept =
      !refined && std::isfinite(lens->holdout_flight_points_px) &&
      lens->holdout_rematched_points_px <=
          (1.0 + options_.lens_calibration.rematch_holdout_tolerance) * lens->holdout_flight_points_px;
  for (size_t i = 0; i < edges.size(); ++i) {
    auto* edge = const_cast<Edge*>(edges[i]);
    if (!lens->rematched_points_kept) {
      *edge = std::move((*own)[i]);
      continue;
    }
    edge->points = EdgePoints::Combine(edge->points, (*own)[i].points);
  }
}

namespace {

// The lens is one for the whole flight: a long flight calibrates it on `window` consecutive frames in its middle (its
// first the anchor) with the edges between them, so the solves' memory has a fixed bound; a shorter one on all of it.
LensWindow MiddleWindow(const std::vector<int>& component, const std::vector<const Edge*>& edges, size_t window) {
  LensWindow w;
  // `window` frames in all, the anchor one of them (a component of window + 1 frames once took every frame).
  const bool whole = component.size() <= window;
  const size_t first = whole ? 0 : (component.size() - window) / 2;
  const size_t end = whole ? component.size() : first + window;
  w.anchor = component[first];
  w.variable.insert(component.begin() + static_cast<long>(first) + 1, component.begin() + static_cast<long>(end));
  const auto inside = [&](int id) { return id == w.anchor || w.variable.count(id) != 0; };
  for (const Edge* e : edges)
    if (inside(e->src) && inside(e->tgt)) w.edges.push_back(e);
  return w;
}

}  // namespace

bool RegistrationEngine::CalibrateLensAndResolve(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                                 const std::unordered_set<int>& variable,
                                                 const std::unordered_map<int, double>& half_diag, AdjustResult* linear,
                                                 Solution* s) {
  if (!camera_ || !options_.lens_calibration.enabled) return true;
  for (int id : s->component)
    if (Record(id).work_size != cv::Size(camera_->width, camera_->height)) {
      s->lens.why = "frames of different sizes: the lens is not calibrated";
      return true;
    }
  EnterPhase("lens");
  const int window = std::min(options_.lens_calibration.max_frames, options_.refine.max_frames_per_solve);
  LensWindow w = MiddleWindow(s->component, edges, static_cast<size_t>(window));
  // The window's points are resident (bounded by the window): the calibration reads them many times, and a rematch
  // replaces some, which edges.bin does not hold.
  const size_t max_points = counters_.end_points_per_edge;
  if (!LoadEdgePoints(w.edges, max_points, EndHoldoutShare(max_points))) {  // counted at end_load already
    spdlog::warn("lens: calibrated without some edges (edges.bin unreadable)");
    // Out of the window: a rematch would give them points that the solves, reading them from edges.bin, never see.
    std::erase_if(w.edges, [](const Edge* e) { return !e->points_resident; });
  }
  s->lens = CalibrateLens(w.edges, w.variable, w.anchor, half_diag, options_.refine, *camera_,
                          options_.lens_calibration, mosaic_from_work_);
  s->lens.frames = w.variable.size() + 1;
  if (s->lens.accepted) return ResolveAtAcceptedLens(edges, points, w, *camera_, variable, half_diag, linear, s);
  const bool has_radial = camera_->distortion.k1 != 0.0 || camera_->distortion.k2 != 0.0;
  if (!s->lens.solve_failed || camera_verified_ || !has_radial) return true;
  // A database entry can be wrong for these frames (one calibrated on raw files, JPEGs the camera already corrected):
  // when nothing confirms it, the recorded pixels are the safer model. Its solves started in a basin the wrong lens
  // made, so the lens is calibrated once more from the recorded pixels, with maps solved linearly on them.
  const std::string refused = s->lens.why;
  spdlog::warn("lens: {}; the unverified prepared lens is dropped", refused);
  if (!ResolveAtLens(edges, points, *camera_, LensDistortion{}, variable, half_diag, linear, s)) return false;
  PinholeCamera recorded = *camera_;
  recorded.distortion = LensDistortion{};
  LensCalibration again = CalibrateLens(w.edges, w.variable, w.anchor, half_diag, options_.refine, recorded,
                                        options_.lens_calibration, mosaic_from_work_, "lens from the recorded pixels");
  again.frames = s->lens.frames;
  again.dropped = true;
  again.why = "the unverified prepared lens is dropped (" + refused + ")" +
              (again.accepted ? "" : "; from the recorded pixels: " + again.why);
  if (!again.accepted) {
    again.distortion = LensDistortion{};
    again.distortion_at_half_diagonal = 0.0;
  }
  s->lens = std::move(again);
  if (!s->lens.accepted) return true;
  return ResolveAtAcceptedLens(edges, points, w, recorded, variable, half_diag, linear, s);
}

bool RegistrationEngine::ResolveAtAcceptedLens(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                               const LensWindow& w, const PinholeCamera& resident,
                                               const std::unordered_set<int>& variable,
                                               const std::unordered_map<int, double>& half_diag, AdjustResult* linear,
                                               Solution* s) {
  // The rematch leaves the window's points at `resident`'s ideal pixels (the rematched ones too, when kept); they and
  // the others move to the lens's (corrected when the correction was kept) and are solved again.
  if (options_.lens_calibration.rematch)
    CorrectLensAfterRematch(w.edges, w.variable, w.anchor, half_diag, resident, &s->lens);
  return ResolveAtLens(edges, points, resident, s->lens.distortion, variable, half_diag, linear, s);
}

bool RegistrationEngine::ResolveAtLens(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                       const PinholeCamera& resident, const LensDistortion& lens,
                                       const std::unordered_set<int>& variable,
                                       const std::unordered_map<int, double>& half_diag, AdjustResult* linear,
                                       Solution* s) {
  // The engine owns the edges (the const view is the solve's): their points move to the lens's ideal pixels, the
  // resident ones now, the others as they are read (AsSolved, from the stored points at the prepared lens's).
  for (const Edge* e : edges)
    if (e->points_resident) ReprojectEdgePoints(resident, lens, const_cast<Edge*>(e));
  solved_lens_ = lens;
  *linear = AdjustAffine(edges, variable, half_diag, options_.adjust, &mosaic_from_work_, points);
  if (!linear->ok) {
    s->ok = false;
    s->failure = "final adjustment failed after the lens calibration: " + linear->failure;
    return false;
  }
  return true;
}

// The refinement with the configured model; with the homography model, affine maps too when choose_model is set
// (the homographies are kept only when they fit the held-out points better by homography_min_gain) or when the
// homographies are refused.
RefineResult RegistrationEngine::RefineAndChooseModel(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                                      const std::unordered_set<int>& variable, int anchor,
                                                      const std::unordered_map<int, double>& half_diag, Solution* s) {
  RefineOptions affine = options_.refine;
  affine.model = MotionModel::kAffine;
  std::unordered_map<int, Mat3> affine_maps;
  const bool homography = options_.refine.model == MotionModel::kHomography;
  if (homography) affine_maps = mosaic_from_work_;
  // The affine refinement (the choice's other model, or the fallback) starts from the same maps as the homographies':
  // with choose_model it runs beside them on the second core when both solves fit the plan's refinement line and the
  // points are resident (a point source is read one edge at a time).
  size_t pairs = 0;
  for (const Edge* e : edges) pairs += e->points.size();
  const bool side_by_side = homography && options_.refine.choose_model && points == nullptr &&
                            2 * pairs <= static_cast<size_t>(options_.refine.max_correspondences);
  auto affine_future = std::async(side_by_side ? std::launch::async : std::launch::deferred, [&] {
    return RefineGlobal(edges, variable, anchor, half_diag, affine, &affine_maps, nullptr, points);
  });
  RefineResult rr =
      RefineGlobal(edges, variable, anchor, half_diag, options_.refine, &mosaic_from_work_, nullptr, points);
  s->model = options_.refine.model;
  if (!homography) return rr;
  if (!rr.ok) {
    spdlog::warn("homography refinement refused ({}); refining affine maps instead", rr.failure);
    RefineResult fallback = affine_future.get();
    mosaic_from_work_ = std::move(affine_maps);
    s->model = MotionModel::kAffine;
    return fallback;
  }
  if (!options_.refine.choose_model) return rr;
  const RefineResult ra = affine_future.get();
  if (!ra.ok) return rr;
  const double homography_rms = TransferErrors(edges, mosaic_from_work_, true, 0.0, nullptr, points).rms;
  const double affine_rms = TransferErrors(edges, affine_maps, true, 0.0, nullptr, points).rms;
  const bool keep_homographies = homography_rms < (1.0 - options_.refine.homography_min_gain) * affine_rms;
  spdlog::info("refinement models: held-out RMS {:.4f} px with homographies, {:.4f} with affines: {} kept",
               homography_rms, affine_rms, keep_homographies ? "homographies" : "affines");
  if (keep_homographies) {
    s->holdout_other_model_rms = affine_rms;
    return rr;
  }
  s->holdout_other_model_rms = homography_rms;
  mosaic_from_work_ = std::move(affine_maps);
  s->model = MotionModel::kAffine;
  return ra;
}

// Re-anchors on the component's first frame (identity), solves all of it linearly, then refines: transfer errors in
// frame pixels (no pull to shrink towards the anchor) and, with the homography model, each frame's perspective.
void RegistrationEngine::SolveFinal(const std::vector<const Edge*>& edges, EdgePointSource* points,
                                    const StageTimer& since_finish, Solution* s) {
  const int anchor = s->component.front();
  const Mat3 fix = Map(anchor).inverse();
  for (int id : s->component) SetMap(id, fix * Map(id));
  std::unordered_set<int> variable(s->component.begin() + 1, s->component.end());
  std::unordered_map<int, double> half_diag;
  for (int id : s->component) half_diag[id] = Record(id).half_diagonal;
  EnterPhase("adjust");
  auto r = AdjustAffine(edges, variable, half_diag, options_.adjust, &mosaic_from_work_, points);
  if (!r.ok) {
    s->ok = false;
    s->failure = "final adjustment failed: " + r.failure;
    return;
  }
  spdlog::info("final linear adjustment: {} frames, {} edges, {}", variable.size() + 1, edges.size(),
               r.iterative ? fmt::format("conjugate gradients ({} steps)", r.iterative_steps) : "factored");
  if (!CalibrateLensAndResolve(edges, points, variable, half_diag, &r, s)) return;
  s->rms_px = r.rms_px;
  s->median_px = r.median_px;
  s->adjust_ms = since_finish.ElapsedMs();
  s->holdout_linear = TransferErrors(edges, mosaic_from_work_, true, 0.0, nullptr, points);
  StageTimer refine_timer;
  EnterPhase("refine");
  const RefineResult rr = RefineAndChooseModel(edges, points, variable, anchor, half_diag, s);
  s->refine = rr;
  s->refine_ms = refine_timer.ElapsedMs();
  s->holdout_final = TransferErrors(edges, mosaic_from_work_, true, 0.0, nullptr, points);
  s->holdout_inliers = TransferErrors(edges, mosaic_from_work_, true, options_.refine.outlier_px, nullptr, points);
  if (!rr.ok) {
    spdlog::warn("refinement failed ({}); keeping the affine solution", rr.failure);
    return;
  }
  s->rms_px = rr.final_rms_px;
  s->median_px = rr.final_median_px;
  spdlog::info(
      "{} refinement: transfer error RMS {:.3f} -> {:.3f} px (held-out points {:.3f} -> {:.3f}), {} iterations, "
      "{:.1f} s",
      ToString(s->model), rr.initial_rms_px, rr.final_rms_px, s->holdout_linear.rms, s->holdout_final.rms,
      rr.iterations, rr.seconds);
}

}  // namespace uavm
