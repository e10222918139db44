#pragma once
// PNG encoding of 8-bit BGRA images. PngWriter: tiles, whole, with libdeflate (the whole-buffer DEFLATE library libtiff
// already brings): the web tiles are written by the hundred at the end of a flight, and libpng + zlib spent most of
// that time. PngRowWriter: an image too large to hold, row by row, with zlib's streaming deflate. The format is plain
// PNG (RGBA, 8 bits, no interlace; each row with the SUB filter), read by any decoder.
#include <cstdint>
#include <cstdio>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

struct libdeflate_compressor;
struct z_stream_s;

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

// The same PNG written to a file row by row, through zlib's streaming deflate: an image of any height in the memory of
// one row and the compressor's window (~300 KiB), for images too large to hold whole (the mosaic's quick-look).
class PngRowWriter {
 public:
  // `level`: zlib's compression level, 1 (fastest) to 9.
  explicit PngRowWriter(int level = 2);
  ~PngRowWriter();
  PngRowWriter(const PngRowWriter&) = delete;
  PngRowWriter& operator=(const PngRowWriter&) = delete;

  // Creates (or truncates) `path` for an RGBA image of width x height and writes its header.
  [[nodiscard]] bool Open(const std::string& path, int width, int height, std::string* error);
  // The next row: `width` BGRA pixels.
  [[nodiscard]] bool WriteRow(const uint8_t* bgra, std::string* error);
  // After the last row: the stream's end and the file closed. False when rows are missing or any call failed (the
  // file is then incomplete; the caller removes it); `error` then keeps the first failure's reason.
  [[nodiscard]] bool Finish(std::string* error);

 private:
  // Runs the compressor over what it was given and writes the output as IDAT chunks (`finish`: to the stream's end).
  bool Deflate(bool finish, std::string* error);
  bool Put(const std::vector<uint8_t>& bytes, std::string* error);
  bool Fail(std::string reason, std::string* error);

  int level_;
  std::unique_ptr<z_stream_s> stream_;  // set between Open and Finish
  std::FILE* file_ = nullptr;           // owned, closed by Finish or the destructor
  std::string path_;
  int width_ = 0;
  int height_ = 0;
  int rows_ = 0;
  std::string failure_;       // the first failure since Open: every later call fails with it
  std::vector<uint8_t> row_;  // the filtered row
  std::vector<uint8_t> out_;  // the compressor's output, written out as an IDAT chunk whenever it fills
  std::vector<uint8_t> chunk_;
};

}  // namespace uavm
