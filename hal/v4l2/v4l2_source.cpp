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

V4l2Source::V4l2Source(CaptureOptions options)
    : options_(std::move(options)),
      feed_(static_cast<size_t>(std::max(1, options_.queue)),
            std::filesystem::path(options_.device).filename().string(), cv::Size(options_.width, options_.height)) {}

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
  feed_.Begin();
  thread_ = std::thread([this] { CaptureLoop(); });
  return Status::kOk;
}

void V4l2Source::CaptureLoop() {
  int64_t last_frame_ns = MonotonicNs();
  feed_.RestartSequence();
  while (feed_.running()) {
    CapturedBuffer buffer;
    std::string why;
    const V4l2Device::Wait w = device_.Dequeue(kPollMs, &buffer, &why);
    if (w == V4l2Device::Wait::kFrame) {
      last_frame_ns = MonotonicNs();
      feed_.Deliver(std::move(buffer));  // never blocks; drops (and re-queues) the oldest when full
      continue;
    }
    if (w == V4l2Device::Wait::kCorrupt) {
      feed_.CountDriverGap();
      spdlog::debug("{}: the driver flagged a buffer as damaged", options_.device);
      continue;
    }
    if (w == V4l2Device::Wait::kTimeout) {
      const int64_t stall = StallNs(actual_fps_);
      if (MonotonicNs() - last_frame_ns < stall) continue;
      why = "no frame for " + std::to_string(stall / 1'000'000) + " ms";
    }
    if (!feed_.running()) break;
    if (!Reconnect(why)) break;
    last_frame_ns = MonotonicNs();
    feed_.RestartSequence();  // sequence numbers restart with the new stream
  }
  feed_.queue().Close();
}

bool V4l2Source::Reconnect(const std::string& why) {
  spdlog::error("v4l2 {}: device lost ({}); reconnecting for up to {:.0f} s", options_.device, why,
                options_.reconnect_s);
  // The queued frames are of the lost stream: release them (their buffers are unmapped by Close()).
  const size_t released = feed_.queue().Clear();
  if (released > 0) spdlog::warn("v4l2 {}: {} queued frames of the lost stream dropped", options_.device, released);
  device_.Close();
  const int64_t give_up = MonotonicNs() + static_cast<int64_t>(options_.reconnect_s * 1e9);
  int backoff_ms = 100;
  std::string last_error = why;
  int attempts = 0;
  while (feed_.running()) {
    if (MonotonicNs() >= give_up) break;
    // Sleep in short slices so that Close() is not held up by the back-off.
    const int64_t wake = std::min(give_up, MonotonicNs() + static_cast<int64_t>(backoff_ms) * 1'000'000);
    while (feed_.running() && MonotonicNs() < wake) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (!feed_.running()) break;
    ++attempts;
    std::string err;
    if (device_.Open(options_, &err) == Status::kOk) {
      const uint64_t reconnects = feed_.CountReconnect();
      spdlog::warn("v4l2 {}: reconnected after {} attempt(s) ({} reconnects so far)", options_.device, attempts,
                   reconnects);
      return true;
    }
    last_error = err;
    spdlog::debug("v4l2 {}: reopen failed: {}", options_.device, err);
    backoff_ms = std::min(backoff_ms * 2, 2000);
  }
  if (!feed_.running()) return false;
  std::string failure = options_.device + " lost (" + why + ") and not back within " +
                        std::to_string(options_.reconnect_s) + " s (" + std::to_string(attempts) +
                        " attempts; last: " + last_error + ")";
  spdlog::error("v4l2 {}", failure);
  feed_.Fail(std::move(failure));
  return false;
}

Status V4l2Source::Next(Frame* frame, std::string* error) {
  return feed_.Next(frame, error);
}

void V4l2Source::Close() {
  feed_.End();
  if (thread_.joinable()) thread_.join();
  feed_.queue().Clear();
  device_.Close();
}

std::string V4l2Source::Describe() const {
  return "v4l2:" + options_.device + " " + std::to_string(options_.width) + "x" + std::to_string(options_.height) +
         " " + ToString(options_.format);
}

CaptureCounters V4l2Source::Counters() const {
  return feed_.Counters();
}

}  // namespace uavm::hal
