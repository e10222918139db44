#include "core/sfm/cloud_and_dsm.h"

#include <gdal_alg.h>
#include <gdal_priv.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <sstream>

namespace uavm::sfm {

bool WritePly(const std::string& path, const std::vector<CloudPoint>& points, std::string* error) {
  std::ofstream out(path, std::ios::binary);
  if (!out) {
    *error = "cannot write " + path;
    return false;
  }
  out << "ply\nformat binary_little_endian 1.0\ncomment uavmosaic-ground\nelement vertex " << points.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
      << "property uchar blue\nend_header\n";
  static_assert(std::endian::native == std::endian::little, "PLY writer assumes a little-endian host");
  std::vector<char> buf(points.size() * 15);
  char* p = buf.data();
  for (const auto& pt : points) {
    std::memcpy(p, &pt.xyz[0], 12);
    p[12] = static_cast<char>(pt.bgr[2]);
    p[13] = static_cast<char>(pt.bgr[1]);
    p[14] = static_cast<char>(pt.bgr[0]);
    p += 15;
  }
  out.write(buf.data(), static_cast<std::streamsize>(buf.size()));
  out.close();
  if (!out) {
    *error = "write error on " + path;
    return false;
  }
  return true;
}

bool ReadPly(const std::string& path, std::vector<CloudPoint>* points, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot open " + path;
    return false;
  }
  std::string line;
  std::getline(in, line);
  if (line != "ply") {
    *error = "not a PLY file";
    return false;
  }
  size_t n = 0;
  std::vector<std::string> props;
  bool binary_le = false;
  while (std::getline(in, line)) {
    if (line == "end_header") break;
    std::istringstream s(line);
    std::string w;
    s >> w;
    if (w == "format") {
      std::string f;
      s >> f;
      binary_le = f == "binary_little_endian";
    } else if (w == "element") {
      std::string name;
      s >> name >> n;
      if (name != "vertex") {
        *error = "unexpected element " + name;
        return false;
      }
    } else if (w == "property") {
      std::string type, name;
      s >> type >> name;
      props.push_back(type + " " + name);
    }
  }
  const std::vector<std::string> expected = {"float x", "float y", "float z", "uchar red", "uchar green", "uchar blue"};
  if (!binary_le || props != expected) {
    *error = "PLY is not binary_little_endian with x y z float, red green blue uchar";
    return false;
  }
  std::vector<char> buf(n * 15);
  in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
  if (static_cast<size_t>(in.gcount()) != buf.size()) {
    *error = "PLY truncated";
    return false;
  }
  points->resize(n);
  for (size_t i = 0; i < n; ++i) {
    const char* p = buf.data() + i * 15;
    std::memcpy(&(*points)[i].xyz[0], p, 12);
    (*points)[i].bgr = cv::Vec3b(static_cast<uchar>(p[14]), static_cast<uchar>(p[13]), static_cast<uchar>(p[12]));
  }
  return true;
}

cv::Mat1f RasterizeMedian(const std::vector<CloudPoint>& points, const DsmGrid& grid, float nodata) {
  std::vector<std::vector<float>> cells(static_cast<size_t>(grid.width) * static_cast<size_t>(grid.height));
  for (const auto& p : points) {
    const int col = static_cast<int>(std::floor((p.xyz[0] - grid.x0) / grid.cell));
    const int row = static_cast<int>(std::floor((grid.y0 - p.xyz[1]) / grid.cell));
    if (col < 0 || row < 0 || col >= grid.width || row >= grid.height) continue;
    cells[static_cast<size_t>(row) * static_cast<size_t>(grid.width) + static_cast<size_t>(col)].push_back(p.xyz[2]);
  }
  cv::Mat1f dsm(grid.height, grid.width, nodata);
  for (int r = 0; r < grid.height; ++r) {
    for (int c = 0; c < grid.width; ++c) {
      auto& v = cells[static_cast<size_t>(r) * static_cast<size_t>(grid.width) + static_cast<size_t>(c)];
      if (v.empty()) continue;
      std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
      dsm(r, c) = v[v.size() / 2];
    }
  }
  return dsm;
}

bool WriteDsmGeoTiff(const std::string& path, const cv::Mat1f& dsm, const DsmGrid& grid, const Eigen::Vector2d& offset,
                     const std::string& wkt, float nodata, std::string* error) {
  GDALAllRegister();
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
  if (!drv) {
    *error = "GDAL has no GTiff driver";
    return false;
  }
  char** opts = nullptr;
  opts = CSLSetNameValue(opts, "COMPRESS", "DEFLATE");
  opts = CSLSetNameValue(opts, "TILED", "YES");
  GDALDataset* ds = drv->Create(path.c_str(), dsm.cols, dsm.rows, 1, GDT_Float32, opts);
  CSLDestroy(opts);
  if (!ds) {
    *error = "GDAL cannot create " + path;
    return false;
  }
  double gt[6] = {grid.x0 + offset.x(), grid.cell, 0.0, grid.y0 + offset.y(), 0.0, -grid.cell};
  ds->SetGeoTransform(gt);
  if (!wkt.empty()) ds->SetProjection(wkt.c_str());
  GDALRasterBand* band = ds->GetRasterBand(1);
  band->SetNoDataValue(nodata);
  cv::Mat1f data = dsm.isContinuous() ? dsm : dsm.clone();
  const CPLErr err =
      band->RasterIO(GF_Write, 0, 0, dsm.cols, dsm.rows, data.ptr<float>(), dsm.cols, dsm.rows, GDT_Float32, 0, 0);
  GDALClose(ds);
  if (err != CE_None) {
    *error = "GDAL write error on " + path;
    return false;
  }
  return true;
}

cv::Mat1b FillDsmHoles(cv::Mat1f* dsm, float nodata, int max_distance_cells) {
  cv::Mat1b provenance(dsm->size(), uchar{0});
  provenance.setTo(255, *dsm != nodata);
  if (dsm->empty() || cv::countNonZero(provenance) == 0) return provenance;
  GDALAllRegister();
  GDALDriver* mem = GetGDALDriverManager()->GetDriverByName("MEM");
  if (mem == nullptr) return provenance;
  GDALDataset* ds = mem->Create("", dsm->cols, dsm->rows, 1, GDT_Float32, nullptr);
  if (ds == nullptr) return provenance;
  GDALRasterBand* band = ds->GetRasterBand(1);
  band->SetNoDataValue(nodata);
  cv::Mat1f data = dsm->isContinuous() ? *dsm : dsm->clone();
  bool ok = band->RasterIO(GF_Write, 0, 0, dsm->cols, dsm->rows, data.ptr<float>(), dsm->cols, dsm->rows, GDT_Float32,
                           0, 0) == CE_None;
  ok = ok && GDALFillNodata(band, band->GetMaskBand(), max_distance_cells, 0, 1, nullptr, nullptr, nullptr) == CE_None;
  cv::Mat1f filled(dsm->size());
  ok = ok && band->RasterIO(GF_Read, 0, 0, dsm->cols, dsm->rows, filled.ptr<float>(), dsm->cols, dsm->rows, GDT_Float32,
                            0, 0) == CE_None;
  GDALClose(ds);
  if (!ok) return provenance;
  provenance.setTo(128, (provenance == 0) & (filled != nodata));
  *dsm = filled;
  return provenance;
}

bool WriteDsmFillMask(const std::string& path, const cv::Mat1b& provenance, const DsmGrid& grid,
                      const Eigen::Vector2d& offset, const std::string& wkt, std::string* error) {
  GDALAllRegister();
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
  char** opts = CSLSetNameValue(nullptr, "COMPRESS", "DEFLATE");
  GDALDataset* ds =
      drv != nullptr ? drv->Create(path.c_str(), provenance.cols, provenance.rows, 1, GDT_Byte, opts) : nullptr;
  CSLDestroy(opts);
  if (ds == nullptr) {
    *error = "GDAL cannot create " + path;
    return false;
  }
  double gt[6] = {grid.x0 + offset.x(), grid.cell, 0.0, grid.y0 + offset.y(), 0.0, -grid.cell};
  ds->SetGeoTransform(gt);
  if (!wkt.empty()) ds->SetProjection(wkt.c_str());
  cv::Mat1b flag(provenance.size(), uchar{255});
  flag.setTo(1, provenance == 128);
  flag.setTo(0, provenance == 255);
  GDALRasterBand* band = ds->GetRasterBand(1);
  band->SetNoDataValue(255);
  band->SetDescription("filled (1) or measured (0)");
  const CPLErr err =
      band->RasterIO(GF_Write, 0, 0, flag.cols, flag.rows, flag.data, flag.cols, flag.rows, GDT_Byte, 0, 0);
  GDALClose(ds);
  if (err != CE_None) {
    *error = "GDAL write error on " + path;
    return false;
  }
  return true;
}

cv::Mat RenderCloudTopView(const std::vector<CloudPoint>& points, int long_side) {
  if (points.empty()) return cv::Mat(64, 64, CV_8UC3, cv::Scalar::all(0));
  float x0 = points[0].xyz[0], x1 = x0, y0 = points[0].xyz[1], y1 = y0;
  for (const auto& p : points) {
    x0 = std::min(x0, p.xyz[0]);
    x1 = std::max(x1, p.xyz[0]);
    y0 = std::min(y0, p.xyz[1]);
    y1 = std::max(y1, p.xyz[1]);
  }
  const double span = std::max({static_cast<double>(x1 - x0), static_cast<double>(y1 - y0), 1e-9});
  // Raster at about the cloud's own point spacing (so that it has no holes), then scaled to long_side.
  const double area = std::max(1e-9, static_cast<double>(x1 - x0) * static_cast<double>(y1 - y0));
  const double spacing = 1.3 * std::sqrt(area / static_cast<double>(points.size()));
  const int n = std::clamp(static_cast<int>(span / spacing), 16, 4 * long_side);
  const double s = (n - 1) / span;
  const int w = std::max(1, static_cast<int>((x1 - x0) * s) + 1), h = std::max(1, static_cast<int>((y1 - y0) * s) + 1);
  cv::Mat img(h, w, CV_8UC3, cv::Scalar::all(0));
  cv::Mat1f zbuf(h, w, -1e30f);
  for (const auto& p : points) {
    const int c = static_cast<int>((p.xyz[0] - x0) * s), r = static_cast<int>((y1 - p.xyz[1]) * s);
    if (p.xyz[2] > zbuf(r, c)) {
      zbuf(r, c) = p.xyz[2];
      img.at<cv::Vec3b>(r, c) = p.bgr;
    }
  }
  const double f = static_cast<double>(long_side) / std::max(w, h);
  cv::Mat out;
  cv::resize(img, out, cv::Size(), f, f, f < 1 ? cv::INTER_AREA : cv::INTER_NEAREST);
  return out;
}

cv::Mat RenderDsm(const cv::Mat1f& dsm, float nodata, int long_side) {
  cv::Mat1b valid;
  cv::compare(dsm, nodata, valid, cv::CMP_NE);
  std::vector<float> v;
  for (int r = 0; r < dsm.rows; ++r)
    for (int c = 0; c < dsm.cols; ++c)
      if (valid(r, c)) v.push_back(dsm(r, c));
  cv::Mat out(dsm.size(), CV_8UC3, cv::Scalar::all(0));
  if (!v.empty()) {
    std::sort(v.begin(), v.end());
    const float lo = v[v.size() / 50], hi = v[v.size() - 1 - v.size() / 50];
    cv::Mat1b gray(dsm.size(), uchar(0));
    for (int r = 0; r < dsm.rows; ++r)
      for (int c = 0; c < dsm.cols; ++c)
        if (valid(r, c)) gray(r, c) = cv::saturate_cast<uchar>(255.0 * (dsm(r, c) - lo) / std::max(1e-6f, hi - lo));
    cv::applyColorMap(gray, out, cv::COLORMAP_VIRIDIS);
    out.setTo(cv::Scalar::all(0), ~valid);
  }
  const double s = static_cast<double>(long_side) / std::max(dsm.cols, dsm.rows);
  cv::Mat resized;
  cv::resize(out, resized, cv::Size(), s, s, s < 1 ? cv::INTER_AREA : cv::INTER_NEAREST);
  return resized;
}

}  // namespace uavm::sfm
