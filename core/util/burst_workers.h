#pragma once
// Worker threads for a burst of short parallel loops, such as one frame's detection (~30 loops in ~30 ms).
//
// A loop handed to a sleeping thread starts on it only once the kernel has woken it. On a virtual machine that can
// take milliseconds (the host schedules the virtual CPU): in a paced flight, cv::parallel_for_'s pool (TBB) left the
// second core idle, or the caller waiting on a late worker, for ~8 ms of a 31 ms detection (perf sched). While a
// Burst is open these workers poll for the next loop instead of sleeping (pausing, then sched_yield, which under the
// default scheduler gives the core up only briefly: a Burst costs a core for its whole length, serial stretches
// included); between bursts they sleep. A loop's items are claimed one at a time from a shared counter, so items no
// worker has claimed are the caller's: it waits only for items a worker has started (or, rarely, for a worker
// descheduled between counting itself into the loop and claiming).
//
// Ownership: the workers are this object's threads, joined by its destructor. One caller at a time (ForEach and
// Burst are not for concurrent callers; a second caller needs workers of its own). A loop started from inside an item
// runs on the thread that starts it, one item after another.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace uavm {

class BurstWorkers {
 public:
  // `threads` workers beside the caller (0: every loop runs on the caller).
  explicit BurstWorkers(int threads);
  ~BurstWorkers();
  BurstWorkers(const BurstWorkers&) = delete;
  BurstWorkers& operator=(const BurstWorkers&) = delete;

  [[nodiscard]] int threads() const { return static_cast<int>(threads_.size()); }

  // fn(i) for every i in [0, n), on the caller and the workers, each item once; returns when all have returned. The
  // first exception an item throws is rethrown here, after the others have finished.
  void ForEach(int n, const std::function<void(int)>& fn);

  // While one lives, the workers poll for loops instead of sleeping.
  class Burst {
   public:
    explicit Burst(BurstWorkers* workers);
    ~Burst();
    Burst(const Burst&) = delete;
    Burst& operator=(const Burst&) = delete;

   private:
    BurstWorkers* workers_;
  };

 private:
  struct Loop {
    const std::function<void(int)>* fn = nullptr;
    int n = 0;
    std::atomic<int> next{0};
    std::mutex error_mutex;
    std::exception_ptr error;
  };
  void RunItems(Loop* loop) const;
  void Work();
  void Wake();

  std::atomic<Loop*> loop_{nullptr};     // the open loop, or none
  std::atomic<uint64_t> generation_{0};  // loops opened so far
  std::atomic<int> inside_{0};           // workers inside the open loop: the caller waits for them before closing it
  std::atomic<int> bursts_{0};           // open Bursts
  std::atomic<bool> stop_{false};
  std::mutex mutex_;  // for the sleeping workers' condition
  std::condition_variable wake_;
  std::vector<std::thread> threads_;
};

}  // namespace uavm
