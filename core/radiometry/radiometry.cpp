#include "core/radiometry/radiometry.h"

#include <Eigen/Sparse>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <unordered_map>

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

// r^2 of a pixel, r = distance from the image centre / half-diagonal.
struct RadiusOf {
  explicit RadiusOf(cv::Size s)
      : cx(0.5 * (s.width - 1)),
        cy(0.5 * (s.height - 1)),
        inv_hd2(4.0 / (double(s.width) * s.width + double(s.height) * s.height)) {}
  [[nodiscard]] double R2(double x, double y) const { return ((x - cx) * (x - cx) + (y - cy) * (y - cy)) * inv_hd2; }
  double cx, cy, inv_hd2;
};

bool Usable(const cv::Vec3f& v) {
  for (int c = 0; c < 3; ++c)
    if (v[c] < 8.0f || v[c] > 247.0f) return false;
  return true;
}

cv::Vec3f Log(const cv::Vec3f& v) {
  return {std::log(v[0]), std::log(v[1]), std::log(v[2])};
}

// One channel's weighted least squares: x = [log gains of `frames`..., c1, c2]; `fit_falloff` false leaves c1 = c2 = 0.
struct ChannelSolve {
  std::vector<double> log_gain;
  double c1 = 0, c2 = 0;
  double rms_before = 0, rms_after = 0;
};

// The unknowns a sample touches with their coefficients: +1 at a's gain, -1 at b's, and the radii terms of the falloff
// (index -1 = unused).
using SampleRow = std::array<std::pair<int, double>, 4>;

SampleRow RowOf(const RadiometrySample& s, const std::unordered_map<int, int>& index, bool fit_falloff, int n) {
  SampleRow row{{{index.at(s.a), 1.0}, {index.at(s.b), -1.0}, {-1, 0.0}, {-1, 0.0}}};
  if (fit_falloff) {
    row[2] = {n, double(s.r2_a) - s.r2_b};
    row[3] = {n + 1, double(s.r2_a) * s.r2_a - double(s.r2_b) * s.r2_b};
  }
  return row;
}

// The summed normal equations as triplets (both halves of the symmetric matrix); `pair_sum` is freed.
std::vector<Eigen::Triplet<double>> NormalTriplets(const Eigen::VectorXd& diagonal, const Eigen::MatrixXd& falloff_rows,
                                                   std::unordered_map<uint64_t, double>* pair_sum_in) {
  auto& pair_sum = *pair_sum_in;
  const auto unknowns = static_cast<int>(diagonal.size());
  const int n = unknowns - static_cast<int>(falloff_rows.rows());
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(static_cast<size_t>(unknowns) + 2 * pair_sum.size() + 2 * static_cast<size_t>(falloff_rows.size()));
  for (int i = 0; i < unknowns; ++i) t.emplace_back(i, i, diagonal[i]);
  for (const auto& [key, v] : pair_sum) {
    const auto i = static_cast<int>(key >> 32);
    const auto j = static_cast<int>(key & 0xffffffffu);
    t.emplace_back(i, j, v);
    t.emplace_back(j, i, v);
  }
  for (int r = 0; r < unknowns - n; ++r)
    for (int j = 0; j < unknowns; ++j) {
      if (j == n + r || falloff_rows(r, j) == 0.0) continue;
      t.emplace_back(n + r, j, falloff_rows(r, j));
      if (j < n) t.emplace_back(j, n + r, falloff_rows(r, j));  // the gain rows' falloff columns
    }
  pair_sum = {};
  return t;
}

// One weighted least-squares step: the normal equations with the gain prior (and a whisper of ridge on the falloff,
// which keeps the system definite when radii barely differ). False when the factorisation fails.
bool SolveWeighted(const std::vector<RadiometrySample>& samples, const std::unordered_map<int, int>& index, int channel,
                   bool fit_falloff, double prior, const std::vector<double>& weight, Eigen::VectorXd* x) {
  const int n = static_cast<int>(index.size());
  const auto unknowns = static_cast<int>(x->size());
  // The normal equations summed as they are made: a diagonal, one entry per pair of frames, and the falloff's rows
  // (dense). Their memory grows with the frames and pairs, not with the samples (a triplet per term would take
  // ~250 bytes per sample).
  Eigen::VectorXd diagonal = Eigen::VectorXd::Zero(unknowns);
  Eigen::MatrixXd falloff_rows = Eigen::MatrixXd::Zero(unknowns - n, unknowns);  // rows n.. (0 or 2 of them)
  std::unordered_map<uint64_t, double> pair_sum;  // key: lower index << 32 | higher index
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(unknowns);
  for (int i = 0; i < n; ++i) diagonal[i] = prior;
  for (int i = n; i < unknowns; ++i) diagonal[i] = 1e-6 * static_cast<double>(samples.size());
  for (size_t k = 0; k < samples.size(); ++k) {
    const SampleRow row = RowOf(samples[k], index, fit_falloff, n);
    const double d = double(samples[k].log_a[channel] - samples[k].log_b[channel]);
    for (const auto& [i, vi] : row) {
      if (i < 0) continue;
      rhs[i] += weight[k] * vi * d;
      for (const auto& [j, vj] : row) {
        if (j < 0) continue;
        const double v = weight[k] * vi * vj;
        if (i == j) {
          diagonal[i] += v;
        } else if (i >= n) {
          falloff_rows(i - n, j) += v;
        } else if (j < n && i < j) {
          pair_sum[(static_cast<uint64_t>(i) << 32) | static_cast<uint32_t>(j)] += v;
        }
      }
    }
  }
  const std::vector<Eigen::Triplet<double>> t = NormalTriplets(diagonal, falloff_rows, &pair_sum);
  Eigen::SparseMatrix<double> normal(unknowns, unknowns);
  normal.setFromTriplets(t.begin(), t.end());
  const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(normal);
  if (solver.info() != Eigen::Success) return false;
  *x = solver.solve(rhs);
  return true;
}

// One channel's robust fit (Huber, iteratively reweighted): x = [log gains of the frames in `index`..., c1, c2];
// `fit_falloff` false leaves c1 = c2 = 0. The log gains come back centred (the mean frame keeps its brightness).
ChannelSolve SolveChannel(const std::vector<RadiometrySample>& samples, const std::unordered_map<int, int>& index,
                          int channel, bool fit_falloff, const RadiometryOptions& o) {
  const int n = static_cast<int>(index.size());
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n + (fit_falloff ? 2 : 0));
  std::vector<double> weight(samples.size(), 1.0);
  // Relative to an average frame's share of the data, so that it means the same on any flight.
  const double prior = o.gain_prior_weight * static_cast<double>(samples.size()) / std::max(1, n);
  for (int iteration = 0; iteration < 5; ++iteration) {
    if (!SolveWeighted(samples, index, channel, fit_falloff, prior, weight, &x)) break;
    for (size_t k = 0; k < samples.size(); ++k) {
      double model = 0;
      for (const auto& [i, v] : RowOf(samples[k], index, fit_falloff, n))
        if (i >= 0) model += v * x[i];
      const double r = std::abs(double(samples[k].log_a[channel] - samples[k].log_b[channel]) - model);
      weight[k] = r <= o.huber_log ? 1.0 : o.huber_log / r;
    }
  }
  ChannelSolve out;
  out.log_gain.assign(x.data(), x.data() + n);
  double mean = 0;
  for (double g : out.log_gain) mean += g / std::max(1, n);
  for (double& g : out.log_gain) g -= mean;
  if (fit_falloff) {
    out.c1 = x[n];
    out.c2 = x[n + 1];
  }
  return out;
}

// Brightness first, colour second: the exposure (mean of the log channels) is solved with the gain prior, then each
// channel's deviation from it (white balance, a colour tint of the falloff) with the stronger colour prior. A colour
// cast drifting along a flight is more visible than a brightness drift, and real white balance moves less than
// exposure.
std::array<ChannelSolve, 3> SolveColour(const std::vector<RadiometrySample>& samples,
                                        const std::unordered_map<int, int>& index, bool fit_falloff,
                                        const RadiometryOptions& options) {
  std::vector<RadiometrySample> grey = samples;
  for (auto& s : grey) {
    s.log_a = cv::Vec3f::all((s.log_a[0] + s.log_a[1] + s.log_a[2]) / 3);
    s.log_b = cv::Vec3f::all((s.log_b[0] + s.log_b[1] + s.log_b[2]) / 3);
  }
  const ChannelSolve exposure = SolveChannel(grey, index, 0, fit_falloff, options);
  auto explained = [&](int id, float r2) {
    const double g = exposure.log_gain[static_cast<size_t>(index.at(id))];
    return static_cast<float>(g + exposure.c1 * r2 + exposure.c2 * double(r2) * r2);
  };
  std::vector<RadiometrySample> colour = samples;
  for (auto& s : colour) {
    s.log_a -= cv::Vec3f::all(explained(s.a, s.r2_a));
    s.log_b -= cv::Vec3f::all(explained(s.b, s.r2_b));
  }
  RadiometryOptions colour_options = options;
  colour_options.gain_prior_weight = options.colour_prior_weight;
  std::array<ChannelSolve, 3> out;
  for (int c = 0; c < 3; ++c) {
    ChannelSolve& cs = out[static_cast<size_t>(c)];
    cs = SolveChannel(colour, index, c, fit_falloff, colour_options);
    for (size_t i = 0; i < cs.log_gain.size(); ++i) cs.log_gain[i] += exposure.log_gain[i];
    cs.c1 += exposure.c1;
    cs.c2 += exposure.c2;
  }
  // Both figures against the pairs' own differences, over the samples the model explains (within 3 loss widths).
  double before = 0, after = 0, count = 0;
  for (const auto& s : samples)
    for (int c = 0; c < 3; ++c) {
      const ChannelSolve& cs = out[static_cast<size_t>(c)];
      const auto model = [&](int id, double r2) {
        return cs.log_gain[static_cast<size_t>(index.at(id))] + cs.c1 * r2 + cs.c2 * r2 * r2;
      };
      const double d = double(s.log_a[c]) - s.log_b[c];
      const double r = d - (model(s.a, s.r2_a) - model(s.b, s.r2_b));
      if (std::abs(r) > 3 * options.huber_log) continue;
      before += d * d;
      after += r * r;
      ++count;
    }
  for (ChannelSolve& cs : out) {
    cs.rms_before = std::sqrt(before / std::max(1.0, count));
    cs.rms_after = std::sqrt(after / std::max(1.0, count));
  }
  return out;
}

// A lens darkens its corners; it does not brighten them (what looks like it is the ground's reflectance changing
// with the view direction, which a radial model must not absorb).
bool PlausibleFalloff(const std::array<ChannelSolve, 3>& solved, const RadiometryOptions& options) {
  for (const ChannelSolve& cs : solved) {
    const double corner = std::exp(cs.c1 + cs.c2);
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

cv::Mat MakeThumbnail(const cv::Mat& bgr, int long_side) {
  const double s = std::min(1.0, long_side / static_cast<double>(std::max(bgr.cols, bgr.rows)));
  cv::Mat thumb;
  cv::resize(bgr, thumb,
             cv::Size(std::max(2, static_cast<int>(std::lround(bgr.cols * s))),
                      std::max(2, static_cast<int>(std::lround(bgr.rows * s)))),
             0, 0, cv::INTER_AREA);
  return thumb;
}

void SampleOverlap(int a, int b, const cv::Mat& thumb_a, const cv::Mat& thumb_b, cv::Size work_a, cv::Size work_b,
                   const Mat3& b_from_a, int max_samples, std::vector<RadiometrySample>* out) {
  const Mat3 work_from_thumb_a =
      ResizeMap(double(thumb_a.cols) / work_a.width, double(thumb_a.rows) / work_a.height).inverse();
  const Mat3 thumb_from_work_b = ResizeMap(double(thumb_b.cols) / work_b.width, double(thumb_b.rows) / work_b.height);
  const RadiusOf radius_a(work_a), radius_b(work_b);
  // A denser grid than max_samples: only the overlap's share of it lands in b.
  const int side = std::max(2, static_cast<int>(std::ceil(std::sqrt(4.0 * max_samples))));
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
      s.a = a;
      s.b = b;
      s.r2_a = static_cast<float>(radius_a.R2(wa.x(), wa.y()));
      s.r2_b = static_cast<float>(radius_b.R2(wb.x(), wb.y()));
      s.log_a = Log(va);
      s.log_b = Log(vb);
      found.push_back(s);
    }
  // Evenly thinned to the bound.
  const size_t keep = std::min(found.size(), static_cast<size_t>(max_samples));
  for (size_t k = 0; k < keep; ++k) out->push_back(found[k * found.size() / keep]);
}

RadiometryModel SolveRadiometry(const std::vector<RadiometrySample>& samples, const std::vector<int>& frames,
                                const RadiometryOptions& options) {
  RadiometryModel m;
  std::unordered_map<int, int> index;
  for (int id : frames) index.emplace(id, static_cast<int>(index.size()));
  std::vector<RadiometrySample> used;
  std::vector<std::pair<int, int>> pairs;
  for (const auto& s : samples)
    if (index.count(s.a) != 0 && index.count(s.b) != 0) {
      used.push_back(s);
      pairs.emplace_back(std::min(s.a, s.b), std::max(s.a, s.b));
    }
  std::sort(pairs.begin(), pairs.end());
  m.edges = static_cast<int>(std::unique(pairs.begin(), pairs.end()) - pairs.begin());
  m.samples = static_cast<int>(used.size());
  if (used.empty() || frames.size() < 2) {
    m.note = "no overlap samples";
    return m;
  }
  m.vignetting = options.vignetting && m.samples >= options.min_vignetting_samples;
  if (options.vignetting && !m.vignetting) m.note = "too few samples to determine the vignetting";
  std::array<ChannelSolve, 3> solved = SolveColour(used, index, m.vignetting, options);
  if (m.vignetting && !PlausibleFalloff(solved, options)) {
    m.vignetting = false;
    m.note = "fitted vignetting implausible (a corner outside [1 - max_corner_falloff, 1.05]); gains only";
    solved = SolveColour(used, index, false, options);
  }
  for (int c = 0; c < 3; ++c) {
    const ChannelSolve& cs = solved[static_cast<size_t>(c)];
    m.log_falloff[static_cast<size_t>(c)] = {cs.c1, cs.c2};
    m.rms_log_before += cs.rms_before / 3;
    m.rms_log_after += cs.rms_after / 3;
    for (const auto& [id, i] : index) m.log_gain[id][c] = cs.log_gain[static_cast<size_t>(i)];
  }
  m.ok = true;
  return m;
}

LiveRadiometry::LiveRadiometry(const RadiometryOptions& options, int window, int solve_every)
    : options_(options), window_(static_cast<size_t>(std::max(2, window))), solve_every_(std::max(1, solve_every)) {}

void LiveRadiometry::AddFrame(int id, const cv::Mat& thumb, cv::Size work_size) {
  if (thumbs_.size() == window_) {
    const int oldest = thumbs_.front().id;
    thumbs_.erase(thumbs_.begin());
    samples_.erase(std::remove_if(samples_.begin(), samples_.end(),
                                  [oldest](const RadiometrySample& s) { return s.a == oldest || s.b == oldest; }),
                   samples_.end());
  }
  thumbs_.push_back({id, thumb, work_size});
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
  SampleOverlap(a, b, ta->image, tb->image, ta->work_size, tb->work_size, b_from_a, options_.samples_per_edge,
                &samples_);
}

bool LiveRadiometry::MaybeSolve() {
  if (frames_since_solve_ < solve_every_) return false;
  frames_since_solve_ = 0;
  std::vector<int> frames;
  for (const Thumb& t : thumbs_) frames.push_back(t.id);
  RadiometryModel m = SolveRadiometry(samples_, frames, options_);
  if (!m.ok || !m.vignetting) return false;
  m.log_gain.clear();  // vignetting only (see the class comment)
  model_ = std::move(m);
  return true;
}

void CorrectRadiometry(const RadiometryModel& model, int id, cv::Size full_size, cv::Point2d origin, cv::Mat* bgr) {
  if (!model.ok || bgr->empty()) return;
  const cv::Vec3d gain = model.Gain(id);
  std::array<std::array<float, kLutSize + 1>, 3> lut{};
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k <= kLutSize; ++k)
      lut[static_cast<size_t>(c)][static_cast<size_t>(k)] =
          static_cast<float>(1.0 / (gain[c] * model.Falloff(c, static_cast<double>(k) / kLutSize)));
  const RadiusOf radius(full_size);
  for (int r = 0; r < bgr->rows; ++r) {
    auto* p = bgr->ptr<cv::Vec3b>(r);
    const double y = origin.y + r;
    for (int col = 0; col < bgr->cols; ++col) {
      const double r2 = std::min(1.0, radius.R2(origin.x + col, y));
      const auto k = static_cast<size_t>(r2 * kLutSize + 0.5);
      for (int c = 0; c < 3; ++c) p[col][c] = cv::saturate_cast<uchar>(p[col][c] * lut[static_cast<size_t>(c)][k]);
    }
  }
}

}  // namespace uavm
