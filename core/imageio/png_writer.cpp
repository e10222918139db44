#include "core/imageio/png_writer.h"

#include <libdeflate.h>

#include <array>
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
  for (size_t y = 0; y < h; ++y) {
    const uint8_t* src = bgra.ptr<uint8_t>(static_cast<int>(y));
    uint8_t* dst = filtered_.data() + y * stride;
    dst[0] = 1;  // SUB: each byte minus the same channel's byte of the pixel to its left
    std::array<uint8_t, 4> left{0, 0, 0, 0};
    for (size_t x = 0; x < w; ++x, src += 4) {
      const std::array<uint8_t, 4> rgba{src[2], src[1], src[0], src[3]};
      for (size_t c = 0; c < 4; ++c) dst[1 + 4 * x + c] = static_cast<uint8_t>(rgba[c] - left[c]);
      left = rgba;
    }
  }
  std::vector<uint8_t> zlib(libdeflate_zlib_compress_bound(compressor_, filtered_.size()));
  const size_t zlib_size =
      libdeflate_zlib_compress(compressor_, filtered_.data(), filtered_.size(), zlib.data(), zlib.size());
  if (zlib_size == 0) return false;
  static constexpr std::array<uint8_t, 8> kSignature{0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  out->reserve(zlib_size + 64);
  out->assign(kSignature.begin(), kSignature.end());
  std::vector<uint8_t> ihdr;
  PutU32(static_cast<uint32_t>(w), &ihdr);
  PutU32(static_cast<uint32_t>(h), &ihdr);
  ihdr.insert(ihdr.end(), {8, 6, 0, 0, 0});  // 8 bits, RGBA, deflate, adaptive filtering, no interlace
  AppendChunk("IHDR", ihdr.data(), ihdr.size(), out);
  AppendChunk("IDAT", zlib.data(), zlib_size, out);
  AppendChunk("IEND", nullptr, 0, out);
  return true;
}

}  // namespace uavm
