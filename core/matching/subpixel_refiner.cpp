#include "core/matching/subpixel_refiner.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace uavm {

bool SubpixelOptions::Check(std::string* why) const {
  auto fail = [&](const char* msg) {
    if (why != nullptr) *why = msg;
    return false;
  };
  if (window < 5 || window % 2 == 0) return fail("matching.subpixel_window must be odd and >= 5");
  if (cache_frames < 2) return fail("matching.subpixel_cache_frames must be >= 2");
  if (!(max_shift_px > 0.0)) return fail("matching.subpixel_max_shift_px must be > 0");
  if (!(min_kept_fraction >= 0.0 && min_kept_fraction <= 1.0))
    return fail("matching.subpixel_min_kept_fraction must be in [0,1]");
  return true;
}

SubpixelRefiner::SubpixelRefiner(const SubpixelOptions& options) : options_(options) {}

void SubpixelRefiner::Put(int id, cv::Mat gray) {
  if (!options_.enabled || gray.empty() || gray.type() != CV_8UC1) return;
  images_.emplace_back(id, std::move(gray));
  while (images_.size() > static_cast<size_t>(options_.cache_frames)) images_.pop_front();
}

const cv::Mat* SubpixelRefiner::Find(int id) const {
  for (auto it = images_.rbegin(); it != images_.rend(); ++it)
    if (it->first == id) return &it->second;
  return nullptr;
}

size_t SubpixelRefiner::MemoryBytes() const {
  size_t bytes = 0;
  for (const auto& [id, m] : images_) bytes += m.total() * m.elemSize();
  return bytes;
}

void SubpixelRefiner::Track(const cv::Mat& src, const cv::Mat& tgt, const Mat3& tgt_from_src,
                            const std::vector<Vec2>& src_pts, std::vector<Vec2>* tgt_pts,
                            std::vector<unsigned char>* ok) const {
  ok->assign(src_pts.size(), 0);
  if (src_pts.empty()) return;
  // Only the region the target points cover (with the LK window and a pyramid level's margin) is warped.
  const int pad = options_.window + 8;
  double x0 = tgt.cols, y0 = tgt.rows, x1 = 0, y1 = 0;
  for (const Vec2& p : *tgt_pts) {
    x0 = std::min(x0, p.x()), y0 = std::min(y0, p.y()), x1 = std::max(x1, p.x()), y1 = std::max(y1, p.y());
  }
  const cv::Rect roi =
      cv::Rect(cv::Point(static_cast<int>(std::floor(x0)) - pad, static_cast<int>(std::floor(y0)) - pad),
               cv::Point(static_cast<int>(std::ceil(x1)) + pad + 1, static_cast<int>(std::ceil(y1)) + pad + 1)) &
      cv::Rect(0, 0, tgt.cols, tgt.rows);
  if (roi.area() <= 0) return;
  const Mat3 roi_from_src = Translation(-roi.x, -roi.y) * tgt_from_src;
  cv::Mat m(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m.at<double>(r, c) = roi_from_src(r, c);
  cv::Mat warped;
  if (IsAffine(roi_from_src, 1e-9))
    cv::warpAffine(src, warped, m.rowRange(0, 2), roi.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  else
    cv::warpPerspective(src, warped, m, roi.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  std::vector<cv::Point2f> from, to;
  from.reserve(src_pts.size());
  to.reserve(src_pts.size());
  for (size_t i = 0; i < src_pts.size(); ++i) {
    const Vec2 a = Apply(roi_from_src, src_pts[i]);
    from.emplace_back(static_cast<float>(a.x()), static_cast<float>(a.y()));
    to.emplace_back(static_cast<float>((*tgt_pts)[i].x() - roi.x), static_cast<float>((*tgt_pts)[i].y() - roi.y));
  }
  const std::vector<cv::Point2f> start = to;
  std::vector<unsigned char> status;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(warped, tgt(roi), from, to, status, err, cv::Size(options_.window, options_.window), 1,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  // A wrong match can settle in a local minimum near where it started: its patches still differ. Tracks whose mean
  // difference is well above the pair's typical one are failures too.
  std::vector<float> tracked_err;
  for (size_t i = 0; i < err.size(); ++i)
    if (status[i] != 0 && std::isfinite(err[i])) tracked_err.push_back(err[i]);
  float max_err = std::numeric_limits<float>::infinity();
  if (!tracked_err.empty()) {
    auto mid = tracked_err.begin() + static_cast<std::ptrdiff_t>(tracked_err.size() / 2);
    std::nth_element(tracked_err.begin(), mid, tracked_err.end());
    max_err = 3.0f * *mid + 2.0f;
  }
  const double max_shift2 = options_.max_shift_px * options_.max_shift_px;
  for (size_t i = 0; i < to.size(); ++i) {
    const double dx = to[i].x - start[i].x, dy = to[i].y - start[i].y;
    if (status[i] == 0 || !(err[i] <= max_err) || !std::isfinite(dx) || !std::isfinite(dy) ||
        dx * dx + dy * dy > max_shift2)
      continue;
    (*ok)[i] = 1;
    (*tgt_pts)[i] = Vec2(static_cast<double>(to[i].x) + roi.x, static_cast<double>(to[i].y) + roi.y);
  }
}

namespace {

// Keeps the pairs whose flag is set.
void KeepFlagged(const std::vector<unsigned char>& ok, size_t offset, std::vector<Vec2>* src, std::vector<Vec2>* tgt) {
  size_t n = 0;
  for (size_t i = 0; i < src->size(); ++i) {
    if (ok[offset + i] == 0) continue;
    (*src)[n] = (*src)[i];
    (*tgt)[n] = (*tgt)[i];
    ++n;
  }
  src->resize(n);
  tgt->resize(n);
}

}  // namespace

bool SubpixelRefiner::RefinePair(int src_id, int tgt_id, const Mat3& tgt_from_src,
                                 std::pair<std::vector<Vec2>*, std::vector<Vec2>*> used,
                                 std::pair<std::vector<Vec2>*, std::vector<Vec2>*> holdout) {
  if (!options_.enabled) return false;
  const cv::Mat* src = Find(src_id);
  const cv::Mat* tgt = Find(tgt_id);
  if (src == nullptr || tgt == nullptr) {
    ++counters_.edges_not_cached;
    return false;
  }
  // One LK call over both sets: the adjustment's points first, then the held-out ones.
  std::vector<Vec2> src_all = *used.first, tgt_all = *used.second;
  src_all.insert(src_all.end(), holdout.first->begin(), holdout.first->end());
  tgt_all.insert(tgt_all.end(), holdout.second->begin(), holdout.second->end());
  std::vector<unsigned char> ok;
  Track(*src, *tgt, tgt_from_src, src_all, &tgt_all, &ok);
  const auto kept = static_cast<size_t>(std::count(ok.begin(), ok.end(), 1));
  if (static_cast<double>(kept) < options_.min_kept_fraction * static_cast<double>(ok.size()) || kept == 0) {
    ++counters_.edges_kept_unrefined;
    return false;
  }
  const size_t n_used = used.first->size();
  std::copy(tgt_all.begin(), tgt_all.begin() + static_cast<std::ptrdiff_t>(n_used), used.second->begin());
  std::copy(tgt_all.begin() + static_cast<std::ptrdiff_t>(n_used), tgt_all.end(), holdout.second->begin());
  KeepFlagged(ok, 0, used.first, used.second);
  KeepFlagged(ok, n_used, holdout.first, holdout.second);
  ++counters_.edges_refined;
  counters_.points_refined += static_cast<long>(kept);
  counters_.points_dropped += static_cast<long>(ok.size() - kept);
  return true;
}

bool SubpixelRefiner::Refine(int src_id, int tgt_id, const Mat3& tgt_from_src, std::vector<Vec2>* src,
                             std::vector<Vec2>* tgt) {
  std::vector<Vec2> none_src, none_tgt;
  return RefinePair(src_id, tgt_id, tgt_from_src, {src, tgt}, {&none_src, &none_tgt});
}

}  // namespace uavm
