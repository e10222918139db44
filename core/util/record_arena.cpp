#include "core/util/record_arena.h"

#include <fcntl.h>
#include <linux/magic.h>
#include <sys/mman.h>
#include <sys/vfs.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <mutex>
#include <new>

#include "core/util/sanitizers.h"

#define UAVM_RECORD_ARENA (!UAVM_ADDRESS_SANITIZER)

namespace uavm {
namespace {

// Block sizes: multiples of 16 (operator new's alignment), four steps per doubling above 128 bytes, so a block wastes
// at most a fifth of itself. A frame's 16-character name (17 bytes) takes 32, where glibc takes a 48-byte chunk.
constexpr std::array<uint16_t, 20> kClassBytes = {16,  32,  48,  64,  80,  96,  112, 128, 160, 192,
                                                  224, 256, 320, 384, 448, 512, 640, 768, 896, 1024};
static_assert(kClassBytes.back() == RecordArena::kMaxBlockBytes);
// A class takes the range in runs of this size; a run's pages become resident as its blocks are handed out.
constexpr size_t kRunBytes = size_t{64} << 10;
constexpr size_t kRuns = RecordArena::kReservedBytes / kRunBytes;

size_t ClassOf(size_t bytes) {
  size_t c = 0;
  while (kClassBytes[c] < bytes) ++c;
  return c;
}

struct FreeBlock {
  FreeBlock* next;
};

struct SizeClass {
  FreeBlock* free = nullptr;
  char* next = nullptr;  // the class's current run, not yet handed out
  char* end = nullptr;
};

class Arena {
 public:
  constexpr Arena() = default;

  // nullptr when the range is full or cannot be reserved: the caller takes the block from malloc.
  void* Allocate(size_t bytes, RecordArena::Group group) {
    const std::lock_guard lock(mutex_);
    if (base_.load(std::memory_order_relaxed) == nullptr && !Reserve()) return Fallback();
    const size_t c = ClassOf(bytes);
    const size_t slot = static_cast<size_t>(group) * kClassBytes.size() + c;
    SizeClass& sc = classes_[slot];
    void* block = nullptr;
    if (sc.free != nullptr) {
      block = sc.free;
      sc.free = sc.free->next;
    } else {
      if (sc.next == nullptr || static_cast<size_t>(sc.end - sc.next) < kClassBytes[c]) {
        size_t run_index = 0;
        if (returned_count_ > 0) {
          run_index = returned_[returned_count_ - 1];  // a run given back to the system, taken again
          if (!AllocateDisk(run_index)) return Fallback();
          --returned_count_;
          counters_.returned_bytes -= kRunBytes;
        } else {
          if (runs_carved_ == kRuns || !AllocateDisk(runs_carved_)) return Fallback();
          run_index = runs_carved_++;
          counters_.carved_bytes += kRunBytes;
        }
        class_of_run_[run_index] = static_cast<uint8_t>(slot);
        char* run = base_.load(std::memory_order_relaxed) + run_index * kRunBytes;
        sc.next = run;
        sc.end = run + kRunBytes;
      }
      block = sc.next;
      sc.next += kClassBytes[c];
    }
    counters_.in_use_bytes += kClassBytes[c];
    ++counters_.blocks_in_use;
    return block;
  }

  [[nodiscard]] bool Owns(const void* p) const {
    const char* base = base_.load(std::memory_order_relaxed);
    const auto* q = static_cast<const char*>(p);
    return base != nullptr && q >= base && q < base + RecordArena::kReservedBytes;
  }

  void Free(void* p) {
    const std::lock_guard lock(mutex_);
    const auto run = static_cast<size_t>(static_cast<char*>(p) - base_.load(std::memory_order_relaxed)) / kRunBytes;
    const size_t slot = class_of_run_[run];
    auto* block = static_cast<FreeBlock*>(p);
    block->next = classes_[slot].free;
    classes_[slot].free = block;
    counters_.in_use_bytes -= kClassBytes[slot % kClassBytes.size()];
    --counters_.blocks_in_use;
  }

  RecordArena::Counters counters() {
    const std::lock_guard lock(mutex_);
    return counters_;
  }

  // Gives the pages of every run whose blocks are all free back to the system. The free lists run through the free
  // blocks themselves, so a run's blocks leave its class's list before its pages are dropped (they read as zeros
  // after). Walks the free blocks once: for the end of a flight, after its records are deleted, not per frame.
  size_t ReturnFreeRuns() {
    const std::lock_guard lock(mutex_);
    char* base = base_.load(std::memory_order_relaxed);
    if (base == nullptr) return 0;
    // On the stack, not the heap: an allocation here would come back to this arena's lock.
    std::array<uint16_t, kRuns> free_in_run{};
    for (const SizeClass& sc : classes_)
      for (const FreeBlock* b = sc.free; b != nullptr; b = b->next) ++free_in_run[RunOf(b)];
    std::array<bool, kRuns> whole{};
    for (size_t slot = 0; slot < classes_.size(); ++slot) {
      SizeClass& sc = classes_[slot];
      const size_t c = slot % kClassBytes.size();
      // The class's current run is still being carved: its blocks beyond sc.next were never handed out.
      const size_t current = sc.next != nullptr ? RunOf(sc.next - 1) : kRuns;
      FreeBlock** link = &sc.free;
      while (*link != nullptr) {
        const size_t run = RunOf(*link);
        if (run != current && free_in_run[run] == kRunBytes / kClassBytes[c]) {
          whole[run] = true;
          *link = (*link)->next;
        } else {
          link = &(*link)->next;
        }
      }
    }
    size_t returned = 0;
    for (size_t run = 0; run < runs_carved_; ++run) {
      if (!whole[run]) continue;
      // A file's run: its disk blocks and cached pages go too (a filesystem that cannot punch holes keeps them on
      // disk, still reclaimable; the run's reuse rewrites them).
      if (fd_ >= 0)
        (void)fallocate(fd_, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, static_cast<off_t>(run * kRunBytes),
                        static_cast<off_t>(kRunBytes));
      madvise(base + run * kRunBytes, kRunBytes, MADV_DONTNEED);
      returned_[returned_count_++] = static_cast<uint16_t>(run);
      returned += kRunBytes;
    }
    counters_.returned_bytes += returned;
    return returned;
  }

  // See RecordArena::BackWithFile. `path` is the file to make (mkostemp's template) in `dir`.
  bool BackWithFile(const char* dir, char* path, std::string* why) {
    const std::lock_guard lock(mutex_);
    if (base_.load(std::memory_order_relaxed) != nullptr || reserve_failed_) {
      *why = "records exist already";
      return false;
    }
    struct statfs fs {};
    if (statfs(dir, &fs) != 0) {
      *why = "cannot stat the directory";
      return false;
    }
    if (fs.f_type == TMPFS_MAGIC || fs.f_type == RAMFS_MAGIC) {
      *why = "the directory is in memory (tmpfs or ramfs)";
      return false;
    }
    const int fd = mkostemp(path, O_CLOEXEC);
    if (fd < 0) {
      *why = "cannot create a file there";
      return false;
    }
    // No one else ever sees the file. It is empty: each run extends it as the run is carved (AllocateDisk), and the
    // arena touches no page of the range beyond the runs it carved (past the end of the file it would fault).
    (void)unlink(path);
    void* range = mmap(nullptr, RecordArena::kReservedBytes, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_NORESERVE, fd, 0);
    if (range == MAP_FAILED) {
      close(fd);
      *why = "cannot map a file there";
      return false;
    }
    madvise(range, RecordArena::kReservedBytes, MADV_NOHUGEPAGE);
    // A child process must not share the records' pages (nothing forks without exec today).
    madvise(range, RecordArena::kReservedBytes, MADV_DONTFORK);
    fd_ = fd;
    counters_.file_backed = true;
    base_.store(static_cast<char*>(range), std::memory_order_relaxed);
    return true;
  }

 private:
  // A file's run gets its disk blocks (and the file its length) before any of its pages is written: a write to a page
  // the filesystem could not back would fault the process. A full disk or a file-size limit fails here instead. No
  // file: nothing to do.
  [[nodiscard]] bool AllocateDisk(size_t run) const {
    return fd_ < 0 || posix_fallocate(fd_, static_cast<off_t>(run * kRunBytes), static_cast<off_t>(kRunBytes)) == 0;
  }
  bool Reserve() {
    if (reserve_failed_) return false;
    // Reserved without swap accounting; untouched pages cost nothing. No huge pages: a 2 MiB page made resident for
    // a few records is the slack this arena exists to avoid.
    void* range = mmap(nullptr, RecordArena::kReservedBytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (range == MAP_FAILED) {
      reserve_failed_ = true;
      return false;
    }
    madvise(range, RecordArena::kReservedBytes, MADV_NOHUGEPAGE);
    base_.store(static_cast<char*>(range), std::memory_order_relaxed);
    return true;
  }
  [[nodiscard]] size_t RunOf(const void* p) const {
    return static_cast<size_t>(static_cast<const char*>(p) - base_.load(std::memory_order_relaxed)) / kRunBytes;
  }
  void* Fallback() {
    ++counters_.fallbacks;
    return nullptr;
  }

  std::mutex mutex_;
  std::atomic<char*> base_{nullptr};
  int fd_ = -1;  // the file behind the range (BackWithFile), else -1: anonymous memory
  bool reserve_failed_ = false;
  size_t runs_carved_ = 0;
  std::array<uint8_t, kRuns> class_of_run_{};
  std::array<uint16_t, kRuns> returned_{};  // runs given back to the system, to be carved again first
  size_t returned_count_ = 0;
  std::array<SizeClass, RecordArena::kGroups * kClassBytes.size()> classes_{};  // by group, then size class
  RecordArena::Counters counters_{};
};

// Never destroyed: a block may be deleted during static destruction, after any destructor of the arena would run.
union ArenaStorage {
  constexpr ArenaStorage() : arena() {}
  ~ArenaStorage() {}  // NOLINT(modernize-use-equals-default): must not destroy the member
  Arena arena;
};
constinit ArenaStorage g_storage;
constinit thread_local int t_scope_depth = 0;
constinit thread_local RecordArena::Group t_group = RecordArena::Group::kFlight;

#if UAVM_RECORD_ARENA
void* MallocOrThrow(size_t bytes) {
  for (;;) {
    if (void* p = std::malloc(bytes == 0 ? 1 : bytes)) return p;
    const std::new_handler handler = std::get_new_handler();
    if (handler == nullptr) throw std::bad_alloc();
    handler();
  }
}

void* NewBlock(size_t bytes) {
  if (t_scope_depth > 0 && bytes <= RecordArena::kMaxBlockBytes) {
    if (void* p = g_storage.arena.Allocate(bytes, t_group)) return p;
  }
  return MallocOrThrow(bytes);
}

void DeleteBlock(void* p) noexcept {
  if (g_storage.arena.Owns(p)) {
    g_storage.arena.Free(p);
    return;
  }
  std::free(p);
}
#endif

}  // namespace

RecordArena::Scope::Scope(Group group) : outer_(t_group) {
  ++t_scope_depth;
  t_group = group;
}
RecordArena::Scope::~Scope() {
  --t_scope_depth;
  t_group = outer_;
}
RecordArena::Counters RecordArena::counters() {
  return g_storage.arena.counters();
}
size_t RecordArena::ReturnFreeRuns() {
  return g_storage.arena.ReturnFreeRuns();
}
bool RecordArena::Owns(const void* p) {
  return g_storage.arena.Owns(p);
}
bool RecordArena::BackWithFile(const std::string& dir, std::string* why) {
#if UAVM_RECORD_ARENA
  // Built before the arena's lock is taken (this string's own memory comes from malloc, not the arena).
  std::string path = dir + "/.uavm-records-XXXXXX";
  return g_storage.arena.BackWithFile(dir.c_str(), path.data(), why);
#else
  (void)dir;
  *why = "the arena is compiled out";
  return false;
#endif
}
bool RecordArena::Enabled() {
  return UAVM_RECORD_ARENA != 0;
}

}  // namespace uavm

#if UAVM_RECORD_ARENA
// The replaceable global allocation functions, so that every std container and string made in a Scope takes part.
// The aligned forms are left to the library: they never see an arena block.
void* operator new(std::size_t bytes) {
  return uavm::NewBlock(bytes);
}
void* operator new[](std::size_t bytes) {
  return uavm::NewBlock(bytes);
}
void* operator new(std::size_t bytes, const std::nothrow_t& /*tag*/) noexcept {
  try {
    return uavm::NewBlock(bytes);
  } catch (...) {
    return nullptr;
  }
}
void* operator new[](std::size_t bytes, const std::nothrow_t& tag) noexcept {
  return operator new(bytes, tag);
}
void operator delete(void* p) noexcept {
  uavm::DeleteBlock(p);
}
void operator delete[](void* p) noexcept {
  uavm::DeleteBlock(p);
}
void operator delete(void* p, std::size_t /*bytes*/) noexcept {
  uavm::DeleteBlock(p);
}
void operator delete[](void* p, std::size_t /*bytes*/) noexcept {
  uavm::DeleteBlock(p);
}
void operator delete(void* p, const std::nothrow_t& /*tag*/) noexcept {
  uavm::DeleteBlock(p);
}
void operator delete[](void* p, const std::nothrow_t& /*tag*/) noexcept {
  uavm::DeleteBlock(p);
}
#endif
