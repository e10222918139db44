#include "core/radiometry/radiometry.h"

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <string>
#include <unordered_map>
#include <vector>

namespace uavm {

namespace {

constexpr int kLutSize = 1024;  // falloff table over r^2 in [0, 1]

// Bilinear BGR at (x, y) of an 8-bit image; false outside the interior where all four neighbours exist.
bool SampleBgr(const cv::Mat& img, double x, double y, cv::Vec3f* out) {
  if (x < 0 || y < 0 || x > img.cols - 1.001 || y > img.rows - 1.001) return false;
  const int x0 = static_cast<int>(x);
  const int y0 = static_cast<int>(y);
  const auto fx = static_cast<float>(x - x0);
  const auto fy = static_cast<float>(y - y0);
  const auto* r0 = img.ptr<cv::Vec3b>(y0);
  const auto* r1 = img.ptr<cv::Vec3b>(y0 + 1);
  for (int c = 0; c < 3; ++c)
    (*out)[c] =
        (1 - fy) * ((1 - fx) * r0[x0][c] + fx * r0[x0 + 1][c]) + fy * ((1 - fx) * r1[x0][c] + fx * r1[x0 + 1][c]);
  return true;
}

// A pixel's place in its frame: centre and half-diagonal, so that any resolution of the frame gives the same (u, v).
struct PlaceOf {
  explicit PlaceOf(cv::Size s)
      : cx(0.5 * (s.width - 1)),
        cy(0.5 * (s.height - 1)),
        inv_hd(2.0 / std::sqrt(double(s.width) * s.width + double(s.height) * s.height)) {}
  [[nodiscard]] ImagePoint At(double x, double y, double heading) const {
    return {static_cast<float>((x - cx) * inv_hd), static_cast<float>((y - cy) * inv_hd), static_cast<float>(heading)};
  }
  double cx, cy, inv_hd;
};

bool Usable(const cv::Vec3f& v) {
  for (int c = 0; c < 3; ++c)
    if (v[c] < 8.0f || v[c] > 247.0f) return false;
  return true;
}

cv::Vec3f Log(const cv::Vec3f& v) {
  return {std::log(v[0]), std::log(v[1]), std::log(v[2])};
}

void FlatBasis(double u, double v, double* out) {
  const double r2 = u * u + v * v;
  out[0] = u;
  out[1] = v;
  out[2] = u * u - v * v;
  out[3] = u * v;
  out[4] = u * r2;
  out[5] = v * r2;
}

void HotspotBasis(const cv::Point2d& centre, const ImagePoint& p, double* out) {
  const double d2 = (p.u - centre.x) * (p.u - centre.x) + (p.v - centre.y) * (p.v - centre.y);
  for (size_t k = 0; k < Hotspot::kSigma.size(); ++k)
    out[k] = std::exp(-d2 / (2 * Hotspot::kSigma[k] * Hotspot::kSigma[k]));
}

// The shared unknowns of a fit, the same for every frame (the radial falloff, the flat field, the hotspot's profile
// about a given antisolar point), and their basis functions at a point.
struct Terms {
  static constexpr int kMax = 2 + RadiometryModel::kFlatTerms + static_cast<int>(Hotspot::kSigma.size());
  bool radial = false;
  bool flat = false;
  bool hotspot = false;
  Hotspot at;  // antisolar point only

  [[nodiscard]] int Count() const {
    return (radial ? 2 : 0) + (flat ? RadiometryModel::kFlatTerms : 0) +
           (hotspot ? static_cast<int>(Hotspot::kSigma.size()) : 0);
  }
  void Eval(const ImagePoint& p, double* out) const {
    if (radial) {
      const double r2 = p.R2();
      *out++ = r2;
      *out++ = r2 * r2;
    }
    if (flat) {
      FlatBasis(p.u, p.v, out);
      out += RadiometryModel::kFlatTerms;
    }
    if (hotspot) HotspotBasis(at.Centre(p.heading), p, out);
  }
  // The sample's row: basis at a minus basis at b.
  void Row(const RadiometrySample& s, double* row) const {
    std::array<double, kMax> at_b{};
    Eval(s.in_a, row);
    Eval(s.in_b, at_b.data());
    for (int j = 0; j < Count(); ++j) row[j] -= at_b[static_cast<size_t>(j)];
  }
};

using Row = std::array<double, Terms::kMax>;

// One channel's fit: a log gain per frame (by index) and the shared terms' coefficients.
struct Fit {
  std::vector<double> log_gain;
  std::vector<double> shared;
  std::vector<double> weight;  // each sample's robust weight at the last iteration
  bool solved = false;         // the first reweighting's solve succeeded (else the gains are 0: no correction)
  bool iterative = false;
  int most_steps = 0;     // of one conjugate-gradient solve
  int failed_solves = 0;  // reweightings whose solve failed (the fit kept the one before)
};

double PairDifference(const RadiometrySample& s, int channel) {
  return double(s.log_a[channel]) - double(s.log_b[channel]);
}

double Predicted(const Fit& fit, const Terms& terms, const std::unordered_map<int, int>& index,
                 const RadiometrySample& s) {
  Row row{};
  terms.Row(s, row.data());
  double p = fit.log_gain[static_cast<size_t>(index.at(s.a))] - fit.log_gain[static_cast<size_t>(index.at(s.b))];
  for (int j = 0; j < terms.Count(); ++j) p += fit.shared[static_cast<size_t>(j)] * row[static_cast<size_t>(j)];
  return p;
}

double Huber(double r, double width) {
  const double a = std::abs(r);
  return a <= width ? 0.5 * r * r : width * (a - 0.5 * width);
}

// One weighted step's normal equations, summed as they are made: a diagonal over the gains, one entry per pair of
// frames and the shared terms' rows (dense, over every unknown). Their memory grows with the frames and pairs, not
// with the samples: 16 bytes a pair (an edge's samples come in one run, so the pairs are summed in place).
struct NormalEquations {
  Eigen::VectorXd diagonal;
  std::vector<std::pair<uint64_t, double>> pairs;  // key: lower index << 32 | higher index; sorted, distinct
  Eigen::MatrixXd shared_rows;                     // row j: unknown n + j's row of the matrix
  Eigen::VectorXd rhs;
};

NormalEquations SumNormalEquations(const std::vector<RadiometrySample>& samples,
                                   const std::unordered_map<int, int>& index, int channel, const Terms& terms,
                                   double prior, const std::vector<double>& weight) {
  const int n = static_cast<int>(index.size());
  const int m = terms.Count();
  NormalEquations q;
  q.diagonal = Eigen::VectorXd::Constant(n, prior);
  q.shared_rows = Eigen::MatrixXd::Zero(m, n + m);
  for (int j = 0; j < m; ++j) q.shared_rows(j, n + j) = 1e-6 * static_cast<double>(samples.size());
  q.rhs = Eigen::VectorXd::Zero(n + m);
  Row row{};
  for (size_t k = 0; k < samples.size(); ++k) {
    const RadiometrySample& s = samples[k];
    const int ia = index.at(s.a);
    const int ib = index.at(s.b);
    const double w = weight[k];
    const double d = PairDifference(s, channel);
    q.diagonal[ia] += w;
    q.diagonal[ib] += w;
    const uint64_t key = (static_cast<uint64_t>(std::min(ia, ib)) << 32) | static_cast<uint32_t>(std::max(ia, ib));
    if (q.pairs.empty() || q.pairs.back().first != key) q.pairs.emplace_back(key, 0.0);
    q.pairs.back().second -= w;
    q.rhs[ia] += w * d;
    q.rhs[ib] -= w * d;
    if (m == 0) continue;
    terms.Row(s, row.data());
    for (int j = 0; j < m; ++j) {
      const double wj = w * row[static_cast<size_t>(j)];
      q.rhs[n + j] += wj * d;
      q.shared_rows(j, ia) += wj;
      q.shared_rows(j, ib) -= wj;
      for (int l = 0; l < m; ++l) q.shared_rows(j, n + l) += wj * row[static_cast<size_t>(l)];
    }
  }
  // A pair sampled in two runs (the samples were filtered or reordered): merged.
  std::sort(q.pairs.begin(), q.pairs.end());
  size_t out = 0;
  for (size_t k = 0; k < q.pairs.size(); ++k) {
    if (out > 0 && q.pairs[out - 1].first == q.pairs[k].first)
      q.pairs[out - 1].second += q.pairs[k].second;
    else
      q.pairs[out++] = q.pairs[k];
  }
  q.pairs.resize(out);
  q.pairs.shrink_to_fit();
  return q;
}

std::pair<int, int> PairOf(uint64_t key) {
  return {static_cast<int>(key >> 32), static_cast<int>(key & 0xffffffffu)};
}

// The factorisation (up to direct_max_frames frames): exact, but its fill and its ordering's copies of the matrix
// grew to ~10 MB at 5000 frames.
bool SolveDirect(const NormalEquations& q, Eigen::VectorXd* x) {
  const auto n = static_cast<int>(q.diagonal.size());
  const auto m = static_cast<int>(q.shared_rows.rows());
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(static_cast<size_t>(n) + 2 * q.pairs.size() + 2 * static_cast<size_t>(q.shared_rows.size()));
  for (int i = 0; i < n; ++i) t.emplace_back(i, i, q.diagonal[i]);
  for (const auto& [key, v] : q.pairs) {
    const auto [i, j] = PairOf(key);
    t.emplace_back(i, j, v);
    t.emplace_back(j, i, v);
  }
  for (int j = 0; j < m; ++j)
    for (int c = 0; c < n + m; ++c) {
      if (q.shared_rows(j, c) == 0.0) continue;
      t.emplace_back(n + j, c, q.shared_rows(j, c));
      if (c < n) t.emplace_back(c, n + j, q.shared_rows(j, c));  // the gain rows' shared columns
    }
  Eigen::SparseMatrix<double> normal(n + m, n + m);
  normal.setFromTriplets(t.begin(), t.end());
  t = {};
  const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(normal);
  if (solver.info() != Eigen::Success) return false;
  *x = solver.solve(q.rhs);
  return true;
}

// y = N x, with N held as SumNormalEquations left it.
void Multiply(const NormalEquations& q, const Eigen::VectorXd& x, Eigen::VectorXd* y) {
  const Eigen::Index n = q.diagonal.size();
  const Eigen::Index m = q.shared_rows.rows();
  y->resize(n + m);
  y->head(n) = q.diagonal.cwiseProduct(x.head(n));
  if (m > 0) {
    y->tail(m).noalias() = q.shared_rows * x;
    y->head(n).noalias() += q.shared_rows.leftCols(n).transpose() * x.tail(m);
  }
  for (const auto& [key, v] : q.pairs) {
    const auto [i, j] = PairOf(key);
    (*y)[i] += v * x[j];
    (*y)[j] += v * x[i];
  }
}

// Beyond direct_max_frames: conjugate gradients on the same matrix, held as it was summed, preconditioned by its
// diagonal over the gains and its dense block over the shared terms; from `x` (the last reweighting's solution). The
// gain prior bounds the condition number (~ an edge's weight over the prior's), so it converges in a few hundred
// steps however long the flight. False when it does not reach the tolerance in max_iterative_steps; `steps` taken.
bool SolveIterative(const NormalEquations& q, const RadiometryOptions& o, Eigen::VectorXd* x, int* steps) {
  const Eigen::Index n = q.diagonal.size();
  const Eigen::Index m = q.shared_rows.rows();
  const Eigen::LDLT<Eigen::MatrixXd> shared_block(q.shared_rows.rightCols(m));
  const auto precondition = [&](const Eigen::VectorXd& r, Eigen::VectorXd* z) {
    z->resize(n + m);
    z->head(n) = r.head(n).cwiseQuotient(q.diagonal);
    if (m > 0) z->tail(m) = shared_block.solve(r.tail(m));
  };
  if (x->size() != n + m) *x = Eigen::VectorXd::Zero(n + m);
  Eigen::VectorXd r(n + m);
  Eigen::VectorXd z(n + m);
  Eigen::VectorXd p(n + m);
  Eigen::VectorXd np(n + m);
  Multiply(q, *x, &np);
  r = q.rhs - np;
  const double stop = o.iterative_tolerance * std::max(q.rhs.norm(), std::numeric_limits<double>::min());
  precondition(r, &z);
  p = z;
  double rz = r.dot(z);
  for (*steps = 0; *steps < o.max_iterative_steps; ++*steps) {
    if (r.norm() <= stop) return true;
    Multiply(q, p, &np);
    const double curvature = p.dot(np);
    if (!(curvature > 0)) return false;
    const double alpha = rz / curvature;
    *x += alpha * p;
    r -= alpha * np;
    precondition(r, &z);
    const double rz_next = r.dot(z);
    p = z + (rz_next / rz) * p;
    rz = rz_next;
  }
  return r.norm() <= stop;
}

// One weighted least-squares step: the normal equations with the gain prior (and a whisper of ridge on the shared
// terms, which keeps the system definite when the samples barely tell them apart). False when the solve fails (`x`
// unchanged); the iterative path and its steps into `fit`.
bool SolveWeighted(const std::vector<RadiometrySample>& samples, const std::unordered_map<int, int>& index, int channel,
                   const Terms& terms, double prior, const RadiometryOptions& o, Fit* fit, Eigen::VectorXd* x) {
  const NormalEquations q = SumNormalEquations(samples, index, channel, terms, prior, fit->weight);
  if (static_cast<int>(index.size()) <= o.direct_max_frames) return SolveDirect(q, x);
  Eigen::VectorXd y = *x;
  int steps = 0;
  const bool converged = SolveIterative(q, o, &y, &steps);
  fit->iterative = true;
  fit->most_steps = std::max(fit->most_steps, steps);
  if (!converged) return false;
  *x = std::move(y);
  return true;
}

// One channel's robust fit (Huber, iteratively reweighted). `prior_share` pulls each log gain towards 0 as a share of
// an average frame's samples, so that it means the same on any flight. The log gains come back centred (the mean
// frame keeps its brightness).
Fit SolveRobust(const std::vector<RadiometrySample>& samples, const std::unordered_map<int, int>& index, int channel,
                const Terms& terms, double prior_share, const RadiometryOptions& o) {
  const int n = static_cast<int>(index.size());
  const int m = terms.Count();
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n + m);
  Fit fit;
  fit.weight.assign(samples.size(), 1.0);
  const double prior = prior_share * static_cast<double>(samples.size()) / std::max(1, n);
  for (int iteration = 0; iteration < 5; ++iteration) {
    if (!SolveWeighted(samples, index, channel, terms, prior, o, &fit, &x)) {
      ++fit.failed_solves;
      break;
    }
    fit.solved = true;
    fit.log_gain.assign(x.data(), x.data() + n);
    fit.shared.assign(x.data() + n, x.data() + n + m);
    for (size_t k = 0; k < samples.size(); ++k) {
      const double r = std::abs(PairDifference(samples[k], channel) - Predicted(fit, terms, index, samples[k]));
      fit.weight[k] = r <= o.huber_log ? 1.0 : o.huber_log / r;
    }
  }
  fit.log_gain.assign(x.data(), x.data() + n);
  fit.shared.assign(x.data() + n, x.data() + n + m);
  double mean = 0;
  for (double g : fit.log_gain) mean += g / std::max(1, n);
  for (double& g : fit.log_gain) g -= mean;
  return fit;
}

// The samples' mean log colour in every channel (the exposure's share of them).
std::vector<RadiometrySample> Grey(const std::vector<RadiometrySample>& samples) {
  std::vector<RadiometrySample> grey = samples;
  for (auto& s : grey) {
    s.log_a = cv::Vec3f::all((s.log_a[0] + s.log_a[1] + s.log_a[2]) / 3);
    s.log_b = cv::Vec3f::all((s.log_b[0] + s.log_b[1] + s.log_b[2]) / 3);
  }
  return grey;
}

// Evenly thinned to at most `most`.
std::vector<RadiometrySample> Thinned(const std::vector<RadiometrySample>& samples, size_t most) {
  if (samples.size() <= most) return samples;
  std::vector<RadiometrySample> out;
  out.reserve(most);
  for (size_t k = 0; k < most; ++k) out.push_back(samples[k * samples.size() / most]);
  return out;
}

// The antisolar point that best explains the grey samples with the frames' gains held at `gains`' (and their robust
// weights): for each point of a grid (`step` apart within `radius` of `around`), the shared terms alone by dense least
// squares; the lowest weighted cost wins. Cheap enough for a few hundred points: the gains' sparse system is not
// solved again.
cv::Point2d SearchAntisolar(const std::vector<RadiometrySample>& grey, const std::unordered_map<int, int>& index,
                            const Terms& terms, const Fit& gains, cv::Point2d around, double radius, double step) {
  const int m = terms.Count();
  std::vector<double> rest(grey.size());
  for (size_t k = 0; k < grey.size(); ++k)
    rest[k] = PairDifference(grey[k], 0) - (gains.log_gain[static_cast<size_t>(index.at(grey[k].a))] -
                                            gains.log_gain[static_cast<size_t>(index.at(grey[k].b))]);
  const int steps = static_cast<int>(std::floor(radius / step));
  std::vector<cv::Point2d> grid;  // in scan order: the first of equal costs wins, whatever the threads
  for (int i = -steps; i <= steps; ++i)
    for (int j = -steps; j <= steps; ++j)
      if (i * i + j * j <= steps * steps) grid.emplace_back(around.x + j * step, around.y + i * step);
  // Each point's least squares alone (~450 on the coarse grid), on OpenCV's threads.
  std::vector<double> costs(grid.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(grid.size())), [&](const cv::Range& range) {
    Terms trial = terms;
    Row row{};
    for (int g = range.start; g < range.end; ++g) {
      trial.at.antisolar_u = grid[static_cast<size_t>(g)].x;
      trial.at.antisolar_v = grid[static_cast<size_t>(g)].y;
      Eigen::MatrixXd normal = Eigen::MatrixXd::Identity(m, m) * 1e-6 * static_cast<double>(grey.size());
      Eigen::VectorXd rhs = Eigen::VectorXd::Zero(m);
      double base = 0;
      for (size_t k = 0; k < grey.size(); ++k) {
        trial.Row(grey[k], row.data());
        const Eigen::Map<const Eigen::VectorXd> r(row.data(), m);
        normal.selfadjointView<Eigen::Lower>().rankUpdate(r, gains.weight[k]);
        rhs += gains.weight[k] * rest[k] * r;
        base += gains.weight[k] * rest[k] * rest[k];
      }
      normal.triangularView<Eigen::Upper>() = normal.transpose();
      const Eigen::VectorXd x = normal.ldlt().solve(rhs);
      costs[static_cast<size_t>(g)] = base - x.dot(rhs);  // the weighted residual at the least-squares solution
    }
  });
  double best_cost = std::numeric_limits<double>::infinity();
  cv::Point2d best = around;
  for (size_t g = 0; g < grid.size(); ++g)
    if (costs[g] < best_cost) {
      best_cost = costs[g];
      best = grid[g];
    }
  return best;
}

// The hotspot's antisolar point for these samples: a coarse grid over the frame (the antisolar point may be anywhere
// in it, or beyond its border at a lower sun), then a fine one around the best, each with the gains of a fit with the
// hotspot at the point found so far.
Fit FitHotspot(const std::vector<RadiometrySample>& grey, const std::unordered_map<int, int>& index, Terms* terms,
               const Fit& without, const RadiometryOptions& o) {
  constexpr size_t kSearchSamples = 6000;
  const std::vector<RadiometrySample> few = Thinned(grey, kSearchSamples);
  const cv::Point2d coarse = SearchAntisolar(few, index, *terms, without, {0, 0}, 0.96, 0.08);
  terms->at.antisolar_u = coarse.x;
  terms->at.antisolar_v = coarse.y;
  const Fit first = SolveRobust(grey, index, 0, *terms, o.gain_prior_weight, o);
  const cv::Point2d fine = SearchAntisolar(few, index, *terms, first, coarse, 0.08, 0.02);
  terms->at.antisolar_u = fine.x;
  terms->at.antisolar_v = fine.y;
  return SolveRobust(grey, index, 0, *terms, o.gain_prior_weight, o);
}

double HeldOutCost(const std::vector<RadiometrySample>& held, const std::unordered_map<int, int>& index,
                   const Terms& terms, const Fit& fit, double huber) {
  double cost = 0;
  for (const auto& s : held) cost += Huber(PairDifference(s, 0) - Predicted(fit, terms, index, s), huber);
  return cost / static_cast<double>(std::max<size_t>(1, held.size()));
}

Hotspot HotspotOf(const Terms& terms, const Fit& fit) {
  Hotspot h = terms.at;
  h.found = true;
  const size_t first = static_cast<size_t>(terms.Count()) - Hotspot::kSigma.size();
  for (size_t k = 0; k < Hotspot::kSigma.size(); ++k) h.weights[k] = fit.shared[first + k];
  return h;
}

// A hotspot brightens the ground around the antisolar point, by less than a factor of 3.
bool PlausibleHotspot(const Hotspot& h) {
  const double peak = h.LogBoost(0.0);
  return peak > 0.01 && peak < std::log(3.0);
}

// Which shared terms the grey samples support: the radial model (as `base` says), then the flat field, then the
// hotspot, each kept when the held-out fifth of the edges' samples costs `min_holdout_gain` less with it. Held-out
// costs into `cost` (0 where not tried).
Terms ChooseTerms(const std::vector<RadiometrySample>& grey, const std::unordered_map<int, int>& index, Terms base,
                  const RadiometryOptions& o, std::array<double, 3>* cost, std::string* note) {
  std::vector<RadiometrySample> train;
  std::vector<RadiometrySample> held;
  for (const auto& s : grey) {
    const auto lo = static_cast<uint64_t>(std::min(s.a, s.b));
    const auto hi = static_cast<uint64_t>(std::max(s.a, s.b));
    ((lo * 2654435761u + hi * 40503u) % 5 == 0 ? held : train).push_back(s);
  }
  constexpr size_t kMinHeld = 300;
  if (held.size() < kMinHeld || train.size() < 4 * kMinHeld || index.size() < 6) {
    *note = "too few samples to test a flat field or a hotspot";
    return base;
  }
  Terms chosen = base;
  Fit fit = SolveRobust(train, index, 0, base, o.gain_prior_weight, o);
  (*cost)[0] = HeldOutCost(held, index, base, fit, o.huber_log);
  double best = (*cost)[0];
  if (o.flat_field) {
    Terms flat = base;
    flat.flat = true;
    const Fit with = SolveRobust(train, index, 0, flat, o.gain_prior_weight, o);
    (*cost)[1] = HeldOutCost(held, index, flat, with, o.huber_log);
    if (with.solved && (*cost)[1] < best * (1 - o.min_holdout_gain)) {
      chosen = flat;
      best = (*cost)[1];
      fit = with;
    }
  }
  if (o.hotspot) {
    Terms hot = chosen;
    hot.hotspot = true;
    const Fit with = FitHotspot(train, index, &hot, fit, o);
    (*cost)[2] = HeldOutCost(held, index, hot, with, o.huber_log);
    if (with.solved && (*cost)[2] < best * (1 - o.min_holdout_gain) && PlausibleHotspot(HotspotOf(hot, with)))
      chosen = hot;
  }
  return chosen;
}

// The whole model for the chosen terms: the exposure (grey) with them and the gain prior, then each channel's
// deviation from it (white balance, a tint of the radial falloff) with the stronger colour prior. A colour cast
// drifting along a flight is more visible than a brightness drift, and real white balance moves less than exposure.
struct ColourSolve {
  std::array<std::vector<double>, 3> log_gain;
  std::array<std::array<double, 2>, 3> radial{};
  std::array<double, RadiometryModel::kFlatTerms> flat{};
  Hotspot hotspot;
  double rms_before = 0, rms_after = 0;
  // Over the exposure's and the channels' fits.
  bool solved = true;
  bool iterative = false;
  int most_steps = 0;
  int failed_solves = 0;

  void Tally(const Fit& fit) {
    solved = solved && fit.solved;
    iterative = iterative || fit.iterative;
    most_steps = std::max(most_steps, fit.most_steps);
    failed_solves += fit.failed_solves;
  }
};

ColourSolve SolveColour(const std::vector<RadiometrySample>& samples, const std::unordered_map<int, int>& index,
                        Terms terms, const RadiometryOptions& o) {
  const std::vector<RadiometrySample> grey = Grey(samples);
  Fit exposure = SolveRobust(grey, index, 0, terms, o.gain_prior_weight, o);
  if (terms.hotspot) {  // the point found on the training samples, refined on all of them
    const cv::Point2d fine = SearchAntisolar(Thinned(grey, 6000), index, terms, exposure,
                                             {terms.at.antisolar_u, terms.at.antisolar_v}, 0.04, 0.02);
    terms.at.antisolar_u = fine.x;
    terms.at.antisolar_v = fine.y;
    exposure = SolveRobust(grey, index, 0, terms, o.gain_prior_weight, o);
  }
  ColourSolve out;
  out.Tally(exposure);
  size_t j = 0;
  std::array<double, 2> grey_radial{};
  if (terms.radial) grey_radial = {exposure.shared[j], exposure.shared[j + 1]}, j += 2;
  if (terms.flat)
    for (double& f : out.flat) f = exposure.shared[j++];
  if (terms.hotspot) out.hotspot = HotspotOf(terms, exposure);
  Row row{};
  auto explained = [&](int id, const ImagePoint& p) {
    terms.Eval(p, row.data());
    double e = exposure.log_gain[static_cast<size_t>(index.at(id))];
    for (int k = 0; k < terms.Count(); ++k) e += exposure.shared[static_cast<size_t>(k)] * row[static_cast<size_t>(k)];
    return static_cast<float>(e);
  };
  std::vector<RadiometrySample> colour = samples;
  for (auto& s : colour) {
    s.log_a -= cv::Vec3f::all(explained(s.a, s.in_a));
    s.log_b -= cv::Vec3f::all(explained(s.b, s.in_b));
  }
  Terms tint;
  tint.radial = terms.radial;
  std::array<Fit, 3> channel;
  for (int c = 0; c < 3; ++c) {
    const auto cu = static_cast<size_t>(c);
    channel[cu] = SolveRobust(colour, index, c, tint, o.colour_prior_weight, o);
    out.Tally(channel[cu]);
    out.log_gain[cu] = channel[cu].log_gain;
    for (size_t i = 0; i < out.log_gain[cu].size(); ++i) out.log_gain[cu][i] += exposure.log_gain[i];
    if (terms.radial) out.radial[cu] = {grey_radial[0] + channel[cu].shared[0], grey_radial[1] + channel[cu].shared[1]};
  }
  // Both figures against the pairs' own differences, over the samples the model explains (within 3 loss widths).
  double before = 0, after = 0, count = 0;
  for (size_t k = 0; k < samples.size(); ++k)
    for (int c = 0; c < 3; ++c) {
      const double d = PairDifference(samples[k], c);
      const double r =
          PairDifference(colour[k], c) - Predicted(channel[static_cast<size_t>(c)], tint, index, colour[k]);
      if (std::abs(r) > 3 * o.huber_log) continue;
      before += d * d;
      after += r * r;
      ++count;
    }
  out.rms_before = std::sqrt(before / std::max(1.0, count));
  out.rms_after = std::sqrt(after / std::max(1.0, count));
  return out;
}

// A lens darkens its corners; it does not brighten them (what looks like it is the ground's reflectance changing
// with the view direction, which a radial model must not absorb).
bool PlausibleFalloff(const ColourSolve& solved, const RadiometryOptions& options) {
  for (const auto& c : solved.radial) {
    const double corner = std::exp(c[0] + c[1]);
    if (corner < 1.0 - options.max_corner_falloff || corner > 1.05) return false;
  }
  return true;
}

}  // namespace

bool RadiometryOptions::Check(std::string* why) const {
  auto fail = [why](const char* m) {
    *why = m;
    return false;
  };
  if (thumb_long_side < 16 || thumb_long_side > 1024) return fail("radiometry.thumb_long_side must be in [16, 1024]");
  if (samples_per_edge < 4 || samples_per_edge > 4096) return fail("radiometry.samples_per_edge must be in [4, 4096]");
  if (max_samples < 1000) return fail("radiometry.max_samples must be >= 1000");
  if (!(gain_prior_weight > 0)) return fail("radiometry.gain_prior_weight must be > 0");
  if (!(colour_prior_weight > 0)) return fail("radiometry.colour_prior_weight must be > 0");
  if (!(huber_log > 0)) return fail("radiometry.huber_log must be > 0");
  if (min_vignetting_samples < 0) return fail("radiometry.min_vignetting_samples must be >= 0");
  if (!(max_corner_falloff > 0 && max_corner_falloff < 1))
    return fail("radiometry.max_corner_falloff must be in (0, 1)");
  if (!(min_holdout_gain >= 0 && min_holdout_gain < 1)) return fail("radiometry.min_holdout_gain must be in [0, 1)");
  if (direct_max_frames < 0) return fail("radiometry.direct_max_frames must be >= 0");
  if (!(iterative_tolerance > 0 && iterative_tolerance < 1))
    return fail("radiometry.iterative_tolerance must be in (0, 1)");
  if (max_iterative_steps < 1) return fail("radiometry.max_iterative_steps must be >= 1");
  return true;
}

double RadiometryModel::Falloff(int channel, double r2) const {
  if (!vignetting) return 1.0;
  const auto& c = log_falloff[static_cast<size_t>(channel)];
  return std::exp(c[0] * r2 + c[1] * r2 * r2);
}

cv::Vec3d RadiometryModel::Gain(int id) const {
  auto it = log_gain.find(id);
  if (it == log_gain.end()) return {1, 1, 1};
  return {std::exp(it->second[0]), std::exp(it->second[1]), std::exp(it->second[2])};
}

double RadiometryModel::LogShading(int channel, const ImagePoint& p) const {
  double s = 0;
  if (vignetting) {
    const auto& c = log_falloff[static_cast<size_t>(channel)];
    const double r2 = p.R2();
    s += c[0] * r2 + c[1] * r2 * r2;
  }
  if (flat_field) {
    std::array<double, kFlatTerms> basis{};
    FlatBasis(p.u, p.v, basis.data());
    for (size_t k = 0; k < basis.size(); ++k) s += log_flat[k] * basis[k];
  }
  if (hotspot.found) {
    const cv::Point2d c = hotspot.Centre(p.heading);
    s += hotspot.LogBoost((p.u - c.x) * (p.u - c.x) + (p.v - c.y) * (p.v - c.y));
  }
  return s;
}

cv::Point2d Hotspot::Centre(double heading) const {
  // The antisolar direction is fixed on the ground; a frame turned by `heading` into the mosaic sees it turned back.
  const double c = std::cos(heading);
  const double s = std::sin(heading);
  return {c * antisolar_u + s * antisolar_v, -s * antisolar_u + c * antisolar_v};
}

double Hotspot::LogBoost(double d2) const {
  double b = 0;
  for (size_t k = 0; k < kSigma.size(); ++k) b += weights[k] * std::exp(-d2 / (2 * kSigma[k] * kSigma[k]));
  return b;
}

double Hotspot::CoreRadius() const {
  const double half = 0.5 * LogBoost(0.0);
  double d = 0;
  while (d < 1.5 && LogBoost(d * d) > half) d += 0.005;
  return d;
}

double HeadingOf(const Mat3& mosaic_from_work, cv::Size work_size) {
  const Vec2 centre(0.5 * (work_size.width - 1), 0.5 * (work_size.height - 1));
  const Vec2 c0 = Apply(mosaic_from_work, centre);
  Mat3 local = Mat3::Identity();  // the map's linear part at the centre (exact for affine maps)
  local.block<2, 1>(0, 0) = Apply(mosaic_from_work, centre + Vec2(1, 0)) - c0;
  local.block<2, 1>(0, 1) = Apply(mosaic_from_work, centre + Vec2(0, 1)) - c0;
  return Decompose(local).rotation;
}

cv::Mat MakeThumbnail(const cv::Mat& bgr, int long_side) {
  const double s = std::min(1.0, long_side / static_cast<double>(std::max(bgr.cols, bgr.rows)));
  cv::Mat thumb;
  cv::resize(bgr, thumb,
             cv::Size(std::max(2, static_cast<int>(std::lround(bgr.cols * s))),
                      std::max(2, static_cast<int>(std::lround(bgr.rows * s)))),
             0, 0, cv::INTER_AREA);
  return thumb;
}

void SampleOverlap(const OverlapView& a, const OverlapView& b, const Mat3& b_from_a, int max_samples,
                   std::vector<RadiometrySample>* out) {
  const cv::Mat& thumb_a = *a.thumb;
  const cv::Mat& thumb_b = *b.thumb;
  const Mat3 work_from_thumb_a =
      ResizeMap(double(thumb_a.cols) / a.work_size.width, double(thumb_a.rows) / a.work_size.height).inverse();
  const Mat3 thumb_from_work_b =
      ResizeMap(double(thumb_b.cols) / b.work_size.width, double(thumb_b.rows) / b.work_size.height);
  const PlaceOf place_a(a.work_size), place_b(b.work_size);
  // A denser grid than max_samples: only the overlap's share of it lands in b.
  const int side = std::max(4, static_cast<int>(std::ceil(std::sqrt(4.0 * max_samples))));
  std::vector<RadiometrySample> found;
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j) {
      const Vec2 ta(1 + (j + 0.5) * (thumb_a.cols - 3) / side, 1 + (i + 0.5) * (thumb_a.rows - 3) / side);
      const Vec2 wa = Apply(work_from_thumb_a, ta);
      const Vec2 wb = Apply(b_from_a, wa);
      const Vec2 tb = Apply(thumb_from_work_b, wb);
      RadiometrySample s;
      cv::Vec3f va, vb;
      // One thumbnail pixel inside b's border: the area average there mixes no outside.
      if (tb.x() < 1 || tb.y() < 1 || tb.x() > thumb_b.cols - 2 || tb.y() > thumb_b.rows - 2) continue;
      if (!SampleBgr(thumb_a, ta.x(), ta.y(), &va) || !SampleBgr(thumb_b, tb.x(), tb.y(), &vb)) continue;
      if (!Usable(va) || !Usable(vb)) continue;
      s.a = a.id;
      s.b = b.id;
      s.in_a = place_a.At(wa.x(), wa.y(), a.heading);
      s.in_b = place_b.At(wb.x(), wb.y(), b.heading);
      s.log_a = Log(va);
      s.log_b = Log(vb);
      found.push_back(s);
    }
  // Evenly thinned to the bound, each kept sample in the middle of its share of the grid's scan order (one sample: the
  // middle one found).
  const size_t keep = std::min(found.size(), static_cast<size_t>(max_samples));
  for (size_t k = 0; k < keep; ++k) out->push_back(found[(2 * k + 1) * found.size() / (2 * keep)]);
}

RadiometryModel SolveRadiometry(std::vector<RadiometrySample> samples, const std::vector<int>& frames,
                                const RadiometryOptions& options, const std::function<void()>& terms_chosen) {
  RadiometryModel m;
  std::unordered_map<int, int> index;
  for (int id : frames) index.emplace(id, static_cast<int>(index.size()));
  // Filtered in place: the samples are the solve's largest input, held once.
  std::vector<RadiometrySample>& used = samples;
  used.erase(std::remove_if(used.begin(), used.end(),
                            [&](const RadiometrySample& s) { return index.count(s.a) == 0 || index.count(s.b) == 0; }),
             used.end());
  std::vector<std::pair<int, int>> pairs;  // an edge's samples are consecutive: one entry per run
  for (const auto& s : used) {
    const std::pair<int, int> pair(std::min(s.a, s.b), std::max(s.a, s.b));
    if (pairs.empty() || pairs.back() != pair) pairs.push_back(pair);
  }
  std::sort(pairs.begin(), pairs.end());
  m.edges = static_cast<int>(std::unique(pairs.begin(), pairs.end()) - pairs.begin());
  m.samples = static_cast<int>(used.size());
  if (used.empty() || frames.size() < 2) {
    m.note = "no overlap samples";
    return m;
  }
  Terms terms;
  terms.radial = options.vignetting && m.samples >= options.min_vignetting_samples;
  if (options.vignetting && !terms.radial) m.note = "too few samples to determine the vignetting";
  if (options.flat_field || options.hotspot) {
    std::string why;
    terms = ChooseTerms(Grey(used), index, terms, options, &m.holdout_cost, &why);
    if (terms_chosen) terms_chosen();
    if (!why.empty()) m.note += (m.note.empty() ? "" : "; ") + why;
  }
  ColourSolve solved = SolveColour(used, index, terms, options);
  if (terms.radial && !PlausibleFalloff(solved, options)) {
    terms.radial = false;
    m.note = "fitted vignetting implausible (a corner outside [1 - max_corner_falloff, 1.05]); no radial falloff";
    solved = SolveColour(used, index, terms, options);
  }
  if (terms.hotspot && !PlausibleHotspot(solved.hotspot)) {
    terms.hotspot = false;
    solved = SolveColour(used, index, terms, options);
  }
  m.iterative = solved.iterative;
  m.most_iterative_steps = solved.most_steps;
  m.failed_solves = solved.failed_solves;
  if (!solved.solved) {
    // A breakdown (no positive curvature left) stops the gradients before their step cap, so both are said.
    m.note = solved.iterative ? "the gains' conjugate gradients did not reach their tolerance (stopped after " +
                                    std::to_string(solved.most_steps) + " of at most " +
                                    std::to_string(options.max_iterative_steps) + " steps)"
                              : "the gains' factorisation failed";
    return m;
  }
  m.vignetting = terms.radial;
  m.flat_field = terms.flat;
  m.log_flat = solved.flat;
  m.hotspot = solved.hotspot;
  m.log_falloff = solved.radial;
  m.rms_log_before = solved.rms_before;
  m.rms_log_after = solved.rms_after;
  for (int c = 0; c < 3; ++c)
    for (const auto& [id, i] : index)
      m.log_gain[id][c] = solved.log_gain[static_cast<size_t>(c)][static_cast<size_t>(i)];
  m.ok = true;
  return m;
}

LiveRadiometry::LiveRadiometry(const RadiometryOptions& options, int window, int solve_every)
    : options_(options), window_(static_cast<size_t>(std::max(2, window))), solve_every_(std::max(1, solve_every)) {}

void LiveRadiometry::AddFrame(int id, const cv::Mat& thumb, cv::Size work_size, double heading) {
  if (thumbs_.size() == window_) {
    const int oldest = thumbs_.front().id;
    thumbs_.erase(thumbs_.begin());
    samples_.erase(std::remove_if(samples_.begin(), samples_.end(),
                                  [oldest](const RadiometrySample& s) { return s.a == oldest || s.b == oldest; }),
                   samples_.end());
  }
  thumbs_.push_back({id, thumb, work_size, heading});
  ++frames_since_solve_;
}

const LiveRadiometry::Thumb* LiveRadiometry::Find(int id) const {
  for (const Thumb& t : thumbs_)
    if (t.id == id) return &t;
  return nullptr;
}

void LiveRadiometry::AddEdge(int a, int b, const Mat3& b_from_a) {
  const Thumb* ta = Find(a);
  const Thumb* tb = Find(b);
  if (ta == nullptr || tb == nullptr) return;
  SampleOverlap({a, &ta->image, ta->work_size, ta->heading}, {b, &tb->image, tb->work_size, tb->heading}, b_from_a,
                options_.samples_per_edge, &samples_);
}

bool LiveRadiometry::MaybeSolve() {
  if (frames_since_solve_ < solve_every_) return false;
  frames_since_solve_ = 0;
  std::vector<int> frames;
  for (const Thumb& t : thumbs_) frames.push_back(t.id);
  RadiometryModel m = SolveRadiometry(samples_, frames, options_);
  if (!m.ok || (!m.vignetting && !m.BeyondRadial())) return false;
  m.log_gain.clear();  // no gains (see the class comment)
  model_ = std::move(m);
  return true;
}

namespace {

// Gain and radial falloff only: a table over r^2.
void CorrectRadial(const RadiometryModel& model, int id, cv::Size full_size, cv::Point2d origin, cv::Mat* bgr) {
  const cv::Vec3d gain = model.Gain(id);
  std::array<std::array<float, kLutSize + 1>, 3> lut{};
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k <= kLutSize; ++k)
      lut[static_cast<size_t>(c)][static_cast<size_t>(k)] =
          static_cast<float>(1.0 / (gain[c] * model.Falloff(c, static_cast<double>(k) / kLutSize)));
  // R2 = u u + v v in floats as ImagePoint computes it: u u per column once, v v per row.
  const PlaceOf place(full_size);
  const auto cols = static_cast<size_t>(bgr->cols);
  std::vector<float> uu(cols);
  for (size_t col = 0; col < cols; ++col) {
    const float u = place.At(origin.x + static_cast<double>(col), 0, 0).u;
    uu[col] = u * u;
  }
  std::vector<uint16_t> index(cols);
  for (int r = 0; r < bgr->rows; ++r) {
    const float v = place.At(0, origin.y + r, 0).v;
    const float vv = v * v;
    for (size_t col = 0; col < cols; ++col)
      index[col] = static_cast<uint16_t>(std::min(1.0, double(uu[col] + vv)) * kLutSize + 0.5);
    auto* p = bgr->ptr<cv::Vec3b>(r);
    for (size_t col = 0; col < cols; ++col)
      for (int c = 0; c < 3; ++c)
        p[col][c] = cv::saturate_cast<uchar>(p[col][c] * lut[static_cast<size_t>(c)][index[col]]);
  }
}

// Any shading: the factor evaluated on a grid of nodes kNodeStep px apart over the part and interpolated bilinearly
// between them (the shading is smooth: its narrowest term is a Gaussian of 0.07 half-diagonals).
void CorrectShading(const RadiometryModel& model, int id, double heading, cv::Size full_size, cv::Point2d origin,
                    cv::Mat* bgr) {
  constexpr int kNodeStep = 8;
  const cv::Vec3d gain = model.Gain(id);
  const PlaceOf place(full_size);
  const int nodes_x = (bgr->cols - 1) / kNodeStep + 2;
  const int nodes_y = (bgr->rows - 1) / kNodeStep + 2;
  cv::Mat factor(nodes_y, nodes_x, CV_32FC3);
  for (int i = 0; i < nodes_y; ++i)
    for (int j = 0; j < nodes_x; ++j) {
      const ImagePoint p = place.At(origin.x + j * kNodeStep, origin.y + i * kNodeStep, heading);
      for (int c = 0; c < 3; ++c)
        factor.at<cv::Vec3f>(i, j)[c] = static_cast<float>(1.0 / (gain[c] * std::exp(model.LogShading(c, p))));
    }
  std::vector<cv::Vec3f> row_nodes(static_cast<size_t>(nodes_x));
  for (int r = 0; r < bgr->rows; ++r) {
    const int i = r / kNodeStep;
    const float ty = static_cast<float>(r - i * kNodeStep) / kNodeStep;
    const auto* f0 = factor.ptr<cv::Vec3f>(i);
    const auto* f1 = factor.ptr<cv::Vec3f>(i + 1);
    for (int j = 0; j < nodes_x; ++j) row_nodes[static_cast<size_t>(j)] = f0[j] * (1 - ty) + f1[j] * ty;
    auto* p = bgr->ptr<cv::Vec3b>(r);
    for (int col = 0; col < bgr->cols; ++col) {
      const int j = col / kNodeStep;
      const float tx = static_cast<float>(col - j * kNodeStep) / kNodeStep;
      const cv::Vec3f f = row_nodes[static_cast<size_t>(j)] * (1 - tx) + row_nodes[static_cast<size_t>(j) + 1] * tx;
      for (int c = 0; c < 3; ++c) p[col][c] = cv::saturate_cast<uchar>(p[col][c] * f[c]);
    }
  }
}

}  // namespace

void CorrectRadiometry(const RadiometryModel& model, int id, double heading, cv::Size full_size, cv::Point2d origin,
                       cv::Mat* bgr) {
  if (!model.ok || bgr->empty()) return;
  if (model.BeyondRadial())
    CorrectShading(model, id, heading, full_size, origin, bgr);
  else
    CorrectRadial(model, id, full_size, origin, bgr);
}

AvoidDisc HotspotDisc(const RadiometryModel& model, double heading, cv::Size size) {
  if (!model.ok || !model.hotspot.found) return {};
  const PlaceOf place(size);
  const cv::Point2d c = model.hotspot.Centre(heading);
  // The drone's shadow sits at the centre whatever the bump's width: never less than 0.06 half-diagonals.
  const double radius = std::clamp(model.hotspot.CoreRadius(), 0.06, 0.3);
  return {cv::Point2d(place.cx + c.x / place.inv_hd, place.cy + c.y / place.inv_hd), radius / place.inv_hd};
}

}  // namespace uavm
