#include "core/sfm/initial_poses.h"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include "core/geometry/similarity.h"
#include "core/georef/georef.h"
#include "core/sfm/colmap_io.h"

namespace uavm::sfm {

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

std::vector<int> ImagesPerCamera(const Reconstruction& rec) {
  std::vector<int> images_of(rec.cameras.size(), 0);
  for (const auto& im : rec.images) ++images_of[static_cast<size_t>(im.camera)];
  return images_of;
}
size_t MostUsedCamera(const Reconstruction& rec) {
  const std::vector<int> n = ImagesPerCamera(rec);
  return static_cast<size_t>(std::max_element(n.begin(), n.end()) - n.begin());
}

namespace {

// Nearest orthogonal matrix (may be a reflection).
Eigen::Matrix2d Polar(const Eigen::Matrix2d& m) {
  const Eigen::JacobiSVD<Eigen::Matrix2d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU() * svd.matrixV().transpose();
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

}  // namespace

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

}  // namespace uavm::sfm
