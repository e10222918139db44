#pragma once
#include <map>
#include <string>
#include <vector>

namespace uavm {

struct Summary {
  size_t count = 0;
  double median = 0.0;
  double p95 = 0.0;
  double max = 0.0;
  double total = 0.0;
};

// Median / p95 / max / total of a sample (nearest-rank percentiles). Empty input gives zeros.
[[nodiscard]] Summary Summarize(std::vector<double> values);

// Per-stage timing samples (ms), one sample per frame and stage. Insertion order of stages is kept for reports.
class StageStats {
 public:
  void Add(const std::string& stage, double ms);
  [[nodiscard]] const std::vector<std::string>& Stages() const { return order_; }
  [[nodiscard]] Summary Get(const std::string& stage) const;

 private:
  std::vector<std::string> order_;
  std::map<std::string, std::vector<double>> samples_;
};

}  // namespace uavm
