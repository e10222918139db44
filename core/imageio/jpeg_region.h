#pragma once
// Reading part of a JPEG file without transforming the rest: the compositor needs only the part of a frame it owns
// plus the blend's reach, and a whole 12 MP decode was most of its time and its largest buffer. (Rows above the part
// are still entropy-decoded: without restart markers libjpeg cannot seek, so a part low in the frame saves less.)
// jpeglib.h uses FILE and size_t without including their headers.
#include <cstdio>
// (kept apart so that include sorting leaves it after <cstdio>)
#include <jpeglib.h>

#include <csetjmp>
#include <opencv2/core.hpp>
#include <string>

namespace uavm {

// libjpeg error handling that never exits the process: fatal errors long-jump back to the caller's setjmp, warnings
// about damaged entropy-coded data are counted (libjpeg goes on and returns a smeared image; OpenCV ignores them).
struct JpegErrors {
  jpeg_error_mgr mgr;
  std::jmp_buf jump;
  int corrupt = 0;
  char message[JMSG_LENGTH_MAX] = {};
};
// Points cinfo->err at `err` with the handlers above. Call before jpeg_create_decompress (jpeg_create_compress).
void InstallJpegErrors(jpeg_decompress_struct* cinfo, JpegErrors* err);
void InstallJpegErrors(jpeg_compress_struct* cinfo, JpegErrors* err);

struct JpegRegion {
  cv::Mat bgr;           // 8-bit BGR, at least the region asked for (columns widened to libjpeg's MCU bounds)
  cv::Point origin;      // position of bgr's pixel (0, 0) in the scaled image
  cv::Size scaled_size;  // the whole image at 1/denom
  bool corrupt = false;  // libjpeg warned about damaged data while decoding the region
};

// Decodes `region` (pixels of the image scaled by 1/denom, denom 1, 2, 4 or 8; clipped to it) of the JPEG file at
// `path`: rows above it are skipped, columns outside it are not transformed (libjpeg-turbo's jpeg_skip_scanlines and
// jpeg_crop_scanline), so time and memory follow the region's area. False with a reason for an unreadable file, a
// region outside the image and CMYK/YCCK files (the caller decodes those whole).
[[nodiscard]] bool DecodeJpegRegion(const std::string& path, unsigned denom, const cv::Rect& region, JpegRegion* out,
                                    std::string* why);

}  // namespace uavm
