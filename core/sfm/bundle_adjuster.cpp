#include "core/sfm/bundle_adjuster.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace uavm::sfm {

bool BundleOptions::Check(std::string* why) const {
  if (!(loss_scale_px > 0.0)) {
    *why = "bundle: loss_scale_px must be > 0";
    return false;
  }
  if (!(control_sigma_m > 0.0) || !(control_click_px > 0.0) || !(control_sigma_z_m >= 0.0)) {
    *why = "bundle: control_sigma_m and control_click_px must be > 0";
    return false;
  }
  if (max_iterations < 1 || threads < 1 || min_images_for_lens < 1) {
    *why = "bundle: max_iterations, threads and min_images_for_lens must be >= 1";
    return false;
  }
  return true;
}

namespace {

// Intrinsics block: f cx cy k1 k2 p1 p2 k3 (fx = fy: square pixels).
constexpr int kIntrinsics = 8;

struct ReprojectionCost {
  ReprojectionCost(double x, double y, double weight = 1.0) : x(x), y(y), weight(weight) {}
  template <typename T>
  bool operator()(const T* const intr, const T* const rot, const T* const centre, const T* const point,
                  T* residual) const {
    T d[3] = {point[0] - centre[0], point[1] - centre[1], point[2] - centre[2]};
    T p[3];
    ceres::AngleAxisRotatePoint(rot, d, p);
    const T xn = p[0] / p[2], yn = p[1] / p[2];
    const T r2 = xn * xn + yn * yn;
    const T radial = T(1) + r2 * (intr[3] + r2 * (intr[4] + r2 * intr[7]));
    const T xd = xn * radial + T(2) * intr[5] * xn * yn + intr[6] * (r2 + T(2) * xn * xn);
    const T yd = yn * radial + intr[5] * (r2 + T(2) * yn * yn) + T(2) * intr[6] * xn * yn;
    residual[0] = (intr[0] * xd + intr[1] - T(x)) * T(weight);
    residual[1] = (intr[0] * yd + intr[2] - T(y)) * T(weight);
    return true;
  }
  double x, y, weight;
};

struct FocalPrior {
  FocalPrior(double f0, double sigma) : f0(f0), sigma(sigma) {}
  template <typename T>
  bool operator()(const T* const intr, T* residual) const {
    residual[0] = (intr[0] - T(f0)) / T(sigma);
    return true;
  }
  double f0, sigma;
};

struct CentrePrior {
  CentrePrior(const Eigen::Vector3d& c, double sxy, double sz) : c(c), sxy(sxy), sz(sz) {}
  template <typename T>
  bool operator()(const T* const centre, T* residual) const {
    residual[0] = (centre[0] - T(c.x())) / T(sxy);
    residual[1] = (centre[1] - T(c.y())) / T(sxy);
    residual[2] = (centre[2] - T(c.z())) / T(sz);
    return true;
  }
  Eigen::Vector3d c;
  double sxy, sz;
};

using Intrinsics = std::array<double, kIntrinsics>;

// Each control point's 3-D block, its clicks and its surveyed position; returns how many entered.
int AddControl(const BundleOptions& options, const Reconstruction& rec, std::vector<Intrinsics>& intr,
               std::vector<std::array<double, 3>>& rot, std::vector<std::array<double, 3>>& centre,
               std::vector<Eigen::Vector3d>* blocks, ceres::Problem* problem) {
  blocks->clear();
  for (const auto& cp : options.control) blocks->push_back(cp.world);
  int n = 0;
  for (size_t k = 0; k < options.control.size(); ++k) {
    const auto& cp = options.control[k];
    double* X = (*blocks)[k].data();
    for (const auto& [image, pixel] : cp.observations) {
      const auto i = static_cast<size_t>(image);
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<ReprojectionCost, 2, kIntrinsics, 3, 3, 3>(
                                    new ReprojectionCost(pixel.x(), pixel.y(), 1.0 / options.control_click_px)),
                                nullptr, intr[static_cast<size_t>(rec.images[i].camera)].data(), rot[i].data(),
                                centre[i].data(), X);
    }
    problem->AddResidualBlock(
        new ceres::AutoDiffCostFunction<CentrePrior, 3, 3>(
            new CentrePrior(cp.world, options.control_sigma_m,
                            options.control_sigma_z_m > 0.0 ? options.control_sigma_z_m : options.control_sigma_m)),
        nullptr, X);
    ++n;
  }
  return n;
}

}  // namespace

bool BundleAdjust(Reconstruction* rec, const BundleOptions& options, BundleSummary* summary, std::string* error) {
  if (!options.Check(error)) return false;
  if (rec->images.size() < 2 || rec->points.empty()) {
    *error = "bundle: needs at least two images and one point";
    return false;
  }
  // One intrinsics block per camera (a flight may mix cameras or image sizes), shared by its images.
  std::vector<Intrinsics> intr;
  for (const Camera& c : rec->cameras) intr.push_back({c.fx, c.cx, c.cy, c.k1, c.k2, c.p1, c.p2, c.k3});
  const size_t n_images = rec->images.size();
  std::vector<std::array<double, 3>> rot(n_images), centre(n_images);
  for (size_t i = 0; i < n_images; ++i) {
    const Eigen::Matrix3d R = rec->images[i].pose.R;
    ceres::RotationMatrixToAngleAxis(ceres::ColumnMajorAdapter3x3(R.data()), rot[i].data());
    for (int k = 0; k < 3; ++k) centre[i][static_cast<size_t>(k)] = rec->images[i].pose.c(k);
  }
  summary->rms_before_px = rec->ReprojectionRms();

  ceres::Problem problem;
  ceres::LossFunction* loss = nullptr;
  if (options.loss == BundleOptions::Loss::kHuber) loss = new ceres::HuberLoss(options.loss_scale_px);
  if (options.loss == BundleOptions::Loss::kCauchy) loss = new ceres::CauchyLoss(options.loss_scale_px);
  std::vector<bool> used(n_images, false);
  for (auto& p : rec->points) {
    for (const auto& o : p.track) {
      const size_t i = static_cast<size_t>(o.image);
      const auto& kp = rec->images[i].keypoints[static_cast<size_t>(o.feature)];
      auto* cost = new ceres::AutoDiffCostFunction<ReprojectionCost, 2, kIntrinsics, 3, 3, 3>(
          new ReprojectionCost(kp.x(), kp.y()));
      // One loss object for all blocks: the problem reference-counts it and deletes it once.
      problem.AddResidualBlock(cost, loss, intr[static_cast<size_t>(rec->images[i].camera)].data(), rot[i].data(),
                               centre[i].data(), p.X.data());
      used[i] = true;
    }
  }
  int n_priors = 0;
  for (size_t i = 0; i < n_images && i < options.centre_priors.size(); ++i) {
    if (!options.centre_priors[i] || !used[i]) continue;
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<CentrePrior, 3, 3>(new CentrePrior(
                                 *options.centre_priors[i], options.prior_sigma_xy_m, options.prior_sigma_z_m)),
                             nullptr, centre[i].data());
    ++n_priors;
  }
  std::vector<Eigen::Vector3d> control_blocks;
  const int n_control = AddControl(options, *rec, intr, rot, centre, &control_blocks, &problem);
  if (n_control >= 3) n_priors = std::max(n_priors, 3);  // the control points fix the gauge
  // Gauge: the priors (or control points), or one image and one coordinate of another.
  int fixed = options.fixed_image;
  if (fixed < 0 || fixed >= static_cast<int>(n_images) || !used[static_cast<size_t>(fixed)]) {
    fixed = -1;
    for (size_t i = 0; i < n_images && fixed < 0; ++i) {
      if (used[i]) fixed = static_cast<int>(i);
    }
  }
  int scale = options.scale_image;
  const auto& cf = rec->images[static_cast<size_t>(fixed)].pose.c;
  if (scale < 0 || scale >= static_cast<int>(n_images) || scale == fixed || !used[static_cast<size_t>(scale)]) {
    double best = -1.0;
    for (size_t i = 0; i < n_images; ++i) {
      const double d = (rec->images[i].pose.c - cf).norm();
      if (used[i] && static_cast<int>(i) != fixed && d > best) {
        best = d;
        scale = static_cast<int>(i);
      }
    }
  }
  if (n_priors < 3) {
    problem.SetParameterBlockConstant(rot[static_cast<size_t>(fixed)].data());
    problem.SetParameterBlockConstant(centre[static_cast<size_t>(fixed)].data());
  }
  if (scale >= 0 && n_priors < 3) {
    const Eigen::Vector3d d = rec->images[static_cast<size_t>(scale)].pose.c - cf;
    int axis = 0;
    d.cwiseAbs().maxCoeff(&axis);
    problem.SetManifold(centre[static_cast<size_t>(scale)].data(), new ceres::SubsetManifold(3, {axis}));
  }
  std::vector<int> held;
  held.reserve(kIntrinsics);  // (also keeps GCC 12's -Wstringop-overflow from a false positive on the inserts)
  if (!options.refine_focal) held.push_back(0);
  if (!options.refine_principal_point) held.insert(held.end(), {1, 2});
  if (!options.refine_radial) held.insert(held.end(), {3, 4});
  if (!options.refine_tangential) held.insert(held.end(), {5, 6});
  if (!options.refine_k3 || !options.refine_radial) held.push_back(7);
  std::vector<int> images_of(intr.size(), 0);
  for (size_t i = 0; i < n_images; ++i)
    if (used[i]) ++images_of[static_cast<size_t>(rec->images[i].camera)];
  for (size_t k = 0; k < intr.size(); ++k) {
    double* block = intr[k].data();
    if (!problem.HasParameterBlock(block)) continue;  // a camera none of whose images observe a point
    std::vector<int> held_k = held;
    const bool focal_held = k < options.focal_held.size() && options.focal_held[k] != 0;
    if (images_of[k] < options.min_images_for_lens) {
      held_k = {1, 2, 3, 4, 5, 6, 7};
      if (!options.refine_focal || focal_held) held_k.push_back(0);
    } else if (focal_held && std::find(held_k.begin(), held_k.end(), 0) == held_k.end()) {
      held_k.insert(held_k.begin(), 0);
    }
    if (held_k.size() == kIntrinsics) {
      problem.SetParameterBlockConstant(block);
    } else if (!held_k.empty()) {
      problem.SetManifold(block, new ceres::SubsetManifold(kIntrinsics, held_k));
    }
    if (options.focal_prior_sigma > 0.0 && options.refine_focal && !focal_held) {
      const double f0 = rec->cameras[k].fx;
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<FocalPrior, 1, kIntrinsics>(
                                   new FocalPrior(f0, options.focal_prior_sigma * f0)),
                               nullptr, block);
    }
  }

  ceres::Solver::Options sopts;
  sopts.linear_solver_type = ceres::SPARSE_SCHUR;
  sopts.max_num_iterations = options.max_iterations;
  sopts.num_threads = options.threads;
  // 1e-6 (Ceres' default), not 1e-8: with 1e-8 every round ran to its iteration cap creeping by < 0.1 % of the RMS;
  // caliterra's adjustment took 77.7 s for 0.6294 px, now 39.2 s for 0.6300 px (brighton_beach 9.2 -> 7.4 s,
  // 0.566 -> 0.571 px, camera centres against GPS unchanged).
  sopts.function_tolerance = 1e-6;
  sopts.parameter_tolerance = 1e-10;
  sopts.logging_type = ceres::SILENT;
  ceres::Solver::Summary s;
  ceres::Solve(sopts, &problem, &s);
  if (!s.IsSolutionUsable()) {
    *error = "bundle: " + s.message;
    return false;
  }
  for (size_t k = 0; k < intr.size(); ++k) {
    Camera& cam = rec->cameras[k];
    const Intrinsics& v = intr[k];
    cam.fx = cam.fy = v[0];
    cam.cx = v[1];
    cam.cy = v[2];
    cam.k1 = v[3];
    cam.k2 = v[4];
    cam.p1 = v[5];
    cam.p2 = v[6];
    cam.k3 = v[7];
  }
  for (size_t i = 0; i < n_images; ++i) {
    Eigen::Matrix3d R;
    ceres::AngleAxisToRotationMatrix(rot[i].data(), ceres::ColumnMajorAdapter3x3(R.data()));
    rec->images[i].pose.R = R;
    rec->images[i].pose.c = Eigen::Vector3d(centre[i][0], centre[i][1], centre[i][2]);
  }
  summary->control_adjusted = control_blocks;
  summary->rms_after_px = rec->ReprojectionRms();
  summary->iterations = static_cast<int>(s.iterations.size());
  summary->seconds = s.total_time_in_seconds;
  summary->converged = s.termination_type == ceres::CONVERGENCE;
  summary->report = s.BriefReport();
  return true;
}

}  // namespace uavm::sfm
