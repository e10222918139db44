#include "hal/common/frame_source.h"

namespace uavm::hal {

const char* ToString(Status s) {
  switch (s) {
    case Status::kOk:
      return "ok";
    case Status::kEndOfStream:
      return "end of stream";
    case Status::kSkipped:
      return "skipped";
    case Status::kError:
      return "error";
  }
  return "unknown";
}

}  // namespace uavm::hal
