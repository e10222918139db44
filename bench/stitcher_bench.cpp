// uavm-stitcher-bench: baseline for the real-flight benchmark. Runs OpenCV's own
// cv::Stitcher (SCANS mode, otherwise default settings) on a folder of frames and prints
// exactly one JSON line on stdout, so run_real.sh can compare it with uavmosaic-onboard.

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstddef>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/core/utils/logger.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/stitching.hpp>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace fs = std::filesystem;

namespace {

bool is_digit(char c) {
  return c >= '0' && c <= '9';
}

// Natural order: digit runs compare as numbers, so frame_2 < frame_10 (plain string order
// would put frame_10 first and feed the stitcher a scrambled flight).
bool natural_less(std::string_view a, std::string_view b) {
  std::size_t i = 0;
  std::size_t j = 0;
  while (i < a.size() && j < b.size()) {
    if (is_digit(a[i]) && is_digit(b[j])) {
      std::size_t ie = i;
      std::size_t je = j;
      while (ie < a.size() && is_digit(a[ie])) ++ie;
      while (je < b.size() && is_digit(b[je])) ++je;
      // Strip leading zeros, then a longer run is the bigger number; equal length compares lexically.
      std::size_t iz = i;
      std::size_t jz = j;
      while (iz + 1 < ie && a[iz] == '0') ++iz;
      while (jz + 1 < je && b[jz] == '0') ++jz;
      const std::string_view na = a.substr(iz, ie - iz);
      const std::string_view nb = b.substr(jz, je - jz);
      if (na.size() != nb.size()) return na.size() < nb.size();
      if (na != nb) return na < nb;
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i;
      ++j;
    }
  }
  if (a.size() - i != b.size() - j) return a.size() - i < b.size() - j;
  return a < b;  // tie-break ("01" vs "1") so the order is strict and deterministic
}

bool is_image(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".jpg" || ext == ".jpeg" || ext == ".png";
}

std::vector<fs::path> list_images(const fs::path& dir) {
  if (!fs::is_directory(dir)) throw std::runtime_error("not a directory: " + dir.string());
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.is_regular_file() && is_image(e.path())) files.push_back(e.path());
  }
  std::sort(files.begin(), files.end(), [](const fs::path& x, const fs::path& y) {
    return natural_less(x.filename().string(), y.filename().string());
  });
  return files;
}

const char* status_name(cv::Stitcher::Status s) {
  switch (s) {
    case cv::Stitcher::OK:
      return "OK";
    case cv::Stitcher::ERR_NEED_MORE_IMGS:
      return "ERR_NEED_MORE_IMGS";
    case cv::Stitcher::ERR_HOMOGRAPHY_EST_FAIL:
      return "ERR_HOMOGRAPHY_EST_FAIL";
    case cv::Stitcher::ERR_CAMERA_PARAMS_ADJUST_FAIL:
      return "ERR_CAMERA_PARAMS_ADJUST_FAIL";
  }
  return "UNKNOWN_STATUS";
}

// Exception texts (cv::Exception::what() spans lines and quotes) must not break the JSON line.
std::string json_escape(std::string_view s) {
  std::string out;
  out.reserve(s.size() + 8);
  for (const char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    switch (ch) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (c < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(c));
          out += buf;
        } else {
          out += ch;
        }
    }
  }
  return out;
}

// cv::Exception::what() spans several lines; a table cell and a log grep want one.
std::string one_line(const std::string& s) {
  std::string out = s;
  std::replace(out.begin(), out.end(), '\n', ' ');
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Run OpenCV cv::Stitcher (SCANS) on a folder of frames; prints one JSON line"};
  std::string images_dir;
  std::string out_file;
  int max_frames = 0;
  app.add_option("--images", images_dir, "folder of .jpg/.JPG/.png frames (natural filename order)")->required();
  app.add_option("--out", out_file, "panorama output file (.png)")->required();
  app.add_option("--max-frames", max_frames, "use only the first N frames (0 = all)")->check(CLI::NonNegativeNumber);
  std::string exposure = "none";
  app.add_option("--exposure", exposure,
                 "exposure compensator: none (SCANS' default), gain, channels, gain_blocks, channels_blocks")
      ->check(CLI::IsMember({"none", "gain", "channels", "gain_blocks", "channels_blocks"}));
  CLI11_PARSE(app, argc, argv);

  // Keep stdout for the single JSON line; OpenCV's info chatter would go to stderr anyway,
  // but silence it so logs stay readable.
  cv::utils::logging::setLogLevel(cv::utils::logging::LOG_LEVEL_WARNING);

  const auto t0 = std::chrono::steady_clock::now();
  std::string status = "ok";
  std::size_t frames = 0;
  std::size_t in_result = 0;
  int width = 0;
  int height = 0;
  int rc = 0;

  try {
    std::vector<fs::path> files = list_images(images_dir);
    if (max_frames > 0 && files.size() > static_cast<std::size_t>(max_frames)) {
      files.resize(static_cast<std::size_t>(max_frames));
    }
    std::vector<cv::Mat> imgs;
    imgs.reserve(files.size());
    for (const auto& f : files) {
      cv::Mat m = cv::imread(f.string(), cv::IMREAD_COLOR);
      if (m.empty()) throw std::runtime_error("cannot read image " + f.string());
      imgs.push_back(std::move(m));
    }
    frames = imgs.size();

    cv::Ptr<cv::Stitcher> stitcher = cv::Stitcher::create(cv::Stitcher::SCANS);
    using cv::detail::ExposureCompensator;
    if (exposure != "none") {
      const int type = exposure == "gain"          ? ExposureCompensator::GAIN
                       : exposure == "channels"    ? ExposureCompensator::CHANNELS
                       : exposure == "gain_blocks" ? ExposureCompensator::GAIN_BLOCKS
                                                   : ExposureCompensator::CHANNELS_BLOCKS;
      stitcher->setExposureCompensator(ExposureCompensator::createDefault(type));
    }
    cv::Mat pano;
    const cv::Stitcher::Status st = stitcher->stitch(imgs, pano);
    in_result = stitcher->component().size();
    imgs.clear();  // release the inputs before encoding a possibly huge PNG

    if (st != cv::Stitcher::OK) {
      status = std::string("failed: ") + status_name(st);
      rc = 1;
    } else {
      width = pano.cols;
      height = pano.rows;
      const fs::path out_path(out_file);
      if (out_path.has_parent_path()) fs::create_directories(out_path.parent_path());
      if (!cv::imwrite(out_file, pano)) throw std::runtime_error("imwrite failed for " + out_file);
    }
  } catch (const cv::Exception& e) {
    status = "failed: " + one_line(e.what());
    rc = 1;
  } catch (const std::exception& e) {
    status = "failed: " + one_line(e.what());
    rc = 1;
  }

  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::cout << "{\"status\":\"" << json_escape(status) << "\",\"frames\":" << frames
            << ",\"frames_in_result\":" << in_result << ",\"wall_s\":" << wall_s << ",\"width\":" << width
            << ",\"height\":" << height << "}" << std::endl;
  return rc;
}
