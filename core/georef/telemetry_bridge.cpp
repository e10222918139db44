#include "core/georef/telemetry_bridge.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>

#include "core/geometry/similarity.h"

namespace uavm {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
// Offsets further than this from the robust centre are outliers (a turn, a jump of the heading).
constexpr double kInlierRad = 30.0 * kDeg;
// The robust centre is found among at most this many offsets (O(n^2)); the mean then uses every inlier.
constexpr size_t kMaxCentreCandidates = 400;

double Wrap(double rad) {
  return std::remainder(rad, 2.0 * kPi);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  const auto mid = v.begin() + static_cast<long>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

Vec2 Centre(cv::Size size) {
  return Vec2(0.5 * (size.width - 1), 0.5 * (size.height - 1));
}

// The map's local linear part at `at`: direction of the frame's +x axis on the ground (radians, from east towards
// north), metres (or units) per pixel, and the sign of its determinant (-1: an unmirrored image in a y-up world).
struct LinearAt {
  double angle = 0, scale = 0;
  int sign = -1;
};

LinearAt Linearise(const Mat3& m, const Vec2& at) {
  const Eigen::Vector3d p = m * Eigen::Vector3d(at.x(), at.y(), 1.0);
  Eigen::Matrix2d j;
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 2; ++c) j(r, c) = (m(r, c) - p(r) / p(2) * m(2, c)) / p(2);
  const double det = j.determinant();
  return {std::atan2(j(1, 0), j(0, 0)), std::sqrt(std::abs(det)), det < 0 ? -1 : 1};
}

// world_from_frame of a frame whose centre lies at `position`, its +x axis at `angle`, `scale` units per pixel.
Mat3 Place(const Vec2& position, double angle, double scale, int sign, cv::Size size) {
  Mat3 m = Mat3::Identity();
  m(0, 0) = scale * std::cos(angle);
  m(1, 0) = scale * std::sin(angle);
  m(0, 1) = -sign * scale * std::sin(angle);
  m(1, 1) = sign * scale * std::cos(angle);
  const Vec2 c = Centre(size);
  m(0, 2) = position.x() - (m(0, 0) * c.x() + m(0, 1) * c.y());
  m(1, 2) = position.y() - (m(1, 0) * c.x() + m(1, 1) * c.y());
  return m;
}

// Robust circular centre of angles: the candidate with the smallest truncated distance sum, then the mean of the
// angles within kInlierRad of it. `rms` over those inliers; `inlier_fraction` of all.
struct CircularFit {
  bool ok = false;
  double centre = 0, rms = 0, inlier_fraction = 0;
};

CircularFit RobustCircularMean(const std::vector<double>& angles) {
  CircularFit fit;
  if (angles.empty()) return fit;
  const size_t stride = std::max<size_t>(1, angles.size() / kMaxCentreCandidates);
  double best_cost = 1e300, seed = 0;
  for (size_t k = 0; k < angles.size(); k += stride) {
    double cost = 0;
    for (size_t i = 0; i < angles.size(); i += stride)
      cost += std::min(std::abs(Wrap(angles[i] - angles[k])), kInlierRad);
    if (cost < best_cost) best_cost = cost, seed = angles[k];
  }
  double sx = 0, sy = 0;
  int n = 0;
  for (double a : angles) {
    if (std::abs(Wrap(a - seed)) >= kInlierRad) continue;
    sx += std::cos(a), sy += std::sin(a), ++n;
  }
  fit.centre = std::atan2(sy, sx);
  fit.rms = 0;
  for (double a : angles) {
    const double d = Wrap(a - fit.centre);
    if (std::abs(d) < kInlierRad) fit.rms += d * d;
  }
  fit.rms = std::sqrt(fit.rms / std::max(1, n));
  fit.inlier_fraction = static_cast<double>(n) / static_cast<double>(angles.size());
  fit.ok = fit.inlier_fraction >= 0.6;
  return fit;
}

// Direction of travel at each frame (radians from east towards north): from the previous to the next frame with a
// position, or one side at the ends; none when the fixes are too close to tell (hovering).
std::vector<std::optional<double>> Courses(const std::vector<BridgeFrame>& frames) {
  std::vector<size_t> with_position;
  for (size_t i = 0; i < frames.size(); ++i)
    if (frames[i].position) with_position.push_back(i);
  std::vector<std::optional<double>> course(frames.size());
  for (size_t k = 0; k < with_position.size(); ++k) {
    const size_t a = with_position[k == 0 ? 0 : k - 1];
    const size_t b = with_position[std::min(k + 1, with_position.size() - 1)];
    const Vec2 d = *frames[b].position - *frames[a].position;
    if (d.norm() >= 1.0) course[with_position[k]] = std::atan2(d.y(), d.x());
  }
  return course;
}

// Image-placed frames before and after a frame whose rotations differ by less than this bracket no turn.
constexpr double kNeighboursAgreeRad = 20.0 * kDeg;
// How far (frames, in the order of flight) the image-placed neighbours of a frame are looked for.
constexpr size_t kMaxGap = 50;

struct Prediction {
  double angle = 0, scale = 0;
  const char* rotation_from = "";
  std::optional<std::pair<size_t, size_t>> between;  // the image-placed frames of one strip around it
};

// How rotation and scale are predicted for a frame, calibrated on the image-placed frames.
class Predictor {
 public:
  Predictor(const std::vector<BridgeFrame>& frames, const BridgeOptions& options, BridgeResult* result)
      : frames_(frames), courses_(Courses(frames)) {
    Calibrate(options, result);
  }
  [[nodiscard]] bool ok() const { return ok_; }
  [[nodiscard]] int sign() const { return sign_; }
  // Rotation (radians) and scale (world units per pixel) of frame i.
  [[nodiscard]] std::optional<Prediction> Predict(size_t i) const;

 private:
  void Calibrate(const BridgeOptions& options, BridgeResult* result);
  void CalibrateHeading(const std::vector<size_t>& refs, const BridgeOptions& options);
  void CalibrateCourse(const std::vector<size_t>& refs, const BridgeOptions& options);
  void CalibrateScale(const std::vector<size_t>& refs);
  [[nodiscard]] std::optional<Prediction> PredictRotation(size_t i) const;
  [[nodiscard]] double GlobalScale(const BridgeFrame& f) const;
  [[nodiscard]] double ScaleBetween(size_t i, size_t before, size_t after) const;
  [[nodiscard]] std::optional<size_t> NearestPlaced(size_t i, int step) const;
  void FitAltitudeScale(const std::vector<size_t>& refs);
  [[nodiscard]] double HeadingDirection(double heading_deg, int sense) const {
    return (90.0 - sense * heading_deg) * kDeg;
  }

  const std::vector<BridgeFrame>& frames_;
  std::vector<std::optional<double>> courses_;
  std::vector<LinearAt> linear_;  // of the reference frames, by frame index (scale 0 for the others)
  bool ok_ = false;
  int sign_ = -1;
  std::optional<CircularFit> heading_, course_;
  int heading_sense_ = 1;
  double per_metre_ = 0, median_scale_ = 0;
  double per_altitude_metre_ = 0, ground_ = 0;  // metres per pixel = per_altitude_metre_ * (altitude - ground_)
};

void Predictor::Calibrate(const BridgeOptions& options, BridgeResult* result) {
  linear_.assign(frames_.size(), {});
  std::vector<size_t> refs;
  int negative = 0;
  for (size_t i = 0; i < frames_.size(); ++i) {
    if (frames_[i].piece >= 0 || !frames_[i].position) continue;
    linear_[i] = Linearise(frames_[i].world_from_frame, Centre(frames_[i].size));
    negative += linear_[i].sign < 0 ? 1 : 0;
    refs.push_back(i);
  }
  result->reference_frames = static_cast<int>(refs.size());
  if (static_cast<int>(refs.size()) < options.min_reference_frames) {
    result->failure = "too few image-placed frames with a position to calibrate (" + std::to_string(refs.size()) +
                      " < " + std::to_string(options.min_reference_frames) + ")";
    return;
  }
  sign_ = 2 * negative >= static_cast<int>(refs.size()) ? -1 : 1;
  CalibrateHeading(refs, options);
  CalibrateCourse(refs, options);
  CalibrateScale(refs);
  ok_ = true;
  result->calibrated = true;
  const CircularFit* used = heading_ ? &*heading_ : course_ ? &*course_ : nullptr;
  result->offset_from = heading_ ? "heading" : course_ ? "course" : "none";
  result->heading_offset_deg = used ? used->centre / kDeg : 0;
  result->heading_rms_deg = used ? used->rms / kDeg : 0;
  result->heading_sense = heading_sense_;
  result->metres_per_px_per_metre = per_metre_;
  result->metres_per_px_per_metre_altitude = per_altitude_metre_;
  result->ground_altitude_m = ground_;
  result->metres_per_px = median_scale_;
}

void Predictor::CalibrateHeading(const std::vector<size_t>& refs, const BridgeOptions& options) {
  std::optional<CircularFit> best;
  for (int sense : {1, -1}) {  // clockwise compass (MAVLink, EXIF) unless the data say the other sense
    std::vector<double> offsets;
    for (size_t i : refs)
      if (frames_[i].heading_deg)
        offsets.push_back(Wrap(linear_[i].angle - HeadingDirection(*frames_[i].heading_deg, sense)));
    if (static_cast<int>(offsets.size()) < options.min_reference_frames) return;
    const CircularFit fit = RobustCircularMean(offsets);
    if (!fit.ok || fit.rms > options.max_heading_rms_deg * kDeg) continue;
    if (!best || fit.rms < 0.8 * best->rms) best = fit, heading_sense_ = sense;
  }
  heading_ = best;
}

void Predictor::CalibrateCourse(const std::vector<size_t>& refs, const BridgeOptions& options) {
  std::vector<double> offsets;
  for (size_t i : refs)
    if (courses_[i]) offsets.push_back(Wrap(linear_[i].angle - *courses_[i]));
  if (static_cast<int>(offsets.size()) < options.min_reference_frames) return;
  const CircularFit fit = RobustCircularMean(offsets);
  if (fit.ok && fit.rms <= options.max_heading_rms_deg * kDeg) course_ = fit;
}

void Predictor::CalibrateScale(const std::vector<size_t>& refs) {
  std::vector<double> per_metre, scales;
  for (size_t i : refs) {
    scales.push_back(linear_[i].scale);
    if (frames_[i].height_m && *frames_[i].height_m > 1.0) per_metre.push_back(linear_[i].scale / *frames_[i].height_m);
  }
  median_scale_ = Median(scales);
  // Heights of most frames are needed: a few would make the model rest on them alone.
  if (2 * per_metre.size() >= refs.size()) {
    per_metre_ = Median(per_metre);
  } else {
    FitAltitudeScale(refs);
  }
}

// Metres per pixel against altitude above sea level, a line through the reference frames (the ground's altitude is
// where it meets zero). Kept only when the altitudes vary and the line explains the scales better than their median.
void Predictor::FitAltitudeScale(const std::vector<size_t>& refs) {
  std::vector<std::pair<double, double>> pts;  // (altitude, scale)
  for (size_t i : refs)
    if (frames_[i].altitude_m) pts.emplace_back(*frames_[i].altitude_m, linear_[i].scale);
  if (pts.size() < 3 || 2 * pts.size() < refs.size()) return;
  double ma = 0, ms = 0;
  for (const auto& [a, sc] : pts) ma += a, ms += sc;
  ma /= static_cast<double>(pts.size());
  ms /= static_cast<double>(pts.size());
  double saa = 0, sas = 0;
  for (const auto& [a, sc] : pts) saa += (a - ma) * (a - ma), sas += (a - ma) * (sc - ms);
  if (saa < 25.0 * static_cast<double>(pts.size())) return;  // altitudes within a few metres: nothing to fit
  const double slope = sas / saa;
  if (!(slope > 0)) return;
  double line_sq = 0, median_sq = 0;
  for (const auto& [a, sc] : pts) {
    line_sq += std::pow(sc - (ms + slope * (a - ma)), 2);
    median_sq += std::pow(sc - median_scale_, 2);
  }
  if (line_sq >= 0.5 * median_sq) return;
  per_altitude_metre_ = slope;
  ground_ = ma - ms / slope;
}

std::optional<Prediction> Predictor::Predict(size_t i) const {
  std::optional<Prediction> p = PredictRotation(i);
  if (!p) return std::nullopt;
  p->scale = p->between ? ScaleBetween(i, p->between->first, p->between->second) : GlobalScale(frames_[i]);
  return p;
}

// The flight's scale model: metres per pixel from the height above take-off, else from the altitude, else the median.
double Predictor::GlobalScale(const BridgeFrame& f) const {
  if (per_metre_ > 0 && f.height_m && *f.height_m > 1.0) return per_metre_ * *f.height_m;
  if (per_altitude_metre_ > 0 && f.altitude_m)
    return std::max(0.25 * median_scale_, per_altitude_metre_ * (*f.altitude_m - ground_));
  return median_scale_;
}

// Between two image-placed frames of one strip: their scales interpolated (the ground and the altitude change
// smoothly along a strip), each carried to this frame's height when the heights are known.
double Predictor::ScaleBetween(size_t i, size_t before, size_t after) const {
  const auto carried = [&](size_t k) {
    const auto& h = frames_[i].height_m;
    const auto& hk = frames_[k].height_m;
    return h && hk && *hk > 1.0 && *h > 1.0 ? linear_[k].scale * *h / *hk : linear_[k].scale;
  };
  const double t = static_cast<double>(i - before) / static_cast<double>(after - before);
  return (1 - t) * carried(before) + t * carried(after);
}

// The heading, calibrated; without one, the image-placed frames just before and after it when they agree (no turn in
// between: a drone need not point along its track, so this beats the direction of travel), else the direction of
// travel, calibrated, else the nearer of those frames.
std::optional<Prediction> Predictor::PredictRotation(size_t i) const {
  const BridgeFrame& f = frames_[i];
  if (heading_ && f.heading_deg)
    return Prediction{Wrap(HeadingDirection(*f.heading_deg, heading_sense_) + heading_->centre), 0, "heading",
                      std::nullopt};
  const std::optional<size_t> before = NearestPlaced(i, -1), after = NearestPlaced(i, 1);
  if (before && after) {
    const double a = linear_[*before].angle, turn = Wrap(linear_[*after].angle - a);
    if (std::abs(turn) < kNeighboursAgreeRad) {
      const double t = static_cast<double>(i - *before) / static_cast<double>(*after - *before);
      return Prediction{Wrap(a + t * turn), 0, "neighbours", std::make_pair(*before, *after)};
    }
  }
  if (course_ && courses_[i]) return Prediction{Wrap(*courses_[i] + course_->centre), 0, "course", std::nullopt};
  if (!before && !after) return std::nullopt;
  const size_t nearest = !after || (before && i - *before <= *after - i) ? *before : *after;
  return Prediction{linear_[nearest].angle, 0, "nearest frame", std::nullopt};
}

// The nearest image-placed frame before (step -1) or after (+1) frame i in the order of flight, within kMaxGap.
std::optional<size_t> Predictor::NearestPlaced(size_t i, int step) const {
  for (size_t d = 1; d <= kMaxGap; ++d) {
    if (step < 0 && i < d) break;
    const size_t k = step < 0 ? i - d : i + d;
    if (k >= frames_.size()) break;
    if (linear_[k].scale > 0) return k;
  }
  return std::nullopt;
}

// world_from_piece for a piece of several image-linked frames (members: indices into `frames`, `flip`: the piece's
// coordinates turned to the world's handedness). From its own GPS positions when they spread far enough, else from
// the members' predicted rotation and scale; the translation always from all of its positions.
std::optional<Mat3> PlacePiece(const std::vector<BridgeFrame>& frames, const std::vector<size_t>& members,
                               const Mat3& flip, const Predictor& predictor, const BridgeOptions& options) {
  std::vector<Vec2> src, dst;
  std::vector<double> rotations, ratios;
  for (size_t i : members) {
    const BridgeFrame& f = frames[i];
    if (!f.position) continue;
    const Mat3 m = flip * f.piece_from_frame;
    src.push_back(Apply(m, Centre(f.size)));
    dst.push_back(*f.position);
    const LinearAt own = Linearise(m, Centre(f.size));
    if (const auto p = predictor.Predict(i)) {
      rotations.push_back(Wrap(p->angle - own.angle));
      ratios.push_back(p->scale / own.scale);
    }
  }
  if (dst.empty()) return std::nullopt;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : dst) mean += p;
  mean /= static_cast<double>(dst.size());
  double spread = 0;
  for (const auto& p : dst) spread += (p - mean).squaredNorm();
  spread = std::sqrt(spread / static_cast<double>(dst.size()));
  Similarity2 sim;
  if (dst.size() >= 3 && spread >= options.piece_fit_min_spread_m && FitSimilarity<2>(src, dst, &sim)) {
    Mat3 m = Mat3::Identity();
    m.topLeftCorner<2, 2>() = sim.scale * sim.rotation;
    m.topRightCorner<2, 1>() = sim.translation;
    return m * flip;
  }
  if (rotations.empty()) return std::nullopt;
  const CircularFit rot = RobustCircularMean(rotations);
  const double ratio = Median(ratios);
  Mat3 m = Mat3::Identity();
  m.topLeftCorner<2, 2>() = ratio * Eigen::Rotation2Dd(rot.centre).toRotationMatrix();
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
  for (size_t k = 0; k < src.size(); ++k) t += dst[k] - m.topLeftCorner<2, 2>() * src[k];
  m.topRightCorner<2, 1>() = t / static_cast<double>(src.size());
  return m * flip;
}

}  // namespace

bool BridgeOptions::Check(std::string* why) const {
  if (min_reference_frames < 2) {
    *why = "bridge.min_reference_frames must be >= 2";
    return false;
  }
  if (!(max_heading_rms_deg > 0) || !(piece_fit_min_spread_m >= 0)) {
    *why = "bridge.max_heading_rms_deg must be > 0 and bridge.piece_fit_min_spread_m >= 0";
    return false;
  }
  return true;
}

BridgeResult PlaceByTelemetry(const std::vector<BridgeFrame>& frames, const BridgeOptions& options) {
  BridgeResult result;
  std::map<int, std::vector<size_t>> pieces;
  for (size_t i = 0; i < frames.size(); ++i)
    if (frames[i].piece >= 0) pieces[frames[i].piece].push_back(i);
  if (!options.enabled) {
    result.failure = "bridging is off (bridge.enabled)";
    return result;
  }
  if (pieces.empty()) return result;
  const Predictor predictor(frames, options, &result);
  if (!predictor.ok()) return result;
  for (const auto& [piece, members] : pieces) {
    std::optional<Mat3> world_from_piece;
    Mat3 flip = Mat3::Identity();
    if (members.size() == 1) {
      const BridgeFrame& f = frames[members.front()];
      const auto p = f.position ? predictor.Predict(members.front()) : std::nullopt;
      if (p) {
        world_from_piece = Place(*f.position, p->angle, p->scale, predictor.sign(), f.size);
        ++result.rotation_from[p->rotation_from];
      }
    } else {
      const LinearAt own = Linearise(frames[members.front()].piece_from_frame, Centre(frames[members.front()].size));
      if (own.sign != predictor.sign()) flip(1, 1) = -1;
      world_from_piece = PlacePiece(frames, members, flip, predictor, options);
    }
    if (!world_from_piece) {
      result.frames_without_position += static_cast<int>(members.size());
      continue;
    }
    ++result.pieces_placed;
    for (size_t i : members) {
      const Mat3 m = members.size() == 1 ? *world_from_piece : *world_from_piece * frames[i].piece_from_frame;
      result.placed.push_back({frames[i].id, m, piece});
    }
  }
  return result;
}

}  // namespace uavm
