#pragma once
#include <cstddef>

namespace uavm {

inline constexpr double kMiB = 1024.0 * 1024.0;  // bytes in a MiB: every figure the program reports in MiB

// Peak resident set size of this process in MiB (getrusage ru_maxrss). Nothing in the program resets the kernel's
// high-water mark (/proc/self/clear_refs), so this is the run's peak over every phase, as an outside tool sees it;
// per-phase peaks come from a MemoryWatch.
[[nodiscard]] double PeakRssMiB();
// The same high-water mark from /proc/self/status (VmHWM), MiB; 0 when unavailable.
[[nodiscard]] double HighWaterRssMiB();
// VmRSS, RssAnon and VmHWM of this process in MiB, one read of /proc/self/status (0 where it does not give them).
struct RssSample {
  double rss_mib = 0;
  double anon_mib = 0;
  double hwm_mib = 0;
};
[[nodiscard]] RssSample SampleRss();
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

// glibc's M_MMAP_THRESHOLD: an allocation of `bytes` or more that no free chunk of the arena can serve is mapped from
// the kernel and unmapped when freed, instead of growing the arena. Call TrimHeap() first, so that the arena's free
// space is given back and such blocks are mapped. Left as it is when the environment sets the threshold
// (MALLOC_MMAP_THRESHOLD_, or glibc.malloc.mmap_threshold in GLIBC_TUNABLES: the environment wins). Another thread's
// allocation at the moment of the change may still use the old threshold. Returns whether it was set.
bool SetMmapThreshold(size_t bytes);
// The flight's threshold: a detector pyramid, tile or descriptor index of this size leaves the RSS when freed; smaller
// buffers reuse heap pages (mapped afresh, each would fault in and zero its pages on every frame).
constexpr size_t kFlightMmapThreshold = size_t{4} << 20;
// The end's solves' threshold: their per-frame blocks and vectors (a few hundred KiB at thousands of frames) are
// allocated and freed a solve at a time; from the heap, the second solve's blocks could land beside the first's holes
// and the phase kept both resident (refine at 5000 frames: 57-77 MiB anonymous between runs of the same build).
constexpr size_t kEndSolvesMmapThreshold = size_t{128} << 10;

}  // namespace uavm
