#pragma once
// What a tile server needs to know about a pyramid of 256x256 PNG tiles kept on disk as DIR/{z}/{x}/{y}.png: the live
// pyramid the flight grows (LiveTilePyramid) or, once the flight has ended, the end-of-flight tiles/ re-rendered from
// the final mosaic on the same grid. Published as an immutable snapshot (shared_ptr<const TileSetInfo>): a reader
// never sees half of an update.
#include <cstdint>
#include <string>

namespace uavm {

inline constexpr int kTileSize = 256;

struct TileSetInfo {
  std::string dir;  // absolute; tiles at dir/z/x/y.png, each written atomically (temp file + rename)
  // true: EPSG:3857 XYZ tiles on the GoogleMapsCompatible grid (OGC WMTS well-known scale set; x east, y south from
  // the top-left of the world, z in [0, 24]). false: a local pyramid of the unreferenced map (Leaflet CRS.Simple: at
  // max_zoom one tile pixel is one map pixel; tile (z, x, y) covers map pixels from (x, y) * 256 * 2^(max_zoom - z);
  // x, y >= 0).
  bool geographic = false;
  int min_zoom = 0;
  int max_zoom = 0;
  // Extent of what the tiles show: degrees (geographic; west/east longitudes, south/north latitudes) or CRS.Simple
  // units (local: lng = x / 2^max_zoom, lat = -y / 2^max_zoom, so north = 0 and south < 0).
  double west = 0, south = 0, east = 0, north = 0;
  bool final = false;      // the end-of-flight tiles (they no longer change)
  int64_t generation = 0;  // changes when the grid does (local -> geographic, a new georeference, the final tiles):
                           // a client drops what it cached of an older generation
  int64_t updated_ns = 0;  // monotonic time of the last tile written
  int frames = 0;          // frames drawn into the pyramid so far
};

}  // namespace uavm
