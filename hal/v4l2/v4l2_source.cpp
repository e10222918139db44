#include "hal/v4l2/v4l2_source.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "core/util/clock.h"

namespace uavm::hal {

namespace {
constexpr int kPollMs = 100;
// No frame for this long while streaming = the device is lost: 2 s, or 3 frame periods of a slower camera.
int64_t StallNs(double fps) {
  return std::max<int64_t>(2'000'000'000, fps > 0 ? static_cast<int64_t>(3e9 / fps) : 0);
}
}  // namespace

V4l2Source::V4l2Source(CameraOptions options)
    : options_(std::move(options)),
      name_(std::filesystem::path(options_.device).filename().string()),
      queue_(static_cast<size_t>(std::max(1, options_.queue))) {}

V4l2Source::~V4l2Source() {
  Close();
}

Status V4l2Source::Open(std::string* error) {
  if (!options_.Check(error)) return Status::kError;
  if (device_.Open(options_, error) != Status::kOk) return Status::kError;
  actual_fps_ = device_.actual_fps();
  spdlog::info("v4l2 {} ({}, {}): {}x{} {}, {} buffers, queue {}, {:.1f} fps", options_.device, device_.card(),
               device_.driver(), options_.width, options_.height, ToString(options_.format), device_.buffer_count(),
               options_.queue, actual_fps_);
  stop_ = false;
  failed_ = false;
  queue_.Reopen();
  thread_ = std::thread([this] { CaptureLoop(); });
  return Status::kOk;
}

void V4l2Source::CaptureLoop() {
  int64_t last_frame_ns = MonotonicNs();
  bool have_sequence = false;
  uint64_t last_sequence = 0;
  while (!stop_) {
    CapturedBuffer buffer;
    std::string why;
    const V4l2Device::Wait w = device_.Dequeue(kPollMs, &buffer, &why);
    if (w == V4l2Device::Wait::kFrame) {
      last_frame_ns = MonotonicNs();
      ++captured_;
      if (have_sequence && buffer.sequence() > last_sequence + 1) driver_gaps_ += buffer.sequence() - last_sequence - 1;
      have_sequence = true;
      last_sequence = buffer.sequence();
      (void)queue_.Push(std::move(buffer));  // never blocks; drops (and re-queues) the oldest when full
      continue;
    }
    if (w == V4l2Device::Wait::kCorrupt) {
      ++driver_gaps_;
      spdlog::debug("{}: the driver flagged a buffer as damaged", options_.device);
      continue;
    }
    if (w == V4l2Device::Wait::kTimeout) {
      const int64_t stall = StallNs(actual_fps_);
      if (MonotonicNs() - last_frame_ns < stall) continue;
      why = "no frame for " + std::to_string(stall / 1'000'000) + " ms";
    }
    if (stop_) break;
    if (!Reconnect(why)) break;
    last_frame_ns = MonotonicNs();
    have_sequence = false;  // sequence numbers restart with the new stream
  }
  queue_.Close();
}

bool V4l2Source::Reconnect(const std::string& why) {
  spdlog::error("v4l2 {}: device lost ({}); reconnecting for up to {:.0f} s", options_.device, why,
                options_.reconnect_s);
  // The queued frames are of the lost stream: release them (their buffers are unmapped by Close()).
  const size_t released = queue_.Clear();
  if (released > 0) spdlog::warn("v4l2 {}: {} queued frames of the lost stream dropped", options_.device, released);
  device_.Close();
  const int64_t give_up = MonotonicNs() + static_cast<int64_t>(options_.reconnect_s * 1e9);
  int backoff_ms = 100;
  std::string last_error = why;
  int attempts = 0;
  while (!stop_) {
    if (MonotonicNs() >= give_up) break;
    // Sleep in short slices so that Close() is not held up by the back-off.
    const int64_t wake = std::min(give_up, MonotonicNs() + static_cast<int64_t>(backoff_ms) * 1'000'000);
    while (!stop_ && MonotonicNs() < wake) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (stop_) break;
    ++attempts;
    std::string err;
    if (device_.Open(options_, &err) == Status::kOk) {
      ++reconnects_;
      spdlog::warn("v4l2 {}: reconnected after {} attempt(s) ({} reconnects so far)", options_.device, attempts,
                   reconnects_.load());
      return true;
    }
    last_error = err;
    spdlog::debug("v4l2 {}: reopen failed: {}", options_.device, err);
    backoff_ms = std::min(backoff_ms * 2, 2000);
  }
  if (stop_) return false;
  std::lock_guard<std::mutex> lock(failure_mutex_);
  failure_ = options_.device + " lost (" + why + ") and not back within " + std::to_string(options_.reconnect_s) +
             " s (" + std::to_string(attempts) + " attempts; last: " + last_error + ")";
  failed_ = true;
  spdlog::error("v4l2 {}", failure_);
  return false;
}

Status V4l2Source::Next(Frame* frame, std::string* error) {
  for (;;) {
    std::optional<CapturedBuffer> buffer = queue_.Pop(std::chrono::milliseconds(200));
    if (!buffer) {
      if (failed_) {
        std::lock_guard<std::mutex> lock(failure_mutex_);
        *error = failure_;
        return Status::kError;
      }
      if (stop_ || !thread_.joinable()) {
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
    frame->original_size = cv::Size(options_.width, options_.height);
    frame->decode_scale = 1.0;
    frame->metadata = FrameMetadata{};
    const Status st = ConvertToBgr(buffer->image(), &frame->image, error);
    buffer->Release();  // back to the driver as soon as the pixels are converted
    return st;
  }
}

void V4l2Source::Close() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  queue_.Clear();
  device_.Close();
}

std::string V4l2Source::Describe() const {
  return "v4l2:" + options_.device + " " + std::to_string(options_.width) + "x" + std::to_string(options_.height) +
         " " + ToString(options_.format);
}

CaptureCounters V4l2Source::Counters() const {
  CaptureCounters c;
  c.dropped = queue_.dropped();  // before `captured`: a frame counted as captured is pushed (maybe dropped) after
  c.captured = captured_;
  c.driver_gaps = driver_gaps_;
  c.reconnects = reconnects_;
  return c;
}

}  // namespace uavm::hal
