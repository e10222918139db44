#include "core/mosaic/gdal_writer.h"

#include <gdal_priv.h>

#include <opencv2/imgproc.hpp>
#include <vector>

namespace uavm {

struct GdalTiffWriter::Impl {
  GDALDataset* ds = nullptr;
  cv::Size canvas;
};

GdalTiffWriter::GdalTiffWriter() : impl_(std::make_unique<Impl>()) {}

GdalTiffWriter::~GdalTiffWriter() {
  if (impl_->ds != nullptr) GDALClose(impl_->ds);
}

bool GdalTiffWriter::Open(const std::string& path, cv::Size canvas, int block_size, std::string* error) {
  GDALAllRegister();
  CPLSetConfigOption("CPL_LOG_ERRORS", "OFF");
  // GDAL's block cache defaults to 5 % of RAM; tiles are written once, so a small cache is enough.
  GDALSetCacheMax64(int64_t{64} << 20);
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
  impl_->ds = driver->Create(path.c_str(), canvas.width, canvas.height, 4, GDT_Byte, opts);
  CSLDestroy(opts);
  if (impl_->ds == nullptr) {
    *error = "cannot create " + path + ": " + CPLGetLastErrorMsg();
    return false;
  }
  impl_->canvas = canvas;
  return true;
}

bool GdalTiffWriter::Write(const cv::Mat& image, const cv::Mat& mask, cv::Point tl, std::string* error) {
  if (impl_->ds == nullptr) return false;
  cv::Mat rgba;
  cv::Mat rgb;
  cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
  std::vector<cv::Mat> planes;
  cv::split(rgb, planes);
  planes.push_back(mask);
  cv::merge(planes, rgba);
  int bands[4] = {1, 2, 3, 4};
  const CPLErr err = impl_->ds->RasterIO(GF_Write, tl.x, tl.y, image.cols, image.rows, rgba.data, image.cols,
                                         image.rows, GDT_Byte, 4, bands, 4, static_cast<GSpacing>(rgba.step[0]), 1,
                                         nullptr);
  if (err != CE_None) {
    *error = std::string("GDAL write failed: ") + CPLGetLastErrorMsg();
    return false;
  }
  return true;
}

bool GdalTiffWriter::Close(bool build_overviews, std::string* error) {
  if (impl_->ds == nullptr) return true;
  bool ok = true;
  if (build_overviews) {
    std::vector<int> levels;
    for (int f = 2; std::max(impl_->canvas.width, impl_->canvas.height) / f >= 256; f *= 2) levels.push_back(f);
    if (!levels.empty() &&
        impl_->ds->BuildOverviews("AVERAGE", static_cast<int>(levels.size()), levels.data(), 0, nullptr, nullptr,
                                  nullptr) != CE_None) {
      *error = std::string("overviews failed: ") + CPLGetLastErrorMsg();
      ok = false;
    }
  }
  impl_->ds->FlushCache();
  if (CPLGetLastErrorType() == CE_Failure && ok) {
    *error = std::string("GDAL: ") + CPLGetLastErrorMsg();
    ok = false;
  }
  GDALClose(impl_->ds);
  impl_->ds = nullptr;
  return ok;
}

}  // namespace uavm
