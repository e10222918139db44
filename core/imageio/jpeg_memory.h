#pragma once
// JPEG copies held in memory, in OpenCV's BGR order straight from and to libjpeg: the compositor keeps parts of frames
// this way between tiles and decodes each several times. (cv::imencode / cv::imdecode swapped red and blue in a
// scalar loop on every call: ~8 % of the compose phase's CPU.)
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace uavm {

// `bgr` (8-bit, 3 channels; or 1, grey) as a baseline JPEG of `quality` (1..100) with 4:2:0 chroma, as cv::imencode
// writes it. False with a reason when libjpeg fails.
[[nodiscard]] bool EncodeJpegBgr(const cv::Mat& bgr, int quality, std::vector<uchar>* jpeg, std::string* why);

// The JPEG in `jpeg` as 8-bit BGR; false with a reason for data libjpeg cannot read (or damaged data it warned about).
[[nodiscard]] bool DecodeJpegBgr(const std::vector<uchar>& jpeg, cv::Mat* bgr, std::string* why);

}  // namespace uavm
