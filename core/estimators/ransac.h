#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace uavm {

struct RansacOptions {
  double max_error = 3.0;  // inlier threshold, pixels
  double confidence = 0.999;
  int min_iterations = 30;
  int max_iterations = 2000;
  int local_optimization_steps = 3;  // least-squares refits on the inlier set of the best model
  uint64_t seed = 0x5eed;

  [[nodiscard]] bool Check(std::string* why) const {
    const char* problem = nullptr;
    if (!(max_error > 0))
      problem = "ransac.max_error must be > 0";
    else if (!(confidence > 0 && confidence < 1))
      problem = "ransac.confidence must be in (0,1)";
    else if (min_iterations < 1 || max_iterations < min_iterations)
      problem = "ransac iterations: need 1 <= min_iterations <= max_iterations";
    if (problem && why) *why = problem;
    return problem == nullptr;
  }
};

// RANSAC over an Estimator with
//   static constexpr int kMinNumSamples;  using X, Y, Model;
//   static bool Fit(const std::vector<X>&, const std::vector<Y>&, Model*)   // minimal or least squares
//   static double SquaredError(const X&, const Y&, const Model&)
template <typename Estimator>
class RANSAC {
 public:
  using X = typename Estimator::X;
  using Y = typename Estimator::Y;
  using Model = typename Estimator::Model;

  struct Report {
    bool success = false;
    size_t num_inliers = 0;
    int iterations = 0;
    Model model{};
    std::vector<char> inlier_mask;
  };

  explicit RANSAC(const RansacOptions& options) : options_(options) {}

  [[nodiscard]] Report Estimate(const std::vector<X>& x, const std::vector<Y>& y) const {
    return Estimate(x, y, [](const Model&) { return true; });
  }

  // Only models for which is_valid(model) holds compete (minimal samples and refits alike): the best *valid*
  // consensus is returned, not the best consensus that a later check would throw away. Where two structures have
  // similar support (a tilted pair whose near and far ground fit different affines), the implausible one must not
  // hide the other.
  template <typename IsValid>
  [[nodiscard]] Report Estimate(const std::vector<X>& x, const std::vector<Y>& y, const IsValid& is_valid) const {
    Report report;
    const size_t n = x.size();
    constexpr int kMin = Estimator::kMinNumSamples;
    if (n < static_cast<size_t>(kMin) || y.size() != n) return report;
    const double max_sq = options_.max_error * options_.max_error;
    std::mt19937_64 rng(options_.seed);
    std::uniform_int_distribution<size_t> pick(0, n - 1);
    std::vector<X> xs(kMin);
    std::vector<Y> ys(kMin);
    size_t best_count = 0;
    Model best{};
    int max_iters = options_.max_iterations;
    int it = 0;
    for (; it < max_iters; ++it) {
      size_t idx[kMin];
      for (int k = 0; k < kMin; ++k) {
        bool unique = false;
        while (!unique) {
          idx[k] = pick(rng);
          unique = std::find(idx, idx + k, idx[k]) == idx + k;
        }
        xs[k] = x[idx[k]];
        ys[k] = y[idx[k]];
      }
      Model model;
      if (!Estimator::Fit(xs, ys, &model) || !is_valid(model)) continue;
      const size_t count = CountInliers(x, y, model, max_sq);
      if (count > best_count) {
        best_count = count;
        best = model;
        const double inlier_ratio = static_cast<double>(count) / static_cast<double>(n);
        const double p_fail = 1.0 - std::pow(inlier_ratio, kMin);
        if (p_fail <= 1e-12) {
          max_iters = std::min(max_iters, std::max(options_.min_iterations, it + 1));
        } else {
          const double needed = std::log(1.0 - options_.confidence) / std::log(p_fail);
          if (needed < static_cast<double>(max_iters))
            max_iters = std::max(options_.min_iterations, static_cast<int>(std::ceil(needed)));
        }
      }
    }
    report.iterations = it;
    if (best_count < static_cast<size_t>(kMin)) return report;
    // Local optimisation: refit on all inliers of the current model, which removes the minimal sample's noise.
    // The refit is kept unless it loses a noticeable share of the support (inlier counts at a hard threshold are
    // noisy; a least-squares model that drops 1 % of borderline points is still the better estimate).
    for (int step = 0; step < options_.local_optimization_steps; ++step) {
      std::vector<X> xi;
      std::vector<Y> yi;
      for (size_t i = 0; i < n; ++i) {
        if (Estimator::SquaredError(x[i], y[i], best) <= max_sq) {
          xi.push_back(x[i]);
          yi.push_back(y[i]);
        }
      }
      Model refined;
      if (!Estimator::Fit(xi, yi, &refined) || !is_valid(refined)) break;
      const size_t count = CountInliers(x, y, refined, max_sq);
      if (static_cast<double>(count) < 0.95 * static_cast<double>(best_count)) break;
      best = refined;
      const bool converged = count == best_count;
      best_count = count;
      if (converged) break;
    }
    report.model = best;
    report.inlier_mask.resize(n);
    report.num_inliers = 0;
    for (size_t i = 0; i < n; ++i) {
      report.inlier_mask[i] = Estimator::SquaredError(x[i], y[i], best) <= max_sq ? 1 : 0;
      report.num_inliers += static_cast<size_t>(report.inlier_mask[i]);
    }
    report.success = report.num_inliers >= static_cast<size_t>(kMin);
    return report;
  }

 private:
  static size_t CountInliers(const std::vector<X>& x, const std::vector<Y>& y, const Model& m, double max_sq) {
    size_t count = 0;
    for (size_t i = 0; i < x.size(); ++i) count += Estimator::SquaredError(x[i], y[i], m) <= max_sq ? 1u : 0u;
    return count;
  }

  RansacOptions options_;
};

}  // namespace uavm
