#include "tools/relief_flight.h"

#include <gdal_priv.h>
#include <gdal_utils.h>
#include <ogr_spatialref.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/eval/relief_scene.h"
#include "core/util/parallel.h"
#include "core/util/portable_random.h"

namespace uavm::tools {

namespace fs = std::filesystem;

bool ReliefFlightOptions::Check(std::string* why) const {
  const auto fail = [&](const char* msg) {
    *why = msg;
    return false;
  };
  if (half_extent_m < 10.0) return fail("the scene's half extent must be >= 10 m");
  if (width < 64 || height < 64) return fail("frames must be at least 64 x 64");
  if (hfov_deg < 10.0 || hfov_deg > 120.0) return fail("hfov must be in [10, 120] degrees");
  if (altitude_m < 10.0) return fail("altitude must be >= 10 m");
  if (forward_overlap < 0.0 || forward_overlap >= 0.95 || side_overlap < 0.0 || side_overlap >= 0.95)
    return fail("overlaps must be in [0, 0.95)");
  if (gps_sigma_m < 0.0 || gps_vertical_sigma_m < 0.0 || tilt_sigma_deg < 0.0) return fail("noise must be >= 0");
  return true;
}

namespace {

constexpr double kPi = 3.14159265358979323846;

struct FrameTruth {
  std::string name;
  Eigen::Matrix3d R;  // world (local scene metres, z up) to camera (x right, y down, z forward)
  Eigen::Vector3d centre;
  Eigen::Vector3d reported;  // what the GPS said
};

Eigen::Matrix3d NadirRotation(double yaw, double tilt_x, double tilt_y) {
  Eigen::Matrix3d down;
  down << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // camera x = east, y = south, z = down at yaw 0
  const Eigen::Matrix3d world_from_body =
      (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
       Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()))
          .toRotationMatrix();
  return down * world_from_body.transpose();
}

// Every pixel's normalised, undistorted direction (x/z, y/z) for the lens.
cv::Mat2f PixelRays(const cv::Matx33d& K, const cv::Vec4d& dist, cv::Size size) {
  cv::Mat2f pixels(size.area(), 1);
  for (int v = 0; v < size.height; ++v)
    for (int u = 0; u < size.width; ++u)
      pixels(v * size.width + u) = cv::Vec2f(static_cast<float>(u), static_cast<float>(v));
  cv::Mat2f rays;
  cv::undistortPoints(pixels, rays, K, dist, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12));
  return rays.reshape(2, size.height);
}

OGRSpatialReference Utm15N() {
  OGRSpatialReference srs;
  srs.importFromEPSG(32615);
  return srs;
}

bool WriteGeoTiff(const std::string& path, const cv::Mat& image, const double gt[6], std::string* error) {
  GDALDriver* drv = GetGDALDriverManager()->GetDriverByName("GTiff");
  const int bands = image.channels();
  const GDALDataType type = image.depth() == CV_32F ? GDT_Float32 : GDT_Byte;
  char** opts = CSLSetNameValue(nullptr, "COMPRESS", "DEFLATE");
  opts = CSLSetNameValue(opts, "TILED", "YES");
  GDALDataset* ds = drv != nullptr ? drv->Create(path.c_str(), image.cols, image.rows, bands, type, opts) : nullptr;
  CSLDestroy(opts);
  if (ds == nullptr) {
    *error = "cannot create " + path;
    return false;
  }
  double transform[6];
  std::copy(gt, gt + 6, transform);
  ds->SetGeoTransform(transform);
  const OGRSpatialReference srs = Utm15N();
  ds->SetSpatialRef(&srs);
  cv::Mat data = image;
  if (bands == 3) cv::cvtColor(image, data, cv::COLOR_BGR2RGB);
  CPLErr err = CE_None;
  for (int b = 1; b <= bands && err == CE_None; ++b) {
    err = ds->GetRasterBand(b)->RasterIO(GF_Write, 0, 0, data.cols, data.rows, data.data + (b - 1) * data.elemSize1(),
                                         data.cols, data.rows, type, static_cast<GSpacing>(data.elemSize()),
                                         static_cast<GSpacing>(data.step[0]), nullptr);
  }
  GDALClose(ds);
  if (err != CE_None) *error = "cannot write " + path;
  return err == CE_None;
}

}  // namespace

namespace {

// The survey's frames: strips along x (east), flown alternately east and west, covering the scene's centre lines to
// its edges; each with its pointing error and its GPS position's noise.
std::vector<FrameTruth> PlanFrames(const ReliefFlightOptions& o, double gsd, PortableRandom& rng, int* strips_out,
                                   int* per_strip_out) {
  const double step = (1.0 - o.forward_overlap) * o.width * gsd;
  const double spacing = (1.0 - o.side_overlap) * o.height * gsd;
  const int per_strip = static_cast<int>(std::ceil(2.0 * o.half_extent_m / step)) + 1;
  const int strips = static_cast<int>(std::ceil(2.0 * o.half_extent_m / spacing)) + 1;
  std::vector<FrameTruth> frames;
  for (int s = 0; s < strips; ++s) {
    const double y = -o.half_extent_m + s * 2.0 * o.half_extent_m / (strips - 1);
    for (int k = 0; k < per_strip; ++k) {
      const int i = s % 2 == 0 ? k : per_strip - 1 - k;
      const double x = -o.half_extent_m + i * 2.0 * o.half_extent_m / (per_strip - 1);
      FrameTruth t;
      char name[32];
      std::snprintf(name, sizeof(name), "frame_%04zu.jpg", frames.size());
      t.name = name;
      const double tilt = o.tilt_sigma_deg * kPi / 180.0;
      const double tx = rng.Normal(tilt);
      const double ty = rng.Normal(tilt);
      const double yaw_noise = rng.Normal(0.01);
      t.R = NadirRotation((s % 2 == 0 ? 0.0 : kPi) + yaw_noise, tx, ty);
      const double dz = rng.Normal(0.5);
      t.centre = Eigen::Vector3d(x, y, o.altitude_m + dz);
      const double ex = rng.Normal(o.gps_sigma_m);
      const double ey = rng.Normal(o.gps_sigma_m);
      const double ez = rng.Normal(o.gps_vertical_sigma_m);
      t.reported = t.centre + Eigen::Vector3d(ex, ey, ez);
      frames.push_back(t);
    }
  }
  *strips_out = strips;
  *per_strip_out = per_strip;
  return frames;
}

bool RenderFrames(const ReliefFlightOptions& o, const eval::ReliefScene& scene, const cv::Matx33d& K,
                  const std::vector<FrameTruth>& frames, const std::string& out_dir, std::string* error) {
  const cv::Vec4d dist(o.k1, o.k2, 0.0, 0.0);
  const cv::Mat2f rays = PixelRays(K, dist, cv::Size(o.width, o.height));
  std::vector<std::string> failed(frames.size());
  ParallelFor(frames.size(), 2, [&](size_t i) {
    const FrameTruth& t = frames[i];
    const Eigen::Matrix3d Rt = t.R.transpose();
    const cv::Mat image = eval::RenderView(scene, cv::Size(o.width, o.height), t.centre, [&](double u, double v) {
      const cv::Vec2f& xn = rays(static_cast<int>(v), static_cast<int>(u));
      return Eigen::Vector3d(Rt * Eigen::Vector3d(xn[0], xn[1], 1.0));
    });
    const std::string path = (fs::path(out_dir) / "images" / t.name).string();
    if (!cv::imwrite(path, image, {cv::IMWRITE_JPEG_QUALITY, o.jpeg_quality})) failed[i] = path;
  });
  for (const auto& p : failed) {
    if (!p.empty()) {
      *error = "cannot write " + p;
      return false;
    }
  }
  return true;
}

// Targets on open ground (6 m from anything standing), on a jittered grid over the inner scene; each clicked where a
// frame sees it (inside the picture, nothing in between), with click noise; surveyed with survey noise.
void WriteTargets(const ReliefFlightOptions& o, const eval::ReliefScene& scene, const cv::Matx33d& K,
                  const std::vector<FrameTruth>& frames, const std::string& out_dir, PortableRandom& rng,
                  nlohmann::json* targets, nlohmann::json* checkpoints) {
  const auto frame_pixel = [&](const FrameTruth& t, const Eigen::Vector3d& X, cv::Point2d* px) {
    const Eigen::Vector3d p = t.R * (X - t.centre);
    if (p.z() <= 0) return false;
    const double x = p.x() / p.z(), y = p.y() / p.z(), r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (o.k1 + r2 * o.k2);
    *px = cv::Point2d(K(0, 0) * x * radial + K(0, 2), K(1, 1) * y * radial + K(1, 2));
    return px->x >= 10 && px->y >= 10 && px->x <= o.width - 11 && px->y <= o.height - 11;
  };
  std::ofstream gcp(fs::path(out_dir) / "gcp_list.txt"), gcp_flat(fs::path(out_dir) / "gcp_list_no_heights.txt");
  gcp << "EPSG:32615\n";
  gcp_flat << "EPSG:32615\n";
  gcp.precision(12);
  gcp_flat.precision(12);
  *targets = nlohmann::json::array();
  *checkpoints = nlohmann::json::array();
  const int side = std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(o.targets)))));
  for (int k = 0, placed = 0; placed < o.targets && k < 50 * o.targets; ++k) {
    const int cell = placed;
    const double span = 1.4 * o.half_extent_m;
    const double x = -0.5 * span + (cell % side + 0.5) * span / side + rng.Uniform(-0.15, 0.15) * span / side;
    const double y = -0.5 * span + (cell / side + 0.5) * span / side + rng.Uniform(-0.15, 0.15) * span / side;
    bool open_ground = true;
    for (double a = 0; a < 2 * kPi && open_ground; a += kPi / 8)
      open_ground = scene.CoverAt(x + 6 * std::cos(a), y + 6 * std::sin(a)) == 0 && scene.CoverAt(x, y) == 0;
    if (!open_ground) continue;
    const Eigen::Vector3d X(x, y, scene.Ground(x, y));
    const std::string name = "t" + std::to_string(placed + 1);
    const double sx = rng.Normal(o.survey_sigma_m);  // each draw in its own statement: a fixed order everywhere
    const double sy = rng.Normal(o.survey_sigma_m);
    const double sz = rng.Normal(o.survey_sigma_m);
    int clicks = 0;
    for (const auto& t : frames) {
      cv::Point2d px;
      if (!frame_pixel(t, X, &px) || !eval::Sees(scene, t.centre, X)) continue;
      const double cx = rng.Normal(o.click_sigma_px);
      const double cy = rng.Normal(o.click_sigma_px);
      gcp << o.easting + x + sx << ' ' << o.northing + y + sy << ' ' << o.datum_m + X.z() + sz << ' ' << px.x + cx
          << ' ' << px.y + cy << ' ' << t.name << ' ' << name << '\n';
      gcp_flat << o.easting + x + sx << ' ' << o.northing + y + sy << " 0 " << px.x + cx << ' ' << px.y + cy << ' '
               << t.name << ' ' << name << '\n';
      ++clicks;
    }
    targets->push_back({{"name", name}, {"xyz", {x, y, X.z()}}, {"clicks", clicks}});
    if (placed % 3 == 1) checkpoints->push_back(name);
    ++placed;
  }
}

// Positions: reported (geo.txt) and true, in UTM 15N with heights above the datum. Returns the poses for flight.json.
nlohmann::json WritePositions(const ReliefFlightOptions& o, const std::vector<FrameTruth>& frames,
                              const std::string& out_dir) {
  std::ofstream geo(fs::path(out_dir) / "geo.txt"), geo_truth(fs::path(out_dir) / "geo_truth.txt");
  geo << "EPSG:32615\n";
  geo_truth << "EPSG:32615\n";
  geo.precision(12);
  geo_truth.precision(12);
  nlohmann::json poses = nlohmann::json::array();
  for (const auto& t : frames) {
    geo << t.name << ' ' << o.easting + t.reported.x() << ' ' << o.northing + t.reported.y() << ' '
        << o.datum_m + t.reported.z() << '\n';
    geo_truth << t.name << ' ' << o.easting + t.centre.x() << ' ' << o.northing + t.centre.y() << ' '
              << o.datum_m + t.centre.z() << '\n';
    poses.push_back(
        {{"name", t.name},
         {"centre", {t.centre.x(), t.centre.y(), t.centre.z()}},
         {"R", {t.R(0, 0), t.R(0, 1), t.R(0, 2), t.R(1, 0), t.R(1, 1), t.R(1, 2), t.R(2, 0), t.R(2, 1), t.R(2, 2)}}});
  }
  return poses;
}

// The truth from above at the flight's GSD.
bool WriteTruth(const ReliefFlightOptions& o, const eval::ReliefScene& scene, double gsd, const std::string& out_dir,
                std::string* error) {
  eval::TruthGrid grid;
  grid.gsd = gsd;
  grid.x0 = -o.half_extent_m;
  grid.y0 = o.half_extent_m;
  grid.width = grid.height = static_cast<int>(std::ceil(2.0 * o.half_extent_m / gsd));
  const double gt[6] = {o.easting + grid.x0, gsd, 0.0, o.northing + grid.y0, 0.0, -gsd};
  cv::Mat1f surface = eval::RenderTrueSurface(scene, grid);
  surface += o.datum_m;
  cv::Mat1f ground = eval::RenderTrueGround(scene, grid);
  ground += o.datum_m;
  const fs::path truth = fs::path(out_dir) / "truth";
  if (!WriteGeoTiff((truth / "ortho.tif").string(), eval::RenderTrueOrtho(scene, grid), gt, error) ||
      !WriteGeoTiff((truth / "dsm.tif").string(), surface, gt, error) ||
      !WriteGeoTiff((truth / "dtm.tif").string(), ground, gt, error) ||
      !WriteGeoTiff((truth / "cover.tif").string(), eval::RenderCover(scene, grid), gt, error))
    return false;
  return true;
}

}  // namespace

bool WriteReliefFlight(const ReliefFlightOptions& o, const std::string& out_dir, nlohmann::json* summary,
                       std::string* error) {
  if (!o.Check(error)) return false;
  GDALAllRegister();
  std::error_code ec;
  fs::create_directories(fs::path(out_dir) / "images", ec);
  fs::create_directories(fs::path(out_dir) / "truth", ec);
  if (ec) {
    *error = "cannot create " + out_dir + ": " + ec.message();
    return false;
  }
  const double f = 0.5 * o.width / std::tan(0.5 * o.hfov_deg * kPi / 180.0);
  const double gsd = o.altitude_m / f;
  eval::ReliefScene scene = eval::MakeReliefScene(o.seed, o.half_extent_m, o.buildings, o.trees);
  scene.texture_scale = 3.0 * gsd;  // the finest texture three pixels long
  const cv::Matx33d K(f, 0, 0.5 * (o.width - 1) + 0.7, 0, f, 0.5 * (o.height - 1) - 0.4, 0, 0, 1);
  PortableRandom rng(o.seed * 7919u + 11u);
  int strips = 0, per_strip = 0;
  const std::vector<FrameTruth> frames = PlanFrames(o, gsd, rng, &strips, &per_strip);
  if (!RenderFrames(o, scene, K, frames, out_dir, error)) return false;
  nlohmann::json targets, checkpoints;
  WriteTargets(o, scene, K, frames, out_dir, rng, &targets, &checkpoints);
  const nlohmann::json poses = WritePositions(o, frames, out_dir);
  if (!WriteTruth(o, scene, gsd, out_dir, error)) return false;
  const fs::path truth = fs::path(out_dir) / "truth";
  nlohmann::json scene_js = {{"half_extent_m", o.half_extent_m},
                             {"slope", {scene.slope_x, scene.slope_y}},
                             {"buildings", scene.buildings.size()},
                             {"trees", scene.trees.size()},
                             {"texture_scale_m", scene.texture_scale}};
  *summary = {{"frames", frames.size()},
              {"strips", strips},
              {"frames_per_strip", per_strip},
              {"gsd_m", gsd},
              {"camera",
               {{"width", o.width},
                {"height", o.height},
                {"fx", f},
                {"cx", K(0, 2)},
                {"cy", K(1, 2)},
                {"k1", o.k1},
                {"k2", o.k2}}},
              {"utm", {{"epsg", 32615}, {"easting", o.easting}, {"northing", o.northing}, {"datum_m", o.datum_m}}},
              {"scene", scene_js},
              {"targets", targets},
              {"checkpoints", checkpoints},
              {"poses", poses}};
  std::ofstream(truth / "flight.json") << summary->dump(1) << '\n';
  summary->erase("poses");
  return true;
}

namespace {

// All bands of `ds` as one interleaved Mat of `type` (CV_8U or CV_32F); empty on a read error.
cv::Mat ReadRaster(GDALDataset* ds, int type) {
  const int bands = ds->GetRasterCount();
  cv::Mat data(ds->GetRasterYSize(), ds->GetRasterXSize(), CV_MAKETYPE(type, bands));
  for (int b = 1; b <= bands; ++b) {
    if (ds->GetRasterBand(b)->RasterIO(GF_Read, 0, 0, data.cols, data.rows, data.data + (b - 1) * data.elemSize1(),
                                       data.cols, data.rows, type == CV_32F ? GDT_Float32 : GDT_Byte,
                                       static_cast<GSpacing>(data.elemSize()), static_cast<GSpacing>(data.step[0]),
                                       nullptr) != CE_None)
      return {};
  }
  return data;
}

// `path` resampled onto the truth raster's grid (GDAL warp; bilinear or nearest), with an alpha band when asked.
cv::Mat WarpOntoTruth(const std::string& path, GDALDataset* truth, bool nearest, bool alpha, int* bands_out,
                      std::string* error) {
  GDALDatasetH src = GDALOpen(path.c_str(), GA_ReadOnly);
  if (src == nullptr) {
    *error = "cannot open " + path;
    return {};
  }
  double gt[6];
  truth->GetGeoTransform(gt);
  const int w = truth->GetRasterXSize(), h = truth->GetRasterYSize();
  std::vector<std::string> words = {"-of",
                                    "MEM",
                                    "-te",
                                    std::to_string(gt[0]),
                                    std::to_string(gt[3] + h * gt[5]),
                                    std::to_string(gt[0] + w * gt[1]),
                                    std::to_string(gt[3]),
                                    "-ts",
                                    std::to_string(w),
                                    std::to_string(h),
                                    "-r",
                                    nearest ? "near" : "bilinear"};
  if (alpha) words.emplace_back("-dstalpha");
  char** args = nullptr;
  for (const auto& word : words) args = CSLAddString(args, word.c_str());
  GDALWarpAppOptions* options = GDALWarpAppOptionsNew(args, nullptr);
  CSLDestroy(args);
  int usage_error = 0;
  GDALDatasetH out = GDALWarp("", nullptr, 1, &src, options, &usage_error);
  GDALWarpAppOptionsFree(options);
  GDALClose(src);
  if (out == nullptr) {
    *error = "cannot resample " + path + " onto the truth's grid: " + CPLGetLastErrorMsg();
    return {};
  }
  auto* ds = GDALDataset::FromHandle(out);
  const int bands = ds->GetRasterCount();
  const bool is_float = ds->GetRasterBand(1)->GetRasterDataType() == GDT_Float32;
  const cv::Mat data = ReadRaster(ds, is_float ? CV_32F : CV_8U);
  if (data.empty()) {
    GDALClose(out);
    *error = "cannot read the resampled " + path;
    return {};
  }
  GDALClose(out);
  *bands_out = bands;
  return data;
}

double Rms(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// Patch-wise phase correlation of the orthophoto against the true one: per 64 px patch fully covered and textured,
// the shift in truth pixels (= GSD), grouped by what the patch shows. The absolute error includes the map's offset as a
// whole (from the GPS without GCPs); the relative error is what is left once the median shift is taken out.
nlohmann::json OrthoError(const cv::Mat& ours_rgba, const cv::Mat& truth_rgb, const cv::Mat1b& cover) {
  constexpr int kPatch = 64;
  cv::Mat ours_grey, truth_grey;
  cv::Mat ours_rgb;
  cv::cvtColor(ours_rgba, ours_rgb, cv::COLOR_RGBA2RGB);
  cv::cvtColor(ours_rgb, ours_grey, cv::COLOR_RGB2GRAY);
  cv::cvtColor(truth_rgb, truth_grey, cv::COLOR_RGB2GRAY);
  cv::Mat1b alpha;
  cv::extractChannel(ours_rgba, alpha, 3);
  cv::Mat window;
  cv::createHanningWindow(window, cv::Size(kPatch, kPatch), CV_32F);
  struct Patch {
    cv::Point2d shift;
    int cls;  // 0 ground, 1 roof, 2 crown, -1 mixed
    cv::Point at;
    double response;
  };
  std::vector<Patch> found;
  int patches = 0, unmatched = 0;
  for (int y = 0; y + kPatch <= cover.rows; y += kPatch) {
    for (int x = 0; x + kPatch <= cover.cols; x += kPatch) {
      const cv::Rect r(x, y, kPatch, kPatch);
      if (cv::countNonZero(alpha(r)) < kPatch * kPatch) continue;
      ++patches;
      cv::Mat a, b;
      ours_grey(r).convertTo(a, CV_32F);
      truth_grey(r).convertTo(b, CV_32F);
      double response = 0.0;
      const cv::Point2d shift = cv::phaseCorrelate(b, a, window, &response);
      if (response < 0.05 || std::hypot(shift.x, shift.y) > kPatch / 4.0) {  // no peak: nothing alike
        ++unmatched;
        continue;
      }
      const int area = kPatch * kPatch;
      int cls = -1;
      if (cv::countNonZero(cover(r) == 0) == area) cls = 0;
      if (cv::countNonZero(cover(r) == 1) > 0.8 * area) cls = 1;
      if (cv::countNonZero(cover(r) == 2) > 0.5 * area) cls = 2;
      found.push_back({shift, cls, r.tl(), response});
    }
  }
  std::vector<double> sx, sy;
  for (const auto& p : found) {
    sx.push_back(p.shift.x);
    sy.push_back(p.shift.y);
  }
  const cv::Point2d offset(Median(sx), Median(sy));
  const auto stats = [&](int cls) {
    std::vector<double> absolute, relative;
    for (const auto& p : found) {
      if (cls != -2 && p.cls != cls) continue;
      absolute.push_back(std::hypot(p.shift.x, p.shift.y));
      relative.push_back(std::hypot(p.shift.x - offset.x, p.shift.y - offset.y));
    }
    return nlohmann::json{{"patches", absolute.size()},
                          {"rms_gsd", Rms(absolute)},
                          {"median_gsd", Median(absolute)},
                          {"relative_rms_gsd", Rms(relative)},
                          {"relative_median_gsd", Median(relative)}};
  };
  nlohmann::json list = nlohmann::json::array();  // x, y (truth pixels), shift x, y (GSD), class, response
  for (const auto& p : found) list.push_back({p.at.x, p.at.y, p.shift.x, p.shift.y, p.cls, p.response});
  return {{"patches", patches},
          {"patch_shifts", list},
          {"unmatched", unmatched},
          {"offset_gsd", {offset.x, offset.y}},
          {"all", stats(-2)},
          {"ground", stats(0)},
          {"roofs", stats(1)},
          {"crowns", stats(2)},
          {"covered_fraction", cv::countNonZero(alpha) / static_cast<double>(alpha.total())}};
}

// Height errors of `ours` against `truth` where `measured`, away from the edges of buildings and crowns (a DSM cell
// there mixes a roof and the ground), per cover class.
nlohmann::json HeightError(const cv::Mat1f& ours, const cv::Mat1f& truth, const cv::Mat1b& measured,
                           const cv::Mat1b& cover, double gsd) {
  cv::Mat1b hi, lo;
  const int k = 2 * static_cast<int>(std::ceil(1.0 / gsd)) + 1;  // +-1 m
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(k, k));
  cv::dilate(cover, hi, kernel);
  cv::erode(cover, lo, kernel);
  std::vector<double> all, by_class[3];
  for (int r = 0; r < ours.rows; ++r) {
    for (int c = 0; c < ours.cols; ++c) {
      if (measured(r, c) == 0 || hi(r, c) != lo(r, c)) continue;
      const double e = ours(r, c) - truth(r, c);
      all.push_back(e);
      by_class[cover(r, c)].push_back(e);
    }
  }
  const double bias = Median(all);
  const auto stats = [&](const std::vector<double>& v) {
    std::vector<double> centred;
    for (double e : v) centred.push_back(e - bias);
    return nlohmann::json{
        {"cells", v.size()}, {"rms_m", Rms(v)}, {"rms_gsd", Rms(v) / gsd}, {"rms_after_bias_gsd", Rms(centred) / gsd}};
  };
  return {{"bias_m", bias},
          {"surfaces", stats(all)},
          {"ground", stats(by_class[0])},
          {"roofs", stats(by_class[1])},
          {"crowns", stats(by_class[2])}};
}

}  // namespace

bool CompareWithTruth(const std::string& flight_dir, const ProductPaths& products, nlohmann::json* report,
                      std::string* error) {
  GDALAllRegister();
  const fs::path truth = fs::path(flight_dir) / "truth";
  auto open = [&](const char* name) {
    return static_cast<GDALDataset*>(GDALOpen((truth / name).c_str(), GA_ReadOnly));
  };
  GDALDataset* ortho = open("ortho.tif");
  GDALDataset* cover_ds = open("cover.tif");
  GDALDataset* dsm_ds = open("dsm.tif");
  GDALDataset* dtm_ds = open("dtm.tif");
  const auto close_all = [&] {
    for (GDALDataset* ds : {ortho, cover_ds, dsm_ds, dtm_ds})
      if (ds != nullptr) GDALClose(ds);
  };
  if (ortho == nullptr || cover_ds == nullptr || dsm_ds == nullptr || dtm_ds == nullptr) {
    close_all();
    *error = "cannot open the truth in " + truth.string();
    return false;
  }
  double gt[6];
  ortho->GetGeoTransform(gt);
  const double gsd = gt[1];
  const cv::Mat truth_rgb = ReadRaster(ortho, CV_8U);
  const cv::Mat1b cover = ReadRaster(cover_ds, CV_8U);
  const cv::Mat1f true_dsm = ReadRaster(dsm_ds, CV_32F);
  const cv::Mat1f true_dtm = ReadRaster(dtm_ds, CV_32F);
  *report = nlohmann::json::object();
  (*report)["gsd_m"] = gsd;
  bool ok = true;
  int bands = 0;
  if (!products.ortho.empty()) {
    cv::Mat ours = WarpOntoTruth(products.ortho, ortho, false, true, &bands, error);
    ok = !ours.empty() && bands == 4;
    if (ok) (*report)["ortho"] = OrthoError(ours, truth_rgb, cover);
  }
  const auto heights = [&](const std::string& path, const cv::Mat1f& truth_heights, const char* key) {
    cv::Mat ours = WarpOntoTruth(path, ortho, false, false, &bands, error);
    if (ours.empty()) return false;
    cv::Mat1b measured;
    cv::compare(ours, -9000.0, measured, cv::CMP_GT);
    if (!products.dsm_filled.empty() && std::string(key) == "dsm") {
      const cv::Mat flags = WarpOntoTruth(products.dsm_filled, ortho, true, false, &bands, error);
      if (flags.empty()) return false;
      measured &= cv::Mat1b(flags == 0);
    }
    nlohmann::json js = HeightError(ours, truth_heights, measured, cover, gsd);
    js["measured_fraction"] = cv::countNonZero(measured) / static_cast<double>(measured.total());
    (*report)[key] = js;
    return true;
  };
  ok = ok && (products.dsm.empty() || heights(products.dsm, true_dsm, "dsm"));
  ok = ok && (products.dtm.empty() || heights(products.dtm, true_dtm, "dtm"));
  close_all();
  return ok;
}

}  // namespace uavm::tools
