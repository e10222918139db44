#pragma once
// Web-mercator (EPSG:3857) XYZ tile arithmetic on the GoogleMapsCompatible grid: at zoom z the world is 2^z x 2^z
// tiles of 256 px, pixel (0, 0) at the top-left corner (180 W, 85.05 N). "Global pixels" below are continuous pixel
// coordinates of that grid whose integer values are pixel *corners*.
#include "core/geometry/transform.h"

namespace uavm {

inline constexpr double kMercatorHalfWorldM = 20037508.342789244;  // pi * 6378137

// WGS 84 lat/lon (degrees) -> global pixel coordinates at zoom z.
[[nodiscard]] Vec2 MercatorPixelFromLatLon(double lat_deg, double lon_deg, int z);
// The inverse: (lat, lon) in degrees as (x = lon, y = lat).
[[nodiscard]] Vec2 LonLatFromMercatorPixel(const Vec2& px, int z);
// EPSG:3857 metres of a global pixel at zoom z.
[[nodiscard]] Vec2 MercatorMetresFromPixel(const Vec2& px, int z);

// The finest zoom whose tile pixel on the ground (at latitude `lat_deg`) is no larger than `gsd_m`, within [0, 24].
[[nodiscard]] int MaxZoomForGsd(double lat_deg, double gsd_m);

}  // namespace uavm
