#pragma once
#include <cstddef>

namespace uavm {

// Peak resident set size of this process in MiB (getrusage ru_maxrss).
[[nodiscard]] double PeakRssMiB();
// Peak RSS since the last ResetPeakRss() (VmHWM of /proc/self/status), MiB; 0 when unavailable.
[[nodiscard]] double HighWaterRssMiB();
// Starts a new high-water mark (writes 5 to /proc/self/clear_refs), so that each phase of a run reports its own
// peak. False when the kernel does not allow it (then HighWaterRssMiB() keeps the run's peak).
bool ResetPeakRss();
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
// Open file descriptors of this process (/proc/self/fd); -1 when unavailable. A long flight must not grow it.
[[nodiscard]] int OpenFileDescriptors();
// Log lines at warning level and above since start (counted by a sink on the default logger, see CountLogWarnings).
[[nodiscard]] size_t LogWarnings();
[[nodiscard]] size_t LogErrors();
// Adds the counting sink to spdlog's default logger (once, at start-up).
void CountLogWarnings();

// Gives the allocator's free pages back to the kernel (glibc malloc_trim): freed edge points, feature sets and solver
// blocks leave holes in the arenas that RSS would otherwise keep counting.
void TrimHeap();

}  // namespace uavm
