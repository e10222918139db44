#include "core/util/burst_workers.h"

#include <algorithm>
#include <cstdint>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace uavm {
namespace {

// A spin-wait hint to the core (lets a sibling hyper-thread run, saves power).
inline void CpuRelax() {
#if defined(__x86_64__) || defined(__i386__)
  _mm_pause();
#elif defined(__aarch64__)
  asm volatile("yield");
#endif
}

// Polls before a waiting thread starts yielding its core on every poll (a few microseconds).
constexpr int kPollsBeforeYield = 64;

// The workers whose loop item this thread is running, if any: a loop started inside an item runs inline (a worker
// would wait for itself to leave the outer loop; the caller would close the outer loop early).
thread_local const BurstWorkers* tls_running = nullptr;

}  // namespace

BurstWorkers::BurstWorkers(int threads) {
  threads_.reserve(static_cast<size_t>(std::max(threads, 0)));
  try {
    for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { Work(); });
  } catch (...) {  // no thread for the rest: stop those started (joinable threads must not be destroyed)
    stop_.store(true);
    Wake();
    for (auto& t : threads_) t.join();
    throw;
  }
}

BurstWorkers::~BurstWorkers() {
  stop_.store(true);
  Wake();
  for (auto& t : threads_) t.join();
}

void BurstWorkers::Wake() {
  try {
    const std::lock_guard<std::mutex> lock(mutex_);  // a worker between its check and its wait is then waiting
  } catch (...) {  // (a mutex that cannot be locked: the workers then find the loop when they poll, or not at all)
  }
  wake_.notify_all();
}

void BurstWorkers::RunItems(Loop* loop) const {
  const BurstWorkers* const outer = tls_running;
  tls_running = this;
  for (int i = loop->next.fetch_add(1); i < loop->n; i = loop->next.fetch_add(1)) {
    try {
      (*loop->fn)(i);
    } catch (...) {
      const std::lock_guard<std::mutex> lock(loop->error_mutex);
      if (!loop->error) loop->error = std::current_exception();
    }
  }
  tls_running = outer;
}

void BurstWorkers::ForEach(int n, const std::function<void(int)>& fn) {
  if (n <= 0) return;
  Loop loop;
  loop.fn = &fn;
  loop.n = n;
  const bool shared = n > 1 && !threads_.empty() && tls_running != this;
  if (shared) {
    generation_.fetch_add(1);  // before the loop is seen: a worker that sees it sees its generation
    loop_.store(&loop);
    if (bursts_.load() == 0) Wake();
  }
  RunItems(&loop);
  // Close the loop, then wait for the workers inside it (they finish the items they claimed). A worker enters by
  // counting itself in and then checking the loop is still open (both sequentially consistent), so after this store
  // and a count of zero none can be inside.
  if (shared) {
    loop_.store(nullptr);
    for (int polls = 0; inside_.load() != 0; ++polls) {
      CpuRelax();
      if (polls > kPollsBeforeYield) std::this_thread::yield();
    }
  }
  if (loop.error) std::rethrow_exception(loop.error);
}

void BurstWorkers::Work() {
  int polls = 0;
  uint64_t done =
      0;  // the generation of the last loop this worker ran (a loop is not run twice: its items are claimed)
  while (!stop_.load()) {
    if (loop_.load() != nullptr && generation_.load() != done) {
      inside_.fetch_add(1);
      // Counted in first: the loop seen now stays open until this worker leaves. Its generation is read after it (the
      // caller counts it before opening it, and cannot open another while this worker is inside).
      Loop* loop = loop_.load();
      const uint64_t generation = generation_.load();
      if (loop != nullptr && generation != done) {
        RunItems(loop);
        done = generation;
      }
      inside_.fetch_sub(1);
      polls = 0;
      continue;
    }
    if (bursts_.load() > 0) {
      CpuRelax();
      if (++polls > kPollsBeforeYield) std::this_thread::yield();
      continue;
    }
    std::unique_lock<std::mutex> lock(mutex_);
    wake_.wait(lock, [this] { return stop_.load() || bursts_.load() > 0 || loop_.load() != nullptr; });
    polls = 0;
  }
}

BurstWorkers::Burst::Burst(BurstWorkers* workers) : workers_(workers) {
  if (workers_ == nullptr || workers_->threads_.empty()) return;
  if (workers_->bursts_.fetch_add(1) == 0) workers_->Wake();
}

BurstWorkers::Burst::~Burst() {
  if (workers_ != nullptr && !workers_->threads_.empty()) workers_->bursts_.fetch_sub(1);
}

}  // namespace uavm
