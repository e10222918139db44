// The orthophoto's files against the truth of a synthetic relief survey (tools/relief_flight.h), with the survey's
// exact cameras and its true DSM: what is left is the orthophoto's own error (projection, z-buffer, blending, the
// COG's georeferencing), measured the way bench/ground_relief.sh measures the whole chain.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "core/sfm/ortho_files.h"
#include "tools/relief_flight.h"

namespace uavm {
namespace {

namespace fs = std::filesystem;

TEST(ReliefOrtho, ExactCamerasAndTrueDsmGiveAnOrthophotoOnTheTruth) {
  const fs::path dir = fs::temp_directory_path() / ("uavm_relief_ortho_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  tools::ReliefFlightOptions o;
  o.half_extent_m = 30.0;
  o.buildings = 3;
  o.trees = 6;
  o.width = 500;
  o.height = 375;
  o.altitude_m = 50.0;
  nlohmann::json flight;
  std::string error;
  ASSERT_TRUE(tools::WriteReliefFlight(o, dir.string(), &flight, &error)) << error;
  // The survey's cameras as a reconstruction, in the scene's local metres (the map's = local + the UTM offset).
  std::ifstream in(dir / "truth/flight.json");
  const auto truth = nlohmann::json::parse(in);
  sfm::Reconstruction rec;
  sfm::Camera cam;
  cam.width = o.width;
  cam.height = o.height;
  cam.fx = cam.fy = truth["camera"]["fx"].get<double>();
  cam.cx = truth["camera"]["cx"].get<double>();
  cam.cy = truth["camera"]["cy"].get<double>();
  cam.k1 = o.k1;
  cam.k2 = o.k2;
  rec.cameras = {cam};
  std::vector<std::string> paths;
  for (const auto& p : truth["poses"]) {
    sfm::Image im;
    im.name = p["name"].get<std::string>();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) im.pose.R(r, c) = p["R"][static_cast<size_t>(3 * r + c)].get<double>();
    im.pose.c =
        Eigen::Vector3d(p["centre"][0].get<double>(), p["centre"][1].get<double>(), p["centre"][2].get<double>());
    rec.images.push_back(im);
    paths.push_back((dir / "images" / im.name).string());
  }
  // The true DSM and DTM (heights above the datum) on their own grid.
  GDALAllRegister();
  const auto read = [&](const char* name, cv::Mat1f* out, double* gt) {
    auto* ds = static_cast<GDALDataset*>(GDALOpen((dir / "truth" / name).c_str(), GA_ReadOnly));
    ASSERT_NE(ds, nullptr) << name;
    ds->GetGeoTransform(gt);
    *out = cv::Mat1f(ds->GetRasterYSize(), ds->GetRasterXSize());
    ASSERT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, out->cols, out->rows, out->data, out->cols, out->rows,
                                             GDT_Float32, 0, 0, nullptr),
              CE_None);
    GDALClose(ds);
    *out -= static_cast<float>(o.datum_m);
  };
  double gt[6], gt_dtm[6];
  cv::Mat1f dsm, dtm;
  ASSERT_NO_FATAL_FAILURE(read("dsm.tif", &dsm, gt));
  ASSERT_NO_FATAL_FAILURE(read("dtm.tif", &dtm, gt_dtm));
  ASSERT_EQ(dtm.size(), dsm.size());
  sfm::DsmGrid grid;
  grid.x0 = gt[0] - o.easting;
  grid.y0 = gt[3] - o.northing;
  grid.cell = gt[1];
  grid.width = dsm.cols;
  grid.height = dsm.rows;
  OGRSpatialReference srs;
  srs.importFromEPSG(32615);
  char* wkt = nullptr;
  srs.exportToWkt(&wkt);
  const std::string crs(wkt);
  CPLFree(wkt);
  // Twice: each cell from its most nadir view, then each standing object (a building, a tree: the DSM above the DTM)
  // taken whole from one view, so that no seam cuts it.
  for (const bool objects : {false, true}) {
    sfm::OrthoOptions options;
    options.gsd = grid.cell;
    options.seams_off_objects = objects;
    sfm::OrthoFiles files;
    files.cog = (dir / (objects ? "ortho_objects.tif" : "ortho_cells.tif")).string();
    sfm::OrthoFilesReport report;
    ASSERT_TRUE(sfm::WriteOrthophoto(rec, paths, dsm, dtm, grid, -9999.0f, Eigen::Vector2d(o.easting, o.northing), crs,
                                     options, files, {}, &report, &error))
        << error;
    nlohmann::json measured;
    tools::ProductPaths products;
    products.ortho = files.cog;
    ASSERT_TRUE(tools::CompareWithTruth(dir.string(), products, &measured, &error)) << error;
    const auto& m = measured["ortho"];
    const auto& r = report.ortho;
    std::printf(
        "exact cameras, %s: offset %s GSD, all %s, roofs %s; %d standing objects (%d taken whole), %zu seam "
        "cells, %zu on standing objects\n",
        objects ? "objects whole" : "per cell", m["offset_gsd"].dump().c_str(), m["all"].dump().c_str(),
        m["roofs"].dump().c_str(), r.objects, r.objects_taken_whole, r.seam_cells, r.seam_cells_on_objects);
    EXPECT_GT(m["all"]["patches"].get<int>(), 40);
    EXPECT_LT(std::hypot(m["offset_gsd"][0].get<double>(), m["offset_gsd"][1].get<double>()), 0.25);
    EXPECT_LT(m["all"]["rms_gsd"].get<double>(), 0.5);
    EXPECT_GT(r.seam_cells, 100u);
    EXPECT_GE(r.objects, o.buildings);  // the buildings (trees may merge with them or each other)
    if (!objects) {
      EXPECT_EQ(r.objects_taken_whole, 0);
      EXPECT_GT(r.seam_cells_on_objects, 0u);  // per cell the seams cross roofs: the test can fail
    } else {
      EXPECT_GE(r.objects_taken_whole, r.objects - 1);
      EXPECT_LT(static_cast<double>(r.seam_cells_on_objects), 0.02 * static_cast<double>(r.seam_cells));
    }
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace uavm
