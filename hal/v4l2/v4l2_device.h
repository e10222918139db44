#pragma once
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "hal/common/camera_options.h"
#include "hal/common/capture_queue.h"

namespace uavm::hal {

// One V4L2 video capture node streaming through mmap buffers (single-planar API: UVC webcams, vivid, most CSI
// bridges' /dev/video nodes). The buffers are allocated and mapped once in Open() and form the pool: Dequeue() hands
// a filled one out as a CapturedBuffer, whose destruction re-queues it (Return, thread-safe).
class V4l2Device final : public BufferPool {
 public:
  enum class Wait {
    kFrame,    // *out holds a filled buffer
    kTimeout,  // nothing within the timeout
    kCorrupt,  // the driver flagged the buffer as damaged (V4L2_BUF_FLAG_ERROR); it went back to the driver
    kLost,     // the device is gone or broken (ENODEV, EIO, POLLERR): Close(), then Open() again
  };

  V4l2Device() = default;
  ~V4l2Device() override;
  V4l2Device(const V4l2Device&) = delete;
  V4l2Device& operator=(const V4l2Device&) = delete;

  // Opens the node, negotiates exactly options.width x height in options.format (a different answer from the driver
  // is an error that names what it offered), sets the frame rate, allocates and maps options.buffers buffers, queues
  // them and starts streaming. kError with the reason otherwise (nothing left open).
  [[nodiscard]] Status Open(const CaptureOptions& options, std::string* error);
  // Waits up to timeout_ms for a filled buffer. Single consumer (the capture thread).
  [[nodiscard]] Wait Dequeue(int timeout_ms, CapturedBuffer* out, std::string* error);
  // Stops streaming, unmaps and closes. Waits until every CapturedBuffer issued has been released first (their
  // memory is unmapped here), so callers release theirs (queue Clear()) before.
  void Close();
  void Return(uint32_t slot, uint64_t generation) noexcept override;

  [[nodiscard]] bool is_open() const { return fd_ >= 0; }
  [[nodiscard]] const std::string& card() const { return card_; }
  [[nodiscard]] const std::string& driver() const { return driver_; }
  [[nodiscard]] double actual_fps() const { return actual_fps_; }
  [[nodiscard]] int buffer_count() const { return static_cast<int>(maps_.size()); }
  [[nodiscard]] int stride() const { return stride_; }
  // Timestamps are the driver's own (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC); false when it gives none and the dequeue
  // time (CLOCK_MONOTONIC) is used instead.
  [[nodiscard]] bool driver_timestamps() const { return driver_timestamps_; }

 private:
  struct Mapping {
    void* addr = nullptr;
    size_t length = 0;
  };
  int fd_ = -1;
  uint64_t generation_ = 0;  // incremented by every Open(): a handle from an earlier stream is not re-queued
  std::vector<Mapping> maps_;
  int width_ = 0;
  int height_ = 0;
  int stride_ = 0;
  PixelFormat format_ = PixelFormat::kYuyv;
  double actual_fps_ = 0;
  bool driver_timestamps_ = true;
  std::string card_;
  std::string driver_;
  std::mutex mutex_;  // guards outstanding_ and the fd against Close() while a Return() runs
  std::condition_variable returned_;
  int outstanding_ = 0;
};

// What --list-cameras prints for one V4L2 node.
struct V4l2DeviceInfo {
  std::string path;
  std::string card;
  std::string driver;
  std::string bus;
  bool capture = false;              // single-planar video capture with streaming I/O (usable by V4l2Source)
  std::vector<std::string> formats;  // "YUYV 640x480 1280x720 ..." one per pixel format
};

// Every /dev/video* node (natural order), queried without streaming. Nodes that cannot be opened are listed with
// the reason in `card`.
[[nodiscard]] std::vector<V4l2DeviceInfo> ListV4l2Devices();

}  // namespace uavm::hal
