#include "core/imageio/jpeg_memory.h"

#include <cstdlib>

#include "core/imageio/jpeg_region.h"

namespace uavm {

namespace {

// The libjpeg calls that may long-jump, apart, so that no local of the caller lives across setjmp.
bool CompressRows(jpeg_compress_struct* cinfo, JpegErrors* err, const cv::Mat& bgr, int quality) {
  if (setjmp(err->jump) != 0) return false;
  cinfo->image_width = static_cast<JDIMENSION>(bgr.cols);
  cinfo->image_height = static_cast<JDIMENSION>(bgr.rows);
  cinfo->input_components = 3;
  cinfo->in_color_space = JCS_EXT_BGR;
  jpeg_set_defaults(cinfo);
  jpeg_set_quality(cinfo, quality, TRUE);
  jpeg_start_compress(cinfo, TRUE);
  for (int r = 0; r < bgr.rows; ++r) {
    JSAMPROW rows[1] = {const_cast<JSAMPLE*>(bgr.ptr<JSAMPLE>(r))};
    jpeg_write_scanlines(cinfo, rows, 1);
  }
  jpeg_finish_compress(cinfo);
  return true;
}

bool DecompressRows(jpeg_decompress_struct* cinfo, JpegErrors* err, cv::Mat* bgr) {
  if (setjmp(err->jump) != 0) return false;
  jpeg_read_header(cinfo, TRUE);
  cinfo->out_color_space = JCS_EXT_BGR;
  jpeg_start_decompress(cinfo);
  bgr->create(static_cast<int>(cinfo->output_height), static_cast<int>(cinfo->output_width), CV_8UC3);
  for (int r = 0; r < bgr->rows; ++r) {
    JSAMPROW rows[1] = {bgr->ptr<JSAMPLE>(r)};
    jpeg_read_scanlines(cinfo, rows, 1);
  }
  jpeg_finish_decompress(cinfo);
  return true;
}

}  // namespace

bool EncodeJpegBgr(const cv::Mat& bgr, int quality, std::vector<uchar>* jpeg, std::string* why) {
  if (bgr.empty() || bgr.type() != CV_8UC3) {
    *why = "not an 8-bit BGR image";
    return false;
  }
  jpeg_compress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  jpeg_create_compress(&cinfo);
  unsigned char* buffer = nullptr;  // libjpeg's, grown as it writes
  unsigned long size = 0;           // NOLINT(google-runtime-int): jpeg_mem_dest's type
  jpeg_mem_dest(&cinfo, &buffer, &size);
  const bool ok = CompressRows(&cinfo, &err, bgr, quality);
  jpeg_destroy_compress(&cinfo);
  if (ok) jpeg->assign(buffer, buffer + size);
  std::free(buffer);
  if (!ok) *why = std::string("JPEG encoding failed: ") + err.message;
  return ok;
}

bool DecodeJpegBgr(const std::vector<uchar>& jpeg, cv::Mat* bgr, std::string* why) {
  jpeg_decompress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, jpeg.data(), static_cast<unsigned long>(jpeg.size()));  // NOLINT(google-runtime-int)
  const bool ok = DecompressRows(&cinfo, &err, bgr);
  jpeg_destroy_decompress(&cinfo);
  if (ok && err.corrupt == 0) return true;
  *why = std::string("corrupt JPEG data: ") + err.message;
  bgr->release();
  return false;
}

}  // namespace uavm
