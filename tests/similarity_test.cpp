// FitSimilarity (core/geometry/similarity.h) against similarities known by construction, an independent linear
// least-squares solution (2-D), and the inputs it must refuse.
#include "core/geometry/similarity.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <random>

namespace uavm {
namespace {

template <int D>
using Points = std::vector<Eigen::Matrix<double, D, 1>>;

template <int D>
Points<D> RandomPoints(int n, double spread, std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-spread, spread);
  Points<D> p(static_cast<size_t>(n));
  for (auto& x : p)
    for (int k = 0; k < D; ++k) x(k) = u(*rng);
  return p;
}

template <int D>
Points<D> Map(const Similarity<D>& s, const Points<D>& src) {
  Points<D> out;
  for (const auto& p : src) out.push_back(s.Apply(p));
  return out;
}

template <int D>
double SumSquares(const Similarity<D>& s, const Points<D>& src, const Points<D>& dst) {
  double sum = 0.0;
  for (size_t i = 0; i < src.size(); ++i) sum += (s.Apply(src[i]) - dst[i]).squaredNorm();
  return sum;
}

Similarity2 Make2(double scale, double angle, double tx, double ty) {
  Similarity2 s;
  s.scale = scale;
  s.rotation = Eigen::Rotation2Dd(angle).toRotationMatrix();
  s.translation = Eigen::Vector2d(tx, ty);
  return s;
}

Similarity3 Make3(double scale, const Eigen::Vector3d& axis, double angle, const Eigen::Vector3d& t) {
  Similarity3 s;
  s.scale = scale;
  s.rotation = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  s.translation = t;
  return s;
}

template <int D>
void ExpectNear(const Similarity<D>& a, const Similarity<D>& b, double tol) {
  EXPECT_NEAR(a.scale, b.scale, tol * b.scale);
  EXPECT_LE((a.rotation - b.rotation).cwiseAbs().maxCoeff(), tol);
  EXPECT_LE((a.translation - b.translation).norm(), tol * (1.0 + b.translation.norm()));
}

TEST(SimilarityTest, RecoversExact2d) {
  std::mt19937 rng(1);
  const Similarity2 truth = Make2(0.05, 2.6, 512345.0, -4123456.0);  // pixels -> UTM-sized metres
  const Points<2> src = RandomPoints<2>(30, 3000.0, &rng);
  Similarity2 fit;
  ASSERT_TRUE(FitSimilarity<2>(src, Map(truth, src), &fit));
  ExpectNear(fit, truth, 1e-9);
  EXPECT_NEAR(fit.rotation.determinant(), 1.0, 1e-12);
}

TEST(SimilarityTest, RecoversExact3d) {
  std::mt19937 rng(2);
  const Similarity3 truth = Make3(3.7, Eigen::Vector3d(0.3, -1.0, 0.4), 1.1, Eigen::Vector3d(10.0, -20.0, 5.0));
  const Points<3> src = RandomPoints<3>(12, 50.0, &rng);
  Similarity3 fit;
  ASSERT_TRUE(FitSimilarity<3>(src, Map(truth, src), &fit));
  ExpectNear(fit, truth, 1e-12);
  EXPECT_NEAR(fit.rotation.determinant(), 1.0, 1e-12);
}

TEST(SimilarityTest, TwoPointsFix2d) {
  const Similarity2 truth = Make2(2.0, -0.7, 3.0, 4.0);
  const Points<2> src = {Eigen::Vector2d(0, 0), Eigen::Vector2d(10, 5)};
  Similarity2 fit;
  ASSERT_TRUE(FitSimilarity<2>(src, Map(truth, src), &fit));
  ExpectNear(fit, truth, 1e-12);
}

// With noise the fit is the least-squares one: it matches the 4-parameter linear solution u = a x - b y + tx,
// v = b x + a y + ty (a different algorithm for the same optimum), and fits better than the truth.
TEST(SimilarityTest, NoisyFitIsLeastSquares2d) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 2.0);
  const Similarity2 truth = Make2(0.8, 0.3, -40.0, 25.0);
  const Points<2> src = RandomPoints<2>(200, 500.0, &rng);
  Points<2> dst = Map(truth, src);
  for (auto& p : dst) p += Eigen::Vector2d(noise(rng), noise(rng));
  Similarity2 fit;
  ASSERT_TRUE(FitSimilarity<2>(src, dst, &fit));
  ExpectNear(fit, truth, 1e-2);
  EXPECT_LE(SumSquares(fit, src, dst), SumSquares(truth, src, dst));

  Eigen::MatrixXd a(2 * src.size(), 4);
  Eigen::VectorXd b(2 * src.size());
  for (size_t i = 0; i < src.size(); ++i) {
    const auto r = static_cast<Eigen::Index>(2 * i);
    a.row(r) << src[i].x(), -src[i].y(), 1, 0;
    a.row(r + 1) << src[i].y(), src[i].x(), 0, 1;
    b(r) = dst[i].x();
    b(r + 1) = dst[i].y();
  }
  const Eigen::Vector4d x = a.colPivHouseholderQr().solve(b);
  Similarity2 linear;
  linear.scale = std::hypot(x(0), x(1));
  linear.rotation << x(0), -x(1), x(1), x(0);
  linear.rotation /= linear.scale;
  linear.translation = x.tail<2>();
  ExpectNear(fit, linear, 1e-9);
}

TEST(SimilarityTest, NoisyFitIsLeastSquares3d) {
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, 0.5);
  const Similarity3 truth = Make3(12.0, Eigen::Vector3d(1, 2, 3), -0.9, Eigen::Vector3d(300.0, 200.0, 50.0));
  const Points<3> src = RandomPoints<3>(100, 10.0, &rng);
  Points<3> dst = Map(truth, src);
  for (auto& p : dst) p += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
  Similarity3 fit;
  ASSERT_TRUE(FitSimilarity<3>(src, dst, &fit));
  ExpectNear(fit, truth, 1e-2);
  const double best = SumSquares(fit, src, dst);
  EXPECT_LE(best, SumSquares(truth, src, dst));
  // A minimum: small changes of scale, rotation or translation only make it worse.
  for (int k = 0; k < 7; ++k) {
    for (double step : {-1e-4, 1e-4}) {
      Similarity3 p = fit;
      if (k == 0) p.scale *= 1.0 + step;
      if (k >= 1 && k <= 3)
        p.rotation = Eigen::AngleAxisd(step, Eigen::Vector3d::Unit(k - 1)).toRotationMatrix() * p.rotation;
      if (k >= 4) p.translation(k - 4) += step;
      EXPECT_GT(SumSquares(p, src, dst), best) << k << " " << step;
    }
  }
}

TEST(SimilarityTest, ReflectionOnlyWhenAllowed) {
  std::mt19937 rng(5);
  Similarity2 truth = Make2(1.5, 0.4, 7.0, -3.0);
  truth.rotation = truth.rotation * Eigen::DiagonalMatrix<double, 2>(1.0, -1.0);  // y flipped, like image rows
  const Points<2> src = RandomPoints<2>(20, 100.0, &rng);
  const Points<2> dst = Map(truth, src);
  Similarity2 proper;
  ASSERT_TRUE(FitSimilarity<2>(src, dst, &proper));
  EXPECT_NEAR(proper.rotation.determinant(), 1.0, 1e-12);
  EXPECT_GT(SumSquares(proper, src, dst), 1.0);
  Similarity2 any;
  ASSERT_TRUE(FitSimilarity<2>(src, dst, &any, {.allow_reflection = true}));
  ExpectNear(any, truth, 1e-12);
  // And a proper map stays proper when reflections are allowed.
  const Similarity2 rot = Make2(1.5, 0.4, 7.0, -3.0);
  ASSERT_TRUE(FitSimilarity<2>(src, Map(rot, src), &any, {.allow_reflection = true}));
  ExpectNear(any, rot, 1e-12);

  Similarity3 mirror3 = Make3(2.0, Eigen::Vector3d(0, 0, 1), 0.5, Eigen::Vector3d(1, 2, 3));
  mirror3.rotation = mirror3.rotation * Eigen::DiagonalMatrix<double, 3>(1.0, 1.0, -1.0);
  const Points<3> src3 = RandomPoints<3>(10, 5.0, &rng);
  Similarity3 fit3;
  ASSERT_TRUE(FitSimilarity<3>(src3, Map(mirror3, src3), &fit3, {.allow_reflection = true}));
  ExpectNear(fit3, mirror3, 1e-12);
}

TEST(SimilarityTest, IndexSubsetIgnoresTheRest) {
  std::mt19937 rng(6);
  const Similarity2 truth = Make2(0.1, 1.0, 100.0, 200.0);
  const Points<2> src = RandomPoints<2>(10, 1000.0, &rng);
  Points<2> dst = Map(truth, src);
  dst[2] += Eigen::Vector2d(500.0, -300.0);  // outliers outside the subset
  dst[7] += Eigen::Vector2d(-80.0, 90.0);
  const std::vector<size_t> inliers = {0, 1, 3, 4, 5, 6, 8, 9};
  Similarity2 fit;
  ASSERT_TRUE(FitSimilarity<2>(src, dst, &fit, {.indices = &inliers}));
  ExpectNear(fit, truth, 1e-9);
  const std::vector<size_t> pair = {4, 9};
  ASSERT_TRUE(FitSimilarity<2>(src, dst, &fit, {.indices = &pair}));
  ExpectNear(fit, truth, 1e-9);
}

TEST(SimilarityTest, RefusesDegenerateInput) {
  const Similarity2 untouched = Make2(9.0, 0.1, 1.0, 2.0);
  Similarity2 fit = untouched;
  const Points<2> one = {Eigen::Vector2d(1, 2)};
  EXPECT_FALSE(FitSimilarity<2>(one, one, &fit));
  EXPECT_FALSE(FitSimilarity<2>({}, {}, &fit));
  const Points<2> two = {Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 0)};
  const Points<2> three = {Eigen::Vector2d(0, 0), Eigen::Vector2d(1, 0), Eigen::Vector2d(0, 1)};
  EXPECT_FALSE(FitSimilarity<2>(two, three, &fit));  // sizes differ
  const Points<2> same = {Eigen::Vector2d(5, 5), Eigen::Vector2d(5, 5), Eigen::Vector2d(5, 5)};
  EXPECT_FALSE(FitSimilarity<2>(same, three, &fit));  // coincident source: no scale
  EXPECT_FALSE(FitSimilarity<2>(three, same, &fit));  // coincident destination: scale 0
  EXPECT_FALSE(FitSimilarity<2>(three, same, &fit, {.allow_reflection = true}));
  Points<2> nan = three;
  nan[1].x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(FitSimilarity<2>(nan, three, &fit));
  const std::vector<size_t> out_of_range = {0, 3};
  EXPECT_FALSE(FitSimilarity<2>(three, three, &fit, {.indices = &out_of_range}));
  const std::vector<size_t> single = {1};
  EXPECT_FALSE(FitSimilarity<2>(three, three, &fit, {.indices = &single}));
  const Points<3> same3(4, Eigen::Vector3d(1, 2, 3));
  Similarity3 fit3;
  EXPECT_FALSE(FitSimilarity<3>(same3, same3, &fit3));
  ExpectNear(fit, untouched, 0.0);
}

}  // namespace
}  // namespace uavm
