#pragma once
#include <cstdint>
#include <opencv2/core.hpp>
#include <optional>
#include <string>

// The frame a source delivers and the pipeline consumes: plain data, so that core needs nothing from hal to take it.
namespace uavm {

// Optional per-frame metadata. Nothing in the registration needs it; georeferencing and the ground tool use it.
struct FrameMetadata {
  std::optional<double> latitude_deg;
  std::optional<double> longitude_deg;
  std::optional<double> altitude_m;           // GPS altitude (above sea level)
  std::optional<double> relative_altitude_m;  // DJI XMP RelativeAltitude (above take-off)
  std::optional<double> flight_yaw_deg;       // DJI XMP FlightYawDegree
  std::optional<double> gimbal_yaw_deg;       // DJI XMP GimbalYawDegree
  std::optional<double> gimbal_pitch_deg;     // DJI XMP GimbalPitchDegree
  std::optional<double> focal_length_mm;
  std::optional<double> focal_length_35mm;
  std::string make;
  std::string model;
  std::string datetime_original;

  [[nodiscard]] bool HasGps() const { return latitude_deg.has_value() && longitude_deg.has_value(); }
  [[nodiscard]] bool Empty() const {
    return !latitude_deg && !longitude_deg && !altitude_m && !relative_altitude_m && !flight_yaw_deg &&
           !gimbal_yaw_deg && !gimbal_pitch_deg && !focal_length_mm && !focal_length_35mm && make.empty() &&
           model.empty() && datetime_original.empty();
  }
};

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

// Counters of a live camera source for report.json (all zero for replay and simulation).
struct CaptureCounters {
  uint64_t captured = 0;     // frames the driver delivered to the source
  uint64_t dropped = 0;      // dropped by the source's own queue (the consumer was slower than the camera)
  uint64_t driver_gaps = 0;  // frames the driver skipped itself (gaps in its sequence numbers: no buffer was free)
  uint64_t reconnects = 0;   // times the device was lost (ENODEV, EIO, unplugged) and opened again
};

}  // namespace uavm
