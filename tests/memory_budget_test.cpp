#include "core/pipeline/memory_budget.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/core.hpp>

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
  // Our detector's scale space of a 1000x750 frame (69 MiB) fits whole; OpenCV's (168 MiB) would need bands.
  EXPECT_EQ(plan.sift_bands, 1);
  EXPECT_EQ(SiftBands(1000, 750, o.features), plan.sift_bands);
  FeatureOptions opencv = o.features;
  opencv.opencv_sift = true;
  EXPECT_GE(SiftBands(1000, 750, opencv), 2);
  EXPECT_LE(o.queue_capacity, 2);
  EXPECT_LT(o.feature_cache_mib, 192);
  EXPECT_LT(o.relocalization.max_descriptors, 131072);
  EXPECT_TRUE(o.Check(&why)) << why;
}

// What the compositor holds for a flight of `frame` originals at the default mosaic scale (0.5): the plan's end
// phase as the compositor refits it, with the loader's worst case (its 2.56x larger decode beside the image). The
// canvas does not count: the quick-look is made on disk.
double ComposeMiB(const MemoryPlan& plan, const PipelineOptions& o, cv::Size frame) {
  const double mib = 1024.0 * 1024.0;
  const size_t image = static_cast<size_t>(frame.area()) * 3 / 4;  // half the side
  const auto pixels = static_cast<size_t>(plan.image_cache_mib * mib);
  const auto blend = static_cast<size_t>(o.mosaic.BlendMiBPerWorker() * mib);
  const CompositorMemory m = FitCompositorMemory(pixels, static_cast<size_t>(3.56 * static_cast<double>(image)), image,
                                                 o.mosaic.threads, blend);
  EXPECT_TRUE(m.fits) << frame;
  return plan.baseline_mib + plan.graph_mib + plan.residue_mib + plan.gdal_cache_mib +
         m.threads * o.mosaic.BlendMiBPerWorker() +
         static_cast<double>(static_cast<size_t>(3.56 * static_cast<double>(image)) + m.cache_bytes) / mib;
}

// Issue 20: 12 MP 3:2 and 4:3 frames, 8 MP 4:3 and 16:9: both phases fit the default budget, the compositor too
// once it knows the frames (the plan is made for the working size only).
TEST(MemoryBudgetTest, DefaultBudgetHoldsForAnyFrameSizeAndAspect) {
  for (const cv::Size frame : {cv::Size(4272, 2848), cv::Size(4000, 3000), cv::Size(3240, 2430), cv::Size(3840, 2160),
                               cv::Size(4000, 2250), cv::Size(1000, 750)}) {
    PipelineOptions o;
    const int work_h = frame.height * o.work_long_side / frame.width;
    MemoryPlan plan;
    std::string why;
    ASSERT_TRUE(ApplyMemoryBudget(o.work_long_side, work_h, &o, &plan, &why)) << why;
    EXPECT_LE(plan.FlightMiB(), 256.0) << frame;
    EXPECT_LE(plan.EndMiB(), 256.0) << frame;
    EXPECT_GE(plan.residue_mib, 20.0);
    EXPECT_EQ(o.mosaic.memory_budget_mib, 256);
    EXPECT_LE(ComposeMiB(plan, o, frame), 256.0) << frame;
  }
}

TEST(MemoryBudgetTest, CompositorDropsAWorkerRatherThanTheBudget) {
  const size_t mib = size_t{1} << 20;
  // Small frames: both workers, the cache gets the rest.
  CompositorMemory m = FitCompositorMemory(49 * mib, 8 * mib, 2 * mib, 2, 30 * mib);
  EXPECT_EQ(m.threads, 2);
  EXPECT_EQ(m.cache_bytes, 41 * mib);
  EXPECT_TRUE(m.fits);
  // 12 MP frames at half scale (9.5 MiB images, worst-case load 34 MiB): a worker goes, its memory to the cache.
  m = FitCompositorMemory(49 * mib, 34 * mib, 9 * mib + mib / 2, 2, 30 * mib);
  EXPECT_EQ(m.threads, 1);
  EXPECT_EQ(m.cache_bytes, 45 * mib);
  EXPECT_TRUE(m.fits);
  // Too large even for one worker: one cached crop, reported as not fitting.
  m = FitCompositorMemory(5 * mib, 34 * mib, 9 * mib, 2, 30 * mib);
  EXPECT_EQ(m.threads, 1);
  EXPECT_EQ(m.cache_bytes, 9 * mib);
  EXPECT_FALSE(m.fits);
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
  EXPECT_GT(plan.FlightMiB(), 256.0);  // the caches as configured, beside the whole-image detector (69 MiB)
  const PipelineOptions defaults;
  EXPECT_EQ(o.feature_cache_mib, defaults.feature_cache_mib);
}

TEST(MemoryBudgetTest, TooSmallABudgetIsAClearError) {
  PipelineOptions o;
  o.memory_budget_mib = 100;
  MemoryPlan plan;
  std::string why;
  EXPECT_FALSE(ApplyMemoryBudget(1000, 750, &o, &plan, &why));
  EXPECT_NE(why.find("memory_budget_mib"), std::string::npos) << why;
  const PipelineOptions defaults;
  EXPECT_EQ(o.feature_cache_mib, defaults.feature_cache_mib);  // a refused plan changes nothing
}

}  // namespace
}  // namespace uavm
