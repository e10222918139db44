#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "hal/common/camera_feed.h"
#include "hal/common/camera_options.h"
#include "hal/common/frame_source.h"

namespace libcamera {
class Camera;
class CameraManager;
class FrameBufferAllocator;
class Request;
class Stream;
}  // namespace libcamera

namespace uavm::hal {

// A libcamera camera as a FrameSource (--source libcamera:N or libcamera:<camera id>), on Debian 12's libcamera 0.0.3.
// One viewfinder-role stream of options.width x height in options.format (libcamera's RGB888/BGR888 are this
// project's BGR24/RGB24 by memory order); options.buffers FrameBuffers allocated once by a FrameBufferAllocator, one
// Request per buffer, created once and reused; every plane mmapped once. A completed request becomes a CapturedBuffer
// in the same bounded drop-oldest CaptureQueue as V4l2Source; releasing it re-queues the request.
// Device loss (the camera's `disconnected` signal, a failed request, or no frame for 2 s): logged, and Next() then
// returns kError with the reason. No reconnect: libcamera 0.0.3 aborts the process in Camera::stop() when the device
// is gone (a FATAL assertion in PipelineHandler::stop, seen on vimc unbind) and allows one CameraManager per process,
// so the lost camera is abandoned (kept allocated until exit) instead. options.reconnect_s is not used here.
// libcamera allows one CameraManager per process: do not list cameras while a LibcameraSource is open.
class LibcameraSource final : public FrameSource, private BufferPool {
 public:
  explicit LibcameraSource(CaptureOptions options);
  ~LibcameraSource() override;
  LibcameraSource(const LibcameraSource&) = delete;
  LibcameraSource& operator=(const LibcameraSource&) = delete;

  [[nodiscard]] Status Open(std::string* error) override;
  [[nodiscard]] Status Next(Frame* frame, std::string* error) override;
  void Close() override;
  [[nodiscard]] std::string Describe() const override;
  [[nodiscard]] CaptureCounters Counters() const override;

  [[nodiscard]] const std::string& camera_id() const { return camera_id_; }

 private:
  struct Slot;
  [[nodiscard]] bool Start(std::string* error);  // manager, camera, configuration, buffers, requests, start
  void Stop();                                   // the reverse; waits for every handle out to come back
  void OnRequestCompleted(libcamera::Request* request);
  void OnDisconnected();
  void Return(uint32_t slot, uint64_t generation) noexcept override;
  void WatchLoop();
  void Abandon();  // gives up a lost camera without stopping it (libcamera 0.0.3 aborts there)

  CaptureOptions options_;
  std::string camera_id_;
  std::unique_ptr<libcamera::CameraManager> manager_;
  std::shared_ptr<libcamera::Camera> camera_;
  std::unique_ptr<libcamera::FrameBufferAllocator> allocator_;
  libcamera::Stream* stream_ = nullptr;  // borrowed from camera_
  std::vector<std::unique_ptr<Slot>> slots_;
  int stride_ = 0;
  CameraFeed feed_;  // frames named "libcamera_<timestamp>"

  std::mutex mutex_;  // guards running_, generation_, outstanding_ against Stop()
  std::condition_variable returned_;
  bool running_ = false;
  uint64_t generation_ = 0;
  int outstanding_ = 0;

  std::thread watch_;  // detects loss
  std::atomic<bool> lost_{false};
  std::atomic<int64_t> last_frame_ns_{0};
};

// What --list-cameras prints for libcamera: one line per camera (id, model, stream formats of the viewfinder role).
// Creates (and destroys) its own CameraManager.
[[nodiscard]] std::vector<std::string> ListLibcameraCameras(std::string* error);

}  // namespace uavm::hal
