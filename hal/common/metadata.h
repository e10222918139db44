#pragma once
#include <cstddef>
#include <optional>
#include <string>

namespace uavm::hal {

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
};

// Reads EXIF/XMP with Exiv2. Never throws: unreadable or garbage metadata gives an empty result and, when `warning`
// is given, a one-line reason.
[[nodiscard]] FrameMetadata ReadMetadata(const std::string& path, std::string* warning = nullptr);
// The same from the bytes of an image file already in memory.
[[nodiscard]] FrameMetadata ReadMetadata(const unsigned char* data, size_t size, std::string* warning = nullptr);

}  // namespace uavm::hal
