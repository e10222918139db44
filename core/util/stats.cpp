#include "core/util/stats.h"

#include <algorithm>
#include <cmath>

namespace uavm {

namespace {

constexpr int kBins = StageStats::kBinsPerDecade * StageStats::kDecades;

int BinOf(double ms) {
  if (!(ms > StageStats::kMinMs)) return 0;
  const double b = std::floor(std::log10(ms / StageStats::kMinMs) * StageStats::kBinsPerDecade);
  return static_cast<int>(std::min<double>(b, kBins - 1));
}

// The bin's geometric centre.
double CentreOf(int bin) {
  return StageStats::kMinMs * std::pow(10.0, (bin + 0.5) / StageStats::kBinsPerDecade);
}

}  // namespace

void StageStats::Add(const std::string& stage, double ms) {
  auto [it, inserted] = stages_.try_emplace(stage);
  Histogram& h = it->second;
  if (inserted) {
    order_.push_back(stage);
    h.bins.assign(kBins, 0);
    h.min = ms;
    h.max = ms;
  }
  ++h.bins[static_cast<size_t>(BinOf(ms))];
  ++h.count;
  h.total += ms;
  h.min = std::min(h.min, ms);
  h.max = std::max(h.max, ms);
}

Summary StageStats::Get(const std::string& stage) const {
  const auto it = stages_.find(stage);
  if (it == stages_.end()) return {};
  const Histogram& h = it->second;
  Summary s;
  s.count = h.count;
  s.total = h.total;
  s.max = h.max;
  // The value of nearest rank `rank` (1-based), clamped to what was seen.
  const auto value_at = [&](size_t rank) {
    size_t seen = 0;
    for (int b = 0; b < kBins; ++b) {
      seen += h.bins[static_cast<size_t>(b)];
      if (seen >= rank) return std::clamp(CentreOf(b), h.min, h.max);
    }
    return h.max;
  };
  s.median = value_at((h.count + 1) / 2);
  s.p95 = value_at(static_cast<size_t>(std::ceil(0.95 * static_cast<double>(h.count))));
  return s;
}

}  // namespace uavm
