#include "ground_app/stereo_command.h"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <exception>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "core/stereo/sgm.h"
#include "ground_app/exit_codes.h"

namespace uavm::ground {
namespace {

int Error(const std::string& what) {
  std::fprintf(stderr, "uavmosaic-ground stereo: error: %s\n", what.c_str());
  return kExitStereoFailed;
}

}  // namespace

int RunStereoCommand(int argc, char** argv) {
  CLI::App app{
      "Dense disparity of one rectified pair (semi-global matching, census or DAISY cost, left-right check). Writes "
      "the LEFT "
      "image's disparity (x_left - x_right, pixels) as a float32 single-band TIFF; NaN = no disparity.",
      "uavmosaic-ground stereo"};
  std::string left_path, right_path, out_path;
  int max_disparity = 0;
  stereo::SgmOptions options;
  bool no_fill = false;
  app.add_option("LEFT", left_path, "left rectified image")->required();
  app.add_option("RIGHT", right_path, "right rectified image")->required();
  app.add_option("--out", out_path, "output disparity TIFF (float32)")->required();
  app.add_option("--max-disparity", max_disparity,
                 "disparities 0 .. N-1 are searched (default: a quarter of the width, rounded up to 16, at most 256)")
      ->check(CLI::Range(1, 1024));
  app.add_option("--min-disparity", options.min_disparity, "smallest disparity searched");
  app.add_option("--paths", options.num_paths, "SGM aggregation paths (4 or 8)")->check(CLI::IsMember({4, 8}));
  std::string cost = "census";
  app.add_option("--cost", cost, "matching cost: census (+ gradient) or daisy (radius 15, 3 rings, 8 x 8)")
      ->check(CLI::IsMember({"census", "daisy"}));
  app.add_flag("--no-fill", no_fill, "leave pixels that fail the checks as NaN instead of filling them");
  app.add_option("--threads", options.threads, "worker threads (0 = all cores)")->check(CLI::NonNegativeNumber);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);  // 0 for --help, else CLI11's own code for the error (see exit_codes.h)
  }

  try {
    const cv::Mat left = cv::imread(left_path, cv::IMREAD_COLOR);
    if (left.empty()) return Error("cannot read left image '" + left_path + "'");
    const cv::Mat right = cv::imread(right_path, cv::IMREAD_COLOR);
    if (right.empty()) return Error("cannot read right image '" + right_path + "'");
    if (left.size() != right.size()) {
      return Error("image sizes differ: left " + std::to_string(left.cols) + "x" + std::to_string(left.rows) +
                   ", right " + std::to_string(right.cols) + "x" + std::to_string(right.rows) +
                   " (the pair must be rectified to a common size)");
    }
    options.num_disparities = max_disparity > 0 ? max_disparity : std::min(256, (left.cols / 4 + 15) / 16 * 16);
    options.num_disparities = std::max(options.num_disparities, 2);
    options.fill_holes = !no_fill;
    if (cost == "daisy") options.cost = stereo::SgmOptions::Cost::kDaisy;
    std::string why;
    if (!options.Check(&why)) return Error(why);
    cv::Mat disparity;
    if (!stereo::ComputeDisparity(left, right, options, &disparity, &why)) return Error(why);
    // OpenCV writes CV_32FC1 as an IEEE-float single-band TIFF (readable by GDAL).
    if (!cv::imwrite(out_path, disparity)) return Error("cannot write '" + out_path + "'");
    int valid = 0;
    for (int y = 0; y < disparity.rows; ++y)
      for (int x = 0; x < disparity.cols; ++x) valid += disparity.at<float>(y, x) == disparity.at<float>(y, x);
    std::fprintf(stderr,
                 "uavmosaic-ground stereo: %dx%d, disparities %d..%d, %.1f %% of pixels with a disparity -> %s\n",
                 left.cols, left.rows, options.min_disparity, options.min_disparity + options.num_disparities - 1,
                 100.0 * valid / (static_cast<double>(disparity.total()) + 1e-9), out_path.c_str());
    return kExitOk;
  } catch (const std::exception& e) {
    // cv::imwrite throws on unsupported extensions, for instance.
    return Error(e.what());
  }
}

}  // namespace uavm::ground
