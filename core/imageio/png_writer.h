#pragma once
// PNG encoding of 8-bit BGRA tiles with libdeflate (the whole-buffer DEFLATE library libtiff already brings): the
// web tiles are written by the hundred at the end of a flight, and libpng + zlib spent most of that time. The format
// is plain PNG (RGBA, 8 bits, no interlace; each row with the SUB filter), read by any decoder.
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

struct libdeflate_compressor;

namespace uavm {

class PngWriter {
 public:
  // `level`: libdeflate's compression level, 1 (fastest) to 12.
  explicit PngWriter(int level = 2);
  ~PngWriter();
  PngWriter(const PngWriter&) = delete;
  PngWriter& operator=(const PngWriter&) = delete;

  // `bgra`: CV_8UC4. False (and `out` empty) on a wrong type or a failed compression.
  [[nodiscard]] bool Encode(const cv::Mat& bgra, std::vector<uint8_t>* out);

 private:
  ::libdeflate_compressor* compressor_ = nullptr;  // owned, freed by the destructor
  std::vector<uint8_t> filtered_;                  // scratch: the filtered rows, reused tile after tile
};

}  // namespace uavm
