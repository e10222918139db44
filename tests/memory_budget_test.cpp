#include "core/pipeline/memory_budget.h"

#include <gtest/gtest.h>

namespace uavm {
namespace {

TEST(MemoryBudgetTest, DefaultBudgetFitsBothPhasesOfA12MpFlight) {
  PipelineOptions o;
  ASSERT_EQ(o.memory_budget_mib, 256);
  MemoryPlan plan;
  std::string why;
  ASSERT_TRUE(ApplyMemoryBudget(1000, 750, &o, &plan, &why)) << why;
  EXPECT_LE(plan.FlightMiB(), 256.0);
  EXPECT_LE(plan.EndMiB(), 256.0);
  // The whole-image scale space of a 1000x750 frame (173 MiB) cannot fit: the detector works in bands.
  EXPECT_GE(plan.sift_bands, 2);
  EXPECT_EQ(SiftBands(1000, 750, o.features), plan.sift_bands);
  EXPECT_LE(o.queue_capacity, 2);
  EXPECT_LT(o.feature_cache_mib, 192);
  EXPECT_LT(o.relocalization.max_descriptors, 131072);
  EXPECT_TRUE(o.Check(&why)) << why;
}

TEST(MemoryBudgetTest, LargeBudgetKeepsTheConfiguredSizes) {
  PipelineOptions o;
  o.memory_budget_mib = 4096;
  const PipelineOptions before = o;
  MemoryPlan plan;
  std::string why;
  ASSERT_TRUE(ApplyMemoryBudget(1000, 750, &o, &plan, &why)) << why;
  EXPECT_EQ(plan.sift_bands, 1);
  EXPECT_EQ(o.queue_capacity, before.queue_capacity);
  EXPECT_EQ(o.feature_cache_mib, before.feature_cache_mib);
  EXPECT_EQ(o.mosaic.tile_size, before.mosaic.tile_size);
  EXPECT_EQ(o.relocalization.max_descriptors, before.relocalization.max_descriptors);
}

TEST(MemoryBudgetTest, NoBudgetChangesNothingAndDescribesTheConfiguration) {
  PipelineOptions o;
  o.memory_budget_mib = 0;
  MemoryPlan plan;
  std::string why;
  ASSERT_TRUE(ApplyMemoryBudget(1000, 750, &o, &plan, &why)) << why;
  EXPECT_EQ(plan.sift_bands, 1);
  EXPECT_GT(plan.FlightMiB(), 256.0);  // the whole-image detector alone is 173 MiB
  EXPECT_EQ(o.feature_cache_mib, PipelineOptions{}.feature_cache_mib);
}

TEST(MemoryBudgetTest, TooSmallABudgetIsAClearError) {
  PipelineOptions o;
  o.memory_budget_mib = 100;
  MemoryPlan plan;
  std::string why;
  EXPECT_FALSE(ApplyMemoryBudget(1000, 750, &o, &plan, &why));
  EXPECT_NE(why.find("memory_budget_mib"), std::string::npos) << why;
  EXPECT_EQ(o.feature_cache_mib, PipelineOptions{}.feature_cache_mib);  // a refused plan changes nothing
}

}  // namespace
}  // namespace uavm
