#include "core/sfm/run_reconstruction.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <opencv2/calib3d.hpp>
#include <opencv2/flann.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <unordered_map>

#include "core/features/sift.h"
#include "core/geometry/similarity.h"
#include "core/georef/georef.h"
#include "core/matching/radius_matcher.h"
#include "core/sfm/colmap_io.h"
#include "core/sfm/dense.h"
#include "core/util/memory.h"
#include "core/util/parallel.h"

namespace uavm::sfm {

bool ReconstructionOptions::Check(std::string* why) const {
  auto fail = [&](const char* m) {
    *why = m;
    return false;
  };
  if (threads < 1) return fail("--threads must be >= 1");
  if (!(feature_scale >= 0.0 && feature_scale <= 1.0)) return fail("feature_scale must be in [0,1] (0 = automatic)");
  if (feature_scale == 0.0 && feature_long_side_px < 100) return fail("feature_long_side_px must be >= 100");
  if (max_features < 100) return fail("max_features must be >= 100");
  if (!(ratio > 0.0 && ratio < 1.0)) return fail("ratio must be in (0,1)");
  if (!(fundamental_threshold_px > 0.0)) return fail("fundamental_threshold_px must be > 0");
  if (round_reprojection_px.empty()) return fail("round_reprojection_px needs at least one round");
  if (!(dense_image_scale > 0.0 && dense_image_scale <= 1.0)) return fail("dense_image_scale must be in (0,1]");
  if (dense_sample_step < 1 || fusion_min_pairs < 1) return fail("dense_sample_step, fusion_min_pairs >= 1");
  if (dsm_fill_cells < 0) return fail("--dsm-fill must be >= 0");
  if (!checkpoints.empty() && gcp_file.empty()) return fail("--checkpoints needs --gcp");
  if (!gcp_file.empty() && !control.Check(why)) return false;
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

// 1. The frames the reconstruction uses: registered, with a stored file and at least one used graph edge.
struct SelectedFrames {
  Session session;
  std::vector<const SessionFrame*> frames;  // into session.frames, in frames.csv order; position = image slot
  std::map<int, size_t> slot_of;            // session index -> image slot
  // Registered frames left out of the reconstruction, with the reason (summary.json "frames_not_used").
  std::vector<std::pair<const SessionFrame*, std::string>> left_out;
};

bool SelectFrames(const std::string& session_dir, SelectedFrames* out, std::string* error) {
  if (!ReadSession(session_dir, &out->session, error)) return false;
  std::set<int> in_graph;
  for (const auto& e : out->session.edges) {
    if (e.used) {
      in_graph.insert(e.src);
      in_graph.insert(e.tgt);
    }
  }
  for (const auto& f : out->session.frames) {
    if (f.registered && f.has_transform && in_graph.count(f.index) && !f.stored_file.empty()) {
      out->frames.push_back(&f);
    }
  }
  if (out->frames.size() < 2) {
    *error = "fewer than two registered frames with used graph edges in " + session_dir;
    return false;
  }
  for (size_t i = 0; i < out->frames.size(); ++i) out->slot_of[out->frames[i]->index] = i;
  return true;
}

nlohmann::json LeftOutJson(const SelectedFrames& sel) {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& [f, why] : sel.left_out) j.push_back({{"index", f->index}, {"file", f->filename}, {"reason", why}});
  return j;
}

double FeatureScale(const ReconstructionOptions& options, const SessionFrame& frame) {
  if (options.feature_scale > 0.0) return options.feature_scale;
  const int long_side = std::max(frame.width, frame.height);
  return long_side > options.feature_long_side_px ? static_cast<double>(options.feature_long_side_px) / long_side : 1.0;
}

// 2. Features of one stored frame at feature_scale, keypoints in original-resolution pixels with their colours.
bool FrameFeaturesOf(const std::string& path, const SiftExtractor& sift, double s, FrameFeatures* out) {
  const cv::Mat img = ReadFrame(path);
  if (img.empty()) return false;
  cv::Mat gray, work;
  cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
  if (s < 1.0) {
    cv::resize(gray, work, cv::Size(), s, s, cv::INTER_AREA);
  } else {
    work = gray;
  }
  Features f = sift.Extract(work);
  out->descriptors = f.descriptors;
  for (const auto& p : f.points) {
    const double x = (p.x + 0.5) / s - 0.5, y = (p.y + 0.5) / s - 0.5;
    out->points.emplace_back(x, y);
    const int xi = std::clamp(static_cast<int>(std::lround(x)), 0, img.cols - 1);
    const int yi = std::clamp(static_cast<int>(std::lround(y)), 0, img.rows - 1);
    out->colors.push_back(img.at<cv::Vec3b>(yi, xi));
  }
  return true;
}

// A frame whose stored image cannot be read is left out (named with the reason), not the whole reconstruction.
bool ExtractFeatures(const std::string& session_dir, SelectedFrames* sel, const ReconstructionOptions& options,
                     const ProgressFn& progress, std::vector<FrameFeatures>* feats, nlohmann::json* js,
                     std::string* error) {
  const std::vector<const SessionFrame*>& frames = sel->frames;
  feats->assign(frames.size(), FrameFeatures{});
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
    const double scale = FeatureScale(options, *frames[i]);
    if (!FrameFeaturesOf(session_dir + "/" + frames[i]->stored_file, sift, scale, &(*feats)[i])) {
      failures[i] = "cannot read " + frames[i]->stored_file;
      return;
    }
    if (progress) progress("features", ++done, frames.size());
  });
  cv::setNumThreads(cv_threads);
  size_t kept = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (!failures[i].empty()) {
      std::fprintf(stderr, "uavmosaic-ground: warning: frame %d (%s) left out: %s\n", frames[i]->index,
                   frames[i]->filename.c_str(), failures[i].c_str());
      sel->left_out.emplace_back(frames[i], failures[i]);
      continue;
    }
    if (kept != i) {  // (a vector moved onto itself is left empty)
      sel->frames[kept] = frames[i];
      (*feats)[kept] = std::move((*feats)[i]);
    }
    ++kept;
  }
  sel->frames.resize(kept);
  feats->resize(kept);
  sel->slot_of.clear();
  for (size_t i = 0; i < kept; ++i) sel->slot_of[sel->frames[i]->index] = i;
  (*js)["frames_not_used"] = LeftOutJson(*sel);
  if (kept < 2) {
    *error = "fewer than two readable frames (" + std::to_string(sel->left_out.size()) + " left out)";
    return false;
  }
  size_t total_kp = 0;
  for (const auto& f : *feats) total_kp += f.points.size();
  (*js)["keypoints_per_frame_mean"] = static_cast<double>(total_kp) / static_cast<double>(frames.size());
  (*js)["feature_scale"] = FeatureScale(options, *frames[0]);
  return true;
}

// 3. Matching of graph.csv's used pairs, verified by RANSAC on F.
struct PairMatch {
  int candidates = 0;                 // guided, ratio-tested, mutual
  int inliers = 0;                    // of F
  std::vector<FeatureMatch> matches;  // the inliers when at least min_pair_inliers, else none
};

PairMatch MatchPair(size_t a, size_t b, const FrameFeatures& fa, const FrameFeatures& fb, const SessionFrame& frame_a,
                    const SessionFrame& frame_b, const ReconstructionOptions& options) {
  PairMatch out;
  if (fa.points.size() < 8 || fb.points.size() < 8) return out;
  const Mat3 b_from_a = frame_b.mosaic_from_frame.inverse() * frame_a.mosaic_from_frame;
  // Guided by the onboard maps (core/matching/radius_matcher.h): candidates near the predicted position only.
  const RadiusMatchOptions guide{.radius_px = options.guided_radius * std::max(frame_a.width, frame_a.height),
                                 .ratio = options.ratio};
  const std::vector<RadiusMatch> guided = MatchWithinRadius(fa.points, fa.descriptors, fb.points, fb.descriptors,
                                                            cv::Size(frame_b.width, frame_b.height), b_from_a, guide);
  std::vector<cv::Point2f> pa, pb;
  std::vector<FeatureMatch> cand;
  for (const RadiusMatch& m : guided) {
    cand.push_back({static_cast<int>(a), m.a, static_cast<int>(b), m.b, m.distance_sq});
    pa.emplace_back(static_cast<float>(fa.points[static_cast<size_t>(m.a)].x()),
                    static_cast<float>(fa.points[static_cast<size_t>(m.a)].y()));
    pb.emplace_back(static_cast<float>(fb.points[static_cast<size_t>(m.b)].x()),
                    static_cast<float>(fb.points[static_cast<size_t>(m.b)].y()));
  }
  out.candidates = static_cast<int>(cand.size());
  if (static_cast<int>(cand.size()) < options.min_pair_inliers) return out;
  std::vector<uchar> mask;
  const cv::Mat F = cv::findFundamentalMat(pa, pb, cv::FM_RANSAC, options.fundamental_threshold_px, 0.9999, mask);
  if (F.empty()) return out;
  std::vector<FeatureMatch> inl;
  for (size_t i = 0; i < cand.size(); ++i) {
    if (mask[i]) inl.push_back(cand[i]);
  }
  out.inliers = static_cast<int>(inl.size());
  if (static_cast<int>(inl.size()) >= options.min_pair_inliers) out.matches = std::move(inl);
  return out;
}

// The verified matches of all pairs, in pair order (image slots, ascending).
std::vector<FeatureMatch> MatchGraphPairs(const SelectedFrames& sel, const std::vector<FrameFeatures>& feats,
                                          const ReconstructionOptions& options, const ProgressFn& progress,
                                          nlohmann::json* js) {
  const auto& frames = sel.frames;
  std::vector<std::pair<size_t, size_t>> pairs;
  for (const auto& e : sel.session.edges) {
    if (e.used && sel.slot_of.count(e.src) && sel.slot_of.count(e.tgt)) {
      pairs.emplace_back(sel.slot_of.at(e.src), sel.slot_of.at(e.tgt));
    }
  }
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  std::vector<PairMatch> results(pairs.size());
  std::atomic<size_t> done{0};
  ParallelFor(pairs.size(), options.threads, [&](size_t k) {
    const auto [a, b] = pairs[k];
    results[k] = MatchPair(a, b, feats[a], feats[b], *frames[a], *frames[b], options);
    if (feats[a].points.size() < 8 || feats[b].points.size() < 8) return;  // as before: no progress for those
    if (progress) progress("matching", ++done, pairs.size());
  });
  std::vector<FeatureMatch> all_matches;
  int pairs_ok = 0;
  nlohmann::json jp = nlohmann::json::array();
  for (size_t k = 0; k < pairs.size(); ++k) {
    auto& m = results[k].matches;
    if (!m.empty()) ++pairs_ok;
    all_matches.insert(all_matches.end(), m.begin(), m.end());
    jp.push_back(
        {frames[pairs[k].first]->index, frames[pairs[k].second]->index, results[k].candidates, results[k].inliers});
  }
  (*js)["pairs_listed"] = pairs.size();
  (*js)["pairs_verified"] = pairs_ok;
  (*js)["pair_matches"] = jp;  // [src, tgt, guided candidates, F inliers]
  (*js)["matches"] = all_matches.size();
  return all_matches;
}

// 5. Camera and initial poses.
// GPS -> UTM (origin at the first GPS frame, so the solver works with small numbers).
struct GpsPositions {
  std::vector<std::optional<Eigen::Vector3d>> local;  // per image slot: E, N (relative to origin), altitude
  Eigen::Vector2d origin = Eigen::Vector2d::Zero();
  bool projected = false;  // a UTM zone and at least one position: the products carry the CRS below
  std::string crs_wkt;
  int epsg = 0;
};

GpsPositions ProjectGps(const std::vector<const SessionFrame*>& frames) {
  GpsPositions out;
  out.local.resize(frames.size());
  // The UTM zone of the first frame with a position: the whole flight in one CRS.
  int epsg = 0;
  for (const auto* f : frames) {
    if (f->latitude_deg && f->longitude_deg) {
      epsg = UtmEpsg(*f->latitude_deg, *f->longitude_deg);
      break;
    }
  }
  if (epsg == 0) return out;
  ProjectedConverter utm;
  bool origin_set = false;
  for (size_t i = 0; i < frames.size(); ++i) {
    const auto* f = frames[i];
    if (!f->latitude_deg || !f->longitude_deg) continue;
    Vec2 en;
    if (!utm.ToProjected(epsg, *f->latitude_deg, *f->longitude_deg, &en)) continue;
    if (!origin_set) {
      out.origin = Eigen::Vector2d(std::round(en.x()), std::round(en.y()));
      origin_set = true;
    }
    const double z = f->relative_altitude_m ? *f->relative_altitude_m : f->altitude_m.value_or(NAN);
    out.local[i] = Eigen::Vector3d(en.x() - out.origin.x(), en.y() - out.origin.y(), z);
  }
  if (origin_set) {
    out.projected = true;
    out.crs_wkt = EpsgWkt(epsg);
    out.epsg = epsg;
  }
  return out;
}

// Images per camera, and the camera most images use (the flight's main one: it starts from the onboard lens, and
// summary.json "camera" is its).
std::vector<int> ImagesPerCamera(const Reconstruction& rec) {
  std::vector<int> images_of(rec.cameras.size(), 0);
  for (const auto& im : rec.images) ++images_of[static_cast<size_t>(im.camera)];
  return images_of;
}
size_t MostUsedCamera(const Reconstruction& rec) {
  const std::vector<int> n = ImagesPerCamera(rec);
  return static_cast<size_t>(std::max_element(n.begin(), n.end()) - n.begin());
}

// The reconstruction's images (keypoints, no poses yet) and their cameras: one per image size (a flight may mix
// cameras, or one camera set to another resolution for some shots), each guessed from its first frame's EXIF.
// The onboard program's lens (camera.yaml) as the start of the camera's distortion: its k's are normalised by its own
// focal length, so they are rescaled to the guessed one (the same bending in pixels).
void StartDistortionFrom(const std::optional<SessionLens>& lens, Camera* camera, nlohmann::json* js) {
  (*js)["distortion_initial_from"] = "none";
  if (!lens || (lens->k1 == 0 && lens->k2 == 0 && lens->p1 == 0 && lens->p2 == 0)) return;
  const double s = camera->fx / lens->focal_px;
  camera->k1 = lens->k1 * s * s;
  camera->k2 = lens->k2 * s * s * s * s;
  camera->p1 = lens->p1 * s;
  camera->p2 = lens->p2 * s;
  (*js)["distortion_initial_from"] = "camera.yaml (" + lens->source + ")";
}

IntrinsicsGuess InitImages(const std::vector<const SessionFrame*>& frames, const std::vector<FrameFeatures>& feats,
                           const std::optional<SessionLens>& lens, const ReconstructionOptions& options,
                           Reconstruction* rec, nlohmann::json* js) {
  *rec = Reconstruction{};
  std::map<std::pair<int, int>, int> camera_of_size;
  std::vector<IntrinsicsGuess> guesses;
  for (size_t i = 0; i < frames.size(); ++i) {
    const SessionFrame& f = *frames[i];
    const auto [it, added] = camera_of_size.emplace(std::pair(f.width, f.height), static_cast<int>(guesses.size()));
    if (added) {
      guesses.push_back(GuessIntrinsics(f.width, f.height, f.focal_length_mm.value_or(0.0), options.camera_model,
                                        options.default_hfov_deg));
      rec->cameras.push_back(guesses.back().camera);
    }
    Image im;
    im.frame_index = f.index;
    im.name = f.stored_file.substr(f.stored_file.find_last_of('/') + 1);
    im.camera = it->second;
    im.keypoints = feats[i].points;
    rec->images.push_back(std::move(im));
  }
  // The onboard lens (camera.yaml) was estimated on the flight's frames: it starts the camera most of them use.
  const size_t main = MostUsedCamera(*rec);
  StartDistortionFrom(lens, &rec->cameras[main], js);
  (*js)["intrinsics_source"] = guesses[main].source;
  (*js)["focal_initial_px"] = rec->cameras[main].fx;
  if (rec->cameras.size() > 1) {
    std::fprintf(stderr, "uavmosaic-ground: %zu image sizes in the flight: a camera model each\n", rec->cameras.size());
  }
  return guesses[main];
}

// Poses and intrinsics of a COLMAP text model, matched by image name (the image size stays the session's).
bool PosesFromColmap(const std::string& dir, Reconstruction* rec, std::string* error) {
  Reconstruction imported;
  if (!ReadColmapText(dir, &imported, error)) return false;
  std::map<std::string, const Image*> by_name;
  for (const auto& im : imported.images) by_name[im.name] = &im;
  for (auto& im : rec->images) {
    const auto it = by_name.find(im.name);
    if (it == by_name.end()) {
      *error = "COLMAP model has no image " + im.name;
      return false;
    }
    im.pose = it->second->pose;
  }
  // Each camera's intrinsics from the imported camera of its first image.
  std::vector<bool> set(rec->cameras.size(), false);
  for (const auto& im : rec->images) {
    auto& cam = rec->cameras[static_cast<size_t>(im.camera)];
    if (set[static_cast<size_t>(im.camera)]) continue;
    set[static_cast<size_t>(im.camera)] = true;
    const int w = cam.width, h = cam.height;
    cam = imported.CameraOf(*by_name.at(im.name));
    cam.width = w;
    cam.height = h;
  }
  return true;
}

// Mosaic -> world similarity (x_world = s Q x_mosaic + t).
struct MosaicToWorld {
  double s = 1.0;
  Eigen::Matrix2d Q = (Eigen::Matrix2d() << 1, 0, 0, -1).finished();  // mosaic rows go south
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  std::string pose_source;
};

// From the frame centres onto GPS; without GPS, metres from the relative altitude when known, else mosaic pixels.
MosaicToWorld FitMosaicToWorld(const std::vector<const SessionFrame*>& frames, const GpsPositions& gps,
                               const std::vector<Eigen::Vector2d>& centre_mosaic,
                               const std::vector<Eigen::Matrix2d>& jac, const std::vector<double>& fpx) {
  MosaicToWorld m;
  std::vector<Eigen::Vector2d> src, dst;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (gps.local[i]) {
      src.push_back(centre_mosaic[i]);
      dst.push_back(gps.local[i]->head<2>());
    }
  }
  // The mosaic may be mirrored against the world (its rows go south): a reflection is allowed here.
  if (Similarity2 fit; src.size() >= 3 && FitSimilarity<2>(src, dst, &fit, {.allow_reflection = true})) {
    m.s = fit.scale;
    m.Q = fit.rotation;
    m.t = fit.translation;
    m.pose_source = "onboard_maps+gps";
    return m;
  }
  std::vector<double> ratios;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i]->relative_altitude_m && *frames[i]->relative_altitude_m > 1.0) {
      ratios.push_back(*frames[i]->relative_altitude_m / (fpx[i] * std::sqrt(std::abs(jac[i].determinant()))));
    }
  }
  if (!ratios.empty()) {
    std::nth_element(ratios.begin(), ratios.begin() + static_cast<long>(ratios.size() / 2), ratios.end());
    m.s = ratios[ratios.size() / 2];
    m.pose_source = "onboard_maps+relative_altitude";
  } else {
    m.pose_source = "onboard_maps(mosaic_pixel_units)";
  }
  return m;
}

// Nadir assumption from the onboard maps: the frame's centre and local linear part in the mosaic give position,
// in-plane yaw and (via scale) height.
// A camera model of another image size than the flight's main one starts from the onboard maps' scale rather than
// its EXIF focal length (which cannot tell a crop from a resize): at the same flying height a frame's pixel covers
// ground in inverse proportion to its focal length in pixels, so f = f_main x scale_main / scale (scale: mosaic pixels
// per frame pixel, medians per camera). A crop keeps the main camera's focal length, a half-size copy halves it.
std::vector<double> FocalsFromOnboardScale(const std::vector<Eigen::Matrix2d>& jac, Reconstruction* rec,
                                           std::vector<double>* fpx, nlohmann::json* js) {
  std::vector<double> ratio(rec->cameras.size(), 0.0);
  if (rec->cameras.size() < 2) return ratio;
  std::vector<std::vector<double>> scale(rec->cameras.size());
  for (size_t i = 0; i < jac.size(); ++i)
    scale[static_cast<size_t>(rec->images[i].camera)].push_back(std::sqrt(std::abs(jac[i].determinant())));
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  const size_t main = MostUsedCamera(*rec);
  if (scale[main].empty()) return ratio;
  const double main_scale = median(scale[main]);
  for (size_t k = 0; k < rec->cameras.size(); ++k) {
    if (k == main || scale[k].empty() || !(main_scale > 0.0)) continue;
    Camera& cam = rec->cameras[k];
    const double exif_fx = cam.fx;
    ratio[k] = main_scale / median(scale[k]);
    cam.fx = cam.fy = rec->cameras[main].fx * ratio[k];
    (*js)["focal_from_onboard_scale"].push_back(
        {{"camera", k}, {"exif_focal_px", exif_fx}, {"focal_px", cam.fx}, {"main_focal_px", rec->cameras[main].fx}});
  }
  for (size_t i = 0; i < fpx->size(); ++i) (*fpx)[i] = rec->CameraOf(rec->images[i]).fx;
  return ratio;
}

bool PosesFromOnboardMaps(const std::vector<const SessionFrame*>& frames, const GpsPositions& gps, Reconstruction* rec,
                          std::string* pose_source, std::vector<double>* focal_ratio, nlohmann::json* js,
                          std::string* error) {
  std::vector<Eigen::Vector2d> centre_mosaic(frames.size());
  std::vector<Eigen::Matrix2d> jac(frames.size());
  std::vector<double> fpx(frames.size());  // each image's camera's focal length, pixels
  for (size_t i = 0; i < frames.size(); ++i) {
    const Camera& cam = rec->CameraOf(rec->images[i]);
    fpx[i] = cam.fx;
    const Vec2 pp(cam.cx, cam.cy);
    const Mat3& H = frames[i]->mosaic_from_frame;
    centre_mosaic[i] = Apply(H, pp);
    Eigen::Matrix2d J;
    constexpr double d = 1.0;
    J.col(0) = Apply(H, pp + Vec2(d, 0)) - centre_mosaic[i];
    J.col(1) = Apply(H, pp + Vec2(0, d)) - centre_mosaic[i];
    jac[i] = J;
  }
  *focal_ratio = FocalsFromOnboardScale(jac, rec, &fpx, js);
  const MosaicToWorld m = FitMosaicToWorld(frames, gps, centre_mosaic, jac, fpx);
  *pose_source = m.pose_source;
  (*js)["mosaic_to_world_reflection"] = m.Q.determinant() < 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Eigen::Matrix2d L = m.s * m.Q * jac[i];  // frame px -> world metres near the principal point
    const double h = fpx[i] * std::sqrt(std::abs(L.determinant()));
    const Eigen::Matrix2d Q2 = Polar(L.transpose());
    Pose& p = rec->images[i].pose;
    p.R.setZero();
    p.R.topLeftCorner<2, 2>() = Q2;
    p.R(2, 2) = -1.0;
    if (p.R.determinant() < 0) {
      *error = "onboard map of frame " + std::to_string(frames[i]->index) + " is mirrored";
      return false;
    }
    const Eigen::Vector2d xy = m.s * m.Q * centre_mosaic[i] + m.t;
    // Height: the relative altitude when GPS gave metres (take-off = 0, the ground near 0), else from the scale.
    const auto& g = gps.local[i];
    const bool use_alt = g && std::isfinite(g->z()) && frames[i]->relative_altitude_m;
    p.c = Eigen::Vector3d(xy.x(), xy.y(), use_alt ? g->z() : h);
  }
  return true;
}

struct InitialModel {
  IntrinsicsGuess guess;
  GpsPositions gps;
  std::string pose_source;
  // Per camera model: its focal length over the main camera's from the onboard maps (0 = its own).
  std::vector<double> focal_ratio;
};

bool InitialPoses(const std::vector<const SessionFrame*>& frames, const std::vector<FrameFeatures>& feats,
                  const std::optional<SessionLens>& lens, const ReconstructionOptions& options, Reconstruction* rec,
                  InitialModel* out, nlohmann::json* js, std::string* error) {
  out->guess = InitImages(frames, feats, lens, options, rec, js);
  out->gps = ProjectGps(frames);
  if (!options.colmap_import_dir.empty()) {
    if (!PosesFromColmap(options.colmap_import_dir, rec, error)) return false;
    out->pose_source = "colmap:" + options.colmap_import_dir;
  } else if (!PosesFromOnboardMaps(frames, out->gps, rec, &out->pose_source, &out->focal_ratio, js, error)) {
    return false;
  }
  (*js)["initial_pose_source"] = out->pose_source;
  return true;
}

// 6. Triangulation and BA rounds.
// Every track triangulated with the current poses; observations above max_err leave the track (it stays if two
// remain).
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

// What every BA round shares: the focal-length prior and the GPS centre priors.
struct BundlePriors {
  double focal_sigma = 0.1;
  std::vector<std::optional<Eigen::Vector3d>> centres;
  std::vector<double> focal_ratio;  // InitialModel's
};

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

// A camera model of another image size seen by too few images to calibrate (BundleOptions::min_images_for_lens) has
// its focal length tied to the main camera's by the onboard maps' ratio (FocalsFromOnboardScale), set before each
// adjustment and held in it: one odd-sized shot cannot tell its focal length from its height (free under a prior, a
// cropped frame went 12 % short started as resized, 10 % long started as cropped).
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

// 8. Dense: stereo pairs of the adjusted images, their raw points and which pair made each.
struct DenseCloud {
  std::vector<CloudPoint> points;
  DenseReport report;
};

bool DenseStage(const std::string& session_dir, const std::vector<const SessionFrame*>& frames,
                const Reconstruction& rec, const ReconstructionOptions& options, const ProgressFn& progress,
                DenseCloud* out, nlohmann::json* js, std::string* error) {
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
    dopt.daisy_cost = options.dense_daisy;
    std::vector<std::string> paths;
    for (const auto* f : frames) paths.push_back(session_dir + "/" + f->stored_file);
    if (!DenseFromReconstruction(rec, paths, dopt, progress, &out->points, &out->report, error)) return false;
  }
  (*js)["dense"] = out->report.ToJson();
  return true;
}

// 9. Fusion + DSM.
// Cell size: the dense sampling distance on the ground (or 20x the sparse GSD without dense points).
double DsmCell(const Reconstruction& rec, bool have_dense, const ReconstructionOptions& options, nlohmann::json* js) {
  const double gsd = rec.MedianGsd();
  double cell = options.dsm_cell_m;
  if (cell <= 0.0) {
    cell = !have_dense ? 20.0 * gsd : 1.5 * gsd * options.dense_sample_step / options.dense_image_scale;
  }
  (*js)["gsd_m"] = gsd;
  (*js)["dsm_cell"] = cell;
  return cell;
}

// The grid covering the points' x, y extent, north up.
DsmGrid GridOver(const std::vector<CloudPoint>& points, double cell) {
  float x0 = 1e30f, x1 = -1e30f, y0 = 1e30f, y1 = -1e30f;
  for (const auto& p : points) {
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
  return g;
}

// The fused dense cloud (the sparse points without one) and the DSM rasterised from it.
void FuseAndRasterize(const DenseCloud& dense, const ReconstructionOptions& options, ReconstructionResult* result) {
  auto& js = result->summary;
  const Reconstruction& rec = result->rec;
  std::vector<CloudPoint> sparse_cloud;
  for (const auto& p : rec.points) {
    sparse_cloud.push_back(
        {cv::Vec3f(static_cast<float>(p.X.x()), static_cast<float>(p.X.y()), static_cast<float>(p.X.z())), p.bgr});
  }
  const double cell = DsmCell(rec, !dense.points.empty(), options, &js);
  FusionReport fusion;
  std::vector<CloudPoint> fused;
  if (!dense.points.empty()) {
    fused = FuseClouds(dense.points, dense.report.point_pair, cell, options.fusion_tolerance_cells * cell,
                       options.fusion_min_pairs, &fusion);
  }
  const std::vector<CloudPoint>& dsm_source = fused.empty() ? sparse_cloud : fused;
  js["fusion"] = fusion.ToJson();
  js["dense_points"] = fused.size();
  const DsmGrid g = GridOver(dsm_source, cell);
  result->grid = g;
  result->dsm = RasterizeMedian(dsm_source, g, -9999.0f);
  result->dsm_provenance = FillDsmHoles(&result->dsm, -9999.0f, options.dsm_fill_cells);
  const double cells = std::max(1, g.width * g.height);
  js["dsm_measured_fraction"] = cv::countNonZero(result->dsm_provenance == 255) / cells;
  js["dsm_filled_fraction"] = cv::countNonZero(result->dsm_provenance == 128) / cells;
  js["dsm_size"] = {g.width, g.height};
  js["dsm_source"] = fused.empty() ? "sparse" : "dense";
  if (options.dense && fused.empty()) {
    // A stage that made nothing is said, in the log and the summary: the products fall back to the sparse points.
    const auto& failures = dense.report.failures;
    std::string why =
        std::to_string(dense.report.pairs.size()) + " stereo pair(s), " + std::to_string(failures.size()) + " refused";
    if (!failures.empty()) why += " (first: " + failures.front() + ")";
    const std::string warning =
        "dense matching made no point: " + why + "; cloud.ply and dsm.tif hold the sparse points";
    std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", warning.c_str());
    js["warnings"].push_back(warning);
  }
  result->dense = fused.empty() ? sparse_cloud : std::move(fused);
}

// 7b. Ground control points: the georeferenced model moved onto the GCPs, adjusted with them, every point measured.
bool AdjustToGcps(const std::vector<const SessionFrame*>& frames, const InitialModel& init, GcpInput* gcp,
                  const ReconstructionOptions& options, Reconstruction* rec, nlohmann::json* js, std::string* error) {
  BundlePriors priors = MakeBundlePriors(frames, init, options, js);
  ControlReport report;
  const auto& cps = gcp->binding.points;
  ControlOptions control = options.control;
  control.horizontal_only = control.horizontal_only || gcp->horizontal_only;
  if (!AlignToControl(cps, control, rec, &priors.centres, &report, error)) return false;
  BundleOptions bo;
  bo.threads = options.threads;
  bo.focal_prior_sigma = priors.focal_sigma;
  bo.centre_priors = priors.centres;
  bo.refine_k3 = options.refine_k3;
  bo.control = ControlConstraints(cps, *rec, control);
  bo.control_sigma_m = control.sigma_m;
  if (control.horizontal_only) bo.control_sigma_z_m = control.free_height_sigma_m;
  bo.control_click_px = options.control.click_px;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);
  BundleSummary bs;
  if (!BundleAdjust(rec, bo, &bs, error)) return false;
  TieFocals(priors, bo.min_images_for_lens, rec, &bo);
  MeasureControl(*rec, cps, &report);
  nlohmann::json j = report.ToJson();
  j["file"] = options.gcp_file;
  j["crs"] = gcp->crs.name();
  j["clicks_in_unused_frames"] = gcp->binding.clicks_skipped;
  for (const auto& w : gcp->binding.warnings) j["warnings"].push_back(w);
  j["ba_rms_px"] = bs.rms_after_px;
  j["sigma_m"] = options.control.sigma_m;
  j["click_sigma_px"] = options.control.click_px;
  (*js)["gcp"] = j;
  (*js)["ba_rms_after_px"] = rec->ReprojectionRms();
  for (const auto& w : report.warnings) std::fprintf(stderr, "uavmosaic-ground: warning: %s\n", w.c_str());
  return true;
}

// The GCP file (none without options.gcp_file) read, checked and bound to the selected frames' image slots.
bool BindGcpFile(const SelectedFrames& sel, const ReconstructionOptions& options, std::unique_ptr<GcpInput>* gcp,
                 nlohmann::json* js, std::string* error) {
  if (options.gcp_file.empty()) return true;
  *gcp = std::make_unique<GcpInput>();
  (*gcp)->horizontal_only = options.control.horizontal_only;
  return LoadGcpInput(options.gcp_file, options.checkpoints, sel.session, sel.frames, options.gcp_max_distance_km,
                      gcp->get(), js, error);
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
    FuseAndRasterize(dense, options, result);
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
