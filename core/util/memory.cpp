#include "core/util/memory.h"

#include <malloc.h>

#include <sys/resource.h>
#include <unistd.h>

#include <cstdio>

namespace uavm {

double PeakRssMiB() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0.0;
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

double HighWaterRssMiB() {
  FILE* f = std::fopen("/proc/self/status", "r");
  if (f == nullptr) return 0.0;
  char line[256];
  double mib = 0.0;
  while (std::fgets(line, sizeof(line), f) != nullptr) {
    long kib = 0;
    if (std::sscanf(line, "VmHWM: %ld kB", &kib) == 1) {
      mib = static_cast<double>(kib) / 1024.0;
      break;
    }
  }
  std::fclose(f);
  return mib;
}

bool ResetPeakRss() {
  FILE* f = std::fopen("/proc/self/clear_refs", "w");
  if (f == nullptr) return false;
  const bool ok = std::fputs("5", f) >= 0;
  return (std::fclose(f) == 0) && ok;
}

double CurrentRssMiB() {
  FILE* f = std::fopen("/proc/self/statm", "r");
  if (f == nullptr) return 0.0;
  long pages_total = 0;
  long pages_resident = 0;
  const int n = std::fscanf(f, "%ld %ld", &pages_total, &pages_resident);
  std::fclose(f);
  if (n != 2) return 0.0;
  return static_cast<double>(pages_resident) * static_cast<double>(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

HeapStats CurrentHeapStats() {
  HeapStats h;
  const struct mallinfo2 mi = mallinfo2();
  constexpr double kMiB = 1024.0 * 1024.0;
  h.in_use_mib = static_cast<double>(mi.uordblks) / kMiB;
  h.arena_mib = static_cast<double>(mi.arena) / kMiB;
  h.mmapped_mib = static_cast<double>(mi.hblkhd) / kMiB;
  return h;
}

void TrimHeap() { malloc_trim(0); }

}  // namespace uavm
