#include "core/buffers/mat_pool.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <fstream>

#include "core/util/sanitizers.h"

namespace uavm {

namespace {

constexpr size_t kHugePage = size_t{2} << 20;

#if UAVM_ADDRESS_SANITIZER
// Under AddressSanitizer the blocks come from its allocator, which guards their ends: a mapping of our own would hide
// an overrun from it.
void* AllocateBlock(size_t bytes) {
  const size_t align = bytes >= kHugePage ? kHugePage : 64;
  void* block = std::aligned_alloc(align, (bytes + align - 1) / align * align);
  if (block == nullptr) CV_Error_(cv::Error::StsNoMem, ("failed to allocate %zu bytes", bytes));
#ifdef MADV_HUGEPAGE
  if (align == kHugePage) (void)madvise(block, bytes & ~(kHugePage - 1), MADV_HUGEPAGE);  // as below: advice only
#endif
  return block;
}

void ReleaseBlock(void* block, size_t /*bytes*/) {
  std::free(block);  // NOLINT(cppcoreguidelines-no-malloc): aligned_alloc's
}
#else
// Whether the kernel's transparent huge page is 2 MiB (x86-64, and arm64 with 4 KiB pages): with 16 or 64 KiB pages
// it is 32 or 512 MiB, larger than any block, and aligning would only waste address space.
bool HugePagesAre2MiB() {
  static const bool yes = [] {
    std::ifstream in("/sys/kernel/mm/transparent_hugepage/hpage_pmd_size");
    size_t bytes = 0;
    return static_cast<bool>(in >> bytes) && bytes == kHugePage;
  }();
  return yes;
}

size_t MappedLength(size_t bytes) {
  static const auto page = static_cast<size_t>(sysconf(_SC_PAGESIZE));  // 4 KiB, or 16/64 KiB on some arm64 kernels
  return (bytes + page - 1) & ~(page - 1);
}

// Every block is a mapping of its own, not a heap chunk: a block the pool gives back goes to the kernel whole, and
// the heap never holds large blocks between the flight's small records (freed into the heap, an evicted block left
// pages that small records then pinned: 105.7 MiB of arena for 45.9 in use at the end of a 5000-frame flight). Where
// the huge page is 2 MiB, a block of 2 MiB or more starts on a 2 MiB boundary (mapped 2 MiB longer, the ends unmapped)
// and its whole 2 MiB pages are advised as transparent huge pages (where the kernel offers them on request, THP
// "madvise", as Debian's and Raspberry Pi OS's kernels do): a 3 MB scale-space image then costs one page fault for its
// first 2 MiB instead of 512. The tail stays in small pages, so the resident memory is what the Mat touches.
void* AllocateBlock(size_t bytes) {
  const size_t length = MappedLength(bytes);
  const size_t span = length >= kHugePage && HugePagesAre2MiB() ? length + kHugePage : length;
  void* mapped = mmap(nullptr, span, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (mapped == MAP_FAILED)
    CV_Error_(cv::Error::StsNoMem, ("failed to allocate %zu bytes", bytes));  // as cv::fastMalloc does
  if (span == length) return mapped;
  auto* raw = static_cast<char*>(mapped);
  const auto start = (reinterpret_cast<uintptr_t>(raw) + kHugePage - 1) & ~(kHugePage - 1);
  auto* block = reinterpret_cast<char*>(start);
  const auto head = static_cast<size_t>(block - raw);
  if (head > 0) (void)munmap(raw, head);
  if (span - head > length) (void)munmap(block + length, span - head - length);
#ifdef MADV_HUGEPAGE
  (void)madvise(block, length & ~(kHugePage - 1), MADV_HUGEPAGE);  // advice only: without THP nothing changes
#endif
  return block;
}

void ReleaseBlock(void* block, size_t bytes) {
  (void)munmap(block, MappedLength(bytes));
}
#endif

}  // namespace

MatPool::MatPool(const MatPoolOptions& options) : options_(options) {}

MatPool::~MatPool() {
  Flush();
}

void* MatPool::Take(size_t bytes) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto slack = static_cast<size_t>(static_cast<double>(bytes) * options_.max_slack);
  void* block = nullptr;
  const auto it = by_capacity_.lower_bound(bytes);
  if (it != by_capacity_.end() && it->first <= bytes + slack) {
    block = it->second->block;
    stats_.pooled_bytes -= it->first;
    free_.erase(it->second);
    by_capacity_.erase(it);
    ++stats_.hits;
  } else {
    // A new mapping: pooled blocks go first while pooled + in use + it would pass the peak without the pool.
    EvictLocked(bytes, std::max(stats_.peak_in_use_bytes, stats_.in_use_bytes + bytes));
    ++stats_.misses;
    block = AllocateBlock(bytes);
    capacity_[block] = bytes;
  }
  stats_.in_use_bytes += capacity_[block];
  stats_.peak_in_use_bytes = std::max(stats_.peak_in_use_bytes, stats_.in_use_bytes);
  stats_.window_peak_in_use_bytes = std::max(stats_.window_peak_in_use_bytes, stats_.in_use_bytes);
  return block;
}

void MatPool::EraseLocked(FreeList::iterator it) const {
  auto range = by_capacity_.equal_range(it->capacity);
  for (auto i = range.first; i != range.second; ++i)
    if (i->second == it) {
      by_capacity_.erase(i);
      break;
    }
  stats_.pooled_bytes -= it->capacity;
  capacity_.erase(it->block);
  ReleaseBlock(it->block, it->capacity);
  free_.erase(it);
  ++stats_.evictions;
}

void MatPool::EvictLocked(size_t incoming, size_t limit) const {
  while (!free_.empty() && stats_.pooled_bytes + stats_.in_use_bytes + incoming > limit) EraseLocked(free_.begin());
}

bool MatPool::Give(void* block) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = capacity_.find(block);
  if (it == capacity_.end()) return false;  // not the pool's: a small Mat's malloc block
  const size_t capacity = it->second;
  stats_.in_use_bytes -= capacity;
  if (capacity > options_.max_pooled_bytes) {
    capacity_.erase(it);
    ReleaseBlock(block, capacity);
    return true;
  }
  while (!free_.empty() && stats_.pooled_bytes + capacity > options_.max_pooled_bytes) EraseLocked(free_.begin());
  free_.push_back({capacity, block});
  by_capacity_.emplace(capacity, std::prev(free_.end()));
  stats_.pooled_bytes += capacity;
  stats_.peak_pooled_bytes = std::max(stats_.peak_pooled_bytes, stats_.pooled_bytes);
  return true;
}

cv::UMatData* MatPool::allocate(int dims, const int* sizes, int type, void* data, size_t* step,
                                cv::AccessFlag /*flags*/, cv::UMatUsageFlags /*usage*/) const {
  size_t total = CV_ELEM_SIZE(type);
  for (int i = dims - 1; i >= 0; --i) {
    if (step != nullptr) {
      if (data != nullptr && step[i] != cv::Mat::AUTO_STEP) {
        CV_Assert(total <= step[i]);
        total = step[i];
      } else {
        step[i] = total;
      }
    }
    total *= static_cast<size_t>(sizes[i]);
  }
  auto* u = new cv::UMatData(this);
  if (data != nullptr) {
    u->data = u->origdata = static_cast<uchar*>(data);
    u->flags |= cv::UMatData::USER_ALLOCATED;
  } else if (total >= options_.min_block_bytes) {
    u->data = u->origdata = static_cast<uchar*>(Take(total));
  } else {
    u->data = u->origdata = static_cast<uchar*>(cv::fastMalloc(total));
  }
  u->size = total;
  return u;
}

bool MatPool::allocate(cv::UMatData* u, cv::AccessFlag /*access*/, cv::UMatUsageFlags /*usage*/) const {
  return u != nullptr;
}

void MatPool::deallocate(cv::UMatData* u) const {
  if (u == nullptr) return;
  CV_Assert(u->urefcount == 0);
  CV_Assert(u->refcount == 0);
  if (!(u->flags & cv::UMatData::USER_ALLOCATED) && u->origdata != nullptr) {
    if (!Give(u->origdata)) cv::fastFree(u->origdata);
    u->origdata = nullptr;
  }
  delete u;
}

void MatPool::Flush() const {
  std::lock_guard<std::mutex> lock(mutex_);
  while (!free_.empty()) EraseLocked(free_.begin());
  stats_.peak_in_use_bytes = stats_.in_use_bytes;
  stats_.window_peak_in_use_bytes = stats_.in_use_bytes;
}

void MatPool::StartPeakWindow() const {
  std::lock_guard<std::mutex> lock(mutex_);
  stats_.peak_in_use_bytes = std::max(stats_.window_peak_in_use_bytes, stats_.in_use_bytes);
  EvictLocked(0, stats_.peak_in_use_bytes);
  stats_.window_peak_in_use_bytes = stats_.in_use_bytes;
}

MatPoolStats MatPool::Stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

namespace {
std::atomic<MatPool*> g_pool{nullptr};
std::mutex g_install;
}  // namespace

MatPool* InstallMatPool(const MatPoolOptions& options) {
  std::lock_guard<std::mutex> lock(g_install);
  if (MatPool* existing = g_pool.load()) return existing;
  // Never destroyed: Mats alive at exit (statics, other threads' caches) still return their blocks to it.
  auto* pool = new MatPool(options);
  cv::Mat::setDefaultAllocator(pool);
  g_pool.store(pool);
  return pool;
}

MatPool* InstalledMatPool() {
  return g_pool.load();
}

void FlushMatPool() {
  if (MatPool* pool = g_pool.load()) pool->Flush();
}

}  // namespace uavm
