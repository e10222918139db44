#include "core/eval/evaluator.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>

namespace uavm::eval {

namespace {

// Hartley normalisation: centroid to the origin, mean distance sqrt(2).
Mat3 Normaliser(const std::vector<Vec2>& pts) {
  Vec2 c = Vec2::Zero();
  for (const auto& p : pts) c += p;
  c /= static_cast<double>(pts.size());
  double d = 0.0;
  for (const auto& p : pts) d += (p - c).norm();
  d /= static_cast<double>(pts.size());
  const double s = d > 0 ? std::sqrt(2.0) / d : 1.0;
  Mat3 t = Mat3::Identity();
  t(0, 0) = s;
  t(1, 1) = s;
  t(0, 2) = -s * c.x();
  t(1, 2) = -s * c.y();
  return t;
}

// Frame pixel p through a camera's undistortion; p itself without a camera or distortion.
Vec2 Undistorted(const std::optional<PinholeCamera>& camera, const Vec2& p) {
  return camera && !camera->distortion.IsZero() ? camera->UndistortPixel(p) : p;
}

// The session row of each ground-truth frame (nullptr when unregistered or absent): by filename when every
// registered session filename is in the ground truth (robust to skipped inputs shifting indices), else by index.
std::vector<const TransformRow*> PairRows(const std::vector<TransformRow>& session, const std::vector<GtRow>& gt) {
  std::map<std::string, size_t> gt_by_name;
  std::map<int, size_t> gt_by_index;
  for (size_t i = 0; i < gt.size(); ++i) {
    gt_by_name[gt[i].filename] = i;
    gt_by_index[gt[i].index] = i;
  }
  bool by_name = true;
  for (const auto& r : session)
    if (r.registered && !gt_by_name.count(r.filename)) by_name = false;
  std::vector<const TransformRow*> match(gt.size(), nullptr);
  for (const auto& r : session) {
    if (!r.registered) continue;
    if (by_name) {
      match[gt_by_name[r.filename]] = &r;
    } else if (auto it = gt_by_index.find(r.index); it != gt_by_index.end()) {
      match[it->second] = &r;
    }
  }
  return match;
}

double SumSquares(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x * x;
  return s;
}

}  // namespace

bool FitHomography(const std::vector<Vec2>& src, const std::vector<Vec2>& tgt, const std::vector<double>& weights,
                   int iterations, Mat3* tgt_from_src) {
  const size_t n = src.size();
  if (n < 4 || tgt.size() != n || weights.size() != n) return false;
  const Mat3 ts = Normaliser(src);
  const Mat3 tt = Normaliser(tgt);
  std::vector<Vec2> a(n);
  std::vector<Vec2> b(n);
  for (size_t i = 0; i < n; ++i) {
    a[i] = Apply(ts, src[i]);
    b[i] = Apply(tt, tgt[i]);
  }
  // DLT through the 9x9 normal matrix: the refinement below removes the conditioning loss of squaring.
  Eigen::Matrix<double, 9, 9> ata = Eigen::Matrix<double, 9, 9>::Zero();
  for (size_t i = 0; i < n; ++i) {
    const double x = a[i].x(), y = a[i].y(), u = b[i].x(), v = b[i].y();
    Eigen::Matrix<double, 9, 1> r1, r2;
    r1 << x, y, 1, 0, 0, 0, -u * x, -u * y, -u;
    r2 << 0, 0, 0, x, y, 1, -v * x, -v * y, -v;
    ata += weights[i] * (r1 * r1.transpose() + r2 * r2.transpose());
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> es(ata);
  const Eigen::Matrix<double, 9, 1> h9 = es.eigenvectors().col(0);
  if (std::abs(h9(8)) < 1e-12) return false;
  Eigen::Matrix<double, 8, 1> h;
  for (int k = 0; k < 8; ++k) h(k) = h9(k) / h9(8);

  // Levenberg-Marquardt on the weighted transfer error in normalised target coordinates.
  auto residuals = [&](const Eigen::Matrix<double, 8, 1>& p, std::vector<double>* r) {
    r->resize(2 * n);
    for (size_t i = 0; i < n; ++i) {
      const double x = a[i].x(), y = a[i].y();
      const double d = p(6) * x + p(7) * y + 1.0;
      const double sw = std::sqrt(weights[i]);
      (*r)[2 * i] = sw * ((p(0) * x + p(1) * y + p(2)) / d - b[i].x());
      (*r)[2 * i + 1] = sw * ((p(3) * x + p(4) * y + p(5)) / d - b[i].y());
    }
  };
  std::vector<double> r;
  residuals(h, &r);
  double cost = SumSquares(r);
  double lambda = 1e-6;
  for (int it = 0; it < iterations && cost > 0.0; ++it) {
    Eigen::Matrix<double, 8, 8> jtj = Eigen::Matrix<double, 8, 8>::Zero();
    Eigen::Matrix<double, 8, 1> jtr = Eigen::Matrix<double, 8, 1>::Zero();
    for (size_t i = 0; i < n; ++i) {
      const double x = a[i].x(), y = a[i].y();
      const double d = h(6) * x + h(7) * y + 1.0;
      const double u = (h(0) * x + h(1) * y + h(2)) / d;
      const double v = (h(3) * x + h(4) * y + h(5)) / d;
      const double sw = std::sqrt(weights[i]);
      Eigen::Matrix<double, 8, 1> ju, jv;
      ju << x / d, y / d, 1 / d, 0, 0, 0, -u * x / d, -u * y / d;
      jv << 0, 0, 0, x / d, y / d, 1 / d, -v * x / d, -v * y / d;
      ju *= sw;
      jv *= sw;
      jtj += ju * ju.transpose() + jv * jv.transpose();
      jtr += ju * r[2 * i] + jv * r[2 * i + 1];
    }
    bool improved = false;
    for (int tries = 0; tries < 10 && !improved; ++tries) {
      Eigen::Matrix<double, 8, 8> damped = jtj;
      damped.diagonal() *= (1.0 + lambda);
      const Eigen::Matrix<double, 8, 1> step = damped.ldlt().solve(-jtr);
      const Eigen::Matrix<double, 8, 1> trial = h + step;
      std::vector<double> rt;
      residuals(trial, &rt);
      const double ct = SumSquares(rt);
      if (std::isfinite(ct) && ct < cost) {
        h = trial;
        r.swap(rt);
        const double gain = cost - ct;
        cost = ct;
        lambda = std::max(lambda * 0.1, 1e-12);
        improved = true;
        if (gain <= 1e-16 * cost) it = iterations;  // converged
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved) break;
  }
  Mat3 hn;
  hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), 1.0;
  Mat3 m = tt.inverse() * hn * ts;
  *tgt_from_src = m / m(2, 2);
  return tgt_from_src->allFinite();
}

bool EvaluateSession(const std::vector<TransformRow>& session, const std::vector<GtRow>& gt, cv::Size frame_size,
                     EvalResult* result, std::string* error, const EvalOptions& options) {
  *result = EvalResult{};
  if (gt.empty()) {
    *error = "ground truth has no frames";
    return false;
  }
  if (frame_size.width < 2 || frame_size.height < 2 || options.grid < 2) {
    *error = "frame size and grid must be at least 2";
    return false;
  }
  const std::vector<const TransformRow*> match = PairRows(session, gt);

  // Grid of frame points, through both maps.
  std::vector<Vec2> grid;
  for (int j = 0; j < options.grid; ++j)
    for (int i = 0; i < options.grid; ++i)
      grid.emplace_back((frame_size.width - 1.0) * i / (options.grid - 1),
                        (frame_size.height - 1.0) * j / (options.grid - 1));
  std::vector<Vec2> mosaic_pts, canvas_pts;
  std::vector<double> weights, scales;
  std::vector<size_t> owner;
  int registered = 0;
  for (size_t f = 0; f < gt.size(); ++f) {
    if (match[f] == nullptr) continue;
    ++registered;
    for (const Vec2& p : grid) {
      const Vec2 ideal = Undistorted(options.truth_camera, p);
      // A strong barrel folds before the frame's corners: a recorded pixel there has no ideal preimage (its
      // undistortion does not round-trip), so the truth says nothing about it.
      if (options.truth_camera && (options.truth_camera->DistortPixel(ideal) - p).norm() > 1e-3) continue;
      const double s = LocalScale(gt[f].canvas_from_frame, ideal);
      mosaic_pts.push_back(Apply(match[f]->mosaic_from_frame, Undistorted(options.session_camera, p)));
      canvas_pts.push_back(Apply(gt[f].canvas_from_frame, ideal));
      scales.push_back(s);
      weights.push_back(1.0 / (s * s));
      owner.push_back(f);
    }
  }
  result->frames = static_cast<int>(gt.size());
  result->registered = registered;
  result->registered_share = static_cast<double>(result->registered) / static_cast<double>(result->frames);
  if (result->registered == 0) {
    *error = "no registered frame matches the ground truth";
    return false;
  }
  if (!FitHomography(mosaic_pts, canvas_pts, weights, options.refine_iterations, &result->canvas_from_mosaic)) {
    *error = "global mosaic->canvas homography fit failed (degenerate point set)";
    return false;
  }

  result->per_frame.resize(gt.size());
  std::vector<double> sum_sq(gt.size(), 0.0);
  std::vector<size_t> points(gt.size(), 0);  // grid points of each frame the truth covers
  double total_sq = 0.0;
  for (size_t k = 0; k < mosaic_pts.size(); ++k) {
    const double e = (Apply(result->canvas_from_mosaic, mosaic_pts[k]) - canvas_pts[k]).norm() / scales[k];
    sum_sq[owner[k]] += e * e;
    ++points[owner[k]];
    total_sq += e * e;
    result->per_frame[owner[k]].max_px = std::max(result->per_frame[owner[k]].max_px, e);
    result->max_px = std::max(result->max_px, e);
  }
  result->rms_px = std::sqrt(total_sq / static_cast<double>(mosaic_pts.size()));
  double path = 0.0;
  const Vec2 centre((frame_size.width - 1.0) / 2, (frame_size.height - 1.0) / 2);
  std::vector<size_t> reg;
  for (size_t f = 0; f < gt.size(); ++f) {
    FrameError& fe = result->per_frame[f];
    if (f > 0) path += (Apply(gt[f].canvas_from_frame, centre) - Apply(gt[f - 1].canvas_from_frame, centre)).norm();
    fe.index = gt[f].index;
    fe.filename = gt[f].filename;
    fe.registered = match[f] != nullptr;
    fe.path_length_px = path;
    if (fe.registered) {
      fe.rms_px = points[f] > 0 ? std::sqrt(sum_sq[f] / static_cast<double>(points[f])) : 0.0;
      reg.push_back(f);
    }
  }

  // Drift figures over the registered frames in flight order.
  const size_t third = std::max<size_t>(1, reg.size() / 3);
  auto pooled = [&](size_t begin, size_t end) {
    double s = 0.0;
    size_t n = 0;
    for (size_t i = begin; i < end; ++i) {
      s += sum_sq[reg[i]];
      n += points[reg[i]];
    }
    return n > 0 ? std::sqrt(s / static_cast<double>(n)) : 0.0;
  };
  result->first_third_rms_px = pooled(0, third);
  result->last_third_rms_px = pooled(reg.size() - third, reg.size());
  result->drift_ratio = result->first_third_rms_px > 1e-9 ? result->last_third_rms_px / result->first_third_rms_px : 0;
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  const double nreg = static_cast<double>(reg.size());
  for (size_t f : reg) {
    const double x = result->per_frame[f].path_length_px / 1000.0;
    const double y = result->per_frame[f].rms_px;
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  const double den = nreg * sxx - sx * sx;
  result->drift_slope_px_per_kpx = std::abs(den) > 1e-12 ? (nreg * sxy - sx * sy) / den : 0.0;
  return true;
}

std::vector<TransformRow> AffineFloorSession(const std::vector<GtRow>& gt) {
  std::vector<TransformRow> rows;
  rows.reserve(gt.size());
  for (const auto& g : gt) rows.push_back({g.index, g.filename, true, g.affine, "image"});
  return rows;
}

nlohmann::json ToJson(const EvalResult& r, const EvalResult* affine_floor) {
  nlohmann::json j;
  j["frames"] = r.frames;
  j["registered"] = r.registered;
  j["registered_share"] = r.registered_share;
  j["rms_px"] = r.rms_px;
  j["max_px"] = r.max_px;
  if (affine_floor != nullptr) {
    j["affine_floor_rms_px"] = affine_floor->rms_px;
    j["affine_floor_max_px"] = affine_floor->max_px;
  }
  j["drift"] = {{"first_third_rms_px", r.first_third_rms_px},
                {"last_third_rms_px", r.last_third_rms_px},
                {"ratio", r.drift_ratio},
                {"slope_px_per_kpx", r.drift_slope_px_per_kpx}};
  nlohmann::json pf = nlohmann::json::array();
  for (const auto& f : r.per_frame) {
    pf.push_back({{"index", f.index},
                  {"filename", f.filename},
                  {"registered", f.registered},
                  {"rms_px", f.rms_px},
                  {"max_px", f.max_px},
                  {"path_length_px", f.path_length_px}});
  }
  j["per_frame"] = pf;
  const Mat3& h = r.canvas_from_mosaic;
  j["canvas_from_mosaic"] = {h(0, 0), h(0, 1), h(0, 2), h(1, 0), h(1, 1), h(1, 2), h(2, 0), h(2, 1), h(2, 2)};
  j["units"] = "frame pixels (original resolution)";
  return j;
}

}  // namespace uavm::eval
