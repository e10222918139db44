#include "core/tiles/web_mercator.h"

#include <algorithm>
#include <cmath>

#include "core/tiles/tile_set.h"

namespace uavm {

namespace {

double WorldPixels(int z) {
  return kTileSize * std::ldexp(1.0, z);
}

}  // namespace

Vec2 MercatorPixelFromLatLon(double lat_deg, double lon_deg, int z) {
  const double lat = std::clamp(lat_deg, -85.05112878, 85.05112878) * M_PI / 180.0;
  const double x = (lon_deg + 180.0) / 360.0;
  const double y = 0.5 - std::log(std::tan(M_PI / 4 + lat / 2)) / (2 * M_PI);
  return Vec2(x, y) * WorldPixels(z);
}

Vec2 LonLatFromMercatorPixel(const Vec2& px, int z) {
  const Vec2 u = px / WorldPixels(z);
  const double lon = u.x() * 360.0 - 180.0;
  const double lat = (2 * std::atan(std::exp((0.5 - u.y()) * 2 * M_PI)) - M_PI / 2) * 180.0 / M_PI;
  return Vec2(lon, lat);
}

Vec2 MercatorMetresFromPixel(const Vec2& px, int z) {
  const double m_per_px = 2 * kMercatorHalfWorldM / WorldPixels(z);
  return Vec2(px.x() * m_per_px - kMercatorHalfWorldM, kMercatorHalfWorldM - px.y() * m_per_px);
}

int MaxZoomForGsd(double lat_deg, double gsd_m) {
  if (!(gsd_m > 0)) return 0;
  // A tile pixel at zoom z covers (equator circumference * cos(lat)) / (256 * 2^z) metres of ground.
  const double ground = 2 * kMercatorHalfWorldM * std::cos(lat_deg * M_PI / 180.0);
  return std::clamp(static_cast<int>(std::ceil(std::log2(ground / (kTileSize * gsd_m)) - 1e-9)), 0, 24);
}

}  // namespace uavm
