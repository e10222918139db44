#include "core/imageio/png_writer.h"

#include <libdeflate.h>
#include <zlib.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <string>

namespace uavm {

namespace {

void PutU32(uint32_t v, std::vector<uint8_t>* out) {
  for (int shift = 24; shift >= 0; shift -= 8) out->push_back(static_cast<uint8_t>(v >> shift));
}

// length, type, data, CRC-32 of type + data.
void AppendChunk(const char type[4], const uint8_t* data, size_t size, std::vector<uint8_t>* out) {
  PutU32(static_cast<uint32_t>(size), out);
  const size_t type_at = out->size();
  out->insert(out->end(), type, type + 4);
  out->insert(out->end(), data, data + size);
  PutU32(libdeflate_crc32(0, out->data() + type_at, 4 + size), out);
}

constexpr std::array<uint8_t, 8> kSignature{0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

std::vector<uint8_t> Ihdr(size_t width, size_t height) {
  std::vector<uint8_t> ihdr;
  PutU32(static_cast<uint32_t>(width), &ihdr);
  PutU32(static_cast<uint32_t>(height), &ihdr);
  ihdr.insert(ihdr.end(), {8, 6, 0, 0, 0});  // 8 bits, RGBA, deflate, adaptive filtering, no interlace
  return ihdr;
}

// One row of `w` BGRA pixels as PNG stores it: the filter byte, then RGBA with the SUB filter (each byte minus the
// same channel's byte of the pixel to its left). `dst` holds 1 + 4 w bytes.
void FilterRow(const uint8_t* src, size_t w, uint8_t* dst) {
  dst[0] = 1;
  std::array<uint8_t, 4> left{0, 0, 0, 0};
  for (size_t x = 0; x < w; ++x, src += 4) {
    const std::array<uint8_t, 4> rgba{src[2], src[1], src[0], src[3]};
    for (size_t c = 0; c < 4; ++c) dst[1 + 4 * x + c] = static_cast<uint8_t>(rgba[c] - left[c]);
    left = rgba;
  }
}

}  // namespace

PngWriter::PngWriter(int level) : compressor_(libdeflate_alloc_compressor(level)) {}

PngWriter::~PngWriter() {
  if (compressor_ != nullptr) libdeflate_free_compressor(compressor_);
}

bool PngWriter::Encode(const cv::Mat& bgra, std::vector<uint8_t>* out) {
  out->clear();
  if (compressor_ == nullptr || bgra.type() != CV_8UC4 || bgra.empty()) return false;
  const auto w = static_cast<size_t>(bgra.cols);
  const auto h = static_cast<size_t>(bgra.rows);
  const size_t stride = 1 + 4 * w;  // filter byte, then RGBA
  filtered_.resize(stride * h);
  for (size_t y = 0; y < h; ++y) FilterRow(bgra.ptr<uint8_t>(static_cast<int>(y)), w, filtered_.data() + y * stride);
  std::vector<uint8_t> zlib(libdeflate_zlib_compress_bound(compressor_, filtered_.size()));
  const size_t zlib_size =
      libdeflate_zlib_compress(compressor_, filtered_.data(), filtered_.size(), zlib.data(), zlib.size());
  if (zlib_size == 0) return false;
  out->reserve(zlib_size + 64);
  out->assign(kSignature.begin(), kSignature.end());
  const std::vector<uint8_t> ihdr = Ihdr(w, h);
  AppendChunk("IHDR", ihdr.data(), ihdr.size(), out);
  AppendChunk("IDAT", zlib.data(), zlib_size, out);
  AppendChunk("IEND", nullptr, 0, out);
  return true;
}

PngRowWriter::PngRowWriter(int level) : level_(level) {}

PngRowWriter::~PngRowWriter() {
  if (stream_) deflateEnd(stream_.get());
  if (file_ != nullptr) std::fclose(file_);
}

bool PngRowWriter::Fail(std::string reason, std::string* error) {
  if (failure_.empty()) failure_ = std::move(reason);
  *error = failure_;
  return false;
}

bool PngRowWriter::Open(const std::string& path, int width, int height, std::string* error) {
  if (stream_ || file_ != nullptr || width <= 0 || height <= 0) {
    *error = "png: opened twice or an empty image";
    return false;
  }
  failure_.clear();
  stream_ = std::make_unique<z_stream_s>();
  if (deflateInit(stream_.get(), level_) != Z_OK) {
    stream_.reset();
    return Fail("png: zlib could not start", error);
  }
  path_ = path;
  file_ = std::fopen(path.c_str(), "wb");
  if (file_ == nullptr) return Fail(path + ": " + std::strerror(errno), error);
  width_ = width;
  height_ = height;
  rows_ = 0;
  row_.resize(1 + 4 * static_cast<size_t>(width));
  out_.resize(size_t{1} << 16);
  std::vector<uint8_t> head(kSignature.begin(), kSignature.end());
  const std::vector<uint8_t> ihdr = Ihdr(static_cast<size_t>(width), static_cast<size_t>(height));
  AppendChunk("IHDR", ihdr.data(), ihdr.size(), &head);
  return Put(head, error);
}

bool PngRowWriter::Put(const std::vector<uint8_t>& bytes, std::string* error) {
  if (std::fwrite(bytes.data(), 1, bytes.size(), file_) == bytes.size()) return true;
  return Fail(path_ + ": " + std::strerror(errno), error);
}

bool PngRowWriter::Deflate(bool finish, std::string* error) {
  z_stream_s& z = *stream_;
  for (;;) {
    z.next_out = out_.data();
    z.avail_out = static_cast<uInt>(out_.size());
    const int rc = deflate(&z, finish ? Z_FINISH : Z_NO_FLUSH);
    const size_t produced = out_.size() - z.avail_out;
    // Z_BUF_ERROR with nothing produced: no progress was possible (never with a fresh output buffer).
    if (rc == Z_STREAM_ERROR || (rc == Z_BUF_ERROR && produced == 0)) return Fail("png: zlib failed", error);
    if (produced > 0) {
      chunk_.clear();
      AppendChunk("IDAT", out_.data(), produced, &chunk_);
      if (!Put(chunk_, error)) return false;
    }
    // Without finish all input is taken once the compressor has output room left; with finish it says when it is done.
    if (finish ? rc == Z_STREAM_END : z.avail_out != 0) return true;
  }
}

bool PngRowWriter::WriteRow(const uint8_t* bgra, std::string* error) {
  if (!failure_.empty()) return Fail({}, error);
  if (file_ == nullptr || rows_ >= height_) return Fail("png: a row beyond the image", error);
  FilterRow(bgra, static_cast<size_t>(width_), row_.data());
  stream_->next_in = row_.data();
  stream_->avail_in = static_cast<uInt>(row_.size());
  ++rows_;
  return Deflate(false, error);
}

bool PngRowWriter::Finish(std::string* error) {
  if (file_ == nullptr) {
    if (stream_) deflateEnd(stream_.get());
    stream_.reset();
    return Fail("png: not open", error);
  }
  bool ok = failure_.empty();
  if (ok && rows_ != height_)
    ok = Fail("png: " + std::to_string(rows_) + " of " + std::to_string(height_) + " rows written", error);
  ok = ok && Deflate(true, error);
  if (ok) {
    chunk_.clear();
    AppendChunk("IEND", nullptr, 0, &chunk_);
    ok = Put(chunk_, error);
  }
  deflateEnd(stream_.get());
  stream_.reset();
  const bool closed = std::fclose(file_) == 0;  // the buffered tail is written here
  file_ = nullptr;
  if (ok && !closed) ok = Fail(path_ + ": " + std::strerror(errno), error);
  if (!ok) *error = failure_;
  return ok;
}

}  // namespace uavm
