#pragma once

namespace uavm {

// Peak resident set size of this process in MiB (getrusage ru_maxrss).
[[nodiscard]] double PeakRssMiB();
// Current resident set size in MiB (/proc/self/statm); 0 when unavailable.
[[nodiscard]] double CurrentRssMiB();

// The allocator's view (glibc mallinfo2): heap bytes in use, heap bytes held (in use + free inside the arenas, i.e.
// fragmentation), and bytes in mmapped chunks. MiB.
struct HeapStats {
  double in_use_mib = 0;
  double arena_mib = 0;
  double mmapped_mib = 0;
};
[[nodiscard]] HeapStats CurrentHeapStats();

}  // namespace uavm
