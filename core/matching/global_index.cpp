#include "core/matching/global_index.h"

#include <algorithm>
#include <map>

#include "core/matching/pair_matcher.h"

namespace uavm {

bool GlobalIndexOptions::Check(std::string* why) const {
  if (descriptors_per_frame < 8 || max_descriptors < descriptors_per_frame * 4) {
    if (why != nullptr) *why = "relocalization: need descriptors_per_frame >= 8 and max_descriptors >= 4x that";
    return false;
  }
  if (!(keyframe_spacing >= 0 && keyframe_spacing <= 4)) {
    if (why != nullptr) *why = "relocalization.keyframe_spacing must be in [0, 4]";
    return false;
  }
  if (!(ratio > 0 && ratio <= 1) || min_votes < 1 || rebuild_every_frames < 1) {
    if (why != nullptr) *why = "relocalization: ratio must be in (0,1], min_votes >= 1, rebuild_every_frames >= 1";
    return false;
  }
  return true;
}

GlobalIndex::GlobalIndex(const GlobalIndexOptions& options)
    : options_(options),
      quota_(options.descriptors_per_frame),
      // Zeroed, not just allocated: every page is resident from the first frame, so the index's line of the memory
      // plan is held from take-off instead of arriving in the flight's last hour (and a budget that cannot hold it
      // fails at the start).
      descriptors_(cv::Mat::zeros(options.max_descriptors, kDescriptorSize, CV_8U)) {
  const auto cap = static_cast<size_t>(options.max_descriptors);
  frame_of_row_.reserve(cap);
  rank_in_frame_.reserve(cap);
  index_frame_of_row_.reserve(cap);
}

void GlobalIndex::Add(int frame_id, const Features& features) {
  const int n = features.descriptors.rows;
  if (n == 0 || descriptors_.empty() || features.descriptors.cols != kDescriptorSize) return;
  const int take = std::min(n, quota_);
  const cv::Mat q =
      features.descriptors.type() == CV_8U ? features.descriptors : QuantizeDescriptors(features.descriptors);
  while (rows_ + take > options_.max_descriptors && quota_ > 1) Thin();
  const int take_now = std::min({take, quota_, options_.max_descriptors - rows_});
  for (int k = 0; k < take_now; ++k) {
    const int row = static_cast<int>(static_cast<long>(k) * n / take_now);  // evenly spread over the frame's list
    q.row(row).copyTo(descriptors_.row(rows_++));
    frame_of_row_.push_back(frame_id);
    rank_in_frame_.push_back(k);
  }
  dirty_ = true;
  ++added_since_build_;
}

void GlobalIndex::Thin() {
  index_.reset();  // the tree borrows rows that are about to move
  index_rows_ = 0;
  int kept = 0;
  for (int r = 0; r < rows_; ++r) {
    const auto rs = static_cast<size_t>(r);
    if (rank_in_frame_[rs] % 2 != 0) continue;
    const auto ks = static_cast<size_t>(kept);
    if (kept != r) descriptors_.row(r).copyTo(descriptors_.row(kept));
    frame_of_row_[ks] = frame_of_row_[rs];
    rank_in_frame_[ks] = rank_in_frame_[rs] / 2;
    ++kept;
  }
  rows_ = kept;
  frame_of_row_.resize(static_cast<size_t>(kept));
  rank_in_frame_.resize(static_cast<size_t>(kept));
  quota_ = std::max(1, quota_ / 2);
  dirty_ = true;
  ++thinnings_;
}

void GlobalIndex::Release() {
  index_.reset();
  index_rows_ = 0;
  rows_ = 0;
  descriptors_.release();
  frame_of_row_.clear();
  frame_of_row_.shrink_to_fit();
  rank_in_frame_.clear();
  rank_in_frame_.shrink_to_fit();
  index_frame_of_row_.clear();
  index_frame_of_row_.shrink_to_fit();
  dirty_ = true;
}

std::vector<int> GlobalIndex::Query(const Features& features, int max_results, bool allow_stale) {
  std::vector<int> out;
  if (rows_ < 2 || features.descriptors.rows == 0 || features.descriptors.cols != kDescriptorSize) return out;
  const bool stale_ok = allow_stale && index_ && added_since_build_ < options_.rebuild_every_frames;
  if (dirty_ && !stale_ok) {
    added_since_build_ = 0;
    // Rebuilt lazily: relocalisation is rare, adding frames is not.
    index_frame_of_row_.assign(frame_of_row_.begin(), frame_of_row_.end());  // within the reserved capacity
    index_.reset();
    index_ = std::make_unique<KdForest>(descriptors_.rowRange(0, rows_), kForest);
    index_rows_ = rows_;
    dirty_ = false;
  }
  const cv::Mat query = QuantizeDescriptors(features.descriptors);
  const double ratio_sq = options_.ratio * options_.ratio;  // of squared distances
  std::map<int, int> votes;
  for (int q = 0; q < query.rows; ++q) {
    int nearest[2];
    uint32_t dist[2];
    index_->Nearest2(query.ptr<uint8_t>(q), kChecks, nearest, dist);
    const int t0 = nearest[0];
    const int t1 = nearest[1];
    if (t0 < 0 || t0 >= index_rows_) continue;
    const int f0 = index_frame_of_row_[static_cast<size_t>(t0)];
    // Two neighbours from the same frame do not make the match ambiguous.
    const bool same_frame = t1 >= 0 && t1 < index_rows_ && index_frame_of_row_[static_cast<size_t>(t1)] == f0;
    if (same_frame || static_cast<double>(dist[0]) < ratio_sq * static_cast<double>(dist[1])) ++votes[f0];
  }
  std::vector<std::pair<int, int>> ranked;
  for (const auto& [frame, v] : votes)
    if (v >= options_.min_votes) ranked.emplace_back(v, frame);
  std::sort(ranked.rbegin(), ranked.rend());
  for (size_t i = 0; i < ranked.size() && static_cast<int>(i) < max_results; ++i) out.push_back(ranked[i].second);
  return out;
}

}  // namespace uavm
