#include "core/util/stats.h"

#include <algorithm>
#include <cmath>

namespace uavm {

LogHistogram::LogHistogram(double min_value, int decades, int bins_per_decade)
    : min_value_(min_value > 0 ? min_value : 1e-300),
      bins_per_decade_(std::max(1, bins_per_decade)),
      bins_(static_cast<size_t>(std::max(1, decades) * bins_per_decade_) + 2, 0) {}

size_t LogHistogram::BinOf(double value) const {
  if (!(value >= min_value_)) return 0;
  const double b = std::floor(std::log10(value / min_value_) * bins_per_decade_);
  const auto last = static_cast<double>(bins_.size() - 1);
  return b + 1 >= last ? bins_.size() - 1 : static_cast<size_t>(b) + 1;
}

void LogHistogram::Add(double value) {
  if (!std::isfinite(value)) {
    ++non_finite_;
    return;
  }
  if (count_ == 0) min_ = max_ = value;
  ++bins_[BinOf(value)];
  ++count_;
  min_ = std::min(min_, value);
  max_ = std::max(max_, value);
}

double LogHistogram::AtRank(size_t rank) const {
  if (count_ == 0) return 0.0;
  rank = std::clamp<size_t>(rank, 1, count_);
  size_t seen = 0;
  for (size_t b = 0; b < bins_.size(); ++b) {
    seen += bins_[b];
    if (seen < rank) continue;
    if (b == 0) return min_;
    if (b + 1 == bins_.size()) return max_;
    const double centre = min_value_ * std::pow(10.0, (static_cast<double>(b - 1) + 0.5) / bins_per_decade_);
    return std::clamp(centre, min_, max_);
  }
  return max_;
}

void StageStats::Add(const std::string& stage, double ms) {
  auto [it, inserted] = stages_.try_emplace(stage);
  if (inserted) order_.push_back(stage);
  it->second.histogram.Add(ms);
  it->second.total += ms;
}

Summary StageStats::Get(const std::string& stage) const {
  const auto it = stages_.find(stage);
  if (it == stages_.end()) return {};
  const LogHistogram& h = it->second.histogram;
  Summary s;
  s.count = h.count();
  s.total = it->second.total;
  s.max = h.max();
  s.median = h.Median();
  s.p95 = h.AtRank(static_cast<size_t>(std::ceil(0.95 * static_cast<double>(h.count()))));
  return s;
}

}  // namespace uavm
