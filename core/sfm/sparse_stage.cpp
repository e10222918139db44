#include "core/sfm/sparse_stage.h"

#include <cmath>

#include "core/sfm/triangulation.h"

namespace uavm::sfm {

void TriangulateAll(const std::vector<Track>& tracks, const std::vector<FrameFeatures>& feats, double min_angle_deg,
                    double max_err, Reconstruction* rec) {
  rec->points.clear();
  for (const auto& tr : tracks) {
    std::vector<Pose> poses;
    std::vector<Eigen::Vector2d> xn;
    for (const auto& o : tr) {
      poses.push_back(rec->images[static_cast<size_t>(o.image)].pose);
      const Image& im = rec->images[static_cast<size_t>(o.image)];
      xn.push_back(rec->CameraOf(im).Undistort(im.keypoints[static_cast<size_t>(o.feature)]));
    }
    const auto X = TriangulateDlt(poses, xn);
    if (!X) continue;
    if (MaxTriangulationAngleDeg(poses, *X) < min_angle_deg) continue;
    Point3D p;
    p.X = *X;
    double sum = 0.0;
    for (size_t k = 0; k < tr.size(); ++k) {
      const auto proj = Project(rec->CameraOf(tr[k].image), poses[k], *X);
      const auto& kp = rec->images[static_cast<size_t>(tr[k].image)].keypoints[static_cast<size_t>(tr[k].feature)];
      const double e = proj ? (*proj - kp).norm() : 1e9;
      if (e <= max_err) {
        p.track.push_back(tr[k]);
        sum += e;
      }
    }
    if (p.track.size() < 2) continue;
    p.error_px = sum / static_cast<double>(p.track.size());
    p.bgr = feats[static_cast<size_t>(p.track[0].image)].colors[static_cast<size_t>(p.track[0].feature)];
    rec->points.push_back(std::move(p));
  }
}

BundlePriors MakeBundlePriors(const std::vector<const SessionFrame*>& frames, const InitialModel& init,
                              const ReconstructionOptions& options, nlohmann::json* js) {
  BundlePriors priors;
  // A nadir flight over nearly flat ground cannot tell focal length from depth: the EXIF focal length stays as a prior
  // (1 % when the sensor is known, 10 % for a guess).
  priors.focal_sigma = init.guess.source == "exif+sensor" ? 0.01 : 0.1;
  priors.centres.resize(frames.size());
  int n_priors = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    const auto& g = init.gps.local[i];
    if (g && std::isfinite(g->z()) && frames[i]->relative_altitude_m && options.colmap_import_dir.empty()) {
      priors.centres[i] = *g;
      ++n_priors;
    }
  }
  (*js)["ba_centre_priors"] = n_priors;
  (*js)["ba_focal_prior_sigma"] = priors.focal_sigma;
  priors.focal_ratio = init.focal_ratio;
  return priors;
}

void TieFocals(const BundlePriors& priors, int min_images, Reconstruction* rec, BundleOptions* bo) {
  bo->focal_held.assign(rec->cameras.size(), 0);
  if (priors.focal_ratio.size() != rec->cameras.size()) return;
  const std::vector<int> images = ImagesPerCamera(*rec);
  const Camera& main = rec->cameras[MostUsedCamera(*rec)];
  for (size_t k = 0; k < rec->cameras.size(); ++k) {
    if (priors.focal_ratio[k] <= 0.0 || images[k] >= min_images) continue;
    rec->cameras[k].fx = rec->cameras[k].fy = main.fx * priors.focal_ratio[k];
    bo->focal_held[k] = 1;
  }
}

namespace {

// Drops observations above max_err from the adjusted points (without re-triangulating).
void FilterObservations(double min_angle_deg, double max_err, Reconstruction* rec) {
  std::vector<Point3D> kept;
  for (auto& p : rec->points) {
    Track t;
    double sum = 0.0;
    for (const auto& o : p.track) {
      const auto& im = rec->images[static_cast<size_t>(o.image)];
      const auto proj = Project(rec->CameraOf(im), im.pose, p.X);
      const double e = proj ? (*proj - im.keypoints[static_cast<size_t>(o.feature)]).norm() : 1e9;
      if (e <= max_err) {
        t.push_back(o);
        sum += e;
      }
    }
    if (t.size() < 2) continue;
    std::vector<Pose> poses;
    for (const auto& o : t) poses.push_back(rec->images[static_cast<size_t>(o.image)].pose);
    if (MaxTriangulationAngleDeg(poses, p.X) < min_angle_deg) continue;
    p.track = std::move(t);
    p.error_px = sum / static_cast<double>(p.track.size());
    kept.push_back(std::move(p));
  }
  rec->points = std::move(kept);
}

// The BA rounds: each adjusts, re-triangulates every track with the adjusted poses (recovers points the rough poses
// lost) and rejects above the round's threshold; a final BA on the cleaned set gives the reported before/after pair.
bool BundleRounds(const std::vector<Track>& tracks, const std::vector<FrameFeatures>& feats, const BundlePriors& priors,
                  const ReconstructionOptions& options, const ProgressFn& progress, Reconstruction* rec,
                  nlohmann::json* rounds, std::string* error) {
  BundleOptions base;
  base.threads = options.threads;
  base.focal_prior_sigma = priors.focal_sigma;
  base.fixed_image = 0;
  base.centre_priors = priors.centres;
  for (size_t r = 0; r < options.round_reprojection_px.size(); ++r) {
    BundleOptions bo = base;
    bo.loss = r == 0 ? BundleOptions::Loss::kCauchy : BundleOptions::Loss::kHuber;
    bo.loss_scale_px = r == 0 ? 4.0 : 1.0;
    bo.refine_k3 = options.refine_k3 && r > 0;
    bo.max_iterations = 50;
    TieFocals(priors, bo.min_images_for_lens, rec, &bo);
    BundleSummary bs;
    if (!BundleAdjust(rec, bo, &bs, error)) return false;
    if (progress) progress("bundle", r + 1, options.round_reprojection_px.size());
    const double thr = options.round_reprojection_px[r];
    TriangulateAll(tracks, feats, options.min_triangulation_angle_deg, thr, rec);
    rounds->push_back({{"rms_before_px", bs.rms_before_px},
                       {"rms_after_px", bs.rms_after_px},
                       {"iterations", bs.iterations},
                       {"seconds", bs.seconds},
                       {"reject_above_px", thr},
                       {"points_after_reject", rec->points.size()},
                       {"rms_after_reject_px", rec->ReprojectionRms()}});
  }
  BundleOptions bo = base;
  bo.loss = BundleOptions::Loss::kHuber;
  bo.loss_scale_px = 1.0;
  bo.refine_k3 = options.refine_k3;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);
  BundleSummary bs;
  if (!BundleAdjust(rec, bo, &bs, error)) return false;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);  // to the main camera as the last adjustment left it
  FilterObservations(options.min_triangulation_angle_deg, options.round_reprojection_px.back(), rec);
  rounds->push_back({{"rms_before_px", bs.rms_before_px},
                     {"rms_after_px", bs.rms_after_px},
                     {"iterations", bs.iterations},
                     {"seconds", bs.seconds},
                     {"final", true},
                     {"points", rec->points.size()}});
  return true;
}

}  // namespace

bool TriangulateAndAdjust(const std::vector<const SessionFrame*>& frames, const std::vector<FrameFeatures>& feats,
                          const std::vector<Track>& tracks, const InitialModel& init,
                          const ReconstructionOptions& options, const ProgressFn& progress, Reconstruction* rec,
                          nlohmann::json* js, std::string* error) {
  TriangulateAll(tracks, feats, options.min_triangulation_angle_deg, options.initial_reprojection_px, rec);
  size_t obs_tracks = 0;
  for (const auto& t : tracks) obs_tracks += t.size();
  (*js)["initial_points"] = rec->points.size();
  const double rms_initial = rec->ReprojectionRms();
  (*js)["ba_rms_initial_px"] = rms_initial;
  if (rec->points.size() < 20) {
    *error = "too few points triangulate with the initial poses (" + std::to_string(rec->points.size()) + ")";
    return false;
  }
  const BundlePriors priors = MakeBundlePriors(frames, init, options, js);
  nlohmann::json rounds = nlohmann::json::array();
  if (!BundleRounds(tracks, feats, priors, options, progress, rec, &rounds, error)) return false;
  (*js)["ba_rounds"] = rounds;
  (*js)["ba_rms_before_px"] = rms_initial;  // with the initial poses, all first-triangulated points
  (*js)["ba_rms_after_px"] = rec->ReprojectionRms();
  (*js)["ba_rms_units"] = "original-resolution pixels";
  (*js)["observations_in_tracks"] = obs_tracks;
  (*js)["observations_kept"] = rec->NumObservations();
  (*js)["sparse_points"] = rec->points.size();
  // Each camera (one per image size) with its images; "camera" is the one most images use.
  const std::vector<int> images_of = ImagesPerCamera(*rec);
  nlohmann::json cameras = nlohmann::json::array();
  for (size_t k = 0; k < rec->cameras.size(); ++k) {
    const Camera& c = rec->cameras[k];
    cameras.push_back({{"width", c.width},
                       {"height", c.height},
                       {"images", images_of[k]},
                       {"fx", c.fx},
                       {"fy", c.fy},
                       {"cx", c.cx},
                       {"cy", c.cy},
                       {"k1", c.k1},
                       {"k2", c.k2},
                       {"p1", c.p1},
                       {"p2", c.p2},
                       {"k3", c.k3}});
  }
  (*js)["camera"] = cameras[MostUsedCamera(*rec)];
  (*js)["cameras"] = cameras;
  return true;
}

}  // namespace uavm::sfm
