#include "core/util/memory_watch.h"

#include <pthread.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "core/util/clock.h"

namespace uavm {

namespace {
double NowS() {
  return static_cast<double>(MonotonicNs()) * 1e-9;
}
}  // namespace

MemoryWatch::MemoryWatch(int interval_ms) : interval_ms_(std::max(1, interval_ms)) {
  phases_.push_back({"start", 0, 0, 0});
  phase_start_s_ = NowS();
  phase_start_hwm_mib_ = SampleRss().hwm_mib;
  thread_ = std::thread([this] { Run(); });
}

MemoryWatch::~MemoryWatch() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void MemoryWatch::SampleLocked() {
  const RssSample s = SampleRss();
  PhaseMemory& p = phases_[current_];
  p.peak_rss_mib = std::max(p.peak_rss_mib, s.rss_mib);
  p.peak_anon_mib = std::max(p.peak_anon_mib, s.anon_mib);
  // The high-water mark rose during this phase: the phase's own peak reached it, between samples or not.
  if (s.hwm_mib > phase_start_hwm_mib_) p.peak_rss_mib = std::max(p.peak_rss_mib, s.hwm_mib);
  max_sampled_mib_ = std::max({max_sampled_mib_, s.rss_mib, s.hwm_mib});
}

void MemoryWatch::Enter(const std::string& name) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (phases_[current_].name == name) return;
    SampleLocked();
    const double now = NowS();
    phases_[current_].seconds += now - phase_start_s_;
    const auto it = std::find_if(phases_.begin(), phases_.end(), [&](const PhaseMemory& p) { return p.name == name; });
    current_ = static_cast<size_t>(it - phases_.begin());
    if (it == phases_.end()) phases_.push_back({name, 0, 0, 0, CurrentHeapStats()});
    phase_start_s_ = now;
    phase_start_hwm_mib_ = SampleRss().hwm_mib;
    SampleLocked();
    renamed_ = true;
  }
  wake_.notify_all();
}

std::vector<PhaseMemory> MemoryWatch::Phases() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<PhaseMemory> out = phases_;
  out[current_].seconds += NowS() - phase_start_s_;
  // "start" is the few milliseconds before the first phase: nothing to report unless it is all there was.
  if (out.size() > 1 && out.front().name == "start") out.erase(out.begin());
  return out;
}

double MemoryWatch::PeakRssMiB() const {
  const RssSample s = SampleRss();
  std::lock_guard<std::mutex> lock(mutex_);
  return std::max({s.hwm_mib, s.rss_mib, max_sampled_mib_});
}

std::string MemoryWatch::current() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return phases_[current_].name;
}

void MemoryWatch::NameThread() {
  // Linux keeps 15 characters of a thread's name.
  const std::string name = ("mem:" + current()).substr(0, 15);
  pthread_setname_np(pthread_self(), name.c_str());
}

void MemoryWatch::Run() {
  NameThread();
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stop_) {
    SampleLocked();
    if (renamed_.exchange(false)) {
      lock.unlock();
      NameThread();
      lock.lock();
    }
    wake_.wait_for(lock, std::chrono::milliseconds(interval_ms_), [this] { return stop_ || renamed_.load(); });
  }
}

}  // namespace uavm
