#pragma once
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <thread>
#include <vector>

namespace uavm {

// As ParallelFor (below), calling fn(i, worker) with the number of the worker that runs it, in [0, min(max(1, threads),
// n)): a worker's calls run one after another, so fn may use state of its own per worker (e.g. buffers reused for every
// item).
template <typename Fn>
void ParallelForOnWorkers(size_t n, int threads, Fn&& fn) {
  if (n == 0) return;
  const size_t workers = std::min(static_cast<size_t>(std::max(1, threads)), n);
  std::atomic<size_t> next{0};
  auto work = [&](size_t worker) {
    for (size_t i = next.fetch_add(1); i < n; i = next.fetch_add(1)) fn(i, worker);
  };
  std::vector<std::thread> pool;
  pool.reserve(workers - 1);
  for (size_t k = 1; k < workers; ++k) pool.emplace_back(work, k);
  work(0);
  for (auto& t : pool) t.join();
}

// Calls fn(i) once for every i in [0, n) on min(threads, n) workers, the calling thread being one of them, and
// returns when all calls have returned. Each worker claims the next index from a shared counter, so items of uneven
// cost balance and indices are started in increasing order. Results are deterministic when fn(i) writes only to
// slot i. fn must not throw (a worker thread would terminate the program).
template <typename Fn>
void ParallelFor(size_t n, int threads, Fn&& fn) {
  ParallelForOnWorkers(n, threads, [&fn](size_t i, size_t /*worker*/) { fn(i); });
}

}  // namespace uavm
