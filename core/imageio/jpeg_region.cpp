#include "core/imageio/jpeg_region.h"

#include <jerror.h>

#include <cstdio>
#include <memory>

namespace uavm {

namespace {

void JpegErrorExit(j_common_ptr cinfo) {
  auto* err = reinterpret_cast<JpegErrors*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, err->message);
  std::longjmp(err->jump, 1);
}

void JpegEmitMessage(j_common_ptr cinfo, int level) {
  // Level -1 is a warning; the JFIF version and Adobe transform warnings say nothing about the pixels.
  auto* err = reinterpret_cast<JpegErrors*>(cinfo->err);
  if (level >= 0 || err->mgr.msg_code == JWRN_JFIF_MAJOR || err->mgr.msg_code == JWRN_ADOBE_XFORM) return;
  if (err->corrupt++ == 0) (*cinfo->err->format_message)(cinfo, err->message);
}

jpeg_error_mgr* InstallHandlers(JpegErrors* err) {
  jpeg_error_mgr* mgr = jpeg_std_error(&err->mgr);
  err->mgr.error_exit = JpegErrorExit;
  err->mgr.emit_message = JpegEmitMessage;
  return mgr;
}

enum class RegionStatus { kOk, kFailed, kCmyk, kOutside };

// The libjpeg calls that may long-jump, apart, so that no local of the caller lives across setjmp.
// (jpeg_create_decompress too: it fails only when out of memory, by the same long jump.)
RegionStatus DecodeRegionRows(jpeg_decompress_struct* cinfo, JpegErrors* err, FILE* file, unsigned denom,
                              cv::Rect region, JpegRegion* out) {
  if (setjmp(err->jump) != 0) return RegionStatus::kFailed;
  jpeg_create_decompress(cinfo);
  jpeg_stdio_src(cinfo, file);
  jpeg_read_header(cinfo, TRUE);
  if (cinfo->jpeg_color_space == JCS_CMYK || cinfo->jpeg_color_space == JCS_YCCK) return RegionStatus::kCmyk;
  cinfo->scale_num = 1;
  cinfo->scale_denom = denom;
  cinfo->out_color_space = JCS_EXT_BGR;  // grey and RGB files expand to BGR too
  jpeg_start_decompress(cinfo);
  out->scaled_size = cv::Size(static_cast<int>(cinfo->output_width), static_cast<int>(cinfo->output_height));
  region &= cv::Rect(cv::Point(), out->scaled_size);
  if (region.empty()) return RegionStatus::kOutside;
  auto x = static_cast<JDIMENSION>(region.x);
  auto width = static_cast<JDIMENSION>(region.width);
  jpeg_crop_scanline(cinfo, &x, &width);  // widens to the bounds of the MCU columns
  out->origin = cv::Point(static_cast<int>(x), region.y);
  out->bgr.create(region.height, static_cast<int>(width), CV_8UC3);
  if (region.y > 0) jpeg_skip_scanlines(cinfo, static_cast<JDIMENSION>(region.y));
  for (int r = 0; r < region.height; ++r) {
    JSAMPROW rows[1] = {out->bgr.ptr<JSAMPLE>(r)};
    jpeg_read_scanlines(cinfo, rows, 1);
  }
  // The rows below are not needed: no point in decoding them to finish.
  jpeg_abort_decompress(cinfo);
  return RegionStatus::kOk;
}

}  // namespace

void InstallJpegErrors(jpeg_decompress_struct* cinfo, JpegErrors* err) {
  cinfo->err = InstallHandlers(err);
}

void InstallJpegErrors(jpeg_compress_struct* cinfo, JpegErrors* err) {
  cinfo->err = InstallHandlers(err);
}

bool DecodeJpegRegion(const std::string& path, unsigned denom, const cv::Rect& region, JpegRegion* out,
                      std::string* why) {
  const std::unique_ptr<FILE, int (*)(FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!file) {
    *why = "cannot open " + path;
    return false;
  }
  jpeg_decompress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  *out = JpegRegion{};
  const RegionStatus status = DecodeRegionRows(&cinfo, &err, file.get(), denom, region, out);
  jpeg_destroy_decompress(&cinfo);  // also after a failed create: libjpeg frees only what it allocated
  out->corrupt = err.corrupt > 0;
  switch (status) {
    case RegionStatus::kOk:
      return true;
    case RegionStatus::kFailed:
      *why = std::string("corrupt JPEG data: ") + err.message;
      break;
    case RegionStatus::kCmyk:
      *why = "CMYK JPEG: decoded whole";
      break;
    case RegionStatus::kOutside:
      *why = "region outside the image";
      break;
  }
  out->bgr.release();
  return false;
}

}  // namespace uavm
