#include "core/mosaic/gdal_writer.h"

#include <gdal_priv.h>

#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace uavm {

struct GdalTiffWriter::Impl {
  GDALDataset* ds = nullptr;
  cv::Size canvas;
  std::vector<int> overview_factors;  // written tile by tile, alongside the full resolution
  std::string path;                   // final name; GDAL writes path + ".part"
};

namespace {

bool WriteRgba(GDALDataset* ds, int overview, const cv::Mat& image, const cv::Mat& mask, cv::Point tl,
               std::string* error) {
  cv::Mat rgb;
  cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
  cv::Mat rgba;
  cv::cvtColor(rgb, rgba, cv::COLOR_RGB2RGBA);
  cv::insertChannel(mask, rgba, 3);
  CPLErr err = CE_None;
  for (int b = 1; b <= 4 && err == CE_None; ++b) {
    GDALRasterBand* band = ds->GetRasterBand(b);
    if (overview >= 0) band = band->GetOverview(overview);
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
  opts = CSLSetNameValue(opts, "COMPRESS", "DEFLATE");
  opts = CSLSetNameValue(opts, "ZLEVEL", "1");  // fast: the onboard CPU has better things to do
  opts = CSLSetNameValue(opts, "PREDICTOR", "2");
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
  return true;
}

bool GdalTiffWriter::Write(const cv::Mat& image, const cv::Mat& mask, cv::Point tl, std::string* error) {
  if (impl_->ds == nullptr) return false;
  if (!WriteRgba(impl_->ds, -1, image, mask, tl, error)) return false;
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
    if (!WriteRgba(impl_->ds, static_cast<int>(level), small, small_mask, otl, error)) return false;
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
