#pragma once
#include <nlohmann/json.hpp>

#include "core/pipeline/memory_budget.h"
#include "core/util/memory.h"

namespace uavm {

// The process's resources at the phases of a run (flight, end-of-flight solves, composing), for report.json: a long
// flight must neither leak descriptors nor outgrow its memory plan. Each phase's peak is the kernel's high-water mark,
// reset between phases.
class ResourceLog {
 public:
  void FlightStart();
  void FlightEnd();   // after the last frame
  void SolvesEnd();   // after the final solve
  void ComposeEnd();  // after the mosaic is written
  // report.json "memory" (with the plan it was sized by) and "open_fds".
  [[nodiscard]] nlohmann::json MemoryJson(const MemoryPlan& plan) const;
  [[nodiscard]] nlohmann::json FdsJson() const;

 private:
  int fds_at_start_ = -1;
  int fds_at_flight_end_ = -1;
  double flight_peak_rss_mib_ = 0.0;   // peak RSS when the last frame was registered
  double flight_end_rss_mib_ = 0.0;    // RSS then
  double solve_peak_rss_mib_ = 0.0;    // peak of the end-of-flight solves (from flight end)
  double compose_peak_rss_mib_ = 0.0;  // peak of writing the session files and the mosaic (from the solves' end)
  HeapStats flight_end_heap_;
};

}  // namespace uavm
