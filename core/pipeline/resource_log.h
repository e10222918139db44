#pragma once
#include <nlohmann/json.hpp>

#include "core/pipeline/memory_budget.h"
#include "core/util/memory.h"
#include "core/util/memory_watch.h"
#include "core/util/record_arena.h"

namespace uavm {

// The process's resources at the phases of a run (flight, end-of-flight solves, composing), for report.json: a long
// flight must neither leak descriptors nor outgrow its memory plan. Each phase's peak is sampled by a MemoryWatch;
// the kernel's high-water mark is never reset, so the run's peak is the same figure for it and for an outside tool.
class ResourceLog {
 public:
  void FlightStart();
  void FlightEnd();  // after the last frame
  // The end of the flight's steps, in order (the engine's solves, radiometry, outputs, compositing, products). Each
  // starts with the pages the last one freed given back (the image pool's free blocks, then TrimHeap): a phase's peak
  // is its own working set on top of what stays, not the previous phase's holes.
  void EnterPhase(const std::string& name);
  void ComposeEnd();  // after the mosaic is written
  // The run's peak RSS over every phase so far, MiB.
  [[nodiscard]] double PeakRssMiB() const { return watch_.PeakRssMiB(); }
  [[nodiscard]] std::vector<PhaseMemory> Phases() const { return watch_.Phases(); }
  // report.json "memory" (with the plan it was sized by) and "open_fds".
  [[nodiscard]] nlohmann::json MemoryJson(const MemoryPlan& plan) const;
  [[nodiscard]] nlohmann::json FdsJson() const;

 private:
  int fds_at_start_ = -1;
  int fds_at_flight_end_ = -1;
  double flight_end_rss_mib_ = 0.0;  // RSS when the last frame was registered
  HeapStats flight_end_heap_;
  RecordArena::Counters flight_end_arena_;
  MemoryWatch watch_;
};

}  // namespace uavm
