#include "core/sfm/run_reconstruction.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

#include "core/geometry/similarity.h"
#include "core/sfm/dense_stage.h"
#include "core/sfm/feature_stage.h"
#include "core/sfm/frame_selection.h"
#include "core/sfm/gcp_stage.h"
#include "core/sfm/initial_poses.h"
#include "core/sfm/pair_matching.h"
#include "core/sfm/sparse_stage.h"
#include "core/util/memory.h"

namespace uavm::sfm {

namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Records each stage's wall time under its key of the summary's "timings", and the process's memory when it ends
// under "stage_memory_mib" (resident, and the high-water mark so far: a stage that raised it holds the peak).
class StageTimes {
 public:
  template <typename Stage>
  bool Run(const char* key, Stage&& stage) {
    const auto t0 = Clock::now();
    const bool ok = stage();
    json_[key] = Seconds(t0);
    const RssSample rss = SampleRss();
    memory_[key] = {{"rss_end", rss.rss_mib}, {"peak_so_far", rss.hwm_mib}};
    return ok;
  }
  nlohmann::json Finish() {
    json_["total_s"] = Seconds(start_);
    return json_;
  }
  [[nodiscard]] const nlohmann::json& memory() const { return memory_; }

 private:
  Clock::time_point start_ = Clock::now();
  nlohmann::json json_ = nlohmann::json::object();
  nlohmann::json memory_ = nlohmann::json::object();
};

// 7. Georeferencing: similarity of the adjusted centres onto GPS (E, N, relative altitude).
void Georeference(const GpsPositions& gps, Reconstruction* rec, nlohmann::json* js) {
  std::vector<Eigen::Vector3d> src, dst;
  for (size_t i = 0; i < rec->images.size(); ++i) {
    if (gps.local[i] && std::isfinite(gps.local[i]->z())) {
      src.push_back(rec->images[i].pose.c);
      dst.push_back(*gps.local[i]);
    }
  }
  Similarity3 fit;
  if (src.size() < 3 || !FitSimilarity<3>(src, dst, &fit)) {
    (*js)["georef"] = {{"method", "none"}};
    return;
  }
  rec->Transform(fit);
  double sum = 0.0;
  for (size_t k = 0; k < src.size(); ++k) sum += (fit.Apply(src[k]) - dst[k]).squaredNorm();
  (*js)["georef"] = {{"method", "similarity to GPS camera positions"},
                     {"cameras", src.size()},
                     {"scale", fit.scale},
                     {"rms_m", std::sqrt(sum / static_cast<double>(src.size()))},
                     {"z_reference", "relative altitude (take-off = 0) when in EXIF, else GPS altitude"}};
}

void SetCrs(const InitialModel& init, const GcpInput* gcp, ReconstructionResult* result) {
  auto& js = result->summary;
  result->offset = init.gps.origin;
  if (gcp != nullptr) {
    result->offset = gcp->offset;
    result->crs_wkt = gcp->crs.wkt();
    result->epsg = gcp->crs.epsg();
    js["crs"] = gcp->crs.name();
    js["crs_source"] =
        gcp->crs.converted_from_geographic() ? "GCP file (geographic, projected to its UTM zone)" : "GCP file";
    js["z_reference"] = gcp->horizontal_only ? "the flight's GPS altitude (GCPs horizontal only)" : "the GCPs' heights";
  } else if (init.gps.projected) {
    result->crs_wkt = init.gps.crs_wkt;
    result->epsg = init.gps.epsg;
    js["crs"] = "EPSG:" + std::to_string(init.gps.epsg);
  } else {
    js["crs"] = nullptr;
    js["crs_note"] = "no GPS: local coordinates without a CRS (" + init.pose_source + ")";
  }
}

// Per image for the report: its name, camera, centre and GPS position in the map's coordinates (GPS only when the map
// is georeferenced by it, not by GCPs), its reprojection residuals.
nlohmann::json ImagesJson(const Reconstruction& rec, const GpsPositions& gps, bool gcp, const Eigen::Vector2d& offset) {
  nlohmann::json list = nlohmann::json::array();
  const auto residuals = rec.ResidualsPerImage();
  for (size_t i = 0; i < rec.images.size(); ++i) {
    const Image& im = rec.images[i];
    nlohmann::json js = {{"name", im.name},
                         {"camera", im.camera},
                         {"centre", {im.pose.c.x() + offset.x(), im.pose.c.y() + offset.y(), im.pose.c.z()}},
                         {"observations", residuals[i].observations},
                         {"rms_px", residuals[i].rms_px}};
    if (!gcp && gps.projected && gps.local[i])
      js["gps"] = {gps.local[i]->x() + gps.origin.x(), gps.local[i]->y() + gps.origin.y(), gps.local[i]->z()};
    list.push_back(js);
  }
  return list;
}

}  // namespace

// The stages in order; each reads the earlier ones' outputs and adds its figures to the summary.
bool RunReconstruction(const std::string& session_dir, const ReconstructionOptions& options, const ProgressFn& progress,
                       ReconstructionResult* result, std::string* error) {
  if (!options.Check(error)) return false;
  auto& js = result->summary;
  js = nlohmann::json::object();
  StageTimes times;
  SelectedFrames sel;
  std::vector<FrameFeatures> feats;
  std::vector<FeatureMatch> matches;
  std::vector<Track> tracks;
  InitialModel init;
  Reconstruction& rec = result->rec;
  DenseCloud dense;
  std::unique_ptr<GcpInput> gcp;
  const auto& frames = sel.frames;
  const bool ok = times.Run("import_s", [&] {
    if (!SelectFrames(session_dir, &sel, error)) return false;
    js["frames_not_used"] = LeftOutJson(sel);
    return BindGcpFile(sel, options, &gcp, &js, error);  // read and checked before the long stages
  }) && times.Run("features_s", [&] {
    const size_t left_out = sel.left_out.size();
    if (!ExtractFeatures(session_dir, &sel, options, progress, &feats, &js, error)) return false;
    // An unreadable frame moved the image slots that the GCPs' clicks are bound to.
    return sel.left_out.size() == left_out || BindGcpFile(sel, options, &gcp, &js, error);
  }) && times.Run("matching_s", [&] {
    matches = MatchGraphPairs(sel, feats, options, progress, &js);
    return true;
  }) && times.Run("tracks_s", [&] {
    TrackStats tstats;
    tracks = BuildTracks(matches, 2, &tstats);
    js["tracks"] = tracks.size();
    js["track_conflicts_split"] = tstats.conflicts_refused;
    return true;
  }) && times.Run("initial_poses_s", [&] {
    return InitialPoses(frames, feats, sel.session.lens, options, &rec, &init, &js, error);
  }) && times.Run("bundle_s", [&] {
    return TriangulateAndAdjust(frames, feats, tracks, init, options, progress, &rec, &js, error);
  }) && times.Run("georef_s", [&] {
    Georeference(init.gps, &rec, &js);
    SetCrs(init, gcp.get(), result);
    return true;
  }) && times.Run("gcp_s", [&] {
    return !gcp || AdjustToGcps(frames, init, gcp.get(), options, &rec, &js, error);
  }) && times.Run("dense_s", [&] {
    return DenseStage(session_dir, frames, rec, options, progress, &dense, &js, error);
  }) && times.Run("fusion_dsm_s", [&] {
    SurfaceModel surface = FuseAndRasterize(dense, rec, options, &js);
    result->dense = std::move(surface.cloud);
    result->dsm = std::move(surface.dsm);
    result->dsm_provenance = std::move(surface.dsm_provenance);
    result->grid = surface.grid;
    return true;
  });
  if (!ok) return false;
  for (const auto* f : frames) result->image_paths.push_back(session_dir + "/" + f->stored_file);
  js["images"] = ImagesJson(rec, init.gps, gcp != nullptr, result->offset);
  js["timings"] = times.Finish();
  js["stage_memory_mib"] = times.memory();
  js["frames_used"] = frames.size();
  return true;
}

}  // namespace uavm::sfm
