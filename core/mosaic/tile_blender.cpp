#include "core/mosaic/tile_blender.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "core/buffers/image_buffer.h"

namespace uavm {

namespace {

// Burt & Adelson's multi-band blend, with the arithmetic of OpenCV's cv::detail::MultiBandBlender (16-bit Laplacian
// levels, float weights, sums truncated as it does: tests/tile_blender_test.cpp checks the two agree), but every level,
// the pieces' pyramids and the scratch are views into buffers that only grow: a worker blends every tile in the same
// memory. OpenCV's allocates each fed piece's pyramid afresh, and those pieces of varying sizes left the heap with
// holes: its own buffers took 25 MiB off the peak of a 5000-frame flight's mosaic.
class MultiBand final : public TileBlender {
 public:
  explicit MultiBand(int bands) : max_bands_(bands) {}
  void Prepare(const cv::Rect& roi) override;
  void Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) override;
  void Blend(cv::Mat* image, cv::Mat* mask) override;

 private:
  static constexpr float kWeightEps = 1e-5f;  // OpenCV's WEIGHT_EPS
  // The piece's pyramid (image levels made Laplacian in place, weight levels Gaussian) over `piece` (dst coordinates,
  // a multiple of 2^bands_), its pixels starting `border` inside.
  void BuildPiecePyramids(const cv::Mat& image, const cv::Mat& mask, const cv::Rect& piece, cv::Point border);
  void AddPieceToSums(const cv::Rect& piece);

  int max_bands_;
  int bands_ = 0;
  cv::Rect roi_;                       // canvas pixels asked for
  cv::Rect padded_;                    // roi_ grown at its bottom right to a multiple of 2^bands_
  std::vector<cv::Mat> sums_;          // per level: sum of weighted Laplacian pieces, CV_16SC3 (views)
  std::vector<cv::Mat> weight_sums_;   // per level: sum of weights, CV_32F (views)
  std::vector<cv::Mat> piece_;         // per level: the fed piece's pyramid, CV_16SC3 (views)
  std::vector<cv::Mat> piece_weight_;  // per level: its weights' Gaussian pyramid, CV_32F (views)
  std::vector<ImageBuffer> sum_buffers_, weight_sum_buffers_, piece_buffers_, piece_weight_buffers_;
  ImageBuffer bordered_buffer_;  // the fed image with its border, before the conversion to 16 bits
  ImageBuffer mask_buffer_;      // the fed mask with its border
  ImageBuffer up_buffer_;        // a level expanded to the one below
};

void MultiBand::Prepare(const cv::Rect& roi) {
  CV_Assert(!roi.empty());
  roi_ = roi;
  // No more levels than halvings of the longer side (as OpenCV counts them).
  const double longest = std::max(1, std::max(roi.width, roi.height));
  bands_ = std::max(0, std::min(max_bands_, static_cast<int>(std::ceil(std::log(longest) / std::log(2.0)))));
  const int step = 1 << bands_;
  padded_ = cv::Rect(roi.x, roi.y, (roi.width + step - 1) / step * step, (roi.height + step - 1) / step * step);
  const auto levels = static_cast<size_t>(bands_ + 1);
  for (auto* buffers : {&sum_buffers_, &weight_sum_buffers_, &piece_buffers_, &piece_weight_buffers_})
    if (buffers->size() < levels) buffers->resize(levels);
  sums_.resize(levels);
  weight_sums_.resize(levels);
  piece_.resize(levels);
  piece_weight_.resize(levels);
  cv::Size size = padded_.size();
  for (size_t i = 0; i < levels; ++i) {
    sums_[i] = sum_buffers_[i].View(size, CV_16SC3);
    weight_sums_[i] = weight_sum_buffers_[i].View(size, CV_32F);
    sums_[i].setTo(cv::Scalar::all(0));
    weight_sums_[i].setTo(0);
    size = cv::Size((size.width + 1) / 2, (size.height + 1) / 2);
  }
}

void MultiBand::Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) {
  CV_Assert(image.type() == CV_8UC3 || image.type() == CV_16SC3);
  CV_Assert(mask.type() == CV_8U && mask.size() == image.size());
  // The piece reaches the pyramid's support beyond the image, is aligned to the coarsest level's grid (so each level
  // is exactly half the one below) and stays inside the padded ROI.
  const int step = 1 << bands_;
  const int reach = 3 * step;
  const cv::Point tl = top_left - padded_.tl();
  cv::Point lo(std::max(0, tl.x - reach), std::max(0, tl.y - reach));
  cv::Point hi(std::min(padded_.width, tl.x + image.cols + reach), std::min(padded_.height, tl.y + image.rows + reach));
  lo = cv::Point(lo.x / step * step, lo.y / step * step);
  const auto round_up = [step](int v) { return (v + step - 1) / step * step; };
  cv::Rect piece(lo, cv::Size(round_up(hi.x - lo.x), round_up(hi.y - lo.y)));
  // (as OpenCV's feed; with lo on the grid and the padded size a multiple of it, the piece never passes the padded ROI)
  piece -= cv::Point(std::max(0, piece.br().x - padded_.width), std::max(0, piece.br().y - padded_.height));
  BuildPiecePyramids(image, mask, piece, tl - piece.tl());
  AddPieceToSums(piece);
}

void MultiBand::BuildPiecePyramids(const cv::Mat& image, const cv::Mat& mask, const cv::Rect& piece, cv::Point border) {
  // Borders of the fed pixels alone (ISOLATED): `image` and `mask` may be parts of larger Mats.
  const int top = border.y;
  const int left = border.x;
  const int bottom = piece.height - top - image.rows;
  const int right = piece.width - left - image.cols;
  piece_[0] = piece_buffers_[0].View(piece.size(), CV_16SC3);
  if (image.type() == CV_16SC3) {
    cv::copyMakeBorder(image, piece_[0], top, bottom, left, right, cv::BORDER_REFLECT | cv::BORDER_ISOLATED);
  } else {
    cv::Mat bordered = bordered_buffer_.View(piece.size(), image.type());
    cv::copyMakeBorder(image, bordered, top, bottom, left, right, cv::BORDER_REFLECT | cv::BORDER_ISOLATED);
    bordered.convertTo(piece_[0], CV_16S);
  }
  cv::Mat bordered_mask = mask_buffer_.View(piece.size(), CV_8U);
  cv::copyMakeBorder(mask, bordered_mask, top, bottom, left, right, cv::BORDER_CONSTANT | cv::BORDER_ISOLATED,
                     cv::Scalar(0));
  piece_weight_[0] = piece_weight_buffers_[0].View(piece.size(), CV_32F);
  bordered_mask.convertTo(piece_weight_[0], CV_32F, 1.0 / 255.0);
  for (size_t i = 1; i <= static_cast<size_t>(bands_); ++i) {
    const cv::Size size((piece_[i - 1].cols + 1) / 2, (piece_[i - 1].rows + 1) / 2);
    piece_[i] = piece_buffers_[i].View(size, CV_16SC3);
    piece_weight_[i] = piece_weight_buffers_[i].View(size, CV_32F);
    cv::pyrDown(piece_[i - 1], piece_[i], size);
    cv::pyrDown(piece_weight_[i - 1], piece_weight_[i], size);
  }
  // Gaussian -> Laplacian from the finest level up: level i still holds its Gaussian when level i - 1 needs it.
  for (size_t i = 0; i < static_cast<size_t>(bands_); ++i) {
    cv::Mat up = up_buffer_.View(piece_[i].size(), CV_16SC3);
    cv::pyrUp(piece_[i + 1], up, piece_[i].size());
    cv::subtract(piece_[i], up, piece_[i]);
  }
}

void MultiBand::AddPieceToSums(const cv::Rect& piece) {
  cv::Rect at = piece;
  for (size_t i = 0; i <= static_cast<size_t>(bands_); ++i) {
    for (int y = 0; y < at.height; ++y) {
      const auto* src = piece_[i].ptr<cv::Vec3s>(y);
      const auto* w = piece_weight_[i].ptr<float>(y);
      auto* dst = sums_[i].ptr<cv::Vec3s>(at.y + y) + at.x;
      auto* dst_w = weight_sums_[i].ptr<float>(at.y + y) + at.x;
      for (int x = 0; x < at.width; ++x) {
        for (int c = 0; c < 3; ++c) dst[x][c] = static_cast<short>(dst[x][c] + static_cast<short>(src[x][c] * w[x]));
        dst_w[x] += w[x];
      }
    }
    at = cv::Rect(at.x / 2, at.y / 2, at.width / 2, at.height / 2);
  }
}

void MultiBand::Blend(cv::Mat* image, cv::Mat* mask) {
  for (size_t i = 0; i < sums_.size(); ++i) {
    for (int y = 0; y < sums_[i].rows; ++y) {
      auto* row = sums_[i].ptr<cv::Vec3s>(y);
      const auto* w = weight_sums_[i].ptr<float>(y);
      for (int x = 0; x < sums_[i].cols; ++x)
        for (int c = 0; c < 3; ++c) row[x][c] = static_cast<short>(row[x][c] / (w[x] + kWeightEps));
    }
  }
  for (size_t i = sums_.size() - 1; i > 0; --i) {
    cv::Mat up = up_buffer_.View(sums_[i - 1].size(), CV_16SC3);
    cv::pyrUp(sums_[i], up, sums_[i - 1].size());
    cv::add(up, sums_[i - 1], sums_[i - 1]);
  }
  const cv::Rect inside(0, 0, roi_.width, roi_.height);
  cv::compare(weight_sums_[0](inside), kWeightEps, *mask, cv::CMP_GT);
  sums_[0](inside).convertTo(*image, CV_8UC3);
  cv::Mat uncovered = mask_buffer_.View(inside.size(), CV_8U);
  cv::compare(weight_sums_[0](inside), kWeightEps, uncovered, cv::CMP_LE);
  image->setTo(cv::Scalar::all(0), uncovered);
}

class SeamOnly final : public TileBlender {
 public:
  void Prepare(const cv::Rect& roi) override {
    roi_ = roi;
    image_ = image_buffer_.View(roi.size(), CV_8UC3);
    image_.setTo(cv::Scalar::all(0));
    mask_ = mask_buffer_.View(roi.size(), CV_8U);
    mask_.setTo(0);
  }
  void Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) override {
    const cv::Rect r(top_left - roi_.tl(), image.size());
    image.copyTo(image_(r), mask);
    mask_(r).setTo(255, mask);
  }
  void Blend(cv::Mat* image, cv::Mat* mask) override {
    image_.copyTo(*image);
    mask_.copyTo(*mask);
  }

 private:
  cv::Rect roi_;
  cv::Mat image_;  // views into the buffers
  cv::Mat mask_;
  ImageBuffer image_buffer_;
  ImageBuffer mask_buffer_;
};

}  // namespace

std::unique_ptr<TileBlender> MakeMultiBandBlender(int num_bands) {
  return std::make_unique<MultiBand>(num_bands);
}
std::unique_ptr<TileBlender> MakeSeamOnlyBlender() {
  return std::make_unique<SeamOnly>();
}

}  // namespace uavm
