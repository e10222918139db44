#include "core/imageio/jpeg_memory.h"

#include <jerror.h>

#include <algorithm>
#include <new>

#include "core/imageio/jpeg_region.h"

namespace uavm {

namespace {

// libjpeg's output appended to a vector that grows as it writes (jpeg_mem_dest's own buffer, freed and replaced as
// it grows, is handed back only when the encode finishes: a failed encode would leave a freed pointer behind).
struct VectorDestination {
  jpeg_destination_mgr mgr;
  std::vector<uchar>* out;
};

void GrowTo(j_compress_ptr cinfo, size_t used, size_t size) {
  auto* dest = reinterpret_cast<VectorDestination*>(cinfo->dest);
  bool grown = true;
  try {
    dest->out->resize(size);
  } catch (const std::bad_alloc&) {
    grown = false;
  }
  if (!grown) ERREXIT(cinfo, JERR_OUT_OF_MEMORY);  // a long jump to the caller's setjmp, outside any catch
  dest->mgr.next_output_byte = dest->out->data() + used;
  dest->mgr.free_in_buffer = size - used;
}

void InitDestination(j_compress_ptr cinfo) {
  auto* dest = reinterpret_cast<VectorDestination*>(cinfo->dest);
  dest->out->clear();
  // A quality-95 copy of a frame's part is ~1/10 of its pixels' bytes.
  GrowTo(cinfo, 0, std::max<size_t>(4096, size_t{cinfo->image_width} * cinfo->image_height / 4));
}

boolean EmptyOutputBuffer(j_compress_ptr cinfo) {
  auto* dest = reinterpret_cast<VectorDestination*>(cinfo->dest);
  const size_t used = dest->out->size();  // the whole buffer is full when libjpeg calls this
  GrowTo(cinfo, used, 2 * used);
  return TRUE;
}

void TermDestination(j_compress_ptr cinfo) {
  auto* dest = reinterpret_cast<VectorDestination*>(cinfo->dest);
  dest->out->resize(dest->out->size() - dest->mgr.free_in_buffer);
}

// The libjpeg calls that may long-jump, apart, so that no local of the caller lives across setjmp.
bool CompressRows(jpeg_compress_struct* cinfo, JpegErrors* err, const cv::Mat& bgr, int quality,
                  VectorDestination* dest) {
  if (setjmp(err->jump) != 0) return false;
  jpeg_create_compress(cinfo);
  cinfo->dest = &dest->mgr;
  cinfo->image_width = static_cast<JDIMENSION>(bgr.cols);
  cinfo->image_height = static_cast<JDIMENSION>(bgr.rows);
  const bool grey = bgr.channels() == 1;
  cinfo->input_components = grey ? 1 : 3;
  cinfo->in_color_space = grey ? JCS_GRAYSCALE : JCS_EXT_BGR;
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

bool DecompressRows(jpeg_decompress_struct* cinfo, JpegErrors* err, const std::vector<uchar>& jpeg, cv::Mat* bgr) {
  if (setjmp(err->jump) != 0) return false;
  jpeg_create_decompress(cinfo);
  jpeg_mem_src(cinfo, jpeg.data(), static_cast<unsigned long>(jpeg.size()));  // NOLINT(google-runtime-int)
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
  if (bgr.empty() || (bgr.type() != CV_8UC3 && bgr.type() != CV_8UC1)) {
    *why = "not an 8-bit BGR or grey image";
    return false;
  }
  jpeg_compress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  VectorDestination dest{{}, jpeg};
  dest.mgr.init_destination = InitDestination;
  dest.mgr.empty_output_buffer = EmptyOutputBuffer;
  dest.mgr.term_destination = TermDestination;
  const bool ok = CompressRows(&cinfo, &err, bgr, quality, &dest);
  jpeg_destroy_compress(&cinfo);  // also after a failure in jpeg_create_compress: it checks what was made
  if (ok) return true;
  jpeg->clear();
  *why = std::string("JPEG encoding failed: ") + err.message;
  return false;
}

bool DecodeJpegBgr(const std::vector<uchar>& jpeg, cv::Mat* bgr, std::string* why) {
  if (jpeg.empty()) {
    *why = "no JPEG data";
    return false;
  }
  jpeg_decompress_struct cinfo{};
  JpegErrors err{};
  InstallJpegErrors(&cinfo, &err);
  const bool ok = DecompressRows(&cinfo, &err, jpeg, bgr);
  jpeg_destroy_decompress(&cinfo);
  if (ok && err.corrupt == 0) return true;
  *why = std::string("corrupt JPEG data: ") + err.message;
  bgr->release();
  return false;
}

}  // namespace uavm
