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
  void Reserve(cv::Size largest_roi) override;

 private:
  static constexpr float kWeightEps = 1e-5f;  // OpenCV's WEIGHT_EPS
  // The piece's pyramid (image levels made Laplacian in place, weight levels Gaussian) over `piece` (dst coordinates,
  // a multiple of 2^bands_), its pixels starting `border` inside.
  void BuildPiecePyramids(const cv::Mat& image, const cv::Mat& mask, const cv::Rect& piece, cv::Point border);
  void AddPieceToSums(const cv::Rect& piece);

  // One level of the pyramids: views (valid for the current tile and piece) into the level's buffers.
  struct Level {
    cv::Mat sum;           // sum of weighted Laplacian pieces, CV_16SC3
    cv::Mat weight_sum;    // sum of weights, CV_32F
    cv::Mat piece;         // the fed piece's level, CV_16SC3
    cv::Mat piece_weight;  // its weights' Gaussian level, CV_32F
    ImageBuffer sum_buffer, weight_sum_buffer, piece_buffer, piece_weight_buffer;
  };

  int max_bands_;
  int bands_ = 0;
  cv::Rect roi_;                 // canvas pixels asked for
  cv::Rect padded_;              // roi_ grown at its bottom right to a multiple of 2^bands_
  std::vector<Level> levels_;    // bands_ + 1 in use; more kept from a larger tile
  ImageBuffer bordered_buffer_;  // the fed image with its border, before the conversion to 16 bits
  ImageBuffer mask_buffer_;      // the fed mask with its border
  ImageBuffer up_buffer_;        // a level expanded to the one below
};

namespace {

// Pyramid levels for a ROI: no more than halvings of its longer side (as OpenCV counts them).
int BandsFor(cv::Size roi, int max_bands) {
  const double longest = std::max(1, std::max(roi.width, roi.height));
  return std::max(0, std::min(max_bands, static_cast<int>(std::ceil(std::log(longest) / std::log(2.0)))));
}

// The ROI grown at its bottom right to a multiple of 2^bands. A smaller ROI's padded size is never larger (its step
// divides the larger one's).
cv::Size PaddedSize(cv::Size roi, int bands) {
  const int step = 1 << bands;
  return {(roi.width + step - 1) / step * step, (roi.height + step - 1) / step * step};
}

}  // namespace

void MultiBand::Reserve(cv::Size largest_roi) {
  const int bands = BandsFor(largest_roi, max_bands_);
  cv::Size size = PaddedSize(largest_roi, bands);
  // Pieces, their borders and the expanded level are at most the padded ROI (see Feed).
  const auto padded_area = static_cast<size_t>(size.area());
  bordered_buffer_.ReserveResident(padded_area * CV_ELEM_SIZE(CV_8UC3));
  mask_buffer_.ReserveResident(padded_area * CV_ELEM_SIZE(CV_8U));
  up_buffer_.ReserveResident(padded_area * CV_ELEM_SIZE(CV_16SC3));
  if (levels_.size() < static_cast<size_t>(bands + 1)) levels_.resize(static_cast<size_t>(bands + 1));
  for (int i = 0; i <= bands; ++i) {
    Level& level = levels_[static_cast<size_t>(i)];
    const auto area = static_cast<size_t>(size.area());
    level.sum_buffer.ReserveResident(area * CV_ELEM_SIZE(CV_16SC3));
    level.piece_buffer.ReserveResident(area * CV_ELEM_SIZE(CV_16SC3));
    level.weight_sum_buffer.ReserveResident(area * CV_ELEM_SIZE(CV_32F));
    level.piece_weight_buffer.ReserveResident(area * CV_ELEM_SIZE(CV_32F));
    size = cv::Size((size.width + 1) / 2, (size.height + 1) / 2);
  }
}

void MultiBand::Prepare(const cv::Rect& roi) {
  CV_Assert(!roi.empty());
  roi_ = roi;
  bands_ = BandsFor(roi.size(), max_bands_);
  padded_ = cv::Rect(roi.tl(), PaddedSize(roi.size(), bands_));
  if (levels_.size() < static_cast<size_t>(bands_ + 1)) levels_.resize(static_cast<size_t>(bands_ + 1));
  cv::Size size = padded_.size();
  for (int i = 0; i <= bands_; ++i) {
    Level& level = levels_[static_cast<size_t>(i)];
    level.sum = level.sum_buffer.View(size, CV_16SC3);
    level.weight_sum = level.weight_sum_buffer.View(size, CV_32F);
    level.sum.setTo(cv::Scalar::all(0));
    level.weight_sum.setTo(0);
    size = cv::Size((size.width + 1) / 2, (size.height + 1) / 2);
  }
}

void MultiBand::Feed(const cv::Mat& image, const cv::Mat& mask, cv::Point top_left) {
  CV_Assert(image.type() == CV_8UC3);
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
  Level& base = levels_[0];
  base.piece = base.piece_buffer.View(piece.size(), CV_16SC3);
  cv::Mat bordered = bordered_buffer_.View(piece.size(), CV_8UC3);
  cv::copyMakeBorder(image, bordered, top, bottom, left, right, cv::BORDER_REFLECT | cv::BORDER_ISOLATED);
  bordered.convertTo(base.piece, CV_16S);
  cv::Mat bordered_mask = mask_buffer_.View(piece.size(), CV_8U);
  cv::copyMakeBorder(mask, bordered_mask, top, bottom, left, right, cv::BORDER_CONSTANT | cv::BORDER_ISOLATED,
                     cv::Scalar(0));
  base.piece_weight = base.piece_weight_buffer.View(piece.size(), CV_32F);
  bordered_mask.convertTo(base.piece_weight, CV_32F, 1.0 / 255.0);
  for (size_t i = 1; i <= static_cast<size_t>(bands_); ++i) {
    const Level& finer = levels_[i - 1];
    Level& level = levels_[i];
    const cv::Size size((finer.piece.cols + 1) / 2, (finer.piece.rows + 1) / 2);
    level.piece = level.piece_buffer.View(size, CV_16SC3);
    level.piece_weight = level.piece_weight_buffer.View(size, CV_32F);
    cv::pyrDown(finer.piece, level.piece, size);
    cv::pyrDown(finer.piece_weight, level.piece_weight, size);
  }
  // Gaussian -> Laplacian from the finest level up: level i still holds its Gaussian when level i - 1 needs it.
  for (size_t i = 0; i < static_cast<size_t>(bands_); ++i) {
    Level& level = levels_[i];
    cv::Mat up = up_buffer_.View(level.piece.size(), CV_16SC3);
    cv::pyrUp(levels_[i + 1].piece, up, level.piece.size());
    cv::subtract(level.piece, up, level.piece);
  }
}

void MultiBand::AddPieceToSums(const cv::Rect& piece) {
  cv::Rect at = piece;
  for (size_t i = 0; i <= static_cast<size_t>(bands_); ++i) {
    Level& level = levels_[i];
    for (int y = 0; y < at.height; ++y) {
      const auto* src = level.piece.ptr<cv::Vec3s>(y);
      const auto* w = level.piece_weight.ptr<float>(y);
      auto* dst = level.sum.ptr<cv::Vec3s>(at.y + y) + at.x;
      auto* dst_w = level.weight_sum.ptr<float>(at.y + y) + at.x;
      for (int x = 0; x < at.width; ++x) {
        for (int c = 0; c < 3; ++c) dst[x][c] = static_cast<short>(dst[x][c] + static_cast<short>(src[x][c] * w[x]));
        dst_w[x] += w[x];
      }
    }
    at = cv::Rect(at.x / 2, at.y / 2, at.width / 2, at.height / 2);
  }
}

void MultiBand::Blend(cv::Mat* image, cv::Mat* mask) {
  for (int i = 0; i <= bands_; ++i) {
    Level& level = levels_[static_cast<size_t>(i)];
    for (int y = 0; y < level.sum.rows; ++y) {
      auto* row = level.sum.ptr<cv::Vec3s>(y);
      const auto* w = level.weight_sum.ptr<float>(y);
      for (int x = 0; x < level.sum.cols; ++x)
        for (int c = 0; c < 3; ++c) row[x][c] = static_cast<short>(row[x][c] / (w[x] + kWeightEps));
    }
  }
  for (auto i = static_cast<size_t>(bands_); i > 0; --i) {
    cv::Mat& finer = levels_[i - 1].sum;
    cv::Mat up = up_buffer_.View(finer.size(), CV_16SC3);
    cv::pyrUp(levels_[i].sum, up, finer.size());
    cv::add(up, finer, finer);
  }
  const cv::Rect inside(0, 0, roi_.width, roi_.height);
  cv::compare(levels_[0].weight_sum(inside), kWeightEps, *mask, cv::CMP_GT);
  levels_[0].sum(inside).convertTo(*image, CV_8UC3);
  cv::Mat uncovered = mask_buffer_.View(inside.size(), CV_8U);
  cv::bitwise_not(*mask, uncovered);
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
  void Reserve(cv::Size largest_roi) override {
    image_buffer_.ReserveResident(static_cast<size_t>(largest_roi.area()) * CV_ELEM_SIZE(CV_8UC3));
    mask_buffer_.ReserveResident(static_cast<size_t>(largest_roi.area()) * CV_ELEM_SIZE(CV_8U));
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
