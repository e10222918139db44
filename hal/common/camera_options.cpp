#include "hal/common/camera_options.h"

#include <charconv>
#include <cmath>

namespace uavm::hal {

namespace {

bool ParseInt(const std::string& key, const std::string& v, int lo, int hi, int* out, std::string* error) {
  int value = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), value);
  if (ec != std::errc() || end != v.data() + v.size() || value < lo || value > hi) {
    *error = "camera option " + key + "=" + v + ": expected an integer in [" + std::to_string(lo) + ", " +
             std::to_string(hi) + "]";
    return false;
  }
  *out = value;
  return true;
}

bool ParseSeconds(const std::string& key, const std::string& v, double* out, std::string* error) {
  try {
    size_t used = 0;
    const double value = std::stod(v, &used);
    if (used == v.size() && std::isfinite(value) && value >= 0 && value <= 86400) {
      *out = value;
      return true;
    }
  } catch (const std::exception&) {
  }
  *error = "camera option " + key + "=" + v + ": expected seconds in [0, 86400]";
  return false;
}

}  // namespace

bool CaptureOptions::Check(std::string* error) const {
  if (device.empty()) {
    *error = "camera: no device given";
    return false;
  }
  if (width < 16 || height < 16 || width > 16384 || height > 16384 || width % 2 != 0 || height % 2 != 0) {
    *error = "camera: width and height must be even, 16..16384";
    return false;
  }
  if (fps < 0 || fps > 1000) {
    *error = "camera: fps must be 0..1000";
    return false;
  }
  if (buffers < 2 || buffers > 32) {
    *error = "camera: buffers must be 2..32";
    return false;
  }
  if (queue < 1 || queue >= buffers) {
    *error = "camera: queue must be at least 1 and smaller than buffers (the driver needs a buffer to fill)";
    return false;
  }
  if (!(reconnect_s >= 0)) {
    *error = "camera: reconnect_s must be >= 0";
    return false;
  }
  return true;
}

bool ParseCaptureOptions(const std::string& spec, CaptureOptions* options, std::string* error) {
  const auto q = spec.find('?');
  options->device = spec.substr(0, q);
  if (q != std::string::npos) {
    size_t pos = q + 1;
    while (pos <= spec.size()) {
      const auto amp = std::min(spec.find('&', pos), spec.size());
      const std::string kv = spec.substr(pos, amp - pos);
      pos = amp + 1;
      if (kv.empty()) continue;
      const auto eq = kv.find('=');
      if (eq == std::string::npos) {
        *error = "camera option '" + kv + "': expected key=value";
        return false;
      }
      const std::string key = kv.substr(0, eq);
      const std::string value = kv.substr(eq + 1);
      bool ok = true;
      if (key == "width")
        ok = ParseInt(key, value, 1, 1 << 16, &options->width, error);
      else if (key == "height")
        ok = ParseInt(key, value, 1, 1 << 16, &options->height, error);
      else if (key == "fps")
        ok = ParseInt(key, value, 0, 100000, &options->fps, error);
      else if (key == "buffers")
        ok = ParseInt(key, value, 0, 1000, &options->buffers, error);
      else if (key == "queue")
        ok = ParseInt(key, value, 0, 1000, &options->queue, error);
      else if (key == "reconnect_s")
        ok = ParseSeconds(key, value, &options->reconnect_s, error);
      else if (key == "format") {
        ok = ParsePixelFormat(value, &options->format);
        if (!ok) *error = "camera option format=" + value + ": expected YUYV, NV12, MJPEG, RGB24 or BGR24";
      } else {
        *error = "unknown camera option '" + key + "' (" + CameraOptionsHelp() + ")";
        return false;
      }
      if (!ok) return false;
    }
  }
  return options->Check(error);
}

std::string CameraOptionsHelp() {
  return "keys after '?', joined by '&': width, height (default 640x480), format=YUYV|NV12|MJPEG|RGB24|BGR24 "
         "(default YUYV), fps (default 30), buffers (default 6), queue (default 2, drop-oldest), reconnect_s "
         "(default 30)";
}

}  // namespace uavm::hal
