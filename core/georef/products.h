#pragma once
#include <string>
#include <vector>

#include "core/geometry/transform.h"
#include "core/georef/georef.h"

namespace uavm {

// The map products of a session, made from the tiled mosaic at the end of the flight, tile by tile: GDAL's block cache
// (GDALSetCacheMax, set by the caller) and, per worker, one 256² web tile and the mosaic window it covers (read from
// the overview level just finer than the tile) are all they hold in memory.

// Copies a tiled GeoTIFF into a Cloud Optimized GeoTIFF (GDAL's COG driver, DEFLATE, 512² blocks); the source's
// overviews are reused. Written as `dst`.part and renamed.
[[nodiscard]] bool WriteCog(const std::string& src, const std::string& dst, std::string* error);

struct TileSet {
  bool geographic = false;  // EPSG:3857 XYZ tiles; else a local pyramid (Leaflet CRS.Simple)
  int min_zoom = 0;
  int max_zoom = 0;
  int tiles = 0;  // written (empty tiles are skipped)
  int tiles_empty = 0;
  // Local pyramid: canvas pixel (x, y) is Leaflet CRS.Simple (lat, lng) = (-y, x) / 2^max_zoom.
  double west = 0, south = 0, east = 0, north = 0;  // bounds, degrees (geographic) or CRS.Simple units
  double ms = 0;
};

struct TileOptions {
  int max_tiles = 20000;     // the finest zooms are dropped past this
  int levels_below_fit = 2;  // zoom levels below the one where the whole mosaic fits in one tile
  // Georeferenced: zooms the pyramid must also have (the live pyramid's: its clients keep their URLs).
  int keep_min_zoom = -1;
  int keep_max_zoom = -1;
};

// tiles/z/x/y.png (RGBA). With a georeferenced mosaic: EPSG:3857 XYZ tiles from max_zoom (ground pixel no larger
// than the GSD) down to the whole map in one tile, each warped through a homography fitted to 9 of its points (PROJ),
// on 2 threads; without, a local pyramid of the canvas.
[[nodiscard]] bool WriteTiles(const std::string& tif, const std::string& dir, bool geographic, double gsd_m,
                              const TileOptions& options, TileSet* out, std::string* error);

// mosaic.kmz for Google Earth: a KML super-overlay (doc.kml first, then z/x/y.kml + z/x/y.png with regions and links
// to the children) of the EPSG:3857 tiles WriteTiles wrote to `tiles_dir` (`tiles` its result; geographic only). The
// PNGs are the tiles' own, stored uncompressed in the zip. Written as mosaic.part.kmz and renamed.
[[nodiscard]] bool WriteKmz(const std::string& tiles_dir, const TileSet& tiles, const std::string& kmz,
                            std::string* error);

// One frame for the web page's footprints and match graph.
struct MapFrame {
  int id = -1;
  std::string name;
  bool registered = false;
  Mat3 mosaic_from_frame = Mat3::Identity();  // original-resolution pixels -> mosaic.tif pixels
  int width = 0, height = 0;
};
struct MapEdge {
  int src = -1, tgt = -1;
  int inliers = 0;
  bool used = false;
};

// index.html + leaflet/ (copied from `leaflet_dir`, Debian's libjs-leaflet) + footprints.geojson + graph.geojson:
// the tiles, frame footprints and match graph as toggleable layers, no internet needed (data inlined for file://).
// `mosaic_from_world` (georeferenced) maps easting/northing of `fit.epsg` to mosaic pixels; ignored when local.
[[nodiscard]] bool WriteWebPage(const std::string& out_dir, const std::string& leaflet_dir, const TileSet& tiles,
                                const GeorefFit& fit, const std::vector<MapFrame>& frames,
                                const std::vector<MapEdge>& edges, std::string* error);

}  // namespace uavm
