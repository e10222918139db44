#include "core/adjust/lens_calibration.h"

#include <spdlog/spdlog.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <future>
#include <tuple>

#include "core/util/clock.h"

namespace uavm {

bool LensCalibrationOptions::Check(std::string* why) const {
  if (min_frames < 2 || max_frames < min_frames || max_correspondences < 100 ||
      !(min_holdout_gain >= 0 && min_holdout_gain < 1) || !(min_holdout_t >= 0) ||
      !(max_distortion > 0 && max_distortion < 1) || !(prior_weight >= 0) || !(min_effect_px >= 0) ||
      !(max_halves_disagreement >= 0) || !(halves_below_gain >= 0 && halves_below_gain < 1) ||
      !(rematch_holdout_tolerance >= 0)) {
    if (why != nullptr)
      *why =
          "lens_calibration: min_frames >= 2, max_frames >= min_frames, max_correspondences >= 100, "
          "min_holdout_gain in [0,1), min_holdout_t >= 0, max_distortion in (0,1), prior_weight >= 0, "
          "min_effect_px >= 0, max_halves_disagreement >= 0, halves_below_gain in [0,1), "
          "rematch_holdout_tolerance >= 0";
    return false;
  }
  return true;
}

namespace {

// r_ideal(r_distorted) of a Brown distortion (its inverse along a radius).
double UndistortedRadius(double r, const void* ctx) {
  return static_cast<const LensDistortion*>(ctx)->Undistort(Vec2(r, 0.0)).x();
}

// r_distorted(r_ideal) of an undistortion r_i = r_d (1 + u1 r_d^2 + u2 r_d^4 + u3 r_d^6), by Newton steps.
double DistortedRadius(double ri, const void* ctx) {
  const auto& u = *static_cast<const std::array<double, 3>*>(ctx);
  double rd = ri;
  for (int it = 0; it < 30; ++it) {
    const double r2 = rd * rd;
    const double f = rd * (1.0 + r2 * (u[0] + r2 * (u[1] + r2 * u[2]))) - ri;
    const double df = 1.0 + r2 * (3.0 * u[0] + r2 * (5.0 * u[1] + 7.0 * r2 * u[2]));
    if (!(std::abs(df) > 1e-9)) break;
    const double step = f / df;
    rd -= step;
    if (std::abs(step) < 1e-14) break;
  }
  return rd;
}

}  // namespace

std::array<double, 3> UndistortionFromDistortion(const LensDistortion& d, double max_radius) {
  // The inverse curve r_i(r_d): r_i / r_d - 1 = u1 r^2 + u2 r^4 + u3 r^6, least squares over evenly spaced radii.
  if (d.k1 == 0.0 && d.k2 == 0.0) return {0.0, 0.0, 0.0};
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (int i = 1; i <= 200; ++i) {
    const double rd = max_radius * i / 200.0;
    const double y = UndistortedRadius(rd, &d) / rd - 1.0;
    const double r2 = rd * rd;
    const Eigen::Vector3d row(r2, r2 * r2, r2 * r2 * r2);
    ata += row * row.transpose();
    atb += row * y;
  }
  const Eigen::Vector3d u = ata.ldlt().solve(atb);
  return {u[0], u[1], u[2]};
}

LensDistortion DistortionFromUndistortion(const std::array<double, 3>& u, double max_radius) {
  return FitRadialDistortion(&DistortedRadius, &u, max_radius);
}

namespace {

struct TwoLenses {
  LensDistortion first, residual;
};

double ComposedDistortedRadius(double r, const void* ctx) {
  const auto& l = *static_cast<const TwoLenses*>(ctx);
  return l.first.Distort(l.residual.Distort(Vec2(r, 0.0))).x();
}

}  // namespace

LensDistortion ComposeRadial(const LensDistortion& first, const LensDistortion& residual, double max_radius) {
  const TwoLenses lenses{first, residual};
  const double ideal_max = residual.Undistort(first.Undistort(Vec2(max_radius, 0.0))).x();
  return FitRadialDistortion(&ComposedDistortedRadius, &lenses, std::max(max_radius, ideal_max));
}

PairedGain HoldoutPairedGain(const std::vector<const Edge*>& edges, const std::unordered_map<int, Mat3>& without,
                             const std::unordered_map<int, Mat3>& with, const LensRefine& lens) {
  std::vector<double> drops;  // per edge: mean over its held-out points of e_without^2 - e_with^2
  for (const Edge* e : edges) {
    const auto s0 = without.find(e->src);
    const auto t0 = without.find(e->tgt);
    const auto s1 = with.find(e->src);
    const auto t1 = with.find(e->tgt);
    if (e->points.holdout_size() == 0 || s0 == without.end() || t0 == without.end() || s1 == with.end() ||
        t1 == with.end())
      continue;
    const Mat3 tgt_from_src0 = t0->second.inverse() * s0->second;
    const Mat3 tgt_from_src1 = t1->second.inverse() * s1->second;
    double sum = 0.0;
    for (size_t k = 0; k < e->points.holdout_size(); ++k) {
      const Vec2 p = e->points.holdout_src(k).cast<double>();
      const Vec2 q = e->points.holdout_tgt(k).cast<double>();
      sum += (Apply(tgt_from_src0, p) - q).squaredNorm() -
             (Apply(tgt_from_src1, lens.Ideal(p)) - lens.Ideal(q)).squaredNorm();
    }
    drops.push_back(sum / static_cast<double>(e->points.holdout_size()));
  }
  PairedGain gain;
  gain.edges = drops.size();
  if (drops.size() < 3) return gain;
  const auto n = static_cast<double>(drops.size());
  double mean = 0.0;
  for (double d : drops) mean += d;
  mean /= n;
  double var = 0.0;
  for (double d : drops) var += (d - mean) * (d - mean);
  var /= n - 1.0;
  gain.mean_drop_px2 = mean;
  const double standard_error = std::sqrt(var / n);
  gain.t = standard_error > 0 ? mean / standard_error : (mean > 0 ? HUGE_VAL : 0.0);
  return gain;
}

void ReprojectEdgePoints(const PinholeCamera& prepared, const LensDistortion& calibrated, Edge* edge) {
  PinholeCamera to = prepared;
  to.distortion = calibrated;
  for (Vec2f& p : edge->points.all()) p = to.UndistortPixel(prepared.DistortPixel(p.cast<double>())).cast<float>();
}

namespace {

// The lens estimated on the frames of one half alone (their edges among themselves; the half's first frame, or the
// anchor when it is there, holds the gauge): its distortion at the half-diagonal, NaN when the solve failed or the
// half is too small.
double LensOfHalf(const std::vector<const Edge*>& edges, const std::vector<int>& half, int anchor,
                  const std::unordered_map<int, double>& half_diagonal, const RefineOptions& subset,
                  const PinholeCamera& prepared, const LensRefine& start_lens,
                  const std::unordered_map<int, Mat3>& start) {
  const std::unordered_set<int> members(half.begin(), half.end());
  const int gauge = members.count(anchor) != 0 ? anchor : half.front();
  std::unordered_set<int> variable = members;
  variable.erase(gauge);
  std::vector<const Edge*> inside;
  for (const Edge* e : edges)
    if (members.count(e->src) != 0 && members.count(e->tgt) != 0) inside.push_back(e);
  if (variable.size() < 2 || inside.size() < 3) return std::nan("");
  LensRefine lens = start_lens;
  std::unordered_map<int, Mat3> maps;
  for (int id : half) maps[id] = start.at(id);
  if (!RefineGlobal(inside, variable, gauge, half_diagonal, subset, &maps, &lens).ok) return std::nan("");
  PinholeCamera estimated = prepared;
  estimated.distortion = DistortionFromUndistortion(lens.undistortion, 1.05 * prepared.HalfDiagonalRadius());
  return estimated.RadialDistortionAtHalfDiagonal();
}

// Both halves' lenses, each on its own thread.
std::pair<double, double> LensOfHalves(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                                       int anchor, const std::unordered_map<int, double>& half_diagonal,
                                       const RefineOptions& subset, const PinholeCamera& prepared,
                                       const LensRefine& start_lens, const std::unordered_map<int, Mat3>& start) {
  std::vector<int> frames(variable.begin(), variable.end());
  if (anchor >= 0) frames.push_back(anchor);
  std::sort(frames.begin(), frames.end());
  const auto middle = frames.begin() + static_cast<long>(frames.size() / 2);
  const std::vector<int> lower(frames.begin(), middle);
  const std::vector<int> upper(middle, frames.end());
  auto a = std::async(std::launch::async, [&] {
    return LensOfHalf(edges, lower, anchor, half_diagonal, subset, prepared, start_lens, start);
  });
  const double b = LensOfHalf(edges, upper, anchor, half_diagonal, subset, prepared, start_lens, start);
  return {a.get(), b};
}

// The free-lens solve once more, from the maps the prepared lens converged to: it replaces `r1` (its lens and maps)
// when it fits its points better or `r1` failed.
void SolveFromConvergedMaps(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable, int anchor,
                            const std::unordered_map<int, double>& half_diagonal, const RefineOptions& subset,
                            const LensRefine& start_lens, const std::unordered_map<int, Mat3>& converged,
                            RefineResult* r1, LensRefine* lens, std::unordered_map<int, Mat3>* with) {
  LensRefine second_lens = start_lens;
  std::unordered_map<int, Mat3> second_maps = converged;
  const RefineResult second = RefineGlobal(edges, variable, anchor, half_diagonal, subset, &second_maps, &second_lens);
  if (!second.ok || (r1->ok && second.final_all_rms_px >= r1->final_all_rms_px)) return;
  *r1 = second;
  *lens = second_lens;
  *with = std::move(second_maps);
}

}  // namespace

LensCalibration CalibrateLens(const std::vector<const Edge*>& edges, const std::unordered_set<int>& variable,
                              int anchor, const std::unordered_map<int, double>& half_diagonal,
                              const RefineOptions& refine, const PinholeCamera& prepared,
                              const LensCalibrationOptions& options, const std::unordered_map<int, Mat3>& start,
                              std::string_view log_name) {
  LensCalibration cal;
  StageTimer timer;
  const LensDistortion& d0 = prepared.distortion;
  if (d0.p1 != 0.0 || d0.p2 != 0.0) {
    cal.why = "the configured lens has tangential terms: kept as it is";
    return cal;
  }
  if (variable.size() + 1 < static_cast<size_t>(options.min_frames)) {
    cal.why = "too few frames (" + std::to_string(variable.size() + 1) + ") to calibrate the lens";
    return cal;
  }
  cal.tried = true;
  RefineOptions subset = refine;
  subset.max_correspondences = options.max_correspondences;
  // Without: the prepared lens as it is. With: the same solve, the undistortion free, from two starts: the linear maps
  // (beside the first solve, on the second core, when both fit the refinement's line of the plan: each is one-threaded
  // and the end of the flight has both cores; ~7 MiB more, the window bounding it) and the maps the prepared lens
  // converged to. From the linear maps a lens far from the prepared one and the perspectives can wander together
  // (caliterra under its raw-file database lens: no convergence in 50 iterations, a folded perspective); the linear
  // start stays because it is the one every other flight was measured with. The one fitting its points better wins.
  std::unordered_map<int, Mat3> without = start;
  const bool side_by_side = 2 * int64_t{subset.max_correspondences} <= refine.max_correspondences;
  const double max_radius = 1.05 * prepared.HalfDiagonalRadius();
  LensRefine lens;
  lens.prepared = prepared;
  lens.undistortion = UndistortionFromDistortion(d0, max_radius);
  lens.prior_weight = options.prior_weight;
  const LensRefine start_lens = lens;
  std::unordered_map<int, Mat3> with = start;
  auto from_linear = std::async(side_by_side ? std::launch::async : std::launch::deferred, [&] {
    return RefineGlobal(edges, variable, anchor, half_diagonal, subset, &with, &lens);
  });
  const RefineResult r0 = RefineGlobal(edges, variable, anchor, half_diagonal, subset, &without);
  RefineResult r1 = from_linear.get();
  if (r0.ok)
    SolveFromConvergedMaps(edges, variable, anchor, half_diagonal, subset, start_lens, without, &r1, &lens, &with);
  cal.used = r1.num_used;
  cal.seconds = timer.ElapsedMs() / 1000.0;
  if (!r0.ok || !r1.ok) {
    cal.solve_failed = true;
    cal.why = "refinement failed: " + (r0.ok ? r1.failure : r0.failure);
    return cal;
  }
  const TransferStats h0 = TransferErrors(edges, without, true);
  const TransferStats h1 = TransferErrors(edges, with, true, 0.0, &lens);
  cal.holdout_without_px = h0.rms;
  cal.holdout_with_px = h1.rms;
  cal.holdout_points = h1.count;
  const PairedGain paired = HoldoutPairedGain(edges, without, with, lens);
  cal.holdout_edges = paired.edges;
  cal.holdout_gain_t = paired.t;
  cal.distortion = DistortionFromUndistortion(lens.undistortion, max_radius);
  PinholeCamera estimated = prepared;
  estimated.distortion = cal.distortion;
  cal.distortion_at_half_diagonal = estimated.RadialDistortionAtHalfDiagonal();
  const double effect_px =
      std::abs(cal.distortion_at_half_diagonal) * 0.5 * std::hypot(prepared.width, prepared.height);
  if (h1.count < 50) {
    cal.why = "too few held-out correspondences (" + std::to_string(h1.count) + ") to judge a lens";
  } else if (!(std::abs(cal.distortion_at_half_diagonal) <= options.max_distortion)) {
    cal.why = "implausible distortion at the half-diagonal (" + std::to_string(cal.distortion_at_half_diagonal) + ")";
  } else if (!(h1.rms < (1.0 - options.min_holdout_gain) * h0.rms) || !(paired.t >= options.min_holdout_t)) {
    cal.why = "the flight does not determine the lens: held-out RMS " + std::to_string(h0.rms) + " -> " +
              std::to_string(h1.rms) + " px, paired t " + std::to_string(paired.t) + " over " +
              std::to_string(paired.edges) + " edges";
  } else if (!(effect_px >= options.min_effect_px)) {
    cal.why = "too small to matter: " + std::to_string(effect_px) + " px at the half-diagonal";
  } else if (options.max_halves_disagreement > 0 && h1.rms > (1.0 - options.halves_below_gain) * h0.rms) {
    std::tie(cal.half_a_at_half_diagonal, cal.half_b_at_half_diagonal) =
        LensOfHalves(edges, variable, anchor, half_diagonal, subset, prepared, start_lens, start);
    const double disagreement = std::abs(cal.half_a_at_half_diagonal - cal.half_b_at_half_diagonal);
    if (!(disagreement <= options.max_halves_disagreement * std::abs(cal.distortion_at_half_diagonal)))
      cal.why = "the halves of the flight disagree: " + std::to_string(cal.half_a_at_half_diagonal) + " and " +
                std::to_string(cal.half_b_at_half_diagonal) + " at the half-diagonal";
    else
      cal.accepted = true;
  } else {
    cal.accepted = true;
  }
  cal.seconds = timer.ElapsedMs() / 1000.0;
  spdlog::info(
      "{} {}: k1 {:.4f} k2 {:.4f} ({:+.4f} at the half-diagonal; halves {:+.4f} {:+.4f}), "
      "held-out RMS {:.3f} -> {:.3f} px over {} points (paired t {:.2f} over {} edges), {:.1f} s{}{}",
      log_name, cal.accepted ? "accepted" : "refused", cal.distortion.k1, cal.distortion.k2,
      cal.distortion_at_half_diagonal, cal.half_a_at_half_diagonal, cal.half_b_at_half_diagonal, h0.rms, h1.rms,
      h1.count, paired.t, paired.edges, cal.seconds, cal.why.empty() ? "" : ": ", cal.why);
  return cal;
}

}  // namespace uavm
