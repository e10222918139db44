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

// The frame types live in core (core/frame/frame.h), which consumes them; these names keep hal's users unchanged.
using Frame = ::uavm::Frame;
using CaptureCounters = ::uavm::CaptureCounters;

// What the consumer needs, so a source can decode no more than that (e.g. JPEG DCT-domain downscaling).
struct DecodeHint {
  int min_long_side = 0;  // 0 = full resolution
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  [[nodiscard]] virtual Status Open(std::string* error) = 0;
  // Fills `frame`. On kSkipped, `error` says why and frame.source_name names the bad input.
  [[nodiscard]] virtual Status Next(Frame* frame, std::string* error) = 0;
  virtual void Close() = 0;
  [[nodiscard]] virtual std::string Describe() const = 0;
  void SetDecodeHint(const DecodeHint& hint) { hint_ = hint; }
  // Thread-safe: may be read while another thread is in Next().
  [[nodiscard]] virtual CaptureCounters Counters() const { return {}; }

 protected:
  DecodeHint hint_;
};

}  // namespace uavm::hal
