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

}  // namespace uavm
