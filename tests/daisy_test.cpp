// Dense DAISY (core/stereo/daisy.h) against scikit-image's implementation (tests/daisy_reference.py); as SGM's
// matching cost it is tested with the other Middlebury cases in tests/stereo_matcher_test.cpp.
#include "core/stereo/daisy.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

namespace uavm::stereo {
namespace {

namespace fs = std::filesystem;
const std::string kData = std::string(UAVM_TEST_DATA) + "/middlebury/";

TEST(Daisy, MatchesScikitImage) {
  const cv::Mat full = cv::imread(kData + "venus/im2.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(full.empty());
  const cv::Mat gray = full(cv::Rect(100, 80, 160, 120)).clone();
  char dir_name[64];
  std::snprintf(dir_name, sizeof dir_name, "uavm_daisy_%d", static_cast<int>(::getpid()));
  const fs::path tmp = fs::temp_directory_path() / dir_name;  // (operator+ trips a GCC 12 false positive here)
  fs::create_directories(tmp);
  ASSERT_TRUE(cv::imwrite((tmp / "in.png").string(), gray));
  std::ostringstream command;
  command << "/usr/bin/python3 " << UAVM_SOURCE_DIR << "/tests/daisy_reference.py " << (tmp / "in.png").string() << ' '
          << (tmp / "ref.txt").string() << " 9";
  const std::string cmd = command.str();
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
      << cmd << " failed: scikit-image is Debian's python3-skimage (scripts/setup.sh installs it)";
  DenseDaisy daisy;
  daisy.Prepare(gray);
  const int n = daisy.options().size();
  ASSERT_EQ(n, 200);
  std::vector<float> ours(static_cast<size_t>(n));
  std::ifstream in(tmp / "ref.txt");
  int pixels = 0;
  double worst = 0.0, sum = 0.0;
  for (std::string line; std::getline(in, line);) {
    std::istringstream row(line);
    int x = 0, y = 0;
    row >> x >> y;
    daisy.Descriptor(x, y, ours.data());
    for (int i = 0; i < n; ++i) {
      double ref = 0.0;
      ASSERT_TRUE(static_cast<bool>(row >> ref)) << "short line for pixel " << x << "," << y;
      const double e = std::abs(ref - ours[static_cast<size_t>(i)]);
      worst = std::max(worst, e);
      sum += e;
    }
    ++pixels;
  }
  fs::remove_all(tmp);
  std::printf("%d pixels x %d values: worst difference %.2e, mean %.2e\n", pixels, n, worst, sum / (pixels * n));
  EXPECT_GT(pixels, 100);
  EXPECT_LT(worst, 1e-5);  // float against double (measured 2.2e-7)
}

TEST(Daisy, DistanceIsL1AndZeroForTheSamePixel) {
  const cv::Mat gray = cv::imread(kData + "tsukuba/im3.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(gray.empty());
  DenseDaisy daisy;
  daisy.Prepare(gray);
  const int stride = daisy.options().stride();
  std::vector<uint8_t> row(static_cast<size_t>(gray.cols * stride));
  daisy.Row(100, row.data());
  const uint8_t* a = row.data() + 50 * stride;
  const uint8_t* b = row.data() + 90 * stride;
  int l1 = 0;
  for (int i = 0; i < stride; ++i) l1 += std::abs(int(a[i]) - int(b[i]));
  EXPECT_EQ(DaisyDistance(a, b, stride), l1);
  EXPECT_GT(l1, 0);
  EXPECT_EQ(DaisyDistance(a, a, stride), 0);
  for (int i = daisy.options().size(); i < stride; ++i) EXPECT_EQ(a[i], 0) << "padding";
}

}  // namespace
}  // namespace uavm::stereo
