#pragma once
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "hal/common/metadata.h"

namespace uavm::hal {

// Results of the capture path: status codes, never exceptions.
enum class Status {
  kOk,
  kEndOfStream,  // no more frames
  kSkipped,      // this input was bad (corrupt, empty, not an image): logged and reported, the stream goes on
  kError,        // the source itself failed (device gone, folder vanished)
};

[[nodiscard]] const char* ToString(Status s);

struct Frame {
  uint64_t index = 0;         // position in the stream, counting skipped inputs too
  int64_t timestamp_ns = 0;   // monotonic, ns
  std::string source_name;    // file name for replay, "video:N" for video frames, device name for cameras
  std::string source_path;    // full path of the original file when there is one (its bytes go into the session)
  cv::Size original_size;     // size of the sensor image, before any reduced decoding
  cv::Mat image;              // BGR8; may be reduced (see decode_scale) when the consumer asked for less
  double decode_scale = 1.0;  // image.cols / original_size.width (exactly 1, 1/2, 1/4 or 1/8 for JPEG DCT scaling)
  FrameMetadata metadata;
};

// What the consumer needs, so a source can decode no more than that (e.g. JPEG DCT-domain downscaling).
struct DecodeHint {
  int min_long_side = 0;  // 0 = full resolution
};

// Counters of a live camera source for report.json (all zero for replay and simulation).
struct CaptureCounters {
  uint64_t captured = 0;     // frames the driver delivered to the source
  uint64_t dropped = 0;      // dropped by the source's own queue (the consumer was slower than the camera)
  uint64_t driver_gaps = 0;  // frames the driver skipped itself (gaps in its sequence numbers: no buffer was free)
  uint64_t reconnects = 0;   // times the device was lost (ENODEV, EIO, unplugged) and opened again
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  [[nodiscard]] virtual Status Open(std::string* error) = 0;
  // Fills `frame`. On kSkipped, `error` says why and frame.source_name names the bad input.
  [[nodiscard]] virtual Status Next(Frame* frame, std::string* error) = 0;
  virtual void Close() = 0;
  [[nodiscard]] virtual std::string Describe() const = 0;
  // True when frames come from storage: the consumer may apply back-pressure instead of dropping.
  [[nodiscard]] virtual bool IsReplay() const = 0;
  void SetDecodeHint(const DecodeHint& hint) { hint_ = hint; }
  // Thread-safe: may be read while another thread is in Next().
  [[nodiscard]] virtual CaptureCounters Counters() const { return {}; }

 protected:
  DecodeHint hint_;
};

}  // namespace uavm::hal
