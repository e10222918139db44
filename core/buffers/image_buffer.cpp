#include "core/buffers/image_buffer.h"

namespace uavm {

namespace {
constexpr size_t kRow = 4096;
}  // namespace

void ImageBuffer::Reserve(size_t bytes) {
  if (bytes <= capacity()) return;
  block_.release();  // the old block goes before the new one is mapped: the peak is the new size, not both
  // Rows of 4 KiB: a block of any size within int's rows.
  block_.create(static_cast<int>((bytes + kRow - 1) / kRow), static_cast<int>(kRow), CV_8U);
}

void ImageBuffer::ReserveResident(size_t bytes) {
  Reserve(bytes);
  block_.setTo(0);
}

cv::Mat ImageBuffer::View(cv::Size size, int type) {
  CV_Assert(size.width >= 0 && size.height >= 0);
  const size_t bytes = static_cast<size_t>(size.width) * static_cast<size_t>(size.height) * CV_ELEM_SIZE(type);
  Reserve(bytes);
  return cv::Mat(size, type, block_.data);
}

}  // namespace uavm
