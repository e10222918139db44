// CameraFeed (hal/common/camera_feed.h), the part the V4L2 and libcamera sources share: the consumer's Next() over
// the drop-oldest queue, the counters of report.json, and how the stream ends (closed, or failed with a reason).
#include "hal/common/camera_feed.h"

#include <gtest/gtest.h>

#include <array>
#include <thread>
#include <vector>

namespace uavm::hal {
namespace {

class CountingPool final : public BufferPool {
 public:
  void Return(uint32_t slot, uint64_t) noexcept override {
    std::lock_guard<std::mutex> lock(mutex_);
    returned.push_back(slot);
  }
  // A 2x1 BGR24 image whose first blue value is `sequence`, stamped `sequence` ms.
  CapturedBuffer Make(uint32_t slot, uint64_t sequence) {
    pixels_[slot % pixels_.size()] = {static_cast<uint8_t>(sequence), 20, 30, 40, 50, 60};
    RawImage raw;
    raw.data = pixels_[slot % pixels_.size()].data();
    raw.bytes = 6;
    raw.width = 2;
    raw.height = 1;
    raw.stride = 6;
    raw.format = PixelFormat::kBgr24;
    return CapturedBuffer(this, slot, 1, raw, static_cast<int64_t>(sequence) * 1'000'000, sequence);
  }
  std::mutex mutex_;
  std::vector<uint32_t> returned;

 private:
  std::array<std::array<uint8_t, 6>, 8> pixels_{};
};

TEST(CameraFeedTest, EndOfStreamBeforeBeginAndAfterEnd) {
  CameraFeed feed(2, "cam", cv::Size(2, 1));
  Frame frame;
  std::string error;
  EXPECT_EQ(feed.Next(&frame, &error), Status::kEndOfStream);
  EXPECT_EQ(error, "source closed");
  feed.Begin();
  EXPECT_TRUE(feed.running());
  feed.End();
  EXPECT_FALSE(feed.running());
  EXPECT_EQ(feed.Next(&frame, &error), Status::kEndOfStream);
}

TEST(CameraFeedTest, DeliversConvertedFramesAndCounts) {
  CountingPool pool;
  CameraFeed feed(2, "video0", cv::Size(2, 1));
  feed.Begin();
  feed.Deliver(pool.Make(0, 10));
  feed.Deliver(pool.Make(1, 11));
  feed.Deliver(pool.Make(2, 14));  // the driver skipped 12 and 13; the queue (2) drops 10
  feed.CountDriverGap();
  EXPECT_EQ(feed.CountReconnect(), 1u);
  feed.RestartSequence();
  feed.Deliver(pool.Make(3, 0));  // a new stream: no gap counted against 14
  const CaptureCounters c = feed.Counters();
  EXPECT_EQ(c.captured, 4u);
  EXPECT_EQ(c.dropped, 2u);
  EXPECT_EQ(c.driver_gaps, 3u);
  EXPECT_EQ(c.reconnects, 1u);

  Frame frame;
  std::string error;
  ASSERT_EQ(feed.Next(&frame, &error), Status::kOk) << error;
  EXPECT_EQ(frame.index, 0u);
  EXPECT_EQ(frame.timestamp_ns, 14'000'000);
  EXPECT_EQ(frame.source_name, "video0_0000000000014000000");
  EXPECT_EQ(frame.original_size, cv::Size(2, 1));
  EXPECT_EQ(frame.decode_scale, 1.0);
  ASSERT_EQ(frame.image.size(), cv::Size(2, 1));
  EXPECT_EQ(frame.image.at<cv::Vec3b>(0, 0), cv::Vec3b(14, 20, 30));
  ASSERT_EQ(feed.Next(&frame, &error), Status::kOk) << error;
  EXPECT_EQ(frame.index, 1u);
  EXPECT_EQ(frame.timestamp_ns, 0);
  // Every buffer went back to its pool once: the two dropped, and each consumed one as soon as it was converted.
  EXPECT_EQ(pool.returned.size(), 4u);
}

TEST(CameraFeedTest, SkipsABufferThatDoesNotConvert) {
  CountingPool pool;
  CameraFeed feed(4, "cam", cv::Size(2, 1));
  feed.Begin();
  CapturedBuffer short_buffer = pool.Make(0, 1);
  RawImage raw = short_buffer.image();
  raw.bytes = 3;  // shorter than 2x1 BGR24 needs
  feed.Deliver(CapturedBuffer(&pool, 5, 1, raw, 1, 1));
  short_buffer.Release();
  feed.Deliver(pool.Make(1, 2));
  Frame frame;
  std::string error;
  EXPECT_EQ(feed.Next(&frame, &error), Status::kSkipped);
  EXPECT_FALSE(error.empty());
  EXPECT_EQ(frame.source_name, "cam_0000000000000000001");
  EXPECT_EQ(feed.Next(&frame, &error), Status::kOk) << error;
  EXPECT_EQ(frame.index, 1u);
}

// A failure ends the stream with its reason once the queued frames are consumed, waking a consumer that waits.
TEST(CameraFeedTest, FailureReachesAWaitingConsumer) {
  CountingPool pool;
  CameraFeed feed(2, "cam", cv::Size(2, 1));
  feed.Begin();
  feed.Deliver(pool.Make(0, 1));
  std::thread driver([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    feed.Fail("device lost (test)");
    feed.queue().Close();
  });
  Frame frame;
  std::string error;
  EXPECT_EQ(feed.Next(&frame, &error), Status::kOk);
  EXPECT_EQ(feed.Next(&frame, &error), Status::kError);
  EXPECT_EQ(error, "device lost (test)");
  driver.join();
  // Begin() again (a reopened source) clears the failure.
  feed.Begin();
  feed.Deliver(pool.Make(1, 2));
  EXPECT_EQ(feed.Next(&frame, &error), Status::kOk);
}

}  // namespace
}  // namespace uavm::hal
