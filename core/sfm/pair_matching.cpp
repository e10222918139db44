#include "core/sfm/pair_matching.h"

#include <algorithm>
#include <atomic>
#include <opencv2/calib3d.hpp>

#include "core/matching/radius_matcher.h"
#include "core/util/parallel.h"

namespace uavm::sfm {

PairMatch MatchPair(size_t a, size_t b, const FrameFeatures& fa, const FrameFeatures& fb, const SessionFrame& frame_a,
                    const SessionFrame& frame_b, const ReconstructionOptions& options) {
  PairMatch out;
  if (fa.points.size() < 8 || fb.points.size() < 8) return out;
  const Mat3 b_from_a = frame_b.mosaic_from_frame.inverse() * frame_a.mosaic_from_frame;
  // Guided by the onboard maps (core/matching/radius_matcher.h): candidates near the predicted position only.
  const RadiusMatchOptions guide{.radius_px = options.guided_radius * std::max(frame_a.width, frame_a.height),
                                 .ratio = options.ratio};
  const std::vector<RadiusMatch> guided = MatchWithinRadius(fa.points, fa.descriptors, fb.points, fb.descriptors,
                                                            cv::Size(frame_b.width, frame_b.height), b_from_a, guide);
  std::vector<cv::Point2f> pa, pb;
  std::vector<FeatureMatch> cand;
  for (const RadiusMatch& m : guided) {
    cand.push_back({static_cast<int>(a), m.a, static_cast<int>(b), m.b, m.distance_sq});
    pa.emplace_back(static_cast<float>(fa.points[static_cast<size_t>(m.a)].x()),
                    static_cast<float>(fa.points[static_cast<size_t>(m.a)].y()));
    pb.emplace_back(static_cast<float>(fb.points[static_cast<size_t>(m.b)].x()),
                    static_cast<float>(fb.points[static_cast<size_t>(m.b)].y()));
  }
  out.candidates = static_cast<int>(cand.size());
  if (static_cast<int>(cand.size()) < options.min_pair_inliers) return out;
  std::vector<uchar> mask;
  const cv::Mat F = cv::findFundamentalMat(pa, pb, cv::FM_RANSAC, options.fundamental_threshold_px, 0.9999, mask);
  if (F.empty()) return out;
  std::vector<FeatureMatch> inl;
  for (size_t i = 0; i < cand.size(); ++i) {
    if (mask[i]) inl.push_back(cand[i]);
  }
  out.inliers = static_cast<int>(inl.size());
  if (static_cast<int>(inl.size()) >= options.min_pair_inliers) out.matches = std::move(inl);
  return out;
}

// The verified matches of all pairs, in pair order (image slots, ascending).
std::vector<FeatureMatch> MatchGraphPairs(const SelectedFrames& sel, const std::vector<FrameFeatures>& feats,
                                          const ReconstructionOptions& options, const ProgressFn& progress,
                                          nlohmann::json* js) {
  const auto& frames = sel.frames;
  std::vector<std::pair<size_t, size_t>> pairs;
  for (const auto& e : sel.session.edges) {
    if (e.used && sel.slot_of.count(e.src) && sel.slot_of.count(e.tgt)) {
      pairs.emplace_back(sel.slot_of.at(e.src), sel.slot_of.at(e.tgt));
    }
  }
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  std::vector<PairMatch> results(pairs.size());
  std::atomic<size_t> done{0};
  ParallelFor(pairs.size(), options.threads, [&](size_t k) {
    const auto [a, b] = pairs[k];
    results[k] = MatchPair(a, b, feats[a], feats[b], *frames[a], *frames[b], options);
    if (feats[a].points.size() < 8 || feats[b].points.size() < 8) return;  // as before: no progress for those
    if (progress) progress("matching", ++done, pairs.size());
  });
  std::vector<FeatureMatch> all_matches;
  int pairs_ok = 0;
  nlohmann::json jp = nlohmann::json::array();
  for (size_t k = 0; k < pairs.size(); ++k) {
    auto& m = results[k].matches;
    if (!m.empty()) ++pairs_ok;
    all_matches.insert(all_matches.end(), m.begin(), m.end());
    jp.push_back(
        {frames[pairs[k].first]->index, frames[pairs[k].second]->index, results[k].candidates, results[k].inliers});
  }
  (*js)["pairs_listed"] = pairs.size();
  (*js)["pairs_verified"] = pairs_ok;
  (*js)["pair_matches"] = jp;  // [src, tgt, guided candidates, F inliers]
  (*js)["matches"] = all_matches.size();
  return all_matches;
}

}  // namespace uavm::sfm
