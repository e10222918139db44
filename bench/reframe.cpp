// uavm-reframe: a flight of another frame size made from a bundled one, for bench/memory.sh. Each JPEG is scaled
// to cover WIDTHxHEIGHT and centre-cropped to it (another aspect ratio without stretching), and its APP1 segments
// (EXIF with GPS, XMP) are carried over so that the frames still georeference. --water NAMES turns those frames into
// calm water (their mean colour with a faint gradient): a real flight with frames no image can link, for bridging.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

std::vector<unsigned char> ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The APP1 segments (marker and length included) of a JPEG, read up to the first scan.
std::vector<unsigned char> App1Segments(const std::vector<unsigned char>& jpeg) {
  std::vector<unsigned char> out;
  size_t i = 2;  // after SOI
  while (i + 4 <= jpeg.size() && jpeg[i] == 0xFF) {
    const unsigned char marker = jpeg[i + 1];
    if (marker == 0xDA || marker == 0xD9) break;  // start of scan / end of image
    const size_t length = (static_cast<size_t>(jpeg[i + 2]) << 8) | jpeg[i + 3];
    if (length < 2 || i + 2 + length > jpeg.size()) break;
    if (marker == 0xE1)
      out.insert(out.end(), jpeg.begin() + static_cast<long>(i), jpeg.begin() + static_cast<long>(i + 2 + length));
    i += 2 + length;
  }
  return out;
}

// Calm water over the whole frame: one colour (the frame's mean) with a gradient under two grey levels.
cv::Mat Water(const cv::Mat& frame) {
  const cv::Scalar mean = cv::mean(frame);
  cv::Mat out(frame.size(), frame.type());
  for (int y = 0; y < out.rows; ++y) out.row(y).setTo(mean + cv::Scalar::all(1.5 * y / std::max(1, out.rows - 1)));
  return out;
}

std::vector<std::string> SplitNames(const std::string& list) {
  std::vector<std::string> names;
  size_t start = 0;
  while (start <= list.size()) {
    const size_t comma = std::min(list.find(',', start), list.size());
    if (comma > start) names.push_back(list.substr(start, comma - start));
    start = comma + 1;
  }
  return names;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Resized/cropped copy of a flight's JPEGs (EXIF kept)"};
  std::string in_dir;
  std::string out_dir;
  int width = 0;
  int height = 0;
  int max_frames = 0;
  int quality = 92;
  app.add_option("--in", in_dir, "folder of JPEG frames")->required();
  app.add_option("--out", out_dir, "output folder (created)")->required();
  app.add_option("--width", width, "output width")->required()->check(CLI::Range(16, 20000));
  app.add_option("--height", height, "output height")->required()->check(CLI::Range(16, 20000));
  app.add_option("--frames", max_frames, "first N frames in name order (0 = all)");
  app.add_option("--quality", quality, "JPEG quality")->check(CLI::Range(1, 100));
  std::string water;
  app.add_option("--water", water, "comma-separated file names whose frames become calm water (EXIF kept)");
  CLI11_PARSE(app, argc, argv);
  const std::vector<std::string> water_names = SplitNames(water);

  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(in_dir)) {
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".jpg" || ext == ".jpeg") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  if (max_frames > 0 && files.size() > static_cast<size_t>(max_frames)) files.resize(static_cast<size_t>(max_frames));
  if (files.empty()) {
    std::fprintf(stderr, "no JPEG in %s\n", in_dir.c_str());
    return 1;
  }
  fs::create_directories(out_dir);
  for (const auto& path : files) {
    const std::vector<unsigned char> src = ReadFile(path);
    // The stored orientation, as the onboard program reads it.
    const cv::Mat img = cv::imdecode(src, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
    if (img.empty()) {
      std::fprintf(stderr, "cannot decode %s\n", path.c_str());
      return 1;
    }
    const double s = std::max(static_cast<double>(width) / img.cols, static_cast<double>(height) / img.rows);
    const cv::Size scaled(std::max(width, static_cast<int>(std::lround(img.cols * s))),
                          std::max(height, static_cast<int>(std::lround(img.rows * s))));
    cv::Mat resized;
    cv::resize(img, resized, scaled, 0, 0, s < 1 ? cv::INTER_AREA : cv::INTER_CUBIC);
    cv::Mat out = resized(cv::Rect((scaled.width - width) / 2, (scaled.height - height) / 2, width, height));
    if (std::find(water_names.begin(), water_names.end(), path.filename().string()) != water_names.end())
      out = Water(out);
    std::vector<unsigned char> jpeg;
    if (!cv::imencode(".jpg", out, jpeg, {cv::IMWRITE_JPEG_QUALITY, quality})) {
      std::fprintf(stderr, "cannot encode %s\n", path.c_str());
      return 1;
    }
    // OpenCV writes SOI then JFIF APP0: the source's APP1 segments go right after SOI.
    const std::vector<unsigned char> app1 = App1Segments(src);
    jpeg.insert(jpeg.begin() + 2, app1.begin(), app1.end());
    std::ofstream o(fs::path(out_dir) / path.filename(), std::ios::binary);
    o.write(reinterpret_cast<const char*>(jpeg.data()), static_cast<std::streamsize>(jpeg.size()));
    if (!o) {
      std::fprintf(stderr, "cannot write into %s\n", out_dir.c_str());
      return 1;
    }
  }
  std::printf("%zu frames %dx%d in %s\n", files.size(), width, height, out_dir.c_str());
  return 0;
}
