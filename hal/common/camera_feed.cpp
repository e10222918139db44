#include "hal/common/camera_feed.h"

#include <chrono>
#include <cstdio>
#include <optional>
#include <utility>

#include "hal/common/pixel_convert.h"

namespace uavm::hal {

CameraFeed::CameraFeed(size_t queue_capacity, std::string name, cv::Size size)
    : name_(std::move(name)), size_(size), queue_(queue_capacity) {}

void CameraFeed::Begin() {
  failed_ = false;
  queue_.Reopen();
  running_ = true;
}

void CameraFeed::Deliver(CapturedBuffer buffer) {
  ++captured_;
  if (have_sequence_ && buffer.sequence() > last_sequence_ + 1) driver_gaps_ += buffer.sequence() - last_sequence_ - 1;
  have_sequence_ = true;
  last_sequence_ = buffer.sequence();
  (void)queue_.Push(std::move(buffer));  // refused only when closed: the handle then goes back at once
}

void CameraFeed::Fail(std::string why) {
  {
    std::lock_guard<std::mutex> lock(failure_mutex_);
    failure_ = std::move(why);
  }
  failed_ = true;
}

Status CameraFeed::Next(Frame* frame, std::string* error) {
  for (;;) {
    std::optional<CapturedBuffer> buffer = queue_.Pop(std::chrono::milliseconds(200));
    if (!buffer) {
      if (failed_) {
        std::lock_guard<std::mutex> lock(failure_mutex_);
        *error = failure_;
        return Status::kError;
      }
      if (!running_) {
        *error = "source closed";
        return Status::kEndOfStream;
      }
      continue;  // the camera is slow, or reconnecting
    }
    frame->index = delivered_++;
    frame->timestamp_ns = buffer->timestamp_ns();
    char name[64];
    std::snprintf(name, sizeof(name), "%s_%019lld", name_.c_str(), static_cast<long long>(buffer->timestamp_ns()));
    frame->source_name = name;
    frame->source_path.clear();
    frame->original_size = size_;
    frame->decode_scale = 1.0;
    frame->metadata = FrameMetadata{};
    const Status st = ConvertToBgr(buffer->image(), &frame->image, error);
    buffer->Release();  // back to the driver as soon as the pixels are converted
    return st;
  }
}

CaptureCounters CameraFeed::Counters() const {
  CaptureCounters c;
  c.dropped = queue_.dropped();  // before `captured`: a frame counted as captured is pushed (maybe dropped) after
  c.captured = captured_;
  c.driver_gaps = driver_gaps_;
  c.reconnects = reconnects_;
  return c;
}

}  // namespace uavm::hal
