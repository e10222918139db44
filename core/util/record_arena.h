#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace uavm {

// Pages of their own for the small records that live to the end of the flight: the session's and the engine's
// per-frame records, their names and paths, the edge deque's nodes, the maps' hash nodes.
//
// Why: glibc places such records between the flight's transient buffers (features, matches, solver blocks). At 5000
// frames a few records per page then keep ~1000 pages of the main arena resident through every end phase, pages a
// trim cannot give back (bench/results/memory-20261130-heap-slack-vm.md). Copying them after the flight does not pack
// them: glibc serves the copies from the same scattered holes.
//
// How: an allocation by operator new of at most kMaxBlockBytes, made on a thread while a Scope is open there, comes
// from a size-class page run carved from one reserved address range; anything larger, anything made outside a Scope
// and anything once the range is full goes to malloc as before (the last is counted). A block goes back to its
// class's free list wherever and whenever it is deleted, so the range's pages hold small blocks made in a Scope and
// nothing else, and a freed one is reused by the next. The range is reserved, not committed: only the pages in use
// are resident. Under AddressSanitizer the arena is off (Scope does nothing), so that the sanitizer sees every block.
class RecordArena {
 public:
  static constexpr size_t kMaxBlockBytes = 1024;
  static constexpr size_t kReservedBytes = size_t{256} << 20;  // address range, not memory

  // Records that are freed together: a group's runs hold no block of another group, so that when a group is freed at
  // once its runs are wholly free and ReturnFreeRuns can give their pages back (the edge records, dropped at the end
  // of the flight, shared their 512-byte class with the frames' deque nodes: freeing them gave back 0.5 of 3 MiB).
  enum class Group : uint8_t { kFlight = 0, kEdges = 1 };
  static constexpr size_t kGroups = static_cast<size_t>(Group::kEdges) + 1;  // the last group's + 1

  // Opens the arena for this thread's allocations until it closes, for `group`'s records; nests (the innermost
  // scope's group applies).
  class Scope {
   public:
    explicit Scope(Group group = Group::kFlight);
    ~Scope();
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    Group outer_;
  };

  // Before the first record: the range becomes the pages of a file in `dir`, unlinked at once, instead of anonymous
  // memory. The records stay resident while memory allows, but as file pages the kernel can write back and reclaim
  // under a memory limit, where anonymous pages (no swap on the drone) could only be killed with the process: the
  // records a long flight keeps to its end (~1 KiB a frame) no longer add to its unreclaimable memory. Each run's disk
  // blocks are allocated before its first block is handed out, so a full disk means a malloc fallback (counted), never
  // a fault. False, with why, and the arena stays anonymous: on tmpfs or ramfs (their pages are memory, not disk),
  // when the file cannot be made or mapped, when records already exist, or where the arena is compiled out.
  static bool BackWithFile(const std::string& dir, std::string* why);

  struct Counters {
    bool file_backed = false;  // BackWithFile took
    size_t carved_bytes = 0;   // page runs carved from the range so far (what it can hold resident at most)
    size_t in_use_bytes = 0;   // blocks handed out and not freed, by their class size
    size_t blocks_in_use = 0;
    size_t fallbacks = 0;       // blocks made in a Scope that went to malloc: the range, or the disk, was full
    size_t returned_bytes = 0;  // of carved_bytes, runs whose pages were given back (ReturnFreeRuns) and not reused
  };
  [[nodiscard]] static Counters counters();
  // Gives the pages of runs whose blocks are all free back to the system (madvise DONTNEED); returns their bytes. For
  // when many records have just been deleted (the end of the flight drops its edge records): the free blocks would
  // otherwise stay resident until records of the same size reuse them. O(free blocks), under the arena's lock.
  static size_t ReturnFreeRuns();
  // Whether p is a block of the arena (for tests and the report; delete finds its blocks by this test).
  [[nodiscard]] static bool Owns(const void* p);
  // False where the arena is compiled out (AddressSanitizer builds).
  [[nodiscard]] static bool Enabled();
};

}  // namespace uavm
