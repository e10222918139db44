#include "core/mosaic/gdal_writer.h"

#include <gdal_priv.h>

#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace uavm {

// Pixels written so far into each block of one level (full resolution or an overview): a block goes to the file,
// and out of GDAL's cache, once all of its pixels are written.
struct BlockFill {
  cv::Size block;
  cv::Size level;
  int blocks_across = 0;
  std::vector<int64_t> written;  // per block, row-major
};

struct GdalTiffWriter::Impl {
  GDALDataset* ds = nullptr;
  cv::Size canvas;
  std::vector<int> overview_factors;  // written tile by tile, alongside the full resolution
  std::vector<BlockFill> fill;        // [0] full resolution, [1 + i] overview i
  std::string path;                   // final name; GDAL writes path + ".part"
};

namespace {

GDALRasterBand* LevelBand(GDALDataset* ds, int band, int overview) {
  GDALRasterBand* b = ds->GetRasterBand(band);
  return overview >= 0 && b != nullptr ? b->GetOverview(overview) : b;
}

BlockFill MakeBlockFill(GDALRasterBand* band) {
  BlockFill f;
  int bw = 0;
  int bh = 0;
  band->GetBlockSize(&bw, &bh);
  f.block = cv::Size(bw, bh);
  f.level = cv::Size(band->GetXSize(), band->GetYSize());
  f.blocks_across = (f.level.width + bw - 1) / bw;
  const int blocks_down = (f.level.height + bh - 1) / bh;
  f.written.assign(static_cast<size_t>(f.blocks_across) * static_cast<size_t>(blocks_down), 0);
  return f;
}

// Counts the region's pixels into its blocks and writes every block it completes to the file, dropping it from GDAL's
// cache (all four bands: the file interleaves them, and the first band's flush takes the others' pixels along). A
// block is complete once written whole, so it is compressed once; without this GDAL kept every block until Close,
// the whole mosaic and its overviews up to the cache's cap, a compose line that grew with the canvas.
bool ReleaseCompleteBlocks(GDALDataset* ds, int overview, cv::Rect region, BlockFill* fill, std::string* error) {
  const cv::Rect level(cv::Point(0, 0), fill->level);
  region &= level;
  if (region.empty()) return true;
  const int bw = fill->block.width;
  const int bh = fill->block.height;
  for (int by = region.y / bh; by <= (region.br().y - 1) / bh; ++by) {
    for (int bx = region.x / bw; bx <= (region.br().x - 1) / bw; ++bx) {
      const cv::Rect block = cv::Rect(bx * bw, by * bh, bw, bh) & level;
      int64_t& written =
          fill->written[static_cast<size_t>(by) * static_cast<size_t>(fill->blocks_across) + static_cast<size_t>(bx)];
      written += (block & region).area();
      if (written < block.area()) continue;
      for (int b = 1; b <= 4; ++b) {
        if (LevelBand(ds, b, overview)->FlushBlock(bx, by, TRUE) != CE_None) {
          *error = std::string("GDAL write failed (disk full?): ") + CPLGetLastErrorMsg();
          return false;
        }
      }
    }
  }
  return true;
}

bool WriteRgba(GDALDataset* ds, int overview, const cv::Mat& image, const cv::Mat& mask, cv::Point tl,
               std::string* error) {
  cv::Mat rgb;
  cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
  cv::Mat rgba;
  cv::cvtColor(rgb, rgba, cv::COLOR_RGB2RGBA);
  cv::insertChannel(mask, rgba, 3);
  CPLErr err = CE_None;
  for (int b = 1; b <= 4 && err == CE_None; ++b) {
    GDALRasterBand* band = LevelBand(ds, b, overview);
    if (band == nullptr) {
      *error = "GDAL: missing overview band";
      return false;
    }
    err = band->RasterIO(GF_Write, tl.x, tl.y, image.cols, image.rows, rgba.data + (b - 1), image.cols, image.rows,
                         GDT_Byte, 4, static_cast<GSpacing>(rgba.step[0]), nullptr);
  }
  if (err != CE_None) {
    *error = std::string("GDAL write failed (disk full?): ") + CPLGetLastErrorMsg();
    return false;
  }
  return true;
}

}  // namespace

GdalTiffWriter::GdalTiffWriter() : impl_(std::make_unique<Impl>()) {}

GdalTiffWriter::~GdalTiffWriter() {
  if (impl_->ds != nullptr) {  // not closed: an error path; the partial file goes
    GDALClose(impl_->ds);
    std::remove((impl_->path + ".part").c_str());
  }
}

bool GdalTiffWriter::Open(const std::string& path, cv::Size canvas, int block_size, int tile_size, bool overviews,
                          int cache_mib, std::string* error) {
  GDALAllRegister();
  CPLSetConfigOption("CPL_LOG_ERRORS", "OFF");
  // GDAL's block cache defaults to 5 % of RAM; tiles are written once, so a small cache is enough.
  GDALSetCacheMax64(int64_t{cache_mib} << 20);
  GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GTiff");
  if (driver == nullptr) {
    *error = "GDAL has no GTiff driver";
    return false;
  }
  const std::string block = std::to_string(block_size);
  char** opts = nullptr;
  opts = CSLSetNameValue(opts, "TILED", "YES");
  opts = CSLSetNameValue(opts, "BLOCKXSIZE", block.c_str());
  opts = CSLSetNameValue(opts, "BLOCKYSIZE", block.c_str());
  // The file is an intermediate (its readers: the COG copy and the web tiles, both through GDAL): ZSTD at level 1
  // compresses brighton_beach's mosaic in ~1/3 of the CPU of DEFLATE at level 1 for 9 % more bytes and decodes faster
  // (products 1.94 -> 1.67 s); blocks the compositor never wrote stay absent (SPARSE_OK), read back as transparent.
  opts = CSLSetNameValue(opts, "COMPRESS", "ZSTD");
  opts = CSLSetNameValue(opts, "ZSTD_LEVEL", "1");
  opts = CSLSetNameValue(opts, "PREDICTOR", "2");
  opts = CSLSetNameValue(opts, "SPARSE_OK", "TRUE");
  opts = CSLSetNameValue(opts, "BIGTIFF", "IF_SAFER");
  opts = CSLSetNameValue(opts, "PHOTOMETRIC", "RGB");
  opts = CSLSetNameValue(opts, "ALPHA", "YES");
  impl_->path = path;
  const std::string part = path + ".part";
  impl_->ds = driver->Create(part.c_str(), canvas.width, canvas.height, 4, GDT_Byte, opts);
  CSLDestroy(opts);
  if (impl_->ds == nullptr) {
    *error = "cannot create " + part + ": " + CPLGetLastErrorMsg();
    return false;
  }
  impl_->canvas = canvas;
  if (overviews) {
    // Levels down to ~256 px, each a divisor of the tile size so that tiles map to whole overview blocks.
    for (int f = 2; f <= tile_size && std::max(canvas.width, canvas.height) / f >= 256; f *= 2)
      impl_->overview_factors.push_back(f);
    if (!impl_->overview_factors.empty() &&
        impl_->ds->BuildOverviews("NONE", static_cast<int>(impl_->overview_factors.size()),
                                  impl_->overview_factors.data(), 0, nullptr, nullptr, nullptr) != CE_None) {
      *error = std::string("cannot create overviews: ") + CPLGetLastErrorMsg();
      return false;
    }
  }
  for (int level = -1; level < static_cast<int>(impl_->overview_factors.size()); ++level) {
    GDALRasterBand* band = LevelBand(impl_->ds, 1, level);
    if (band == nullptr) {
      *error = "GDAL: missing overview band";
      return false;
    }
    impl_->fill.push_back(MakeBlockFill(band));
  }
  return true;
}

bool GdalTiffWriter::Write(const cv::Mat& image, const cv::Mat& mask, cv::Point tl, std::string* error) {
  if (impl_->ds == nullptr) return false;
  if (!WriteRgba(impl_->ds, -1, image, mask, tl, error) ||
      !ReleaseCompleteBlocks(impl_->ds, -1, cv::Rect(tl, image.size()), &impl_->fill[0], error))
    return false;
  // Overviews from the tile in hand: tiles start at multiples of every factor, so each level gets exact blocks and
  // nothing is read back at the end.
  for (size_t level = 0; level < impl_->overview_factors.size(); ++level) {
    const int f = impl_->overview_factors[level];
    const cv::Size ov((impl_->canvas.width + f - 1) / f, (impl_->canvas.height + f - 1) / f);
    const cv::Point otl(tl.x / f, tl.y / f);
    const cv::Size osz(std::min((image.cols + f - 1) / f, ov.width - otl.x),
                       std::min((image.rows + f - 1) / f, ov.height - otl.y));
    if (osz.width <= 0 || osz.height <= 0) continue;
    cv::Mat small;
    cv::Mat small_mask;
    cv::resize(image, small, osz, 0, 0, cv::INTER_AREA);
    cv::resize(mask, small_mask, osz, 0, 0, cv::INTER_AREA);
    if (!WriteRgba(impl_->ds, static_cast<int>(level), small, small_mask, otl, error) ||
        !ReleaseCompleteBlocks(impl_->ds, static_cast<int>(level), cv::Rect(otl, osz), &impl_->fill[level + 1], error))
      return false;
  }
  return true;
}

void GdalTiffWriter::SetGeoreference(const std::array<double, 6>& geo_transform, const std::string& crs_wkt) {
  if (impl_->ds == nullptr) return;
  std::array<double, 6> gt = geo_transform;
  impl_->ds->SetGeoTransform(gt.data());
  if (!crs_wkt.empty()) impl_->ds->SetProjection(crs_wkt.c_str());
}

bool GdalTiffWriter::Close(std::string* error) {
  if (impl_->ds == nullptr) return true;
  bool ok = true;
  CPLErrorReset();
  impl_->ds->FlushCache();
  if (CPLGetLastErrorType() == CE_Failure) {
    *error = std::string("GDAL: ") + CPLGetLastErrorMsg();
    ok = false;
  }
  // GDALClose writes what the cache still holds (overviews, the directory): its errors count too.
  GDALClose(impl_->ds);
  impl_->ds = nullptr;
  if (CPLGetLastErrorType() == CE_Failure && ok) {
    *error = std::string("GDAL: ") + CPLGetLastErrorMsg();
    ok = false;
  }
  const std::string part = impl_->path + ".part";
  if (!ok) {
    std::remove(part.c_str());
    return false;
  }
  if (std::rename(part.c_str(), impl_->path.c_str()) != 0) {
    *error = "cannot rename " + part + " to " + impl_->path;
    std::remove(part.c_str());
    return false;
  }
  return true;
}

}  // namespace uavm
