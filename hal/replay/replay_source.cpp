#include "hal/replay/replay_source.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/util/clock.h"
#include "hal/replay/natural_order.h"

namespace uavm::hal {

namespace fs = std::filesystem;

namespace {

bool LooksLikeVideo(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".mp4" || ext == ".mov" || ext == ".avi" || ext == ".mkv" || ext == ".mjpeg" || ext == ".webm";
}

// JPEG DCT scaling decodes 1/2, 1/4, 1/8 sizes several times faster than full size: pick the smallest that still
// gives the consumer its long side.
int ReducedFlag(const cv::Size& full, int min_long_side, double* scale) {
  const int long_side = std::max(full.width, full.height);
  *scale = 1.0;
  if (min_long_side <= 0) return cv::IMREAD_COLOR;
  int flag = cv::IMREAD_COLOR;
  for (int f : {2, 4, 8}) {
    if (long_side / f >= min_long_side) {
      *scale = 1.0 / f;
      flag = f == 2 ? cv::IMREAD_REDUCED_COLOR_2 : (f == 4 ? cv::IMREAD_REDUCED_COLOR_4 : cv::IMREAD_REDUCED_COLOR_8);
    }
  }
  return flag;
}

// Reads the header only, so the full size is known before a reduced decode. Returns false when unreadable.
bool ProbeSize(const std::vector<uchar>& bytes, cv::Size* size) {
  // OpenCV has no header-only API; a 1/8 decode is cheap and gives the size to within rounding. For JPEG the exact
  // size comes from the SOF marker, parsed here to avoid the rounding.
  for (size_t i = 2; i + 9 < bytes.size();) {
    if (bytes[0] != 0xFF || bytes[1] != 0xD8) break;
    if (bytes[i] != 0xFF) return false;
    const uchar marker = bytes[i + 1];
    const size_t len = static_cast<size_t>(bytes[i + 2]) << 8 | bytes[i + 3];
    if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
      size->height = bytes[i + 5] << 8 | bytes[i + 6];
      size->width = bytes[i + 7] << 8 | bytes[i + 8];
      return size->width > 0 && size->height > 0;
    }
    i += 2 + len;
  }
  return false;
}

}  // namespace

ReplaySource::ReplaySource(ReplayOptions options) : options_(std::move(options)) {}

std::string ReplaySource::Describe() const {
  return "replay:" + options_.path;
}

Status ReplaySource::Open(std::string* error) {
  std::error_code ec;
  const fs::path root(options_.path);
  if (options_.stride < 1) {
    *error = "replay stride must be >= 1";
    return Status::kError;
  }
  if (fs::is_directory(root, ec)) {
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(root, ec)) {
      if (entry.is_regular_file(ec) || entry.is_symlink(ec)) names.push_back(entry.path().filename().string());
    }
    if (ec) {
      *error = "cannot list " + options_.path + ": " + ec.message();
      return Status::kError;
    }
    std::sort(names.begin(), names.end(), NaturalLess);
    for (size_t i = 0; i < names.size(); i += static_cast<size_t>(options_.stride))
      files_.push_back((root / names[i]).string());
    if (files_.empty()) {
      *error = "no files in " + options_.path;
      return Status::kError;
    }
    return Status::kOk;
  }
  if (fs::is_regular_file(root, ec) && LooksLikeVideo(root)) {
    video_ = std::make_unique<cv::VideoCapture>(options_.path);
    if (!video_->isOpened()) {
      *error = "cannot open video " + options_.path;
      return Status::kError;
    }
    return Status::kOk;
  }
  *error = "replay source not found (need an image folder or a video file): " + options_.path;
  return Status::kError;
}

Status ReplaySource::Next(Frame* frame, std::string* error) {
  return video_ ? NextVideo(frame, error) : NextFile(frame, error);
}

Status ReplaySource::NextFile(Frame* frame, std::string* error) {
  if (next_file_ >= files_.size()) return Status::kEndOfStream;
  const std::string path = files_[next_file_++];
  *frame = Frame{};
  frame->index = next_index_++;
  frame->source_path = path;
  frame->source_name = fs::path(path).filename().string();
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    // A folder that vanished mid-run is a source error, a single unreadable file is not.
    std::error_code ec;
    if (!fs::exists(fs::path(path).parent_path(), ec)) {
      *error = "replay folder disappeared: " + fs::path(path).parent_path().string();
      return Status::kError;
    }
    *error = "cannot read file";
    return Status::kSkipped;
  }
  std::vector<uchar> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.empty()) {
    *error = "empty file (0 bytes)";
    return Status::kSkipped;
  }
  cv::Size full;
  const bool has_size = ProbeSize(bytes, &full);
  double scale = 1.0;
  const int flag = has_size ? ReducedFlag(full, hint_.min_long_side, &scale) : cv::IMREAD_COLOR;
  // Sensor geometry, not display orientation: transforms and the ground tool refer to the stored pixel grid.
  const int flags = flag | cv::IMREAD_IGNORE_ORIENTATION;
  cv::Mat image;
  try {
    image = cv::imdecode(bytes, flags);
  } catch (const cv::Exception& e) {
    image.release();
  }
  if (image.empty()) {
    *error = "not a decodable image";
    return Status::kSkipped;
  }
  if (!has_size) full = image.size();
  // A truncated JPEG decodes "successfully" with a grey tail; libjpeg only warns. Check the end-of-image marker.
  if (bytes.size() >= 2 && bytes[0] == 0xFF && bytes[1] == 0xD8) {
    size_t end = bytes.size();
    while (end > 2 && bytes[end - 1] == 0x00) --end;  // some writers pad
    if (!(bytes[end - 2] == 0xFF && bytes[end - 1] == 0xD9)) {
      *error = "truncated JPEG (no end-of-image marker)";
      return Status::kSkipped;
    }
  }
  frame->timestamp_ns = MonotonicNs();
  frame->original_size = full;
  frame->decode_scale = static_cast<double>(image.cols) / full.width;
  frame->image = std::move(image);
  if (options_.read_metadata) frame->metadata = ReadMetadata(path);
  return Status::kOk;
}

Status ReplaySource::NextVideo(Frame* frame, std::string* error) {
  cv::Mat image;
  if (!video_->read(image) || image.empty()) return Status::kEndOfStream;
  *frame = Frame{};
  frame->index = next_index_++;
  frame->source_name = "video:" + std::to_string(video_frame_++);
  frame->timestamp_ns = MonotonicNs();
  // Skip to the next frame to deliver now, so that the frame numbers in the names are the video's own.
  for (int skip = 0; skip < options_.stride - 1 && video_->grab(); ++skip) ++video_frame_;
  if (image.channels() == 1) cv::cvtColor(image, image, cv::COLOR_GRAY2BGR);
  frame->original_size = image.size();
  frame->image = std::move(image);
  (void)error;
  return Status::kOk;
}

void ReplaySource::Close() {
  if (video_) video_->release();
  video_.reset();
}

}  // namespace uavm::hal
