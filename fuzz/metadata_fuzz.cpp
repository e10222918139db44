// Fuzzes the EXIF/XMP reader (Exiv2 behind hal::ReadMetadata) with arbitrary file bytes: it must never throw or
// crash, and what it returns is finite and in range.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <optional>
#include <string>

#include "hal/common/metadata.h"

namespace {

void CheckFinite(const std::optional<double>& v) {
  if (v && !std::isfinite(*v)) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string warning;
  const uavm::hal::FrameMetadata md = uavm::hal::ReadMetadata(data, size, &warning);
  CheckFinite(md.latitude_deg);
  CheckFinite(md.longitude_deg);
  CheckFinite(md.altitude_m);
  CheckFinite(md.relative_altitude_m);
  CheckFinite(md.flight_yaw_deg);
  CheckFinite(md.gimbal_yaw_deg);
  CheckFinite(md.gimbal_pitch_deg);
  CheckFinite(md.focal_length_mm);
  CheckFinite(md.focal_length_35mm);
  if (md.latitude_deg && std::abs(*md.latitude_deg) > 180.0) std::abort();
  return 0;
}
