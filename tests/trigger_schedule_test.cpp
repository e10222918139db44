#include "core/util/trigger_schedule.h"

#include <gtest/gtest.h>

namespace uavm {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

// Input i is never delivered before i intervals after the first; overdue inputs are not waited for again.
TEST(TriggerScheduleTest, KeepsTheCameraTimesAndDoesNotWaitForOverdueInputs) {
  TriggerSchedule schedule(milliseconds(40));
  const auto before_first = Clock::now();
  schedule.Wait();  // input 0: at once
  EXPECT_LT(Clock::now() - before_first, milliseconds(40));
  for (int i = 1; i < 4; ++i) {
    schedule.Wait();
    EXPECT_GE(Clock::now() - before_first, milliseconds(40 * i)) << "input " << i << " came early";
  }
  std::this_thread::sleep_for(milliseconds(200));  // a slow reader: inputs 4-8 are due by now
  const auto late = Clock::now();
  for (int i = 4; i < 8; ++i) schedule.Wait();
  EXPECT_LT(Clock::now() - late, milliseconds(4 * 40));
  schedule.Wait();  // input 8 is due 320 ms after the first: later than now only if the machine stalled
  EXPECT_GE(Clock::now() - before_first, milliseconds(8 * 40));
}

TEST(TriggerScheduleTest, ZeroIntervalNeverWaits) {
  TriggerSchedule schedule(milliseconds(0));
  const auto start = Clock::now();
  for (int i = 0; i < 1000; ++i) schedule.Wait();
  EXPECT_LT(Clock::now() - start, milliseconds(40));
}

}  // namespace
}  // namespace uavm
