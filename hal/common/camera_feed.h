#pragma once
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>

#include "hal/common/capture_queue.h"
#include "hal/common/frame_source.h"

namespace uavm::hal {

// What every live camera back-end (V4L2, libcamera) shares between its driver side (a capture thread, or the
// library's completion callbacks) and the consumer: the bounded drop-oldest CaptureQueue, the counters of
// report.json, the failure that ends the stream, and the consumer's Next(). The back-end keeps its device and its
// threads. Status codes, never exceptions.
class CameraFeed {
 public:
  // Frames are named `name`_<timestamp ns, 19 digits> and have `size` (the negotiated format's) as original size.
  CameraFeed(size_t queue_capacity, std::string name, cv::Size size);

  // The stream: Begin() when capture starts (an earlier failure is cleared, the queue reopened), End() when the
  // source is being closed. Capture loops run while running().
  void Begin();
  void End() { running_ = false; }
  [[nodiscard]] bool running() const { return running_; }

  // Driver side, one thread at a time.
  // A filled buffer: counted as captured (and any gap in the driver's sequence numbers before it), then queued;
  // never blocks (the oldest queued buffer is dropped when full).
  void Deliver(CapturedBuffer buffer);
  void CountDriverGap() { ++driver_gaps_; }            // a buffer the driver flagged as damaged
  void RestartSequence() { have_sequence_ = false; }   // a new stream numbers its frames afresh
  uint64_t CountReconnect() { return ++reconnects_; }  // returns the count so far
  // The stream is over with kError: Next() returns `why` once the queued frames are consumed.
  void Fail(std::string why);
  [[nodiscard]] CaptureQueue& queue() { return queue_; }

  // Consumer side. Blocks until a frame is there: kOk, or kSkipped for a buffer that does not convert (the stream
  // goes on); kError with the reason after Fail(); kEndOfStream before Begin() and after End().
  [[nodiscard]] Status Next(Frame* frame, std::string* error);
  // Thread-safe.
  [[nodiscard]] CaptureCounters Counters() const;

 private:
  const std::string name_;
  const cv::Size size_;
  CaptureQueue queue_;
  std::atomic<bool> running_{false};
  std::atomic<bool> failed_{false};
  mutable std::mutex failure_mutex_;
  std::string failure_;
  std::atomic<uint64_t> captured_{0};
  std::atomic<uint64_t> driver_gaps_{0};
  std::atomic<uint64_t> reconnects_{0};
  bool have_sequence_ = false;  // driver side
  uint64_t last_sequence_ = 0;  // driver side
  uint64_t delivered_ = 0;      // consumer side
};

}  // namespace uavm::hal
