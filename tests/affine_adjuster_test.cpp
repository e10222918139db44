#include "core/adjust/affine_adjuster.h"

#include <gtest/gtest.h>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <random>

#include "core/util/portable_random.h"
#include "tests/edge_lists.h"

namespace uavm {
namespace {

constexpr int kW = 800;
constexpr int kH = 600;

Mat3 Similarity(double s, double th, double tx, double ty) {
  Mat3 m;
  m << s * std::cos(th), -s * std::sin(th), tx, s * std::sin(th), s * std::cos(th), ty, 0, 0, 1;
  return m;
}

double MaxCornerError(const Mat3& a, const Mat3& b) {
  double e = 0;
  for (const Vec2& c : ImageCorners(kW, kH)) e = std::max(e, (Apply(a, c) - Apply(b, c)).norm());
  return e;
}

// 50 frames flown around a circle (camera yaw following the path, a slow altitude change), each edge
// linking consecutive frames and the last back to the first; correspondences carry 0.5 px noise.
struct LoopScene {
  std::vector<Mat3> truth;
  std::vector<Edge> edges;
  std::unordered_map<int, Mat3> chained;  // initial guess: noisy relative transforms composed along the chain
};

LoopScene MakeLoop(int n, double noise_px, unsigned seed) {
  LoopScene scene;
  const double radius = 30.0 * n;  // consecutive frames ~190 px apart, whatever n
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    const double scale = 1.0 + 0.08 * std::sin(a);  // altitude changes by +-8 %
    const Mat3 centre = Similarity(scale, a + M_PI / 2, radius * std::cos(a), radius * std::sin(a));
    scene.truth.push_back(centre * Translation(-kW / 2.0, -kH / 2.0));
  }
  PortableRandom rng(seed);  // the same scene on x86-64 and aarch64 (the suite also runs emulated)
  for (int i = 0; i < n; ++i) {
    const int j = (i + 1) % n;
    Edge e;
    e.src = i;
    e.tgt = j;
    const Mat3 tgt_from_src = scene.truth[static_cast<size_t>(j)].inverse() * scene.truth[static_cast<size_t>(i)];
    test::EdgeLists lists;
    while (lists.src.size() < 40) {
      const Vec2 p(rng.Uniform(0, kW - 1), rng.Uniform(0, kH - 1));
      const Vec2 q = Apply(tgt_from_src, p);
      if (q.x() < 0 || q.y() < 0 || q.x() > kW - 1 || q.y() > kH - 1) continue;
      lists.src.push_back(p.cast<float>());
      lists.tgt.push_back((q + Vec2(rng.Normal(noise_px), rng.Normal(noise_px))).cast<float>());
    }
    e.points = lists.Build();
    e.num_inliers = static_cast<int>(e.points.size());
    // The pair's own estimate, from its noisy points (what RANSAC would hand over).
    Eigen::MatrixXd A(2 * e.points.size(), 6);
    Eigen::VectorXd b(2 * e.points.size());
    A.setZero();
    for (size_t k = 0; k < e.points.size(); ++k) {
      const Vec2 p = e.points.src(k).cast<double>();
      A.row(static_cast<long>(2 * k)) << p.x(), p.y(), 1, 0, 0, 0;
      A.row(static_cast<long>(2 * k + 1)) << 0, 0, 0, p.x(), p.y(), 1;
      b(static_cast<long>(2 * k)) = e.points.tgt(k).x();
      b(static_cast<long>(2 * k + 1)) = e.points.tgt(k).y();
    }
    const Eigen::VectorXd x = A.colPivHouseholderQr().solve(b);
    e.tgt_from_src << x(0), x(1), x(2), x(3), x(4), x(5), 0, 0, 1;
    scene.edges.push_back(e);
  }
  scene.chained[0] = scene.truth[0];
  for (int i = 1; i < n; ++i)
    scene.chained[i] = scene.chained[i - 1] * scene.edges[static_cast<size_t>(i - 1)].tgt_from_src.inverse();
  return scene;
}

// Chords i -> i + 2 for i = 0, stride, 2 stride, ... below `end`, from the loop edges i -> i + 1 -> i + 2: the first
// edge's points carried through the second's transform.
void AddChords(LoopScene* scene, int end, int stride) {
  for (int i = 0; i < end; i += stride) {
    Edge e = scene->edges[static_cast<size_t>(i)];
    const Edge& next = scene->edges[static_cast<size_t>(i + 1)];
    e.tgt = i + 2;
    test::EdgeLists lists = test::ListsOf(e.points);
    for (Vec2f& q : lists.tgt) q = Apply(next.tgt_from_src, q.cast<double>()).cast<float>();
    e.points = lists.Build();
    e.tgt_from_src = next.tgt_from_src * e.tgt_from_src;
    scene->edges.push_back(e);
  }
}

TEST(AffineAdjusterTest, ClosedLoopOf50FramesReturnsToItsStart) {
  LoopScene scene = MakeLoop(50, 0.5, 11);
  std::vector<const Edge*> edges;
  for (const auto& e : scene.edges) edges.push_back(&e);
  std::unordered_set<int> variable;
  std::unordered_map<int, double> half_diag;
  for (int i = 1; i < 50; ++i) variable.insert(i);
  for (int i = 0; i < 50; ++i) half_diag[i] = 0.5 * std::hypot(kW, kH);
  // Error of frame j relative to frame i, against the truth, at the corners of frame j (frame pixels of i).
  const auto relative_error = [&](const std::unordered_map<int, Mat3>& T, int i, int j) {
    return MaxCornerError(T.at(i).inverse() * T.at(j),
                          scene.truth[static_cast<size_t>(i)].inverse() * scene.truth[static_cast<size_t>(j)]);
  };
  // Without adjustment the chain does not close: frame 49 misses frame 0 by the accumulated drift.
  const double chained_misclosure = relative_error(scene.chained, 0, 49);
  auto T = scene.chained;
  const AdjustResult r = AdjustAffine(edges, variable, half_diag, AdjustOptions{}, &T);
  ASSERT_TRUE(r.ok) << r.failure;
  // After adjustment the loop returns to its start: the last frame meets the first as the truth does.
  const double misclosure = relative_error(T, 0, 49);
  EXPECT_LT(misclosure, 0.5) << "chained misclosure was " << chained_misclosure << " px";
  EXPECT_GT(chained_misclosure, 2.0);  // the scene is hard enough that the chain alone fails
  // Inside every overlap (where a seam is), neighbours agree with the truth.
  double worst_overlap = 0;
  for (const Edge& e : scene.edges) {
    const Mat3 est = T.at(e.tgt).inverse() * T.at(e.src);
    const Mat3 truth = scene.truth[static_cast<size_t>(e.tgt)].inverse() * scene.truth[static_cast<size_t>(e.src)];
    for (size_t k = 0; k < e.points.size(); ++k) {
      const Vec2 p = e.points.src(k).cast<double>();
      worst_overlap = std::max(worst_overlap, (Apply(est, p) - Apply(truth, p)).norm());
    }
  }
  double worst_pair_alone = 0;  // the pair's own least-squares estimate, for reference
  for (const Edge& e : scene.edges) {
    const Mat3 truth = scene.truth[static_cast<size_t>(e.tgt)].inverse() * scene.truth[static_cast<size_t>(e.src)];
    for (size_t k = 0; k < e.points.size(); ++k) {
      const Vec2 p = e.points.src(k).cast<double>();
      worst_pair_alone = std::max(worst_pair_alone, (Apply(e.tgt_from_src, p) - Apply(truth, p)).norm());
    }
  }
  // The loop is closed without making any seam worse than its own pair measured it (the noise floor).
  EXPECT_LT(worst_overlap, 1.1 * worst_pair_alone);
  EXPECT_LT(r.rms_px, 1.0);  // ~ the noise level (0.5 px per axis)
}

TEST(AffineAdjusterTest, LocalUpdateMovesOnlyTheVariableFrame) {
  LoopScene scene = MakeLoop(10, 0.0, 5);
  auto T = std::unordered_map<int, Mat3>();
  for (int i = 0; i < 10; ++i) T[i] = scene.truth[static_cast<size_t>(i)];
  T[5] = T[5] * Translation(7, -4);  // perturb one frame
  std::vector<const Edge*> edges{&scene.edges[4], &scene.edges[5]};
  const AdjustResult r = AdjustAffine(edges, {5}, {{5, 500.0}}, AdjustOptions{}, &T);
  ASSERT_TRUE(r.ok);
  EXPECT_LT(MaxCornerError(T[5], scene.truth[5]), 1e-3);
  EXPECT_LT(MaxCornerError(T[4], scene.truth[4]), 1e-12);
}

// The adjustment's normal equations are built in blocks and never as rows (BlockSystem): checked here against the rows
// themselves, written out one by one from the terms the options describe, and solved densely by QR. One unweighted
// pass (robust_iterations 0), a frame fixed besides the reference, frames of different half-diagonals (the rigidity
// and relative-linear weights), a loop with its chords, both solvers.
TEST(AffineAdjusterTest, BlocksGiveTheLeastSquaresSolutionOfTheRowsWrittenOut) {
  LoopScene scene = MakeLoop(12, 0.8, 31);
  AddChords(&scene, 9, 2);
  std::vector<const Edge*> edges;
  for (const auto& e : scene.edges) edges.push_back(&e);
  const std::vector<int> column{1, 2, 3, 4, 5, 7, 8, 9, 10, 11};  // 0 and 6 fixed
  const std::unordered_set<int> variable(column.begin(), column.end());
  std::unordered_map<int, double> half_diag;
  for (int i = 0; i < 12; ++i) half_diag[i] = 300.0 + 40.0 * i;
  AdjustOptions options;
  options.robust_iterations = 0;
  options.rigidity_weight = 0.3;  // strong enough to matter in the solution
  options.relative_linear_weight = 0.1;
  const std::unordered_map<int, Mat3> start = scene.chained;

  // The rows: a variable frame's parameters a00 a01 a02 a10 a11 a12 at 6 x its position in `column`.
  const auto index = [&](int id) {
    const auto it = std::find(column.begin(), column.end(), id);
    return it == column.end() ? -1 : static_cast<int>(it - column.begin());
  };
  std::vector<std::pair<Eigen::VectorXd, double>> rows;  // (coefficients, right-hand side)
  const long n = static_cast<long>(column.size()) * 6;
  // coefficient c on parameter (r, k) of frame id: into the row, or onto the right-hand side when the frame is fixed
  const auto term = [&](Eigen::VectorXd* row, double* rhs, int id, int r, int k, double c) {
    if (index(id) >= 0)
      (*row)(6 * index(id) + 3 * r + k) += c;
    else
      *rhs -= c * start.at(id)(r, k);
  };
  for (const Edge* e : edges)
    for (int r = 0; r < 2; ++r) {
      for (size_t k = 0; k < e->points.size(); ++k) {  // T_src p - T_tgt q = 0
        Eigen::VectorXd row = Eigen::VectorXd::Zero(n);
        double rhs = 0;
        const Vec2f p = e->points.src(k), q = e->points.tgt(k);
        const double ph[3] = {p.x(), p.y(), 1.0}, qh[3] = {q.x(), q.y(), 1.0};
        for (int c = 0; c < 3; ++c) {
          term(&row, &rhs, e->src, r, c, ph[c]);
          term(&row, &rhs, e->tgt, r, c, -qh[c]);
        }
        rows.emplace_back(row, rhs);
      }
      const double scale = options.relative_linear_weight * half_diag.at(index(e->src) >= 0 ? e->src : e->tgt);
      for (int c = 0; c < 2; ++c) {  // L_src - L_tgt R = 0
        Eigen::VectorXd row = Eigen::VectorXd::Zero(n);
        double rhs = 0;
        term(&row, &rhs, e->src, r, c, scale);
        for (int k = 0; k < 2; ++k) term(&row, &rhs, e->tgt, r, k, -scale * e->tgt_from_src(k, c));
        rows.emplace_back(row, rhs);
      }
    }
  for (int id : column) {
    const double scale = options.rigidity_weight * half_diag.at(id);
    const int a = 6 * index(id);
    Eigen::VectorXd same_scale = Eigen::VectorXd::Zero(n), no_shear = Eigen::VectorXd::Zero(n);
    same_scale(a + 0) = scale;  // a00 - a11
    same_scale(a + 4) = -scale;
    no_shear(a + 1) = scale;  // a01 + a10
    no_shear(a + 3) = scale;
    rows.emplace_back(same_scale, 0.0);
    rows.emplace_back(no_shear, 0.0);
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 3; ++c) {  // the faint pull to the current value
        Eigen::VectorXd row = Eigen::VectorXd::Zero(n);
        row(a + 3 * r + c) = 1e-6;
        rows.emplace_back(row, 1e-6 * start.at(id)(r, c));
      }
  }
  Eigen::MatrixXd A(static_cast<long>(rows.size()), n);
  Eigen::VectorXd b(static_cast<long>(rows.size()));
  for (size_t i = 0; i < rows.size(); ++i) {
    A.row(static_cast<long>(i)) = rows[i].first.transpose();
    b(static_cast<long>(i)) = rows[i].second;
  }
  const Eigen::VectorXd x = A.colPivHouseholderQr().solve(b);

  for (const int direct_max_frames : {1000, 0}) {
    options.direct_max_frames = direct_max_frames;
    auto T = start;
    const AdjustResult result = AdjustAffine(edges, variable, half_diag, options, &T);
    ASSERT_TRUE(result.ok) << result.failure;
    EXPECT_EQ(result.iterative, direct_max_frames == 0);
    double worst = 0, moved = 0;
    for (int id : column) {
      Mat3 reference = Mat3::Identity();
      for (int r = 0; r < 2; ++r)
        for (int c = 0; c < 3; ++c) reference(r, c) = x(6 * index(id) + 3 * r + c);
      worst = std::max(worst, MaxCornerError(T.at(id), reference));
      moved = std::max(moved, MaxCornerError(start.at(id), reference));
    }
    EXPECT_LT(worst, 1e-6) << "pixels at the frame corners, direct_max_frames " << direct_max_frames;
    EXPECT_GT(moved, 1.0) << "the solution is not the start";
    EXPECT_EQ(T.at(6), start.at(6)) << "the fixed frame stays";
  }
}

// Beyond direct_max_frames the normal equations are solved by conjugate gradients instead of a factorisation (bounded
// memory at the end of a long flight): the same problem must give the same maps, whichever way it is solved. A long
// loop (a poorly conditioned chain) with cross edges between neighbours' neighbours, and a fixed frame besides the
// reference (the right-hand side of a fixed side).
TEST(AffineAdjusterTest, ConjugateGradientsGiveTheFactorisationsSolution) {
  LoopScene scene = MakeLoop(300, 0.5, 23);
  AddChords(&scene, 298, 3);
  std::vector<const Edge*> edges;
  for (const auto& e : scene.edges) edges.push_back(&e);
  std::unordered_set<int> variable;
  std::unordered_map<int, double> half_diag;
  for (int i = 1; i < 300; ++i)
    if (i != 150) variable.insert(i);
  for (int i = 0; i < 300; ++i) half_diag[i] = 0.5 * std::hypot(kW, kH);
  auto start = scene.chained;
  start[150] = scene.truth[150];
  AdjustOptions direct;
  direct.direct_max_frames = 1000;
  AdjustOptions iterative;
  iterative.direct_max_frames = 10;
  auto T_direct = start;
  auto T_iterative = start;
  const AdjustResult rd = AdjustAffine(edges, variable, half_diag, direct, &T_direct);
  const AdjustResult ri = AdjustAffine(edges, variable, half_diag, iterative, &T_iterative);
  ASSERT_TRUE(rd.ok) << rd.failure;
  ASSERT_TRUE(ri.ok) << ri.failure;
  EXPECT_FALSE(rd.iterative);
  EXPECT_TRUE(ri.iterative);
  EXPECT_GT(ri.iterative_steps, 10);
  double worst = 0;
  for (int id : variable) worst = std::max(worst, MaxCornerError(T_direct.at(id), T_iterative.at(id)));
  EXPECT_LT(worst, 1e-4);  // pixels at the frame corners
  EXPECT_NEAR(rd.rms_px, ri.rms_px, 1e-6);
  // Both moved the chained start (drift of several pixels) onto the loop.
  EXPECT_GT(MaxCornerError(start.at(299), T_iterative.at(299)), 1.0);
  // Too few steps allowed: a failure that says so, not a half-solved map.
  iterative.max_iterative_steps = 2;
  auto T_short = start;
  const AdjustResult rs = AdjustAffine(edges, variable, half_diag, iterative, &T_short);
  EXPECT_FALSE(rs.ok);
  EXPECT_NE(rs.failure.find("did not converge"), std::string::npos) << rs.failure;
}

}  // namespace
}  // namespace uavm
