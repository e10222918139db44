#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace uavm {

// Quantiles of values in fixed memory: `bins_per_decade` log-spaced bins a decade over `decades` decades from
// `min_value` (> 0), and two more for what falls outside: values below `min_value` (zero, negatives) and values beyond
// the last decade, which report the smallest and the largest seen. A quantile in the range is its bin's geometric
// centre clamped to the values seen: within half a bin of the exact figure (10^(0.5 / bins_per_decade) - 1 relative),
// and exact for a single value. A NaN or an infinity is not added (counted apart). Count, min and max are exact. What
// it holds does not grow with the values added.
class LogHistogram {
 public:
  LogHistogram(double min_value, int decades, int bins_per_decade);

  void Add(double value);
  [[nodiscard]] size_t count() const { return count_; }
  [[nodiscard]] size_t non_finite() const { return non_finite_; }
  [[nodiscard]] double min() const { return min_; }
  [[nodiscard]] double max() const { return max_; }
  // The value of nearest rank `rank` (1-based, clamped to [1, count]); 0 when empty.
  [[nodiscard]] double AtRank(size_t rank) const;
  // Nearest rank (count + 1) / 2: of an even count, the lower of the two middle values.
  [[nodiscard]] double Median() const { return AtRank((count_ + 1) / 2); }

 private:
  [[nodiscard]] size_t BinOf(double value) const;

  double min_value_;
  int bins_per_decade_;
  std::vector<uint32_t> bins_;  // [0] below min_value, [1, n] the decades, [n + 1] beyond
  size_t count_ = 0;
  size_t non_finite_ = 0;
  double min_ = 0.0;
  double max_ = 0.0;
};

// A histogram for residuals in pixels: 10^-6 to 10^6 px within 0.12 % (47 KiB, whatever the count).
[[nodiscard]] inline LogHistogram ResidualHistogram() {
  return LogHistogram(1e-6, 12, 1000);
}

struct Summary {
  size_t count = 0;
  double median = 0.0;
  double p95 = 0.0;
  double max = 0.0;
  double total = 0.0;
};

// Per-stage timing samples (ms), one sample per frame and stage; insertion order of stages is kept for reports. Count,
// total and max are exact; the median and p95 (nearest rank) come from a LogHistogram of kBinsPerDecade bins a decade
// (within 0.6 % of the exact figure), so a flight of any length holds the same few KiB per stage and reading a median
// on every frame costs the same at frame 5 as at frame 50 000.
class StageStats {
 public:
  static constexpr int kBinsPerDecade = 200;
  static constexpr double kMinMs = 1e-3;  // bins from 1 us to 10^7 ms; beyond, the end bins
  static constexpr int kDecades = 10;

  void Add(const std::string& stage, double ms);
  [[nodiscard]] const std::vector<std::string>& Stages() const { return order_; }
  [[nodiscard]] Summary Get(const std::string& stage) const;

 private:
  struct Stage {
    LogHistogram histogram{kMinMs, kDecades, kBinsPerDecade};
    double total = 0.0;
  };
  std::vector<std::string> order_;
  std::map<std::string, Stage> stages_;
};

}  // namespace uavm
