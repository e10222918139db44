#include "core/pipeline/resource_log.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <cstdlib>
#include <cstring>
#include <memory>

#include "core/util/sanitizers.h"

namespace uavm {
namespace {

constexpr size_t kSolverBlock = 512 << 10;  // a few thousand frames' vector of a solve
static_assert(kSolverBlock >= kEndSolvesMmapThreshold && kSolverBlock < kFlightMmapThreshold);

// Bytes malloc holds in blocks mapped for themselves (mallinfo2's hblkhd) while a block of `bytes` is allocated.
size_t MappedWhileHolding(size_t bytes) {
  std::unique_ptr<char, decltype(&std::free)> block(static_cast<char*>(std::malloc(bytes)), &std::free);
  std::memset(block.get(), 1, bytes);
  asm volatile("" : : "r"(block.get()) : "memory");  // the block escapes: the compiler may not drop the pair
  return mallinfo2().hblkhd;
}

TEST(ResourceLogTest, TheEndSolvesMapTheirBlocksAndThePhasesThatDecodeFramesCarveThemFromTheHeap) {
  if (UAVM_ADDRESS_SANITIZER) GTEST_SKIP() << "AddressSanitizer's allocator: glibc's threshold does not apply";
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr || std::getenv("GLIBC_TUNABLES") != nullptr)
    GTEST_SKIP() << "the environment sets malloc's threshold: it wins";
  ResourceLog log;
  // The compositor's buffers below the flight's threshold reuse heap pages (mapping each would fault it in afresh).
  log.EnterPhase("compose");
  const size_t mapped_before = mallinfo2().hblkhd;
  EXPECT_LT(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock);

  // Mapped for itself, a solve's block leaves the resident set when freed: no heap hole for the next solve to sit by.
  for (const char* solve : {"end_load", "adjust", "refine"}) {
    log.EnterPhase(solve);
    EXPECT_GE(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock) << solve;
    EXPECT_EQ(mallinfo2().hblkhd, mapped_before) << solve;
  }

  // The phases that load, decode or match frames keep the flight's threshold.
  for (const char* phase : {"end_match", "lens", "radiometry", "products"}) {
    log.EnterPhase(phase);
    EXPECT_LT(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock) << phase;
  }
}

}  // namespace
}  // namespace uavm
