#pragma once
#include <cstdint>
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

// Per-stage timing samples (ms), one sample per frame and stage; insertion order of stages is kept for reports. Count,
// total and max are exact; the median and p95 (nearest rank) come from a fixed histogram of kBinsPerDecade
// log-spaced bins a decade (within 0.6 % of the exact figure), so a flight of any length holds the same few KiB per
// stage and reading a median on every frame costs the same at frame 5 as at frame 50 000.
class StageStats {
 public:
  static constexpr int kBinsPerDecade = 200;
  static constexpr double kMinMs = 1e-3;  // bins from 1 us to 10^7 ms; beyond, the end bins
  static constexpr int kDecades = 10;

  void Add(const std::string& stage, double ms);
  [[nodiscard]] const std::vector<std::string>& Stages() const { return order_; }
  [[nodiscard]] Summary Get(const std::string& stage) const;

 private:
  struct Histogram {
    std::vector<uint32_t> bins;
    size_t count = 0;
    double total = 0.0;
    double min = 0.0;
    double max = 0.0;
  };
  std::vector<std::string> order_;
  std::map<std::string, Histogram> stages_;
};

}  // namespace uavm
