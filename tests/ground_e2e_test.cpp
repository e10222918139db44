// End to end: uavmosaic-onboard on brighton_beach_small into a temp session, then uavmosaic-ground on it; every
// product is checked on disk.
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/colmap_io.h"
#include "tests/browser_shot.h"
#include "tests/test_env.h"

namespace uavm::sfm {
namespace {

namespace fs = std::filesystem;

int RunCommand(const std::string& cmd) {
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// Under emulation (tests/test_env.h) the ground tool works on fewer keypoints and fewer, coarser stereo pairs: the
// same stages on less work (SIFT and dense matching run ~40x slower under qemu-user).
std::string GroundEmulationArgs() {
  return test::Emulated() ? " --max-dense-pairs 10 --dense-scale 0.5 --feature-scale 0.5 --max-features 4000" : "";
}

std::string ReadText(const fs::path& path) {
  std::stringstream ss;
  ss << std::ifstream(path).rdbuf();
  return ss.str();
}

// COLMAP itself reads our model: model_analyzer's counts, and model_converter to its binary format and back.
void CheckColmapReads(const fs::path& sparse, size_t images, size_t points, const fs::path& tmp) {
  ASSERT_EQ(RunCommand("command -v colmap >/dev/null"), 0) << "colmap is not installed (scripts/setup.sh installs it)";
  ASSERT_EQ(
      RunCommand("colmap model_analyzer --path " + sparse.string() + " >" + (tmp / "analyzer.txt").string() + " 2>&1"),
      0);
  const std::string a = ReadText(tmp / "analyzer.txt");
  auto figure = [&](const std::string& key) {
    const size_t at = a.find(key + ": ");
    return at == std::string::npos ? -1.0 : std::atof(a.c_str() + at + key.size() + 2);
  };
  EXPECT_EQ(figure("Registered images"), static_cast<double>(images)) << a;
  EXPECT_EQ(figure("Points"), static_cast<double>(points)) << a;
  EXPECT_GT(figure("Mean reprojection error"), 0.0) << a;
  EXPECT_LT(figure("Mean reprojection error"), 1.0) << a;
  const fs::path bin = tmp / "colmap_bin", txt = tmp / "colmap_txt";
  fs::create_directories(bin);
  fs::create_directories(txt);
  ASSERT_EQ(RunCommand("colmap model_converter --input_path " + sparse.string() + " --output_path " + bin.string() +
                       " --output_type BIN >/dev/null 2>&1 && colmap model_converter --input_path " + bin.string() +
                       " --output_path " + txt.string() + " --output_type TXT >/dev/null 2>&1"),
            0);
  EXPECT_GT(fs::file_size(bin / "points3D.bin"), 1000u);
  Reconstruction back;
  std::string err;
  ASSERT_TRUE(ReadColmapText(txt.string(), &back, &err)) << err;
  EXPECT_EQ(back.images.size(), images);
  EXPECT_EQ(back.points.size(), points);
}

// Pseudo ground control points from a finished run: well-spread sparse points seen in three or more frames, their
// georeferenced positions re-expressed in NAD83 / UTM 15N (EPSG:26915, another CRS than the run's WGS 84 / UTM 15N) and
// their keypoints as clicks. Their "survey" comes from the model itself, so this checks the path end to end (parsing,
// CRS, adjustment, outputs in the GCPs' CRS), not the accuracy (tests/sfm_gcp_test.cpp does that against a truth).
std::string WritePseudoGcps(const fs::path& out, const fs::path& path) {
  Reconstruction rec;
  std::string err;
  if (!ReadColmapText((out / "sparse").string(), &rec, &err)) return err;
  std::ifstream js_in(out / "summary.json");
  const auto js = nlohmann::json::parse(js_in);
  const double ox = js["coordinates"]["ply_and_colmap_offset_xy"][0],
               oy = js["coordinates"]["ply_and_colmap_offset_xy"][1];
  std::vector<size_t> chosen;  // farthest-point sampling in x, y among points seen three or more times
  while (chosen.size() < 6) {
    size_t best = rec.points.size();
    double best_d = -1.0;
    for (size_t k = 0; k < rec.points.size(); ++k) {
      if (rec.points[k].track.size() < 3) continue;
      double d = 1e30;
      for (size_t c : chosen) d = std::min(d, (rec.points[k].X - rec.points[c].X).head<2>().norm());
      if (d > best_d) best_d = d, best = k;
    }
    if (best == rec.points.size()) return "too few points seen three times";
    chosen.push_back(best);
  }
  OGRSpatialReference wgs_utm, nad_utm;
  wgs_utm.importFromEPSG(32615);
  nad_utm.importFromEPSG(26915);
  wgs_utm.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  nad_utm.SetAxisMappingStrategy(OAMS_TRADITIONAL_GIS_ORDER);
  std::unique_ptr<OGRCoordinateTransformation> tr(OGRCreateCoordinateTransformation(&wgs_utm, &nad_utm));
  if (!tr) return "no transformation 32615 -> 26915";
  std::ofstream f(path);
  f << "EPSG:26915\n";
  for (size_t n = 0; n < chosen.size(); ++n) {
    const auto& p = rec.points[chosen[n]];
    double x = p.X.x() + ox, y = p.X.y() + oy;
    if (!tr->Transform(1, &x, &y)) return "transform failed";
    for (const auto& o : p.track) {
      const auto& im = rec.images[static_cast<size_t>(o.image)];
      const auto& kp = im.keypoints[static_cast<size_t>(o.feature)];
      char row[256];
      std::snprintf(row, sizeof row, "%.3f %.3f %.3f %.2f %.2f %s p%zu\n", x, y, p.X.z() + 180.0, kp.x(), kp.y(),
                    im.name.substr(7).c_str(), n);  // stored names are 000012_<original name>
      f << row;
    }
  }
  return "";
}

// The same session with the pseudo GCPs (two of them checkpoints): outputs in EPSG:26915, checkpoints on the model.
void CheckGcpRun(const fs::path& tmp, const fs::path& session, const fs::path& first_out) {
  const fs::path gcp = tmp / "gcp_list.txt", out = tmp / "ground_gcp";
  ASSERT_EQ(WritePseudoGcps(first_out, gcp), "");
  ASSERT_EQ(RunCommand(std::string(UAVM_GROUND_BIN) + " " + session.string() + " --out " + out.string() +
                       " --no-dense --gcp " + gcp.string() + " --checkpoints p4,p5" + GroundEmulationArgs() + " 2>" +
                       (tmp / "stderr_gcp.txt").string()),
            0);
  std::ifstream js_in(out / "summary.json");
  const auto js = nlohmann::json::parse(js_in);
  EXPECT_EQ(js["crs"].get<std::string>(), "EPSG:26915");
  const auto& g = js["gcp"];
  std::printf("gcp: control %s, checkpoints %s\n", g["control_rms"].dump().c_str(), g["checkpoint_rms"].dump().c_str());
  EXPECT_EQ(g["points"].size(), 6u);
  EXPECT_EQ(g["checkpoint_rms"]["points"].get<int>(), 2);
  EXPECT_LT(g["checkpoint_rms"]["total_gsd"].get<double>(), 3.0);
  EXPECT_LT(g["control_rms"]["total_gsd"].get<double>(), 3.0);
  GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen((out / "dsm.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  ASSERT_NE(ds->GetSpatialRef(), nullptr);
  EXPECT_STREQ(ds->GetSpatialRef()->GetAuthorityCode(nullptr), "26915");
  GDALClose(ds);
  // The same targets with every height 0 (a handheld GPS's file): horizontal control only, said in the log and the
  // summary, checkpoints still on the model horizontally.
  {
    std::ifstream in(gcp);
    std::ofstream flat(tmp / "gcp_no_heights.txt");
    std::string row;
    std::getline(in, row);
    flat << row << "\n";
    while (std::getline(in, row)) {
      std::istringstream fields(row);
      std::string x, y, z, rest;
      fields >> x >> y >> z;
      std::getline(fields, rest);
      flat << x << " " << y << " 0" << rest << "\n";
    }
  }
  const fs::path flat_out = tmp / "ground_gcp_no_heights";
  ASSERT_EQ(RunCommand(std::string(UAVM_GROUND_BIN) + " " + session.string() + " --out " + flat_out.string() +
                       " --no-dense --gcp " + (tmp / "gcp_no_heights.txt").string() + " --checkpoints p4,p5" +
                       GroundEmulationArgs() + " 2>" + (tmp / "stderr_gcp_flat.txt").string()),
            0);
  std::ifstream flat_in(flat_out / "summary.json");
  const auto flat_js = nlohmann::json::parse(flat_in);
  const auto& fg = flat_js["gcp"];
  std::printf("gcp without heights: control %s, checkpoints %s\n", fg["control_rms"].dump().c_str(),
              fg["checkpoint_rms"].dump().c_str());
  EXPECT_TRUE(fg["horizontal_only"].get<bool>());
  EXPECT_TRUE(fg["checkpoint_rms"]["z_m"].is_null());
  EXPECT_LT(fg["checkpoint_rms"]["total_gsd"].get<double>(), 3.0);
  EXPECT_NE(ReadText(tmp / "stderr_gcp_flat.txt").find("horizontal"), std::string::npos);
  // Bad files stop before the long stages, with their reason: an image that is not in the session, and the right
  // coordinates under the wrong CRS (zone 33 instead of 15: thousands of kilometres from the flight's GPS).
  std::string first_row;
  {
    std::ifstream in(gcp);
    std::getline(in, first_row);
    std::getline(in, first_row);
  }
  const std::string coords = first_row.substr(0, first_row.find(' ', first_row.find(' ', first_row.find(' ') + 1) + 1));
  const std::pair<std::string, std::string> bad_files[] = {
      {"EPSG:26915\n" + coords + " 10 10 nope.jpg a\n", "image 'nope.jpg' is not a frame of this session"},
      {"EPSG:32633\n" + first_row + "\n",
       "km from the flight's GPS positions: is the CRS on the GCP file's first line"},
  };
  for (const auto& [text, expected] : bad_files) {
    std::ofstream(tmp / "bad_gcp.txt") << text;
    EXPECT_NE(RunCommand(std::string(UAVM_GROUND_BIN) + " " + session.string() + " --out " + (tmp / "bad").string() +
                         " --gcp " + (tmp / "bad_gcp.txt").string() + " 2>" + (tmp / "stderr_bad.txt").string()),
              0);
    const std::string bad = ReadText(tmp / "stderr_bad.txt");
    EXPECT_NE(bad.find(expected), std::string::npos) << bad;
  }
}

// The same session with its first frame at another size (a centre crop of 0.9x its sides, as another camera or a
// digital zoom would give) and its last one unreadable: the first gets a camera model of its own and takes part, the
// unreadable one is left out and named with the reason, and the flight still makes a dense cloud (with the first
// frame's size taken as the only camera's, every stereo pair was refused; an unreadable frame stopped the run).
void CheckMixedSizeRun(const fs::path& tmp, const fs::path& session, int frames) {
  const fs::path mixed = tmp / "session_mixed", out = tmp / "ground_mixed";
  fs::copy(session, mixed, fs::copy_options::recursive);
  std::ifstream in(session / "frames.csv");
  std::ofstream csv(mixed / "frames.csv");
  std::string row;
  std::getline(in, row);
  csv << row << "\n";
  int changed = -1;
  while (std::getline(in, row)) {
    std::vector<std::string> cols;  // every field, the empty ones too
    for (size_t start = 0;;) {
      const size_t comma = row.find(',', start);
      cols.push_back(row.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    if (changed < 0 && cols.size() > 6 && cols[6] == "1") {  // index,filename,stored_file,width,height,ts,registered
      const fs::path stored = mixed / "frames" / cols[2];
      const cv::Mat image = cv::imread(stored.string(), cv::IMREAD_COLOR);
      ASSERT_FALSE(image.empty()) << stored;
      const cv::Size size(image.cols * 9 / 10, image.rows * 9 / 10);
      ASSERT_TRUE(cv::imwrite(
          stored.string(),
          image(cv::Rect((image.cols - size.width) / 2, (image.rows - size.height) / 2, size.width, size.height))));
      cols[3] = std::to_string(size.width);
      cols[4] = std::to_string(size.height);
      changed = std::stoi(cols[0]);
      row.clear();
      for (size_t k = 0; k < cols.size(); ++k) row += (k > 0 ? "," : "") + cols[k];
    }
    csv << row << "\n";
  }
  csv.close();
  ASSERT_GE(changed, 0);
  // And the last stored frame cut short (a card pulled mid-write): left out too, named, the rest goes on.
  fs::path last;
  for (const auto& entry : fs::directory_iterator(mixed / "frames"))
    if (last.empty() || entry.path().filename() > last.filename()) last = entry.path();
  fs::resize_file(last, 600);
  ASSERT_EQ(RunCommand(std::string(UAVM_GROUND_BIN) + " " + mixed.string() + " --out " + out.string() +
                       " --threads 2 --max-dense-pairs 6" + GroundEmulationArgs() + " 2>" +
                       (tmp / "stderr_mixed.txt").string()),
            0);
  std::ifstream js_in(out / "summary.json");
  const auto js = nlohmann::json::parse(js_in);
  const std::string log = ReadText(tmp / "stderr_mixed.txt");
  std::printf("mixed sizes: %s\n", js["frames_not_used"].dump().c_str());
  ASSERT_EQ(js["frames_not_used"].size(), 1u) << log;
  EXPECT_NE(js["frames_not_used"][0]["reason"].get<std::string>().find("cannot read"), std::string::npos);
  EXPECT_EQ(js["frames_used"].get<int>(), frames - 1);
  // Two camera models: the cropped frame has one of its own size.
  ASSERT_EQ(js["cameras"].size(), 2u) << js["cameras"].dump();
  const auto& small =
      js["cameras"][0]["width"].get<int>() < js["cameras"][1]["width"].get<int>() ? js["cameras"][0] : js["cameras"][1];
  const auto& large = &small == &js["cameras"][0] ? js["cameras"][1] : js["cameras"][0];
  EXPECT_EQ(small["images"].get<int>(), 1);
  EXPECT_EQ(large["images"].get<int>(), frames - 2);
  std::printf("cameras: small %s, large %s\n", small.dump().c_str(), large.dump().c_str());
  // One image cannot calibrate a lens: the small camera keeps the start's (none), only its focal length moves.
  EXPECT_EQ(small["k1"].get<double>(), 0.0);
  EXPECT_EQ(small["cx"].get<double>(), 449.5);
  // A crop keeps the focal length in pixels: the onboard maps' scale says so, and the odd shot's focal length stays
  // tied to the main camera's (free, it went 10-12 % off and took the main camera's 18 % with it).
  EXPECT_NEAR(small["fx"].get<double>() / large["fx"].get<double>(), 1.0, 0.03);
  // The main camera near its EXIF focal length (3.61 mm on the FC300S's 6.17 mm sensor: 583.5 px at 1000 px; the
  // single-size run finds 607-609): the weak prior of a flight whose first frame hides its model let it drift 13-17 %.
  EXPECT_NEAR(large["fx"].get<double>(), 583.5, 0.05 * 583.5);
  EXPECT_LT(js["ba_rms_after_px"].get<double>(), 0.6);
  EXPECT_GT(js["dense_points"].get<size_t>(), 1000u) << log;
  EXPECT_EQ(js["dsm_source"].get<std::string>(), "dense");
  // The orthophoto has every used frame in view, the cropped one through its own camera.
  EXPECT_EQ(js["ortho"]["images_in_view"].get<int>(), frames - 1) << js["ortho"].dump();
  EXPECT_EQ(js["ortho"]["images_unreadable"].get<int>(), 0);
  EXPECT_NE(log.find("left out"), std::string::npos) << log;
  EXPECT_NE(log.find("(1 left out)"), std::string::npos) << log;  // the closing line counts it
  // COLMAP reads the two cameras back.
  Reconstruction rec;
  std::string err;
  ASSERT_TRUE(ReadColmapText((out / "sparse").string(), &rec, &err)) << err;
  EXPECT_EQ(rec.cameras.size(), 2u);
}

// The orthophoto: a valid COG (GDAL's own validator when python3-gdal is there, as setup.sh installs it) in UTM 15N
// at the summary's GSD, RGB with a mask, covering the flown area; its MBTiles package with zoom levels; the DSM's fill
// mask agreeing with the summary.
void CheckOrthophoto(const fs::path& out, const nlohmann::json& js) {
  ASSERT_TRUE(js.contains("ortho")) << js.dump();
  const auto& o = js["ortho"];
  // The onboard program corrected this flight's radiometry: the orthophoto divides the same gains and shading out.
  EXPECT_EQ(o.value("radiometry", ""), "the onboard gains and shading (radiometry.csv, report.json)") << o.dump();
  const char* validator = "/usr/share/doc/python3-gdal/examples/validate_cloud_optimized_geotiff.py";
  if (fs::exists(validator) && fs::exists("/usr/bin/python3")) {
    EXPECT_EQ(RunCommand(std::string("/usr/bin/python3 ") + validator + " --full-check=yes " +
                         (out / "ortho.tif").string() + " > /dev/null"),
              0);
  }
  auto* ds = static_cast<GDALDataset*>(GDALOpen((out / "ortho.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  const char* layout = ds->GetMetadataItem("LAYOUT", "IMAGE_STRUCTURE");
  EXPECT_STREQ(layout != nullptr ? layout : "", "COG");
  EXPECT_EQ(ds->GetRasterCount(), 3);
  EXPECT_EQ(ds->GetRasterXSize(), o["size"][0].get<int>());
  GDALRasterBand* band = ds->GetRasterBand(1);
  EXPECT_EQ(band->GetMaskFlags(), GMF_PER_DATASET);
  EXPECT_GE(band->GetOverviewCount(), 2);
  double gt[6];
  ds->GetGeoTransform(gt);
  EXPECT_NEAR(gt[1], o["gsd"].get<double>(), 1e-9);
  EXPECT_NEAR(gt[0], 576000.0, 5000.0);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32615");
  // The mask, read at an overview: most of the map is covered, and what is covered is a photograph (not one colour).
  const int w = ds->GetRasterXSize() / 4, h = ds->GetRasterYSize() / 4;
  cv::Mat1b mask(h, w), grey(h, w);
  ASSERT_EQ(band->GetMaskBand()->RasterIO(GF_Read, 0, 0, ds->GetRasterXSize(), ds->GetRasterYSize(), mask.data, w, h,
                                          GDT_Byte, 0, 0, nullptr),
            CE_None);
  ASSERT_EQ(band->RasterIO(GF_Read, 0, 0, ds->GetRasterXSize(), ds->GetRasterYSize(), grey.data, w, h, GDT_Byte, 0, 0,
                           nullptr),
            CE_None);
  GDALClose(ds);
  EXPECT_GT(cv::countNonZero(mask), w * h / 3);
  cv::Scalar mean, stddev;
  cv::meanStdDev(grey, mean, stddev, mask);
  EXPECT_GT(stddev[0], 15.0);
  EXPECT_EQ(o["images_in_view"].get<int>(), js["frames_used"].get<int>());
  EXPECT_GT(o["images_used"].get<int>(), js["frames_used"].get<int>() / 2);
  // QGIS opens it (python3-qgis, headless) in its CRS and draws it: the map where the mask says, white around it.
  const fs::path qgis_png = out / "qgis_ortho.png";
  ASSERT_EQ(RunCommand(std::string("/usr/bin/python3 ") + UAVM_SOURCE_DIR + "/tests/qgis_render.py " +
                       (out / "ortho.tif").string() + " " + qgis_png.string() + " > " + (out / "qgis.json").string()),
            0)
      << "python3-qgis missing? (scripts/setup.sh installs it)";
  EXPECT_NE(ReadText(out / "qgis.json").find("EPSG:32615"), std::string::npos);
  const cv::Mat drawn = cv::imread(qgis_png.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(drawn.empty());
  cv::Mat white;
  cv::inRange(drawn, cv::Scalar(250, 250, 250), cv::Scalar(255, 255, 255), white);
  const double white_share = cv::countNonZero(white) / static_cast<double>(white.total());
  EXPECT_LT(white_share, 0.6);
  EXPECT_GT(white_share, 0.02);  // the mask is honoured: outside the flown area is background, not black
  // XYZ web tiles as the onboard program writes them, down to the whole map in one tile.
  EXPECT_GT(o["web_tiles"].get<int>(), 4);
  const int z0 = o["web_zoom"][0].get<int>();
  ASSERT_TRUE(fs::is_directory(out / "tiles" / std::to_string(z0)));
  // MBTiles: Web Mercator tiles with their zoom levels.
  auto* tiles = static_cast<GDALDataset*>(GDALOpen((out / "ortho.mbtiles").c_str(), GA_ReadOnly));
  ASSERT_NE(tiles, nullptr);
  EXPECT_STREQ(tiles->GetDriver()->GetDescription(), "MBTiles");
  EXPECT_GE(tiles->GetRasterBand(1)->GetOverviewCount(), 2);
  GDALClose(tiles);
  // The DSM's fill mask: 1 filled, 0 measured, as many as the summary says.
  auto* fill = static_cast<GDALDataset*>(GDALOpen((out / "dsm_filled.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(fill, nullptr);
  cv::Mat1b flags(fill->GetRasterYSize(), fill->GetRasterXSize());
  ASSERT_EQ(fill->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, flags.cols, flags.rows, flags.data, flags.cols, flags.rows,
                                             GDT_Byte, 0, 0, nullptr),
            CE_None);
  GDALClose(fill);
  const double cells = static_cast<double>(flags.total());
  EXPECT_NEAR(cv::countNonZero(flags == 0) / cells, js["dsm_measured_fraction"].get<double>(), 1e-9);
  EXPECT_NEAR(cv::countNonZero(flags == 1) / cells, js["dsm_filled_fraction"].get<double>(), 1e-9);
  EXPECT_GT(js["dsm_measured_fraction"].get<double>(), 0.2);
  // The DTM: on the DSM's grid, nowhere above the surface (beyond the interpolation's noise), mostly ground on a beach
  // park.
  auto* dsm = static_cast<GDALDataset*>(GDALOpen((out / "dsm.tif").c_str(), GA_ReadOnly));
  auto* dtm = static_cast<GDALDataset*>(GDALOpen((out / "dtm.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(dsm, nullptr);
  ASSERT_NE(dtm, nullptr);
  ASSERT_EQ(dtm->GetRasterXSize(), dsm->GetRasterXSize());
  cv::Mat1f surface(dsm->GetRasterYSize(), dsm->GetRasterXSize()), terrain(surface.size());
  ASSERT_EQ(dsm->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, surface.cols, surface.rows, surface.data, surface.cols,
                                            surface.rows, GDT_Float32, 0, 0, nullptr),
            CE_None);
  ASSERT_EQ(dtm->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, terrain.cols, terrain.rows, terrain.data, terrain.cols,
                                            terrain.rows, GDT_Float32, 0, 0, nullptr),
            CE_None);
  GDALClose(dsm);
  GDALClose(dtm);
  const cv::Mat has = surface != -9999.0f;
  EXPECT_EQ(cv::countNonZero(has), cv::countNonZero(terrain != -9999.0f));
  const cv::Mat above = (terrain > surface + 0.5f) & has;
  EXPECT_LT(cv::countNonZero(above), cv::countNonZero(has) / 100);
  EXPECT_GT(js["terrain"]["ground_fraction"].get<double>(), 0.3) << js["terrain"].dump();
}

// The report: one self-contained file (nothing fetched), drawn by headless Chromium with the orthophoto and its
// figures; the screenshot is kept beside it (report.png) to be looked at.
void CheckReport(const fs::path& out, const fs::path& work) {
  const std::string html = ReadText(out / "report.html");
  ASSERT_GT(html.size(), 10000u);
  EXPECT_EQ(html.find("src='http"), std::string::npos);
  EXPECT_EQ(html.find("href='http"), std::string::npos);
  EXPECT_EQ(html.find("<script"), std::string::npos);
  for (const char* section : {"Orthophoto, cameras and control", "Overlap", "Cameras", "Reprojection residuals",
                              "Surface and terrain", "Time and memory per stage"})
    EXPECT_NE(html.find(section), std::string::npos) << section;
  ASSERT_FALSE(test::ChromiumBinary().empty()) << "chromium missing: run scripts/setup.sh";
  const cv::Mat shot =
      test::Screenshot("file://" + (out / "report.html").string(), work / "report_shot", 3000, cv::Size(1200, 2400));
  ASSERT_FALSE(shot.empty());
  cv::imwrite((out / "report.png").string(), shot);
  // The page shows pictures, not just text: a good share of it is neither white background nor black text.
  cv::Mat hsv;
  cv::cvtColor(shot, hsv, cv::COLOR_BGR2HSV);
  cv::Mat coloured;
  cv::inRange(hsv, cv::Scalar(0, 40, 40), cv::Scalar(180, 255, 255), coloured);
  const double share = cv::countNonZero(coloured) / static_cast<double>(coloured.total());
  std::printf("report screenshot: %.0f %% coloured\n", 100.0 * share);
  EXPECT_GT(share, 0.15);
}

TEST(GroundE2e, BrightonBeachSmall) {
  const fs::path tmp = fs::temp_directory_path() / ("uavm_ground_e2e_" + std::to_string(::getpid()));
  fs::remove_all(tmp);
  const fs::path session = tmp / "session", out = tmp / "ground";
  // Under emulation the first 12 frames (two strips: stereo pairs along and across them).
  const test::FlightForTest flight(fs::path(UAVM_TEST_DATA) / "brighton_beach_small/images", 12, tmp / "flight");
  const int frames = flight.frames();
  ASSERT_EQ(RunCommand(std::string(UAVM_ONBOARD_BIN) + " --source replay:" + flight.string() + " --out " +
                       session.string() + " --log-level warn --no-tiff" + test::EmulationArgsString()),
            0);
  ASSERT_EQ(
      RunCommand(std::string(UAVM_GROUND_BIN) + " " + session.string() + " --out " + out.string() +
                 " --threads 2 --render-previews" + GroundEmulationArgs() + " 2>" + (tmp / "stderr.txt").string()),
      0);
  for (const char* f :
       {"cloud.ply", "dsm.tif", "summary.json", "sparse/cameras.txt", "sparse/images.txt", "sparse/points3D.txt",
        "preview_cloud.png", "preview_dsm.png", "preview_dtm.png", "dtm.tif", "report.html"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  std::ifstream js_in(out / "summary.json");
  const auto js = nlohmann::json::parse(js_in);
  std::printf("ground: %s\n", js["timings"].dump().c_str());
  EXPECT_EQ(js["frames_used"].get<int>(), frames);
  const double before = js["ba_rms_before_px"].get<double>(), after = js["ba_rms_after_px"].get<double>();
  EXPECT_LT(after, before);
  EXPECT_LT(after, 0.6);  // 1000x562 frames; measured 3.99 -> 0.32 px
  EXPECT_GT(js["sparse_points"].get<int>(), 1000);
  EXPECT_EQ(js["crs"].get<std::string>(), "EPSG:32615");

  // The PLY parses and holds a real cloud.
  std::vector<CloudPoint> cloud;
  std::string err;
  ASSERT_TRUE(ReadPly((out / "cloud.ply").string(), &cloud, &err)) << err;
  EXPECT_GT(cloud.size(), test::Emulated() ? 5000u : 20000u);
  EXPECT_EQ(cloud.size(), js["dense_points"].get<size_t>());

  // The COLMAP model reads back with every frame and the sparse points.
  Reconstruction rec;
  ASSERT_TRUE(ReadColmapText((out / "sparse").string(), &rec, &err)) << err;
  EXPECT_EQ(rec.images.size(), static_cast<size_t>(frames));
  EXPECT_EQ(rec.points.size(), js["sparse_points"].get<size_t>());
  EXPECT_NEAR(rec.ReprojectionRms(), after, 1e-6);
  CheckColmapReads(out / "sparse", rec.images.size(), rec.points.size(), tmp);

  // DSM: float32 with nodata, UTM 15N, heights of a flat beach.
  GDALAllRegister();
  GDALDataset* ds = static_cast<GDALDataset*>(GDALOpen((out / "dsm.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(ds, nullptr);
  GDALRasterBand* band = ds->GetRasterBand(1);
  EXPECT_EQ(band->GetRasterDataType(), GDT_Float32);
  int has_nodata = 0;
  const double nodata = band->GetNoDataValue(&has_nodata);
  EXPECT_TRUE(has_nodata);
  const OGRSpatialReference* srs = ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  EXPECT_TRUE(srs->IsProjected());
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32615");
  double gt[6];
  ds->GetGeoTransform(gt);
  EXPECT_NEAR(gt[0], 576000.0, 5000.0);  // Brighton Beach, Duluth MN (46.84 N, 92.0 W): UTM 15N
  const int w = ds->GetRasterXSize(), h = ds->GetRasterYSize();
  std::vector<float> v(static_cast<size_t>(w) * static_cast<size_t>(h));
  ASSERT_EQ(band->RasterIO(GF_Read, 0, 0, w, h, v.data(), w, h, GDT_Float32, 0, 0), CE_None);
  GDALClose(ds);
  // Heights measured (dsm_filled.tif 0) and filled (1): the fill interpolates, so it stays within the measured range.
  auto* fill = static_cast<GDALDataset*>(GDALOpen((out / "dsm_filled.tif").c_str(), GA_ReadOnly));
  ASSERT_NE(fill, nullptr);
  std::vector<uint8_t> flag(v.size());
  ASSERT_EQ(fill->GetRasterBand(1)->RasterIO(GF_Read, 0, 0, w, h, flag.data(), w, h, GDT_Byte, 0, 0), CE_None);
  GDALClose(fill);
  std::vector<float> valid, filled;
  for (size_t i = 0; i < v.size(); ++i) {
    if (flag[i] == 0) valid.push_back(v[i]);
    if (flag[i] == 1) filled.push_back(v[i]);
    EXPECT_EQ(flag[i] == 255, v[i] == static_cast<float>(nodata)) << i;
  }
  ASSERT_GT(valid.size(), v.size() / 4);
  std::sort(valid.begin(), valid.end());
  ASSERT_FALSE(filled.empty());
  EXPECT_GE(*std::min_element(filled.begin(), filled.end()), valid.front() - 1e-3f);
  EXPECT_LE(*std::max_element(filled.begin(), filled.end()), valid.back() + 1e-3f);
  const float p05 = valid[valid.size() / 20], p50 = valid[valid.size() / 2], p95 = valid[valid.size() * 19 / 20];
  // Heights relative to take-off (DJI relative altitude): a beach is a few metres below/around the take-off point and
  // gently sloping park. Measured: p05 -3.92, p50 0.14, p95 1.31 m (spread 5.2 m).
  std::printf("DSM heights p05 %.2f p50 %.2f p95 %.2f m (%zu cells)\n", p05, p50, p95, valid.size());
  EXPECT_LT(std::abs(p50), 15.0);
  EXPECT_LT(p95 - p05, 8.0);
  CheckOrthophoto(out, js);
  CheckReport(out, tmp);
  CheckGcpRun(tmp, session, out);
  CheckMixedSizeRun(tmp, session, frames);
  fs::remove_all(tmp);
}

}  // namespace
}  // namespace uavm::sfm
