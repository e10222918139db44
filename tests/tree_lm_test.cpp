// SolveTreeLm on small problems whose solution a dense least-squares solve gives independently (Eigen's QR), and the
// tree preconditioner's exactness on a tree. The refinement's own problems are checked against Ceres' factorisation
// in global_refiner_test and lens_calibration_test.
#include "core/adjust/tree_lm.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>

namespace uavm {
namespace {

// Frames of 8 parameters; each edge measures x_tgt - x_src (8 residuals) and, when `shared`, the shared block's
// first 3 entries enter it too (x_tgt - x_src + c_e * s); frame 0 is fixed; a prior holds s near 0.
class LinearTerms final : public FrameGraphTerms {
 public:
  struct Link {
    size_t src, tgt;
    Eigen::Matrix<double, 8, 1> measured;
    double shared_gain;
    bool in_tree;
  };
  LinearTerms(size_t frames, std::vector<Link> links, bool shared) : n_(frames), links_(std::move(links)), s_(shared) {}

  size_t NumFrames() const override { return n_; }
  size_t NumEdges() const override { return links_.size(); }
  size_t EdgeSrc(size_t e) const override { return links_[e].src; }
  size_t EdgeTgt(size_t e) const override { return links_[e].tgt; }
  bool InTree(size_t e) const override { return links_[e].in_tree; }
  bool Free(size_t frame, int /*k*/) const override { return frame != 0; }
  bool HasShared() const override { return s_; }

  void Edge(size_t e, const double* src, const double* tgt, const double* shared, std::vector<double>* residuals,
            std::vector<double>* jacobian) const override {
    const Link& l = links_[e];
    for (int k = 0; k < 8; ++k) {
      const double s = s_ && k < 3 ? l.shared_gain * shared[k] : 0.0;
      residuals->push_back(tgt[k] - src[k] + s - l.measured(k));
      if (jacobian == nullptr) continue;
      std::array<double, kEdgeColumns> row{};
      row[k] = -1.0;
      row[8 + k] = 1.0;
      if (s_ && k < 3) row[16 + k] = l.shared_gain;
      jacobian->insert(jacobian->end(), row.begin(), row.end());
    }
  }
  void FramePrior(size_t, const double*, std::vector<double>*, std::vector<double>*) const override {}
  void SharedPrior(const double* shared, std::vector<double>* residuals, std::vector<double>* jacobian) const override {
    for (int k = 0; k < 3; ++k) {
      residuals->push_back(0.5 * shared[k]);
      if (jacobian == nullptr) continue;
      std::array<double, 3> row{};
      row[k] = 0.5;
      jacobian->insert(jacobian->end(), row.begin(), row.end());
    }
  }

  // The same least squares as one dense matrix over the free unknowns (frames 1.., then the shared block).
  Eigen::VectorXd DenseSolution() const {
    const auto cols = static_cast<Eigen::Index>(8 * (n_ - 1) + (s_ ? 3 : 0));
    const auto rows = static_cast<Eigen::Index>(8 * links_.size() + (s_ ? 3 : 0));
    Eigen::MatrixXd a = Eigen::MatrixXd::Zero(rows, cols);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(rows);
    for (size_t e = 0; e < links_.size(); ++e)
      for (int k = 0; k < 8; ++k) {
        const auto row = static_cast<Eigen::Index>(8 * e + k);
        if (links_[e].src != 0) a(row, static_cast<Eigen::Index>(8 * (links_[e].src - 1) + k)) = -1.0;
        if (links_[e].tgt != 0) a(row, static_cast<Eigen::Index>(8 * (links_[e].tgt - 1) + k)) = 1.0;
        if (s_ && k < 3) a(row, static_cast<Eigen::Index>(8 * (n_ - 1) + k)) = links_[e].shared_gain;
        b(row) = links_[e].measured(k);
      }
    if (s_)
      for (int k = 0; k < 3; ++k) a(rows - 3 + k, cols - 3 + k) = 0.5;
    return a.colPivHouseholderQr().solve(b);
  }

 private:
  size_t n_;
  std::vector<Link> links_;
  bool s_;
};

// A grid of frames: the tree is the first row and every column; the other edges close loops.
LinearTerms Grid(int rows, int cols, bool shared, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::vector<LinearTerms::Link> links;
  const auto id = [&](int r, int c) { return static_cast<size_t>(r * cols + c); };
  const auto link = [&](size_t a, size_t b, bool tree) {
    Eigen::Matrix<double, 8, 1> m;
    for (int k = 0; k < 8; ++k) m(k) = g(rng);
    links.push_back({a, b, m, 0.5 + 0.1 * g(rng), tree});
  };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      if (c + 1 < cols) link(id(r, c), id(r, c + 1), r == 0);
      if (r + 1 < rows) link(id(r + 1, c), id(r, c), true);
    }
  return LinearTerms(static_cast<size_t>(rows * cols), std::move(links), shared);
}

Eigen::VectorXd Solve(const LinearTerms& terms, TreeLmSummary* summary) {
  std::vector<FrameParamVector> frames(terms.NumFrames());
  SharedParamVector shared{};
  TreeLmOptions options;
  options.linear_tolerance = 1e-9;
  options.function_tolerance = 1e-15;
  *summary = SolveTreeLm(terms, options, &frames, &shared);
  Eigen::VectorXd x(static_cast<Eigen::Index>(8 * (frames.size() - 1) + (terms.HasShared() ? 3 : 0)));
  for (size_t f = 1; f < frames.size(); ++f)
    for (int k = 0; k < 8; ++k) x(static_cast<Eigen::Index>(8 * (f - 1) + k)) = frames[f][static_cast<size_t>(k)];
  if (terms.HasShared())
    for (int k = 0; k < 3; ++k) x(x.size() - 3 + k) = shared[static_cast<size_t>(k)];
  EXPECT_EQ(frames[0], FrameParamVector{}) << "a fixed frame moved";
  return x;
}

TEST(TreeLm, ALoopyGraphReachesTheDenseLeastSquaresSolution) {
  for (const bool shared : {false, true}) {
    const LinearTerms terms = Grid(6, 7, shared, 3);
    TreeLmSummary summary;
    const Eigen::VectorXd x = Solve(terms, &summary);
    ASSERT_TRUE(summary.usable) << summary.message;
    const Eigen::VectorXd truth = terms.DenseSolution();
    EXPECT_LT((x - truth).lpNorm<Eigen::Infinity>(), 1e-6) << "shared " << shared;
    EXPECT_LT(summary.final_cost, summary.initial_cost);
  }
}

// On a tree without a shared block the preconditioner is the system itself: one conjugate-gradient step per solve.
TEST(TreeLm, OnATreeThePreconditionerIsExact) {
  std::vector<LinearTerms::Link> links;
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  for (size_t f = 1; f < 40; ++f) {
    Eigen::Matrix<double, 8, 1> m;
    for (int k = 0; k < 8; ++k) m(k) = g(rng);
    links.push_back({f / 2, f, m, 0.0, true});  // a binary tree
  }
  const LinearTerms terms(40, std::move(links), false);
  TreeLmSummary summary;
  const Eigen::VectorXd x = Solve(terms, &summary);
  EXPECT_LT((x - terms.DenseSolution()).lpNorm<Eigen::Infinity>(), 1e-6);
  EXPECT_LE(summary.linear_iterations, 2 * summary.iterations);
}

TEST(TreeLm, OptionsAreChecked) {
  TreeLmOptions o;
  std::string why;
  EXPECT_TRUE(o.Check(&why));
  o.linear_tolerance = 1.0;
  EXPECT_FALSE(o.Check(&why));
  EXPECT_NE(why.find("linear_tolerance"), std::string::npos);
}

}  // namespace
}  // namespace uavm
