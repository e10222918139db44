#pragma once
#include <cstdint>
#include <string>
#include <thread>

#include "hal/common/camera_feed.h"
#include "hal/common/camera_options.h"
#include "hal/common/frame_source.h"
#include "hal/v4l2/v4l2_device.h"

namespace uavm::hal {

// A V4L2 camera as a FrameSource (--source v4l2:/dev/videoN?...). A capture thread of its own dequeues buffers as
// the driver fills them and pushes their handles into a bounded drop-oldest CaptureQueue (it never waits for the
// consumer); Next() takes the newest-but-unconsumed one, converts it to BGR and releases it (the buffer goes back to
// the driver). Device loss (ENODEV, EIO, POLLERR, or no frame for 2 s) is logged, the device is closed and opened
// again with back-off (0.1 s doubling to 2 s) for up to options.reconnect_s; each success is counted in
// Counters().reconnects. When it gives up, Next() returns kError with the reason.
class V4l2Source final : public FrameSource {
 public:
  explicit V4l2Source(CaptureOptions options);
  ~V4l2Source() override;
  V4l2Source(const V4l2Source&) = delete;
  V4l2Source& operator=(const V4l2Source&) = delete;

  // Opens the device synchronously (a wrong format or size is reported here), then starts the capture thread.
  [[nodiscard]] Status Open(std::string* error) override;
  // Blocks until a frame is there. kSkipped for a buffer that does not convert (the stream goes on).
  [[nodiscard]] Status Next(Frame* frame, std::string* error) override;
  void Close() override;
  [[nodiscard]] std::string Describe() const override;
  [[nodiscard]] CaptureCounters Counters() const override;

  [[nodiscard]] const CaptureOptions& options() const { return options_; }
  [[nodiscard]] double actual_fps() const { return actual_fps_; }

 private:
  void CaptureLoop();
  // Closes the lost device (after releasing queued buffers) and reopens it with back-off. False when it gave up.
  bool Reconnect(const std::string& why);

  CaptureOptions options_;
  V4l2Device device_;
  CameraFeed feed_;  // frames named after the device node ("video0_<timestamp>")
  std::thread thread_;
  double actual_fps_ = 0;
};

}  // namespace uavm::hal
