// uavm-side-by-side LEFT RIGHT OUT [--left-label TEXT] [--right-label TEXT] [--height PX]: two pictures (e.g. a mosaic
// before and after a change) scaled to one height, labelled, side by side in one JPEG, for a benchmark's result file.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace {

cv::Mat Labelled(const cv::Mat& in, int height, const std::string& label) {
  cv::Mat bgr = in;
  if (in.channels() == 4) cv::cvtColor(in, bgr, cv::COLOR_BGRA2BGR);
  cv::Mat out;
  const double s = static_cast<double>(height) / bgr.rows;
  cv::resize(bgr, out, cv::Size(std::max(1, static_cast<int>(bgr.cols * s)), height), 0, 0, cv::INTER_AREA);
  cv::putText(out, label, cv::Point(12, 36), cv::FONT_HERSHEY_SIMPLEX, 1.0, cv::Scalar(0, 0, 0), 5);
  cv::putText(out, label, cv::Point(12, 36), cv::FONT_HERSHEY_SIMPLEX, 1.0, cv::Scalar(255, 255, 255), 2);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Two pictures side by side, scaled to one height and labelled"};
  std::string left, right, out, left_label = "before", right_label = "after";
  int height = 900;
  app.add_option("left", left)->required();
  app.add_option("right", right)->required();
  app.add_option("out", out)->required();
  app.add_option("--left-label", left_label);
  app.add_option("--right-label", right_label);
  app.add_option("--height", height)->check(CLI::Range(64, 8000));
  CLI11_PARSE(app, argc, argv);
  const cv::Mat a = cv::imread(left, cv::IMREAD_UNCHANGED), b = cv::imread(right, cv::IMREAD_UNCHANGED);
  if (a.empty() || b.empty()) {
    std::fprintf(stderr, "cannot read %s\n", a.empty() ? left.c_str() : right.c_str());
    return 1;
  }
  cv::Mat both;
  cv::hconcat(Labelled(a, height, left_label), Labelled(b, height, right_label), both);
  if (!cv::imwrite(out, both, {cv::IMWRITE_JPEG_QUALITY, 85})) {
    std::fprintf(stderr, "cannot write %s\n", out.c_str());
    return 1;
  }
  return 0;
}
