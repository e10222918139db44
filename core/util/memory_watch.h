#pragma once
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/util/memory.h"

namespace uavm {

// One phase of a run as seen from the process's resident memory: the largest VmRSS and RssAnon sampled while it ran.
struct PhaseMemory {
  std::string name;
  double peak_rss_mib = 0;   // VmRSS
  double peak_anon_mib = 0;  // RssAnon: the heap and stacks, what a memory cgroup cannot reclaim
  double seconds = 0;
  // The allocator's view when the phase was first entered (glibc mallinfo2): heap in use, and what the arenas hold
  // (in use + free inside them). What a phase starts with, and how much of it is holes, beside its peak.
  HeapStats heap_at_start;
};

// Samples this process's VmRSS and RssAnon (/proc/self/status) on a thread of its own, every `interval_ms`, and
// attributes each sample to the phase the run is in. It never resets the kernel's high-water mark (VmHWM, the
// `ru_maxrss` of getrusage, what /usr/bin/time and a cgroup's accounting read), so an outside tool sees every phase's
// peak too. A phase that raised VmHWM gets that figure, so a spike between two samples is not lost either.
// The sampling thread is named "mem:<phase>" (/proc/PID/task/TID/comm): an outside sampler can tell the phases
// apart without any file of the program's (bench/memory.sh does).
class MemoryWatch {
 public:
  explicit MemoryWatch(int interval_ms = 20);
  ~MemoryWatch();
  MemoryWatch(const MemoryWatch&) = delete;
  MemoryWatch& operator=(const MemoryWatch&) = delete;

  // Ends the current phase (with a sample) and starts `name` (at most 11 characters are shown in the thread name).
  // Entering the phase that is current does nothing.
  void Enter(const std::string& name);
  // Every phase so far, in order (the current one up to now); a phase entered twice has one entry.
  [[nodiscard]] std::vector<PhaseMemory> Phases() const;
  // The run's peak VmRSS so far: the kernel's high-water mark, or the largest sample when that cannot be read.
  [[nodiscard]] double PeakRssMiB() const;
  [[nodiscard]] std::string current() const;

 private:
  void Run();
  void SampleLocked();
  void NameThread();

  const int interval_ms_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  bool stop_ = false;
  std::vector<PhaseMemory> phases_;  // guarded by mutex_
  size_t current_ = 0;
  double phase_start_hwm_mib_ = 0;
  double phase_start_s_ = 0;
  double max_sampled_mib_ = 0;
  std::atomic<bool> renamed_{false};
  std::thread thread_;  // last: started when everything it reads exists
};

}  // namespace uavm
