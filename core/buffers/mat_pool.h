#pragma once
// A pool of large image buffers behind cv::Mat's default allocator.
//
// The program maps large buffers straight from the kernel (main.cpp's mallopt; 256 KiB and more when the pool was
// written, 4 MiB now) so that freed memory leaves the RSS. Every SIFT call then mapped its scale space afresh (tens of
// MiB a frame) and the kernel zeroed every page on first touch: a fifth of the run's CPU went to page faults. Each
// block is a mapping of its own (never a heap chunk, so that giving one back leaves no hole in the heap; under
// AddressSanitizer its allocator's, which guards the ends); where the kernel's huge page is 2 MiB, blocks of 2 MiB and
// more start on a 2 MiB boundary and are advised as transparent huge pages (one fault per 2 MiB). The pool
// keeps the large blocks that Mats free and hands them to the next Mat of about the same size. It never makes the RSS
// exceed what the program's pooled-size buffers reached without it: pooled + in-use bytes stay within the peak of
// in-use bytes since the last Flush() or the window before the last StartPeakWindow() (least recently freed blocks go
// first), and the pool holds at most `max_pooled_bytes`. Flush() returns every pooled block to the kernel and starts a
// new peak (at the end of a phase).
#include <cstddef>
#include <cstdint>
#include <list>
#include <map>
#include <mutex>
#include <opencv2/core.hpp>
#include <unordered_map>

namespace uavm {

struct MatPoolOptions {
  size_t min_block_bytes = size_t{1} << 20;    // smaller Mats go to malloc as before
  size_t max_pooled_bytes = size_t{96} << 20;  // free bytes the pool may keep
  double max_slack = 0.25;                     // a pooled block serves a request up to this share smaller
};

struct MatPoolStats {
  uint64_t hits = 0;       // requests served from the pool
  uint64_t misses = 0;     // large requests mapped new
  uint64_t evictions = 0;  // pooled blocks returned to the kernel to make room, to respect the cap or by Flush()
  size_t pooled_bytes = 0;
  size_t in_use_bytes = 0;       // blocks the pool made that Mats hold
  size_t peak_in_use_bytes = 0;  // the limit: since the last Flush(), or the last window's peak (StartPeakWindow)
  size_t window_peak_in_use_bytes = 0;  // since the last StartPeakWindow() or Flush()
  size_t peak_pooled_bytes = 0;         // over the run
};

class MatPool final : public cv::MatAllocator {
 public:
  explicit MatPool(const MatPoolOptions& options);
  ~MatPool() override;
  MatPool(const MatPool&) = delete;
  MatPool& operator=(const MatPool&) = delete;

  // cv::MatAllocator: the contract of OpenCV's standard allocator (64-byte aligned fastMalloc), user data untouched.
  cv::UMatData* allocate(int dims, const int* sizes, int type, void* data, size_t* step, cv::AccessFlag flags,
                         cv::UMatUsageFlags usage) const override;
  bool allocate(cv::UMatData* u, cv::AccessFlag access, cv::UMatUsageFlags usage) const override;
  void deallocate(cv::UMatData* u) const override;

  // Returns every pooled block to the kernel and starts a new peak.
  void Flush() const;
  // Lowers the limit to the peak of in-use bytes since the last call (or Flush), returning the oldest pooled blocks
  // above it, and starts a new window. Called every so many frames, the pool keeps the flight's recent working set:
  // without it a rare coincidence of large buffers (a relocalisation beside a reload) set a limit the pool kept to the
  // end, and a longer flight met a rarer one (heaptrack: +2.8 MiB of the pool's blocks in the flight's heap peak at
  // 1000 frames against 200).
  void StartPeakWindow() const;
  [[nodiscard]] MatPoolStats Stats() const;

 private:
  struct FreeBlock {
    size_t capacity;
    void* block;
  };
  using FreeList = std::list<FreeBlock>;  // least recently freed first

  void* Take(size_t bytes) const;
  // Takes back a block the pool made (false for any other block: the caller frees it).
  [[nodiscard]] bool Give(void* block) const;
  // Frees pooled blocks, least recently freed first, until pooled + in use + `incoming` fits under `limit`.
  void EvictLocked(size_t incoming, size_t limit) const;
  void EraseLocked(FreeList::iterator it) const;

  MatPoolOptions options_;
  mutable std::mutex mutex_;
  mutable FreeList free_;
  mutable std::multimap<size_t, FreeList::iterator> by_capacity_;
  mutable std::unordered_map<void*, size_t> capacity_;  // every block the pool made, in use or free
  mutable MatPoolStats stats_;
};

// Installs a process-wide pool as cv::Mat's default allocator (once; later calls return the same pool). It lives to
// the end of the process: Mats may be freed during static destruction.
MatPool* InstallMatPool(const MatPoolOptions& options = {});
// The installed pool, or null.
[[nodiscard]] MatPool* InstalledMatPool();
// Flushes the installed pool, if any.
void FlushMatPool();

}  // namespace uavm
