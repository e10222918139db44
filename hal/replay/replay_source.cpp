#include "hal/replay/replay_source.h"

#include <jpeglib.h>

#include <algorithm>
#include <csetjmp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string_view>

#include "core/imageio/jpeg_region.h"
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
unsigned ReducedDenominator(const cv::Size& full, int min_long_side) {
  const int long_side = std::max(full.width, full.height);
  unsigned denom = 1;
  if (min_long_side <= 0) return denom;
  for (unsigned f : {2u, 4u, 8u})
    if (long_side / static_cast<int>(f) >= min_long_side) denom = f;
  return denom;
}

// What a frame may be, checked on its header before any pixel is decoded. A header beyond the pixel limit is a
// decompression bomb (a few bytes declaring gigapixels); a side below the minimum cannot be registered.
constexpr int64_t kMaxImagePixels = 120'000'000;         // above any drone camera (100 Mpx)
constexpr uintmax_t kMaxFileBytes = uintmax_t{1} << 30;  // read whole into memory: a 100 Mpx 16-bit TIFF is ~600 MiB
constexpr int kMinImageSide = 32;

enum class Format { kUnknown, kJpeg, kPng, kTiff };

Format Sniff(const std::vector<uchar>& b) {
  static constexpr uchar kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  if (b.size() >= 3 && b[0] == 0xFF && b[1] == 0xD8 && b[2] == 0xFF) return Format::kJpeg;
  if (b.size() >= 8 && std::equal(kPng, kPng + 8, b.begin())) return Format::kPng;
  if (b.size() >= 8 && ((b[0] == 'I' && b[1] == 'I' && b[2] == 42 && b[3] == 0) ||
                        (b[0] == 'M' && b[1] == 'M' && b[2] == 0 && b[3] == 42)))
    return Format::kTiff;
  return Format::kUnknown;
}

// The frame size from the SOF marker. False when there is none before the scan.
bool JpegSize(const std::vector<uchar>& bytes, cv::Size* size) {
  for (size_t i = 2; i + 9 < bytes.size();) {
    if (bytes[i] != 0xFF) return false;
    const uchar marker = bytes[i + 1];
    const size_t len = static_cast<size_t>(bytes[i + 2]) << 8 | bytes[i + 3];
    if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
      size->height = bytes[i + 5] << 8 | bytes[i + 6];
      size->width = bytes[i + 7] << 8 | bytes[i + 8];
      return size->width > 0 && size->height > 0;
    }
    if (marker == 0xDA) return false;
    i += 2 + len;
  }
  return false;
}

uint32_t Be32(const uchar* p) {
  return static_cast<uint32_t>(p[0]) << 24 | static_cast<uint32_t>(p[1]) << 16 | static_cast<uint32_t>(p[2]) << 8 |
         p[3];
}

// IHDR is the first chunk: width and height at bytes 16..23.
bool PngSize(const std::vector<uchar>& b, cv::Size* size) {
  if (b.size() < 24 || std::string_view(reinterpret_cast<const char*>(&b[12]), 4) != "IHDR") return false;
  const uint32_t w = Be32(&b[16]);
  const uint32_t h = Be32(&b[20]);
  if (w == 0 || h == 0 || w > (1u << 30) || h > (1u << 30)) return false;
  *size = cv::Size(static_cast<int>(w), static_cast<int>(h));
  return true;
}

// ImageWidth (256) and ImageLength (257) of the first IFD of a classic TIFF.
bool TiffSize(const std::vector<uchar>& b, cv::Size* size) {
  const bool le = b[0] == 'I';
  const auto u16 = [&](size_t o) -> uint32_t {
    return le ? static_cast<uint32_t>(b[o]) | static_cast<uint32_t>(b[o + 1]) << 8
              : static_cast<uint32_t>(b[o]) << 8 | static_cast<uint32_t>(b[o + 1]);
  };
  const auto u32 = [&](size_t o) -> uint32_t { return le ? u16(o) | u16(o + 2) << 16 : u16(o) << 16 | u16(o + 2); };
  const size_t ifd = u32(4);
  if (ifd + 2 > b.size()) return false;
  const size_t n = u16(ifd);
  uint32_t w = 0;
  uint32_t h = 0;
  for (size_t k = 0; k < n && ifd + 2 + 12 * (k + 1) <= b.size(); ++k) {
    const size_t e = ifd + 2 + 12 * k;
    const uint32_t tag = u16(e);
    const uint32_t type = u16(e + 2);
    const uint32_t value = type == 3 ? u16(e + 8) : (type == 4 ? u32(e + 8) : 0);
    if (tag == 256) w = value;
    if (tag == 257) h = value;
  }
  if (w == 0 || h == 0 || w > (1u << 30) || h > (1u << 30)) return false;
  *size = cv::Size(static_cast<int>(w), static_cast<int>(h));
  return true;
}

bool DeclaredSize(Format format, const std::vector<uchar>& bytes, cv::Size* size) {
  switch (format) {
    case Format::kJpeg:
      return JpegSize(bytes, size);
    case Format::kPng:
      return PngSize(bytes, size);
    case Format::kTiff:
      return TiffSize(bytes, size);
    case Format::kUnknown:
      break;
  }
  return false;
}

// JPEG frames are decoded with libjpeg directly: it reports damaged entropy-coded data (bad Huffman codes, a scan
// that ends early or late) as warnings and goes on, and OpenCV's decoder ignores those warnings and returns a smeared
// frame. One pass decodes (DCT-scaled, as OpenCV's reduced modes) and collects them (JpegErrors).
// The libjpeg calls that may long-jump, apart, so that no local of the caller lives across setjmp. Fills `image`
// (8-bit, 3 channels BGR, or 4 channels CMYK as stored for CMYK/YCCK files).
bool JpegDecodeScaled(jpeg_decompress_struct* cinfo, JpegErrors* err, const std::vector<uchar>& bytes, unsigned denom,
                      cv::Mat* image) {
  if (setjmp(err->jump) != 0) return false;
  jpeg_mem_src(cinfo, bytes.data(), static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(cinfo, TRUE);
  cinfo->scale_num = 1;
  cinfo->scale_denom = denom;
  const bool cmyk = cinfo->jpeg_color_space == JCS_CMYK || cinfo->jpeg_color_space == JCS_YCCK;
  cinfo->out_color_space = cmyk ? JCS_CMYK : JCS_EXT_BGR;  // grey and RGB files expand to BGR too
  jpeg_start_decompress(cinfo);
  image->create(static_cast<int>(cinfo->output_height), static_cast<int>(cinfo->output_width),
                cmyk ? CV_8UC4 : CV_8UC3);
  while (cinfo->output_scanline < cinfo->output_height) {
    JSAMPROW rows[1] = {image->ptr<JSAMPLE>(static_cast<int>(cinfo->output_scanline))};
    jpeg_read_scanlines(cinfo, rows, 1);
  }
  jpeg_finish_decompress(cinfo);
  return true;
}

// Decodes a JPEG at 1/denom scale into 8-bit BGR. False with libjpeg's message when the file is damaged.
bool DecodeJpeg(const std::vector<uchar>& bytes, unsigned denom, cv::Mat* bgr, std::string* why) {
  jpeg_decompress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  jpeg_create_decompress(&cinfo);
  cv::Mat image;
  const bool decoded = JpegDecodeScaled(&cinfo, &err, bytes, denom, &image);
  jpeg_destroy_decompress(&cinfo);
  if (!decoded || err.corrupt > 0) {
    *why = std::string("corrupt JPEG data: ") + err.message;
    return false;
  }
  if (image.channels() == 4) {
    // Adobe CMYK is stored inverted (255 = no ink): each colour is the inverted ink scaled by the inverted black.
    bgr->create(image.size(), CV_8UC3);
    image.forEach<cv::Vec4b>([&](const cv::Vec4b& v, const int* pos) {
      const int k = v[3];
      const auto channel = [k](int ink) { return static_cast<uchar>(k - ((255 - ink) * k >> 8)); };
      bgr->at<cv::Vec3b>(pos[0], pos[1]) = cv::Vec3b(channel(v[2]), channel(v[1]), channel(v[0]));
    });
    return true;
  }
  *bgr = std::move(image);
  return true;
}

// The whole of the file at `path` into `bytes` (kOk), or why not: kSkipped for this file, kError when its folder
// vanished mid-run (a source error, not a single unreadable file).
Status ReadWholeFile(const std::string& path, std::vector<uchar>* bytes, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::error_code ec;
    if (!fs::exists(fs::path(path).parent_path(), ec)) {
      *error = "replay folder disappeared: " + fs::path(path).parent_path().string();
      return Status::kError;
    }
    *error = "cannot read file";
    return Status::kSkipped;
  }
  // One read of the whole file (a byte-by-byte stream iterator took ~3 ms of the capture thread per 4 MB photo), of a
  // regular file only: a directory or a pipe has no size to read (a directory's end lies far beyond any buffer).
  std::error_code size_ec;
  if (!fs::is_regular_file(path, size_ec)) {
    *error = "not a regular file";
    return Status::kSkipped;
  }
  const auto size = fs::file_size(path, size_ec);
  if (size_ec) {
    *error = "cannot read file";
    return Status::kSkipped;
  }
  if (size > kMaxFileBytes) {
    *error = "file of " + std::to_string(size >> 20) + " MiB: more than any photo (" +
             std::to_string(kMaxFileBytes >> 20) + " MiB)";
    return Status::kSkipped;
  }
  bytes->resize(static_cast<size_t>(size));
  if (size > 0 && !in.read(reinterpret_cast<char*>(bytes->data()), static_cast<std::streamsize>(size))) {
    *error = "cannot read file";
    return Status::kSkipped;
  }
  return Status::kOk;
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
    video_ = OpenVideo(options_.path, error);
    return video_ ? Status::kOk : Status::kError;
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
  std::vector<uchar>& bytes = file_bytes_;
  if (const Status read = ReadWholeFile(path, &bytes, error); read != Status::kOk) return read;
  if (bytes.empty()) {
    *error = "empty file (0 bytes)";
    return Status::kSkipped;
  }
  // The same bytes twice (a camera that wrote a frame twice, a copied file) add nothing but a degenerate pair.
  const size_t hash =
      std::hash<std::string_view>{}(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
  const auto seen = seen_.find(hash);
  if (seen != seen_.end() && seen->second.size == bytes.size()) {
    *error = "duplicate of " + seen->second.name + " (identical bytes)";
    return Status::kSkipped;
  }
  // Only formats whose size can be read from the header before decoding: a decompression bomb is refused unopened.
  const Format format = Sniff(bytes);
  if (format == Format::kUnknown) {
    *error = "unsupported format: not a JPEG, PNG or TIFF image";
    return Status::kSkipped;
  }
  cv::Size full;
  if (!DeclaredSize(format, bytes, &full)) {
    *error = "unreadable image header";
    return Status::kSkipped;
  }
  const int64_t pixels = static_cast<int64_t>(full.width) * full.height;
  if (pixels > kMaxImagePixels) {
    *error = "header declares " + std::to_string(full.width) + "x" + std::to_string(full.height) + " (" +
             std::to_string(pixels / 1'000'000) + " Mpx), more than the " +
             std::to_string(kMaxImagePixels / 1'000'000) + " Mpx a frame may have (decompression bomb?)";
    return Status::kSkipped;
  }
  if (std::min(full.width, full.height) < kMinImageSide) {
    *error = "image too small to register: " + std::to_string(full.width) + "x" + std::to_string(full.height) +
             " (a frame needs " + std::to_string(kMinImageSide) + " px a side)";
    return Status::kSkipped;
  }
  if (format == Format::kJpeg) {
    // A truncated JPEG decodes "successfully" with a grey tail; libjpeg only warns. Check the end-of-image marker
    // (the decoder below checks the entropy-coded data).
    size_t end = bytes.size();
    while (end > 2 && bytes[end - 1] == 0x00) --end;  // some writers pad
    if (!(bytes[end - 2] == 0xFF && bytes[end - 1] == 0xD9)) {
      *error = "truncated JPEG (no end-of-image marker)";
      return Status::kSkipped;
    }
  }
  // JPEG decodes DCT-scaled (1/2, 1/4, 1/8) to what the consumer needs; the other formats decode whole and the
  // consumer resizes. Sensor geometry, not display orientation: transforms and the ground tool refer to the stored
  // pixel grid (libjpeg ignores EXIF orientation; OpenCV is told to). Every frame becomes 8-bit BGR: 16-bit, grey,
  // alpha (dropped) and CMYK inputs are converted.
  cv::Mat image;
  if (format == Format::kJpeg) {
    if (!DecodeJpeg(bytes, ReducedDenominator(full, hint_.min_long_side), &image, error)) return Status::kSkipped;
  } else {
    try {
      image = cv::imdecode(bytes, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
    } catch (const cv::Exception& e) {
      image.release();
    }
  }
  if (image.empty()) {
    *error = "not a decodable image";
    return Status::kSkipped;
  }
  if (options_.read_metadata) frame->metadata = ReadMetadata(bytes.data(), bytes.size());
  frame->timestamp_ns = MonotonicNs();
  frame->original_size = full;
  frame->decode_scale = static_cast<double>(image.cols) / full.width;
  frame->image = std::move(image);
  seen_.emplace(hash, Seen{bytes.size(), frame->source_name});
  return Status::kOk;
}

Status ReplaySource::NextVideo(Frame* frame, std::string* error) {
  cv::Mat image;
  if (!video_->Read(&image)) return Status::kEndOfStream;
  *frame = Frame{};
  frame->index = next_index_++;
  frame->source_name = "video:" + std::to_string(video_frame_++);
  frame->timestamp_ns = MonotonicNs();
  // Skip to the next frame to deliver now, so that the frame numbers in the names are the video's own.
  for (int skip = 0; skip < options_.stride - 1 && video_->Grab(); ++skip) ++video_frame_;
  if (image.channels() == 1) cv::cvtColor(image, image, cv::COLOR_GRAY2BGR);
  frame->original_size = image.size();
  frame->image = std::move(image);
  (void)error;
  return Status::kOk;
}

void ReplaySource::Close() {
  video_.reset();
  file_bytes_ = {};
}

}  // namespace uavm::hal
