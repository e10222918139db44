// mosaic.kmz from the XYZ tiles already on disk: no second reprojection of the mosaic (GDAL's KMLSUPEROVERLAY driver
// took as long as the tiles themselves). Each web-mercator tile is shown in a KML LatLonBox (its corners' latitudes and
// longitudes), as gdal2tiles does for its mercator profile: inside one tile the mercator y is not linear in latitude,
// but across a tile of zoom >= 10 the difference is far below one tile pixel (and drone maps start near zoom 15).
#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_string.h>

#include <charconv>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "core/georef/products.h"
#include "core/tiles/web_mercator.h"

namespace uavm {

namespace fs = std::filesystem;

namespace {

using TileKey = std::tuple<int, int, int>;  // z, x, y

// Region thresholds (pixels on screen of the region's box): a tile shows from 128 px; a parent hands over to its
// children once they are 512 px (it is 1024), so that both are never drawn for long; the tiles with no child stay.
constexpr int kMinLodPixels = 128;
constexpr int kParentMaxLodPixels = 1024;

std::string Box(const char* tag, const TileKey& t) {
  const auto [z, x, y] = t;
  const Vec2 nw = LonLatFromMercatorPixel(Vec2(x * 256.0, y * 256.0), z);
  const Vec2 se = LonLatFromMercatorPixel(Vec2((x + 1) * 256.0, (y + 1) * 256.0), z);
  char buf[320];
  std::snprintf(buf, sizeof(buf),
                "<%s><north>%.12f</north><south>%.12f</south><east>%.12f</east><west>%.12f</west></%s>", tag, nw.y(),
                se.y(), se.x(), nw.x(), tag);
  return buf;
}

std::string Region(const TileKey& t, int max_lod) {
  return "<Region>" + Box("LatLonAltBox", t) + "<Lod><minLodPixels>" + std::to_string(kMinLodPixels) +
         "</minLodPixels><maxLodPixels>" + std::to_string(max_lod) + "</maxLodPixels></Lod></Region>\n";
}

std::string Name(const TileKey& t) {
  return std::to_string(std::get<0>(t)) + "/" + std::to_string(std::get<1>(t)) + "/" + std::to_string(std::get<2>(t));
}

// A NetworkLink loading tile `t`'s KML (`href`, relative to the linking file) when its region comes into view.
std::string Link(const TileKey& t, const std::string& href) {
  return "<NetworkLink><name>" + Name(t) + "</name>" + Region(t, -1) + "<Link><href>" + href +
         "</href><viewRefreshMode>onRegion</viewRefreshMode></Link></NetworkLink>\n";
}

const char* kHead =
    "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<kml xmlns=\"http://www.opengis.net/kml/2.2\">\n<Document>\n";
const char* kTail = "</Document>\n</kml>\n";

std::string TileKml(const TileKey& t, const std::set<TileKey>& tiles) {
  const auto [z, x, y] = t;
  std::string links;
  for (int k = 0; k < 4; ++k) {
    const TileKey c{z + 1, 2 * x + k % 2, 2 * y + k / 2};
    if (tiles.count(c) != 0) links += Link(c, "../../" + Name(c) + ".kml");
  }
  return kHead + ("<name>" + Name(t) + "</name>\n") + Region(t, links.empty() ? -1 : kParentMaxLodPixels) +
         "<GroundOverlay><drawOrder>" + std::to_string(z) + "</drawOrder><Icon><href>" + std::to_string(y) +
         ".png</href></Icon>" + Box("LatLonBox", t) + "</GroundOverlay>\n" + links + kTail;
}

bool ParseInt(const std::string& s, int* v) {
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), *v);
  return ec == std::errc() && end == s.data() + s.size();
}

// The tiles z/x/y.png of zooms [min_zoom, max_zoom] under `dir`.
std::set<TileKey> ListTiles(const std::string& dir, const TileSet& set) {
  std::set<TileKey> out;
  std::error_code ec;
  for (int z = set.min_zoom; z <= set.max_zoom; ++z)
    for (fs::recursive_directory_iterator it(fs::path(dir) / std::to_string(z), ec), end; !ec && it != end;
         it.increment(ec)) {
      const fs::path& p = it->path();
      int x = 0, y = 0;
      if (p.extension() == ".png" && p.parent_path().parent_path().filename() == std::to_string(z) &&
          ParseInt(p.parent_path().filename().string(), &x) && ParseInt(p.stem().string(), &y))
        out.emplace(z, x, y);
    }
  return out;
}

class Zip {
 public:
  explicit Zip(const std::string& path) : handle_(CPLCreateZip(path.c_str(), nullptr)) {}
  ~Zip() { Close(); }
  Zip(const Zip&) = delete;
  Zip& operator=(const Zip&) = delete;
  [[nodiscard]] bool ok() const { return handle_ != nullptr; }
  // PNGs are stored: deflating them again gains nothing and costs time.
  bool Add(const std::string& name, const void* data, size_t size, bool compress) {
    char** opts = compress ? nullptr : CSLSetNameValue(nullptr, "COMPRESSED", "NO");
    bool ok = CPLCreateFileInZip(handle_, name.c_str(), opts) == CE_None;
    CSLDestroy(opts);
    ok = ok && CPLWriteFileInZip(handle_, data, static_cast<int>(size)) == CE_None;
    return CPLCloseFileInZip(handle_) == CE_None && ok;
  }
  bool Close() {
    const bool ok = handle_ == nullptr || CPLCloseZip(handle_) == CE_None;
    handle_ = nullptr;
    return ok;
  }

 private:
  void* handle_;
};

bool ReadFile(const fs::path& p, std::string* out) {
  std::ifstream in(p, std::ios::binary);
  out->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  return static_cast<bool>(in) || in.eof();
}

// doc.kml first (Google Earth opens the first .kml of a KMZ), then each tile's KML and PNG.
bool FillZip(Zip* zip, const std::string& dir, const std::set<TileKey>& tiles, int min_zoom, std::string* error) {
  std::string doc = kHead + std::string("<name>uavmosaic</name>\n");
  for (const TileKey& t : tiles)
    if (std::get<0>(t) == min_zoom) doc += Link(t, Name(t) + ".kml");
  doc += kTail;
  if (!zip->Add("doc.kml", doc.data(), doc.size(), true)) {
    *error = std::string("KMZ: ") + CPLGetLastErrorMsg();
    return false;
  }
  std::string png;
  for (const TileKey& t : tiles) {
    const std::string kml = TileKml(t, tiles);
    if (!ReadFile(fs::path(dir) / (Name(t) + ".png"), &png)) {
      *error = "KMZ: cannot read tile " + Name(t);
      return false;
    }
    if (!zip->Add(Name(t) + ".kml", kml.data(), kml.size(), true) ||
        !zip->Add(Name(t) + ".png", png.data(), png.size(), false)) {
      *error = std::string("KMZ: ") + CPLGetLastErrorMsg();
      return false;
    }
  }
  return true;
}

}  // namespace

bool WriteKmz(const std::string& tiles_dir, const TileSet& set, const std::string& kmz, std::string* error) {
  const std::set<TileKey> tiles = ListTiles(tiles_dir, set);
  if (!set.geographic || tiles.empty()) {
    *error = "KMZ: no web-mercator tiles in " + tiles_dir;
    return false;
  }
  std::string part = kmz;
  part.insert(part.size() - std::min<size_t>(part.size(), 4), ".part");  // mosaic.part.kmz
  std::remove(part.c_str());
  CPLErrorReset();
  Zip zip(part);
  bool ok = zip.ok() && FillZip(&zip, tiles_dir, tiles, set.min_zoom, error);
  if (!zip.ok()) *error = "KMZ: cannot create " + part + ": " + CPLGetLastErrorMsg();
  if (!zip.Close() && ok) {
    *error = "KMZ: cannot finish " + part;
    ok = false;
  }
  if (!ok) {
    std::remove(part.c_str());
    return false;
  }
  std::error_code ec;
  fs::rename(part, kmz, ec);
  if (ec) *error = "cannot rename " + part + " to " + kmz + ": " + ec.message();
  return !ec;
}

}  // namespace uavm
