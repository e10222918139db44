#include "core/pipeline/resource_log.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <cstdlib>
#include <cstring>
#include <memory>

namespace uavm {
namespace {

// Bytes malloc holds in blocks mapped for themselves (mallinfo2's hblkhd) while a block of `bytes` is allocated.
size_t MappedWhileHolding(size_t bytes) {
  std::unique_ptr<char, decltype(&std::free)> block(static_cast<char*>(std::malloc(bytes)), &std::free);
  std::memset(block.get(), 1, bytes);
  asm volatile("" : : "r"(block.get()) : "memory");  // the block escapes: the compiler may not drop the pair
  return mallinfo2().hblkhd;
}

TEST(ResourceLogTest, TheEndSolvesMapTheirBlocksAndTheMosaicPhasesCarveThemFromTheHeapAgain) {
  if (std::getenv("MALLOC_MMAP_THRESHOLD_") != nullptr) GTEST_SKIP() << "MALLOC_MMAP_THRESHOLD_ set: glibc's wins";
  constexpr size_t kSolverBlock = 512 << 10;  // a few thousand frames' vector of a solve
  ResourceLog log;
  // The compositor's buffers below the flight's threshold reuse heap pages (mapping each would fault it in afresh).
  log.EnterPhase("compose");
  const size_t mapped_before = mallinfo2().hblkhd;
  EXPECT_LT(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock);

  // Mapped for itself, a solve's block leaves the resident set when freed: no heap hole for the next solve to sit by.
  log.EnterPhase("refine");
  EXPECT_GE(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock);
  EXPECT_EQ(mallinfo2().hblkhd, mapped_before);

  log.EnterPhase("products");
  EXPECT_LT(MappedWhileHolding(kSolverBlock), mapped_before + kSolverBlock);
  ASSERT_LT(kSolverBlock, kFlightMappedAllocation);
  EXPECT_GE(kSolverBlock, kEndSolvesMappedAllocation);
}

}  // namespace
}  // namespace uavm
