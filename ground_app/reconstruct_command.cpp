// `uavmosaic-ground SESSION_DIR --out DIR`: the offline reconstruction of a flight (core/sfm/run_reconstruction.h) and
// its products: cloud.ply, dsm.tif, sparse/ (COLMAP text model), summary.json, optional PNG previews.
#include "ground_app/reconstruct_command.h"

#include <spdlog/fmt/fmt.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <thread>

#include "core/sfm/cloud_and_dsm.h"
#include "core/sfm/colmap_io.h"
#include "core/sfm/ortho_files.h"
#include "core/sfm/report_html.h"
#include "core/sfm/run_reconstruction.h"
#include "core/sfm/session_import.h"
#include "core/sfm/session_radiometry.h"
#include "core/sfm/terrain.h"
#include "core/util/memory.h"
#include "ground_app/exit_codes.h"
#include "hal/common/metadata.h"

namespace uavm::ground {

namespace {

// The reconstruction's tuning options (features, matching, dense, GCPs).
void AddReconstructionOptions(CLI::App* app, sfm::ReconstructionOptions* opts, std::string* dense_cost) {
  app->add_option("--feature-scale", opts->feature_scale,
                  "SIFT resolution relative to the stored frames (1 = full; 0 = long side --feature-size, default)");
  app->add_option("--feature-size", opts->feature_long_side_px,
                  "long side of the SIFT images when --feature-scale is 0");
  app->add_option("--max-features", opts->max_features, "SIFT keypoints per frame");
  app->add_option("--contrast-threshold", opts->contrast_threshold, "SIFT start contrast threshold");
  app->add_option("--guided-radius", opts->guided_radius,
                  "matching window around the onboard maps' prediction, fraction of the long image side");
  app->add_option("--colmap-import", opts->colmap_import_dir, "initial poses and intrinsics from a COLMAP text model");
  app->add_option("--dense-scale", opts->dense_image_scale, "dense matching resolution relative to the frames");
  app->add_option("--dense-cost", *dense_cost, "SGM matching cost: census (+ gradient) or daisy")
      ->check(CLI::IsMember({"census", "daisy"}));
  app->add_option("--dense-step", opts->dense_sample_step, "one dense point per N x N rectified pixels");
  app->add_option("--max-dense-pairs", opts->max_dense_pairs, "stereo pairs for the dense cloud");
  app->add_option("--pairs-per-image", opts->dense_pairs_per_image, "stereo partners chosen per image");
  app->add_option("--dsm-cell", opts->dsm_cell_m, "DSM cell size in metres (0 = automatic)");
  app->add_option("--dsm-fill", opts->dsm_fill_cells,
                  "DSM holes are filled up to this many cells from a measured one (dsm_filled.tif marks them)");
  app->add_option("--hfov", opts->default_hfov_deg, "horizontal field of view (deg) when EXIF gives no focal length");
  app->add_flag("--refine-k3", opts->refine_k3, "also refine the radial k3 term");
  app->add_option("--gcp", opts->gcp_file,
                  "ground control points (OpenDroneMap gcp_list.txt); the outputs are then in their CRS")
      ->check(CLI::ExistingFile);
  app->add_option("--checkpoints", opts->checkpoints, "GCP names kept out of the adjustment and reported as checks")
      ->delimiter(',');
  app->add_option("--gcp-accuracy", opts->control.sigma_m, "GCP survey accuracy per axis, metres");
  app->add_option("--click-accuracy", opts->control.click_px, "GCP click accuracy, pixels");
  app->add_flag("--gcp-horizontal-only", opts->control.horizontal_only,
                "GCPs tie x and y only (heights from the flight's GPS); automatic when every GCP has the same height");
}

// The orthophoto's options.
void AddOrthoOptions(CLI::App* app, sfm::OrthoOptions* ortho, bool* no_ortho, bool* no_mbtiles) {
  app->add_option("--ortho-gsd", ortho->gsd, "orthophoto pixel size in the map's units (0 = the flight's GSD)");
  app->add_option("--ortho-object-height", ortho->object_height,
                  "seams keep off what stands this high above the terrain (m): each roof or crown from one frame "
                  "(0 = each cell from its most nadir view)");
  app->add_flag(
      "--ortho-seams-anywhere", [ortho](std::int64_t) { ortho->seams_off_objects = false; },
      "each cell from its most nadir view, seams through roofs and crowns too (the standing objects still counted)");
  app->add_flag("--no-ortho", *no_ortho, "no orthophoto (ortho.tif, ortho_preview.png, ortho.mbtiles, tiles/)");
  app->add_flag("--no-mbtiles", *no_mbtiles, "no ortho.mbtiles");
}

// The camera model (for the sensor table) from the stored frames' EXIF; empty when none says.
std::string CameraModelOf(const std::string& session_dir) {
  sfm::Session s;
  std::string error;
  if (!sfm::ReadSession(session_dir, &s, &error)) return {};
  // The first frame that names its camera: one without EXIF (re-encoded, another camera's) must not hide the
  // flight's model, which sets the focal length's prior (a 10x weaker one let a mixed-size flight's drift 17 %).
  for (const auto& f : s.frames) {
    if (f.stored_file.empty()) continue;
    std::string model = hal::ReadMetadata(session_dir + "/" + f.stored_file).model;
    if (!model.empty()) return model;
  }
  return {};
}

// The DSM's fill mask and the terrain under buildings and trees (core/sfm/terrain.h): dsm_filled.tif, dtm.tif.
bool WriteTerrain(sfm::ReconstructionResult& result, const std::string& out_dir, cv::Mat1f* dtm, std::string* error) {
  sfm::TerrainReport terrain;
  *dtm = sfm::TerrainFromDsm(result.dsm, -9999.0f, result.grid.cell, sfm::TerrainOptions{}, nullptr, &terrain);
  result.summary["terrain"] = terrain.ToJson();
  return sfm::WriteDsmGeoTiff(out_dir + "/dtm.tif", *dtm, result.grid, result.offset, result.crs_wkt, -9999.0f,
                              error) &&
         sfm::WriteDsmFillMask(out_dir + "/dsm_filled.tif", result.dsm_provenance, result.grid, result.offset,
                               result.crs_wkt, error);
}

// The true orthophoto's files (core/sfm/ortho_files.h), its figures in the summary and its pictures for the report.
bool WriteOrtho(sfm::ReconstructionResult& result, const cv::Mat1f& dtm, const std::string& session_dir,
                const sfm::OrthoOptions& ortho, const std::string& out_dir, bool mbtiles, sfm::ReportPictures* pictures,
                std::vector<std::string>* outputs, std::string* error) {
  auto& js = result.summary;
  // The onboard gains and shading divided out of each frame, as the onboard map did (none when the session has none).
  std::string no_radiometry;
  const sfm::OrthoFrameCorrection correct = sfm::SessionRadiometryCorrection(session_dir, result.rec, &no_radiometry);
  sfm::OrthoFiles files;
  files.cog = out_dir + "/ortho.tif";
  files.quicklook = out_dir + "/ortho_preview.png";
  if (mbtiles && !result.crs_wkt.empty()) files.mbtiles = out_dir + "/ortho.mbtiles";
  if (!result.crs_wkt.empty()) files.tiles_dir = out_dir + "/tiles";
  sfm::OrthoFilesReport report;
  const auto t_ortho = std::chrono::steady_clock::now();
  // The orthophoto's surface has no hole: where dsm.tif stays empty (farther than --dsm-fill from a measurement:
  // water, a uniform field) the interpolated surface still places the frames' pixels, which on such ground are
  // flat; without it those pixels were holes in the map.
  cv::Mat1f surface = result.dsm.clone();
  (void)sfm::FillDsmHoles(&surface, -9999.0f, std::max(surface.rows, surface.cols));
  if (!sfm::WriteOrthophoto(result.rec, result.image_paths, surface, dtm, result.grid, -9999.0f, result.offset,
                            result.crs_wkt, ortho, files, correct, &report, error))
    return false;
  js["ortho"] = report.ToJson();
  js["ortho"]["radiometry"] =
      correct ? "the onboard gains and shading (radiometry.csv, report.json)" : "none: " + no_radiometry;
  for (const auto& w : report.warnings) {
    std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", w.c_str());
    js["warnings"].push_back(w);
  }
  js["ortho"]["origin"] = {report.ortho.grid.x0 + result.offset.x(), report.ortho.grid.y0 + result.offset.y()};
  js["timings"]["ortho_s"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_ortho).count();
  const RssSample rss = SampleRss();
  js["stage_memory_mib"]["ortho_s"] = {{"rss_end", rss.rss_mib}, {"peak_so_far", rss.hwm_mib}};
  pictures->ortho = cv::imread(files.quicklook, cv::IMREAD_UNCHANGED);
  pictures->overlap = report.ortho.overlap;
  outputs->insert(outputs->end(), {"ortho.tif", "ortho_preview.png"});
  if (report.mbtiles_written) outputs->push_back("ortho.mbtiles");
  if (report.web_tiles > 0) outputs->push_back("tiles/");
  return true;
}

// What was made: the dense points are the fused cloud's (cloud.ply holds the sparse points when there is none).
void PrintClosingLine(const sfm::ReconstructionResult& result) {
  const auto& js = result.summary;
  std::string ortho_line = "no orthophoto";
  if (js.contains("ortho"))
    ortho_line = fmt::format("orthophoto {}x{} px at {:.3f} from {} frames", js["ortho"]["size"][0].get<int>(),
                             js["ortho"]["size"][1].get<int>(), js["ortho"]["gsd"].get<double>(),
                             js["ortho"]["images_used"].get<int>());
  std::fprintf(stderr,
               "uavmosaic-ground: %zu frames (%zu left out), %zu sparse points, BA RMS %.3f -> %.3f px, %zu dense "
               "points, DSM from the %s points (%.0f %% of it filled), %s\n",
               result.rec.images.size(), js.value("frames_not_used", nlohmann::json::array()).size(),
               result.rec.points.size(), js.value("ba_rms_before_px", 0.0), js.value("ba_rms_after_px", 0.0),
               js.value("dense_points", size_t{0}), js.value("dsm_source", std::string("sparse")).c_str(),
               100.0 * js.value("dsm_filled_fraction", 0.0), ortho_line.c_str());
}

// --render-previews: the cloud seen from above, the DSM and the DTM as PNGs.
void WritePreviews(const sfm::ReconstructionResult& result, const sfm::ReportPictures& pictures,
                   const std::string& out_dir) {
  const std::vector<int> png = {cv::IMWRITE_PNG_COMPRESSION, 9};
  cv::imwrite(out_dir + "/preview_cloud.png", sfm::RenderCloudTopView(result.dense, 900), png);
  cv::imwrite(out_dir + "/preview_dsm.png", pictures.dsm, png);
  cv::imwrite(out_dir + "/preview_dtm.png", pictures.dtm, png);
}

// Each stage's progress on one stderr line, from any thread.
class StderrProgress {
 public:
  void operator()(const std::string& stage, size_t done, size_t total) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::fprintf(stderr, "\r[%s] %zu/%zu%s", stage.c_str(), done, total, done == total ? "\n" : "");
    std::fflush(stderr);
  }

 private:
  std::mutex mutex_;
};

}  // namespace

int RunReconstructCommand(int argc, char** argv) {
  CLI::App app{"uavmosaic-ground: sparse + dense 3-D reconstruction of a uavmosaic session directory"};
  std::string session_dir, out_dir;
  sfm::ReconstructionOptions opts;
  opts.threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  bool previews = false;
  bool no_dense = false;
  std::string dense_cost = "census";
  app.add_option("session", session_dir, "session directory written by uavmosaic-onboard")->required();
  app.add_option("--out", out_dir, "output directory (created)")->required();
  app.add_option("--threads", opts.threads, "worker threads (features, matching, bundle adjustment)");
  AddReconstructionOptions(&app, &opts, &dense_cost);
  app.add_flag("--no-dense", no_dense, "sparse only (the DSM is rasterised from the sparse points)");
  app.add_flag("--render-previews", previews, "write preview_cloud.png, preview_dsm.png and preview_dtm.png");
  sfm::OrthoOptions ortho;
  bool no_ortho = false;
  bool no_mbtiles = false;
  AddOrthoOptions(&app, &ortho, &no_ortho, &no_mbtiles);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }
  opts.dense = !no_dense;
  ortho.threads = opts.threads;
  opts.dense_daisy = dense_cost == "daisy";
  std::string error;
  if (!opts.Check(&error) || !ortho.Check(&error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitUsage;
  }
  std::error_code ec;
  std::filesystem::create_directories(out_dir + "/sparse", ec);
  if (ec) {
    std::fprintf(stderr, "uavmosaic-ground: cannot create %s: %s\n", out_dir.c_str(), ec.message().c_str());
    return kExitOutputError;
  }
  opts.camera_model = CameraModelOf(session_dir);
  StderrProgress progress;
  sfm::ReconstructionResult result;
  if (!sfm::RunReconstruction(session_dir, opts, std::ref(progress), &result, &error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitReconstructionFailed;
  }
  if (result.dense.empty()) {  // neither dense nor sparse points: no product to write
    std::fprintf(stderr, "uavmosaic-ground: no point was reconstructed (summary: %s)\n", result.summary.dump().c_str());
    return kExitReconstructionFailed;
  }
  const auto t_out = std::chrono::steady_clock::now();
  auto& js = result.summary;
  if (!sfm::WritePly(out_dir + "/cloud.ply", result.dense, &error) ||
      !sfm::WriteColmapText(result.rec, out_dir + "/sparse", &error) ||
      !sfm::WriteDsmGeoTiff(out_dir + "/dsm.tif", result.dsm, result.grid, result.offset, result.crs_wkt, -9999.0f,
                            &error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitOutputError;
  }
  std::vector<std::string> outputs = {"cloud.ply", "dsm.tif", "dsm_filled.tif", "dtm.tif"};
  cv::Mat1f dtm;
  if (!WriteTerrain(result, out_dir, &dtm, &error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitOutputError;
  }
  sfm::ReportPictures pictures;
  pictures.dsm = sfm::RenderDsm(result.dsm, -9999.0f, 900);
  pictures.dtm = sfm::RenderDsm(dtm, -9999.0f, 900);
  if (!no_ortho && !WriteOrtho(result, dtm, session_dir, ortho, out_dir, !no_mbtiles, &pictures, &outputs, &error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitOutputError;
  }
  if (previews) WritePreviews(result, pictures, out_dir);
  js["camera_model_exif"] = opts.camera_model;
  js["coordinates"] = {{"ply_and_colmap_offset_xy", {result.offset.x(), result.offset.y()}},
                       {"note",
                        "cloud.ply and sparse/ are in local coordinates: add the offset for the CRS ("
                        "dsm.tif is georeferenced with it)"}};
  outputs.insert(outputs.end(), {"sparse/cameras.txt", "sparse/images.txt", "sparse/points3D.txt", "report.html"});
  js["outputs"] = outputs;
  js["timings"]["write_s"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_out).count();
  if (!sfm::WriteReportHtml(out_dir + "/report.html", js, pictures, &error)) {
    std::fprintf(stderr, "uavmosaic-ground: %s\n", error.c_str());
    return kExitOutputError;
  }
  std::ofstream(out_dir + "/summary.json") << js.dump(2) << '\n';
  PrintClosingLine(result);
  return kExitOk;
}

}  // namespace uavm::ground
