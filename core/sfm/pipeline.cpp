#include "core/sfm/pipeline.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <opencv2/calib3d.hpp>
#include <opencv2/flann.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <unordered_map>

#include "core/features/sift.h"
#include "core/geometry/similarity.h"
#include "core/sfm/colmap_io.h"
#include "core/sfm/dense.h"
#include "core/util/parallel.h"

namespace uavm::sfm {

bool PipelineOptions::Check(std::string* why) const {
  auto fail = [&](const char* m) {
    *why = m;
    return false;
  };
  if (threads < 1) return fail("--threads must be >= 1");
  if (!(feature_scale > 0.0 && feature_scale <= 1.0)) return fail("feature_scale must be in (0,1]");
  if (max_features < 100) return fail("max_features must be >= 100");
  if (!(ratio > 0.0 && ratio < 1.0)) return fail("ratio must be in (0,1)");
  if (!(fundamental_threshold_px > 0.0)) return fail("fundamental_threshold_px must be > 0");
  if (round_reprojection_px.empty()) return fail("round_reprojection_px needs at least one round");
  if (!(dense_image_scale > 0.0 && dense_image_scale <= 1.0)) return fail("dense_image_scale must be in (0,1]");
  if (dense_sample_step < 1 || fusion_min_pairs < 1) return fail("dense_sample_step, fusion_min_pairs >= 1");
  return true;
}

namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

struct FrameFeatures {
  std::vector<Eigen::Vector2d> points;  // original-resolution pixels
  std::vector<cv::Vec3b> colors;
  cv::Mat descriptors;
};

// Nearest orthogonal matrix (may be a reflection).
Eigen::Matrix2d Polar(const Eigen::Matrix2d& m) {
  const Eigen::JacobiSVD<Eigen::Matrix2d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU() * svd.matrixV().transpose();
}

cv::Mat ReadFrame(const std::string& path) {
  return cv::imread(path, cv::IMREAD_COLOR);
}

}  // namespace

bool RunPipeline(const std::string& session_dir, const PipelineOptions& options, const ProgressFn& progress,
                 PipelineResult* result, std::string* error) {
  if (!options.Check(error)) return false;
  auto& js = result->summary;
  js = nlohmann::json::object();
  nlohmann::json timings = nlohmann::json::object();
  const auto t_total = Clock::now();

  // 1. Session.
  auto t0 = Clock::now();
  Session session;
  if (!ReadSession(session_dir, &session, error)) return false;
  std::set<int> in_graph;
  for (const auto& e : session.edges) {
    if (e.used) {
      in_graph.insert(e.src);
      in_graph.insert(e.tgt);
    }
  }
  std::vector<const SessionFrame*> frames;
  for (const auto& f : session.frames) {
    if (f.registered && f.has_transform && in_graph.count(f.index) && !f.stored_file.empty()) frames.push_back(&f);
  }
  if (frames.size() < 2) {
    *error = "fewer than two registered frames with used graph edges in " + session_dir;
    return false;
  }
  std::map<int, size_t> slot_of;  // session index -> image slot
  for (size_t i = 0; i < frames.size(); ++i) slot_of[frames[i]->index] = i;
  timings["import_s"] = Seconds(t0);

  // 2. Features at full (or feature_scale) resolution.
  t0 = Clock::now();
  std::vector<FrameFeatures> feats(frames.size());
  std::vector<std::string> failures(frames.size());
  std::atomic<size_t> done{0};
  FeatureOptions fo;
  fo.max_features = options.max_features;
  // A higher start threshold than the onboard one: offline, repeatable (contrasted) keypoints matter more than many.
  fo.contrast_threshold = options.contrast_threshold;
  fo.target_min_features = options.max_features / 4;
  fo.max_scale_space_mib = 1200;  // bands the 4000 px frames: two threads stay within a few GiB
  const SiftExtractor sift(fo);
  // Each worker runs a single-threaded SIFT; OpenCV's own pool would oversubscribe the cores.
  const int cv_threads = cv::getNumThreads();
  cv::setNumThreads(options.threads > 1 ? 1 : cv_threads);
  ParallelFor(frames.size(), options.threads, [&](size_t i) {
    const cv::Mat img = ReadFrame(session_dir + "/" + frames[i]->stored_file);
    if (img.empty()) {
      failures[i] = "cannot read " + frames[i]->stored_file;
      return;
    }
    cv::Mat gray, work;
    cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
    const double s = options.feature_scale;
    if (s < 1.0) {
      cv::resize(gray, work, cv::Size(), s, s, cv::INTER_AREA);
    } else {
      work = gray;
    }
    Features f = sift.Extract(work);
    FrameFeatures& out = feats[i];
    out.descriptors = f.descriptors;
    for (const auto& p : f.points) {
      const double x = (p.x + 0.5) / s - 0.5, y = (p.y + 0.5) / s - 0.5;
      out.points.emplace_back(x, y);
      const int xi = std::clamp(static_cast<int>(std::lround(x)), 0, img.cols - 1);
      const int yi = std::clamp(static_cast<int>(std::lround(y)), 0, img.rows - 1);
      out.colors.push_back(img.at<cv::Vec3b>(yi, xi));
    }
    if (progress) progress("features", ++done, frames.size());
  });
  cv::setNumThreads(cv_threads);
  for (const auto& f : failures) {
    if (!f.empty()) {
      *error = f;
      return false;
    }
  }
  timings["features_s"] = Seconds(t0);
  size_t total_kp = 0;
  for (const auto& f : feats) total_kp += f.points.size();
  js["keypoints_per_frame_mean"] = static_cast<double>(total_kp) / static_cast<double>(frames.size());

  // 3. Matching of graph.csv's used pairs, verified by RANSAC on F.
  t0 = Clock::now();
  std::vector<std::pair<size_t, size_t>> pairs;
  for (const auto& e : session.edges) {
    if (e.used && slot_of.count(e.src) && slot_of.count(e.tgt)) pairs.emplace_back(slot_of[e.src], slot_of[e.tgt]);
  }
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  std::vector<std::vector<FeatureMatch>> pair_matches(pairs.size());
  std::vector<std::array<int, 2>> pair_counts(pairs.size(), {0, 0});  // candidates, F inliers
  done = 0;
  ParallelFor(pairs.size(), options.threads, [&](size_t k) {
    const auto [a, b] = pairs[k];
    const FrameFeatures& fa = feats[a];
    const FrameFeatures& fb = feats[b];
    if (fa.points.size() < 8 || fb.points.size() < 8) return;
    // Guided matching: the onboard maps predict where a keypoint of `a` lies in `b`; only keypoints of `b` within
    // guided_radius of that prediction are candidates. At full resolution this keeps the ratio test meaningful (the
    // unguided nearest neighbour among 8000 fine-scale features is too often a look-alike).
    const Mat3 b_from_a = frames[b]->mosaic_from_frame.inverse() * frames[a]->mosaic_from_frame;
    const double radius = options.guided_radius * std::max(frames[a]->width, frames[a]->height);
    const double cell = radius;
    const int gw = static_cast<int>(frames[b]->width / cell) + 1, gh = static_cast<int>(frames[b]->height / cell) + 1;
    std::vector<std::vector<int>> grid(static_cast<size_t>(gw * gh));
    for (size_t j = 0; j < fb.points.size(); ++j) {
      const int gx = std::clamp(static_cast<int>(fb.points[j].x() / cell), 0, gw - 1);
      const int gy = std::clamp(static_cast<int>(fb.points[j].y() / cell), 0, gh - 1);
      grid[static_cast<size_t>(gy * gw + gx)].push_back(static_cast<int>(j));
    }
    // Best and second-best candidate per keypoint of a; best per keypoint of b (for the mutual check).
    std::vector<int> best_a(fa.points.size(), -1);
    std::vector<float> d1_a(fa.points.size(), 1e30f), d2_a(fa.points.size(), 1e30f);
    std::vector<int> best_b(fb.points.size(), -1);
    std::vector<float> d1_b(fb.points.size(), 1e30f);
    for (size_t i = 0; i < fa.points.size(); ++i) {
      const Vec2 q = Apply(b_from_a, fa.points[i]);
      const int gx = static_cast<int>(std::floor(q.x() / cell)), gy = static_cast<int>(std::floor(q.y() / cell));
      const cv::Mat da = fa.descriptors.row(static_cast<int>(i));
      for (int y = gy - 1; y <= gy + 1; ++y) {
        for (int x = gx - 1; x <= gx + 1; ++x) {
          if (x < 0 || y < 0 || x >= gw || y >= gh) continue;
          for (int j : grid[static_cast<size_t>(y * gw + x)]) {
            if ((fb.points[static_cast<size_t>(j)] - q).norm() > radius) continue;
            const float d = static_cast<float>(cv::norm(da, fb.descriptors.row(j), cv::NORM_L2SQR));
            if (d < d1_a[i]) {
              d2_a[i] = d1_a[i];
              d1_a[i] = d;
              best_a[i] = j;
            } else if (d < d2_a[i]) {
              d2_a[i] = d;
            }
            if (d < d1_b[static_cast<size_t>(j)]) {
              d1_b[static_cast<size_t>(j)] = d;
              best_b[static_cast<size_t>(j)] = static_cast<int>(i);
            }
          }
        }
      }
    }
    std::vector<cv::Point2f> pa, pb;
    std::vector<FeatureMatch> cand;
    const float r2 = static_cast<float>(options.ratio * options.ratio);  // squared distances
    for (size_t i = 0; i < fa.points.size(); ++i) {
      const int j = best_a[i];
      if (j < 0 || d1_a[i] > r2 * d2_a[i]) continue;
      if (best_b[static_cast<size_t>(j)] != static_cast<int>(i)) continue;  // mutual best
      cand.push_back({static_cast<int>(a), static_cast<int>(i), static_cast<int>(b), j, d1_a[i]});
      pa.emplace_back(static_cast<float>(fa.points[i].x()), static_cast<float>(fa.points[i].y()));
      pb.emplace_back(static_cast<float>(fb.points[static_cast<size_t>(j)].x()),
                      static_cast<float>(fb.points[static_cast<size_t>(j)].y()));
    }
    pair_counts[k][0] = static_cast<int>(cand.size());
    if (static_cast<int>(cand.size()) >= options.min_pair_inliers) {
      std::vector<uchar> mask;
      const cv::Mat F = cv::findFundamentalMat(pa, pb, cv::FM_RANSAC, options.fundamental_threshold_px, 0.9999, mask);
      if (!F.empty()) {
        std::vector<FeatureMatch> inl;
        for (size_t i = 0; i < cand.size(); ++i) {
          if (mask[i]) inl.push_back(cand[i]);
        }
        pair_counts[k][1] = static_cast<int>(inl.size());
        if (static_cast<int>(inl.size()) >= options.min_pair_inliers) pair_matches[k] = std::move(inl);
      }
    }
    if (progress) progress("matching", ++done, pairs.size());
  });
  std::vector<FeatureMatch> all_matches;
  int pairs_ok = 0;
  for (auto& m : pair_matches) {
    if (!m.empty()) ++pairs_ok;
    all_matches.insert(all_matches.end(), m.begin(), m.end());
  }
  timings["matching_s"] = Seconds(t0);
  js["pairs_listed"] = pairs.size();
  js["pairs_verified"] = pairs_ok;
  {
    nlohmann::json jp = nlohmann::json::array();
    for (size_t k = 0; k < pairs.size(); ++k) {
      jp.push_back(
          {frames[pairs[k].first]->index, frames[pairs[k].second]->index, pair_counts[k][0], pair_counts[k][1]});
    }
    js["pair_matches"] = jp;  // [src, tgt, guided candidates, F inliers]
  }
  js["matches"] = all_matches.size();

  // 4. Tracks.
  t0 = Clock::now();
  TrackStats tstats;
  std::vector<Track> tracks = BuildTracks(all_matches, 2, &tstats);
  js["tracks"] = tracks.size();
  js["track_conflicts_split"] = tstats.conflicts_refused;
  timings["tracks_s"] = Seconds(t0);

  // 5. Camera and initial poses.
  t0 = Clock::now();
  Reconstruction& rec = result->rec;
  rec = Reconstruction{};
  const SessionFrame& f0 = *frames[0];
  const auto guess = GuessIntrinsics(f0.width, f0.height, f0.focal_length_mm.value_or(0.0), options.camera_model,
                                     options.default_hfov_deg);
  rec.camera = guess.camera;
  js["intrinsics_source"] = guess.source;
  js["focal_initial_px"] = rec.camera.fx;
  for (size_t i = 0; i < frames.size(); ++i) {
    Image im;
    im.frame_index = frames[i]->index;
    im.name = frames[i]->stored_file.substr(frames[i]->stored_file.find_last_of('/') + 1);
    im.keypoints = feats[i].points;
    rec.images.push_back(std::move(im));
  }
  // GPS -> UTM (origin at the first GPS frame, so the solver works with small numbers).
  UtmProjection utm;
  std::vector<std::optional<Eigen::Vector3d>> gps(frames.size());
  bool have_utm = false;
  for (const auto* f : frames) {
    if (f->latitude_deg && f->longitude_deg) {
      std::string why;
      have_utm = utm.Init(*f->latitude_deg, *f->longitude_deg, &why);
      break;
    }
  }
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  bool origin_set = false;
  if (have_utm) {
    for (size_t i = 0; i < frames.size(); ++i) {
      const auto* f = frames[i];
      if (!f->latitude_deg || !f->longitude_deg) continue;
      const auto en = utm.Forward(*f->latitude_deg, *f->longitude_deg);
      if (!en) continue;
      if (!origin_set) {
        origin = Eigen::Vector2d(std::round(en->x()), std::round(en->y()));
        origin_set = true;
      }
      const double z = f->relative_altitude_m ? *f->relative_altitude_m : f->altitude_m.value_or(NAN);
      gps[i] = Eigen::Vector3d(en->x() - origin.x(), en->y() - origin.y(), z);
    }
  }
  const double fpx = rec.camera.fx;
  std::string pose_source;
  if (!options.colmap_import_dir.empty()) {
    Reconstruction imported;
    if (!ReadColmapText(options.colmap_import_dir, &imported, error)) return false;
    std::map<std::string, const Image*> by_name;
    for (const auto& im : imported.images) by_name[im.name] = &im;
    for (auto& im : rec.images) {
      const auto it = by_name.find(im.name);
      if (it == by_name.end()) {
        *error = "COLMAP model has no image " + im.name;
        return false;
      }
      im.pose = it->second->pose;
    }
    const int w = rec.camera.width, h = rec.camera.height;
    rec.camera = imported.camera;
    rec.camera.width = w;
    rec.camera.height = h;
    pose_source = "colmap:" + options.colmap_import_dir;
  } else {
    // Nadir assumption from the onboard maps: the frame's centre and local linear part in the mosaic give position,
    // in-plane yaw and (via scale) height.
    std::vector<Eigen::Vector2d> centre_mosaic(frames.size());
    std::vector<Eigen::Matrix2d> jac(frames.size());
    const Vec2 pp(rec.camera.cx, rec.camera.cy);
    for (size_t i = 0; i < frames.size(); ++i) {
      const Mat3& H = frames[i]->mosaic_from_frame;
      centre_mosaic[i] = Apply(H, pp);
      Eigen::Matrix2d J;
      constexpr double d = 1.0;
      J.col(0) = Apply(H, pp + Vec2(d, 0)) - centre_mosaic[i];
      J.col(1) = Apply(H, pp + Vec2(0, d)) - centre_mosaic[i];
      jac[i] = J;
    }
    double s = 1.0;
    Eigen::Matrix2d Q;
    Q << 1, 0, 0, -1;  // mosaic rows go south
    Eigen::Vector2d t = Eigen::Vector2d::Zero();
    std::vector<Eigen::Vector2d> src, dst;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (gps[i]) {
        src.push_back(centre_mosaic[i]);
        dst.push_back(gps[i]->head<2>());
      }
    }
    // The mosaic may be mirrored against the world (its rows go south): a reflection is allowed here.
    if (Similarity2 fit; src.size() >= 3 && FitSimilarity<2>(src, dst, &fit, {.allow_reflection = true})) {
      s = fit.scale;
      Q = fit.rotation;
      t = fit.translation;
      pose_source = "onboard_maps+gps";
    } else {
      // Without GPS: metres from the relative altitude when known, else mosaic pixels.
      std::vector<double> ratios;
      for (size_t i = 0; i < frames.size(); ++i) {
        if (frames[i]->relative_altitude_m && *frames[i]->relative_altitude_m > 1.0) {
          ratios.push_back(*frames[i]->relative_altitude_m / (fpx * std::sqrt(std::abs(jac[i].determinant()))));
        }
      }
      if (!ratios.empty()) {
        std::nth_element(ratios.begin(), ratios.begin() + static_cast<long>(ratios.size() / 2), ratios.end());
        s = ratios[ratios.size() / 2];
        pose_source = "onboard_maps+relative_altitude";
      } else {
        pose_source = "onboard_maps(mosaic_pixel_units)";
      }
    }
    js["mosaic_to_world_reflection"] = Q.determinant() < 0;
    for (size_t i = 0; i < frames.size(); ++i) {
      const Eigen::Matrix2d L = s * Q * jac[i];  // frame px -> world metres near the principal point
      const double h = fpx * std::sqrt(std::abs(L.determinant()));
      const Eigen::Matrix2d Q2 = Polar(L.transpose());
      Pose& p = rec.images[i].pose;
      p.R.setZero();
      p.R.topLeftCorner<2, 2>() = Q2;
      p.R(2, 2) = -1.0;
      if (p.R.determinant() < 0) {
        *error = "onboard map of frame " + std::to_string(frames[i]->index) + " is mirrored";
        return false;
      }
      const Eigen::Vector2d xy = s * Q * centre_mosaic[i] + t;
      // Height: the relative altitude when GPS gave metres (take-off = 0, the ground near 0), else from the scale.
      const bool use_alt = gps[i] && std::isfinite(gps[i]->z()) && frames[i]->relative_altitude_m;
      p.c = Eigen::Vector3d(xy.x(), xy.y(), use_alt ? gps[i]->z() : h);
    }
  }
  js["initial_pose_source"] = pose_source;
  timings["initial_poses_s"] = Seconds(t0);

  // 6. Triangulation and BA rounds.
  t0 = Clock::now();
  auto triangulate_all = [&](double max_err) {
    rec.points.clear();
    for (const auto& tr : tracks) {
      std::vector<Pose> poses;
      std::vector<Eigen::Vector2d> xn;
      for (const auto& o : tr) {
        poses.push_back(rec.images[static_cast<size_t>(o.image)].pose);
        xn.push_back(
            rec.camera.Undistort(rec.images[static_cast<size_t>(o.image)].keypoints[static_cast<size_t>(o.feature)]));
      }
      const auto X = TriangulateDlt(poses, xn);
      if (!X) continue;
      if (MaxTriangulationAngleDeg(poses, *X) < options.min_triangulation_angle_deg) continue;
      Point3D p;
      p.X = *X;
      double sum = 0.0;
      for (size_t k = 0; k < tr.size(); ++k) {
        const auto proj = Project(rec.camera, poses[k], *X);
        const auto& kp = rec.images[static_cast<size_t>(tr[k].image)].keypoints[static_cast<size_t>(tr[k].feature)];
        const double e = proj ? (*proj - kp).norm() : 1e9;
        // Keep the observations that agree; the rest leave the track (it stays if two remain).
        if (e <= max_err) {
          p.track.push_back(tr[k]);
          sum += e;
        }
      }
      if (p.track.size() < 2) continue;
      p.error_px = sum / static_cast<double>(p.track.size());
      p.bgr = feats[static_cast<size_t>(p.track[0].image)].colors[static_cast<size_t>(p.track[0].feature)];
      rec.points.push_back(std::move(p));
    }
  };
  // Drops observations above max_err from the adjusted points (without re-triangulating).
  auto filter = [&](double max_err) {
    std::vector<Point3D> kept;
    for (auto& p : rec.points) {
      Track t;
      double sum = 0.0;
      for (const auto& o : p.track) {
        const auto& im = rec.images[static_cast<size_t>(o.image)];
        const auto proj = Project(rec.camera, im.pose, p.X);
        const double e = proj ? (*proj - im.keypoints[static_cast<size_t>(o.feature)]).norm() : 1e9;
        if (e <= max_err) {
          t.push_back(o);
          sum += e;
        }
      }
      if (t.size() < 2) continue;
      std::vector<Pose> poses;
      for (const auto& o : t) poses.push_back(rec.images[static_cast<size_t>(o.image)].pose);
      if (MaxTriangulationAngleDeg(poses, p.X) < options.min_triangulation_angle_deg) continue;
      p.track = std::move(t);
      p.error_px = sum / static_cast<double>(p.track.size());
      kept.push_back(std::move(p));
    }
    rec.points = std::move(kept);
  };
  triangulate_all(options.initial_reprojection_px);
  const size_t obs_tracks = [&] {
    size_t n = 0;
    for (const auto& t : tracks) n += t.size();
    return n;
  }();
  js["initial_points"] = rec.points.size();
  const double rms_initial = rec.ReprojectionRms();
  js["ba_rms_initial_px"] = rms_initial;
  if (rec.points.size() < 20) {
    *error = "too few points triangulate with the initial poses (" + std::to_string(rec.points.size()) + ")";
    return false;
  }
  nlohmann::json rounds = nlohmann::json::array();
  // A nadir flight over nearly flat ground cannot tell focal length from depth: the EXIF focal length stays as a prior
  // (1 % when the sensor is known, 10 % for a guess).
  const double focal_sigma = guess.source == "exif+sensor" ? 0.01 : 0.1;
  std::vector<std::optional<Eigen::Vector3d>> centre_priors(frames.size());
  int n_priors = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (gps[i] && std::isfinite(gps[i]->z()) && frames[i]->relative_altitude_m && options.colmap_import_dir.empty()) {
      centre_priors[i] = *gps[i];
      ++n_priors;
    }
  }
  js["ba_centre_priors"] = n_priors;
  js["ba_focal_prior_sigma"] = focal_sigma;
  BundleSummary first{}, last{};
  for (size_t r = 0; r < options.round_reprojection_px.size(); ++r) {
    BundleOptions bo;
    bo.threads = options.threads;
    bo.loss = r == 0 ? BundleOptions::Loss::kCauchy : BundleOptions::Loss::kHuber;
    bo.loss_scale_px = r == 0 ? 4.0 : 1.0;
    bo.refine_k3 = options.refine_k3 && r > 0;
    bo.focal_prior_sigma = focal_sigma;
    bo.fixed_image = 0;
    bo.centre_priors = centre_priors;
    bo.max_iterations = 50;
    BundleSummary bs;
    if (!BundleAdjust(&rec, bo, &bs, error)) return false;
    if (r == 0) first = bs;
    last = bs;
    if (progress) progress("bundle", r + 1, options.round_reprojection_px.size());
    const double thr = options.round_reprojection_px[r];
    // Re-triangulate every track with the adjusted poses (recovers points the rough poses lost), then reject.
    triangulate_all(thr);
    rounds.push_back({{"rms_before_px", bs.rms_before_px},
                      {"rms_after_px", bs.rms_after_px},
                      {"iterations", bs.iterations},
                      {"seconds", bs.seconds},
                      {"reject_above_px", thr},
                      {"points_after_reject", rec.points.size()},
                      {"rms_after_reject_px", rec.ReprojectionRms()}});
  }
  // Final BA on the cleaned set; its before/after is the reported pair.
  {
    BundleOptions bo;
    bo.threads = options.threads;
    bo.loss = BundleOptions::Loss::kHuber;
    bo.loss_scale_px = 1.0;
    bo.refine_k3 = options.refine_k3;
    bo.fixed_image = 0;
    bo.focal_prior_sigma = focal_sigma;
    bo.centre_priors = centre_priors;
    BundleSummary bs;
    if (!BundleAdjust(&rec, bo, &bs, error)) return false;
    filter(options.round_reprojection_px.back());
    rounds.push_back({{"rms_before_px", bs.rms_before_px},
                      {"rms_after_px", bs.rms_after_px},
                      {"iterations", bs.iterations},
                      {"seconds", bs.seconds},
                      {"final", true},
                      {"points", rec.points.size()}});
    last = bs;
  }
  size_t obs_kept = rec.NumObservations();
  js["ba_rounds"] = rounds;
  js["ba_rms_before_px"] = rms_initial;  // with the initial poses, all first-triangulated points
  js["ba_rms_after_px"] = rec.ReprojectionRms();
  js["ba_rms_units"] = "original-resolution pixels";
  js["observations_in_tracks"] = obs_tracks;
  js["observations_kept"] = obs_kept;
  js["sparse_points"] = rec.points.size();
  js["camera"] = {{"fx", rec.camera.fx}, {"fy", rec.camera.fy}, {"cx", rec.camera.cx},
                  {"cy", rec.camera.cy}, {"k1", rec.camera.k1}, {"k2", rec.camera.k2},
                  {"p1", rec.camera.p1}, {"p2", rec.camera.p2}, {"k3", rec.camera.k3}};
  timings["bundle_s"] = Seconds(t0);

  // 7. Georeferencing: similarity of the adjusted centres onto GPS (E, N, relative altitude).
  t0 = Clock::now();
  {
    std::vector<Eigen::Vector3d> src, dst;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (gps[i] && std::isfinite(gps[i]->z())) {
        src.push_back(rec.images[i].pose.c);
        dst.push_back(*gps[i]);
      }
    }
    if (Similarity3 fit; src.size() >= 3 && FitSimilarity<3>(src, dst, &fit)) {
      const double s = fit.scale;
      const Eigen::Matrix3d& Q = fit.rotation;
      const Eigen::Vector3d& t = fit.translation;
      for (auto& im : rec.images) {
        im.pose.c = s * Q * im.pose.c + t;
        im.pose.R = im.pose.R * Q.transpose();
      }
      for (auto& p : rec.points) p.X = s * Q * p.X + t;
      double sum = 0.0;
      for (size_t k = 0; k < src.size(); ++k) sum += (s * Q * src[k] + t - dst[k]).squaredNorm();
      js["georef"] = {{"method", "similarity to GPS camera positions"},
                      {"cameras", src.size()},
                      {"scale", s},
                      {"rms_m", std::sqrt(sum / static_cast<double>(src.size()))},
                      {"z_reference", "relative altitude (take-off = 0) when in EXIF, else GPS altitude"}};
    } else {
      js["georef"] = {{"method", "none"}};
    }
  }
  result->offset = origin;
  if (have_utm && origin_set) {
    result->crs_wkt = utm.wkt();
    result->epsg = utm.epsg();
    js["crs"] = "EPSG:" + std::to_string(utm.epsg());
  } else {
    js["crs"] = nullptr;
    js["crs_note"] = "no GPS: local coordinates without a CRS (" + pose_source + ")";
  }
  timings["georef_s"] = Seconds(t0);

  // 8. Dense.
  t0 = Clock::now();
  std::vector<CloudPoint> cloud;
  DenseReport dense_report;
  if (options.dense) {
    DenseOptions dopt;
    dopt.image_scale = options.dense_image_scale;
    dopt.sample_step = options.dense_sample_step;
    dopt.max_pairs = options.max_dense_pairs;
    dopt.pairs_per_image = options.dense_pairs_per_image;
    dopt.min_baseline_ratio = options.min_baseline_ratio;
    dopt.max_baseline_ratio = options.max_baseline_ratio;
    dopt.target_baseline_ratio = options.target_baseline_ratio;
    dopt.min_overlap = options.min_pair_overlap;
    dopt.threads = options.threads;
    std::vector<std::string> paths;
    for (const auto* f : frames) paths.push_back(session_dir + "/" + f->stored_file);
    if (!DenseFromReconstruction(rec, paths, dopt, progress, &cloud, &dense_report, error)) return false;
  }
  timings["dense_s"] = Seconds(t0);
  js["dense"] = dense_report.ToJson();

  // 9. Fusion + DSM.
  t0 = Clock::now();
  std::vector<CloudPoint> sparse_cloud;
  for (const auto& p : rec.points) {
    sparse_cloud.push_back(
        {cv::Vec3f(static_cast<float>(p.X.x()), static_cast<float>(p.X.y()), static_cast<float>(p.X.z())), p.bgr});
  }
  // Cell size: the dense sampling distance on the ground (or 4x the sparse GSD without dense points).
  std::vector<double> depths;
  for (const auto& p : rec.points) {
    for (const auto& o : p.track) depths.push_back(rec.images[static_cast<size_t>(o.image)].pose.ToCamera(p.X).z());
  }
  std::nth_element(depths.begin(), depths.begin() + static_cast<long>(depths.size() / 2), depths.end());
  const double median_depth = depths[depths.size() / 2];
  const double gsd = median_depth / rec.camera.fx;
  double cell = options.dsm_cell_m;
  if (cell <= 0.0) {
    cell = cloud.empty() ? 20.0 * gsd : 1.5 * gsd * options.dense_sample_step / options.dense_image_scale;
  }
  js["gsd_m"] = gsd;
  js["dsm_cell"] = cell;
  FusionReport fusion;
  std::vector<CloudPoint> fused;
  if (!cloud.empty()) {
    fused = FuseClouds(cloud, dense_report.point_pair, cell, options.fusion_tolerance_cells * cell,
                       options.fusion_min_pairs, &fusion);
  }
  const std::vector<CloudPoint>& dsm_source = fused.empty() ? sparse_cloud : fused;
  js["fusion"] = fusion.ToJson();
  js["dense_points"] = fused.size();
  {
    float x0 = 1e30f, x1 = -1e30f, y0 = 1e30f, y1 = -1e30f;
    for (const auto& p : dsm_source) {
      x0 = std::min(x0, p.xyz[0]);
      x1 = std::max(x1, p.xyz[0]);
      y0 = std::min(y0, p.xyz[1]);
      y1 = std::max(y1, p.xyz[1]);
    }
    DsmGrid g;
    g.cell = cell;
    g.x0 = std::floor(x0 / cell) * cell;
    g.y0 = std::ceil(y1 / cell) * cell;
    g.width = static_cast<int>(std::ceil((x1 - g.x0) / cell)) + 1;
    g.height = static_cast<int>(std::ceil((g.y0 - y0) / cell)) + 1;
    result->grid = g;
    result->dsm = RasterizeMedian(dsm_source, g, -9999.0f);
    js["dsm_size"] = {g.width, g.height};
    js["dsm_source"] = fused.empty() ? "sparse" : "dense";
  }
  result->dense = fused.empty() ? sparse_cloud : std::move(fused);
  timings["fusion_dsm_s"] = Seconds(t0);
  timings["total_s"] = Seconds(t_total);
  js["timings"] = timings;
  js["frames_used"] = frames.size();
  return true;
}

}  // namespace uavm::sfm
