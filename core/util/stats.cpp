#include "core/util/stats.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace uavm {

Summary Summarize(std::vector<double> values) {
  Summary s;
  s.count = values.size();
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  auto rank = [&](double q) {
    const auto idx = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size()))) - 1;
    return values[std::min(idx, values.size() - 1)];
  };
  const size_t n = values.size();
  s.median = (n % 2 == 1) ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
  s.p95 = rank(0.95);
  s.max = values.back();
  s.total = std::accumulate(values.begin(), values.end(), 0.0);
  return s;
}

void StageStats::Add(const std::string& stage, double ms) {
  auto [it, inserted] = samples_.try_emplace(stage);
  if (inserted) order_.push_back(stage);
  it->second.push_back(ms);
}

Summary StageStats::Get(const std::string& stage) const {
  auto it = samples_.find(stage);
  return it == samples_.end() ? Summary{} : Summarize(it->second);
}

}  // namespace uavm
