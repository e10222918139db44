#pragma once
#include <map>
#include <string>

#include "hal/common/pixel_convert.h"

namespace uavm::hal {

// What both camera back-ends (hal/v4l2, hal/libcamera) are asked for. Source syntax (--source):
//   v4l2:/dev/video0?width=640&height=480&format=YUYV&fps=30&buffers=6&queue=2&reconnect_s=30
//   libcamera:0?width=640&height=480&format=RGB24      (libcamera:N = N-th camera, or libcamera:<camera id>)
// Every key is optional; an unknown key or a bad value is an error. (How a capture is asked for; the lens of the frames
// is core/lens's CameraOptions.)
struct CaptureOptions {
  std::string device;  // /dev/videoN for V4L2; index or camera id for libcamera
  int width = 640;     // requested size; the driver's nearest size is refused unless equal (no surprises)
  int height = 480;
  PixelFormat format = PixelFormat::kYuyv;
  int fps = 30;               // requested frame rate (0 = the driver's default)
  int buffers = 6;            // capture buffers allocated once at stream start (the pool)
  int queue = 2;              // bounded queue between capture and consumer (drop-oldest); must be < buffers
  double reconnect_s = 30.0;  // after a device loss, keep trying to reopen it this long (0 = give up at once)

  [[nodiscard]] bool Check(std::string* error) const;
};

// Splits "DEVICE?k=v&k=v" and applies the keys to `options` (which keeps its defaults for keys not given).
[[nodiscard]] bool ParseCaptureOptions(const std::string& spec, CaptureOptions* options, std::string* error);

// The query syntax above as one line of help text.
[[nodiscard]] std::string CameraOptionsHelp();

}  // namespace uavm::hal
