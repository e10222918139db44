#include "core/util/memory.h"

#include <malloc.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>

namespace uavm {

double PeakRssMiB() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0.0;
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

RssSample SampleRss() {
  RssSample s;
  FILE* f = std::fopen("/proc/self/status", "r");
  if (f == nullptr) return s;
  char line[256];
  while (std::fgets(line, sizeof(line), f) != nullptr) {
    long kib = 0;
    if (std::sscanf(line, "VmRSS: %ld kB", &kib) == 1)
      s.rss_mib = static_cast<double>(kib) / 1024.0;
    else if (std::sscanf(line, "RssAnon: %ld kB", &kib) == 1)
      s.anon_mib = static_cast<double>(kib) / 1024.0;
    else if (std::sscanf(line, "VmHWM: %ld kB", &kib) == 1)
      s.hwm_mib = static_cast<double>(kib) / 1024.0;
  }
  std::fclose(f);
  return s;
}

double HighWaterRssMiB() {
  return SampleRss().hwm_mib;
}

double CurrentRssMiB() {
  FILE* f = std::fopen("/proc/self/statm", "r");
  if (f == nullptr) return 0.0;
  long pages_total = 0;
  long pages_resident = 0;
  const int n = std::fscanf(f, "%ld %ld", &pages_total, &pages_resident);
  std::fclose(f);
  if (n != 2) return 0.0;
  return static_cast<double>(pages_resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / kMiB;
}

HeapStats CurrentHeapStats() {
  HeapStats h;
  const struct mallinfo2 mi = mallinfo2();
  h.in_use_mib = static_cast<double>(mi.uordblks) / kMiB;
  h.arena_mib = static_cast<double>(mi.arena) / kMiB;
  h.mmapped_mib = static_cast<double>(mi.hblkhd) / kMiB;
  return h;
}

void TrimHeap() {
  malloc_trim(0);
}

bool SetMmapThreshold(size_t bytes) {
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr ||
      (tunables != nullptr && std::strstr(tunables, "mmap_threshold") != nullptr))
    return false;
  return mallopt(M_MMAP_THRESHOLD, static_cast<int>(bytes)) == 1;
}

namespace {
std::atomic<size_t> g_log_warnings{0};
std::atomic<size_t> g_log_errors{0};

class CountingSink final : public spdlog::sinks::base_sink<spdlog::details::null_mutex> {
 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    if (msg.level == spdlog::level::warn) ++g_log_warnings;
    if (msg.level >= spdlog::level::err && msg.level != spdlog::level::off) ++g_log_errors;
  }
  void flush_() override {}
};
}  // namespace

int OpenFileDescriptors() {
  std::error_code ec;
  int n = 0;
  for (auto it = std::filesystem::directory_iterator("/proc/self/fd", ec);
       !ec && it != std::filesystem::directory_iterator(); it.increment(ec))
    ++n;
  return ec ? -1 : n - 1;  // minus the directory iterator's own descriptor
}

size_t LogWarnings() {
  return g_log_warnings.load();
}
size_t LogErrors() {
  return g_log_errors.load();
}

void CountLogWarnings() {
  auto logger = spdlog::default_logger();
  if (logger) logger->sinks().push_back(std::make_shared<CountingSink>());
}

}  // namespace uavm
